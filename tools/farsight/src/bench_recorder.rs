//! `farsight bench recorder`: what `farsight record` sustains writing
//! 1280x720 RGB frames to disk, reading the camera topic's latest value or
//! its queue (`--queue-depths`), with the Foxglove channels on or off
//! (`--foxglove`), and the shared memory each costs. This process publishes the real ORFD camera
//! frames (cycled; `../shared/data/orfd`) at each target rate into shared
//! memory while a `farsight record` child process records them; the table
//! gives the frames it wrote and skipped, the bandwidth in and on disk, and
//! the recorder's CPU share and CPU time per frame written (its user +
//! system time over the wall time or the frames, from `getrusage` of the
//! child).
//!
//! A first table times the writer alone, in this process, on an injected
//! clock (no shared memory, no scheduling): the ORFD frames at 30 Hz and
//! every farsight message of a recording (`--recording`, the replay
//! fixture by default) on the clock of its log times, each written with
//! every message its own chunk (how recordings were written before issue
//! 19) and with chunks of at most 1 s and 1 MiB (the default), Foxglove
//! channels on and off: file size, chunks, the median cost of one write (a
//! camera frame, any other message) and the time of all writes and the
//! finish. A write that closes a chunk pays for closing it.

use anyhow::{bail, Context, Result};
use farsight_interfaces::msg::{ImageHeader, PixelEncoding, Stamp};
use farsight_interfaces::topics;
use farsight_interfaces::transport::ipc::{Bus, IpcSettings};
use farsight_interfaces::transport::wire;
use farsight_recording::mcap_file::McapFile;
use farsight_recording::read::Recording;
use farsight_recording::write::{ChunkBounds, RecordingWriter, WriterOptions};
use farsight_recording::MESSAGE_ENCODING;
use std::io::BufRead;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
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
    /// The recorder's Foxglove channels: on (the default of `farsight
    /// record`: every frame is also downscaled to 640 px and JPEG-encoded)
    /// and/or off (`--no-foxglove`).
    #[arg(long, value_delimiter = ',', default_values_t = [true, false])]
    pub foxglove: Vec<bool>,
    /// Folder with the camera frames to publish.
    #[arg(long, default_value = "../shared/data/orfd/image_data")]
    pub frames: PathBuf,
    /// Camera frames per row of the writer table (0: no writer table).
    #[arg(long, default_value_t = 60)]
    pub writer_frames: usize,
    /// A recording whose farsight messages the writer table writes again
    /// (left out if the file is missing).
    #[arg(long, default_value = "tests/fixtures/sim-povnav/recording.mcap")]
    pub recording: PathBuf,
    /// Only the writer table.
    #[arg(long)]
    pub writer_only: bool,
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

/// One message for the writer table: topic, stamp, log time, wire bytes.
type Msg = (String, Stamp, u64, Vec<u8>);

/// A writer-table input's camera frames and how many to write; `None`: the
/// recording's messages.
type Frames<'a> = Option<(&'a [Vec<u8>], usize)>;

/// Calls `f` on each message of one writer-table input, in order. `None`
/// frames: the recording's farsight messages instead.
fn for_each_input(
    frames: Frames<'_>,
    recorded: &[Msg],
    mut f: impl FnMut(&str, Stamp, u64, &[u8]) -> Result<()>,
) -> Result<()> {
    match frames {
        Some((frames, n)) => {
            for k in 1..=n as u64 {
                // 30 Hz on the capture and log clock.
                let t = k * 1_000_000_000 / 30;
                let stamp = Stamp::new(k, t);
                let header = ImageHeader::packed(stamp, 0, W, H, PixelEncoding::RGB8);
                let bytes =
                    wire::encode_slice(&header, frames[k as usize % frames.len()].as_slice())?;
                f("camera/bench/image", stamp, t, &bytes)?;
            }
        }
        None => {
            for (topic, stamp, log_ns, bytes) in recorded {
                f(topic, *stamp, *log_ns, bytes)?;
            }
        }
    }
    Ok(())
}

fn median_ms(v: &mut [Duration]) -> String {
    if v.is_empty() {
        return "-".into();
    }
    v.sort_unstable();
    format!("{:.2}", v[v.len() / 2].as_secs_f64() * 1e3)
}

/// What one pass of the writer over an input took.
struct Pass {
    messages: u64,
    chunks: usize,
    disk: u64,
    /// Each write of a camera frame, and of any other message.
    camera: Vec<Duration>,
    other: Vec<Duration>,
    /// Every write and the finish.
    total: Duration,
}

/// Writes one input into `file` as `opts` say, on the clock of its log
/// times, and reads the file's chunks back.
fn write_once(
    input: Frames<'_>,
    recorded: &[Msg],
    file: &Path,
    opts: WriterOptions,
) -> Result<Pass> {
    let mut w = RecordingWriter::create_with_options(file, &opts)?;
    let t0 = Instant::now();
    let mut first_log = None;
    let (mut camera, mut other) = (Vec::new(), Vec::new());
    let mut messages = 0u64;
    for_each_input(input, recorded, |topic, stamp, log_ns, bytes| {
        let first = *first_log.get_or_insert(log_ns);
        let now = t0 + Duration::from_nanos(log_ns.saturating_sub(first));
        let start = Instant::now();
        w.write_at(now, topic, stamp, log_ns, bytes)?;
        let took = start.elapsed();
        if topics::kind_of(topic) == Some(topics::TopicKind::Image) {
            camera.push(took);
        } else {
            other.push(took);
        }
        messages += 1;
        Ok(())
    })?;
    let start = Instant::now();
    w.finish()?;
    let total = start.elapsed() + camera.iter().chain(&other).sum::<Duration>();
    let disk = std::fs::metadata(file)?.len();
    let mut chunk_offsets = std::collections::BTreeSet::new();
    McapFile::open(file)?.read(|m| {
        chunk_offsets.insert(m.offset);
        ControlFlow::Continue(())
    })?;
    std::fs::remove_file(file)?;
    Ok(Pass {
        messages,
        chunks: chunk_offsets.len(),
        disk,
        camera,
        other,
        total,
    })
}

/// The writer alone (see the module docs): one row per input, Foxglove
/// channels on or off, and chunking.
fn writer_table(a: &RecorderArgs, frames: &[Vec<u8>], dir: &Path) -> Result<()> {
    let mut recorded: Vec<Msg> = Vec::new();
    let fixture = a.recording.exists();
    if fixture {
        Recording::open(&a.recording)?.for_each(|m| {
            if &*m.encoding == MESSAGE_ENCODING {
                recorded.push((
                    m.topic.to_string(),
                    Stamp::new(u64::from(m.sequence), m.capture_time_ns),
                    m.log_time_ns,
                    m.data.into_owned(),
                ));
            }
            Ok(())
        })?;
    } else {
        eprintln!("{}: not there, left out", a.recording.display());
    }
    let orfd = format!("ORFD {W}x{H}, {} frames at 30 Hz", a.writer_frames);
    let fixture_name = a.recording.display().to_string();
    let mut inputs: Vec<(&str, Frames<'_>)> = Vec::new();
    if a.writer_frames > 0 {
        inputs.push((orfd.as_str(), Some((frames, a.writer_frames))));
    }
    if fixture {
        inputs.push((fixture_name.as_str(), None));
    }
    if inputs.is_empty() {
        return Ok(());
    }
    println!(
        "writer alone (zstd level 1, this process, the writer's clock injected; one run, this machine):\n"
    );
    println!("| input | foxglove | chunks closed on | messages | chunks | MB on disk | size vs every message | median write ms: camera frame | median write ms: other message | write s, all messages and finish |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    let file = dir.join("writer.mcap");
    for (name, input) in inputs {
        // A first, untimed pass: the allocator and the page cache grow
        // while the first rows would be timed otherwise.
        write_once(input, &recorded, &file, WriterOptions::default())?;
        for foxglove in a.foxglove.iter().copied() {
            let mut every_message_bytes = None;
            for (chunking, chunks) in [
                ("every message", ChunkBounds::EVERY_MESSAGE),
                ("1 s or 1 MiB", ChunkBounds::default()),
            ] {
                let opts = WriterOptions {
                    foxglove,
                    zstd: true,
                    chunks,
                };
                let mut r = write_once(input, &recorded, &file, opts)?;
                let ratio = match every_message_bytes {
                    None => {
                        every_message_bytes = Some(r.disk);
                        "1".to_string()
                    }
                    Some(b) => format!("{:.3}", r.disk as f64 / b as f64),
                };
                println!(
                    "| {name} | {} | {chunking} | {} | {} | {:.2} | {ratio} | {} | {} | {:.2} |",
                    if foxglove { "on" } else { "off" },
                    r.messages,
                    r.chunks,
                    r.disk as f64 / 1e6,
                    median_ms(&mut r.camera),
                    median_ms(&mut r.other),
                    r.total.as_secs_f64(),
                );
            }
        }
    }
    println!();
    Ok(())
}

pub fn run(a: RecorderArgs) -> Result<()> {
    let frames = load_frames(&a.frames)?;
    let dir = std::env::temp_dir().join(format!("farsight-bench-recorder-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    writer_table(&a, &frames, &dir)?;
    if a.writer_only {
        std::fs::remove_dir_all(&dir)?;
        return Ok(());
    }
    println!(
        "recorder: {W}x{H} RGB ORFD frames, {} s per cell, zstd level 1 and uncompressed (one run, this machine):\n",
        a.seconds
    );
    println!("| target Hz | queue | shm per publisher MB | foxglove | compression | published | written | skipped | written/s | MB/s in | MB/s on disk | recorder CPU | CPU ms per frame |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    let foxgloves = &a.foxglove;
    let cells = a.rates_hz.iter().flat_map(|&r| {
        a.queue_depths
            .iter()
            .flat_map(move |&q| foxgloves.iter().map(move |&f| (r, q, f)))
    });
    for (rate, depth, foxglove) in cells {
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
            if !foxglove {
                args.push("--no-foxglove");
            }
            // The recorder's own log, shown if it fails.
            let log = dir.join("record.log");
            let cpu_before = children_cpu_s();
            let mut child = Command::new(std::env::current_exe()?)
                .args(&args)
                .env("FARSIGHT_IPC_PREFIX", &prefix)
                .env(
                    farsight_interfaces::transport::ipc::QUEUES_ENV,
                    queues.as_deref().unwrap_or(""),
                )
                .stdout(Stdio::piped())
                .stderr(Stdio::from(std::fs::File::create(&log)?))
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
            let info = Recording::open(&file)
                .and_then(|r| r.info())
                .with_context(|| {
                    format!(
                        "the recorder's file; its log:\n{}",
                        std::fs::read_to_string(&log).unwrap_or_default()
                    )
                })?;
            let written = info
                .topics
                .iter()
                .find(|t| t.topic == "camera/bench/image")
                .map_or(0, |t| t.count);
            let disk = std::fs::metadata(&file)?.len() as f64;
            let raw = written as f64 * (W * H * 3) as f64;
            println!(
                "| {} | {} | {:.0} | {} | {} | {k} | {written} | {} | {:.1} | {:.0} | {:.0} | {:.0}% | {:.1} |",
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
                if foxglove { "on" } else { "off" },
                if zstd { "zstd 1" } else { "none" },
                k.saturating_sub(written),
                written as f64 / wall,
                raw / wall / 1e6,
                disk / wall / 1e6,
                100.0 * cpu / wall,
                1e3 * cpu / written.max(1) as f64
            );
            std::fs::remove_file(&file)?;
        }
    }
    std::fs::remove_dir_all(&dir)?;
    Ok(())
}
