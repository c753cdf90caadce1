//! The subgoal-selection stage's config (`subgoal-selection.toml`, defaults shown):
//!
//! ```toml
//! method = "povnav"              # "povnav", "lrn", "goal_heuristic", "dstar_lite" or "hip"
//! camera = "front"               # povnav: reads perception/<camera>/navigability; hip: camera/<camera>/image
//! robot_width_m = 0.8            # povnav: footprint for the safe visual path
//! safety_margin_m = 0.2
//! subgoal_distance_m = 25.0      # lrn: the heading becomes a subgoal this far out;
//!                                # dstar_lite: the subgoal is this far along the path
//! costmap = "fused"              # dstar_lite, hip: plans on costmap/<costmap>
//! replan_rate_hz = 2.0           # dstar_lite, hip: at most this often (D* Lite also on each change)
//! clock = "wall"                 # "stamps": time is the inputs' capture times, and
//!                                # dstar_lite, hip plan once per costmap message
//!                                # (lock-step simulation, replays)
//! input_deadline_s = 1.0         # on capture time: an older required input (the image,
//!                                # bins or costmap; the pose) stops the stage; an older
//!                                # hip camera image drops the learned term
//! hip_library = ""               # hip: the trajectory library (`farsight hip-library` writes one)
//! hip_model = ""                 # hip: model config of the learned density (an output of kind
//!                                # "trajectory_log_likelihood", classes = library size) run on
//!                                # camera/<camera>/image (with clock = "stamps" a costmap waits
//!                                # for its frame's image); empty: the learned term is 0
//! path_max_range_m = 50.0        # povnav: robot-frame path points further out are dropped
//!                                # (near the horizon line, ground projection is ill-conditioned)
//! health_rate_hz = 1.0
//! subgoal_topic = "nav/subgoal"  # where the subgoal goes: the servo follows nav/subgoal; a
//!                                # guide for another instance writes nav/subgoal/<name>
//! guide = ""                     # povnav, dstar_lite, hip: a nav/subgoal/<name> topic whose
//!                                # subgoal (another method's, e.g. LRN's heading) is this
//!                                # instance's goal in place of nav/goal; each frame is planned
//!                                # once the guide's subgoal of the same frame is in
//! # anchor_latitude_deg / anchor_longitude_deg: ENU origin for GPS goals
//!
//! [povnav]                       # see farsight_subgoal_selection::povnav::PovnavConfig
//! [lrn]                          # see farsight_subgoal_selection::lrn_head::LrnHeadConfig (Spot preset)
//! [planner]                      # see farsight_subgoal_selection::planner::WorldPlannerConfig
//! [hip]                          # see farsight_subgoal_selection::hip::HipPlannerConfig
//! ```

use crate::hip::HipPlannerConfig;
use crate::lrn_head::LrnHeadConfig;
use crate::planner::WorldPlannerConfig;
use crate::povnav::PovnavConfig;
use farsight_interfaces::topics;
use farsight_stage::inputs::INPUT_DEADLINE_S;
use farsight_stage::ranges::RATE_HZ;
use farsight_stage::{ConfigError, Io, Need, Range, Ranges, Validate};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SubgoalStageConfig {
    pub method: String,
    pub camera: String,
    pub robot_width_m: f64,
    pub safety_margin_m: f64,
    pub subgoal_distance_m: f64,
    pub path_max_range_m: f64,
    pub costmap: String,
    pub replan_rate_hz: f64,
    pub clock: farsight_stage::ClockSource,
    pub hip_library: std::path::PathBuf,
    pub hip_model: std::path::PathBuf,
    pub health_rate_hz: f64,
    pub input_deadline_s: f64,
    pub anchor_latitude_deg: Option<f64>,
    pub anchor_longitude_deg: Option<f64>,
    pub subgoal_topic: String,
    pub guide: String,
    pub povnav: PovnavConfig,
    pub lrn: LrnHeadConfig,
    pub planner: WorldPlannerConfig,
    pub hip: HipPlannerConfig,
}

impl Default for SubgoalStageConfig {
    fn default() -> Self {
        Self {
            method: "povnav".into(),
            camera: "front".into(),
            robot_width_m: 0.8,
            safety_margin_m: 0.2,
            subgoal_distance_m: 25.0,
            path_max_range_m: 50.0,
            costmap: "fused".into(),
            replan_rate_hz: 2.0,
            clock: Default::default(),
            hip_library: Default::default(),
            hip_model: Default::default(),
            health_rate_hz: 1.0,
            input_deadline_s: farsight_stage::inputs::DEFAULT_INPUT_DEADLINE_S,
            anchor_latitude_deg: None,
            anchor_longitude_deg: None,
            subgoal_topic: topics::subgoal().name().to_string(),
            guide: String::new(),
            povnav: PovnavConfig::default(),
            lrn: LrnHeadConfig::default(),
            planner: WorldPlannerConfig::default(),
            hip: HipPlannerConfig::default(),
        }
    }
}

impl Validate for SubgoalStageConfig {
    fn ranges(&self, r: &mut Ranges) {
        r.key(
            "robot_width_m",
            self.robot_width_m,
            Range::above_to(0.0, 10.0).unit("m"),
        )
        .key(
            "safety_margin_m",
            self.safety_margin_m,
            Range::between(0.0, 10.0).unit("m"),
        )
        .key(
            "subgoal_distance_m",
            self.subgoal_distance_m,
            Range::above_to(0.0, 1000.0).unit("m"),
        )
        .key(
            "path_max_range_m",
            self.path_max_range_m,
            Range::above_to(0.0, 1000.0).unit("m"),
        )
        .key(
            "replan_rate_hz",
            self.replan_rate_hz,
            Range::above_to(0.0, 100.0).unit("Hz"),
        )
        .key("health_rate_hz", self.health_rate_hz, RATE_HZ)
        .key("input_deadline_s", self.input_deadline_s, INPUT_DEADLINE_S)
        .nested("povnav", &self.povnav)
        .nested("lrn", &self.lrn)
        .nested("planner", &self.planner)
        .nested("hip", &self.hip);
        farsight_stage::anchor_ranges(r, self.anchor_latitude_deg, self.anchor_longitude_deg);
    }

    fn check_rules(&self) -> Result<(), ConfigError> {
        ConfigError::check(
            ["povnav", "lrn", "goal_heuristic", "dstar_lite", "hip"]
                .contains(&self.method.as_str()),
            "method",
            &self.method,
            "\"povnav\", \"lrn\", \"goal_heuristic\", \"dstar_lite\" or \"hip\"",
        )?;
        ConfigError::check(
            self.method != "hip" || !self.hip_library.as_os_str().is_empty(),
            "hip_library",
            "\"\"",
            "a trajectory library file when method = \"hip\"",
        )?;
        ConfigError::check(
            self.method != "hip"
                || !self.hip.learner_only()
                || !self.hip_model.as_os_str().is_empty(),
            "hip.phi",
            self.hip.phi,
            "above 0 without a hip_model (phi = 0 is HIP's Learner alone: it plans on the learned term only)",
        )?;
        farsight_interfaces::topics::validate_name(&self.costmap)
            .map_err(|e| ConfigError::invalid("costmap", &self.costmap, e.why))?;
        farsight_interfaces::topics::validate_name(&self.camera)
            .map_err(|e| ConfigError::invalid("camera", &self.camera, e.why))?;
        farsight_stage::check_anchor(self.anchor_latitude_deg, self.anchor_longitude_deg)?;
        let subgoal_kind = Some(topics::TopicKind::Subgoal);
        ConfigError::check(
            topics::kind_of(&self.subgoal_topic) == subgoal_kind,
            "subgoal_topic",
            &self.subgoal_topic,
            "nav/subgoal or nav/subgoal/<name>",
        )?;
        if !self.guide.is_empty() {
            ConfigError::check(
                topics::kind_of(&self.guide) == subgoal_kind && self.guide != self.subgoal_topic,
                "guide",
                &self.guide,
                "a nav/subgoal/<name> topic other than subgoal_topic",
            )?;
            ConfigError::check(
                self.follows_a_guide_kind(),
                "guide",
                &self.guide,
                "empty for method = \"lrn\" or \"goal_heuristic\" (they steer by the goal; \
                 a guide is for povnav, dstar_lite or hip)",
            )?;
        }
        self.hip.check_rules()?;
        self.povnav.check_rules()
    }
}

impl SubgoalStageConfig {
    /// Whether this method can follow a guide's subgoal as its goal.
    fn follows_a_guide_kind(&self) -> bool {
        ["povnav", "dstar_lite", "hip"].contains(&self.method.as_str())
    }
}

impl farsight_stage::DeclaresTopics for SubgoalStageConfig {
    fn topics(&self, instance: &str, _: &std::path::Path) -> Result<Io, String> {
        let c = &self.camera;
        let mut io = Io::for_instance(instance);
        // No goal (or guide), no subgoal: every method needs one.
        let goal = match self.guide.as_str() {
            "" => topics::goal().name().to_string(),
            guide => guide.to_string(),
        };
        io.read(topics::pose().name(), Need::Required)
            .read(goal, Need::Required)
            .write(&self.subgoal_topic);
        match self.method.as_str() {
            "povnav" => {
                io.read(topics::navigability(c).name(), Need::Required)
                    .read(topics::camera_info(c).name(), Need::Required)
                    .write(topics::path("visual").name())
                    .write(topics::path("visual_robot").name());
            }
            "dstar_lite" | "hip" => {
                io.read(topics::costmap(&self.costmap).name(), Need::Required)
                    .write(topics::path("planned").name());
                if self.method == "hip" && !self.hip_model.as_os_str().is_empty() {
                    // Stale or missing: HIP plans without its learned term.
                    io.read(topics::camera_image(c).name(), Need::Optional);
                }
            }
            _ => {
                io.read(topics::angular_bins().name(), Need::Required);
            }
        }
        Ok(io)
    }
}
