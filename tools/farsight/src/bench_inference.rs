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
    let table = config
        .class_table_path()
        .map(|p| ClassTableFile::open(&p))
        .transpose()?;
    let mut backend = Backend::Onnx(Box::new(OnnxModel::load(config)?));
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
    if a.stage_seconds > 0.0 {
        let fps = stage_fps(&a)?;
        println!("\nstage throughput: camera-ingest at 200 Hz -> farsight-inference -> {fps:.1} navigability images/s");
    }
    Ok(())
}

/// Runs camera-ingest (as fast as 200 Hz) and the inference stage as real
/// processes and counts navigability images over `stage_seconds`.
fn stage_fps(a: &InferenceArgs) -> Result<f64> {
    let dir = std::env::temp_dir().join(format!("farsight-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let prefix = format!("benchinf{}_", std::process::id());
    let frames = std::fs::canonicalize(&a.frames)?;
    let model = std::fs::canonicalize(&a.model_config)?;
    // The ORFD camera model, one file for every ORFD config.
    let camera_info = crate::graph::repo_file("tests/fixtures/orfd/front.yaml")?;
    let camera_info = std::fs::canonicalize(camera_info)?;
    std::fs::write(
        dir.join("inference.toml"),
        format!(
            "camera = \"front\"\nmodel_config = {:?}\n",
            model.display().to_string()
        ),
    )?;
    std::fs::write(
        dir.join("ingest.toml"),
        format!(
            "[[cameras]]\nfolder = {:?}\nrate_hz = 200.0\nloops = 0\n[cameras.model]\nname = \"front\"\ncamera_info = {:?}\n",
            frames.display().to_string(),
            camera_info.display().to_string()
        ),
    )?;
    let exe = std::env::current_exe()?;
    let start = |name: &str, cfg: &str| -> Result<std::process::Child> {
        let mut c = Command::new(exe.with_file_name(format!("farsight-{name}")))
            .arg("--config")
            .arg(dir.join(cfg))
            .env("FARSIGHT_IPC_PREFIX", &prefix)
            .env("RUST_LOG", "warn")
            .stdout(Stdio::piped())
            .spawn()
            .with_context(|| format!("starting farsight-{name}"))?;
        let mut line = String::new();
        BufReader::new(c.stdout.take().expect("stdout")).read_line(&mut line)?;
        if !line.contains("ready") {
            bail!("farsight-{name} did not start");
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
    let nav = bus.slice_subscriber(&topics::navigability("front"))?;
    let mut inference = start("inference", "inference.toml")?;
    let mut ingest = start("camera-ingest", "ingest.toml")?;
    // Warm up, then count distinct outputs.
    std::thread::sleep(Duration::from_secs(2));
    while nav.latest()?.is_some() {}
    let t0 = Instant::now();
    let mut n = 0u64;
    while t0.elapsed().as_secs_f64() < a.stage_seconds {
        if nav.latest()?.is_some() {
            n += 1;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    let fps = n as f64 / t0.elapsed().as_secs_f64();
    for c in [&mut ingest, &mut inference] {
        let _ = c.kill();
        let _ = c.wait();
    }
    drop(nav);
    drop(bus);
    let _ = std::fs::remove_dir_all(&dir);
    if let Ok(entries) = std::fs::read_dir("/dev/shm") {
        for e in entries.flatten() {
            if e.file_name().to_string_lossy().starts_with(&prefix) {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }
    Ok(fps)
}
