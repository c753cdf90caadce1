//! `farsight bench e2e` (issue 21 item 4, first part): the POVNav chain of
//! `graphs/orfd.toml` as the robot runs it, every stage its own process
//! (`farsight demo --orfd --loops 0`, in a shared-memory namespace of its
//! own), on the real ORFD frames, timed from each frame's capture time (the
//! ingest time: camera-ingest stamps replayed frames as they go out) to
//! when each topic on the path carries it: per hop and capture-to-command,
//! median and p99, beside the inference stage's phases alone. And each
//! stage's private and shared memory ([`crate::memory`]).
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
use farsight_interfaces::msg::Stamp;
use farsight_interfaces::topics;
use farsight_interfaces::transport::ipc::Bus;
use farsight_interfaces::transport::Stamped;
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

#[derive(Debug, clap::Args)]
pub struct E2eArgs {
    /// Seconds of measurement, after the first command and a warm-up.
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
}

const CAMERA: &str = "front";

/// The path of a frame, in order, with the stage that produced each topic.
const PATH: [(&str, &str); 4] = [
    ("camera/front/image", "camera-ingest"),
    ("perception/front/navigability", "inference"),
    ("nav/subgoal", "subgoal-selection"),
    ("cmd/velocity", "velocity-servoing"),
];

/// Per topic, per frame sequence: when it first arrived, ms after capture.
type Arrivals = Vec<BTreeMap<u64, f64>>;

fn quantile(v: &mut [f64], q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

pub fn run(a: E2eArgs) -> Result<()> {
    let graph = crate::graph::repo_file("graphs/orfd.toml")?;
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
    let model_config = node("inference")
        .and_then(|c| c.get("model_config")?.as_str().map(str::to_string))
        .context("graphs/orfd.toml: the inference node names no model_config")?;
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
    };
    let frames_folder = node("camera-ingest")
        .and_then(|c| {
            c.get("cameras")?
                .get(0)?
                .get("folder")?
                .as_str()
                .map(str::to_string)
        })
        .context("graphs/orfd.toml: camera-ingest names no frame folder")?;
    let graph_dir = graph.parent().unwrap_or(std::path::Path::new("."));
    let frames = graph_dir.join(frames_folder);
    eprintln!("inference alone: {} frames ...", a.inference_runs);
    let model_path = graph_dir.join(&model_config);
    let alone = crate::bench_inference::phase_medians(
        &ModelConfig::load(&model_path)?,
        &frames,
        a.inference_runs,
    )?;

    let prefix = format!("benche2e{}_", std::process::id());
    std::fs::create_dir_all(&a.out)?;
    let log = std::fs::File::create(a.out.join("demo.log"))?;
    eprintln!(
        "starting the graph (farsight demo --orfd --loops 0, its errors in {}) ...",
        a.out.join("demo.log").display()
    );
    let mut demo = Command::new(std::env::current_exe()?)
        .args(["demo", "--orfd", "--loops", "0", "--out"])
        .arg(&a.out)
        .env("FARSIGHT_IPC_PREFIX", &prefix)
        .stdout(Stdio::null())
        .stderr(log)
        .stdin(Stdio::null())
        .spawn()
        .context("starting farsight demo --orfd")?;
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
    let (arrivals, memory, span_s) = result?;
    print_report(&arrivals, &memory, span_s, &alone, servo_timing);
    Ok(())
}

/// Taps the path until `seconds` of frames have passed through it.
fn measure(a: &E2eArgs, prefix: &str) -> Result<(Arrivals, BTreeMap<String, ProcessMemory>, f64)> {
    let bus = Bus::open_with("bench-e2e", &crate::bench::bench_settings(prefix))?;
    // Typed ports, read in place: the tap copies no frame out of shared
    // memory, so it takes no CPU from the stages it times.
    let image = bus.slice_subscriber(&topics::camera_image(CAMERA))?;
    let navigability = bus.slice_subscriber(&topics::navigability(CAMERA))?;
    let subgoal = bus.subscriber(&topics::subgoal())?;
    let command = bus.subscriber(&topics::velocity_command())?;
    debug_assert_eq!(
        [
            image.topic(),
            navigability.topic(),
            subgoal.topic(),
            command.topic()
        ],
        PATH.map(|(t, _)| t)
    );
    let newest_stamps = || -> Result<[Option<Stamp>; 4]> {
        Ok([
            image.latest()?.map(|s| s.header().stamp),
            navigability.latest()?.map(|s| s.header().stamp),
            subgoal.latest()?.map(|m| m.stamp()),
            command.latest()?.map(|m| m.stamp()),
        ])
    };
    let health: Vec<_> = PATH
        .iter()
        .map(|(_, s)| bus.subscriber(&topics::health(s)))
        .collect::<Result<_, _>>()?;
    let listeners = [
        image.listener(),
        navigability.listener(),
        subgoal.listener(),
        command.listener(),
    ];
    let mut arrivals: Arrivals = vec![BTreeMap::new(); PATH.len()];
    let mut pids: BTreeMap<String, u32> = BTreeMap::new();
    let started = Instant::now();
    let mut first_command: Option<Instant> = None;
    let mut measuring_since: Option<(Instant, u64)> = None;
    let mut newest_frame = 0u64;
    crate::bench::on_each_wake(&listeners, Some(Duration::from_millis(100)), || {
        let now_ns = WallClock.now_ns();
        for (k, stamp) in newest_stamps()?.into_iter().enumerate() {
            if let Some(stamp) = stamp {
                let ms = now_ns.saturating_sub(stamp.capture_time_ns) as f64 * 1e-6;
                if k == 0 {
                    newest_frame = newest_frame.max(stamp.frame_seq);
                }
                if k == PATH.len() - 1 && first_command.is_none() {
                    first_command = Some(Instant::now());
                    eprintln!("first command; warming up {} s ...", a.warm_up_s);
                }
                if let Some((_, first_seq)) = measuring_since {
                    if stamp.frame_seq >= first_seq {
                        arrivals[k].entry(stamp.frame_seq).or_insert(ms);
                    }
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
                // Frames captured from here on are the measured ones.
                measuring_since = Some((Instant::now(), newest_frame + 1));
                eprintln!("measuring {} s ...", a.seconds);
            }
            (_, Some((t, _))) if t.elapsed().as_secs_f64() >= a.seconds => return Ok(true),
            (None, _) if started.elapsed() > Duration::from_secs(300) => {
                bail!("no command within 300 s of starting the graph (see its demo.log)")
            }
            _ => {}
        }
        Ok(false)
    })?;
    let memory = pids
        .iter()
        .filter_map(|(s, &pid)| memory::of_pid(pid).map(|m| (s.clone(), m)))
        .collect();
    let span = measuring_since.map_or(0.0, |(t, _)| t.elapsed().as_secs_f64());
    if arrivals[PATH.len() - 1].is_empty() {
        bail!("no frame reached cmd/velocity while measuring");
    }
    Ok((arrivals, memory, span))
}

/// How the graph's servo publishes: the tick alone (rate-limited) or a
/// command on each new subgoal too (`command_on_input`).
#[derive(Debug, Clone, Copy)]
struct ServoTiming {
    rate_hz: f64,
    on_input: bool,
}

impl ServoTiming {
    fn describe(&self) -> String {
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
    arrivals: &Arrivals,
    memory: &BTreeMap<String, ProcessMemory>,
    span_s: f64,
    alone: &crate::bench_inference::PhaseMedians,
    servo: ServoTiming,
) {
    let commands = arrivals[PATH.len() - 1].len();
    println!(
        "end to end: graphs/orfd.toml as processes on the ORFD frames ({}x{}), {:.0} s, {} frames to a command, one run\n",
        alone.frame.0, alone.frame.1, span_s, commands
    );
    println!("| from capture to | produced by | frames | median ms | p99 ms |");
    println!("|---|---|---|---|---|");
    for (k, (topic, stage)) in PATH.iter().enumerate() {
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
    for k in 1..PATH.len() {
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
            PATH[k - 1].0,
            PATH[k].0,
            PATH[k].1,
            quantile(&mut v, 0.5),
            quantile(&mut v, 0.99)
        );
    }
    let total = alone.pre_ms + alone.inference_ms + alone.post_ms;
    println!(
        "\ninference alone (same model and frames, no graph): pre {:.1} + inference {:.1} + post {:.1} = {:.1} ms (median)",
        alone.pre_ms, alone.inference_ms, alone.post_ms, total
    );
    let mut c2c: Vec<f64> = arrivals[PATH.len() - 1].values().copied().collect();
    let c2c = quantile(&mut c2c, 0.5);
    println!(
        "capture-to-command median {:.1} ms = inference alone + {:.1} ms (goal: + 2 ms where every stage on the path is event-driven)",
        c2c,
        c2c - total
    );
    println!("{}", servo.describe());
    if !memory.is_empty() {
        println!("\n| stage | private MB | shared memory MB |");
        println!("|---|---|---|");
        for (s, m) in memory {
            println!(
                "| {s} | {:.1} | {:.1} |",
                memory::mb(m.private_bytes),
                memory::mb(m.shared_memory_bytes)
            );
        }
    }
}
