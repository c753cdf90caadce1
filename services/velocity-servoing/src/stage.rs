//! The servo stage's config (`velocity-servoing.toml`, defaults shown):
//!
//! ```toml
//! output_rate_hz = 20.0          # commands are published at this rate, always
//! command_on_input = false       # on the wall clock, also one command the moment a new
//!                                # tracked input arrives (capture-to-command without
//!                                # waiting up to a period for the tick); the tick goes on,
//!                                # so a stale input still stops the robot on time
//! clock = "wall"                 # "wall": the system clock, commands at output_rate_hz;
//!                                # "stamps": time is the inputs' capture times and one
//!                                # command answers each new tracked input (lock-step
//!                                # simulation and replays; never on a robot: with no
//!                                # input, time stands still and nothing goes stale)
//! track = "subgoal"              # "subgoal" (nav/subgoal: POVNav features or an
//!                                # LRN heading) or "path" (a planner's path, by carrot)
//! path_topic = "planned"         # with track = "path": nav/path/<path_topic>
//! subgoal_deadline_s = 0.5       # stop when the tracked input (subgoal or path), or the
//!                                # pose it needs, is older than this, measured from the
//!                                # capture time of the oldest frame behind it: a dead or
//!                                # frozen stage anywhere upstream stops the robot
//! command_topic = "cmd/velocity" # where commands go: the base's topic when the servo is
//!                                # its only writer; "cmd/autonomy" behind farsight-command-mux
//! command_ttl_s = 0.25           # every command's time-to-live: the base obeys it this
//!                                # long after receipt, then stops unless a newer one came
//!                                # (so a dead or frozen servo stops the robot)
//! health_rate_hz = 1.0
//! # anchor_latitude_deg / anchor_longitude_deg: the ENU origin for GPS goals
//! # (default: the first GPS fix in the pose)
//!
//! [servo]                        # see farsight_velocity_servoing::ServoConfig
//! desired_proximity_px = 50.0
//! k_linear = 0.01
//! k_angular = 1.5
//! max_linear_mps = 0.5
//! max_angular_radps = 3.141592653589793
//! max_linear_accel_mps2 = 1.0
//! max_angular_accel_radps2 = 3.0
//! max_lateral_accel_mps2 = 0.0   # friction circle, 0 = off
//! allow_reverse = false
//! goal_radius_m = 0.5
//! lookahead_m = 2.0              # carrot distance along a tracked path
//! ```

use crate::ServoConfig;
use farsight_interfaces::topics;
use farsight_stage::ranges::RATE_HZ;
pub use farsight_stage::ClockSource;
use farsight_stage::{ConfigError, Io, Need, Range, Ranges, Validate};
use serde::{Deserialize, Serialize};

/// Which input the servo follows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Track {
    /// `nav/subgoal`: POVNav's features through its control law, or a heading.
    #[default]
    Subgoal,
    /// `nav/path/<path_topic>`: a carrot point along a planner's path.
    Path,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ServoStageConfig {
    pub output_rate_hz: f64,
    pub command_on_input: bool,
    pub clock: ClockSource,
    pub track: Track,
    pub path_topic: String,
    pub subgoal_deadline_s: f64,
    pub command_topic: String,
    pub command_ttl_s: f64,
    pub health_rate_hz: f64,
    pub anchor_latitude_deg: Option<f64>,
    pub anchor_longitude_deg: Option<f64>,
    pub servo: ServoConfig,
}

impl Default for ServoStageConfig {
    fn default() -> Self {
        Self {
            output_rate_hz: 20.0,
            command_on_input: false,
            clock: ClockSource::Wall,
            track: Track::Subgoal,
            path_topic: "planned".into(),
            subgoal_deadline_s: 0.5,
            command_topic: "cmd/velocity".into(),
            command_ttl_s: 0.25,
            health_rate_hz: 1.0,
            anchor_latitude_deg: None,
            anchor_longitude_deg: None,
            servo: ServoConfig::default(),
        }
    }
}

impl Validate for ServoStageConfig {
    fn ranges(&self, r: &mut Ranges) {
        r.key("output_rate_hz", self.output_rate_hz, RATE_HZ)
            .key(
                "subgoal_deadline_s",
                self.subgoal_deadline_s,
                Range::above_to(0.0, 60.0).unit("s"),
            )
            .key(
                "command_ttl_s",
                self.command_ttl_s,
                Range::above_to(0.0, 60.0).unit("s"),
            )
            .key("health_rate_hz", self.health_rate_hz, RATE_HZ)
            .nested("servo", &self.servo);
        farsight_stage::anchor_ranges(r, self.anchor_latitude_deg, self.anchor_longitude_deg);
    }

    fn check_rules(&self) -> Result<(), ConfigError> {
        // A TTL of about one output period would stop the base between two
        // commands of a healthy servo at the least jitter.
        ConfigError::check(
            self.command_ttl_s * self.output_rate_hz >= 2.0,
            "command_ttl_s",
            self.command_ttl_s,
            "seconds, at least two output periods (2 / output_rate_hz)",
        )?;
        ConfigError::check(
            !self.path_topic.is_empty() && !self.path_topic.contains(char::is_whitespace),
            "path_topic",
            &self.path_topic,
            "a topic name such as \"planned\"",
        )?;
        ConfigError::check(
            matches!(
                farsight_interfaces::topics::kind_of(&self.command_topic),
                Some(farsight_interfaces::topics::TopicKind::VelocityCommand)
            ),
            "command_topic",
            &self.command_topic,
            "a command topic: \"cmd/velocity\" or a command mux input such as \"cmd/autonomy\"",
        )?;
        farsight_stage::check_anchor(self.anchor_latitude_deg, self.anchor_longitude_deg)
    }
}

impl ServoStageConfig {
    /// [`Self::command_ttl_s`] as the command's `ttl_ms` field.
    pub fn command_ttl_ms(&self) -> u16 {
        (self.command_ttl_s * 1e3)
            .round()
            .clamp(1.0, f64::from(u16::MAX)) as u16
    }
}

impl farsight_stage::DeclaresTopics for ServoStageConfig {
    fn topics(&self, instance: &str, _: &std::path::Path) -> Result<Io, String> {
        let mut io = Io::for_instance(instance);
        match self.track {
            Track::Subgoal => {
                // The pose becomes required once a goal is set (the
                // goal-reached stop needs it); a subgoal alone can steer.
                io.read(topics::subgoal().name(), Need::Required)
                    .read(topics::pose().name(), Need::Optional);
            }
            Track::Path => {
                io.read(topics::path(&self.path_topic).name(), Need::Required)
                    .read(topics::pose().name(), Need::Required);
            }
        }
        io.read(topics::goal().name(), Need::Optional)
            .read(topics::estop().name(), Need::Optional)
            .write(self.command_topic.clone());
        Ok(io)
    }
}
