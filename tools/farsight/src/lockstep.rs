//! A graph file driven by the simulator in one process: the graph's nodes
//! built as stage library types and composed by the in-process executor
//! (`farsight_stage::executor`), the simulated robot
//! (`farsight_sim::sim_robot`) feeding them each frame and driving with the
//! command they answer. No processes and no shared memory, and
//! deterministic: a seed drives the same track every run, and the same
//! track as `farsight demo`, which runs the same graph file as processes
//! against `farsight-sim run` (tests/closed_loop.rs compares the two).
//! `farsight bench nav` runs its trials here.

use crate::graph::Graph;
use anyhow::{bail, Result};
use farsight_interfaces::message::Message;
use farsight_interfaces::msg::{CommandReason, HealthState, VelocityCommand};
use farsight_interfaces::topics;
use farsight_sim::episode::{Outcome, PoseLog, Summary};
use farsight_sim::sim_robot::{SimOptions, SimRobot};
use farsight_stage::executor::Executor;
use std::collections::BTreeMap;
use std::path::Path;

/// What one driven trial came to.
#[derive(Debug, Clone)]
pub struct Trial {
    pub summary: Summary,
    /// Frames simulated (simulator + graph steps).
    pub frames: u64,
    /// Frames the graph answered with no usable command.
    pub late: u64,
    /// Stage steps run over all nodes.
    pub stage_steps: u64,
    /// Why frames went without a usable command: each stage that was not
    /// healthy then and its reason (numbers as `#`), or that the answer was
    /// for an older frame; counted per frame.
    pub late_reasons: BTreeMap<String, u64>,
    /// Frames the graph answered with a stop of its own (no plan, a stale
    /// input, an e-stop; not the goal reached), by the unhealthy stages'
    /// reasons as in `late_reasons`: a planner with no way on stops the
    /// robot rather than leave the frame unanswered.
    pub stops: u64,
    pub stop_reasons: BTreeMap<String, u64>,
    /// The driven track and where each intervention happened
    /// (`farsight_sim::episode::Episode`).
    pub track: Vec<[f64; 2]>,
    pub intervention_points: Vec<[f64; 2]>,
    /// Where frames went without a usable command (a point at most every
    /// 0.25 m).
    pub no_command_points: Vec<[f64; 2]>,
}

/// The graph's nodes in one executor. Every node must have an in-process
/// build (not a camera driver or the bridge).
pub fn executor(graph: &Graph) -> Result<Executor> {
    let mut ex = Executor::new();
    for node in &graph.nodes {
        ex.add(node.spec.name.clone(), node.build()?);
    }
    Ok(ex)
}

/// Drives `graph` in the simulator described by `options` until the
/// episode ends; with `trace`, writes the robot's pose after every frame
/// there (`poses.csv`, as `farsight-sim run` writes it).
pub fn drive(graph: &Graph, options: &SimOptions, trace: Option<&Path>) -> Result<Trial> {
    let mut ex = executor(graph)?;
    let mut sim = SimRobot::new(options)?;
    if !writes_command(graph) {
        bail!(
            "{}: no node writes {}: nothing would drive the robot",
            graph.path.display(),
            topics::velocity_command().name()
        );
    }
    let mut trace = trace.map(PoseLog::create).transpose()?;
    ex.publish(topics::goal().name(), Message::Goal(sim.goal()));
    let (mut frames, mut late) = (0u64, 0u64);
    let mut late_reasons = BTreeMap::new();
    let (mut stops, mut stop_reasons) = (0u64, BTreeMap::new());
    let mut no_command_points: Vec<[f64; 2]> = Vec::new();
    loop {
        let stamp = sim.next_stamp(None);
        let wanted = |t: &str| ex.is_read(t);
        for (topic, m) in sim.sense(stamp, wanted) {
            ex.publish(&topic, m);
        }
        ex.run(stamp.capture_time_ns);
        // Lock-step, as `farsight-sim run` waits: the first command that
        // answers this frame.
        let answers: Vec<VelocityCommand> = ex
            .take_sent()
            .into_iter()
            .filter(|(t, _)| t == topics::velocity_command().name())
            .filter_map(|(_, m)| VelocityCommand::try_from(m).ok())
            .collect();
        let command = answers
            .iter()
            .find(|c| c.stamp.frame_seq >= stamp.frame_seq)
            .copied();
        frames += 1;
        let here = [sim.episode.robot.x_m, sim.episode.robot.y_m];
        let (fresh, outcome) = sim.drive(command);
        if !fresh {
            late += 1;
            let last = no_command_points.last();
            if last.is_none_or(|p| (p[0] - here[0]).hypot(p[1] - here[1]) >= 0.25) {
                no_command_points.push(here);
            }
            for why in late_why(&ex, command.is_some(), !answers.is_empty()) {
                *late_reasons.entry(why).or_insert(0) += 1;
            }
        } else if command.is_some_and(|c| {
            c.reason != CommandReason::TRACKING && c.reason != CommandReason::GOAL_REACHED
        }) {
            stops += 1;
            for why in unhealthy(&ex) {
                *stop_reasons.entry(why).or_insert(0) += 1;
            }
        }
        if let Some(t) = &mut trace {
            t.record(&sim.episode)?;
        }
        if outcome != Outcome::Driving {
            break;
        }
    }
    if let Some(t) = &mut trace {
        t.flush()?;
    }
    Ok(Trial {
        summary: sim.episode.summary(),
        frames,
        late,
        stage_steps: ex.steps,
        late_reasons,
        stops,
        stop_reasons,
        track: sim.episode.track.clone(),
        intervention_points: sim.episode.intervention_points.clone(),
        no_command_points,
    })
}

/// Why a frame got no usable command: a command that was not finite, one
/// answering an older frame, or else each unhealthy stage's reason, its
/// numbers replaced by `#` so that reasons counting up tally as one.
fn late_why(ex: &Executor, answered: bool, any_command: bool) -> Vec<String> {
    if answered {
        return vec!["a command that is not finite".into()];
    }
    if any_command {
        return vec!["a command answering an older frame".into()];
    }
    let mut out = unhealthy(ex);
    if out.is_empty() {
        out.push("no command, every stage healthy".into());
    }
    out
}

/// Each stage that is not healthy and its reason, its numbers replaced by
/// `#` so that reasons counting up tally as one.
fn unhealthy(ex: &Executor) -> Vec<String> {
    ex.health()
        .filter(|(_, h)| h.state() != HealthState::OK)
        .map(|(instance, h)| {
            let mut why = format!("{instance}: ");
            let mut digits = false;
            for ch in h.report().reason.as_str().chars() {
                let d = ch.is_ascii_digit() || (digits && ch == '.');
                if !(d && digits) {
                    why.push(if d { '#' } else { ch });
                }
                digits = d;
            }
            why
        })
        .collect()
}

fn writes_command(graph: &Graph) -> bool {
    graph
        .topics
        .get(topics::velocity_command().name())
        .is_some_and(|e| e.writers.iter().any(|w| !w.starts_with("external")))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bench_nav::{sim_options, TrialRules};

    /// LRN's head on bins from a segmentation that finds nothing
    /// navigable (an HSV range of a colour the renderer never draws:
    /// saturated magenta), publishing on `{subgoal}`, and the servo
    /// tracking `{track}`.
    const NOTHING_AFFORDABLE: &str = r#"
description = "Test: LRN's head on bins with nothing affordable."

[[node]]
name = "inference"
stage = "inference"
[node.config]
camera = "front"
backend = "hsv"
[[node.config.hsv.ranges]]
hue_deg = [299.0, 301.0]
saturation = [0.99, 1.0]
value = [0.99, 1.0]

[[node]]
name = "bin-projection"
stage = "bin-projection"
[node.config]
method = "lrn"
cameras = ["front"]
[node.config.bins]
input = "navigability"
threshold_on = "bins"

[[node]]
name = "lrn-head"
stage = "subgoal-selection"
[node.config]
method = "lrn"
clock = "stamps"
subgoal_topic = "{subgoal}"

[[node]]
name = "velocity-servoing"
stage = "velocity-servoing"
[node.config]
clock = "stamps"
subgoal_deadline_s = 2.0
track = "{track}"

[[external]]
topic = "camera/front/image"
from = "farsight-sim"

[[external]]
topic = "camera/front/info"
from = "farsight-sim"

[[external]]
topic = "state/pose"
from = "farsight-sim"

[[external]]
topic = "nav/goal"
from = "farsight-sim"

[[external]]
topic = "cmd/velocity"
to = "farsight-sim's base"
"#;

    /// The head guiding D* Lite on the fused near field (the servo on its
    /// path), as `graphs/sim/lrn-dstar.toml`.
    const GUIDED_PLANNER: &str = r#"
[[node]]
name = "costmap-fusion"
stage = "costmap-fusion"
[node.config]
clock = "stamps"
width_cells = 61
height_cells = 61

[[node]]
name = "local-planner"
stage = "subgoal-selection"
[node.config]
method = "dstar_lite"
clock = "stamps"
guide = "nav/subgoal/lrn"
[node.config.planner]
margin_m = 30.0

[[external]]
topic = "costmap/local"
from = "farsight-sim's near-field sensor"
"#;

    #[test]
    fn a_head_with_nothing_affordable_answers_every_frame_with_a_stop_counted_by_its_reason() {
        let dir = std::env::temp_dir().join(format!("farsight-lockstep-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let cases = [
            ("heading-servo", "nav/subgoal", "subgoal", "", None),
            (
                "guided-planner",
                "nav/subgoal/lrn",
                "path",
                GUIDED_PLANNER,
                Some("local-planner: the guide's subgoal is blocked: nothing to plan toward"),
            ),
        ];
        for (name, subgoal, track, planner, planner_why) in cases {
            let path = dir.join(format!("{name}.toml"));
            let text = NOTHING_AFFORDABLE
                .replace("{subgoal}", subgoal)
                .replace("{track}", track)
                + planner;
            std::fs::write(&path, text).unwrap();
            let graph = Graph::load(&path).unwrap();
            let options = sim_options(&graph, "bug-trap", 1, &TrialRules::limited_to(3.0));
            let t = drive(&graph, &options, None).unwrap();
            assert!(t.frames > 10, "{name}: {t:?}");
            // Every frame answered on time (no simulator timeout, no
            // coasting), and every answer a stop the head's reason (and a
            // guided planner's) explains.
            assert_eq!(t.late, 0, "{name}: {:?}", t.late_reasons);
            assert_eq!(t.stops, t.frames, "{name}: {:?}", t.stop_reasons);
            let counted = |why: &str| t.stop_reasons.get(why).copied();
            assert_eq!(
                counted("lrn-head: no affordable observed bin"),
                Some(t.frames),
                "{name}: {:?}",
                t.stop_reasons
            );
            if let Some(why) = planner_why {
                assert_eq!(counted(why), Some(t.frames), "{name}: {:?}", t.stop_reasons);
            }
            assert!(t.summary.distance_m < 1e-6, "{name}: {:?}", t.summary);
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
