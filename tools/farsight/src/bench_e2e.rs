//! `farsight bench e2e` (issue 21 item 4): a chain as the robot runs it,
//! every stage its own process (`farsight demo`, in a shared-memory
//! namespace of its own), timed from each frame's ingest to when each topic
//! on the path carries it: per hop and capture-to-command, median and p99,
//! beside the inference stage's phases alone. And each stage's private and
//! shared memory ([`crate::memory`]). Two chains:
//!
//! - POVNav, `graphs/orfd.toml` on the real ORFD frames
//!   (`farsight demo --orfd --loops 0`): timed from each frame's capture
//!   time, which is its ingest time (camera-ingest stamps replayed frames
//!   as they go out);
//! - FITAM, `graphs/sim/fitam.toml` in the simulator, lock-step
//!   (`farsight demo --graph`): simulated time is on the stamps, so each
//!   frame is timed from when the tap saw the simulator publish it.
//!
//! The tap is one more subscriber asleep on a WaitSet on every topic of
//! the path; it reads the clock as it wakes and each message's stamp in
//! shared memory, copying nothing out.
//! A frame is counted on a topic the first time a message carrying its
//! sequence number arrives there: the servo republishes its last command
//! at its own rate, and only the first one is the frame's.

use crate::memory::{self, ProcessMemory};
use anyhow::{bail, Context, Result};
use farsight_inference::model_config::ModelConfig;
use farsight_interfaces::clock::{Clock, WallClock};
use farsight_interfaces::message::Message;
use farsight_interfaces::msg::ImageHeader;
use farsight_interfaces::topics;
use farsight_interfaces::transport::any::AnySubscriber;
use farsight_interfaces::transport::ipc::Bus;
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

#[derive(Debug, clap::Args)]
pub struct E2eArgs {
    /// Seconds of measurement, after the first command and a warm-up (longer
    /// where no measured frame has reached the path's end by then).
    #[arg(long, default_value_t = 30.0)]
    pub seconds: f64,
    /// Seconds after the first command before measuring.
    #[arg(long, default_value_t = 5.0)]
    pub warm_up_s: f64,
    /// Frames for the inference-alone row.
    #[arg(long, default_value_t = 20)]
    pub inference_runs: usize,
    /// The demo's output folder (configs, logs, recording).
    #[arg(long, default_value = "out/bench-e2e")]
    pub out: PathBuf,
    /// Which chain to run.
    #[arg(long, value_enum, default_value = "povnav-orfd")]
    pub chain: Chain,
    /// fitam-sim: the simulator's scenario (the default is a long drive,
    /// so the graph is still running when the measurement ends).
    #[arg(long, default_value = "road-forest")]
    pub scenario: String,
}

/// The chains `bench e2e` runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Chain {
    /// graphs/orfd.toml on the ORFD frames: camera -> TwinLiteNet -> POVNav -> servo.
    PovnavOrfd,
    /// graphs/sim/fitam.toml in the simulator, lock-step: camera -> FITAM far
    /// field -> polar bins -> Kalman fusion -> D* Lite path -> servo.
    FitamSim,
}

impl Chain {
    fn graph(self) -> &'static str {
        match self {
            Chain::PovnavOrfd => "graphs/orfd.toml",
            Chain::FitamSim => "graphs/sim/fitam.toml",
        }
    }

    /// The path of a frame, in order, with the stage that produced each topic.
    fn path(self) -> &'static [(&'static str, &'static str)] {
        match self {
            Chain::PovnavOrfd => &[
                ("camera/front/image", "camera-ingest"),
                ("perception/front/navigability", "inference"),
                ("nav/subgoal", "subgoal-selection"),
                ("cmd/velocity", "velocity-servoing"),
            ],
            Chain::FitamSim => &[
                ("camera/front/image", "farsight-sim"),
                ("perception/front/far_field", "inference"),
                ("bins/polar", "bin-projection"),
                ("costmap/fused", "costmap-fusion"),
                ("nav/path/planned", "subgoal-selection"),
                ("cmd/velocity", "velocity-servoing"),
            ],
        }
    }

    /// Whether frames carry their ingest time as capture time (the wall
    /// clock), or simulated time (then the tap's first sight is the ingest).
    fn stamps_are_ingest_time(self) -> bool {
        self == Chain::PovnavOrfd
    }
}

/// Per topic, per frame sequence: when it first arrived, ms after capture.
type Arrivals = Vec<BTreeMap<u64, f64>>;

fn quantile(v: &mut [f64], q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

pub fn run(a: E2eArgs) -> Result<()> {
    let graph = crate::graph::repo_file(a.chain.graph())?;
    let graph_text = std::fs::read_to_string(&graph)?;
    let doc: toml::Value = toml::from_str(&graph_text)?;
    let node = |name: &str| {
        doc.get("node")
            .and_then(|n| n.as_array())
            .and_then(|n| {
                n.iter()
                    .find(|v| v.get("name").and_then(|s| s.as_str()) == Some(name))
            })
            .and_then(|v| v.get("config"))
            .cloned()
    };
    let shown = a.chain.graph();
    let model_config = node("inference")
        .and_then(|c| c.get("model_config")?.as_str().map(str::to_string))
        .with_context(|| format!("{shown}: the inference node names no model_config"))?;
    let servo = node("velocity-servoing");
    let servo_timing = ServoTiming {
        // A key the graph leaves out has the stage's default.
        rate_hz: servo
            .as_ref()
            .and_then(|c| c.get("output_rate_hz")?.as_float())
            .unwrap_or(
                farsight_velocity_servoing::stage::ServoStageConfig::default().output_rate_hz,
            ),
        on_input: servo
            .as_ref()
            .and_then(|c| c.get("command_on_input")?.as_bool())
            .unwrap_or(false),
        on_stamps: servo
            .as_ref()
            .and_then(|c| c.get("clock")?.as_str().map(|c| c == "stamps"))
            .unwrap_or(false),
    };
    let graph_dir = graph.parent().unwrap_or(std::path::Path::new("."));
    let model = ModelConfig::load(&graph_dir.join(&model_config))?;
    let alone = match a.chain {
        Chain::PovnavOrfd => {
            let frames_folder = node("camera-ingest")
                .and_then(|c| {
                    c.get("cameras")?
                        .get(0)?
                        .get("folder")?
                        .as_str()
                        .map(str::to_string)
                })
                .with_context(|| format!("{shown}: camera-ingest names no frame folder"))?;
            eprintln!("inference alone: {} frames ...", a.inference_runs);
            Some(crate::bench_inference::phase_medians(
                &model,
                &graph_dir.join(frames_folder),
                a.inference_runs,
            )?)
        }
        // Timed on the frames the tap copies from the run.
        Chain::FitamSim => None,
    };

    let prefix = format!("benche2e{}_", std::process::id());
    std::fs::create_dir_all(&a.out)?;
    let log = std::fs::File::create(a.out.join("demo.log"))?;
    let mut demo = Command::new(std::env::current_exe()?);
    match a.chain {
        Chain::PovnavOrfd => demo.args(["demo", "--orfd", "--loops", "0"]),
        // Long enough to outlast the measurement; lock-step, so a busy
        // machine slows the simulated clock, it is never late.
        Chain::FitamSim => demo
            .args(["demo", "--graph"])
            .arg(&graph)
            .args(["--scenario", &a.scenario, "--max-time-s", "100000"])
            .args(["--command-timeout-s", "120"]),
    };
    eprintln!(
        "starting the graph (farsight demo, {shown}, its errors in {}) ...",
        a.out.join("demo.log").display()
    );
    let mut demo = demo
        .arg("--out")
        .arg(&a.out)
        .env("FARSIGHT_IPC_PREFIX", &prefix)
        .stdout(Stdio::null())
        .stderr(log)
        .stdin(Stdio::null())
        .spawn()
        .context("starting farsight demo")?;
    let result = measure(&a, &prefix);
    // SIGINT, as Ctrl-C: the demo stops its graph and exits.
    // SAFETY: kill(2) on our own child's pid.
    unsafe { libc::kill(demo.id() as libc::pid_t, libc::SIGINT) };
    let deadline = Instant::now() + Duration::from_secs(30);
    while demo.try_wait()?.is_none() && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(100));
    }
    if demo.try_wait()?.is_none() {
        let _ = demo.kill();
        let _ = demo.wait();
    }
    let m = result?;
    let alone = match alone {
        Some(alone) => alone,
        None => {
            eprintln!(
                "inference alone: {} runs on {} frames of the run ...",
                a.inference_runs,
                m.frames.len()
            );
            crate::bench_inference::phase_medians_on(&model, &m.frames, a.inference_runs)?
        }
    };
    print_report(a.chain, &m, &alone, servo_timing);
    Ok(())
}

/// What the tap saw.
struct Measured {
    arrivals: Arrivals,
    memory: BTreeMap<String, ProcessMemory>,
    span_s: f64,
    /// The first frames of the path's first topic, copied (only where the
    /// inference-alone row needs them: the simulator's frames).
    frames: Vec<(ImageHeader, Vec<u8>)>,
}

/// Taps the path until `seconds` of frames have passed through it.
fn measure(a: &E2eArgs, prefix: &str) -> Result<Measured> {
    let path = a.chain.path();
    let bus = Bus::open_with("bench-e2e", &crate::bench::bench_settings(prefix))?;
    // Stamps read in shared memory: the tap copies no frame out, so it
    // takes no CPU from the stages it times.
    let subs: Vec<AnySubscriber> = path
        .iter()
        .map(|(t, _)| AnySubscriber::open(&bus, t))
        .collect::<Result<_, _>>()?;
    let health: Vec<_> = path
        .iter()
        .filter(|(_, s)| *s != "farsight-sim")
        .map(|(_, s)| bus.subscriber(&topics::health(s)))
        .collect::<Result<_, _>>()?;
    let listeners: Vec<_> = subs.iter().map(AnySubscriber::listener).collect();
    let copy_frames = !a.chain.stamps_are_ingest_time();
    let mut frames = Vec::new();
    let mut arrivals: Arrivals = vec![BTreeMap::new(); path.len()];
    // Per frame: its ingest time on the wall clock.
    let mut ingest_ns: BTreeMap<u64, u64> = BTreeMap::new();
    let mut pids: BTreeMap<String, u32> = BTreeMap::new();
    let started = Instant::now();
    let mut first_command: Option<Instant> = None;
    let mut last_command = Instant::now();
    let mut measuring_since: Option<(Instant, u64)> = None;
    let mut newest_frame = 0u64;
    let mut ended = false;
    // The stages' memory as measuring starts, in case the run ends (and
    // its processes with it) before the measurement does.
    let mut memory_at_start = BTreeMap::new();
    crate::bench::on_each_wake(&listeners, Some(Duration::from_millis(100)), || {
        let now_ns = WallClock.now_ns();
        for (k, sub) in subs.iter().enumerate() {
            let stamp = if k == 0 && copy_frames && frames.len() < a.inference_runs.max(1) {
                match sub.take_message()? {
                    Some(Message::Image(m)) => {
                        let stamp = m.header.stamp;
                        frames.push((m.header, m.data));
                        Some(stamp)
                    }
                    _ => None,
                }
            } else {
                sub.take_stamp()?
            };
            let Some(stamp) = stamp else { continue };
            if k == 0 {
                newest_frame = newest_frame.max(stamp.frame_seq);
                let ingest = if copy_frames {
                    now_ns
                } else {
                    stamp.capture_time_ns
                };
                ingest_ns.entry(stamp.frame_seq).or_insert(ingest);
            }
            // A command answering no frame (the servo's stop while its
            // input is starved, stamped frame 0) is neither the first
            // answer nor a sign the run goes on.
            if k == path.len() - 1 && stamp.frame_seq > 0 {
                last_command = Instant::now();
                if first_command.is_none() {
                    first_command = Some(Instant::now());
                    eprintln!("first command; warming up {} s ...", a.warm_up_s);
                }
            }
            if let Some((_, first_seq)) = measuring_since {
                if let (true, Some(&t0)) = (
                    stamp.frame_seq >= first_seq,
                    ingest_ns.get(&stamp.frame_seq),
                ) {
                    let ms = now_ns.saturating_sub(t0) as f64 * 1e-6;
                    arrivals[k].entry(stamp.frame_seq).or_insert(ms);
                }
            }
        }
        for h in &health {
            if let Some(h) = h.latest()? {
                pids.insert(h.stage.as_str().to_string(), h.pid);
            }
        }
        match (first_command, measuring_since) {
            (Some(t), None) if t.elapsed().as_secs_f64() >= a.warm_up_s => {
                // Frames ingested from here on are the measured ones.
                measuring_since = Some((Instant::now(), newest_frame + 1));
                memory_at_start = read_memory(&pids);
                eprintln!("measuring {} s ...", a.seconds);
            }
            // Paced on answers too: on a busy machine one frame can take
            // longer than the window, so it stays open until a measured
            // frame has reached the path's end.
            (_, Some((t, _)))
                if t.elapsed().as_secs_f64() >= a.seconds
                    && !arrivals[path.len() - 1].is_empty() =>
            {
                return Ok(true)
            }
            (_, Some((t, _))) if t.elapsed().as_secs_f64() >= a.seconds + 300.0 => bail!(
                "no measured frame reached {} in {:.0} s of measuring (see its demo.log)",
                path[path.len() - 1].0,
                t.elapsed().as_secs_f64()
            ),
            // The run ended (a simulated drive reached its goal).
            (_, Some(_)) if last_command.elapsed() > Duration::from_secs(20) => {
                eprintln!("no command for 20 s: the run ended; reporting what was measured");
                ended = true;
                return Ok(true);
            }
            (None, _) if started.elapsed() > Duration::from_secs(300) => {
                bail!("no command within 300 s of starting the graph (see its demo.log)")
            }
            _ => {}
        }
        Ok(false)
    })?;
    // Health goes out once a second: a short run may end before every
    // stage's first report has reached the tap.
    let until = Instant::now() + Duration::from_secs(5);
    while pids.len() < health.len() && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(100));
        for h in &health {
            if let Some(h) = h.latest()? {
                pids.insert(h.stage.as_str().to_string(), h.pid);
            }
        }
    }
    let mut memory = read_memory(&pids);
    if memory.len() < memory_at_start.len() {
        memory = memory_at_start;
    }
    // A run that ended measured until its last command.
    let span_s = measuring_since.map_or(0.0, |(t, _)| {
        let end = if ended { last_command } else { Instant::now() };
        end.saturating_duration_since(t).as_secs_f64()
    });
    if arrivals[path.len() - 1].is_empty() {
        bail!("no frame reached cmd/velocity while measuring");
    }
    Ok(Measured {
        arrivals,
        memory,
        span_s,
        frames,
    })
}

/// Each stage's memory, by the pid its health reports.
fn read_memory(pids: &BTreeMap<String, u32>) -> BTreeMap<String, ProcessMemory> {
    pids.iter()
        .filter_map(|(s, &pid)| memory::of_pid(pid).map(|m| (s.clone(), m)))
        .collect()
}

/// How the graph's servo publishes: the tick alone (rate-limited) or a
/// command on each new subgoal too (`command_on_input`).
#[derive(Debug, Clone, Copy)]
struct ServoTiming {
    rate_hz: f64,
    on_input: bool,
    /// On the stamps' clock: one command per subgoal or path, at once.
    on_stamps: bool,
}

impl ServoTiming {
    fn describe(&self, chain: Chain) -> String {
        if self.on_stamps {
            let stages: Vec<&str> = chain.path().iter().skip(1).map(|(_, s)| *s).collect();
            return format!(
                "event-driven: {} (clock = \"stamps\": each answers its input at once; the simulator waits for each command)",
                stages.join(", ")
            );
        }
        let stages = "camera-ingest (paced by the navigability), inference, subgoal-selection";
        let tick = format!("{} Hz", self.rate_hz);
        if self.on_input {
            format!("event-driven: {stages}, velocity-servoing (a command on each new subgoal; its {tick} tick goes on and judges staleness)")
        } else {
            format!("event-driven: {stages}; rate-limited: velocity-servoing ({tick}: a subgoal waits up to {:.0} ms for the next tick)", 1000.0 / self.rate_hz)
        }
    }
}

fn print_report(
    chain: Chain,
    m: &Measured,
    alone: &crate::bench_inference::PhaseMedians,
    servo: ServoTiming,
) {
    let (path, arrivals) = (chain.path(), &m.arrivals);
    let commands = arrivals[path.len() - 1].len();
    let source = match chain {
        Chain::PovnavOrfd => "on the ORFD frames",
        Chain::FitamSim => "in the simulator, lock-step,",
    };
    println!(
        "end to end: {} as processes {source} ({}x{}), {:.0} s, {} frames to a command, one run\n",
        chain.graph(),
        alone.frame.0,
        alone.frame.1,
        m.span_s,
        commands
    );
    println!("| from ingest to | produced by | frames | median ms | p99 ms |");
    println!("|---|---|---|---|---|");
    for (k, (topic, stage)) in path.iter().enumerate() {
        let mut v: Vec<f64> = arrivals[k].values().copied().collect();
        if v.is_empty() {
            println!("| {topic} | {stage} | 0 | - | - |");
            continue;
        }
        let n = v.len();
        println!(
            "| {topic} | {stage} | {n} | {:.1} | {:.1} |",
            quantile(&mut v, 0.5),
            quantile(&mut v, 0.99)
        );
    }
    println!("\n| hop | frames | median ms | p99 ms |");
    println!("|---|---|---|---|");
    for k in 1..path.len() {
        let mut v: Vec<f64> = arrivals[k]
            .iter()
            .filter_map(|(seq, t)| arrivals[k - 1].get(seq).map(|t0| t - t0))
            .collect();
        if v.is_empty() {
            continue;
        }
        let n = v.len();
        println!(
            "| {} -> {} ({}) | {n} | {:.1} | {:.1} |",
            path[k - 1].0,
            path[k].0,
            path[k].1,
            quantile(&mut v, 0.5),
            quantile(&mut v, 0.99)
        );
    }
    let total = alone.pre_ms + alone.inference_ms + alone.post_ms;
    println!(
        "\ninference alone (same model and frames, no graph): pre {:.1} + inference {:.1} + post {:.1} = {:.1} ms (median)",
        alone.pre_ms, alone.inference_ms, alone.post_ms, total
    );
    let mut c2c: Vec<f64> = arrivals[path.len() - 1].values().copied().collect();
    let c2c = quantile(&mut c2c, 0.5);
    println!(
        "capture-to-command median {:.1} ms = inference alone + {:.1} ms (goal: + 2 ms where every stage on the path is event-driven)",
        c2c,
        c2c - total
    );
    println!("{}", servo.describe(chain));
    if !m.memory.is_empty() {
        println!("\n| stage | private MB | shared memory MB |");
        println!("|---|---|---|");
        for (s, m) in &m.memory {
            println!(
                "| {s} | {:.1} | {:.1} |",
                memory::mb(m.private_bytes),
                memory::mb(m.shared_memory_bytes)
            );
        }
    }
}
