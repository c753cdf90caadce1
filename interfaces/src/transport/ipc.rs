//! Zero-copy transport on the vehicle over iceoryx2 shared memory.
//!
//! Every topic is a publish-subscribe service paired with an event service of
//! the same name: `publish` writes the message into shared memory once and
//! notifies, and a stage sleeps on a WaitSet ([`wait_loop`]) until one of its
//! inputs has news or its tick interval passes. Subscribers have latest-value
//! semantics (buffer of one, safe overflow), read samples in place, and count
//! what they skipped.
//!
//! Queues: a consumer that must not lose messages (the recorder) reads a
//! topic's *queue* instead: a second service per topic, declared in
//! `FARSIGHT_QUEUES` (`topic=depth,...`, written by `farsight run` from the
//! graph's queued edges), with [`QUEUE_SUBSCRIBERS`] slots of `depth`
//! samples each, which every publisher of the topic also sends to. A deep
//! buffer on the topic's own service would cost every one of its
//! [`MAX_SUBSCRIBERS`] slots that depth in shared memory
//! ([`segment_samples`]): 12 slots at depth 32 of a 2.7 MB camera frame are
//! about 1.1 GB, the queue's two slots 0.2 GB.
//!
//! Restarts: a SIGKILLed process leaves its node behind; [`Bus::open`] and
//! [`Bus::cleanup_dead_nodes`] remove dead nodes so a restarted stage can
//! reconnect, and port creation retries once after a clean-up when a service
//! is full of dead ports. Test isolation: [`IpcSettings::prefix`] (env
//! `FARSIGHT_IPC_PREFIX`) gives every test its own namespace.
//!
//! ```no_run
//! use farsight_interfaces::{msg::*, topics, transport::ipc::Bus};
//!
//! let bus = Bus::open("example")?;
//! let publisher = bus.publisher(&topics::velocity_command())?;
//! let subscriber = bus.subscriber(&topics::velocity_command())?;
//! publisher.publish(&VelocityCommand::stop(Stamp::new(1, 0), CommandReason::ESTOP))?;
//! if let Some(cmd) = subscriber.latest()? {
//!     assert_eq!(cmd.linear_mps, 0.0);
//! }
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use super::{SkipCounter, Stamped, TransportError};
use crate::topics::{Slice, Topic};
use core::cell::Cell;
use core::fmt::Debug;
use core::ops::ControlFlow;
use core::time::Duration;
use iceoryx2::node::Node;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher as IoxPublisher;
use iceoryx2::port::subscriber::Subscriber as IoxSubscriber;
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample;
use iceoryx2::waitset::WaitSetRunResult;

/// Publishers per topic: one live one plus room for a restarted one whose
/// predecessor has not been cleaned up yet.
pub const MAX_PUBLISHERS: usize = 4;
/// Subscribers per topic: the stages of the graph plus bridge, recorder and tools.
pub const MAX_SUBSCRIBERS: usize = 12;
/// Nodes per topic (live and not yet cleaned dead ones).
pub const MAX_NODES: usize = 32;
/// Samples a subscriber may hold at once: the one being processed and the
/// newer one found while draining.
const MAX_BORROWED: usize = 2;
/// Samples a publisher may loan at once (iceoryx2's default).
const MAX_LOANED: usize = 2;
/// Subscriber slots of a topic's queue: the recorder, and room for a
/// restarted one whose predecessor has not been cleaned up yet.
pub const QUEUE_SUBSCRIBERS: usize = 2;
/// The deepest queue a topic may declare.
pub const MAX_QUEUE_DEPTH: usize = 1024;
/// The environment variable that declares the queued topics.
pub const QUEUES_ENV: &str = "FARSIGHT_QUEUES";

/// Samples in one publisher's shared-memory data segment, as iceoryx2 0.10
/// sizes it (`required_amount_of_samples_per_data_segment`).
pub const fn segment_samples(max_subscribers: usize, buffer: usize, history: usize) -> usize {
    max_subscribers * (buffer + MAX_BORROWED) + history + MAX_LOANED
}

/// Shared memory one publisher of a topic maps for messages of
/// `sample_bytes`: its latest-value service and, with `queue_depth`, its
/// queue.
pub const fn publisher_shm_bytes(sample_bytes: usize, queue_depth: Option<usize>) -> usize {
    let base = segment_samples(MAX_SUBSCRIBERS, 1, 1);
    let queue = match queue_depth {
        // History 1: a reader that joins late still gets a rare topic's
        // last message (the goal).
        Some(d) => segment_samples(QUEUE_SUBSCRIBERS, d, 1),
        None => 0,
    };
    (base + queue) * sample_bytes
}

/// Parses a queue declaration, `topic=depth,topic=depth` (the value of
/// [`QUEUES_ENV`]); a bad entry is refused, naming it.
pub fn parse_queues(
    spec: &str,
) -> Result<std::collections::BTreeMap<String, usize>, TransportError> {
    let mut queues = std::collections::BTreeMap::new();
    for entry in spec.split(',').map(str::trim).filter(|e| !e.is_empty()) {
        let bad = || TransportError::Setting {
            key: QUEUES_ENV,
            value: entry.to_string(),
            expected: "topic=depth, a farsight topic and a depth of 1 to 1024",
        };
        let (topic, depth) = entry.split_once('=').ok_or_else(bad)?;
        let depth: usize = depth.trim().parse().map_err(|_| bad())?;
        let topic = topic.trim();
        if crate::topics::kind_of(topic).is_none() || !(1..=MAX_QUEUE_DEPTH).contains(&depth) {
            return Err(bad());
        }
        queues.insert(topic.to_string(), depth);
    }
    Ok(queues)
}

/// The event listener of a subscriber, to attach to [`wait_loop`].
pub type InputListener = Listener<ipc::Service>;

/// Where the iceoryx2 resources of this process live.
#[derive(Debug, Clone, Default)]
pub struct IpcSettings {
    /// Prefix of every shared-memory resource; processes only see each other with
    /// the same prefix. Default: iceoryx2's (`iox2_`).
    pub prefix: Option<String>,
    /// Root directory of iceoryx2's management files (default `/tmp/iceoryx2`;
    /// the systemd deployment moves it under `/run`).
    pub root: Option<String>,
    /// The queued topics and their depths, `topic=depth,...` (see the
    /// module docs; env `FARSIGHT_QUEUES`).
    pub queues: Option<String>,
}

impl IpcSettings {
    /// Reads `FARSIGHT_IPC_PREFIX` and `FARSIGHT_IPC_ROOT`.
    pub fn from_env() -> Self {
        Self {
            prefix: std::env::var("FARSIGHT_IPC_PREFIX")
                .ok()
                .filter(|s| !s.is_empty()),
            root: std::env::var("FARSIGHT_IPC_ROOT")
                .ok()
                .filter(|s| !s.is_empty()),
            queues: std::env::var(QUEUES_ENV).ok().filter(|s| !s.is_empty()),
        }
    }

    fn config(&self) -> Result<Config, TransportError> {
        let mut config = Config::global_config().clone();
        if let Some(prefix) = &self.prefix {
            config.global.prefix =
                FileName::new(prefix.as_bytes()).map_err(|_| TransportError::Setting {
                    key: "FARSIGHT_IPC_PREFIX",
                    value: prefix.clone(),
                    expected: "a short file name: letters, digits, '_', '-', '.'",
                })?;
        }
        if let Some(root) = &self.root {
            let path = iceoryx2::prelude::Path::new(root.as_bytes()).map_err(|_| {
                TransportError::Setting {
                    key: "FARSIGHT_IPC_ROOT",
                    value: root.clone(),
                    expected: "an absolute directory path",
                }
            })?;
            config.global.set_root_path(&path);
        }
        Ok(config)
    }
}

/// A process's connection to the vehicle bus (one iceoryx2 node).
pub struct Bus {
    node: Node<ipc::Service>,
    name: String,
    queues: std::collections::BTreeMap<String, usize>,
}

fn ipc_err(what: &'static str, topic: &str, e: impl Debug) -> TransportError {
    TransportError::Ipc {
        what,
        topic: topic.to_string(),
        detail: format!("{e:?}"),
    }
}

impl Bus {
    /// Opens the bus with settings from the environment.
    pub fn open(node_name: &str) -> Result<Self, TransportError> {
        Self::open_with(node_name, &IpcSettings::from_env())
    }

    /// Opens the bus, removing what dead processes left behind first.
    pub fn open_with(node_name: &str, settings: &IpcSettings) -> Result<Self, TransportError> {
        // iceoryx2 logs to the console; by default only its errors (IOX2_LOG_LEVEL overrides).
        set_log_level_from_env_or(LogLevel::Error);
        let config = settings.config()?;
        let queues = parse_queues(settings.queues.as_deref().unwrap_or(""))?;
        let name = NodeName::new(node_name).map_err(|e| ipc_err("node name", node_name, e))?;
        let node = NodeBuilder::new()
            .name(&name)
            .config(&config)
            // The stage decides what to do on SIGTERM/SIGINT (wait_loop reports it).
            .signal_handling_mode(SignalHandlingMode::HandleTerminationRequests)
            .create::<ipc::Service>()
            .map_err(|e| ipc_err("node creation", node_name, e))?;
        let bus = Self {
            node,
            name: node_name.to_string(),
            queues,
        };
        watch_termination_signals(&bus.node);
        let removed = bus.cleanup_dead_nodes();
        if removed > 0 {
            tracing::info!(removed, "cleaned up dead iceoryx2 nodes");
        }
        Ok(bus)
    }

    pub fn node(&self) -> &Node<ipc::Service> {
        &self.node
    }

    /// Whether SIGTERM or SIGINT has arrived, for loops that do not sleep
    /// in [`wait_loop`]. A wait cut short for another reason (SIGCONT after
    /// a freeze) is not a request to stop.
    pub fn termination_requested(&self) -> bool {
        termination_requested()
            || matches!(
                self.node.wait(Duration::ZERO),
                Err(iceoryx2::node::NodeWaitFailure::TerminationRequest)
            )
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    /// The depth of `topic`'s queue, if one is declared.
    pub fn queue_depth(&self, topic: &str) -> Option<usize> {
        self.queues.get(topic).copied()
    }

    fn declared_queue(&self, topic: &str) -> Result<usize, TransportError> {
        self.queue_depth(topic)
            .ok_or_else(|| TransportError::Setting {
                key: QUEUES_ENV,
                value: topic.to_string(),
                expected: "a topic with a declared queue (a queued edge of the graph)",
            })
    }

    /// The service of `topic`'s queue: outside the farsight root, so
    /// [`Bus::topics`] does not list it as a topic.
    fn queue_service_name(topic: &str) -> Result<ServiceName, TransportError> {
        let full = format!("{}-queue/{topic}", crate::topics::ROOT);
        ServiceName::new(&full).map_err(|e| ipc_err("service name", topic, e))
    }

    fn fixed_queue_service<M: IpcMessage>(
        &self,
        topic: &str,
        depth: usize,
    ) -> Result<
        iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, M, ()>,
        TransportError,
    > {
        let name = Self::queue_service_name(topic)?;
        self.with_cleanup_retry("queue service", topic, || {
            self.node
                .service_builder(&name)
                .publish_subscribe::<M>()
                .enable_safe_overflow(true)
                .subscriber_max_buffer_size(depth)
                .history_size(1)
                .subscriber_max_borrowed_samples(MAX_BORROWED)
                .max_publishers(MAX_PUBLISHERS)
                .max_subscribers(QUEUE_SUBSCRIBERS)
                .max_nodes(MAX_NODES)
                .open_or_create()
        })
    }

    /// [`Bus::fixed_queue_service`] for header + slice topics (iceoryx2's
    /// builder takes the slice and its header as other type parameters).
    fn slice_queue_service<H: IpcHeader, E: IpcElem>(
        &self,
        topic: &str,
        depth: usize,
    ) -> Result<
        iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, [E], H>,
        TransportError,
    > {
        let name = Self::queue_service_name(topic)?;
        self.with_cleanup_retry("queue service", topic, || {
            self.node
                .service_builder(&name)
                .publish_subscribe::<[E]>()
                .user_header::<H>()
                .enable_safe_overflow(true)
                .subscriber_max_buffer_size(depth)
                .history_size(1)
                .subscriber_max_borrowed_samples(MAX_BORROWED)
                .max_publishers(MAX_PUBLISHERS)
                .max_subscribers(QUEUE_SUBSCRIBERS)
                .max_nodes(MAX_NODES)
                .open_or_create()
        })
    }

    fn queue_notifier(&self, topic: &str) -> Result<Notifier<ipc::Service>, TransportError> {
        let events = self.event_ports(topic, &Self::queue_service_name(topic)?)?;
        self.with_cleanup_retry("queue notifier", topic, || {
            events.notifier_builder().create()
        })
    }

    fn queue_listener(&self, topic: &str) -> Result<Listener<ipc::Service>, TransportError> {
        let events = self.event_ports(topic, &Self::queue_service_name(topic)?)?;
        self.with_cleanup_retry("queue listener", topic, || {
            events.listener_builder().create()
        })
    }

    /// A subscriber of `topic`'s queue: every message its publishers send,
    /// in order, up to the declared depth behind (then the oldest is lost,
    /// and counted from the frame numbers). Refused for a topic without a
    /// declared queue.
    pub fn queue_subscriber<M: IpcMessage>(
        &self,
        topic: &Topic<M>,
    ) -> Result<Subscriber<M>, TransportError> {
        let depth = self.declared_queue(topic.name())?;
        let service = self.fixed_queue_service::<M>(topic.name(), depth)?;
        let port = self.with_cleanup_retry("queue subscriber", topic.name(), || {
            service.subscriber_builder().buffer_size(depth).create()
        })?;
        Ok(Subscriber {
            port,
            listener: self.queue_listener(topic.name())?,
            topic: topic.name().to_string(),
            skips: Cell::new(SkipCounter::default()),
        })
    }

    /// [`Bus::queue_subscriber`] for header + slice topics.
    pub fn queue_slice_subscriber<H: IpcHeader, E: IpcElem>(
        &self,
        topic: &Topic<Slice<H, E>>,
    ) -> Result<SliceSubscriber<H, E>, TransportError> {
        let depth = self.declared_queue(topic.name())?;
        let service = self.slice_queue_service::<H, E>(topic.name(), depth)?;
        let port = self.with_cleanup_retry("queue subscriber", topic.name(), || {
            service.subscriber_builder().buffer_size(depth).create()
        })?;
        Ok(SliceSubscriber {
            port,
            listener: self.queue_listener(topic.name())?,
            topic: topic.name().to_string(),
            skips: Cell::new(SkipCounter::default()),
        })
    }

    /// The farsight topics that exist on this bus now (publish-subscribe
    /// services under the farsight root), sorted: what a recorder's glob
    /// patterns are matched against.
    pub fn topics(&self) -> Result<Vec<String>, TransportError> {
        let prefix = format!("{}/", crate::topics::ROOT);
        let mut out = Vec::new();
        ipc::Service::list(self.node.config(), |s| {
            let name = s.static_details.name().as_str();
            if matches!(
                s.static_details.messaging_pattern(),
                iceoryx2::service::static_config::messaging_pattern::MessagingPattern::PublishSubscribe(_)
            ) {
                if let Some(t) = name.strip_prefix(&prefix) {
                    out.push(t.to_string());
                }
            }
            CallbackProgression::Continue
        })
        .map_err(|e| ipc_err("service list", "*", e))?;
        out.sort();
        out.dedup();
        Ok(out)
    }

    /// Removes the resources of nodes whose process died; returns how many.
    pub fn cleanup_dead_nodes(&self) -> usize {
        let state = self.node.try_cleanup_dead_nodes();
        state.cleanups as usize
    }

    /// Runs `create`; if it fails (typically a service still full of a dead
    /// process's ports), cleans up dead nodes and tries once more.
    fn with_cleanup_retry<T, E: Debug>(
        &self,
        what: &'static str,
        topic: &str,
        mut create: impl FnMut() -> Result<T, E>,
    ) -> Result<T, TransportError> {
        match create() {
            Ok(v) => Ok(v),
            Err(first) => {
                let removed = self.cleanup_dead_nodes();
                tracing::debug!(
                    topic,
                    ?first,
                    removed,
                    "retrying {what} after dead-node clean-up"
                );
                create().map_err(|e| ipc_err(what, topic, e))
            }
        }
    }

    fn event_ports(
        &self,
        topic: &str,
        service_name: &ServiceName,
    ) -> Result<iceoryx2::service::port_factory::event::PortFactory<ipc::Service>, TransportError>
    {
        self.with_cleanup_retry("event service", topic, || {
            self.node
                .service_builder(service_name)
                .event()
                .max_notifiers(MAX_PUBLISHERS)
                .max_listeners(MAX_SUBSCRIBERS)
                .max_nodes(MAX_NODES)
                .open_or_create()
        })
    }

    fn service_name(topic: &str) -> Result<ServiceName, TransportError> {
        let full = crate::topics::ipc_service_name(topic);
        ServiceName::new(&full).map_err(|e| ipc_err("service name", topic, e))
    }

    /// A publisher of fixed-size messages.
    pub fn publisher<M: IpcMessage>(
        &self,
        topic: &Topic<M>,
    ) -> Result<Publisher<M>, TransportError> {
        let name = Self::service_name(topic.name())?;
        let service = self.with_cleanup_retry("publish-subscribe service", topic.name(), || {
            self.node
                .service_builder(&name)
                .publish_subscribe::<M>()
                .enable_safe_overflow(true)
                .subscriber_max_buffer_size(1)
                .history_size(1)
                .subscriber_max_borrowed_samples(MAX_BORROWED)
                .max_publishers(MAX_PUBLISHERS)
                .max_subscribers(MAX_SUBSCRIBERS)
                .max_nodes(MAX_NODES)
                .open_or_create()
        })?;
        let port = self.with_cleanup_retry("publisher", topic.name(), || {
            service.publisher_builder().create()
        })?;
        let events = self.event_ports(topic.name(), &name)?;
        let notifier = self.with_cleanup_retry("notifier", topic.name(), || {
            events.notifier_builder().create()
        })?;
        let queue = match self.queue_depth(topic.name()) {
            Some(depth) => {
                let service = self.fixed_queue_service::<M>(topic.name(), depth)?;
                let port = self.with_cleanup_retry("queue publisher", topic.name(), || {
                    service.publisher_builder().create()
                })?;
                Some((port, self.queue_notifier(topic.name())?))
            }
            None => None,
        };
        Ok(Publisher {
            port,
            notifier,
            queue,
            topic: topic.name().to_string(),
            sent: Cell::new(0),
        })
    }

    /// A latest-value subscriber of fixed-size messages.
    pub fn subscriber<M: IpcMessage>(
        &self,
        topic: &Topic<M>,
    ) -> Result<Subscriber<M>, TransportError> {
        let name = Self::service_name(topic.name())?;
        let service = self.with_cleanup_retry("publish-subscribe service", topic.name(), || {
            self.node
                .service_builder(&name)
                .publish_subscribe::<M>()
                .enable_safe_overflow(true)
                .subscriber_max_buffer_size(1)
                .history_size(1)
                .subscriber_max_borrowed_samples(MAX_BORROWED)
                .max_publishers(MAX_PUBLISHERS)
                .max_subscribers(MAX_SUBSCRIBERS)
                .max_nodes(MAX_NODES)
                .open_or_create()
        })?;
        let port = self.with_cleanup_retry("subscriber", topic.name(), || {
            service.subscriber_builder().buffer_size(1).create()
        })?;
        let events = self.event_ports(topic.name(), &name)?;
        let listener = self.with_cleanup_retry("listener", topic.name(), || {
            events.listener_builder().create()
        })?;
        Ok(Subscriber {
            port,
            listener,
            topic: topic.name().to_string(),
            skips: Cell::new(SkipCounter::default()),
        })
    }

    /// A publisher of header + slice messages whose slices hold at most
    /// `max_len` elements. The shared memory is allocated once, up front: a
    /// growing segment can lose samples when its publisher exits.
    pub fn slice_publisher<H: IpcHeader, E: IpcElem>(
        &self,
        topic: &Topic<Slice<H, E>>,
        max_len: usize,
    ) -> Result<SlicePublisher<H, E>, TransportError> {
        if max_len == 0 {
            return Err(TransportError::Setting {
                key: "max_len",
                value: "0".into(),
                expected: "at least one element",
            });
        }
        let name = Self::service_name(topic.name())?;
        let service = self.slice_service::<H, E>(topic.name(), &name)?;
        let port = self.with_cleanup_retry("publisher", topic.name(), || {
            service
                .publisher_builder()
                .initial_max_slice_len(max_len)
                .allocation_strategy(AllocationStrategy::Static)
                .create()
        })?;
        let events = self.event_ports(topic.name(), &name)?;
        let notifier = self.with_cleanup_retry("notifier", topic.name(), || {
            events.notifier_builder().create()
        })?;
        let queue = match self.queue_depth(topic.name()) {
            Some(depth) => {
                let service = self.slice_queue_service::<H, E>(topic.name(), depth)?;
                let port = self.with_cleanup_retry("queue publisher", topic.name(), || {
                    service
                        .publisher_builder()
                        .initial_max_slice_len(max_len)
                        .allocation_strategy(AllocationStrategy::Static)
                        .create()
                })?;
                Some((port, self.queue_notifier(topic.name())?))
            }
            None => None,
        };
        Ok(SlicePublisher {
            port,
            notifier,
            queue,
            topic: topic.name().to_string(),
            max_len,
            sent: Cell::new(0),
        })
    }

    /// A latest-value subscriber of header + slice messages.
    pub fn slice_subscriber<H: IpcHeader, E: IpcElem>(
        &self,
        topic: &Topic<Slice<H, E>>,
    ) -> Result<SliceSubscriber<H, E>, TransportError> {
        let name = Self::service_name(topic.name())?;
        let service = self.slice_service::<H, E>(topic.name(), &name)?;
        let port = self.with_cleanup_retry("subscriber", topic.name(), || {
            service.subscriber_builder().buffer_size(1).create()
        })?;
        let events = self.event_ports(topic.name(), &name)?;
        let listener = self.with_cleanup_retry("listener", topic.name(), || {
            events.listener_builder().create()
        })?;
        Ok(SliceSubscriber {
            port,
            listener,
            topic: topic.name().to_string(),
            skips: Cell::new(SkipCounter::default()),
        })
    }

    fn slice_service<H: IpcHeader, E: IpcElem>(
        &self,
        topic: &str,
        name: &ServiceName,
    ) -> Result<
        iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, [E], H>,
        TransportError,
    > {
        self.with_cleanup_retry("publish-subscribe service", topic, || {
            self.node
                .service_builder(name)
                .publish_subscribe::<[E]>()
                .user_header::<H>()
                .enable_safe_overflow(true)
                .subscriber_max_buffer_size(1)
                .history_size(1)
                .subscriber_max_borrowed_samples(MAX_BORROWED)
                .max_publishers(MAX_PUBLISHERS)
                .max_subscribers(MAX_SUBSCRIBERS)
                .max_nodes(MAX_NODES)
                .open_or_create()
        })
    }
}

/// A fixed-size message that can live in shared memory.
pub trait IpcMessage: Debug + Copy + ZeroCopySend + Stamped + 'static {}
impl<T: Debug + Copy + ZeroCopySend + Stamped + 'static> IpcMessage for T {}

/// The header of a header + slice message.
pub trait IpcHeader: Debug + Copy + Default + ZeroCopySend + Stamped + 'static {}
impl<T: Debug + Copy + Default + ZeroCopySend + Stamped + 'static> IpcHeader for T {}

/// An element of a slice payload.
pub trait IpcElem: Debug + Copy + ZeroCopySend + bytemuck::Pod + 'static {}
impl<T: Debug + Copy + ZeroCopySend + bytemuck::Pod + 'static> IpcElem for T {}

/// A publisher's port on its topic's queue, and the queue's notifier.
type QueuePort<P, H> = (IoxPublisher<ipc::Service, P, H>, Notifier<ipc::Service>);

/// Publishes fixed-size messages of one topic.
pub struct Publisher<M: IpcMessage> {
    port: IoxPublisher<ipc::Service, M, ()>,
    notifier: Notifier<ipc::Service>,
    /// The topic's queue, where one is declared: a copy of every message.
    queue: Option<QueuePort<M, ()>>,
    topic: String,
    sent: Cell<u64>,
}

impl<M: IpcMessage> Publisher<M> {
    /// Copies `msg` into shared memory and wakes the subscribers.
    pub fn publish(&self, msg: &M) -> Result<(), TransportError> {
        self.port
            .send_copy(*msg)
            .map_err(|e| ipc_err("send", &self.topic, e))?;
        self.sent.set(self.sent.get() + 1);
        // A listener that is gone is not this publisher's failure.
        let _ = self.notifier.notify();
        if let Some((queue, notifier)) = &self.queue {
            queue
                .send_copy(*msg)
                .map_err(|e| ipc_err("queue send", &self.topic, e))?;
            let _ = notifier.notify();
        }
        Ok(())
    }

    pub fn sent(&self) -> u64 {
        self.sent.get()
    }

    pub fn topic(&self) -> &str {
        &self.topic
    }

    /// Hands the last message to subscribers that joined since it was sent.
    /// iceoryx2 only does this when the publisher sends or is told to, so a
    /// publisher of rare messages (a goal, an e-stop) calls this on its tick:
    /// a stage that restarts still learns the current goal.
    pub fn deliver_history(&self) -> Result<(), TransportError> {
        use iceoryx2::port::update_connections::UpdateConnections;
        if let Some((queue, _)) = &self.queue {
            queue
                .update_connections()
                .map_err(|e| ipc_err("update connections", &self.topic, e))?;
        }
        self.port
            .update_connections()
            .map_err(|e| ipc_err("update connections", &self.topic, e))
    }
}

/// Receives the newest fixed-size message of one topic.
pub struct Subscriber<M: IpcMessage> {
    port: IoxSubscriber<ipc::Service, M, ()>,
    listener: Listener<ipc::Service>,
    topic: String,
    skips: Cell<SkipCounter>,
}

impl<M: IpcMessage> Subscriber<M> {
    /// The newest message since the last call, if any; older ones are skipped
    /// and counted.
    pub fn latest(&self) -> Result<Option<M>, TransportError> {
        let mut newest: Option<M> = None;
        while let Some(sample) = self
            .port
            .receive()
            .map_err(|e| ipc_err("receive", &self.topic, e))?
        {
            newest = Some(*sample.payload());
        }
        if let Some(m) = &newest {
            self.observe(m.stamp().frame_seq);
        }
        Ok(newest)
    }

    /// Every message waiting, oldest first (on a queue subscriber: all
    /// sent since the last call, up to the depth; latest-value: the newest).
    ///
    /// At most the subscriber's buffer (its queue depth) per call: a
    /// publisher that keeps pace with the reader would otherwise keep one
    /// call taking, and its memory growing, for as long as it publishes.
    /// What is left is taken by the next call.
    pub fn drain(&self) -> Result<Vec<M>, TransportError> {
        let mut out = Vec::new();
        while out.len() < self.port.buffer_size() {
            let Some(sample) = self
                .port
                .receive()
                .map_err(|e| ipc_err("receive", &self.topic, e))?
            else {
                break;
            };
            self.observe(sample.payload().stamp().frame_seq);
            out.push(*sample.payload());
        }
        Ok(out)
    }

    /// The listener to attach to a WaitSet (see [`wait_loop`]).
    pub fn listener(&self) -> &Listener<ipc::Service> {
        &self.listener
    }

    pub fn skips(&self) -> SkipCounter {
        self.skips.get()
    }

    fn observe(&self, seq: u64) {
        let mut s = self.skips.get();
        s.observe(seq);
        self.skips.set(s);
    }

    pub fn topic(&self) -> &str {
        &self.topic
    }
}

/// Publishes header + slice messages (frames, maps) of one topic.
pub struct SlicePublisher<H: IpcHeader, E: IpcElem> {
    port: IoxPublisher<ipc::Service, [E], H>,
    notifier: Notifier<ipc::Service>,
    /// The topic's queue, where one is declared: a copy of every message.
    queue: Option<QueuePort<[E], H>>,
    topic: String,
    max_len: usize,
    sent: Cell<u64>,
}

impl<H: IpcHeader, E: IpcElem> SlicePublisher<H, E> {
    fn check_len(&self, len: usize) -> Result<(), TransportError> {
        if len > self.max_len {
            return Err(TransportError::TooLarge {
                topic: self.topic.clone(),
                detail: format!(
                    "{len} elements, the publisher was created for at most {}",
                    self.max_len
                ),
            });
        }
        Ok(())
    }

    /// Loans `len` zeroed elements in shared memory, lets `fill` write them in
    /// place and return the header, then sends. The only copy of the data is
    /// the one `fill` makes; the header is built last so it can describe what
    /// was written (decoded size, send time).
    pub fn publish_with(
        &self,
        len: usize,
        fill: impl FnOnce(&mut [E]) -> H,
    ) -> Result<(), TransportError> {
        self.check_len(len)?;
        let sample = self
            .port
            .loan_slice_uninit(len)
            .map_err(|e| ipc_err("loan", &self.topic, e))?;
        let mut sample = sample.write_from_fn(|_| E::zeroed());
        let header = fill(sample.payload_mut());
        *sample.user_header_mut() = header;
        // The queue's copy first: the sample is the topic's once sent.
        self.send_to_queue(header, sample.payload())?;
        sample.send().map_err(|e| ipc_err("send", &self.topic, e))?;
        self.sent.set(self.sent.get() + 1);
        let _ = self.notifier.notify();
        Ok(())
    }

    fn send_to_queue(&self, header: H, data: &[E]) -> Result<(), TransportError> {
        let Some((queue, notifier)) = &self.queue else {
            return Ok(());
        };
        let sample = queue
            .loan_slice_uninit(data.len())
            .map_err(|e| ipc_err("queue loan", &self.topic, e))?;
        let mut sample = sample.write_from_slice(data);
        *sample.user_header_mut() = header;
        sample
            .send()
            .map_err(|e| ipc_err("queue send", &self.topic, e))?;
        let _ = notifier.notify();
        Ok(())
    }

    /// Copies `data` into shared memory and sends it.
    pub fn publish_copy(&self, header: H, data: &[E]) -> Result<(), TransportError> {
        self.check_len(data.len())?;
        let sample = self
            .port
            .loan_slice_uninit(data.len())
            .map_err(|e| ipc_err("loan", &self.topic, e))?;
        let mut sample = sample.write_from_slice(data);
        *sample.user_header_mut() = header;
        sample.send().map_err(|e| ipc_err("send", &self.topic, e))?;
        self.sent.set(self.sent.get() + 1);
        let _ = self.notifier.notify();
        self.send_to_queue(header, data)
    }

    pub fn max_len(&self) -> usize {
        self.max_len
    }

    pub fn sent(&self) -> u64 {
        self.sent.get()
    }

    pub fn topic(&self) -> &str {
        &self.topic
    }
}

/// A received header + slice message, read in place from shared memory.
pub struct SliceSample<H: IpcHeader, E: IpcElem>(Sample<ipc::Service, [E], H>);

impl<H: IpcHeader, E: IpcElem> SliceSample<H, E> {
    pub fn header(&self) -> &H {
        self.0.user_header()
    }

    pub fn data(&self) -> &[E] {
        self.0.payload()
    }
}

/// Receives the newest header + slice message of one topic.
pub struct SliceSubscriber<H: IpcHeader, E: IpcElem> {
    port: IoxSubscriber<ipc::Service, [E], H>,
    listener: Listener<ipc::Service>,
    topic: String,
    skips: Cell<SkipCounter>,
}

impl<H: IpcHeader, E: IpcElem> SliceSubscriber<H, E> {
    /// The newest message since the last call, if any, without copying it.
    pub fn latest(&self) -> Result<Option<SliceSample<H, E>>, TransportError> {
        let mut newest = None;
        while let Some(sample) = self
            .port
            .receive()
            .map_err(|e| ipc_err("receive", &self.topic, e))?
        {
            newest = Some(sample);
        }
        if let Some(s) = &newest {
            self.observe(s.user_header().stamp().frame_seq);
        }
        Ok(newest.map(SliceSample))
    }

    /// How many messages it holds at most: its queue depth (1 for a
    /// latest-value subscriber).
    pub fn buffer_size(&self) -> usize {
        self.port.buffer_size()
    }

    /// The oldest message waiting, if any (on a queue subscriber: each
    /// message in the order sent).
    pub fn next(&self) -> Result<Option<SliceSample<H, E>>, TransportError> {
        let sample = self
            .port
            .receive()
            .map_err(|e| ipc_err("receive", &self.topic, e))?;
        if let Some(s) = &sample {
            self.observe(s.user_header().stamp().frame_seq);
        }
        Ok(sample.map(SliceSample))
    }

    pub fn listener(&self) -> &Listener<ipc::Service> {
        &self.listener
    }

    pub fn skips(&self) -> SkipCounter {
        self.skips.get()
    }

    fn observe(&self, seq: u64) {
        let mut s = self.skips.get();
        s.observe(seq);
        self.skips.set(s);
    }

    pub fn topic(&self) -> &str {
        &self.topic
    }
}

/// Why [`wait_loop`] woke the stage.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Wake {
    /// Input `i` (index into the listeners given) was notified.
    Input(usize),
    /// The tick interval passed.
    Tick,
}

/// Why [`wait_loop`] returned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LoopExit {
    /// SIGTERM or SIGINT: the stage should shut down cleanly.
    Terminated,
    /// The callback asked to stop.
    Stopped,
}

/// Sleeps on a WaitSet until an input is notified or `tick` passes, and calls
/// `on_wake` for each reason. Returns on SIGTERM/SIGINT or when `on_wake`
/// breaks. Each input's listener is drained before `on_wake` runs, so the
/// WaitSet never spins.
pub fn wait_loop(
    inputs: &[&Listener<ipc::Service>],
    tick: Option<Duration>,
    mut on_wake: impl FnMut(Wake) -> ControlFlow<()>,
) -> Result<LoopExit, TransportError> {
    let waitset = WaitSetBuilder::new()
        .signal_handling_mode(SignalHandlingMode::HandleTerminationRequests)
        .create::<ipc::Service>()
        .map_err(|e| ipc_err("waitset", "-", e))?;
    let mut guards = Vec::with_capacity(inputs.len());
    for listener in inputs {
        guards.push(
            waitset
                .attach_notification(*listener)
                .map_err(|e| ipc_err("waitset attach", "-", e))?,
        );
    }
    let tick_guard = match tick {
        Some(t) => Some(
            waitset
                .attach_interval(t)
                .map_err(|e| ipc_err("waitset interval", "-", e))?,
        ),
        None => None,
    };
    // A stopped process (SIGSTOP) that is continued sees its wait
    // interrupted (EINTR), which iceoryx2 reports as `Interrupt` like SIGINT.
    // Only SIGTERM/SIGINT end the loop, as seen by the sticky flag
    // ([`termination_requested`]) on every wake and after every wait.
    let wedge_at = test_hook_wedge_at();
    let mut process = |id: WaitSetAttachmentId<ipc::Service>| {
        if wedge_at.is_some_and(|t| std::time::Instant::now() >= t) {
            wedge();
        }
        // SIGTERM that arrived while a step ran, then SIGCONT: iceoryx2
        // only remembers the last signal, so the flag decides.
        if termination_requested() {
            return CallbackProgression::Stop;
        }
        let mut wake = None;
        for (i, (listener, guard)) in inputs.iter().zip(&guards).enumerate() {
            if id.has_event_from(guard) {
                let _ = listener.try_wait(|_| {});
                wake = Some(Wake::Input(i));
            }
        }
        if let Some(g) = &tick_guard {
            if id.has_event_from(g) {
                wake = Some(Wake::Tick);
            }
        }
        match wake.map(&mut on_wake) {
            Some(ControlFlow::Break(())) => CallbackProgression::Stop,
            _ => CallbackProgression::Continue,
        }
    };
    loop {
        let result = waitset
            .wait_and_process(&mut process)
            .map_err(|e| ipc_err("waitset wait", "-", e))?;
        if termination_requested() {
            return Ok(LoopExit::Terminated);
        }
        match result {
            WaitSetRunResult::TerminationRequest => return Ok(LoopExit::Terminated),
            WaitSetRunResult::Interrupt => continue,
            _ => return Ok(LoopExit::Stopped),
        }
    }
}

/// Set once SIGTERM or SIGINT has arrived; never cleared.
static TERMINATION: std::sync::OnceLock<std::sync::Arc<std::sync::atomic::AtomicBool>> =
    std::sync::OnceLock::new();

/// Whether SIGTERM or SIGINT has arrived since the bus was opened.
///
/// iceoryx2 records signals in one slot that the next signal overwrites and
/// that reading clears, and it catches SIGCONT too. systemd sends SIGCONT
/// right after SIGTERM (so a stopped process can act on it), which left the
/// slot saying SIGCONT and the stop request lost. This flag, set by
/// signal-hook's handler (which then calls iceoryx2's), is not lost.
pub fn termination_requested() -> bool {
    TERMINATION
        .get()
        .is_some_and(|f| f.load(std::sync::atomic::Ordering::SeqCst))
}

/// Installs the flag's handlers once per process, after iceoryx2's own:
/// signal-hook chains to the handler it finds, while iceoryx2 installs its
/// handlers lazily and would replace anything installed before them.
fn watch_termination_signals(node: &Node<ipc::Service>) {
    TERMINATION.get_or_init(|| {
        // Makes iceoryx2 install its handlers now.
        let _ = node.wait(Duration::ZERO);
        let flag = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        for signal in [signal_hook::consts::SIGTERM, signal_hook::consts::SIGINT] {
            if let Err(e) = signal_hook::flag::register(signal, flag.clone()) {
                tracing::warn!("cannot watch signal {signal}: {e}");
            }
        }
        flag
    });
}

/// Test hook (`tests/watchdog.rs`): with `FARSIGHT_TEST_WEDGE_AFTER_S=N` in
/// its environment, the loop's step hangs N seconds after [`wait_loop`]
/// starts, as a stuck step would, so a test can see the watchdog pings stop
/// while the process lives. Never set outside tests.
fn test_hook_wedge_at() -> Option<std::time::Instant> {
    let s: f64 = std::env::var("FARSIGHT_TEST_WEDGE_AFTER_S")
        .ok()?
        .parse()
        .ok()?;
    (s.is_finite() && s >= 0.0).then(|| std::time::Instant::now() + Duration::from_secs_f64(s))
}

fn wedge() -> ! {
    eprintln!("test hook: step wedged (FARSIGHT_TEST_WEDGE_AFTER_S)");
    loop {
        std::thread::park();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_queue_declaration_names_its_bad_entry() {
        let q = parse_queues("state/pose=64, camera/front/image=8,").unwrap();
        assert_eq!(q.get("state/pose"), Some(&64));
        assert_eq!(q.get("camera/front/image"), Some(&8));
        assert!(parse_queues("").unwrap().is_empty());
        for bad in [
            "state/pose",
            "state/pose=0",
            "state/pose=2000",
            "state/pose=x",
            "not/a/topic=4",
        ] {
            let e = parse_queues(bad).unwrap_err().to_string();
            assert!(e.contains(bad.trim()), "{bad}: {e}");
        }
    }

    #[test]
    fn shared_memory_is_stated_as_iceoryx2_sizes_a_data_segment() {
        // 12 slots x (1 + 2 borrowed) + history 1 + 2 loaned.
        assert_eq!(segment_samples(MAX_SUBSCRIBERS, 1, 1), 39);
        // The queue's 2 slots at depth 16, history 1.
        assert_eq!(segment_samples(QUEUE_SUBSCRIBERS, 16, 1), 39);
        assert_eq!(publisher_shm_bytes(100, None), 3900);
        assert_eq!(publisher_shm_bytes(100, Some(16)), 7800);
        // The issue's example: 12 slots at depth 32 of a 2.7 MB frame would
        // be 1.1 GB; the queue costs a fifth of that.
        let frame = 2_700_000;
        assert!(segment_samples(MAX_SUBSCRIBERS, 32, 1) * frame > 1_000_000_000);
        assert!(publisher_shm_bytes(frame, Some(32)) < 300_000_000);
    }
}
