//! The frame sources behind the ingest stage: a folder of images, one topic
//! of an MCAP recording, a V4L2 camera. Each is opened (and checked) first,
//! so a missing camera, an empty folder or a damaged recording is a start-up
//! error; then each runs in its own thread, pacing itself (a folder's
//! `rate_hz`, a recording's log times, the camera's own clock), and hands
//! what it reads to the stage through a bounded channel. The bound is the
//! back-pressure: a source whose frames are not taken (a paced camera
//! waiting for its consumer) blocks instead of piling frames up in memory.

use crate::mcap_source::{McapFile, Truncation};
use crate::v4l2::{V4l2Camera, V4l2Format};
use crate::{capture_time_from_name, list_images, read_frame, CameraEntry};
use anyhow::{bail, Context, Result};
use farsight_interfaces::camera::Camera;
use farsight_interfaces::msg::ImageHeader;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::SyncSender;
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// One frame read by a source.
pub(crate) struct Frame {
    pub camera: usize,
    pub header: ImageHeader,
    /// Shared, so a cached frame replayed from memory is not copied on its
    /// way to the stage.
    pub data: Arc<Vec<u8>>,
    pub capture_time_ns: Option<u64>,
    /// The registered depth image, when the source has one.
    pub depth: Option<(ImageHeader, Vec<u8>)>,
}

/// What a source thread sends to the stage.
pub(crate) enum Event {
    Frame(Frame),
    /// A frame that could not be used (unreadable, wrong size): why.
    Dropped(String),
    /// The source cannot go on (a recording damaged under it): why.
    Failed(usize, String),
    /// The source played all it had.
    End(usize),
}

/// An opened source, not yet running.
pub(crate) enum Source {
    Folder {
        entry: CameraEntry,
        depth_dir: Option<PathBuf>,
        files: Vec<PathBuf>,
        size: (u32, u32),
    },
    Mcap {
        entry: CameraEntry,
        file: McapFile,
        size: (u32, u32),
    },
    V4l2(V4l2Camera),
}

impl Source {
    /// Opens camera `cam`'s source as `entry` says, paths relative to
    /// `base`; with where its recording was cut, if it was. Every error
    /// names the camera.
    pub fn open(
        entry: &CameraEntry,
        cam: &Camera,
        base: &Path,
    ) -> Result<(Self, Option<Truncation>)> {
        let size = (cam.model.width, cam.model.height);
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
                let depth_dir =
                    (!entry.depth_folder.is_empty()).then(|| base.join(&entry.depth_folder));
                let source = Self::Folder {
                    entry: entry.clone(),
                    depth_dir,
                    files,
                    size,
                };
                Ok((source, None))
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
                if let Some(t) = &contents.truncated {
                    tracing::warn!(camera = %cam.name, "{t}; playing the frames before the cut");
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
                let source = Self::Mcap {
                    entry: entry.clone(),
                    file,
                    size,
                };
                Ok((source, contents.truncated))
            }
            _ => {
                let format = V4l2Format::parse(&entry.pixel_format).unwrap_or(V4l2Format::Yuyv);
                let device = V4l2Camera::open(&entry.device, format, size.0, size.1)
                    .with_context(|| format!("camera {}", cam.name))?;
                tracing::info!(camera = %cam.name, device = %entry.device, "v4l2 source");
                Ok((Self::V4l2(device), None))
            }
        }
    }

    /// Runs the source as camera `i` in its own thread until it ends, the
    /// channel closes or `stop` is set.
    pub fn spawn(self, i: usize, tx: SyncSender<Event>, stop: Arc<AtomicBool>) -> JoinHandle<()> {
        std::thread::spawn(move || match self {
            Self::Folder {
                entry,
                depth_dir,
                files,
                size,
            } => folder_source(i, entry, depth_dir, files, size, tx, stop),
            Self::Mcap { entry, file, size } => mcap_source(i, entry, file, size, tx, stop),
            Self::V4l2(cam) => v4l2_source(i, cam, tx, stop),
        })
    }
}

/// Reads a 16-bit depth PNG registered to a frame of size `w` x `h`.
fn read_depth(path: &Path, w: u32, h: u32) -> Result<(ImageHeader, Vec<u8>), String> {
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

/// Plays a folder: decode, pace to `rate_hz`, loop; decoded frames are kept
/// after the first pass (within a budget) so looping costs a copy, not a decode.
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
                Ok((header, data)) => Event::Frame(Frame {
                    camera: i,
                    header,
                    data,
                    capture_time_ns: capture_time_from_name(path),
                    depth,
                }),
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
                Ok((header, data)) => Event::Frame(Frame {
                    camera: i,
                    capture_time_ns: Some(header.stamp.capture_time_ns)
                        .filter(|&t| t > 0)
                        .or(Some(frame.log_time_ns)),
                    header,
                    data: Arc::new(data),
                    depth: None,
                }),
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

/// Captures from a V4L2 camera until stopped; it never ends by itself.
fn v4l2_source(i: usize, mut cam: V4l2Camera, tx: SyncSender<Event>, stop: Arc<AtomicBool>) {
    while !stop.load(Ordering::Relaxed) {
        let event = match cam.capture(1000) {
            Ok((header, data)) => Event::Frame(Frame {
                camera: i,
                header,
                data: Arc::new(data),
                capture_time_ns: None,
                depth: None,
            }),
            Err(e) => Event::Dropped(e.to_string()),
        };
        if tx.send(event).is_err() {
            return;
        }
    }
}
