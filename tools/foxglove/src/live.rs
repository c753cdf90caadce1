//! The live Foxglove WebSocket server, fed from the vehicle's shared memory
//! or from a robot's bridge over zenoh.
//!
//! On the robot it is read-only: no client-publish capability. On the
//! laptop it also takes the operator's goals, e-stop and teleop from the
//! app ([`crate::operator`]) and puts them on the robot's zenoh keys, which
//! the robot's bridge hands to the planner and the command mux.
//!
//! A channel is advertised when its first message is made, so the app
//! lists what the graph actually publishes. Both feeds take the newest
//! message of each topic: a viewer that falls behind skips frames rather
//! than showing old ones late.

use crate::operator::{self, OperatorCommand, OperatorConfig, Refusal};
use crate::view::{Out, View};
use farsight_interfaces::clock::{Clock, WallClock};
use farsight_interfaces::message::Message;
use farsight_interfaces::msg::{EStop, NavGoal, Stamp, VelocityCommand};
use farsight_interfaces::topics::{self, kind_of};
use farsight_interfaces::transport::any::AnySubscriber;
use farsight_interfaces::transport::ipc::{self, Bus, LoopExit};
use farsight_interfaces::transport::net::{NetBus, Publisher};
use farsight_interfaces::transport::TransportError;
use foxglove::websocket::{Capability, Client, ClientChannel, ServerListener, Status};
use foxglove::{Context, PartialMetadata, RawChannel, WebSocketServer, WebSocketServerHandle};
use std::collections::{BTreeMap, HashMap};
use std::ops::ControlFlow;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{mpsc, Arc, Mutex};
use std::time::{Duration, Instant};

#[derive(Debug, thiserror::Error)]
pub enum LiveError {
    #[error("Foxglove server on {host}:{port}: {source}")]
    Start {
        host: String,
        port: u16,
        source: foxglove::FoxgloveError,
    },
    #[error("Foxglove channel {topic}: {source}")]
    Channel {
        topic: String,
        source: foxglove::FoxgloveError,
    },
    #[error(transparent)]
    Transport(#[from] TransportError),
}

/// Messages and bytes sent on one Foxglove topic.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ChannelStats {
    pub messages: u64,
    pub bytes: u64,
}

/// The operator's messages from the app: taken or refused, per topic.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct OperatorStats {
    pub accepted: u64,
    pub refused: u64,
}

/// Who the laptop's server commands as, and within which limits.
#[derive(Debug, Clone)]
pub struct OperatorInput {
    /// `Ok` when the zenoh login may command ([`operator::may_command`]);
    /// otherwise every message from the app is refused with this reason.
    pub rights: Result<(), Refusal>,
    pub config: OperatorConfig,
    /// Who the e-stop says pressed it (`EStop::source`).
    pub source: String,
}

/// The server's side of the app's client channels: runs on the server's
/// threads, so it only checks and converts; the serving loop publishes.
struct OperatorListener {
    input: OperatorInput,
    to_robot: Mutex<mpsc::Sender<OperatorCommand>>,
    stats: Arc<Mutex<BTreeMap<String, OperatorStats>>>,
    seq: AtomicU64,
}

impl OperatorListener {
    fn refuse(&self, client: &Client, topic: &str, why: &Refusal) {
        let refused = {
            let mut stats = self.stats.lock().unwrap_or_else(|p| p.into_inner());
            let s = stats.entry(topic.to_string()).or_default();
            s.refused += 1;
            s.refused
        };
        // The first of a topic and every 100th: a teleop panel sends 10 a second.
        if refused % 100 == 1 {
            tracing::warn!(topic, refused, "refused from the app: {why}");
            client.send_status(Status::error(format!("farsight refused {topic}: {why}")));
        }
    }
}

impl ServerListener for OperatorListener {
    fn on_client_advertise(&self, client: Client, channel: &ClientChannel) {
        tracing::info!(
            topic = channel.topic,
            schema = channel.schema_name,
            "the app advertised a channel"
        );
        if let Err(why) = &self.input.rights {
            client.send_status(Status::warning(format!(
                "farsight will refuse {}: {why}",
                channel.topic
            )));
        }
    }

    fn on_message_data(&self, client: Client, channel: &ClientChannel, payload: &[u8]) {
        let seq = self.seq.fetch_add(1, Ordering::Relaxed);
        let command = self.input.rights.clone().and_then(|()| {
            operator::command_from_client(
                &channel.topic,
                &channel.encoding,
                &channel.schema_name,
                payload,
                Stamp::new(seq, WallClock.now_ns()),
                &self.input.source,
                &self.input.config,
            )
        });
        match command {
            Ok(c) => {
                let sent = self
                    .to_robot
                    .lock()
                    .unwrap_or_else(|p| p.into_inner())
                    .send(c);
                if sent.is_ok() {
                    let mut stats = self.stats.lock().unwrap_or_else(|p| p.into_inner());
                    stats.entry(channel.topic.clone()).or_default().accepted += 1;
                }
            }
            Err(why) => self.refuse(&client, &channel.topic, &why),
        }
    }
}

/// A running Foxglove WebSocket server and its channels.
pub struct LiveServer {
    ctx: Arc<Context>,
    handle: Option<WebSocketServerHandle>,
    channels: HashMap<String, Arc<RawChannel>>,
    stats: BTreeMap<String, ChannelStats>,
    from_app: Option<mpsc::Receiver<OperatorCommand>>,
    operator_stats: Arc<Mutex<BTreeMap<String, OperatorStats>>>,
}

impl LiveServer {
    /// Starts the server on `host:port` (port 0: any free port, see
    /// [`LiveServer::port`]). Read-only: no client-publish capability.
    pub fn start(host: &str, port: u16) -> Result<Self, LiveError> {
        Self::start_with(host, port, None)
    }

    /// [`LiveServer::start`]; with `operator`, the server offers the app
    /// client publishing (JSON) and takes the operator's messages
    /// ([`crate::operator`]), to be sent on by [`serve_zenoh`].
    pub fn start_with(
        host: &str,
        port: u16,
        operator: Option<OperatorInput>,
    ) -> Result<Self, LiveError> {
        let ctx = Context::new();
        let operator_stats = Arc::new(Mutex::new(BTreeMap::new()));
        let mut builder = WebSocketServer::new()
            .name("farsight")
            .bind(host, port)
            .context(&ctx);
        let mut from_app = None;
        if let Some(input) = operator {
            let (tx, rx) = mpsc::channel();
            from_app = Some(rx);
            builder = builder
                .capabilities([Capability::ClientPublish])
                .supported_encodings(["json"])
                .listener(Arc::new(OperatorListener {
                    input,
                    to_robot: Mutex::new(tx),
                    stats: operator_stats.clone(),
                    seq: AtomicU64::new(1),
                }));
        }
        let handle = builder
            .start_blocking()
            .map_err(|source| LiveError::Start {
                host: host.into(),
                port,
                source,
            })?;
        Ok(Self {
            ctx,
            handle: Some(handle),
            channels: HashMap::new(),
            stats: BTreeMap::new(),
            from_app,
            operator_stats,
        })
    }

    /// What the app sent per topic: taken or refused.
    pub fn operator_stats(&self) -> BTreeMap<String, OperatorStats> {
        self.operator_stats
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }

    /// The port the server listens on.
    pub fn port(&self) -> u16 {
        self.handle.as_ref().map_or(0, |h| h.port())
    }

    /// Clients connected now.
    pub fn client_count(&self) -> usize {
        self.handle.as_ref().map_or(0, |h| h.client_count())
    }

    /// What was sent per topic so far.
    pub fn stats(&self) -> &BTreeMap<String, ChannelStats> {
        &self.stats
    }

    /// Sends one message, advertising its channel the first time.
    pub fn log(&mut self, out: &Out) -> Result<(), LiveError> {
        let channel = match self.channels.get(&out.topic) {
            Some(c) => c,
            None => {
                let (schema, encoding) = out.message.schema();
                let c = self
                    .ctx
                    .channel_builder(out.topic.clone())
                    .message_encoding(encoding)
                    .schema(schema)
                    .build_raw()
                    .map_err(|source| LiveError::Channel {
                        topic: out.topic.clone(),
                        source,
                    })?;
                tracing::info!(topic = out.topic, "advertised");
                self.channels.entry(out.topic.clone()).or_insert(c)
            }
        };
        let bytes = out.message.encode();
        channel.log_with_meta(
            &bytes,
            PartialMetadata {
                log_time: Some(out.log_time_ns),
            },
        );
        let s = self.stats.entry(out.topic.clone()).or_default();
        s.messages += 1;
        s.bytes += bytes.len() as u64;
        Ok(())
    }

    /// Stops the server, closing its clients' connections.
    pub fn stop(mut self) {
        if let Some(h) = self.handle.take() {
            h.stop().wait_blocking();
        }
    }
}

/// How long to serve and how often to look for new topics.
#[derive(Debug, Clone)]
pub struct ServeOptions {
    pub rescan: Duration,
    /// Stop after this long (`None`: until SIGINT/SIGTERM).
    pub duration: Option<Duration>,
    /// Print what was sent this often (`None`: never).
    pub progress: Option<Duration>,
}

impl Default for ServeOptions {
    fn default() -> Self {
        Self {
            rescan: Duration::from_millis(500),
            duration: None,
            progress: Some(Duration::from_secs(10)),
        }
    }
}

fn show(
    view: &mut View,
    server: &mut LiveServer,
    topic: &str,
    m: &Message,
) -> Result<(), LiveError> {
    view.on_message(topic, m)
        .iter()
        .try_for_each(|o| server.log(o))
}

struct Progress {
    every: Option<Duration>,
    last: Instant,
    start: Instant,
}

impl Progress {
    fn new(every: Option<Duration>) -> Self {
        Self {
            every,
            last: Instant::now(),
            start: Instant::now(),
        }
    }

    fn tick(&mut self, server: &LiveServer) {
        if self.every.is_some_and(|e| self.last.elapsed() >= e) {
            self.last = Instant::now();
            let (n, b) = server
                .stats()
                .values()
                .fold((0, 0), |(n, b), s| (n + s.messages, b + s.bytes));
            eprintln!(
                "foxglove {:.0} s: {} clients, {} channels, {n} messages, {:.1} MB sent",
                self.start.elapsed().as_secs_f64(),
                server.client_count(),
                server.stats().len(),
                b as f64 / 1e6
            );
        }
    }
}

/// Serves the vehicle's topics from shared memory until the duration is up
/// or the process is told to stop; topics that appear later are picked up
/// within `rescan`.
pub fn serve_shm(
    bus: &Bus,
    view: &mut View,
    server: &mut LiveServer,
    opts: &ServeOptions,
) -> Result<(), LiveError> {
    let start = Instant::now();
    let mut subs: Vec<(String, AnySubscriber)> = Vec::new();
    let mut progress = Progress::new(opts.progress);
    let mut failure = None;
    loop {
        for t in bus.topics()? {
            if kind_of(&t).is_some() && !subs.iter().any(|(n, _)| *n == t) {
                match AnySubscriber::open(bus, &t) {
                    Ok(s) => subs.push((t, s)),
                    Err(e) => tracing::warn!(topic = t, "not shown: {e}"),
                }
            }
        }
        let listeners: Vec<&ipc::InputListener> = subs.iter().map(|(_, s)| s.listener()).collect();
        let scan_at = Instant::now() + opts.rescan;
        let mut done = false;
        let exit = ipc::wait_loop(&listeners, Some(Duration::from_millis(50)), |_| {
            for (topic, s) in &subs {
                match s.take_message() {
                    Ok(Some(m)) => {
                        if let Err(e) = show(view, server, topic, &m) {
                            failure = Some(e);
                            return ControlFlow::Break(());
                        }
                    }
                    Ok(None) => {}
                    Err(e) => tracing::warn!(topic, "dropped: {e}"),
                }
            }
            progress.tick(server);
            done = opts.duration.is_some_and(|d| start.elapsed() >= d);
            if done || Instant::now() >= scan_at {
                return ControlFlow::Break(());
            }
            ControlFlow::Continue(())
        })?;
        if let Some(e) = failure {
            return Err(e);
        }
        if done || exit == LoopExit::Terminated {
            return Ok(());
        }
    }
}

/// The operator's publishers on the robot's imported keys.
struct ToRobot {
    goal: Publisher<NavGoal>,
    teleop: Publisher<VelocityCommand>,
    estop: Publisher<EStop>,
}

impl ToRobot {
    fn open(net: &NetBus) -> Result<Self, TransportError> {
        Ok(Self {
            goal: net.publisher(&topics::goal())?,
            teleop: net.publisher(&topics::command_input("teleop"))?,
            estop: net.publisher(&topics::estop())?,
        })
    }

    fn send(&mut self, command: &OperatorCommand) -> Result<(), TransportError> {
        match command {
            OperatorCommand::Goal(g) => self.goal.publish(g),
            OperatorCommand::Teleop(v) => self.teleop.publish(v),
            OperatorCommand::EStop(e) => self.estop.publish(e),
        }
    }
}

/// Serves what a robot's bridge sends over zenoh (the laptop's view), and
/// sends the operator's messages from the app to the robot when the server
/// was started with an [`OperatorInput`].
/// A message that does not decode as its topic's kind is counted in the
/// view's drops and logged, never shown.
pub fn serve_zenoh(
    net: &NetBus,
    view: &mut View,
    server: &mut LiveServer,
    opts: &ServeOptions,
) -> Result<(), LiveError> {
    let tap = net.tap(1024)?;
    let mut to_robot = match server.from_app {
        Some(_) => Some(ToRobot::open(net)?),
        None => None,
    };
    let start = Instant::now();
    let mut progress = Progress::new(opts.progress);
    let mut failure = None;
    let mut undecodable: BTreeMap<String, u64> = BTreeMap::new();
    ipc::wait_loop(&[], Some(Duration::from_millis(10)), |_| {
        if let (Some(rx), Some(out)) = (&server.from_app, to_robot.as_mut()) {
            for command in rx.try_iter() {
                if let Err(e) = out.send(&command) {
                    failure = Some(e.into());
                    return ControlFlow::Break(());
                }
            }
        }
        loop {
            let (topic, bytes) = match tap.try_next() {
                Ok(Some(m)) => m,
                Ok(None) => break,
                Err(e) => {
                    failure = Some(e.into());
                    return ControlFlow::Break(());
                }
            };
            let Some(kind) = kind_of(&topic) else {
                continue;
            };
            match Message::from_wire(kind, &bytes) {
                Ok(m) => {
                    if let Err(e) = show(view, server, &topic, &m) {
                        failure = Some(e);
                        return ControlFlow::Break(());
                    }
                }
                Err(e) => {
                    let n = undecodable.entry(topic.clone()).or_default();
                    *n += 1;
                    if *n % 100 == 1 {
                        tracing::warn!(topic, dropped = *n, "not shown: {e}");
                    }
                }
            }
        }
        progress.tick(server);
        if opts.duration.is_some_and(|d| start.elapsed() >= d) {
            return ControlFlow::Break(());
        }
        ControlFlow::Continue(())
    })?;
    match failure {
        Some(e) => Err(e),
        None => Ok(()),
    }
}
