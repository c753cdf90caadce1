//! The servo stage as a library type ([`ServoStage`]): each command comes
//! from the newest tracked input (a subgoal: POVNav features or a heading;
//! or a planner's path, by carrot) through the bounded control law and the
//! acceleration limits; a stale input, an active e-stop or a reached goal
//! give zero velocity at once, with the reason in the command and in the
//! stage's health. Staleness is judged on capture time
//! (farsight_stage::inputs): the tracked input carries the oldest capture
//! behind it, and the pose is required when tracking a path or judging a
//! goal. An old command is never republished: every output is computed from
//! the inputs of that moment. Every command carries `command_ttl_s` as its
//! time-to-live, so a base stops by itself once this stage dies or freezes
//! (farsight_interfaces::base).
//!
//! With `clock = "stamps"` (lock-step simulation, replays) time is the
//! inputs' capture times and each new tracked input gets one command, so a
//! run is the same on any machine.

use crate::stage::{ClockSource, ServoStageConfig, Track};
use crate::{
    carrot_command, carrot_point, decide, heading_command, path_in_robot_frame, povnav_command,
    Inputs, RateLimiter,
};
use farsight_interfaces::clock::InputDeadline;
use farsight_interfaces::geo::GoalTracker;
use farsight_interfaces::msg::{
    CommandReason, EStop, HealthState, NavGoal, Path, Pose, ServoMode, Stamp, Subgoal,
    SubgoalSource, VelocityCommand,
};
use farsight_interfaces::topics;
use farsight_stage::inputs::InputId;
use farsight_stage::{Need, Outbox, Ports, Stage, StageEnv, StageInputs, StageKind, Step, Wake};
use std::time::Duration;

/// The servo stage: one instance, its state between steps.
pub struct ServoStage {
    config: ServoStageConfig,
    ports: Ports,
    port: PortIds,
    tracker: GoalTracker,
    tracked: String,
    inputs: StageInputs,
    tracked_in: InputId,
    pose_in: InputId,
    subgoal: Option<Subgoal>,
    path: Option<Path>,
    estop: Option<EStop>,
    pose: Option<Pose>,
    limiter: RateLimiter,
    period: Duration,
    /// The last command's time; the first command's ramp spans one period.
    last_ns: Option<u64>,
    fresh_tracked: bool,
    /// On the stamps' clock time stands still without inputs, so a dead
    /// upstream stage would never make them stale: this deadline on the
    /// wall clock stops the robot anyway.
    watchdog: InputDeadline,
}

struct PortIds {
    subgoal: usize,
    estop: usize,
    path: usize,
    pose: usize,
    goal: usize,
    command: usize,
}

impl StageKind for ServoStage {
    const KIND: &'static str = "velocity-servoing";
    type Config = ServoStageConfig;

    fn new(config: ServoStageConfig, _env: &StageEnv) -> anyhow::Result<Self> {
        let tracker =
            GoalTracker::anchored_at(config.anchor_latitude_deg, config.anchor_longitude_deg)?;
        let period = Duration::from_secs_f64(1.0 / config.output_rate_hz);
        let mut ports = Ports {
            tick: Some(period),
            health_rate_hz: config.health_rate_hz,
            ..Ports::default()
        };
        let port = PortIds {
            subgoal: ports.waking_input(topics::subgoal().name()),
            estop: ports.waking_input(topics::estop().name()),
            path: ports.waking_input(topics::path(&config.path_topic).name()),
            pose: ports.input(topics::pose().name()),
            goal: ports.input(topics::goal().name()),
            command: ports.output(config.command_topic.as_str()),
        };
        let tracked = match config.track {
            Track::Subgoal => topics::subgoal().name().to_string(),
            Track::Path => topics::path(&config.path_topic).name().to_string(),
        };
        // Staleness is judged on capture time: the tracked input's stamp is
        // the oldest capture behind it, so a dead or frozen stage anywhere
        // upstream ages it. A path is followed in the world frame with the
        // pose, and a goal is judged with it, so the pose is then required.
        let mut inputs = StageInputs::new(config.subgoal_deadline_s);
        let tracked_in = inputs.add(&tracked, Need::Required);
        let pose_in = inputs.add(
            topics::pose().name(),
            match config.track {
                Track::Path => Need::Required,
                Track::Subgoal => Need::Optional,
            },
        );
        Ok(Self {
            watchdog: InputDeadline::new(config.subgoal_deadline_s),
            config,
            ports,
            port,
            tracker,
            tracked,
            inputs,
            tracked_in,
            pose_in,
            subgoal: None,
            path: None,
            estop: None,
            pose: None,
            limiter: RateLimiter::default(),
            period,
            last_ns: None,
            fresh_tracked: false,
        })
    }
}

impl Stage for ServoStage {
    fn ports(&self) -> &Ports {
        &self.ports
    }

    fn step(&mut self, step: &mut Step<'_>) {
        self.receive(step);
        // Commands go out on the tick (a fixed output rate, which also
        // judges staleness while nothing arrives), on a new tracked input
        // too where the config asks, and an e-stop is acted on the moment
        // it arrives.
        let now = self.inputs.now_at(self.config.clock, step.wall_ns);
        step.now_ns = now;
        let estop_now =
            step.wake == Wake::Input(self.port.estop) && self.estop.is_some_and(|e| e.active == 1);
        if self.fresh_tracked {
            self.watchdog.seen(step.wall_ns);
        }
        let stamped = self.config.clock == ClockSource::Stamps;
        let starved = stamped && !self.fresh_tracked && self.watchdog.is_stale(step.wall_ns);
        let due = match self.config.clock {
            ClockSource::Wall => {
                step.wake == Wake::Tick || (self.config.command_on_input && self.fresh_tracked)
            }
            ClockSource::Stamps => self.fresh_tracked || (step.wake == Wake::Tick && starved),
        };
        if !due && !estop_now {
            return;
        }
        if starved && !estop_now {
            self.starved_stop(step);
            return;
        }
        self.fresh_tracked = false;
        let (cmd, state, why) = self.command(now, starved);
        let stamp = cmd.stamp;
        step.health.set(state, &why);
        step.out.send(
            self.port.command,
            VelocityCommand {
                ttl_ms: self.config.command_ttl_ms(),
                ..cmd
            },
        );
        step.health.output(stamp, now);
    }

    fn stop(&mut self, out: &mut Outbox) {
        // Leave the robot stopped.
        out.send(
            self.port.command,
            VelocityCommand::stop(Stamp::default(), CommandReason::NO_SUBGOAL),
        );
    }
}

impl ServoStage {
    /// Takes this step's messages in.
    fn receive(&mut self, step: &mut Step<'_>) {
        let track = self.config.track;
        if let Some(s) = step.inbox.take::<Subgoal>(self.port.subgoal) {
            if track == Track::Subgoal {
                step.health.input();
                self.inputs.consumed(self.tracked_in, s.stamp);
                self.fresh_tracked = true;
            }
            self.subgoal = Some(s);
        }
        if let Some(p) = step.inbox.take::<Path>(self.port.path) {
            if track == Track::Path {
                step.health.input();
                self.inputs.consumed(self.tracked_in, p.stamp);
                self.fresh_tracked = true;
            }
            self.path = Some(p);
        }
        if let Some(e) = step.inbox.take::<EStop>(self.port.estop) {
            self.estop = Some(e);
        }
        if let Some(p) = step.inbox.take::<Pose>(self.port.pose) {
            self.inputs.consumed(self.pose_in, p.stamp);
            self.tracker.set_pose(p);
            self.pose = Some(p);
        }
        if let Some(g) = step.inbox.take::<NavGoal>(self.port.goal) {
            self.tracker.set_goal(g);
            // Whether the goal is reached is judged with the pose.
            self.inputs.set_need(self.pose_in, Need::Required);
        }
    }

    /// On the stamps' clock, the wall-clock watchdog's stop: upstream has
    /// sent nothing for `subgoal_deadline_s` of wall time. It goes to the
    /// base at once, but it is not a step of the control law: on the
    /// stamps' clock no time passes between inputs, so the ramp state is
    /// left as it was (otherwise how fast a machine delivers the inputs
    /// would change the track), and it carries no input's stamp, since no
    /// input is behind it (a lock-step simulator never takes it for the
    /// answer to a frame).
    fn starved_stop(&mut self, step: &mut Step<'_>) {
        let why = format!(
            "no {} for {} s of wall time",
            self.tracked, self.config.subgoal_deadline_s
        );
        step.health.set(HealthState::DEGRADED, &why);
        step.out.send(
            self.port.command,
            VelocityCommand {
                ttl_ms: self.config.command_ttl_ms(),
                ..VelocityCommand::stop(Stamp::default(), CommandReason::STALE_INPUT)
            },
        );
    }

    /// The command for `now`, with the health state and reason it implies.
    fn command(&mut self, now: u64, starved: bool) -> (VelocityCommand, HealthState, String) {
        let config = &self.config;
        let goal_distance = self.tracker.goal_in_robot_frame().map(|(_, d)| d);
        let freshness = self.inputs.check(now);
        let decision = Inputs {
            subgoal_stale: freshness.is_stale() || starved,
            estop_active: self.estop.is_some_and(|e| e.active == 1),
            goal_distance_m: goal_distance,
        };
        // The command carries the oldest capture behind it; before every
        // required input is in, the tracked input's (what a lock-step
        // simulator waits for).
        let stamp = self
            .inputs
            .output_stamp()
            .or(self.inputs.newest(self.tracked_in))
            .unwrap_or_default();
        if let Some(reason) = decide(&decision, &config.servo) {
            self.limiter.stop();
            // The next command's ramp starts from the stop, over one period.
            self.last_ns = None;
            let why = match reason {
                CommandReason::STALE_INPUT if starved => format!(
                    "no {} for {} s of wall time",
                    self.tracked, config.subgoal_deadline_s
                ),
                CommandReason::STALE_INPUT => freshness.reason().to_string(),
                CommandReason::ESTOP => "e-stop active".to_string(),
                _ => "goal reached".to_string(),
            };
            let state = if reason == CommandReason::GOAL_REACHED {
                HealthState::OK
            } else {
                HealthState::DEGRADED
            };
            return (VelocityCommand::stop(stamp, reason), state, why);
        }
        let target = match config.track {
            Track::Subgoal => match self.subgoal {
                Some(s) if s.source == SubgoalSource::POVNAV => Ok(povnav_command(
                    s.proximity_lambda_px as f64,
                    s.alignment_phi_rad as f64,
                    &config.servo,
                )),
                // A heading law has no "blocked" manoeuvre (POVNav's law
                // turns in place on its own blocked subgoal, above): a
                // subgoal that says nothing is affordable, or whose heading
                // is not a number, stops the robot with that reason rather
                // than with a zero it calls tracking.
                Some(s) if s.mode == ServoMode::BLOCKED => {
                    Err(format!("subgoal from {} is blocked", s.source))
                }
                Some(s) if !s.heading_rad.is_finite() => Err(format!(
                    "subgoal from {} has heading {}",
                    s.source, s.heading_rad
                )),
                Some(s) => Ok(heading_command(s.heading_rad as f64, &config.servo)),
                None => Err("no subgoal yet".to_string()),
            },
            Track::Path => match &self.path {
                Some(p) => path_in_robot_frame(p, self.pose.as_ref()).and_then(|points| {
                    carrot_point(&points, config.servo.lookahead_m)
                        .map(|c| carrot_command(c, &config.servo))
                        .ok_or_else(|| "path is empty or not finite".to_string())
                }),
                None => Err("no path yet".to_string()),
            },
        };
        match target {
            Ok(target) => {
                let dt = self.last_ns.map_or(self.period.as_secs_f64(), |t| {
                    now.saturating_sub(t) as f64 * 1e-9
                });
                self.last_ns = Some(now);
                let (v, w) = self.limiter.limit(target, dt, &config.servo);
                let cmd = VelocityCommand {
                    stamp,
                    linear_mps: v as f32,
                    angular_radps: w as f32,
                    reason: CommandReason::TRACKING,
                    ..Default::default()
                };
                (cmd, HealthState::OK, String::new())
            }
            Err(why) => {
                // An untrackable input stops the robot like a stale one.
                self.limiter.stop();
                self.last_ns = None;
                let cmd = VelocityCommand::stop(stamp, CommandReason::NO_SUBGOAL);
                (cmd, HealthState::DEGRADED, why)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use farsight_interfaces::fixed::FixedVec;
    use farsight_interfaces::message::Message;
    use farsight_interfaces::msg::PathFrame;
    use farsight_stage::runtime::Harness;

    const S: u64 = 1_000_000_000;

    fn stage(toml: &str) -> Harness<ServoStage> {
        let config: ServoStageConfig = farsight_stage::parse_config(toml, "test").unwrap();
        let env = StageEnv {
            instance: "servo".into(),
            config_dir: ".".into(),
        };
        Harness::new(ServoStage::new(config, &env).unwrap())
    }

    fn stamp(t_ns: u64, seq: u64) -> Stamp {
        Stamp {
            capture_time_ns: t_ns,
            frame_seq: seq,
        }
    }

    fn heading(t_ns: u64, seq: u64, heading_rad: f32) -> Subgoal {
        Subgoal {
            stamp: stamp(t_ns, seq),
            heading_rad,
            source: SubgoalSource::LRN,
            ..Default::default()
        }
    }

    fn commands(out: Vec<(String, Message)>) -> Vec<VelocityCommand> {
        out.into_iter()
            .map(|(topic, m)| {
                assert_eq!(topic, "cmd/velocity");
                VelocityCommand::try_from(m).unwrap()
            })
            .collect()
    }

    #[test]
    fn on_stamps_each_fresh_subgoal_gets_one_command_carrying_its_capture() {
        let mut h = stage("clock = \"stamps\"");
        let wake = h.wake_on("nav/subgoal");
        h.put("nav/subgoal", heading(10 * S, 1, 0.3));
        let cmds = commands(h.step(wake, 0));
        assert_eq!(cmds.len(), 1);
        assert_eq!(cmds[0].reason, CommandReason::TRACKING);
        assert_eq!(cmds[0].stamp.frame_seq, 1);
        assert!(cmds[0].angular_radps > 0.0, "turns toward +0.3 rad");
        assert_eq!(cmds[0].ttl_ms, 250);
        // A tick with nothing new sends nothing (the wall watchdog is fresh).
        assert!(h.step(Wake::Tick, S / 10).is_empty());
        assert_eq!(h.health.report().messages_in, 1);
    }

    #[test]
    fn on_stamps_the_wall_watchdog_stops_the_robot_without_changing_the_next_command() {
        // Two subgoals 0.1 s apart in capture time; in one run the machine
        // takes 3 s of wall time to deliver the second (past the 2 s
        // deadline), so the watchdog stops the robot in between.
        let run = |stall: bool| {
            let mut h = stage("clock = \"stamps\"\nsubgoal_deadline_s = 2.0");
            let wake = h.wake_on("nav/subgoal");
            h.put("nav/subgoal", heading(10 * S, 1, 0.2));
            let first = commands(h.step(wake, 0));
            let mut stops = Vec::new();
            if stall {
                stops = commands(h.step(Wake::Tick, 3 * S));
                assert_eq!(h.health.state(), HealthState::DEGRADED);
                assert!(h.health.report().reason.as_str().contains("wall time"));
            }
            h.put("nav/subgoal", heading(10 * S + S / 10, 2, 0.2));
            let second = commands(h.step(wake, if stall { 3 * S + S / 10 } else { S / 10 }));
            (first, stops, second)
        };
        let (first, none, second) = run(false);
        let (first_stalled, stops, second_stalled) = run(true);
        assert!(none.is_empty());
        assert_eq!(first, first_stalled);
        assert_eq!(stops.len(), 1);
        assert_eq!(stops[0].reason, CommandReason::STALE_INPUT);
        assert_eq!((stops[0].linear_mps, stops[0].angular_radps), (0.0, 0.0));
        assert_eq!(stops[0].stamp, Stamp::default(), "answers no frame");
        assert!(
            second[0].linear_mps > first[0].linear_mps,
            "still ramping up"
        );
        assert_eq!(
            second, second_stalled,
            "the stall leaves the track as it was"
        );
    }

    #[test]
    fn on_the_wall_clock_a_stale_subgoal_stops_the_robot_naming_the_input() {
        let mut h = stage("");
        let wake = h.wake_on("nav/subgoal");
        h.put("nav/subgoal", heading(10 * S, 1, 0.0));
        assert!(h.step(wake, 10 * S).is_empty(), "commands go out on ticks");
        let moving = commands(h.step(Wake::Tick, 10 * S + S / 10));
        assert_eq!(moving[0].reason, CommandReason::TRACKING);
        // 0.6 s after its capture, past the 0.5 s deadline.
        let stale = commands(h.step(Wake::Tick, 10 * S + 6 * S / 10));
        assert_eq!(stale[0].reason, CommandReason::STALE_INPUT);
        assert_eq!((stale[0].linear_mps, stale[0].angular_radps), (0.0, 0.0));
        assert_eq!(h.health.state(), HealthState::DEGRADED);
        assert!(h.health.report().reason.as_str().contains("nav/subgoal"));
    }

    #[test]
    fn with_command_on_input_a_new_subgoal_is_answered_at_once_and_the_tick_still_judges_it() {
        let mut h = stage("command_on_input = true");
        let wake = h.wake_on("nav/subgoal");
        h.put("nav/subgoal", heading(10 * S, 1, 0.3));
        let first = commands(h.step(wake, 10 * S + S / 100));
        assert_eq!(first.len(), 1, "not waiting for the tick");
        assert_eq!(first[0].reason, CommandReason::TRACKING);
        assert_eq!(first[0].stamp.frame_seq, 1);
        assert!(first[0].angular_radps > 0.0);
        // A wake that brings no new subgoal sends nothing.
        assert!(h.step(wake, 10 * S + S / 50).is_empty());
        // The tick goes on: tracking while fresh, a stop once stale.
        let tick = commands(h.step(Wake::Tick, 10 * S + S / 20));
        assert_eq!(tick[0].reason, CommandReason::TRACKING);
        let stale = commands(h.step(Wake::Tick, 10 * S + 6 * S / 10));
        assert_eq!(stale[0].reason, CommandReason::STALE_INPUT);
        assert_eq!((stale[0].linear_mps, stale[0].angular_radps), (0.0, 0.0));
        // A subgoal that arrives already stale is answered at once with a stop.
        h.put("nav/subgoal", heading(10 * S + S / 100, 2, 0.3));
        let late = commands(h.step(wake, 11 * S));
        assert_eq!(late[0].reason, CommandReason::STALE_INPUT);
        assert_eq!((late[0].linear_mps, late[0].angular_radps), (0.0, 0.0));
    }

    #[test]
    fn an_estop_stops_at_once_between_ticks() {
        let mut h = stage("");
        h.put("nav/subgoal", heading(10 * S, 1, 0.0));
        h.step(Wake::Tick, 10 * S);
        let wake = h.wake_on("safety/estop");
        h.put(
            "safety/estop",
            EStop {
                stamp: stamp(10 * S, 1),
                active: 1,
                ..Default::default()
            },
        );
        let cmds = commands(h.step(wake, 10 * S + S / 100));
        assert_eq!(cmds.len(), 1, "not waiting for the tick");
        assert_eq!(cmds[0].reason, CommandReason::ESTOP);
    }

    #[test]
    fn a_path_without_a_pose_is_not_followed() {
        let mut h = stage("track = \"path\"\nclock = \"stamps\"");
        let wake = h.wake_on("nav/path/planned");
        h.put(
            "nav/path/planned",
            Path {
                stamp: stamp(10 * S, 1),
                ..Default::default()
            },
        );
        let cmds = commands(h.step(wake, 0));
        assert_eq!(cmds[0].reason, CommandReason::STALE_INPUT);
        assert!(h.health.report().reason.as_str().contains("state/pose"));
    }

    #[test]
    fn an_empty_path_a_planner_answers_with_stops_the_robot_on_that_frame() {
        // What a map planner with no plan sends (subgoal-selection): the
        // frame gets a stop carrying its stamp, not silence.
        let mut h = stage("track = \"path\"\nclock = \"stamps\"");
        let wake = h.wake_on("nav/path/planned");
        let pose = |seq: u64| Pose {
            stamp: stamp(10 * S + seq * S / 10, seq),
            ..Default::default()
        };
        let path = |seq: u64, points: &[[f32; 2]]| Path {
            stamp: stamp(10 * S + seq * S / 10, seq),
            frame: PathFrame::WORLD,
            points: FixedVec::from_slice(points).unwrap(),
            ..Default::default()
        };
        h.put("state/pose", pose(1));
        h.put("nav/path/planned", path(1, &[[0.0, 0.0], [5.0, 0.0]]));
        let moving = commands(h.step(wake, 0));
        assert_eq!(moving[0].reason, CommandReason::TRACKING);
        assert!(moving[0].linear_mps > 0.0, "{moving:?}");
        h.put("state/pose", pose(2));
        h.put("nav/path/planned", path(2, &[]));
        let stop = commands(h.step(wake, 0));
        assert_eq!(stop.len(), 1);
        assert_eq!(stop[0].stamp, stamp(10 * S + 2 * S / 10, 2));
        assert_eq!(stop[0].reason, CommandReason::NO_SUBGOAL);
        assert_eq!((stop[0].linear_mps, stop[0].angular_radps), (0.0, 0.0));
        assert!(h.health.report().reason.as_str().contains("empty"));
    }

    #[test]
    fn a_blocked_or_headingless_heading_subgoal_stops_the_robot_on_that_frame() {
        // What LRN's head sends when no observed bin is affordable: the
        // frame gets a stop carrying its stamp, named as such.
        let mut h = stage("clock = \"stamps\"");
        let wake = h.wake_on("nav/subgoal");
        h.put("nav/subgoal", heading(10 * S, 1, 0.3));
        let moving = commands(h.step(wake, 0));
        assert_eq!(moving[0].reason, CommandReason::TRACKING);
        assert!(moving[0].linear_mps > 0.0, "{moving:?}");
        let blocked = Subgoal {
            mode: ServoMode::BLOCKED,
            ..heading(10 * S + S / 10, 2, 0.3)
        };
        h.put("nav/subgoal", blocked);
        let stop = commands(h.step(wake, 0));
        assert_eq!(stop.len(), 1);
        assert_eq!(stop[0].stamp, stamp(10 * S + S / 10, 2));
        assert_eq!(stop[0].reason, CommandReason::NO_SUBGOAL);
        assert_eq!((stop[0].linear_mps, stop[0].angular_radps), (0.0, 0.0));
        assert!(h.health.report().reason.as_str().contains("blocked"));
        for bad in [f32::NAN, f32::INFINITY] {
            h.put("nav/subgoal", heading(10 * S + S / 5, 3, bad));
            let stop = commands(h.step(wake, 0));
            assert_eq!(stop[0].reason, CommandReason::NO_SUBGOAL, "heading {bad}");
            assert_eq!((stop[0].linear_mps, stop[0].angular_radps), (0.0, 0.0));
            assert!(h.health.report().reason.as_str().contains("heading"));
        }
    }

    #[test]
    fn ports_are_what_the_config_declares_to_the_graph() {
        use farsight_stage::DeclaresTopics;
        for toml in ["", "track = \"path\"\ncommand_topic = \"cmd/autonomy\""] {
            let h = stage(toml);
            let config: ServoStageConfig = farsight_stage::parse_config(toml, "test").unwrap();
            let io = config.topics("servo", std::path::Path::new(".")).unwrap();
            farsight_stage::runtime::check_ports(&io, h.stage.ports()).unwrap();
        }
    }

    #[test]
    fn a_clean_stop_leaves_a_stop_command() {
        let mut h = stage("");
        let cmds = commands(h.stop());
        assert_eq!(cmds.len(), 1);
        assert_eq!(cmds[0].linear_mps, 0.0);
    }
}
