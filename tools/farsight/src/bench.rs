//! `farsight bench transport`: publish-to-receive latency of one message, for
//! several sizes, over iceoryx2 zero-copy, zenoh on loopback TCP and a plain
//! Unix-socket copy, measured in one run and printed as a table.
//!
//! Each cell uses two processes: this one publishes, a child receives. The send
//! time is taken when the payload is complete, right before it is handed to the
//! transport; the receive time when the receiver holds the whole message (for
//! iceoryx2: a reference into shared memory, nothing copied). Both processes
//! read the same system clock.
//!
//! Beside them, the yardstick for waking a sleeping stage (issue 21 item 3):
//! raw iceoryx2 event ping-pong (a listener blocked in `blocking_wait`, no
//! WaitSet, no sample; the child answers each ping so they go one at a
//! time, with the same pause between them), timed from the ping's notify
//! to the child's wake. Half the round trip would flatter it: the pong
//! wakes a process that went to sleep microseconds before, the ping one
//! that slept through the pause, as a stage does between frames. And the
//! CPU the receiver burned while it waited, which shows the WaitSet
//! receiver sleeps where the polling one spins.

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand, ValueEnum};
use farsight_interfaces::clock::{Clock, WallClock};
use farsight_interfaces::msg::{ImageHeader, PixelEncoding, Stamp};
use farsight_interfaces::topics::{ImageTopic, Topic};
use farsight_interfaces::transport::ipc::{self, Bus, IpcSettings};
use farsight_interfaces::transport::net::NetBus;
use std::io::{BufRead, BufReader, Read, Write};
use std::ops::ControlFlow;
use std::os::unix::net::{UnixListener, UnixStream};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

#[derive(Subcommand)]
pub enum BenchCommand {
    /// Latency table: iceoryx2 vs zenoh vs Unix socket, 64 B to 6 MB.
    Transport(TransportArgs),
    /// Per-frame cost of pre-processing, inference and post-processing on the
    /// ORFD frames, and the frame rate the inference stage sustains fed by
    /// camera-ingest at full speed.
    Inference(InferenceArgs),
    /// Per-frame cost of LRN bins, POVNav and the servo law at 640x360 and 1280x720.
    Navigation(NavigationArgs),
    /// FITAM map updates and D* Lite: first plan vs repair vs A* from scratch.
    Planning(PlanningArgs),
    /// The navigation benchmark: seeded trials per scenario and method in the simulator.
    Nav(NavArgs),
    /// Merges `bench nav --shard K/N --out FILE.json` files and prints the
    /// table of the whole run; refuses mixed versions, hashes or commits.
    NavMerge(crate::bench_record::MergeArgs),
    /// FITAM's own protocol (section V, Table I): a kinematic sense-plan-act
    /// agent on 5 x 5 km worlds, paired % improved and % cost difference
    /// against no far field.
    Fitam(crate::bench_fitam::FitamArgs),
    /// Merges `bench fitam --shard K/N --out FILE.json` files and prints the
    /// table of the whole run; refuses mixed versions, hashes or commits.
    FitamMerge(crate::bench_record::MergeArgs),
    /// What `farsight record` sustains writing 1280x720 RGB frames to disk.
    Recorder(crate::bench_recorder::RecorderArgs),
    /// The ORFD POVNav graph as processes: capture-to-command and per-hop
    /// latency, median and p99, beside inference alone; each stage's memory.
    E2e(crate::bench_e2e::E2eArgs),
    /// (internal) the receiving side of one cell of the transport benchmark.
    #[command(hide = true)]
    TransportReceiver(ReceiverArgs),
}

#[derive(Args)]
pub struct TransportArgs {
    /// Message sizes in bytes.
    #[arg(long, value_delimiter = ',', default_values_t = [64usize, 1 << 20, 6 << 20])]
    sizes: Vec<usize>,
    /// Messages per cell.
    #[arg(long, default_value_t = 200)]
    count: usize,
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum, Debug)]
pub enum Kind {
    /// iceoryx2, receiver polls.
    IpcPoll,
    /// iceoryx2, receiver sleeps on a WaitSet and is woken by the paired event.
    IpcWait,
    /// Raw iceoryx2 events, no payload: ping, the child wakes from a
    /// blocking wait on its listener, notes the time and answers pong
    /// (lock-step); ping to wake.
    IpcEvent,
    /// The same, the child asleep on a WaitSet as every stage is.
    IpcEventWait,
    /// zenoh peer-to-peer over loopback TCP.
    Zenoh,
    /// A Unix stream socket, the payload copied through the kernel.
    Unix,
}

impl Kind {
    fn label(self) -> &'static str {
        match self {
            Kind::IpcPoll => "iceoryx2 (poll)",
            Kind::IpcWait => "iceoryx2 (WaitSet)",
            Kind::IpcEvent => "iceoryx2 raw event ping",
            Kind::IpcEventWait => "iceoryx2 event ping (WaitSet)",
            Kind::Zenoh => "zenoh tcp loopback",
            Kind::Unix => "unix socket copy",
        }
    }
}

#[derive(Args)]
pub struct ReceiverArgs {
    #[arg(long, value_enum)]
    kind: Kind,
    #[arg(long)]
    size: usize,
    #[arg(long)]
    count: usize,
    /// iceoryx2 prefix, zenoh endpoint or socket path.
    #[arg(long)]
    endpoint: String,
}

#[derive(Args)]
pub struct InferenceArgs {
    #[arg(long, default_value = "deploy/models/twinlitenet.toml")]
    pub model_config: std::path::PathBuf,
    #[arg(long, default_value = "../shared/data/orfd/image_data")]
    pub frames: std::path::PathBuf,
    /// Timed runs (after 3 warm-up runs).
    #[arg(long, default_value_t = 30)]
    pub runs: usize,
    /// Seconds of the stage throughput measurement (0 = skip it).
    #[arg(long, default_value_t = 10.0)]
    pub stage_seconds: f64,
    /// Cameras in the throughput measurement. Above 1, compares one
    /// inference process serving them all (one ONNX Runtime session,
    /// batched where the model's batch dimension is open) with one process
    /// per camera: frames/s, CPU and private memory.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=16))]
    pub cameras: u16,
    /// Each camera's frame rate in the throughput measurement: above what
    /// the stage keeps up with, frames/s is its capacity; below it, compare
    /// the CPU a frame.
    #[arg(long, default_value_t = 200, value_parser = clap::value_parser!(u16).range(1..=1000))]
    pub camera_rate_hz: u16,
}

#[derive(Args)]
pub struct NavigationArgs {
    /// Timed runs per cell.
    #[arg(long, default_value_t = 200)]
    pub runs: usize,
}

#[derive(Args)]
pub struct PlanningArgs {
    /// Planning grid side, cells (1 m each).
    #[arg(long, default_value_t = 1000)]
    pub side: usize,
    /// Timed repetitions per row.
    #[arg(long, default_value_t = 20)]
    pub runs: usize,
}

#[derive(Args)]
pub struct NavArgs {
    /// Trials (seeds 1..=N, or from --first-seed) per scenario and method.
    #[arg(long, default_value_t = 3)]
    pub trials: usize,
    /// The first trial's seed: spawns apart from an evaluation's 1..=N, to
    /// tune on without touching the trials that judge. Recorded in the
    /// protocol. The training chain's worlds use seeds from 50 (`cargo
    /// xtask train`'s plan), so a seeded scenario there may be one the
    /// shipped models trained on; HIP's worlds are fixed and the seed
    /// draws only the spawn.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..))]
    pub first_seed: u64,
    #[arg(long, value_delimiter = ',', default_values_t = ["bug-trap".to_string(), "bridge".to_string(), "bush-wall".to_string(), "road-forest".to_string(), "obstacle-field-1".to_string(), "obstacle-field-3".to_string()])]
    pub scenarios: Vec<String>,
    /// Methods to run (default: all).
    #[arg(long, value_delimiter = ',')]
    pub methods: Vec<String>,
    /// Graph files to run instead of the shipped methods (a row per file,
    /// named by its stem).
    #[arg(long, value_delimiter = ',')]
    pub graphs: Vec<std::path::PathBuf>,
    /// A trial may take this many times the expert's time on its world,
    /// start and goal (A* over the true world, each cell at the speed the
    /// robot may drive there).
    #[arg(long, default_value_t = 3.0)]
    pub time_limit_x: f64,
    /// An absolute limit on a trial's simulated seconds, below the
    /// expert-relative one (and the limit when there is no expert path).
    #[arg(long)]
    pub max_time_s: Option<f64>,
    /// When an operator steps in: `carry-back` (stuck in place: carried 3 m
    /// back along the track) or `operator` (LRN section IV: no progress by
    /// the expert's cost to go for 20 s: turned to face the goal; 20 s more:
    /// walked toward it). Recorded in the protocol.
    #[arg(long, default_value = "carry-back", value_parser = farsight_sim::episode::InterventionRule::named)]
    pub intervention_rule: farsight_sim::episode::InterventionRule,
    /// Standard deviation of the noise on the pose the stack is told (m),
    /// seeded per trial: localisation error, and what makes repeated
    /// trials of a layout that no seed changes (bug-trap, bridge) differ,
    /// as a real robot's repeated runs do. Recorded in the protocol.
    #[arg(long, default_value_t = 0.0)]
    pub pose_noise_m: f64,
    /// The same for the heading (degrees).
    #[arg(long, default_value_t = 0.0)]
    pub yaw_noise_deg: f64,
    /// The simulated robot's disc footprint (m); 0.25 is a Clearpath Jackal
    /// (0.43 m wide), POVNav section 5's robot. Recorded in the protocol.
    #[arg(long, default_value_t = farsight_sim::robot::RobotLimits::default().radius_m)]
    pub robot_radius_m: f64,
    /// What the near-field sensor reports: `true-cost`, or
    /// `height-threshold` (HIP's geometric costmap, which errs: tall grass
    /// looks lethal, shrubs and stones free). Recorded in the protocol.
    #[arg(long, default_value = "true-cost", value_parser = farsight_sim::run::parse_near_field)]
    pub near_field: farsight_sim::sensor::CostModel,
    /// Write each trial's poses (`<scenario>-<method>-<seed>.csv`, as
    /// `farsight-sim run` writes `poses.csv`) into this folder, and a
    /// top-down picture of each trial that did not reach the goal or needed
    /// an intervention (`<scenario>-<method>-<seed>.png`).
    #[arg(long)]
    pub trace: Option<std::path::PathBuf>,
    /// Run only the K-th of N parts of the trial list (scenario x method x
    /// seed; trial i is in part (i mod N) + 1), e.g. one per array job.
    #[arg(long)]
    pub shard: Option<crate::bench_record::Shard>,
    /// Write the results (commit, versions, protocol hash, shard, each
    /// trial's summary) to this JSON file, rewritten after every trial.
    #[arg(long)]
    pub out: Option<std::path::PathBuf>,
    /// Print each method and the graph file it runs (tab-separated), run nothing.
    #[arg(long)]
    pub list: bool,
    /// Trials run side by side (default: the machine's cores). Each trial is
    /// seeded and alone in its simulator and graph, so the results are the
    /// same for any number; only the wall time changes.
    #[arg(long)]
    pub jobs: Option<usize>,
}

pub fn run(cmd: BenchCommand) -> Result<()> {
    match cmd {
        BenchCommand::Nav(a) => crate::bench_nav::run(a),
        BenchCommand::Fitam(a) => crate::bench_fitam::run(a),
        BenchCommand::FitamMerge(a) => crate::bench_fitam::run_merge(a),
        BenchCommand::NavMerge(a) => crate::bench_record::run_merge(a),
        BenchCommand::Recorder(a) => crate::bench_recorder::run(a),
        BenchCommand::E2e(a) => crate::bench_e2e::run(a),
        BenchCommand::Planning(a) => crate::bench_planning::run(a),
        BenchCommand::Navigation(a) => crate::bench_navigation::run(a),
        BenchCommand::Transport(a) => transport(a),
        BenchCommand::Inference(a) => crate::bench_inference::run(a),
        BenchCommand::TransportReceiver(a) => receiver(a),
    }
}

fn topic() -> ImageTopic {
    Topic::new("bench/transport").expect("valid name")
}

fn now_ns() -> u64 {
    WallClock.now_ns()
}

/// Median and 99th percentile of latencies in nanoseconds.
fn stats(mut v: Vec<u64>) -> (f64, f64) {
    v.sort_unstable();
    let at = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize] as f64;
    (at(0.5), at(0.99))
}

fn human_size(n: usize) -> String {
    match n {
        n if n >= 1 << 20 && n % (1 << 20) == 0 => format!("{} MB", n >> 20),
        n if n >= 1 << 10 && n % (1 << 10) == 0 => format!("{} kB", n >> 10),
        n => format!("{n} B"),
    }
}

struct Receiver {
    child: Child,
    out: BufReader<std::process::ChildStdout>,
}

impl Receiver {
    fn start(kind: Kind, size: usize, count: usize, endpoint: &str) -> Result<Self> {
        let mut child = Command::new(std::env::current_exe()?)
            .args([
                "bench",
                "transport-receiver",
                "--size",
                &size.to_string(),
                "--count",
                &count.to_string(),
            ])
            .args(["--endpoint", endpoint])
            .arg("--kind")
            .arg(kind.to_possible_value().expect("value").get_name())
            .stdout(Stdio::piped())
            .spawn()
            .context("starting the receiver process")?;
        let out = BufReader::new(child.stdout.take().expect("stdout"));
        Ok(Self { child, out })
    }

    fn line(&mut self) -> Result<String> {
        let mut l = String::new();
        self.out.read_line(&mut l)?;
        if l.is_empty() {
            bail!("receiver exited early ({:?})", self.child.wait()?);
        }
        Ok(l.trim().to_string())
    }

    fn wait_ready(&mut self) -> Result<()> {
        let l = self.line()?;
        if l != "ready" {
            bail!("receiver said {l:?} instead of ready");
        }
        Ok(())
    }

    /// `result <median_ns> <p99_ns> <n> <cpu_fraction>`
    fn result(mut self) -> Result<Cell> {
        let l = self.line()?;
        let _ = self.child.wait();
        let parts: Vec<&str> = l.split_whitespace().collect();
        match parts.as_slice() {
            ["result", m, p, n, cpu] => Ok(Cell {
                median_ns: m.parse()?,
                p99_ns: p.parse()?,
                received: n.parse()?,
                receiver_cpu: cpu.parse()?,
            }),
            _ => bail!("unexpected receiver output {l:?}"),
        }
    }
}

/// Pause between messages: long enough that the largest copy finishes and the
/// receiver is idle again, so each message is timed alone.
fn gap(size: usize) -> Duration {
    Duration::from_micros(2000 + (size / 1000) as u64)
}

/// A bus of its own prefix, so benchmark runs never meet.
pub(crate) fn bench_settings(prefix: &str) -> IpcSettings {
    IpcSettings {
        prefix: Some(prefix.to_string()),
        root: None,
        queues: None,
    }
}

/// One cell of the table: latency, how many arrived, and the share of one
/// core the receiver used from ready to done.
#[derive(Debug, Clone, Copy)]
struct Cell {
    median_ns: f64,
    p99_ns: f64,
    received: usize,
    receiver_cpu: f64,
}

/// CPU time this process has used (user + system), seconds.
fn process_cpu_s() -> f64 {
    let mut u = std::mem::MaybeUninit::<libc::rusage>::zeroed();
    // SAFETY: getrusage fills the struct it is given; RUSAGE_SELF is valid.
    let u = unsafe {
        libc::getrusage(libc::RUSAGE_SELF, u.as_mut_ptr());
        u.assume_init()
    };
    let t = |v: libc::timeval| v.tv_sec as f64 + v.tv_usec as f64 * 1e-6;
    t(u.ru_utime) + t(u.ru_stime)
}

type EventPorts = (
    iceoryx2::port::notifier::Notifier<iceoryx2::prelude::ipc::Service>,
    iceoryx2::port::listener::Listener<iceoryx2::prelude::ipc::Service>,
);

/// One side of a raw ping-pong cell: a notifier on event service
/// `<tag>/<notify>` and a listener on `<tag>/<listen>`.
fn event_ports(bus: &Bus, tag: &str, notify: &str, listen: &str) -> Result<EventPorts> {
    let service = |which: &str| -> Result<_> {
        let name = iceoryx2::prelude::ServiceName::new(&format!("{tag}/{which}"))
            .map_err(|e| anyhow::anyhow!("event service name {tag}/{which}: {e:?}"))?;
        bus.node()
            .service_builder(&name)
            .event()
            .open_or_create()
            .map_err(|e| anyhow::anyhow!("event service {tag}/{which}: {e:?}"))
    };
    let notifier = service(notify)?
        .notifier_builder()
        .create()
        .map_err(|e| anyhow::anyhow!("{notify} notifier: {e:?}"))?;
    let listener = service(listen)?
        .listener_builder()
        .create()
        .map_err(|e| anyhow::anyhow!("{listen} listener: {e:?}"))?;
    Ok((notifier, listener))
}

fn send_cell(kind: Kind, size: usize, count: usize) -> Result<Cell> {
    let tag = format!("bench{}_{}_", std::process::id(), now_ns() % 1_000_000);
    match kind {
        Kind::IpcPoll | Kind::IpcWait => {
            let settings = bench_settings(&tag);
            let bus = Bus::open_with("bench-sender", &settings)?;
            let publisher = bus.slice_publisher(&topic(), size)?;
            let mut rx = Receiver::start(kind, size, count, &tag)?;
            rx.wait_ready()?;
            std::thread::sleep(Duration::from_millis(200));
            for i in 0..count + 1 {
                publisher.publish_with(size, |buf| {
                    buf[0] = i as u8;
                    ImageHeader::packed(
                        Stamp::new(i as u64 + 1, now_ns()),
                        0,
                        size as u32,
                        1,
                        PixelEncoding::MONO8,
                    )
                })?;
                std::thread::sleep(gap(size));
            }
            let r = rx.result();
            drop(publisher);
            drop(bus);
            cleanup_shm(&tag);
            r
        }
        Kind::IpcEvent | Kind::IpcEventWait => {
            let settings = bench_settings(&tag);
            let bus = Bus::open_with("bench-pinger", &settings)?;
            let (notifier, listener) = event_ports(&bus, &tag, "ping", "pong")?;
            let mut rx = Receiver::start(kind, size, count, &tag)?;
            rx.wait_ready()?;
            std::thread::sleep(Duration::from_millis(200));
            let mut lat = Vec::with_capacity(count);
            for i in 0..count + 1 {
                let sent = now_ns();
                notifier
                    .notify()
                    .map_err(|e| anyhow::anyhow!("ping: {e:?}"))?;
                let n = listener
                    .timed_wait(|_| {}, Duration::from_secs(5))
                    .map_err(|e| anyhow::anyhow!("waiting for pong: {e:?}"))?;
                if n == 0 {
                    bail!("no pong within 5 s of ping {i}");
                }
                let line = rx.line()?;
                let woke: u64 = line
                    .strip_prefix("woke ")
                    .and_then(|t| t.parse().ok())
                    .with_context(|| format!("ponger said {line:?}, not \"woke <ns>\""))?;
                // The first ping warms up the connection.
                if i > 0 {
                    lat.push(woke.saturating_sub(sent));
                }
                std::thread::sleep(gap(size));
            }
            let mut r = rx.result()?;
            r.received = lat.len();
            (r.median_ns, r.p99_ns) = stats(lat);
            drop((notifier, listener));
            drop(bus);
            cleanup_shm(&tag);
            Ok(r)
        }
        Kind::Zenoh => {
            let port = std::net::TcpListener::bind("127.0.0.1:0")?
                .local_addr()?
                .port();
            let endpoint = format!("tcp/127.0.0.1:{port}");
            let net = NetBus::open(
                NetBus::config("peer", std::slice::from_ref(&endpoint), &[])?,
                "bench",
            )?;
            let publisher = net.bytes_publisher("bench/transport", false)?;
            let mut rx = Receiver::start(kind, size, count, &endpoint)?;
            rx.wait_ready()?;
            // Let the subscription propagate to this peer.
            std::thread::sleep(Duration::from_millis(1500));
            // Send time, then the message's index (the receiver stops at
            // the last even when an early one was lost in propagation).
            let template = vec![7u8; size.max(16)];
            for i in 0..count + 1 {
                let mut msg = template.clone();
                msg[8..16].copy_from_slice(&(i as u64).to_le_bytes());
                msg[..8].copy_from_slice(&now_ns().to_le_bytes());
                publisher.put(msg)?;
                std::thread::sleep(gap(size));
            }
            rx.result()
        }
        Kind::Unix => {
            let path = std::env::temp_dir().join(format!("{tag}.sock"));
            let listener = UnixListener::bind(&path)?;
            let mut rx = Receiver::start(kind, size, count, path.to_str().unwrap_or_default())?;
            let (mut stream, _) = listener.accept()?;
            rx.wait_ready()?;
            let mut msg = vec![7u8; size.max(8)];
            for _ in 0..count + 1 {
                msg[..8].copy_from_slice(&now_ns().to_le_bytes());
                stream.write_all(&msg)?;
                std::thread::sleep(gap(size));
            }
            let r = rx.result();
            let _ = std::fs::remove_file(&path);
            r
        }
    }
}

fn cleanup_shm(prefix: &str) {
    if let Ok(entries) = std::fs::read_dir("/dev/shm") {
        for e in entries.flatten() {
            if e.file_name().to_string_lossy().starts_with(prefix) {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }
}

fn transport(a: TransportArgs) -> Result<()> {
    let kinds = [
        Kind::IpcPoll,
        Kind::IpcWait,
        Kind::IpcEvent,
        Kind::IpcEventWait,
        Kind::Zenoh,
        Kind::Unix,
    ];
    let mut table = Vec::new();
    for &size in &a.sizes {
        let mut row = Vec::new();
        for kind in kinds {
            eprint!(
                "\rmeasuring {:>6} over {:<20}",
                human_size(size),
                kind.label()
            );
            let r = send_cell(kind, size, a.count)
                .with_context(|| format!("{} at {}", kind.label(), human_size(size)))?;
            row.push(r);
        }
        table.push((size, row));
    }
    eprintln!("\r{:60}", "");
    println!("publish -> receive latency, median / p99 in microseconds ({} messages per cell, one run)\n", a.count);
    print!("| size |");
    for k in kinds {
        print!(" {} |", k.label());
    }
    println!("\n|---|{}", "---|".repeat(kinds.len()));
    for (size, row) in &table {
        print!("| {} |", human_size(*size));
        for c in row {
            let note = if c.received < a.count {
                format!(" ({} recv)", c.received)
            } else {
                String::new()
            };
            print!(" {:.1} / {:.1}{note} |", c.median_ns / 1e3, c.p99_ns / 1e3);
        }
        println!();
    }
    let col = |k: Kind| kinds.iter().position(|&x| x == k).expect("a column");
    let (poll, wait, event, event_wait, unix) = (
        col(Kind::IpcPoll),
        col(Kind::IpcWait),
        col(Kind::IpcEvent),
        col(Kind::IpcEventWait),
        col(Kind::Unix),
    );
    println!("\nreceiver CPU while waiting, share of one core (median over sizes):");
    for k in kinds {
        let mut cpu: Vec<f64> = table.iter().map(|(_, r)| r[col(k)].receiver_cpu).collect();
        cpu.sort_by(f64::total_cmp);
        println!("  {:<30} {:>5.1}%", k.label(), 100.0 * cpu[cpu.len() / 2]);
    }
    println!(
        "\nwake-up over the raw event ping, median (goal <= 1.5x): the WaitSet's own wake / a stage's receive"
    );
    for (size, row) in &table {
        let raw = row[event].median_ns.max(1.0);
        println!(
            "  {:>6}: {:.2}x / {:.2}x",
            human_size(*size),
            row[event_wait].median_ns / raw,
            row[wait].median_ns / raw
        );
    }
    if let Some((size, row)) = table.last() {
        println!(
            "\nat {}: unix socket copy / iceoryx2 (poll) median = {:.0}x, / iceoryx2 (WaitSet) = {:.0}x",
            human_size(*size),
            row[unix].median_ns / row[poll].median_ns.max(1.0),
            row[unix].median_ns / row[wait].median_ns.max(1.0)
        );
    }
    Ok(())
}

/// Sleeps on a WaitSet on `listeners` (and a `tick`, so a deadline is
/// checked), running `step` at each wake until it says done or fails.
pub(crate) fn on_each_wake(
    listeners: &[&ipc::InputListener],
    tick: Option<Duration>,
    mut step: impl FnMut() -> Result<bool>,
) -> Result<()> {
    let mut err = None;
    ipc::wait_loop(listeners, tick, |_| match step() {
        Ok(false) => ControlFlow::Continue(()),
        Ok(true) => ControlFlow::Break(()),
        Err(e) => {
            err = Some(e);
            ControlFlow::Break(())
        }
    })?;
    err.map_or(Ok(()), Err)
}

fn receiver(a: ReceiverArgs) -> Result<()> {
    let mut lat = Vec::with_capacity(a.count);
    let out = |s: &str| {
        println!("{s}");
        std::io::stdout().flush().ok();
    };
    // Set when the receiver says ready: the CPU it uses from then on.
    let mut ready_at = None;
    let mut out_ready = || {
        out("ready");
        ready_at = Some((Instant::now(), process_cpu_s()));
    };
    match a.kind {
        Kind::IpcEvent | Kind::IpcEventWait => {
            let settings = bench_settings(&a.endpoint);
            let bus = Bus::open_with("bench-ponger", &settings)?;
            let (notifier, listener) = event_ports(&bus, &a.endpoint, "pong", "ping")?;
            out_ready();
            // When the ping woke this process; the pinger pairs it with when
            // it notified (lock-step: one ping at a time).
            let pong = || -> Result<()> {
                out(&format!("woke {}", now_ns()));
                notifier
                    .notify()
                    .map(drop)
                    .map_err(|e| anyhow::anyhow!("pong: {e:?}"))
            };
            if a.kind == Kind::IpcEvent {
                for _ in 0..a.count + 1 {
                    listener
                        .blocking_wait(|_| {})
                        .map_err(|e| anyhow::anyhow!("waiting for ping: {e:?}"))?;
                    pong()?;
                }
            } else {
                let mut pings = 0;
                on_each_wake(&[&listener], None, || {
                    pong()?;
                    pings += 1;
                    Ok(pings > a.count)
                })?;
            }
            // The pinger holds the latencies; this side reports its CPU.
            lat.push(0);
        }
        Kind::IpcPoll | Kind::IpcWait => {
            let settings = bench_settings(&a.endpoint);
            let bus = Bus::open_with("bench-receiver", &settings)?;
            let sub = bus.slice_subscriber(&topic())?;
            // The history of one may replay the last sample: skip anything already there.
            while sub.latest()?.is_some() {}
            out_ready();
            let deadline = Instant::now() + Duration::from_secs(60);
            // The first message warms up the connection and is not counted.
            // The sender's last is sequence count + 1: a receiver that was
            // off the CPU when some arrived (latest skips to the newest)
            // stops there rather than waiting for the deadline.
            let mut first = true;
            let last_seen = std::cell::Cell::new(false);
            let mut take = |lat: &mut Vec<u64>| -> Result<bool> {
                if let Some(s) = sub.latest()? {
                    let t = now_ns();
                    if !first {
                        lat.push(t.saturating_sub(s.header().stamp.capture_time_ns));
                    }
                    first = false;
                    if s.header().stamp.frame_seq > a.count as u64 {
                        last_seen.set(true);
                    }
                    return Ok(true);
                }
                Ok(false)
            };
            let done = |lat: &Vec<u64>| {
                lat.len() >= a.count || last_seen.get() || Instant::now() > deadline
            };
            if a.kind == Kind::IpcPoll {
                while !done(&lat) {
                    if !take(&mut lat)? {
                        std::hint::spin_loop();
                    }
                }
            } else {
                on_each_wake(&[sub.listener()], Some(Duration::from_millis(100)), || {
                    take(&mut lat)?;
                    Ok(done(&lat))
                })?;
            }
        }
        Kind::Zenoh => {
            let net = NetBus::open(
                NetBus::config("peer", &[], std::slice::from_ref(&a.endpoint))?,
                "bench",
            )?;
            let sub = net.bytes_subscriber("bench/transport")?;
            out_ready();
            let mut first = true;
            let deadline = Instant::now() + Duration::from_secs(60);
            while lat.len() < a.count && Instant::now() < deadline {
                if let Some(msg) = sub.recv_timeout(Duration::from_millis(200))? {
                    let t = now_ns();
                    if msg.len() < 16 {
                        bail!("a {} B message, expected at least 16", msg.len());
                    }
                    let sent = u64::from_le_bytes(msg[..8].try_into()?);
                    let index = u64::from_le_bytes(msg[8..16].try_into()?);
                    if !first {
                        lat.push(t.saturating_sub(sent));
                    }
                    first = false;
                    if index >= a.count as u64 {
                        break;
                    }
                }
            }
        }
        Kind::Unix => {
            let mut stream = UnixStream::connect(&a.endpoint)?;
            out_ready();
            let mut buf = vec![0u8; a.size.max(8)];
            for i in 0..a.count + 1 {
                stream.read_exact(&mut buf)?;
                let t = now_ns();
                if i > 0 {
                    lat.push(t.saturating_sub(u64::from_le_bytes(buf[..8].try_into()?)));
                }
            }
        }
    }
    if lat.is_empty() {
        bail!("no messages received");
    }
    let n = lat.len();
    let (m, p) = stats(lat);
    let cpu = ready_at.map_or(0.0, |(t0, c0)| {
        (process_cpu_s() - c0) / t0.elapsed().as_secs_f64().max(1e-9)
    });
    out(&format!("result {m} {p} {n} {cpu}"));
    Ok(())
}
