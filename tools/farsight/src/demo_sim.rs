//! `farsight demo` (the default): the closed loop in simulation. Every stage
//! runs as its own process with `farsight-sim run` as the robot on a named
//! scenario (default `bug-trap`), until the robot reaches the goal or the
//! time runs out; the output folder gets each stage's config and log, the
//! map with the driven track and the method's decisions (PNG), a recording
//! of every topic (`recording.mcap`) and `summary.toml`.
//!
//! Methods:
//! - `--method fitam` (default): the shipped FITAM far-field model
//!   (`deploy/models/sim-fitam`) -> bin-projection's polar bins ->
//!   costmap-fusion (near field + Kalman-fused far field) -> D* Lite ->
//!   carrot tracking;
//! - `--method dstar-lite`: the same without the far field (FITAM's "no
//!   far-field" baseline);
//! - `--method lrn`: the shipped LRN affordance model
//!   (`deploy/models/sim-lrn`) in the inference stage on the rendered RGB ->
//!   bin-projection's angular bins -> LRN's goal-conditioned head in the
//!   subgoal stage -> the servo's heading law. Not the default: that model's
//!   heatmap does not tell the bug trap's wall from open ground (README,
//!   "Navigation benchmark");
//! - `--method povnav`: the inference stage's HSV backend on the rendered RGB ->
//!   POVNav -> the POVNav servo law; `--oracle` swaps the inference stage
//!   for the simulator's class image.

use crate::demo::Stage;
use anyhow::{bail, Context, Result};
use clap::ValueEnum;
use farsight_interfaces::transport::ipc::QUEUES_ENV;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Method {
    Fitam,
    DstarLite,
    Povnav,
    Lrn,
    /// LRN's heading as POVNav's goal (graphs/sim/povnav-lrn.toml).
    PovnavLrn,
    /// LRN's heading as a D* Lite local planner's goal (graphs/sim/lrn-dstar.toml).
    LrnDstar,
}

pub struct SimDemo {
    pub out: PathBuf,
    pub scenario: String,
    pub seed: u64,
    pub method: Method,
    pub oracle: bool,
    pub graph: Option<PathBuf>,
    pub max_time_s: f64,
    pub realtime: bool,
    /// Lock-step: how long the simulator waits for each command.
    pub command_timeout_s: f64,
    pub recorder_queue_depth: usize,
    /// Serve the run live to the Foxglove app on this port.
    pub foxglove_port: Option<u16>,
}

/// The recorder's instance name: its health topic is its lock-step answer.
const RECORDER: &str = "recorder";

/// Every topic of the graph, each stage instance's health included, by
/// name: all subscribed before anything runs, so none is recorded from a
/// later message than its first.
fn recorded_topics(graph: &crate::graph::Graph) -> Vec<String> {
    let mut topics: Vec<String> = graph.topics.keys().cloned().collect();
    for node in &graph.nodes {
        let health = farsight_interfaces::topics::health(&node.spec.name)
            .name()
            .to_string();
        if !topics.contains(&health) {
            topics.push(health);
        }
    }
    topics
}

/// `farsight record` into `out/recording.mcap`, as a child process in the
/// lock-step answer set (it reports each command it has written, and the
/// simulator waits for that); stopped (and its file finished) when the
/// returned guard drops.
fn start_recorder(out: &Path, prefix: &str, queues: &str, topics: &[String]) -> Result<Reporting> {
    let mut cmd = Command::new(std::env::current_exe()?);
    cmd.args(["record", "--topics", &topics.join(",")])
        .args([
            "--ack",
            farsight_interfaces::topics::velocity_command().name(),
        ])
        .args(["--instance", RECORDER, "--out"])
        .arg(out.join("recording.mcap"))
        .env(QUEUES_ENV, queues);
    start_reporting(cmd, "recorder", "farsight-record ready", out, prefix)
}

/// `farsight foxglove` on `port`: the run live in the Foxglove app. It
/// reads this machine's shared memory, or with `laptop` (the bridge's zenoh
/// endpoint and robot name) the robot's bridge over zenoh, as a laptop does.
pub(crate) fn start_foxglove(
    out: &Path,
    prefix: &str,
    port: u16,
    laptop: Option<(&str, &str)>,
) -> Result<Reporting> {
    let mut cmd = Command::new(std::env::current_exe()?);
    cmd.args(["foxglove", "--port", &port.to_string()]);
    if let Some((endpoint, robot)) = laptop {
        cmd.args(["--connect", endpoint, "--robot", robot]);
    }
    let child = start_reporting(cmd, "foxglove", "farsight-foxglove ready", out, prefix)?;
    println!("foxglove: ws://127.0.0.1:{port} (open it in the Foxglove app; layout: deploy/foxglove/farsight-layout.json)");
    Ok(child)
}

/// A child `farsight` tool on the demo's bus, started once it prints its
/// ready line; its log goes to `out/<name>.log`, its closing report to our
/// stdout and `out/<name>-report.txt`.
fn start_reporting(
    mut cmd: Command,
    name: &str,
    ready: &str,
    out: &Path,
    prefix: &str,
) -> Result<Reporting> {
    use std::io::BufRead;
    let log_path = out.join(format!("{name}.log"));
    let mut child = crate::demo::die_with_parent(&mut cmd)
        .env("FARSIGHT_IPC_PREFIX", prefix)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(std::fs::File::create(&log_path)?)
        .spawn()
        .with_context(|| format!("starting farsight {name}"))?;
    let mut stdout = std::io::BufReader::new(child.stdout.take().expect("piped"));
    let mut line = String::new();
    stdout.read_line(&mut line)?;
    if !line.trim().starts_with(ready) {
        bail!("farsight {name} did not start; see {}", log_path.display());
    }
    let mut report = std::fs::File::create(out.join(format!("{name}-report.txt")))?;
    let name = name.to_string();
    let reader = std::thread::spawn(move || {
        use std::io::Write;
        for line in stdout.lines().map_while(Result::ok) {
            println!("{name}: {line}");
            let _ = writeln!(report, "{line}");
        }
    });
    Ok(Reporting {
        child: Some(Stage(child)),
        reader: Some(reader),
    })
}

/// A child tool's process and the thread that passes its report on.
pub(crate) struct Reporting {
    child: Option<Stage>,
    reader: Option<std::thread::JoinHandle<()>>,
}

impl Drop for Reporting {
    /// Stops the child (a recorder finishes its file) and waits for its report.
    fn drop(&mut self) {
        drop(self.child.take());
        if let Some(r) = self.reader.take() {
            let _ = r.join();
        }
    }
}

/// Adds the method's decisions to the map PNG, from the recording: every
/// tenth subgoal within 50 m (yellow; robot-frame points placed with the
/// pose of the same frame; POVNav's far horizon points project poorly) and
/// the path every 5 s of driving (orange: D* Lite's planned world path,
/// whose first plans run into the trap; POVNav's visual path on the
/// ground), under the driven track the simulator drew.
fn draw_decisions(out: &Path, scenario: &str, seed: u64) -> Result<()> {
    use farsight_interfaces::msg::{Path as NavPath, PathFrame, Pose, Subgoal};
    use farsight_interfaces::transport::wire;
    use std::collections::HashMap;
    let world = farsight_sim::scenario::scenario(scenario, seed)?.world;
    let map_path = out.join(format!("{scenario}-map.png"));
    let (header, mut rgb) = farsight_imaging::decode_png(&std::fs::read(&map_path)?)?;
    let rec = farsight_recording::read::Recording::open(&out.join("recording.mcap"))?;
    let (mut poses, mut subgoals, mut planned) = (HashMap::new(), Vec::new(), Vec::new());
    rec.for_each(|m| {
        match &*m.topic {
            "state/pose" => {
                let p: Pose = wire::decode_message(&m.data)?;
                poses.insert(p.stamp.frame_seq, p);
            }
            "nav/subgoal" => subgoals.push(wire::decode_message::<Subgoal>(&m.data)?),
            "nav/path/planned" | "nav/path/visual_robot" => {
                planned.push(wire::decode_message::<NavPath>(&m.data)?)
            }
            _ => {}
        }
        Ok(())
    })?;
    let k = farsight_sim::run::map_scale(world.width, world.height);
    let w = header.width as usize;
    let mut dot = |x: f64, y: f64, c: [u8; 3]| {
        if let Some((px, py)) = farsight_sim::run::map_pixel(&world, x, y) {
            for (dx, dy) in (0..k).flat_map(|i| (0..k).map(move |j| (i, j))) {
                let i = ((py + dy) * w + px + dx) * 3;
                // The driven track (white) stays on top.
                if rgb.get(i..i + 3).is_some_and(|p| p != [255, 255, 255]) {
                    rgb[i..i + 3].copy_from_slice(&c);
                }
            }
        }
    };
    for p in planned.iter().step_by(50) {
        let pose = poses.get(&p.stamp.frame_seq);
        for q in p.points.as_slice() {
            let q = [q[0] as f64, q[1] as f64];
            let w = match (p.frame, pose) {
                (PathFrame::WORLD, _) => q,
                (PathFrame::ROBOT, Some(pose)) => pose.to_world_frame(q),
                _ => continue,
            };
            dot(w[0], w[1], [255, 150, 0]);
        }
    }
    for s in subgoals.iter().step_by(10) {
        let near = s.x_m.hypot(s.y_m) <= 50.0;
        if let (Some(p), true) = (poses.get(&s.stamp.frame_seq), near) {
            let q = p.to_world_frame([s.x_m as f64, s.y_m as f64]);
            dot(q[0], q[1], [255, 230, 0]);
        }
    }
    std::fs::write(&map_path, farsight_imaging::encode_png(&header, &rgb)?)?;
    Ok(())
}

impl Method {
    /// The method's graph file, relative to the repository root.
    pub fn graph(self, oracle: bool) -> &'static str {
        match (self, oracle) {
            (Method::Fitam, _) => "graphs/sim/fitam.toml",
            (Method::DstarLite, _) => "graphs/sim/dstar-lite.toml",
            (Method::Lrn, _) => "graphs/sim/lrn.toml",
            (Method::PovnavLrn, _) => "graphs/sim/povnav-lrn.toml",
            (Method::LrnDstar, _) => "graphs/sim/lrn-dstar.toml",
            (Method::Povnav, false) => "graphs/sim/povnav.toml",
            (Method::Povnav, true) => "graphs/sim/povnav-oracle.toml",
        }
    }
}

pub fn run(d: SimDemo) -> Result<()> {
    if d.oracle && d.method != Method::Povnav {
        bail!("--oracle is POVNav's named mode (the class image as navigability); use it with --method povnav");
    }
    std::fs::create_dir_all(&d.out)?;
    let out = std::fs::canonicalize(&d.out)?;
    // Its own shared-memory namespace, or the caller's (`farsight bench
    // e2e --chain fitam-sim` taps the graph from outside).
    let prefix = std::env::var("FARSIGHT_IPC_PREFIX")
        .ok()
        .filter(|p| !p.is_empty())
        .unwrap_or_else(|| format!("simdemo{}_", std::process::id()));
    let graph = match &d.graph {
        Some(g) => std::path::absolute(g)?,
        None => crate::graph::repo_file(d.method.graph(d.oracle))?,
    };
    // The simulator provides what the graph reads from outside it.
    let loaded = crate::graph::Graph::load(&graph)?;
    let sim_options = crate::bench_nav::sim_options(
        &loaded,
        &d.scenario,
        d.seed,
        &crate::bench_nav::TrialRules::limited_to(d.max_time_s),
    );
    // The graph's nodes as processes under `farsight run` (each one's config
    // and log in `out`), all ready before the simulator's first frame.
    // The recorder reads every topic from its queue (each publisher feeds
    // one), so what is published after a frame's command (a far field that
    // comes in late) is not overwritten by the next frame before the
    // recorder takes it; at real time, so a recorder busy writing a frame
    // misses nothing. The default depth, 8: a frame publishes at most two
    // messages of any topic.
    let recorded = recorded_topics(&loaded);
    let queues = match d.recorder_queue_depth {
        0 => String::new(),
        depth => recorded
            .iter()
            .map(|t| format!("{t}={depth}"))
            .collect::<Vec<_>>()
            .join(","),
    };
    let stages = crate::run::start_graph(&graph, &out, &prefix, &queues, Duration::from_secs(120))?;
    eprintln!("{} up; driving {}...", graph.display(), d.scenario,);
    let sim = std::env::current_exe()?.with_file_name("farsight-sim");
    if !sim.exists() {
        bail!(
            "{} not found: build the workspace first (cargo xtask demo does)",
            sim.display()
        );
    }
    // Every topic of the graph goes into the recording, each subscribed
    // before the simulator's first frame.
    let recorder = start_recorder(&out, &prefix, &queues, &recorded)?;
    let foxglove = d
        .foxglove_port
        .map(|port| start_foxglove(&out, &prefix, port, None))
        .transpose()?;
    let mut cmd = Command::new(sim);
    crate::demo::die_with_parent(&mut cmd)
        .args([
            "run",
            "--scenario",
            &d.scenario,
            "--seed",
            &d.seed.to_string(),
        ])
        .args(["--max-time-s", &d.max_time_s.to_string(), "--out"])
        .arg(&out)
        .env("FARSIGHT_IPC_PREFIX", &prefix)
        .env(QUEUES_ENV, &queues)
        .stdin(Stdio::null());
    cmd.args(["--cameras", &sim_options.cameras.join(",")]);
    if d.realtime {
        cmd.args(["--clock", "realtime"]);
    } else {
        cmd.args(["--await-health", RECORDER]);
        cmd.args(["--command-timeout-s", &d.command_timeout_s.to_string()]);
    }
    if sim_options.oracle {
        cmd.arg("--oracle");
    }
    if sim_options.far_field_oracle {
        cmd.arg("--far-field-oracle");
    }
    let status = cmd.status().context("running farsight-sim")?;
    drop(stages);
    drop(recorder);
    drop(foxglove);
    if !status.success() {
        bail!(
            "farsight-sim failed ({status}); stage logs are in {}",
            out.display()
        );
    }
    draw_decisions(&out, &d.scenario, d.seed)?;
    println!(
        "configs, logs, summary.toml, recording.mcap (see recorder.log and recorder-report.txt) and {}-map.png are in {}",
        d.scenario,
        out.display()
    );
    Ok(())
}
