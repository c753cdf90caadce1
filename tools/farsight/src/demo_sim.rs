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

use crate::demo::{start_ready, Stage};
use crate::sim_tuning;
use anyhow::{bail, Context, Result};
use clap::ValueEnum;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Method {
    Fitam,
    DstarLite,
    Povnav,
    Lrn,
}

pub struct SimDemo {
    pub out: PathBuf,
    pub scenario: String,
    pub seed: u64,
    pub method: Method,
    pub oracle: bool,
    pub max_time_s: f64,
}

/// HSV ranges of the simulator's navigable ground colours (road, trail,
/// grass, field), shaded and hazed as the renderer draws them.
const HSV_GROUND: &str = "\
[[hsv.ranges]]          # grass, field: yellow-green to green\n\
hue_deg = [55.0, 115.0]\nsaturation = [0.35, 0.75]\nvalue = [0.35, 0.85]\n\
[[hsv.ranges]]          # road, trail: tan, low saturation\n\
hue_deg = [25.0, 45.0]\nsaturation = [0.1, 0.45]\nvalue = [0.4, 0.8]\n";

/// The topics the demo records by name (subscribed before anything runs).
const RECORDED: [&str; 16] = [
    "camera/front/image",
    "camera/front/info",
    "state/pose",
    "nav/goal",
    "costmap/local",
    "perception/front/navigability",
    "perception/front/heatmap",
    "bins/angular",
    "bins/polar",
    "nav/subgoal",
    "nav/path/visual",
    "nav/path/visual_robot",
    "nav/path/planned",
    "costmap/fused",
    "cmd/velocity",
    "health/*",
];

/// `farsight record` into `out/recording.mcap`, as a child process; stopped
/// (and its file finished) when the returned guard drops.
fn start_recorder(out: &Path, prefix: &str) -> Result<Stage> {
    use std::io::BufRead;
    let log = std::fs::File::create(out.join("recorder.log"))?;
    let mut child = Command::new(std::env::current_exe()?)
        .args(["record", "--topics", &RECORDED.join(","), "--out"])
        .arg(out.join("recording.mcap"))
        .env("FARSIGHT_IPC_PREFIX", prefix)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(log)
        .spawn()
        .context("starting farsight record")?;
    let mut stdout = std::io::BufReader::new(child.stdout.take().expect("piped"));
    let mut line = String::new();
    stdout.read_line(&mut line)?;
    if line.trim() != "farsight-record ready" {
        bail!(
            "farsight record did not start; see {}",
            out.join("recorder.log").display()
        );
    }
    // Its closing report (messages and skips per topic) goes to our stdout.
    std::thread::spawn(move || {
        for line in stdout.lines().map_while(Result::ok) {
            println!("recorder: {line}");
        }
    });
    Ok(Stage(child))
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

/// Fusion, D* Lite and the carrot tracker: FITAM's planning half.
fn dstar_stages(
    fusion: &farsight_costmap_fusion::stage::FusionStageConfig,
) -> Result<Vec<(&'static str, String)>> {
    Ok(vec![
        ("costmap-fusion", sim_tuning::to_toml(fusion)?),
        (
            "subgoal-selection",
            sim_tuning::to_toml(&sim_tuning::dstar_subgoal_selection())?,
        ),
        (
            "velocity-servoing",
            sim_tuning::to_toml(&sim_tuning::dstar_servo())?,
        ),
    ])
}

fn write(out: &Path, name: &str, text: &str) -> Result<PathBuf> {
    let p = out.join(name);
    std::fs::write(&p, text).with_context(|| format!("writing {}", p.display()))?;
    Ok(p)
}

pub fn run(d: SimDemo) -> Result<()> {
    if d.oracle && d.method != Method::Povnav {
        bail!("--oracle is POVNav's named mode (the class image as navigability); use it with --method povnav");
    }
    std::fs::create_dir_all(&d.out)?;
    let out = std::fs::canonicalize(&d.out)?;
    let prefix = format!("simdemo{}_", std::process::id());
    // Each stage's config file, in start order.
    let model = |rel: &str| -> Result<String> {
        let path = sim_tuning::shipped_model(rel)?;
        // A TOML string, escaped as TOML escapes (not as Rust's Debug does).
        let quoted = toml::Value::String(path.canonicalize()?.display().to_string());
        Ok(format!(
            "camera = \"front\"\nbackend = \"onnx\"\nmodel_config = {quoted}\n"
        ))
    };
    let configs: Vec<(&'static str, String)> = match d.method {
        Method::Lrn => vec![
            ("inference", model(sim_tuning::LRN_MODEL)?),
            (
                "bin-projection",
                format!(
                    "method = \"lrn\"\ncameras = [\"front\"]\n\n[bins]\n{}",
                    sim_tuning::to_toml(&sim_tuning::lrn_bins())?
                ),
            ),
            (
                "subgoal-selection",
                sim_tuning::to_toml(&sim_tuning::lrn_subgoal_selection())?,
            ),
            (
                "velocity-servoing",
                sim_tuning::to_toml(&sim_tuning::povnav_servo())?,
            ),
        ],
        Method::Fitam => {
            let mut c = vec![
                ("inference", model(sim_tuning::FITAM_MODEL)?),
                (
                    "bin-projection",
                    "method = \"fitam\"\ncameras = [\"front\"]\n".into(),
                ),
            ];
            c.extend(dstar_stages(&sim_tuning::fitam_costmap_fusion())?);
            c
        }
        Method::DstarLite => dstar_stages(&sim_tuning::dstar_costmap_fusion())?,
        Method::Povnav => {
            let mut c = Vec::new();
            if !d.oracle {
                c.push((
                    "inference",
                    format!("camera = \"front\"\nbackend = \"hsv\"\n{HSV_GROUND}"),
                ));
            }
            c.push((
                "subgoal-selection",
                sim_tuning::to_toml(&sim_tuning::povnav_subgoal_selection())?,
            ));
            c.push((
                "velocity-servoing",
                sim_tuning::to_toml(&sim_tuning::povnav_servo())?,
            ));
            c
        }
    };
    let mut stages: Vec<Stage> = Vec::new();
    for (stage, text) in &configs {
        let config = write(&out, &format!("{stage}.toml"), text)?;
        stages.push(start_ready(stage, &config, &prefix, &out)?);
    }
    eprintln!(
        "stages up ({}); driving {} with {:?}{}...",
        stages.len(),
        d.scenario,
        d.method,
        if d.oracle { " (oracle perception)" } else { "" }
    );
    let sim = std::env::current_exe()?.with_file_name("farsight-sim");
    if !sim.exists() {
        bail!(
            "{} not found: build the workspace first (cargo xtask demo does)",
            sim.display()
        );
    }
    // Every topic goes into the recording; the sim's and the outputs' names
    // are subscribed before the sim starts, the rest (health) when they appear.
    let recorder = start_recorder(&out, &prefix)?;
    let mut cmd = Command::new(sim);
    cmd.args([
        "run",
        "--scenario",
        &d.scenario,
        "--seed",
        &d.seed.to_string(),
    ])
    .args(["--max-time-s", &d.max_time_s.to_string(), "--out"])
    .arg(&out)
    .env("FARSIGHT_IPC_PREFIX", &prefix)
    .stdin(Stdio::null());
    if d.oracle {
        cmd.arg("--oracle");
    }
    let status = cmd.status().context("running farsight-sim")?;
    drop(stages);
    drop(recorder);
    if !status.success() {
        bail!(
            "farsight-sim failed ({status}); stage logs are in {}",
            out.display()
        );
    }
    draw_decisions(&out, &d.scenario, d.seed)?;
    println!(
        "configs, logs, summary.toml, recording.mcap (see recorder.log) and {}-map.png are in {}",
        d.scenario,
        out.display()
    );
    Ok(())
}
