//! The live Foxglove WebSocket server, fed from the vehicle's shared memory
//! or from a robot's bridge over zenoh.
//!
//! A channel is advertised when its first message is made, so the app
//! lists what the graph actually publishes. Both feeds take the newest
//! message of each topic: a viewer that falls behind skips frames rather
//! than showing old ones late.

use crate::view::{Out, View};
use farsight_interfaces::message::Message;
use farsight_interfaces::topics::kind_of;
use farsight_interfaces::transport::any::AnySubscriber;
use farsight_interfaces::transport::ipc::{self, Bus, LoopExit};
use farsight_interfaces::transport::net::NetBus;
use farsight_interfaces::transport::TransportError;
use foxglove::{Context, PartialMetadata, RawChannel, WebSocketServer, WebSocketServerHandle};
use std::collections::{BTreeMap, HashMap};
use std::ops::ControlFlow;
use std::sync::Arc;
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

/// A running Foxglove WebSocket server and its channels.
pub struct LiveServer {
    ctx: Arc<Context>,
    handle: Option<WebSocketServerHandle>,
    channels: HashMap<String, Arc<RawChannel>>,
    stats: BTreeMap<String, ChannelStats>,
}

impl LiveServer {
    /// Starts the server on `host:port` (port 0: any free port, see
    /// [`LiveServer::port`]). Read-only: no client-publish capability.
    pub fn start(host: &str, port: u16) -> Result<Self, LiveError> {
        let ctx = Context::new();
        let handle = WebSocketServer::new()
            .name("farsight")
            .bind(host, port)
            .context(&ctx)
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
        })
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

/// Serves what a robot's bridge sends over zenoh (the laptop's view).
/// A message that does not decode as its topic's kind is counted in the
/// view's drops and logged, never shown.
pub fn serve_zenoh(
    net: &NetBus,
    view: &mut View,
    server: &mut LiveServer,
    opts: &ServeOptions,
) -> Result<(), LiveError> {
    let tap = net.tap(1024)?;
    let start = Instant::now();
    let mut progress = Progress::new(opts.progress);
    let mut failure = None;
    let mut undecodable: BTreeMap<String, u64> = BTreeMap::new();
    ipc::wait_loop(&[], Some(Duration::from_millis(10)), |_| {
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
