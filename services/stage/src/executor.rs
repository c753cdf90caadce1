//! The in-process executor: stage instances ([`Stage`]) composed in one
//! process, passing owned messages by topic name, with no shared memory and
//! no threads. Deterministic: a message published here is delivered to its
//! readers in the order they were added, and the steps it wakes run one at a
//! time, first woken first, until nothing is left to run ([`Executor::run`]).
//! Lock-step simulation and the navigation benchmark run graphs through it;
//! the same stage types run as processes on the process runtime
//! ([`crate::runtime::run_process`]).
//!
//! Time is the caller's: [`Executor::run`] gives each step the simulated
//! time as its wall clock, and [`Executor::tick`] runs the ticks due by then
//! (stages on the wall clock send on ticks; stages on the stamps' clock
//! answer inputs).

use crate::runtime::{Inbox, Outbox, Stage, Step, Wake};
use crate::HealthReport;
use farsight_interfaces::message::Message;
use std::collections::{BTreeMap, VecDeque};

struct Node {
    instance: String,
    stage: Box<dyn Stage>,
    inbox: Inbox,
    out: Outbox,
    health: HealthReport,
    next_tick_ns: Option<u64>,
    queued: bool,
    exited: Option<Result<(), String>>,
}

/// Stage instances in one process.
#[derive(Default)]
pub struct Executor {
    nodes: Vec<Node>,
    /// Topic -> (node, input port) of each reader, in the order added.
    readers: BTreeMap<String, Vec<(usize, usize, bool)>>,
    queue: VecDeque<(usize, Wake)>,
    /// Every message sent, by topic, since the last [`Executor::take_sent`].
    sent: Vec<(String, Message)>,
    /// Steps run, over all nodes.
    pub steps: u64,
}

impl Executor {
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds an instance. Its inputs read from every writer of their topics,
    /// the executor's caller included ([`Executor::publish`]).
    pub fn add(&mut self, instance: impl Into<String>, stage: Box<dyn Stage>) {
        let id = self.nodes.len();
        let ports = stage.ports();
        for (port, input) in ports.inputs.iter().enumerate() {
            self.readers
                .entry(input.topic.clone())
                .or_default()
                .push((id, port, input.wakes));
        }
        let inputs = ports.inputs.len();
        let instance = instance.into();
        self.nodes.push(Node {
            health: HealthReport::new(&instance),
            instance,
            stage,
            inbox: Inbox::new(inputs),
            out: Outbox::default(),
            next_tick_ns: None,
            queued: false,
            exited: None,
        });
    }

    /// The instances' names, in the order added.
    pub fn instances(&self) -> impl Iterator<Item = &str> {
        self.nodes.iter().map(|n| n.instance.as_str())
    }

    /// Whether any instance reads `topic`.
    pub fn is_read(&self, topic: &str) -> bool {
        self.readers.contains_key(topic)
    }

    /// Delivers `msg` on `topic` to every reader; readers for which it is a
    /// waking input are queued to step.
    pub fn publish(&mut self, topic: &str, msg: Message) {
        let Some(readers) = self.readers.get(topic) else {
            return;
        };
        let last = readers.len().saturating_sub(1);
        let mut msg = Some(msg);
        for (i, &(node, port, wakes)) in readers.iter().enumerate() {
            // The last reader takes the message itself; the others a copy.
            let m = if i == last {
                msg.take().expect("taken once")
            } else {
                msg.clone().expect("not yet taken")
            };
            let n = &mut self.nodes[node];
            n.inbox.put(port, m);
            if wakes && !n.queued {
                n.queued = true;
                self.queue.push_back((node, Wake::Input(port)));
            }
        }
    }

    /// Runs queued steps at simulated time `now_ns` until none is left; what
    /// they send is delivered at once (and kept for [`Executor::take_sent`]).
    pub fn run(&mut self, now_ns: u64) {
        while let Some((node, wake)) = self.queue.pop_front() {
            self.nodes[node].queued = false;
            self.step(node, wake, now_ns);
        }
    }

    /// Runs each instance's ticks due by `now_ns` (its first tick comes at
    /// its first call), then what they wake.
    pub fn tick(&mut self, now_ns: u64) {
        for node in 0..self.nodes.len() {
            let Some(period) = self.nodes[node].stage.ports().tick else {
                continue;
            };
            let period_ns = (period.as_nanos() as u64).max(1);
            loop {
                let due = *self.nodes[node].next_tick_ns.get_or_insert(now_ns);
                if due > now_ns {
                    break;
                }
                self.nodes[node].next_tick_ns = Some(due + period_ns);
                self.step(node, Wake::Tick, due);
                self.run(due);
            }
        }
    }

    fn step(&mut self, node: usize, wake: Wake, now_ns: u64) {
        self.steps += 1;
        let n = &mut self.nodes[node];
        let mut step = Step {
            wake,
            wall_ns: now_ns,
            now_ns,
            inbox: &mut n.inbox,
            out: &mut n.out,
            health: &mut n.health,
            exit: None,
        };
        n.stage.step(&mut step);
        if let Some(exit) = step.exit.take() {
            // In one process a stage's end is the run's business: recorded.
            n.exited = Some(exit);
        }
        n.inbox.clear();
        self.deliver(node);
    }

    fn deliver(&mut self, node: usize) {
        let messages = std::mem::take(&mut self.nodes[node].out.messages);
        for (port, msg) in messages {
            let Some(topic) = self.nodes[node]
                .stage
                .ports()
                .outputs
                .get(port)
                .map(|o| o.topic.clone())
            else {
                tracing::error!(
                    instance = %self.nodes[node].instance,
                    "step sent on output {port}, which it did not declare"
                );
                continue;
            };
            self.sent.push((topic.clone(), msg.clone()));
            self.publish(&topic, msg);
        }
    }

    /// Every message the stages sent since the last call, in order.
    pub fn take_sent(&mut self) -> Vec<(String, Message)> {
        std::mem::take(&mut self.sent)
    }

    /// Each instance's last words (a servo's stop), delivered.
    pub fn stop(&mut self) {
        for node in 0..self.nodes.len() {
            let n = &mut self.nodes[node];
            n.stage.stop(&mut n.out);
            self.deliver(node);
        }
    }

    /// The first instance that asked to exit with an error, and why.
    pub fn failed(&self) -> Option<(&str, &str)> {
        self.nodes.iter().find_map(|n| match &n.exited {
            Some(Err(why)) => Some((n.instance.as_str(), why.as_str())),
            _ => None,
        })
    }

    /// Each instance's health report.
    pub fn health(&self) -> impl Iterator<Item = (&str, &HealthReport)> {
        self.nodes.iter().map(|n| (n.instance.as_str(), &n.health))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::runtime::Ports;
    use farsight_interfaces::msg::{Pose, Stamp};

    /// Forwards each pose it reads to its output, one frame later in seq.
    struct Relay {
        ports: Ports,
        seen: Vec<u64>,
    }

    impl Relay {
        fn new(from: &str, to: &str, wakes: bool) -> Self {
            let mut ports = Ports::default();
            if wakes {
                ports.waking_input(from);
            } else {
                ports.input(from);
            }
            ports.output(to);
            Self {
                ports,
                seen: Vec::new(),
            }
        }
    }

    impl Stage for Relay {
        fn ports(&self) -> &Ports {
            &self.ports
        }
        fn step(&mut self, step: &mut Step<'_>) {
            if let Some(mut p) = step.inbox.take::<Pose>(0) {
                self.seen.push(p.stamp.frame_seq);
                p.stamp.frame_seq += 1;
                step.out.send(0, p);
            }
        }
    }

    fn pose(seq: u64) -> Message {
        Message::from(Pose {
            stamp: Stamp {
                frame_seq: seq,
                ..Default::default()
            },
            ..Default::default()
        })
    }

    fn seqs(sent: &[(String, Message)]) -> Vec<(String, u64)> {
        sent.iter()
            .map(|(t, m)| (t.clone(), m.stamp().frame_seq))
            .collect()
    }

    #[test]
    fn a_published_message_runs_the_chain_it_wakes_in_order() {
        let mut ex = Executor::new();
        ex.add("a", Box::new(Relay::new("state/pose", "cmd/a", true)));
        ex.add("b", Box::new(Relay::new("cmd/a", "cmd/b", true)));
        ex.publish("state/pose", pose(1));
        ex.run(0);
        assert_eq!(
            seqs(&ex.take_sent()),
            vec![("cmd/a".into(), 2), ("cmd/b".into(), 3)]
        );
        assert_eq!(ex.steps, 2);
        assert!(ex.take_sent().is_empty(), "taken once");
    }

    #[test]
    fn a_non_waking_input_waits_for_the_next_tick() {
        let mut ex = Executor::new();
        let mut lazy = Relay::new("state/pose", "cmd/a", false);
        lazy.ports.tick = Some(std::time::Duration::from_millis(100));
        ex.add("lazy", Box::new(lazy));
        ex.publish("state/pose", pose(1));
        ex.run(0);
        assert!(ex.take_sent().is_empty(), "nothing woke it");
        ex.tick(0);
        assert_eq!(seqs(&ex.take_sent()), vec![("cmd/a".into(), 2)]);
        // Ticks due at 100, 200 and 300 ms run by 350 ms: three steps.
        let before = ex.steps;
        ex.tick(350_000_000);
        assert_eq!(ex.steps - before, 3);
    }

    #[test]
    fn two_readers_each_get_the_message() {
        let mut ex = Executor::new();
        ex.add("a", Box::new(Relay::new("state/pose", "cmd/a", true)));
        ex.add("b", Box::new(Relay::new("state/pose", "cmd/b", true)));
        ex.publish("state/pose", pose(5));
        ex.run(0);
        assert_eq!(
            seqs(&ex.take_sent()),
            vec![("cmd/a".into(), 6), ("cmd/b".into(), 6)]
        );
        assert!(ex.is_read("state/pose") && !ex.is_read("cmd/b"));
    }
}
