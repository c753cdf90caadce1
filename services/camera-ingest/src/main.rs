//! `farsight-camera-ingest`: each camera's source runs in its own thread and
//! hands frames to the main thread, which writes them into shared memory with
//! the camera model (iceoryx2 ports stay on the thread that made them).

use anyhow::{bail, Context, Result};
use farsight_camera_ingest::mcap_source::McapFile;
use farsight_camera_ingest::v4l2::{V4l2Camera, V4l2Format};
use farsight_camera_ingest::{
    capture_time_from_name, list_images, read_frame, CameraEntry, IngestConfig,
};
use farsight_interfaces::camera::Camera;
use farsight_interfaces::clock::{Clock, WallClock};
use farsight_interfaces::msg::{HealthState, ImageHeader, Stamp};
use farsight_interfaces::topics;
use farsight_interfaces::transport::ipc::Bus;
use farsight_stage::{load_config, Health, StageArgs};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{sync_channel, RecvTimeoutError, SyncSender};
use std::sync::Arc;
use std::time::{Duration, Instant};

const STAGE: &str = "camera-ingest";

/// What a source thread sends to the publishing loop.
enum Event {
    Frame {
        camera: usize,
        header: ImageHeader,
        /// Shared, so a cached frame replayed from memory is not copied on its
        /// way to the publishing loop (which copies it once, into shared memory).
        data: Arc<Vec<u8>>,
        capture_time_ns: Option<u64>,
        /// The registered depth image, when the source has one.
        depth: Option<(ImageHeader, Vec<u8>)>,
    },
    Dropped(String),
    /// The source cannot go on (a recording damaged under it): why.
    Failed(usize, String),
    End(usize),
}

fn main() {
    farsight_stage::run_main(STAGE, run);
}

/// Plays a folder: decode, pace to `rate_hz`, loop; decoded frames are kept
/// after the first pass (within a budget) so looping costs a copy, not a decode.
/// Reads a 16-bit depth PNG registered to a frame of size `w` x `h`.
fn read_depth(path: &std::path::Path, w: u32, h: u32) -> Result<(ImageHeader, Vec<u8>), String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let (header, data) =
        farsight_imaging::decode_png(&bytes).map_err(|e| format!("{}: {e}", path.display()))?;
    if header.encoding != farsight_interfaces::msg::PixelEncoding::MONO16
        || (header.width, header.height) != (w, h)
    {
        return Err(format!(
            "{}: depth must be a {w}x{h} 16-bit PNG, got {}x{} {}",
            path.display(),
            header.width,
            header.height,
            header.encoding
        ));
    }
    Ok((header, data))
}

fn folder_source(
    i: usize,
    entry: CameraEntry,
    depth_dir: Option<PathBuf>,
    files: Vec<PathBuf>,
    (w, h): (u32, u32),
    tx: SyncSender<Event>,
    stop: Arc<AtomicBool>,
) {
    let period = Duration::from_secs_f64(1.0 / entry.rate_hz);
    let frame_bytes = w as usize * h as usize * 3;
    let mut cache: Vec<Option<(ImageHeader, Arc<Vec<u8>>)>> =
        if entry.loops != 1 && files.len() * frame_bytes <= 512 << 20 {
            vec![None; files.len()]
        } else {
            vec![]
        };
    let mut next = Instant::now();
    let mut pass = 0;
    while !stop.load(Ordering::Relaxed) && (entry.loops == 0 || pass < entry.loops) {
        for (k, path) in files.iter().enumerate() {
            if stop.load(Ordering::Relaxed) {
                return;
            }
            let now = Instant::now();
            if next > now {
                std::thread::sleep(next - now);
            }
            next = next.max(now) + period;
            let read = match cache.get(k).cloned().flatten() {
                Some(f) => Ok(f),
                None => read_frame(path, w, h)
                    .map(|(h, d)| (h, Arc::new(d)))
                    .inspect(|f| {
                        if let Some(slot) = cache.get_mut(k) {
                            *slot = Some(f.clone());
                        }
                    }),
            };
            let depth = match (&depth_dir, &read) {
                (Some(dir), Ok(_)) => {
                    match read_depth(&dir.join(path.file_name().unwrap_or_default()), w, h) {
                        Ok(d) => Some(d),
                        Err(e) => {
                            if tx.send(Event::Dropped(format!("depth: {e}"))).is_err() {
                                return;
                            }
                            None
                        }
                    }
                }
                _ => None,
            };
            let event = match read {
                Ok((header, data)) => Event::Frame {
                    camera: i,
                    header,
                    data,
                    capture_time_ns: capture_time_from_name(path),
                    depth,
                },
                Err(e) => Event::Dropped(e.to_string()),
            };
            if tx.send(event).is_err() {
                return;
            }
        }
        pass += 1;
    }
    let _ = tx.send(Event::End(i));
}

/// Plays one topic of an MCAP recording at its recorded pace (times `speed`).
fn mcap_source(
    i: usize,
    entry: CameraEntry,
    file: McapFile,
    (w, h): (u32, u32),
    tx: SyncSender<Event>,
    stop: Arc<AtomicBool>,
) {
    let mut pass = 0;
    while !stop.load(Ordering::Relaxed) && (entry.loops == 0 || pass < entry.loops) {
        let start = Instant::now();
        let mut first_log: Option<u64> = None;
        let played = file.for_each_frame(&entry.topic, |frame| {
            if stop.load(Ordering::Relaxed) {
                return false;
            }
            let t0 = *first_log.get_or_insert(frame.log_time_ns);
            let due = Duration::from_nanos(
                ((frame.log_time_ns.saturating_sub(t0)) as f64 / entry.speed) as u64,
            );
            if let Some(wait) = due.checked_sub(start.elapsed()) {
                std::thread::sleep(wait);
            }
            let event = match frame.image {
                Ok((header, _)) if (header.width, header.height) != (w, h) => {
                    Event::Dropped(format!(
                        "{}: frame is {}x{}, the camera model says {w}x{h}",
                        entry.topic, header.width, header.height
                    ))
                }
                Ok((header, data)) => Event::Frame {
                    camera: i,
                    capture_time_ns: Some(header.stamp.capture_time_ns)
                        .filter(|&t| t > 0)
                        .or(Some(frame.log_time_ns)),
                    header,
                    data: Arc::new(data),
                    depth: None,
                },
                Err(e) => Event::Dropped(format!("{}: {e}", entry.topic)),
            };
            tx.send(event).is_ok()
        });
        match played {
            Ok(p) if p.frames == 0 => {
                let _ = tx.send(Event::Dropped(format!(
                    "no messages on topic {} in the recording{}",
                    entry.topic,
                    p.truncated
                        .map(|t| format!(" before it was cut ({t})"))
                        .unwrap_or_default()
                )));
                break;
            }
            // A truncated file was reported at start: every pass plays up
            // to the cut.
            Ok(_) => {}
            // Checked whole at start, so damage here is the file changing
            // under the stage: stop this camera.
            Err(e) => {
                let _ = tx.send(Event::Failed(i, e));
                return;
            }
        }
        pass += 1;
    }
    let _ = tx.send(Event::End(i));
}

fn v4l2_source(i: usize, mut cam: V4l2Camera, tx: SyncSender<Event>, stop: Arc<AtomicBool>) {
    while !stop.load(Ordering::Relaxed) {
        let event = match cam.capture(1000) {
            Ok((header, data)) => Event::Frame {
                camera: i,
                header,
                data: Arc::new(data),
                capture_time_ns: None,
                depth: None,
            },
            Err(e) => Event::Dropped(e.to_string()),
        };
        if tx.send(event).is_err() {
            return;
        }
    }
}

fn run() -> Result<()> {
    let args = StageArgs::parse(STAGE)?;
    let instance = args.instance.as_str();
    farsight_stage::init_tracing(args.log_format);
    let config: IngestConfig = load_config(args.config.as_deref())?;
    let base = args.config_dir();
    let cameras: Vec<Camera> = config
        .cameras
        .iter()
        .enumerate()
        .map(|(i, c)| c.model.build(i as u32, &base))
        .collect::<Result<_, _>>()?;
    let capture_times: Vec<_> = config.cameras.iter().map(|c| c.capture_time).collect();

    let bus = Bus::open(instance)?;
    let mut publishers = Vec::new();
    let mut depth_publishers = Vec::new();
    for cam in &cameras {
        let (w, h) = (cam.model.width as usize, cam.model.height as usize);
        publishers.push((
            bus.slice_publisher(&topics::camera_image(&cam.name), w * h * 3)?,
            bus.publisher(&topics::camera_info(&cam.name))?,
        ));
    }
    for (entry, cam) in config.cameras.iter().zip(&cameras) {
        let (w, h) = (cam.model.width as usize, cam.model.height as usize);
        depth_publishers.push(if entry.depth_folder.is_empty() {
            None
        } else {
            Some(bus.slice_publisher(&topics::depth(&cam.name), w * h * 2)?)
        });
    }
    let mut health = Health::new(&bus, instance, config.health_rate_hz)?;

    // Open every source before announcing readiness: a missing camera or an
    // empty folder is a start-up error, not a silent stream.
    let stop = Arc::new(AtomicBool::new(false));
    let (tx, rx) = sync_channel::<Event>(2 * cameras.len());
    let mut threads = Vec::new();
    // Recordings cut short (camera, where): played up to the cut, then the
    // stage exits 1 naming it.
    let mut truncated = Vec::new();
    for (i, (entry, cam)) in config.cameras.iter().zip(&cameras).enumerate() {
        let size = (cam.model.width, cam.model.height);
        let (tx, stop) = (tx.clone(), stop.clone());
        match entry.source.as_str() {
            "folder" => {
                let folder: PathBuf = base.join(&entry.folder);
                let files = list_images(&folder)
                    .with_context(|| format!("camera {}: folder {}", cam.name, folder.display()))?;
                if files.is_empty() {
                    bail!(
                        "camera {}: folder {} holds no PNG or JPEG images",
                        cam.name,
                        folder.display()
                    );
                }
                tracing::info!(camera = %cam.name, folder = %folder.display(), frames = files.len(), "folder source");
                let entry = entry.clone();
                let depth_dir =
                    (!entry.depth_folder.is_empty()).then(|| base.join(&entry.depth_folder));
                threads.push(std::thread::spawn(move || {
                    folder_source(i, entry, depth_dir, files, size, tx, stop)
                }));
            }
            "mcap" => {
                let path = base.join(&entry.file);
                // The whole file is checked before the stage is ready: not
                // an MCAP file or damaged (a bad chunk CRC) is a start-up
                // error naming the file and the offset.
                let file = McapFile::open(&path)
                    .map_err(anyhow::Error::msg)
                    .with_context(|| format!("camera {}", cam.name))?;
                let contents = file
                    .contents()
                    .map_err(anyhow::Error::msg)
                    .with_context(|| format!("camera {}", cam.name))?;
                let channels = contents.channels;
                if let Some(t) = contents.truncated {
                    tracing::warn!(camera = %cam.name, "{t}; playing the frames before the cut");
                    truncated.push((i, t));
                }
                if !channels.iter().any(|(t, _, _)| *t == entry.topic) {
                    let topics: Vec<String> = channels
                        .iter()
                        .map(|(t, e, s)| format!("{t} ({e}, {s})"))
                        .collect();
                    bail!(
                        "camera {}: no topic {} in {}; it has {topics:?}",
                        cam.name,
                        entry.topic,
                        path.display()
                    );
                }
                tracing::info!(camera = %cam.name, file = %path.display(), topic = %entry.topic, "mcap source");
                let entry = entry.clone();
                threads.push(std::thread::spawn(move || {
                    mcap_source(i, entry, file, size, tx, stop)
                }));
            }
            _ => {
                let format = V4l2Format::parse(&entry.pixel_format).unwrap_or(V4l2Format::Yuyv);
                let device = V4l2Camera::open(&entry.device, format, size.0, size.1)
                    .with_context(|| format!("camera {}", cam.name))?;
                tracing::info!(camera = %cam.name, device = %entry.device, "v4l2 source");
                threads.push(std::thread::spawn(move || v4l2_source(i, device, tx, stop)));
            }
        }
    }
    drop(tx);
    match truncated.first() {
        Some((_, t)) => {
            let name = Path::new(&t.path)
                .file_name()
                .map_or(t.path.clone(), |n| n.to_string_lossy().into_owned());
            health.set(
                HealthState::DEGRADED,
                &format!("{name} truncated at byte {}", t.offset),
            );
        }
        None => health.set(HealthState::OK, ""),
    }
    farsight_stage::announce_ready(instance);
    let mut failed: Option<anyhow::Error> = None;

    let clock = WallClock;
    let mut seq = vec![0u64; cameras.len()];
    let mut ended = 0;
    // Lock-step pacing: the consumer's output topic per camera, if configured.
    let pacers = config
        .cameras
        .iter()
        .map(|c| {
            if c.pace_by.is_empty() {
                return Ok(None);
            }
            let topic = farsight_interfaces::topics::Topic::new(c.pace_by.as_str())
                .map_err(anyhow::Error::from)?;
            Ok(Some((
                bus.slice_subscriber::<ImageHeader, u8>(&topic)?,
                Duration::from_secs_f64(c.pace_timeout_s),
            )))
        })
        .collect::<Result<Vec<_>>>()?;
    let mut pace_timeouts = 0u64;
    loop {
        if bus.termination_requested() {
            tracing::info!("termination requested");
            break;
        }
        let now = clock.now_ns();
        match rx.recv_timeout(Duration::from_millis(100)) {
            Ok(Event::Frame {
                camera,
                header,
                data,
                capture_time_ns,
                depth,
            }) => {
                health.input();
                if let (Some((consumer, timeout)), true) = (&pacers[camera], seq[camera] > 0) {
                    // Wait for the consumer's result for the previous frame.
                    let waiting_since = Instant::now();
                    let mut done = false;
                    while !done && waiting_since.elapsed() < *timeout {
                        // Waiting on a slow consumer is not a hang: keep
                        // reporting (and pinging the watchdog), and stop
                        // waiting when asked to stop.
                        health.tick(clock.now_ns());
                        if bus.termination_requested() {
                            break;
                        }
                        match consumer.latest() {
                            Ok(Some(s)) if s.header().stamp.frame_seq >= seq[camera] => done = true,
                            Ok(_) => std::thread::sleep(Duration::from_millis(1)),
                            Err(e) => {
                                health.dropped(&e);
                                break;
                            }
                        }
                    }
                    if !done {
                        pace_timeouts += 1;
                        tracing::warn!(pace_timeouts, camera = %cameras[camera].name, "consumer did not take frame {} in time", seq[camera]);
                    }
                }
                seq[camera] += 1;
                let cam = &cameras[camera];
                let stamp = Stamp::new(
                    seq[camera],
                    capture_times[camera].pick(capture_time_ns, now),
                );
                // Source times far from the wall clock (a recording): say once
                // why a graph on the wall clock will not move on them.
                if seq[camera] == 1 && now.abs_diff(stamp.capture_time_ns) > 3_600_000_000_000 {
                    tracing::warn!(
                        camera = %cameras[camera].name,
                        offset_s = (stamp.capture_time_ns as f64 - now as f64) * 1e-9,
                        "frames carry their source's capture times, over an hour from the wall clock: \
                         stages on the wall clock judge them stale (the servo will not move); \
                         set capture_time = \"publish\" to stamp them as they go out, or run the graph on clock = \"stamps\""
                    );
                }
                let (frames, info) = &publishers[camera];
                // The camera model goes first: a consumer that needs it (depth
                // normals, bin projection) can use the very first frame.
                let sent = info.publish(&cam.to_info(stamp));
                let sent = sent.and_then(|()| {
                    frames.publish_with(data.len(), |px| {
                        px.copy_from_slice(&data);
                        ImageHeader {
                            stamp,
                            camera_id: cam.id,
                            ..header
                        }
                    })
                });
                // The depth image goes out with the frame's stamp, so consumers can pair them.
                let sent = match (depth, &depth_publishers[camera]) {
                    (Some((dh, dd)), Some(dp)) => sent.and_then(|()| {
                        dp.publish_copy(
                            ImageHeader {
                                stamp,
                                camera_id: cam.id,
                                ..dh
                            },
                            &dd,
                        )
                    }),
                    _ => sent,
                };
                match sent {
                    Ok(()) => health.output(stamp, clock.now_ns()),
                    Err(e) => health.dropped(&e),
                }
            }
            Ok(Event::Dropped(why)) => {
                health.input();
                health.dropped(&why);
            }
            Ok(Event::Failed(camera, why)) => {
                tracing::error!(camera = %cameras[camera].name, "{why}");
                health.set(HealthState::ERROR, &why);
                failed = Some(anyhow::anyhow!("camera {}: {why}", cameras[camera].name));
                break;
            }
            Ok(Event::End(camera)) => {
                ended += 1;
                tracing::info!(camera = %cameras[camera].name, published = seq[camera], "all frames published");
                if ended == cameras.len() {
                    break;
                }
            }
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => break,
        }
        health.tick(clock.now_ns());
    }
    stop.store(true, Ordering::Relaxed);
    drop(rx);
    for t in threads {
        let _ = t.join();
    }
    health.stopping(clock.now_ns());
    if let Some(e) = failed {
        return Err(e);
    }
    // Every source played to its end (not stopped by a signal): a
    // recording that was cut short is reported with where it ends.
    if ended == cameras.len() {
        if let Some((camera, t)) = truncated.into_iter().next() {
            bail!(
                "camera {}: {t}; published {} frames before the cut",
                cameras[camera].name,
                seq[camera]
            );
        }
    }
    Ok(())
}
