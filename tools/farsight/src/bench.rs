//! `farsight bench transport`: publish-to-receive latency of one message, for
//! several sizes, over iceoryx2 zero-copy, zenoh on loopback TCP and a plain
//! Unix-socket copy, measured in one run and printed as a table.
//!
//! Each cell uses two processes: this one publishes, a child receives. The send
//! time is taken when the payload is complete, right before it is handed to the
//! transport; the receive time when the receiver holds the whole message (for
//! iceoryx2: a reference into shared memory, nothing copied). Both processes
//! read the same system clock.

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
    /// Trials (seeds 1..=N) per scenario and method.
    #[arg(long, default_value_t = 3)]
    pub trials: usize,
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
}

pub fn run(cmd: BenchCommand) -> Result<()> {
    match cmd {
        BenchCommand::Nav(a) => crate::bench_nav::run(a),
        BenchCommand::Fitam(a) => crate::bench_fitam::run(a),
        BenchCommand::FitamMerge(a) => crate::bench_fitam::run_merge(a),
        BenchCommand::NavMerge(a) => crate::bench_record::run_merge(a),
        BenchCommand::Recorder(a) => crate::bench_recorder::run(a),
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

    /// `result <median_ns> <p99_ns> <n>`
    fn result(mut self) -> Result<(f64, f64, usize)> {
        let l = self.line()?;
        let _ = self.child.wait();
        let parts: Vec<&str> = l.split_whitespace().collect();
        match parts.as_slice() {
            ["result", m, p, n] => Ok((m.parse()?, p.parse()?, n.parse()?)),
            _ => bail!("unexpected receiver output {l:?}"),
        }
    }
}

/// Pause between messages: long enough that the largest copy finishes and the
/// receiver is idle again, so each message is timed alone.
fn gap(size: usize) -> Duration {
    Duration::from_micros(2000 + (size / 1000) as u64)
}

fn send_cell(kind: Kind, size: usize, count: usize) -> Result<(f64, f64, usize)> {
    let tag = format!("bench{}_{}_", std::process::id(), now_ns() % 1_000_000);
    match kind {
        Kind::IpcPoll | Kind::IpcWait => {
            let settings = IpcSettings {
                prefix: Some(tag.clone()),
                root: None,
                queues: None,
            };
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
            let template = vec![7u8; size.max(8)];
            for _ in 0..count + 1 {
                let mut msg = template.clone();
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
    let kinds = [Kind::IpcPoll, Kind::IpcWait, Kind::Zenoh, Kind::Unix];
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
        for (m, p, n) in row {
            let note = if *n < a.count {
                format!(" ({n} recv)")
            } else {
                String::new()
            };
            print!(" {:.1} / {:.1}{note} |", m / 1e3, p / 1e3);
        }
        println!();
    }
    if let Some((size, row)) = table.last() {
        println!(
            "\nat {}: unix socket copy / iceoryx2 (poll) median = {:.0}x, / iceoryx2 (WaitSet) = {:.0}x",
            human_size(*size),
            row[3].0 / row[0].0.max(1.0),
            row[3].0 / row[1].0.max(1.0)
        );
    }
    Ok(())
}

fn receiver(a: ReceiverArgs) -> Result<()> {
    let mut lat = Vec::with_capacity(a.count);
    let out = |s: &str| {
        println!("{s}");
        std::io::stdout().flush().ok();
    };
    match a.kind {
        Kind::IpcPoll | Kind::IpcWait => {
            let settings = IpcSettings {
                prefix: Some(a.endpoint.clone()),
                root: None,
                queues: None,
            };
            let bus = Bus::open_with("bench-receiver", &settings)?;
            let sub = bus.slice_subscriber(&topic())?;
            // The history of one may replay the last sample: skip anything already there.
            while sub.latest()?.is_some() {}
            out("ready");
            let deadline = Instant::now() + Duration::from_secs(60);
            // The first message warms up the connection and is not counted.
            let mut first = true;
            let mut take = |lat: &mut Vec<u64>| -> Result<bool> {
                if let Some(s) = sub.latest()? {
                    let t = now_ns();
                    if !first {
                        lat.push(t.saturating_sub(s.header().stamp.capture_time_ns));
                    }
                    first = false;
                    return Ok(true);
                }
                Ok(false)
            };
            if a.kind == Kind::IpcPoll {
                while lat.len() < a.count && Instant::now() < deadline {
                    if !take(&mut lat)? {
                        std::hint::spin_loop();
                    }
                }
            } else {
                let mut err = None;
                ipc::wait_loop(&[sub.listener()], Some(Duration::from_millis(100)), |_| {
                    if let Err(e) = take(&mut lat) {
                        err = Some(e);
                        return ControlFlow::Break(());
                    }
                    if lat.len() >= a.count || Instant::now() > deadline {
                        ControlFlow::Break(())
                    } else {
                        ControlFlow::Continue(())
                    }
                })?;
                if let Some(e) = err {
                    return Err(e);
                }
            }
        }
        Kind::Zenoh => {
            let net = NetBus::open(
                NetBus::config("peer", &[], std::slice::from_ref(&a.endpoint))?,
                "bench",
            )?;
            let sub = net.bytes_subscriber("bench/transport")?;
            out("ready");
            let mut first = true;
            let deadline = Instant::now() + Duration::from_secs(60);
            while lat.len() < a.count && Instant::now() < deadline {
                if let Some(msg) = sub.recv_timeout(Duration::from_millis(200))? {
                    let t = now_ns();
                    let sent = u64::from_le_bytes(msg[..8].try_into()?);
                    if !first {
                        lat.push(t.saturating_sub(sent));
                    }
                    first = false;
                }
            }
        }
        Kind::Unix => {
            let mut stream = UnixStream::connect(&a.endpoint)?;
            out("ready");
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
    out(&format!("result {m} {p} {n}"));
    Ok(())
}
