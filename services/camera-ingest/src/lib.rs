//! # farsight-camera-ingest
//!
//! Puts camera frames into the graph, with the camera model that goes with
//! them, for one or several cameras (front, rear, ...), each with its own mount
//! and source:
//!
//! - `folder`: PNG/JPEG images sorted by name; names that are Unix timestamps
//!   (ms or ns) become capture times; played at `rate_hz`, `loops` times;
//! - `v4l2`: a V4L2 camera (`/dev/videoN`) delivering YUYV or MJPEG, converted to RGB;
//! - `mcap`: one topic of an MCAP recording (a ROS 2 bag with
//!   `sensor_msgs/msg/Image` or `CompressedImage`, or a farsight recording),
//!   at the recorded pace times `speed`.
//!
//! A broken file (truncated image, wrong size) is logged, counted and skipped;
//! the stream goes on.
//!
//! The stage itself is [`ingest_stage::IngestStage`] (the binary runs it on
//! the stage runtime); its sources, each in its own thread, are in `sources`.
//!
//! Config (`camera-ingest.toml`, defaults shown):
//!
//! ```toml
//! health_rate_hz = 1.0
//!
//! [[cameras]]
//! source = "folder"          # "folder", "mcap" or "v4l2"
//! folder = "frames"          # folder: relative to this file
//! depth_folder = ""          # folder: 16-bit depth PNGs named like the frames -> camera/<name>/depth
//! rate_hz = 10.0             # folder: frames per second
//! loops = 1                  # folder: passes over the folder, 0 = forever
//! device = "/dev/video0"     # v4l2
//! pixel_format = "yuyv"      # v4l2: "yuyv" or "mjpeg"
//! file = "run.mcap"          # mcap: relative to this file
//! topic = "/camera/image_raw" # mcap: the channel to play
//! speed = 1.0                # mcap: 2.0 plays twice as fast
//! pace_by = ""               # as fast as a consumer takes frames: e.g. "perception/front/navigability"
//! pace_timeout_s = 2.0       # with pace_by: publish the next frame anyway after this long
//! capture_time = "source"    # a frame's stamp: "source" (the file name's, the recording's;
//!                            # the moment of publishing when the source has none) or
//!                            # "publish" (the moment it goes out: recorded frames played
//!                            # into a graph on the wall clock, which would judge
//!                            # their source times stale and never move)
//!
//! [cameras.model]            # see farsight_interfaces::camera::CameraConfig
//! name = "front"
//! width = 1280
//! height = 720
//! fx = 1487.75
//! fy = 1471.06
//! cx = 625.01
//! cy = 376.48
//! xyz_m = [0.0, 0.0, 1.6]
//! rpy_deg = [0.0, 0.0, 0.0]  # a rear camera: yaw 180
//! ```

pub mod ingest_stage;
pub mod mcap_source;
pub mod ros_cdr;
mod sources;
pub mod v4l2;

use farsight_interfaces::camera::CameraConfig;
use farsight_interfaces::msg::{ImageHeader, PixelEncoding};
use farsight_interfaces::topics;
use farsight_stage::ranges::RATE_HZ;
use farsight_stage::{ConfigError, Io, Need, Range, Ranges, Validate};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The stage's config file.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IngestConfig {
    pub health_rate_hz: f64,
    pub cameras: Vec<CameraEntry>,
}

/// One camera: where its frames come from and its model.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraEntry {
    #[serde(default = "folder")]
    pub source: String,
    #[serde(default)]
    pub folder: String,
    /// Folder of 16-bit depth PNGs named like the frames (optional).
    #[serde(default)]
    pub depth_folder: String,
    #[serde(default = "ten")]
    pub rate_hz: f64,
    #[serde(default = "one")]
    pub loops: u32,
    #[serde(default = "video0")]
    pub device: String,
    #[serde(default = "yuyv")]
    pub pixel_format: String,
    #[serde(default)]
    pub file: String,
    #[serde(default)]
    pub topic: String,
    #[serde(default = "one_f64")]
    pub speed: f64,
    /// Lock-step with a consumer: publish the next frame only after a message
    /// derived from the previous one appears on this topic (e.g.
    /// `perception/front/navigability`), or after `pace_timeout_s`.
    #[serde(default)]
    pub pace_by: String,
    #[serde(default = "two")]
    pub pace_timeout_s: f64,
    /// Which time a frame's stamp carries.
    #[serde(default)]
    pub capture_time: CaptureTime,
    pub model: CameraConfig,
}

impl Validate for CameraEntry {
    fn ranges(&self, r: &mut Ranges) {
        let m = &self.model;
        let focal = Range::above_to(0.0, 1e6).unit("px");
        let centre = Range::between(-1e6, 1e6).unit("px");
        let side = Range::between(
            1.0,
            f64::from(farsight_imaging::ImageLimits::DEFAULT.max_width),
        )
        .unit("px");
        r.key("rate_hz", self.rate_hz, RATE_HZ)
            .key("loops", self.loops, Range::between(0.0, 1e9))
            .key("speed", self.speed, Range::between(0.01, 100.0))
            .key(
                "pace_timeout_s",
                self.pace_timeout_s,
                Range::above_to(0.0, 3600.0).unit("s"),
            )
            .optional("model.id", m.id, Range::between(0.0, f64::from(u32::MAX)))
            .optional("model.width", m.width, side)
            .optional("model.height", m.height, side)
            .optional("model.fx", m.fx, focal)
            .optional("model.fy", m.fy, focal)
            .optional("model.cx", m.cx, centre)
            .optional("model.cy", m.cy, centre)
            .each("model.distortion", &m.distortion, Range::between(-1e3, 1e3))
            // Mount offsets are signed: behind, right of or below base_link.
            .each(
                "model.xyz_m",
                &m.xyz_m,
                Range::between(-100.0, 100.0).unit("m"),
            )
            .each(
                "model.rpy_deg",
                &m.rpy_deg,
                Range::between(-360.0, 360.0).unit("deg"),
            );
    }
}

impl farsight_stage::DeclaresTopics for IngestConfig {
    fn topics(&self, instance: &str, _: &Path) -> Result<Io, String> {
        let mut io = Io::for_instance(instance);
        for c in &self.cameras {
            let name = &c.model.name;
            io.write(topics::camera_image(name).name())
                .write(topics::camera_info(name).name());
            if !c.depth_folder.is_empty() {
                io.write(topics::depth(name).name());
            }
            if !c.pace_by.is_empty() {
                // Lock-step: without an answer it waits pace_timeout_s per frame.
                io.read(c.pace_by.clone(), Need::Optional);
            }
        }
        Ok(io)
    }
}

/// The capture time a frame is stamped with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CaptureTime {
    /// The source's own (file name, recording); the publishing moment when
    /// the source has none.
    #[default]
    Source,
    /// The moment the frame is published.
    Publish,
}

impl CaptureTime {
    /// The stamp's capture time for a frame with `source_ns` published at `now_ns`.
    pub fn pick(self, source_ns: Option<u64>, now_ns: u64) -> u64 {
        match self {
            Self::Source => source_ns.unwrap_or(now_ns),
            Self::Publish => now_ns,
        }
    }
}

fn folder() -> String {
    "folder".into()
}
fn ten() -> f64 {
    10.0
}
fn one() -> u32 {
    1
}
fn two() -> f64 {
    2.0
}
fn one_f64() -> f64 {
    1.0
}
fn video0() -> String {
    "/dev/video0".into()
}
fn yuyv() -> String {
    "yuyv".into()
}

impl Default for IngestConfig {
    fn default() -> Self {
        Self {
            health_rate_hz: 1.0,
            cameras: vec![CameraEntry {
                source: folder(),
                folder: "frames".into(),
                depth_folder: String::new(),
                rate_hz: 10.0,
                loops: 1,
                device: video0(),
                pixel_format: yuyv(),
                file: String::new(),
                topic: String::new(),
                speed: 1.0,
                pace_by: String::new(),
                pace_timeout_s: 2.0,
                capture_time: CaptureTime::Source,
                model: CameraConfig {
                    name: "front".into(),
                    id: None,
                    model: None,
                    width: Some(1280),
                    height: Some(720),
                    fx: Some(1487.75),
                    fy: Some(1471.06),
                    cx: Some(625.01),
                    cy: Some(376.48),
                    distortion: vec![],
                    camera_info: None,
                    xyz_m: [0.0, 0.0, 1.0],
                    rpy_deg: [0.0; 3],
                },
            }],
        }
    }
}

impl Validate for IngestConfig {
    fn ranges(&self, r: &mut Ranges) {
        r.key("health_rate_hz", self.health_rate_hz, RATE_HZ);
        for (i, c) in self.cameras.iter().enumerate() {
            r.nested(&format!("cameras[{i}]"), c);
        }
    }

    fn check_rules(&self) -> Result<(), ConfigError> {
        ConfigError::check(
            !self.cameras.is_empty(),
            "cameras",
            "[]",
            "at least one [[cameras]] table",
        )?;
        let mut names = std::collections::HashSet::new();
        for (i, c) in self.cameras.iter().enumerate() {
            let key = |k: &str| format!("cameras[{i}].{k}");
            ConfigError::check(
                names.insert(c.model.name.clone()),
                &key("model.name"),
                &c.model.name,
                "a name used once",
            )?;
            if !c.pace_by.is_empty() {
                let kind = farsight_interfaces::topics::kind_of(&c.pace_by);
                ConfigError::check(
                    matches!(kind, Some(farsight_interfaces::topics::TopicKind::Image)),
                    &key("pace_by"),
                    &c.pace_by,
                    "an image topic derived from this camera's frames (e.g. perception/<camera>/navigability)",
                )?;
            }
            match c.source.as_str() {
                "folder" => {
                    ConfigError::check(
                        !c.folder.is_empty(),
                        &key("folder"),
                        "\"\"",
                        "a folder of PNG/JPEG images",
                    )?;
                }
                "v4l2" => {
                    ConfigError::check(
                        v4l2::V4l2Format::parse(&c.pixel_format).is_some(),
                        &key("pixel_format"),
                        &c.pixel_format,
                        "\"yuyv\" or \"mjpeg\"",
                    )?;
                }
                "mcap" => {
                    ConfigError::check(
                        !c.file.is_empty(),
                        &key("file"),
                        "\"\"",
                        "an MCAP recording",
                    )?;
                    ConfigError::check(
                        !c.topic.is_empty(),
                        &key("topic"),
                        "\"\"",
                        "the image topic to play",
                    )?;
                }
                other => {
                    return Err(ConfigError::invalid(
                        key("source"),
                        other,
                        "\"folder\", \"v4l2\" or \"mcap\"",
                    ))
                }
            }
        }
        Ok(())
    }
}

/// The images of a folder source, in name order.
pub fn list_images(folder: &Path) -> std::io::Result<Vec<PathBuf>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(folder)?
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            p.extension().and_then(|e| e.to_str()).is_some_and(|e| {
                ["png", "jpg", "jpeg"]
                    .iter()
                    .any(|x| e.eq_ignore_ascii_case(x))
            })
        })
        .collect();
    files.sort();
    Ok(files)
}

/// Capture time from a file name that is a Unix timestamp: milliseconds
/// (13 digits today) or nanoseconds (19 digits). `None` for other names.
pub fn capture_time_from_name(path: &Path) -> Option<u64> {
    let stem = path.file_stem()?.to_str()?;
    let v: u64 = stem.parse().ok()?;
    match stem.len() {
        10..=14 => v.checked_mul(1_000_000),
        16..=20 => Some(v),
        _ => None,
    }
}

/// Why a frame was skipped.
#[derive(Debug, thiserror::Error)]
pub enum FrameError {
    #[error("{path}: {source}")]
    Read {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: {source}")]
    Decode {
        path: String,
        #[source]
        source: farsight_imaging::ImageError,
    },
    #[error("{path}: image is {got_w}x{got_h}, the camera model says {want_w}x{want_h}")]
    WrongSize {
        path: String,
        got_w: u32,
        got_h: u32,
        want_w: u32,
        want_h: u32,
    },
}

/// Reads one PNG or JPEG frame as packed RGB8 (or MONO8), checked against the camera size.
pub fn read_frame(
    path: &Path,
    width: u32,
    height: u32,
) -> Result<(ImageHeader, Vec<u8>), FrameError> {
    let p = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| FrameError::Read {
        path: p.clone(),
        source,
    })?;
    // Never larger than the camera: checked from the file's header before
    // any pixel buffer is allocated.
    let limits = farsight_imaging::ImageLimits {
        max_width: width,
        max_height: height,
    };
    let (mut h, mut data) =
        farsight_imaging::decode_image_within(&bytes, limits).map_err(|source| {
            FrameError::Decode {
                path: p.clone(),
                source,
            }
        })?;
    if (h.width, h.height) != (width, height) {
        return Err(FrameError::WrongSize {
            path: p,
            got_w: h.width,
            got_h: h.height,
            want_w: width,
            want_h: height,
        });
    }
    if h.encoding == PixelEncoding::RGBA8 {
        data = data
            .chunks_exact(4)
            .flat_map(|px| [px[0], px[1], px[2]])
            .collect();
        h = ImageHeader::packed(h.stamp, h.camera_id, h.width, h.height, PixelEncoding::RGB8);
    }
    Ok((h, data))
}

#[cfg(test)]
mod tests {
    use super::*;
    use farsight_interfaces::msg::Stamp;

    #[test]
    fn config_errors_name_the_camera() {
        let e = farsight_stage::parse_config::<IngestConfig>(
            "[[cameras]]\nsource = \"usb\"\n[cameras.model]\nname = \"front\"\n",
            "c.toml",
        )
        .unwrap_err();
        assert_eq!(
            e.to_string(),
            "config key `cameras[0].source` = usb: expected \"folder\", \"v4l2\" or \"mcap\""
        );
        let two = "[[cameras]]\nfolder = \"a\"\n[cameras.model]\nname = \"front\"\n[[cameras]]\nfolder = \"b\"\n[cameras.model]\nname = \"front\"\n";
        let e = farsight_stage::parse_config::<IngestConfig>(two, "c.toml").unwrap_err();
        assert!(
            e.to_string()
                .starts_with("config key `cameras[1].model.name` = front"),
            "{e}"
        );
    }

    #[test]
    fn capture_time_is_the_sources_unless_stamped_on_publishing() {
        assert_eq!(CaptureTime::Source.pick(Some(5), 9), 5);
        assert_eq!(CaptureTime::Source.pick(None, 9), 9);
        assert_eq!(CaptureTime::Publish.pick(Some(5), 9), 9);
        let c: IngestConfig = farsight_stage::parse_config(
            "[[cameras]]\nfolder = \"frames\"\ncapture_time = \"publish\"\n[cameras.model]\nname = \"front\"\nwidth = 64\nheight = 48\nfx = 50.0\nfy = 50.0\ncx = 32.0\ncy = 24.0\n",
            "t.toml",
        )
        .unwrap();
        assert_eq!(c.cameras[0].capture_time, CaptureTime::Publish);
        let e = farsight_stage::parse_config::<IngestConfig>(
            "[[cameras]]\ncapture_time = \"now\"\n[cameras.model]\nname = \"front\"\n",
            "t.toml",
        )
        .unwrap_err();
        assert!(e.to_string().contains("capture_time"), "{e}");
    }

    #[test]
    fn timestamps_from_names() {
        assert_eq!(
            capture_time_from_name(Path::new("1623170389760.png")),
            Some(1_623_170_389_760_000_000)
        );
        assert_eq!(
            capture_time_from_name(Path::new("1623170389760000000.png")),
            Some(1_623_170_389_760_000_000)
        );
        assert_eq!(capture_time_from_name(Path::new("frame_01.png")), None);
        assert_eq!(capture_time_from_name(Path::new("12.png")), None);
    }

    #[test]
    fn broken_and_wrong_size_frames_are_errors() {
        let dir = std::env::temp_dir().join(format!("ingest-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let h = ImageHeader::packed(Stamp::default(), 0, 8, 4, PixelEncoding::RGB8);
        let png = farsight_imaging::encode_png(&h, &[9u8; 8 * 4 * 3]).unwrap();
        std::fs::write(dir.join("a.png"), &png).unwrap();
        std::fs::write(dir.join("b.png"), &png[..png.len() / 2]).unwrap();
        std::fs::write(dir.join("c.txt"), b"x").unwrap();
        std::fs::write(
            dir.join("d.jpg"),
            farsight_imaging::encode_jpeg(&h, &[9u8; 8 * 4 * 3], 90).unwrap(),
        )
        .unwrap();
        let files = list_images(&dir).unwrap();
        assert_eq!(files.len(), 3);
        let (jh, _) = read_frame(&files[2], 8, 4).unwrap();
        assert_eq!((jh.width, jh.encoding), (8, PixelEncoding::RGB8));
        let (fh, data) = read_frame(&files[0], 8, 4).unwrap();
        assert_eq!((fh.width, data.len()), (8, 96));
        assert!(matches!(
            read_frame(&files[1], 8, 4),
            Err(FrameError::Decode { .. })
        ));
        let e = read_frame(&files[0], 16, 4).unwrap_err();
        assert!(
            e.to_string()
                .ends_with("image is 8x4, the camera model says 16x4"),
            "{e}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
