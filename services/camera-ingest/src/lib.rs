//! # farsight-camera-ingest
//!
//! Puts camera frames into the graph, with the camera model that goes with
//! them. This version reads a folder of PNG images (sorted by name); file names
//! that are Unix timestamps become capture times. A broken file is logged,
//! counted and skipped; the stream goes on.
//!
//! Config (`camera-ingest.toml`, defaults shown):
//!
//! ```toml
//! folder = "frames"          # relative to the config file
//! rate_hz = 10.0             # frames per second
//! loops = 1                  # passes over the folder; 0 = forever
//! health_rate_hz = 1.0
//!
//! [camera]                   # see farsight_interfaces::camera::CameraConfig
//! name = "front"
//! width = 1280
//! height = 720
//! fx = 1487.75
//! fy = 1471.06
//! cx = 625.01
//! cy = 376.48
//! ```

use farsight_interfaces::camera::CameraConfig;
use farsight_interfaces::msg::{ImageHeader, PixelEncoding};
use farsight_stage::{ConfigError, Validate};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The stage's config file.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IngestConfig {
    pub folder: String,
    pub rate_hz: f64,
    pub loops: u32,
    pub health_rate_hz: f64,
    pub camera: CameraConfig,
}

impl Default for IngestConfig {
    fn default() -> Self {
        Self {
            folder: "frames".into(),
            rate_hz: 10.0,
            loops: 1,
            health_rate_hz: 1.0,
            camera: CameraConfig {
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
        }
    }
}

impl Validate for IngestConfig {
    fn validate(&self) -> Result<(), ConfigError> {
        ConfigError::check(
            self.rate_hz > 0.0 && self.rate_hz.is_finite(),
            "rate_hz",
            self.rate_hz,
            "a positive rate in Hz",
        )?;
        ConfigError::check(
            self.health_rate_hz > 0.0,
            "health_rate_hz",
            self.health_rate_hz,
            "a positive rate in Hz",
        )?;
        ConfigError::check(
            !self.folder.is_empty(),
            "folder",
            "\"\"",
            "a folder of PNG images",
        )
    }
}

/// The images of a folder source, in name order.
pub fn list_images(folder: &Path) -> std::io::Result<Vec<PathBuf>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(folder)?
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            p.extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| e.eq_ignore_ascii_case("png"))
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

/// Reads one frame as packed RGB8 (or MONO8), checked against the camera size.
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
    let (mut h, mut data) =
        farsight_imaging::decode_png(&bytes).map_err(|source| FrameError::Decode {
            path: p.clone(),
            source,
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
        let files = list_images(&dir).unwrap();
        assert_eq!(files.len(), 2);
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
