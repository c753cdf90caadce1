//! The stage runtime: a stage is a library type ([`Stage`]) whose step takes
//! plain inputs ([`Inbox`]) and gives plain outputs ([`Outbox`]); whoever
//! runs it owns the loop. [`run_process`] runs one stage as a process on
//! iceoryx2 (the binaries' `main`); the in-process executor
//! (`farsight_stage::executor`) runs many in one process, in lock-step.
//!
//! What the process runtime owns, so no stage writes it again: arguments,
//! logging, config loading and validation, the bus and one port per declared
//! topic, the wait loop (inputs that wake the step, a tick), the health
//! report and systemd's watchdog and notify protocol, and the clean stop on
//! SIGTERM/SIGINT (the stage's last words, then a `stopping` report). A
//! SIGSTOP/SIGCONT freeze is not a stop: the loop waits on.

use crate::{announce_ready, init_tracing, load_config, Health, HealthReport, StageArgs, Validate};
use farsight_interfaces::clock::{Clock, WallClock};
use farsight_interfaces::message::Message;
use farsight_interfaces::transport::any::{AnyPublisher, AnySubscriber};
use farsight_interfaces::transport::ipc::{self, Bus};
use serde::de::DeserializeOwned;
use std::cell::RefCell;
use std::ops::ControlFlow;
use std::path::PathBuf;
use std::rc::Rc;
use std::time::Duration;

/// One input of a stage: a topic, and whether a message on it runs the step
/// at once (otherwise it waits in the inbox for the next step).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct InputPort {
    pub topic: String,
    pub wakes: bool,
}

/// One output: a topic, and for header+slice topics (images, maps) the most
/// bytes one message may carry (its shared memory is allocated up front).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OutputPort {
    pub topic: String,
    pub max_slice_bytes: usize,
}

/// A stage's ports: its inputs and outputs by index, its tick, and how often
/// its health goes out.
#[derive(Debug, Clone, PartialEq)]
pub struct Ports {
    pub inputs: Vec<InputPort>,
    pub outputs: Vec<OutputPort>,
    /// The step also runs this often with [`Wake::Tick`].
    pub tick: Option<Duration>,
    pub health_rate_hz: f64,
}

impl Default for Ports {
    fn default() -> Self {
        Self {
            inputs: Vec::new(),
            outputs: Vec::new(),
            tick: None,
            health_rate_hz: 1.0,
        }
    }
}

impl Ports {
    /// An input whose messages wake the step; returns its index.
    pub fn waking_input(&mut self, topic: impl Into<String>) -> usize {
        self.push_input(topic.into(), true)
    }

    /// An input read at the next step; returns its index.
    pub fn input(&mut self, topic: impl Into<String>) -> usize {
        self.push_input(topic.into(), false)
    }

    fn push_input(&mut self, topic: String, wakes: bool) -> usize {
        self.inputs.push(InputPort { topic, wakes });
        self.inputs.len() - 1
    }

    /// An output of fixed-size messages; returns its index.
    pub fn output(&mut self, topic: impl Into<String>) -> usize {
        self.slice_output(topic, 0)
    }

    /// An output of header+slice messages of at most `max_slice_bytes`.
    pub fn slice_output(&mut self, topic: impl Into<String>, max_slice_bytes: usize) -> usize {
        self.outputs.push(OutputPort {
            topic: topic.into(),
            max_slice_bytes,
        });
        self.outputs.len() - 1
    }

    /// The index of the input on `topic`, if there is one.
    pub fn input_index(&self, topic: &str) -> Option<usize> {
        self.inputs.iter().position(|p| p.topic == topic)
    }

    /// The order a process reads its inputs in each step: the waking ones
    /// first, then the rest. What does not wake a stage (the pose, a camera
    /// model) is published before what does: the simulator sends a frame's
    /// pose before its costmap and image, and a stage sends only after it
    /// has read. Read after the waking message, such an input is of that
    /// message's frame or newer. Read before it, a frame published between
    /// the two reads paired its costmap with the previous frame's pose: a
    /// map stamped one frame old, which a lock-step simulator never takes
    /// for an answer (on a busy machine, 1 of 32 bug-trap demos waited out
    /// its 60 s command timeout that way, and its track parted from the
    /// others).
    pub fn read_order(&self) -> Vec<usize> {
        let (waking, rest): (Vec<usize>, Vec<usize>) =
            (0..self.inputs.len()).partition(|&i| self.inputs[i].wakes);
        waking.into_iter().chain(rest).collect()
    }
}

/// Why the step runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Wake {
    /// A message arrived on waking input `i`.
    Input(usize),
    /// The tick period passed.
    Tick,
}

/// The newest message on each input since the last step. Latest-value: a
/// message not taken before a newer one arrives is replaced (and counted).
#[derive(Debug, Default)]
pub struct Inbox {
    slots: Vec<Option<Message>>,
    /// Messages replaced before they were taken.
    pub replaced: u64,
}

impl Inbox {
    pub fn new(inputs: usize) -> Self {
        Self {
            slots: (0..inputs).map(|_| None).collect(),
            replaced: 0,
        }
    }

    /// Delivers `msg` on input `port`.
    pub fn put(&mut self, port: usize, msg: Message) {
        if let Some(slot) = self.slots.get_mut(port) {
            self.replaced += u64::from(slot.replace(msg).is_some());
        }
    }

    /// Takes input `port`'s message if it is a `T`. A message of another
    /// kind cannot arrive on a port (the topic's name fixes its kind); it
    /// is left where it is.
    pub fn take<T: TryFrom<Message, Error = Message>>(&mut self, port: usize) -> Option<T> {
        let slot = self.slots.get_mut(port)?;
        match T::try_from(slot.take()?) {
            Ok(m) => Some(m),
            Err(m) => {
                *slot = Some(m);
                None
            }
        }
    }

    /// Takes input `port`'s message, whatever its kind.
    pub fn take_any(&mut self, port: usize) -> Option<Message> {
        self.slots.get_mut(port)?.take()
    }

    /// Whether input `port` holds a message.
    pub fn has(&self, port: usize) -> bool {
        self.slots.get(port).is_some_and(Option::is_some)
    }

    /// Drops what the step left untaken (it had its chance).
    pub fn clear(&mut self) {
        self.slots.iter_mut().for_each(|s| *s = None);
    }
}

/// What a step sends: (output index, message), in order. They go out
/// after the step, or when the step calls [`Outbox::flush`].
#[derive(Default)]
pub struct Outbox {
    pub messages: Vec<(usize, Message)>,
    sink: Option<Box<dyn Sink>>,
    failures: Vec<String>,
}

/// Where an [`Outbox`] with a sink publishes: the process runtime's ports.
pub trait Sink {
    /// Publishes `msg` on output `port`; an error names the topic.
    fn publish(&mut self, port: usize, msg: Message) -> Result<(), String>;
}

impl std::fmt::Debug for Outbox {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Outbox")
            .field("messages", &self.messages)
            .field("sink", &self.sink.is_some())
            .field("failures", &self.failures)
            .finish()
    }
}

impl Outbox {
    /// An outbox whose [`Outbox::flush`] publishes through `sink`.
    pub fn with_sink(sink: Box<dyn Sink>) -> Self {
        Self {
            sink: Some(sink),
            ..Self::default()
        }
    }

    pub fn send(&mut self, port: usize, msg: impl Into<Message>) {
        self.messages.push((port, msg.into()));
    }

    /// Publishes what was sent so far now, in order, without waiting for
    /// the step to end: a stage whose first output is on the latency path
    /// (fusion's fused map) flushes it before building outputs nobody
    /// waits on. Without a sink (the in-process executor) the messages
    /// stay queued and go out after the step, in the same order, so a
    /// flush never changes what is sent; the test harness keeps what was
    /// flushed ([`Harness::flushed_mid_step`]) and returns everything in
    /// order after the step.
    pub fn flush(&mut self) {
        let Some(sink) = self.sink.as_mut() else {
            return;
        };
        for (port, msg) in self.messages.drain(..) {
            if let Err(e) = sink.publish(port, msg) {
                self.failures.push(e);
            }
        }
    }

    /// Why messages could not be published since the last call.
    pub fn take_failures(&mut self) -> Vec<String> {
        std::mem::take(&mut self.failures)
    }
}

/// The process runtime's sink: one iceoryx2 publisher per output port.
struct Publishers {
    topics: Vec<String>,
    publishers: Vec<AnyPublisher>,
}

impl Sink for Publishers {
    fn publish(&mut self, port: usize, msg: Message) -> Result<(), String> {
        let Some(p) = self.publishers.get_mut(port) else {
            // A stage's bug, not a bad input: logged, not counted as a drop.
            tracing::error!("step sent on output {port}, which it did not declare");
            return Ok(());
        };
        p.publish_message(msg)
            .map_err(|e| format!("{}: {e}", self.topics[port]))
    }
}

/// One step's world: why it runs, the time, its inputs, its outputs and its
/// health.
pub struct Step<'a> {
    pub wake: Wake,
    /// The wall clock in a process; the simulated clock in the executor.
    pub wall_ns: u64,
    /// The time the health report is judged at: `wall_ns` unless the stage
    /// runs on its inputs' stamps and says so.
    pub now_ns: u64,
    pub inbox: &'a mut Inbox,
    pub out: &'a mut Outbox,
    pub health: &'a mut HealthReport,
    /// Set by a stage whose work is over (a played recording, a source
    /// that failed): after this step's outputs go out, the runtime stops it
    /// cleanly and exits 0 (`Ok`) or 1 naming the reason (`Err`).
    pub exit: Option<Result<(), String>>,
}

/// A stage as a library type: ports, and a step over plain data. Object
/// safe, so an executor can hold stages of every kind.
pub trait Stage {
    fn ports(&self) -> &Ports;
    fn step(&mut self, step: &mut Step<'_>);
    /// Last words before a clean stop (the servo leaves the robot stopped).
    fn stop(&mut self, _out: &mut Outbox) {}
}

/// Where an instance runs: its name in the graph and the folder its
/// config's relative paths resolve against.
#[derive(Debug, Clone)]
pub struct StageEnv {
    pub instance: String,
    pub config_dir: PathBuf,
}

/// A stage kind: its name (the binary is `farsight-<KIND>`), its config, and
/// how an instance is built from them.
pub trait StageKind: Stage + Sized {
    const KIND: &'static str;
    type Config: DeserializeOwned + Validate + Default;
    fn new(config: Self::Config, env: &StageEnv) -> anyhow::Result<Self>;
}

/// A stage binary's whole `main`.
pub fn main<S: StageKind>() {
    crate::run_main(S::KIND, run_process::<S>);
}

/// Runs stage `S` as this process: arguments, config, ports on iceoryx2,
/// the wait loop, health and watchdog, clean stop.
pub fn run_process<S: StageKind>() -> anyhow::Result<()> {
    let args = StageArgs::parse(S::KIND)?;
    init_tracing(args.log_format);
    let config: S::Config = load_config(args.config.as_deref())?;
    let env = StageEnv {
        instance: args.instance.clone(),
        config_dir: args.config_dir(),
    };
    let mut stage = S::new(config, &env)?;
    let ports = stage.ports().clone();
    let bus = Bus::open(&env.instance)?;
    let subscribers = ports
        .inputs
        .iter()
        .map(|p| AnySubscriber::open(&bus, &p.topic))
        .collect::<Result<Vec<_>, _>>()?;
    let publishers = ports
        .outputs
        .iter()
        .map(|p| AnyPublisher::open(&bus, &p.topic, p.max_slice_bytes))
        .collect::<Result<Vec<_>, _>>()?;
    let mut out = Outbox::with_sink(Box::new(Publishers {
        topics: ports.outputs.iter().map(|p| p.topic.clone()).collect(),
        publishers,
    }));
    let mut health = Health::new(&bus, &env.instance, ports.health_rate_hz)?;
    announce_ready(&env.instance);

    let waking: Vec<usize> = (0..ports.inputs.len())
        .filter(|&i| ports.inputs[i].wakes)
        .collect();
    let listeners: Vec<_> = waking.iter().map(|&i| subscribers[i].listener()).collect();
    let read_order = ports.read_order();
    let mut inbox = Inbox::new(ports.inputs.len());
    let mut exit = None;
    ipc::wait_loop(&listeners, ports.tick, |wake| {
        let wake = match wake {
            ipc::Wake::Input(k) => Wake::Input(waking[k]),
            ipc::Wake::Tick => Wake::Tick,
        };
        for &i in &read_order {
            match subscribers[i].take_message() {
                Ok(Some(m)) => inbox.put(i, m),
                Ok(None) => {}
                Err(e) => health.dropped(&e),
            }
        }
        let wall_ns = WallClock.now_ns();
        let mut step = Step {
            wake,
            wall_ns,
            now_ns: wall_ns,
            inbox: &mut inbox,
            out: &mut out,
            health: &mut health,
            exit: None,
        };
        stage.step(&mut step);
        let (now_ns, step_exit) = (step.now_ns, step.exit.take());
        inbox.clear();
        publish(&mut out, &mut health);
        let skipped = subscribers.iter().map(|s| s.skips().skipped).sum();
        health.set_skipped(skipped);
        health.tick(now_ns);
        match step_exit {
            Some(e) => {
                exit = Some(e);
                ControlFlow::Break(())
            }
            None => ControlFlow::Continue(()),
        }
    })?;
    stage.stop(&mut out);
    publish(&mut out, &mut health);
    health.stopping(WallClock.now_ns());
    match exit {
        Some(Err(why)) => Err(anyhow::anyhow!(why)),
        _ => Ok(()),
    }
}

/// Publishes what the step left queued, and counts what could not go out.
fn publish(out: &mut Outbox, health: &mut Health) {
    out.flush();
    for why in out.take_failures() {
        health.dropped(&why);
    }
}

/// Checks a stage's ports against what its config declares to the graph
/// ([`crate::DeclaresTopics`]): every declared read is an input, and the
/// outputs are exactly the declared writes (besides `health/<instance>`,
/// which the runtime writes: a declared health topic may have no output,
/// and a stage may also write its own, such as one per camera). An input the
/// declaration leaves out is allowed: a topic the stage listens to but does
/// not need in this config.
pub fn check_ports(io: &crate::Io, ports: &Ports) -> Result<(), String> {
    for r in &io.reads {
        if ports.input_index(&r.topic).is_none() {
            return Err(format!(
                "declares a read of `{}`, but has no such input",
                r.topic
            ));
        }
    }
    let outputs: Vec<&str> = ports.outputs.iter().map(|o| o.topic.as_str()).collect();
    for t in &outputs {
        if !io.writes.iter().any(|w| w == t) {
            return Err(format!("writes `{t}`, which its config does not declare"));
        }
    }
    for t in io.writes.iter().filter(|t| !t.starts_with("health/")) {
        if !outputs.contains(&t.as_str()) {
            return Err(format!("declares a write of `{t}`, but has no such output"));
        }
    }
    Ok(())
}

/// Runs a stage's steps by hand, addressing ports by topic name: how a
/// stage's unit tests drive its rules without a bus.
pub struct Harness<S: Stage> {
    pub stage: S,
    pub health: HealthReport,
    /// What the last step asked of [`Step::exit`].
    pub exit: Option<Result<(), String>>,
    /// The topics the last step published before it ended
    /// ([`Outbox::flush`]), in order.
    pub flushed_mid_step: Vec<String>,
    inbox: Inbox,
    out: Outbox,
    flushed: Rc<RefCell<Vec<(usize, Message)>>>,
}

/// The harness's sink: keeps what a step flushes, to hand back in order.
struct Kept(Rc<RefCell<Vec<(usize, Message)>>>);

impl Sink for Kept {
    fn publish(&mut self, port: usize, msg: Message) -> Result<(), String> {
        self.0.borrow_mut().push((port, msg));
        Ok(())
    }
}

impl<S: Stage> Harness<S> {
    pub fn new(stage: S) -> Self {
        let inputs = stage.ports().inputs.len();
        let flushed = Rc::new(RefCell::new(Vec::new()));
        Self {
            stage,
            health: HealthReport::new("test"),
            exit: None,
            flushed_mid_step: Vec::new(),
            inbox: Inbox::new(inputs),
            out: Outbox::with_sink(Box::new(Kept(flushed.clone()))),
            flushed,
        }
    }

    fn input(&self, topic: &str) -> usize {
        self.stage.ports().input_index(topic).unwrap_or_else(|| {
            panic!(
                "the stage has no input {topic:?}; it has {:?}",
                self.stage.ports().inputs
            )
        })
    }

    /// Delivers `msg` on the input `topic` for the next step.
    pub fn put(&mut self, topic: &str, msg: impl Into<Message>) -> &mut Self {
        let i = self.input(topic);
        self.inbox.put(i, msg.into());
        self
    }

    /// The wake of a message arriving on `topic`.
    pub fn wake_on(&self, topic: &str) -> Wake {
        Wake::Input(self.input(topic))
    }

    /// Runs one step; returns what it sent, by topic.
    pub fn step(&mut self, wake: Wake, wall_ns: u64) -> Vec<(String, Message)> {
        let mut step = Step {
            wake,
            wall_ns,
            now_ns: wall_ns,
            inbox: &mut self.inbox,
            out: &mut self.out,
            health: &mut self.health,
            exit: None,
        };
        self.stage.step(&mut step);
        self.exit = step.exit.take();
        self.inbox.clear();
        let outputs = &self.stage.ports().outputs;
        self.flushed_mid_step = (self.flushed.borrow().iter())
            .map(|(i, _)| outputs[*i].topic.clone())
            .collect();
        self.drain()
    }

    /// The stage's last words.
    pub fn stop(&mut self) -> Vec<(String, Message)> {
        self.stage.stop(&mut self.out);
        self.drain()
    }

    /// Everything sent, flushed or not, in the order sent.
    fn drain(&mut self) -> Vec<(String, Message)> {
        let outputs = &self.stage.ports().outputs;
        let flushed = std::mem::take(&mut *self.flushed.borrow_mut());
        flushed
            .into_iter()
            .chain(self.out.messages.drain(..))
            .map(|(i, m)| (outputs[i].topic.clone(), m))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use farsight_interfaces::msg::{NavGoal, Pose, Stamp};

    #[test]
    fn inbox_keeps_the_newest_and_counts_what_it_replaced() {
        let mut inbox = Inbox::new(2);
        let pose = |seq| {
            Message::from(Pose {
                stamp: farsight_interfaces::msg::Stamp {
                    frame_seq: seq,
                    ..Default::default()
                },
                ..Default::default()
            })
        };
        inbox.put(0, pose(1));
        inbox.put(0, pose(2));
        inbox.put(5, pose(3)); // no such input: ignored
        assert_eq!(inbox.replaced, 1);
        assert!(inbox.take::<NavGoal>(0).is_none(), "not a goal");
        assert!(inbox.has(0), "a wrong-typed take leaves the message");
        assert_eq!(inbox.take::<Pose>(0).map(|p| p.stamp.frame_seq), Some(2));
        assert!(!inbox.has(0));
        inbox.put(1, pose(4));
        inbox.clear();
        assert!(!inbox.has(1));
    }

    #[test]
    fn a_flush_publishes_what_was_sent_so_far_in_order_and_keeps_the_rest() {
        struct Log(Rc<RefCell<Vec<(usize, u64)>>>);
        impl Sink for Log {
            fn publish(&mut self, port: usize, msg: Message) -> Result<(), String> {
                let Message::Pose(p) = msg else {
                    return Err(format!("output {port}: not a pose"));
                };
                self.0.borrow_mut().push((port, p.stamp.frame_seq));
                Ok(())
            }
        }
        let pose = |seq| {
            Message::Pose(Pose {
                stamp: Stamp {
                    frame_seq: seq,
                    ..Default::default()
                },
                ..Default::default()
            })
        };
        let log = Rc::new(RefCell::new(Vec::new()));
        let mut out = Outbox::with_sink(Box::new(Log(log.clone())));
        out.send(1, pose(1));
        out.send(0, pose(2));
        out.flush();
        assert_eq!(*log.borrow(), [(1, 1), (0, 2)]);
        assert!(out.messages.is_empty());
        out.send(0, pose(3));
        assert_eq!(log.borrow().len(), 2, "nothing goes out before a flush");
        out.send(2, Message::Goal(NavGoal::default()));
        out.flush();
        assert_eq!(*log.borrow(), [(1, 1), (0, 2), (0, 3)]);
        assert_eq!(out.take_failures(), ["output 2: not a pose"]);
        assert!(out.take_failures().is_empty());

        // Without a sink a flush keeps every message for after the step.
        let mut queued = Outbox::default();
        queued.send(0, pose(4));
        queued.flush();
        assert_eq!(queued.messages.len(), 1);
    }

    #[test]
    fn ports_are_numbered_in_declaration_order() {
        let mut p = Ports::default();
        assert_eq!(p.waking_input("nav/subgoal"), 0);
        assert_eq!(p.input("state/pose"), 1);
        assert_eq!(p.output("cmd/velocity"), 0);
        assert_eq!(p.slice_output("camera/front/image", 1 << 20), 1);
        assert_eq!(p.input_index("state/pose"), Some(1));
        assert!(p.inputs[0].wakes && !p.inputs[1].wakes);
    }

    #[test]
    fn a_process_reads_what_wakes_it_before_the_pose_it_pairs_with() {
        let mut p = Ports::default();
        p.input("state/pose");
        p.waking_input("costmap/local");
        p.input("nav/goal");
        p.waking_input("bins/polar");
        assert_eq!(p.read_order(), [1, 3, 0, 2]);
        assert!(Ports::default().read_order().is_empty());
    }
}
