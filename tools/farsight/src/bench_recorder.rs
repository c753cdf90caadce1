//! `farsight bench recorder`: what `farsight record` sustains writing
//! 1280x720 RGB frames to disk, reading the camera topic's latest value or
//! its queue (`--queue-depths`), and the shared memory each costs. This process publishes the real ORFD camera
//! frames (cycled; `../shared/data/orfd`) at each target rate into shared
//! memory while a `farsight record` child process records them; the table
//! gives the frames it wrote and skipped, the bandwidth in and on disk, and
//! the recorder's CPU share (its user + system time over the wall time, from
//! `getrusage` of the child).

use anyhow::{bail, Context, Result};
use farsight_interfaces::msg::{ImageHeader, PixelEncoding, Stamp};
use farsight_interfaces::topics;
use farsight_interfaces::transport::ipc::{Bus, IpcSettings};
use farsight_recording::read::Recording;
use std::io::BufRead;
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

#[derive(Debug, clap::Args)]
pub struct RecorderArgs {
    /// Seconds per cell.
    #[arg(long, default_value_t = 8.0)]
    pub seconds: f64,
    /// Target publish rates; 0 = as fast as the publisher can.
    #[arg(long, value_delimiter = ',', default_values_t = [15.0, 30.0, 0.0])]
    pub rates_hz: Vec<f64>,
    /// Queue depths of the camera topic the recorder reads (0: its latest
    /// value, no queue).
    #[arg(long, value_delimiter = ',', default_values_t = [0, 16])]
    pub queue_depths: Vec<usize>,
    /// Folder with the camera frames to publish.
    #[arg(long, default_value = "../shared/data/orfd/image_data")]
    pub frames: PathBuf,
}

const W: u32 = 1280;
const H: u32 = 720;

fn children_cpu_s() -> f64 {
    // SAFETY: getrusage writes into the struct we hand it.
    let mut u: libc::rusage = unsafe { std::mem::zeroed() };
    unsafe { libc::getrusage(libc::RUSAGE_CHILDREN, &mut u) };
    let t = |v: libc::timeval| v.tv_sec as f64 + v.tv_usec as f64 * 1e-6;
    t(u.ru_utime) + t(u.ru_stime)
}

fn load_frames(dir: &PathBuf) -> Result<Vec<Vec<u8>>> {
    let mut names: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| {
            format!(
                "{}: the ORFD frames (see ../shared/README.md)",
                dir.display()
            )
        })?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .collect();
    names.sort();
    let mut out = Vec::new();
    for p in names {
        let (h, d) = farsight_imaging::decode_image(&std::fs::read(&p)?)
            .with_context(|| p.display().to_string())?;
        if (h.width, h.height, h.encoding) == (W, H, PixelEncoding::RGB8) {
            out.push(d);
        }
    }
    if out.is_empty() {
        bail!("no {W}x{H} RGB frames in {}", dir.display());
    }
    Ok(out)
}

pub fn run(a: RecorderArgs) -> Result<()> {
    let frames = load_frames(&a.frames)?;
    let dir = std::env::temp_dir().join(format!("farsight-bench-recorder-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    println!(
        "recorder: {W}x{H} RGB ORFD frames, {} s per cell, zstd level 1 and uncompressed (one run, this machine):\n",
        a.seconds
    );
    println!("| target Hz | queue | shm per publisher MB | compression | published | written | skipped | written/s | MB/s in | MB/s on disk | recorder CPU |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    let cells = a
        .rates_hz
        .iter()
        .flat_map(|&r| a.queue_depths.iter().map(move |&q| (r, q)));
    for (rate, depth) in cells {
        let queue = (depth > 0).then_some(depth);
        let queues = queue.map(|d| format!("camera/bench/image={d}"));
        for zstd in [true, false] {
            let prefix = format!("benchrec{}_", std::process::id());
            let bus = Bus::open_with(
                "bench-recorder",
                &IpcSettings {
                    prefix: Some(prefix.clone()),
                    root: None,
                    queues: queues.clone(),
                },
            )?;
            let images =
                bus.slice_publisher(&topics::camera_image("bench"), (W * H * 3) as usize)?;
            let file = dir.join("bench.mcap");
            let mut args = vec!["record", "--topics", "camera/bench/image", "--out"];
            let path = file.to_str().expect("utf-8 temp path").to_string();
            args.push(&path);
            if !zstd {
                args.push("--no-compression");
            }
            let cpu_before = children_cpu_s();
            let mut child = Command::new(std::env::current_exe()?)
                .args(&args)
                .env("FARSIGHT_IPC_PREFIX", &prefix)
                .env(
                    farsight_interfaces::transport::ipc::QUEUES_ENV,
                    queues.as_deref().unwrap_or(""),
                )
                .stdout(Stdio::piped())
                .stderr(Stdio::null())
                .spawn()?;
            let mut ready = String::new();
            std::io::BufReader::new(child.stdout.take().expect("piped")).read_line(&mut ready)?;
            let start = Instant::now();
            let mut k = 0u64;
            while start.elapsed().as_secs_f64() < a.seconds {
                k += 1;
                let stamp = Stamp::new(k, start.elapsed().as_nanos() as u64);
                let f = &frames[k as usize % frames.len()];
                images.publish_copy(ImageHeader::packed(stamp, 0, W, H, PixelEncoding::RGB8), f)?;
                if rate > 0.0 {
                    let due = Duration::from_secs_f64(k as f64 / rate);
                    std::thread::sleep(due.saturating_sub(start.elapsed()));
                }
            }
            let wall = start.elapsed().as_secs_f64();
            // Let it take the last frame, then stop it (SIGTERM finishes the file).
            std::thread::sleep(Duration::from_millis(200));
            Command::new("kill")
                .args(["-TERM", &child.id().to_string()])
                .status()?;
            child.wait()?;
            let cpu = children_cpu_s() - cpu_before;
            let info = Recording::open(&file)?.info()?;
            let written = info.topics.first().map_or(0, |t| t.count);
            let disk = std::fs::metadata(&file)?.len() as f64;
            let raw = written as f64 * (W * H * 3) as f64;
            println!(
                "| {} | {} | {:.0} | {} | {k} | {written} | {} | {:.1} | {:.0} | {:.0} | {:.0}% |",
                if rate > 0.0 {
                    format!("{rate:.0}")
                } else {
                    "max".into()
                },
                queue.map_or("latest".to_string(), |d| d.to_string()),
                farsight_interfaces::transport::ipc::publisher_shm_bytes(
                    (W * H * 3) as usize,
                    queue
                ) as f64
                    / 1e6,
                if zstd { "zstd 1" } else { "none" },
                k.saturating_sub(written),
                written as f64 / wall,
                raw / wall / 1e6,
                disk / wall / 1e6,
                100.0 * cpu / wall
            );
            std::fs::remove_file(&file)?;
        }
    }
    std::fs::remove_dir_all(&dir)?;
    Ok(())
}
