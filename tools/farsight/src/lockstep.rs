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
use farsight_interfaces::msg::VelocityCommand;
use farsight_interfaces::topics;
use farsight_sim::episode::{Outcome, PoseLog, Summary};
use farsight_sim::sim_robot::{SimOptions, SimRobot};
use farsight_stage::executor::Executor;
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
    loop {
        let stamp = sim.next_stamp(None);
        let wanted = |t: &str| ex.is_read(t);
        for (topic, m) in sim.sense(stamp, wanted) {
            ex.publish(&topic, m);
        }
        ex.run(stamp.capture_time_ns);
        // Lock-step, as `farsight-sim run` waits: the first command that
        // answers this frame.
        let command = ex.take_sent().into_iter().find_map(|(t, m)| {
            let c = VelocityCommand::try_from(m).ok()?;
            (t == topics::velocity_command().name() && c.stamp.frame_seq >= stamp.frame_seq)
                .then_some(c)
        });
        frames += 1;
        let (fresh, outcome) = sim.drive(command);
        late += u64::from(!fresh);
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
    })
}

fn writes_command(graph: &Graph) -> bool {
    graph
        .topics
        .get(topics::velocity_command().name())
        .is_some_and(|e| e.writers.iter().any(|w| !w.starts_with("external")))
}
