//! `farsight-velocity-servoing`: publishes a velocity command at a fixed rate.
//! Each command comes from the newest tracked input (a subgoal: POVNav
//! features or a heading; or a planner's path, by carrot) through the bounded
//! control law and the acceleration limits; a stale input, an active e-stop or
//! a reached goal give zero velocity at once, with the reason in the command
//! and in the stage's health. Staleness is judged on capture time
//! (farsight_stage::inputs): the tracked input carries the oldest capture
//! behind it, and the pose is required when tracking a path or judging a
//! goal. An old command is never republished: every
//! output is computed from the inputs of that moment. Every command carries
//! `command_ttl_s` as its time-to-live, so a base stops by itself once this
//! stage dies or freezes (farsight_interfaces::base).
//!
//! With `clock = "stamps"` (lock-step simulation, replays) time is the
//! inputs' capture times and each new tracked input gets one command, so a
//! run is the same on any machine.

use anyhow::Result;
use farsight_interfaces::clock::{Clock, InputDeadline, WallClock};
use farsight_interfaces::geo::GoalTracker;
use farsight_interfaces::msg::{CommandReason, HealthState, Stamp, SubgoalSource, VelocityCommand};
use farsight_interfaces::topics;
use farsight_interfaces::transport::ipc::{self, Bus, Wake};
use farsight_stage::{load_config, Health, Need, StageArgs, StageInputs};
use farsight_velocity_servoing::stage::{ClockSource, ServoStageConfig, Track};
use farsight_velocity_servoing::{
    carrot_command, carrot_point, decide, heading_command, path_in_robot_frame, povnav_command,
    Inputs, RateLimiter,
};
use std::ops::ControlFlow;
use std::time::Duration;

const STAGE: &str = "velocity-servoing";

fn main() {
    farsight_stage::run_main(STAGE, run);
}

fn run() -> Result<()> {
    let args = StageArgs::parse(STAGE)?;
    let instance = args.instance.as_str();
    farsight_stage::init_tracing(args.log_format);
    let config: ServoStageConfig = load_config(args.config.as_deref())?;
    let mut tracker =
        GoalTracker::anchored_at(config.anchor_latitude_deg, config.anchor_longitude_deg)?;
    let bus = Bus::open(instance)?;
    let subgoals = bus.subscriber(&topics::subgoal())?;
    let paths = bus.subscriber(&topics::path(&config.path_topic))?;
    let estops = bus.subscriber(&topics::estop())?;
    let poses = bus.subscriber(&topics::pose())?;
    let goals = bus.subscriber(&topics::goal())?;
    let commands = bus.publisher(&topics::Topic::<VelocityCommand>::new(
        config.command_topic.as_str(),
    )?)?;
    let mut health = Health::new(&bus, instance, config.health_rate_hz)?;
    farsight_stage::announce_ready(instance);

    let tracked = match config.track {
        Track::Subgoal => "nav/subgoal".to_string(),
        Track::Path => topics::path(&config.path_topic).name().to_string(),
    };
    // Staleness is judged on capture time: the tracked input's stamp is the
    // oldest capture behind it, so a dead or frozen stage anywhere upstream
    // ages it. A path is followed in the world frame with the pose, and a
    // goal is judged with it, so the pose is then required too.
    let mut inputs = StageInputs::new(config.subgoal_deadline_s);
    let tracked_in = inputs.add(&tracked, Need::Required);
    let pose_in = inputs.add(
        topics::pose().name(),
        match config.track {
            Track::Path => Need::Required,
            Track::Subgoal => Need::Optional,
        },
    );
    let (mut subgoal, mut path, mut estop, mut pose) = (None, None, None, None);
    let mut limiter = RateLimiter::default();
    let period = Duration::from_secs_f64(1.0 / config.output_rate_hz);
    // The first command's ramp spans one nominal period.
    let mut last_ns: Option<u64> = None;
    let mut fresh_tracked = false;
    // On the stamps' clock time stands still without inputs, so a dead
    // upstream stage would never make them stale: this watchdog on the
    // wall clock stops the robot anyway.
    let mut watchdog = InputDeadline::new(config.subgoal_deadline_s);
    ipc::wait_loop(
        &[subgoals.listener(), estops.listener(), paths.listener()],
        Some(period),
        |wake| {
            let stamped = config.clock == ClockSource::Stamps;
            match subgoals.latest() {
                Ok(Some(s)) => {
                    if config.track == Track::Subgoal {
                        health.input();
                        inputs.consumed(tracked_in, s.stamp);
                        fresh_tracked = true;
                    }
                    subgoal = Some(s);
                }
                Ok(None) => {}
                Err(e) => health.dropped(&e),
            }
            match paths.latest() {
                Ok(Some(p)) => {
                    if config.track == Track::Path {
                        health.input();
                        inputs.consumed(tracked_in, p.stamp);
                        fresh_tracked = true;
                    }
                    path = Some(p);
                }
                Ok(None) => {}
                Err(e) => health.dropped(&e),
            }
            if let Ok(Some(e)) = estops.latest() {
                estop = Some(e);
            }
            if let Ok(Some(p)) = poses.latest() {
                inputs.consumed(pose_in, p.stamp);
                tracker.set_pose(p);
                pose = Some(p);
            }
            if let Ok(Some(g)) = goals.latest() {
                tracker.set_goal(g);
                // Whether the goal is reached is judged with the pose.
                inputs.set_need(pose_in, Need::Required);
            }
            // Commands go out on the tick only (a fixed output rate), and an e-stop
            // is acted on the moment it arrives.
            let now = inputs.now_ns(config.clock);
            let estop_now = wake == Wake::Input(1) && estop.is_some_and(|e| e.active == 1);
            if fresh_tracked {
                watchdog.seen(WallClock.now_ns());
            }
            let starved = stamped && !fresh_tracked && watchdog.is_stale(WallClock.now_ns());
            let due = match config.clock {
                ClockSource::Wall => wake == Wake::Tick,
                ClockSource::Stamps => fresh_tracked || (wake == Wake::Tick && starved),
            };
            if !due && !estop_now {
                if wake == Wake::Tick {
                    health.tick(now);
                }
                return ControlFlow::Continue(());
            }
            fresh_tracked = false;
            let goal_distance = tracker.goal_in_robot_frame().map(|(_, d)| d);
            let freshness = inputs.check(now);
            let decision = Inputs {
                subgoal_stale: freshness.is_stale() || starved,
                estop_active: estop.is_some_and(|e| e.active == 1),
                goal_distance_m: goal_distance,
            };
            // The command carries the oldest capture behind it; before every
            // required input is in, the tracked input's (what a lock-step
            // simulator waits for).
            let stamp = inputs
                .output_stamp()
                .or(inputs.newest(tracked_in))
                .unwrap_or_default();
            let cmd = match decide(&decision, &config.servo) {
                Some(reason) => {
                    limiter.stop();
                    // The next command's ramp starts from the stop, over one period.
                    last_ns = None;
                    let why = match reason {
                        CommandReason::STALE_INPUT if starved => format!(
                            "no {tracked} for {} s of wall time",
                            config.subgoal_deadline_s
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
                    health.set(state, &why);
                    VelocityCommand::stop(stamp, reason)
                }
                None => {
                    let target = match config.track {
                        Track::Subgoal => {
                            let s = subgoal.expect("not stale, so received");
                            Ok(if s.source == SubgoalSource::POVNAV {
                                povnav_command(
                                    s.proximity_lambda_px as f64,
                                    s.alignment_phi_rad as f64,
                                    &config.servo,
                                )
                            } else {
                                heading_command(s.heading_rad as f64, &config.servo)
                            })
                        }
                        Track::Path => {
                            let p = path.expect("not stale, so received");
                            path_in_robot_frame(&p, pose.as_ref()).and_then(|points| {
                                carrot_point(&points, config.servo.lookahead_m)
                                    .map(|c| carrot_command(c, &config.servo))
                                    .ok_or_else(|| "path is empty or not finite".to_string())
                            })
                        }
                    };
                    match target {
                        Ok(target) => {
                            health.set(HealthState::OK, "");
                            let dt = last_ns.map_or(period.as_secs_f64(), |t| {
                                now.saturating_sub(t) as f64 * 1e-9
                            });
                            last_ns = Some(now);
                            let (v, w) = limiter.limit(target, dt, &config.servo);
                            VelocityCommand {
                                stamp,
                                linear_mps: v as f32,
                                angular_radps: w as f32,
                                reason: CommandReason::TRACKING,
                                ..Default::default()
                            }
                        }
                        Err(why) => {
                            // An untrackable input stops the robot like a stale one.
                            limiter.stop();
                            last_ns = None;
                            health.set(HealthState::DEGRADED, &why);
                            VelocityCommand::stop(stamp, CommandReason::NO_SUBGOAL)
                        }
                    }
                }
            };
            let cmd = VelocityCommand {
                ttl_ms: config.command_ttl_ms(),
                ..cmd
            };
            match commands.publish(&cmd) {
                Ok(()) => health.output(stamp, now),
                Err(e) => health.dropped(&e),
            }
            health.tick(now);
            ControlFlow::Continue(())
        },
    )?;
    // Leave the robot stopped.
    let _ = commands.publish(&VelocityCommand::stop(
        Stamp::default(),
        CommandReason::NO_SUBGOAL,
    ));
    health.stopping(WallClock.now_ns());
    Ok(())
}
