//! `farsight bench inference`: where a frame's time goes in the inference
//! stage, and how many frames per second the real stage process sustains.

use crate::bench::InferenceArgs;
use anyhow::{bail, Context, Result};
use farsight_inference::class_table::ClassTableFile;
use farsight_inference::model_config::ModelConfig;
use farsight_inference::onnx::{OnnxModel, Timings};
use farsight_inference::Backend;
use farsight_interfaces::topics;
use farsight_interfaces::transport::ipc::{Bus, IpcSettings};
use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// The inference stage's phases on a folder of PNG frames, outside any
/// process graph: median pre-processing, inference and post-processing
/// (ms) over `runs` frames after 3 warm-up runs, with the frame size.
pub struct PhaseMedians {
    pub pre_ms: f64,
    pub inference_ms: f64,
    pub post_ms: f64,
    pub frame: (u32, u32),
}

pub fn phase_medians(
    config: &ModelConfig,
    frames_dir: &std::path::Path,
    runs: usize,
) -> Result<PhaseMedians> {
    let mut files: Vec<_> = std::fs::read_dir(frames_dir)
        .with_context(|| format!("reading {}", frames_dir.display()))?
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "png"))
        .collect();
    files.sort();
    if files.is_empty() {
        bail!("no PNG frames in {}", frames_dir.display());
    }
    let frames: Vec<_> = files
        .iter()
        .map(|f| farsight_imaging::decode_png(&std::fs::read(f)?).map_err(anyhow::Error::from))
        .collect::<Result<_>>()?;
    phase_medians_on(config, &frames, runs)
}

/// [`phase_medians`] on frames in memory (the simulator's, as a tap saw them).
pub fn phase_medians_on(
    config: &ModelConfig,
    frames: &[(farsight_interfaces::msg::ImageHeader, Vec<u8>)],
    runs: usize,
) -> Result<PhaseMedians> {
    if frames.is_empty() {
        bail!("no frames to time the model on");
    }
    let table = config
        .class_table_path()
        .map(|p| ClassTableFile::open(&p))
        .transpose()?;
    let mut backend = Backend::Onnx(Box::new(OnnxModel::load(config)?));
    let (mut pre, mut inf, mut post) = (vec![], vec![], vec![]);
    for i in 0..runs.max(1) + 3 {
        let (h, f) = &frames[i % frames.len()];
        let mut t = Timings::default();
        backend.run(h, f, table.as_ref().map(|t| t.table()), &mut t)?;
        if i >= 3 {
            pre.push(t.preprocess_s * 1e3);
            inf.push(t.inference_s * 1e3);
            post.push(t.postprocess_s * 1e3);
        }
    }
    Ok(PhaseMedians {
        pre_ms: median(pre),
        inference_ms: median(inf),
        post_ms: median(post),
        frame: (frames[0].0.width, frames[0].0.height),
    })
}

pub fn run(a: InferenceArgs) -> Result<()> {
    if !(0.0..=86_400.0).contains(&a.stage_seconds) {
        bail!(
            "--stage-seconds {}: expected 0 (skip) to 86400 s",
            a.stage_seconds
        );
    }
    let config = ModelConfig::load(&a.model_config)?;
    let m = phase_medians(&config, &a.frames, a.runs)?;
    let (fw, fh) = m.frame;
    let (p, i, q) = (m.pre_ms, m.inference_ms, m.post_ms);
    println!(
        "inference stage, {} on {fw}x{fh} frames -> {}x{} input, median of {} runs (one run):\n",
        config
            .model_path()
            .file_name()
            .and_then(|n| n.to_str())
            .unwrap_or("model"),
        config.input.width,
        config.input.height,
        a.runs
    );
    println!("| phase | median ms | share of inference |");
    println!("|---|---|---|");
    println!(
        "| pre-processing (resize, normalise) | {p:.2} | {:.1}% |",
        100.0 * p / i
    );
    println!("| inference (ONNX Runtime, CPU) | {i:.2} | 100% |");
    println!(
        "| post-processing (argmax, confidence, class table) | {q:.2} | {:.1}% |",
        100.0 * q / i
    );
    println!(
        "| pre + post | {:.2} | {:.1}% |",
        p + q,
        100.0 * (p + q) / i
    );
    if a.stage_seconds > 0.0 && a.cameras == 1 {
        let r = stage_layout(&a, &[vec![camera_name(0)]])?;
        println!(
            "\nstage throughput: camera-ingest at {} Hz -> farsight-inference -> {:.1} frames/s ({:.0}% of a core)",
            a.camera_rate_hz,
            r.frames_per_s(),
            100.0 * r.cpu_share()
        );
    } else if a.stage_seconds > 0.0 {
        let n = usize::from(a.cameras);
        let cameras: Vec<String> = (0..n).map(camera_name).collect();
        println!(
            "\n{n} cameras (camera-ingest at {} Hz each), {:.0} s each layout, one run:\n",
            a.camera_rate_hz, a.stage_seconds
        );
        println!("| layout | frames/s, all cameras | per camera | inference CPU, % of a core | CPU ms a frame | private memory MB |");
        println!("|---|---|---|---|---|---|");
        let one = stage_layout(&a, std::slice::from_ref(&cameras))?;
        let each = stage_layout(
            &a,
            &cameras.iter().map(|c| vec![c.clone()]).collect::<Vec<_>>(),
        )?;
        for (name, r) in [
            (
                format!(
                    "one process, one session ({})",
                    if model_batches(&config) {
                        "batched"
                    } else {
                        "frames one at a time"
                    }
                ),
                &one,
            ),
            (format!("{n} processes, a session each"), &each),
        ] {
            println!(
                "| {name} | {:.1} | {} | {:.0}% | {:.1} | {:.1} |",
                r.frames_per_s(),
                r.per_camera
                    .iter()
                    .map(|f| format!("{:.1}", *f as f64 / r.seconds))
                    .collect::<Vec<_>>()
                    .join(" / "),
                100.0 * r.cpu_share(),
                1e3 * r.cpu_s / r.frames().max(1) as f64,
                crate::memory::mb(r.private_bytes)
            );
        }
        println!(
            "\none process / {n} processes: {:.2}x the frames/s, {:.2}x the CPU a frame, {:.2}x the private memory",
            one.frames_per_s() / each.frames_per_s(),
            (one.cpu_s / one.frames().max(1) as f64) / (each.cpu_s / each.frames().max(1) as f64),
            one.private_bytes as f64 / each.private_bytes.max(1) as f64
        );
    }
    Ok(())
}

/// Whether the model runs a step's frames as one batch.
fn model_batches(config: &ModelConfig) -> bool {
    OnnxModel::load(config).is_ok_and(|m| m.batches())
}

fn camera_name(i: usize) -> String {
    if i == 0 {
        "front".into()
    } else {
        format!("cam{i}")
    }
}

/// What one layout of inference processes did in the measured window.
struct LayoutResult {
    seconds: f64,
    /// Frames each camera's results went out for, in camera order.
    per_camera: Vec<u64>,
    /// CPU time of the inference processes, user + system.
    cpu_s: f64,
    /// Private memory of the inference processes together, at the end.
    private_bytes: u64,
}

impl LayoutResult {
    fn frames(&self) -> u64 {
        self.per_camera.iter().sum()
    }
    fn frames_per_s(&self) -> f64 {
        self.frames() as f64 / self.seconds
    }
    fn cpu_share(&self) -> f64 {
        self.cpu_s / self.seconds
    }
}

/// CPU time a process has used, user + system, from `/proc/<pid>/stat`.
fn process_cpu_s(pid: u32) -> Result<f64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat"))?;
    let ticks = cpu_ticks(&stat).with_context(|| format!("/proc/{pid}/stat: {stat:?}"))?;
    // SAFETY: sysconf with a valid name has no preconditions.
    let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) }.max(1) as f64;
    Ok(ticks as f64 / hz)
}

/// utime + stime (clock ticks) of a `/proc/<pid>/stat` line: fields 14 and
/// 15 of proc(5), counted after the command name, which may hold spaces and
/// parentheses (so from its last ')').
fn cpu_ticks(stat: &str) -> Option<u64> {
    let (_, rest) = stat.rsplit_once(')')?;
    let f: Vec<&str> = rest.split_whitespace().collect();
    // After ')': state is field 3, so fields 14 and 15 are 0-based 11 and 12.
    Some(f.get(11)?.parse::<u64>().ok()? + f.get(12)?.parse::<u64>().ok()?)
}

/// The processes of one layout and their scratch files, stopped and
/// removed however the measurement ends.
struct Launched {
    children: Vec<std::process::Child>,
    dir: std::path::PathBuf,
    prefix: String,
}

impl Drop for Launched {
    fn drop(&mut self) {
        for c in &mut self.children {
            let _ = c.kill();
            let _ = c.wait();
        }
        let _ = std::fs::remove_dir_all(&self.dir);
        if let Ok(entries) = std::fs::read_dir("/dev/shm") {
            for e in entries.flatten() {
                if e.file_name().to_string_lossy().starts_with(&self.prefix) {
                    let _ = std::fs::remove_file(e.path());
                }
            }
        }
    }
}

/// Runs camera-ingest (every camera at `camera_rate_hz`, the same frames) and
/// one inference process per entry of `layout` (the cameras it serves) as
/// real processes, and counts each camera's results over `stage_seconds`
/// from the health reports (the stage's, or each camera's where a process
/// serves several). The window starts once every camera has had a result
/// and runs on until each has had another, so a slow start or a stalled
/// machine gives a longer window, not an empty one.
fn stage_layout(a: &InferenceArgs, layout: &[Vec<String>]) -> Result<LayoutResult> {
    use farsight_interfaces::msg::StageHealth;
    let dir = std::env::temp_dir().join(format!("farsight-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let prefix = format!("benchinf{}_", std::process::id());
    // Declared before the bus, so dropped after it: children stopped and
    // shared memory removed on every way out, an error's too.
    let mut launched = Launched {
        children: Vec::new(),
        dir: dir.clone(),
        prefix: prefix.clone(),
    };
    let frames = std::fs::canonicalize(&a.frames)?;
    let model = std::fs::canonicalize(&a.model_config)?;
    // The ORFD camera model, one file for every ORFD config.
    let camera_info = crate::graph::repo_file("tests/fixtures/orfd/front.yaml")?;
    let camera_info = std::fs::canonicalize(camera_info)?;
    let cameras: Vec<&String> = layout.iter().flatten().collect();
    let mut ingest = String::new();
    for c in &cameras {
        ingest += &format!(
            "[[cameras]]\nfolder = {:?}\nrate_hz = {}\nloops = 0\ncapture_time = \"publish\"\n[cameras.model]\nname = {c:?}\ncamera_info = {:?}\n",
            frames.display().to_string(),
            a.camera_rate_hz,
            camera_info.display().to_string()
        );
    }
    std::fs::write(dir.join("ingest.toml"), ingest)?;
    let exe = std::env::current_exe()?;
    let start = |name: &str, instance: &str, cfg: &str| -> Result<std::process::Child> {
        let mut c = Command::new(exe.with_file_name(format!("farsight-{name}")))
            .arg("--config")
            .arg(dir.join(cfg))
            .arg("--instance")
            .arg(instance)
            .env("FARSIGHT_IPC_PREFIX", &prefix)
            .env("RUST_LOG", "warn")
            .stdout(Stdio::piped())
            .spawn()
            .with_context(|| format!("starting farsight-{name}"))?;
        let mut line = String::new();
        BufReader::new(c.stdout.take().expect("stdout")).read_line(&mut line)?;
        if !line.contains("ready") {
            bail!("farsight-{name} ({instance}) did not start");
        }
        Ok(c)
    };
    let bus = Bus::open_with(
        "bench-inference",
        &IpcSettings {
            prefix: Some(prefix.clone()),
            root: None,
            queues: None,
        },
    )?;
    // Each camera's count: its own health where a process serves several,
    // the process's where it serves one.
    let mut counters = Vec::new();
    for (i, served) in layout.iter().enumerate() {
        let instance = format!("inference-{i}");
        let cfg = format!("inference-{i}.toml");
        let list = if served.len() == 1 {
            format!("camera = {:?}", served[0])
        } else {
            format!("cameras = {served:?}")
        };
        std::fs::write(
            dir.join(&cfg),
            format!(
                "{list}\nmodel_config = {:?}\nhealth_rate_hz = 20.0\n",
                model.display().to_string()
            ),
        )?;
        for c in served {
            let topic = if served.len() == 1 {
                instance.clone()
            } else {
                format!("{instance}-{c}")
            };
            counters.push(bus.subscriber(&topics::health(&topic))?);
        }
        launched.children.push(start("inference", &instance, &cfg)?);
    }
    let pids: Vec<u32> = launched
        .children
        .iter()
        .map(std::process::Child::id)
        .collect();
    launched
        .children
        .push(start("camera-ingest", "camera-ingest", "ingest.toml")?);
    let mut last: Vec<Option<StageHealth>> = vec![None; counters.len()];
    let poll = |last: &mut Vec<Option<StageHealth>>| -> Result<()> {
        for (slot, sub) in last.iter_mut().zip(&counters) {
            while let Some(h) = sub.latest()? {
                *slot = Some(h);
            }
        }
        Ok(())
    };
    let warm_up_until = Instant::now() + Duration::from_secs(120);
    let outputs = |last: &[Option<StageHealth>]| -> Vec<u64> {
        last.iter()
            .map(|h| h.map_or(0, |h| h.messages_out))
            .collect()
    };
    // Warm up: every camera has had a result.
    while outputs(&last).contains(&0) {
        if Instant::now() > warm_up_until {
            bail!(
                "no result from every camera in 120 s (counts {:?})",
                outputs(&last)
            );
        }
        std::thread::sleep(Duration::from_millis(20));
        poll(&mut last)?;
    }
    let cpu = |pids: &[u32]| -> Result<f64> { pids.iter().map(|&p| process_cpu_s(p)).sum() };
    let (first, cpu0, t0) = (outputs(&last), cpu(&pids)?, Instant::now());
    let window_until = t0 + Duration::from_secs_f64(a.stage_seconds) + Duration::from_secs(120);
    loop {
        std::thread::sleep(Duration::from_millis(20));
        poll(&mut last)?;
        let now = outputs(&last);
        let all_moved = now.iter().zip(&first).all(|(n, f)| n > f);
        if t0.elapsed().as_secs_f64() >= a.stage_seconds && all_moved {
            break;
        }
        if Instant::now() > window_until {
            bail!("a camera had no result in the window (counts {first:?} -> {now:?})");
        }
    }
    let seconds = t0.elapsed().as_secs_f64();
    let cpu_s = cpu(&pids)? - cpu0;
    let per_camera = outputs(&last)
        .iter()
        .zip(&first)
        .map(|(n, f)| n - f)
        .collect();
    let private_bytes = pids
        .iter()
        .filter_map(|&p| crate::memory::of_pid(p))
        .map(|m| m.private_bytes)
        .sum();
    drop(counters);
    drop(bus);
    drop(launched);
    Ok(LayoutResult {
        seconds,
        per_camera,
        cpu_s,
        private_bytes,
    })
}

#[cfg(test)]
mod tests {
    use super::cpu_ticks;

    #[test]
    fn cpu_ticks_are_utime_plus_stime_whatever_the_command_name() {
        // proc(5): pid (comm) state ppid pgrp session tty_nr tpgid flags
        // minflt cminflt majflt cmajflt utime stime ...
        let stat =
            "4242 (farsight-inf) (x) S 1 4242 4242 0 -1 4194560 900 0 0 0 1234 56 0 0 20 0 9 0";
        assert_eq!(cpu_ticks(stat), Some(1234 + 56));
        assert_eq!(cpu_ticks("4242 (cut short) S 1 2"), None);
        assert_eq!(cpu_ticks("no parenthesis"), None);
    }
}
