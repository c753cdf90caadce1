//! What one recording tells the labellers: the camera, the robot's poses
//! over time, and every cell its local costmaps ever observed (the "local
//! map accumulated over the whole run" of FITAM section IV-B). Read in one
//! pass that skips the images; [`for_each_frame`] then streams the frames, so
//! a long recording never sits in memory.

use crate::DatasetError;
use farsight_interfaces::camera::Camera;
use farsight_interfaces::msg::{CameraInfo, CostCell, CostmapHeader, ImageHeader, Pose};
use farsight_interfaces::topics;
use farsight_interfaces::transport::wire;
use farsight_recording::read::Recording;
use farsight_recording::RecordingError;
use std::collections::HashMap;
use std::path::Path;

/// A robot pose as recorded: world position (z = ground under the robot)
/// and yaw.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RecordedPose {
    pub capture_time_ns: u64,
    pub position_m: [f64; 3],
    pub yaw_rad: f64,
}

/// Every cell the local costmaps observed, newest observation kept.
#[derive(Debug, Clone, Default)]
pub struct SeenMap {
    pub resolution_m: f64,
    cells: HashMap<(i64, i64), f32>,
}

impl SeenMap {
    pub fn new(resolution_m: f64) -> Self {
        Self {
            resolution_m,
            cells: HashMap::new(),
        }
    }

    /// The cell index of a world coordinate (the swath rasteriser's rule).
    pub fn cell_of(&self, x_m: f64) -> i64 {
        (x_m / self.resolution_m).round() as i64
    }

    /// Marks a cell observed with a cost (s/m; infinite = lethal).
    pub fn set(&mut self, gx: i64, gy: i64, cost_s_per_m: f32) {
        self.cells.insert((gx, gy), cost_s_per_m);
    }

    /// Adds a local costmap; unobserved (NaN) cells leave the map as it was.
    pub fn add_costmap(&mut self, h: &CostmapHeader, cells: &[CostCell]) -> Result<(), String> {
        let res = h.resolution_m as f64;
        if self.cells.is_empty() && self.resolution_m == 0.0 {
            self.resolution_m = res;
        }
        if (res - self.resolution_m).abs() > 1e-6 {
            return Err(format!(
                "local costmap resolution changed from {} m to {res} m",
                self.resolution_m
            ));
        }
        let (w, hgt) = (h.width as usize, h.height as usize);
        if cells.len() != w * hgt {
            return Err(format!(
                "local costmap of {w}x{hgt} carries {} cells",
                cells.len()
            ));
        }
        for i in 0..hgt {
            for j in 0..w {
                let c = cells[i * w + j].cost_s_per_m;
                if c.is_nan() {
                    continue;
                }
                let x = h.x_min_m + j as f64 * res;
                let y = h.y_max_m - i as f64 * res;
                self.set(self.cell_of(x), self.cell_of(y), c);
            }
        }
        Ok(())
    }

    /// A cell's cost, `None` if never observed.
    pub fn cost(&self, gx: i64, gy: i64) -> Option<f32> {
        self.cells.get(&(gx, gy)).copied()
    }

    pub fn len(&self) -> usize {
        self.cells.len()
    }

    pub fn is_empty(&self) -> bool {
        self.cells.is_empty()
    }

    /// Whether a lethal cell lies on the segment from `a` to `b` (world
    /// metres), ignoring the last `skip_end_m` before `b`: the place the
    /// robot stood is free, and its own cell must not hide it.
    pub fn blocks_sight(&self, a: [f64; 2], b: [f64; 2], skip_end_m: f64) -> bool {
        let len = (b[0] - a[0]).hypot(b[1] - a[1]);
        let step = self.resolution_m * 0.5;
        let n = ((len - skip_end_m).max(0.0) / step) as usize;
        (1..=n).any(|k| {
            let t = k as f64 * step / len.max(1e-9);
            let (x, y) = (a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]));
            self.cost(self.cell_of(x), self.cell_of(y))
                .is_some_and(|c| c.is_infinite())
        })
    }
}

/// The first pass over a recording.
#[derive(Debug, Clone)]
pub struct RunIndex {
    pub camera: Camera,
    /// Sorted by capture time.
    pub poses: Vec<RecordedPose>,
    pub seen: SeenMap,
    /// Camera frames in the file.
    pub frames: usize,
    /// Where the file was cut (a recorder killed mid-write): everything
    /// before it is used.
    pub truncated: Option<farsight_recording::mcap_file::Truncation>,
}

impl RunIndex {
    /// Reads the camera model, the poses and the local costmaps of
    /// `camera` (its `camera/<name>/image` and `/info` topics, `state/pose`,
    /// `costmap/local`).
    pub fn read(path: &Path, camera: &str) -> Result<Self, DatasetError> {
        let rec = Recording::open(path)?;
        let (info_topic, image_topic) = (
            topics::camera_info(camera).name().to_string(),
            topics::camera_image(camera).name().to_string(),
        );
        let pose_topic = topics::pose().name().to_string();
        let local_topic = topics::costmap("local").name().to_string();
        let mut info: Option<CameraInfo> = None;
        let mut poses = Vec::new();
        let mut seen = SeenMap::default();
        let mut frames = 0;
        let bad = |topic: &str, why: String| RecordingError::Topic {
            topic: topic.to_string(),
            why,
        };
        let truncated = rec.for_each(|m| {
            let t = &*m.topic;
            if t == info_topic && info.is_none() {
                info = Some(wire::decode_message(&m.data).map_err(|e| bad(t, e.to_string()))?);
            } else if t == pose_topic {
                let p: Pose = wire::decode_message(&m.data).map_err(|e| bad(t, e.to_string()))?;
                poses.push(RecordedPose {
                    capture_time_ns: p.stamp.capture_time_ns,
                    position_m: p.position_m,
                    yaw_rad: p.yaw_rad,
                });
            } else if t == local_topic {
                let (h, cells): (CostmapHeader, Vec<CostCell>) =
                    wire::decode_slice(&m.data).map_err(|e| bad(t, e.to_string()))?;
                seen.add_costmap(&h, &cells).map_err(|e| bad(t, e))?;
            } else if t == image_topic {
                frames += 1;
            }
            Ok(())
        })?;
        let info = info.ok_or_else(|| DatasetError::Missing {
            path: path.display().to_string(),
            what: format!("{info_topic} (the camera model)"),
        })?;
        if poses.is_empty() {
            return Err(DatasetError::Missing {
                path: path.display().to_string(),
                what: format!("{pose_topic} (the robot's poses)"),
            });
        }
        if frames == 0 {
            return Err(DatasetError::Missing {
                path: path.display().to_string(),
                what: image_topic,
            });
        }
        poses.sort_by_key(|p| p.capture_time_ns);
        let camera = Camera::from_info(&info).map_err(|e| DatasetError::Message {
            path: path.display().to_string(),
            topic: info_topic.clone(),
            why: e.to_string(),
        })?;
        Ok(Self {
            camera,
            poses,
            seen,
            frames,
            truncated,
        })
    }

    /// The index of the pose nearest in capture time, if within `tol_ns`.
    pub fn pose_at(&self, capture_time_ns: u64, tol_ns: u64) -> Option<usize> {
        let i = self
            .poses
            .partition_point(|p| p.capture_time_ns < capture_time_ns);
        [i.checked_sub(1), Some(i)]
            .into_iter()
            .flatten()
            .filter(|&k| k < self.poses.len())
            .min_by_key(|&k| self.poses[k].capture_time_ns.abs_diff(capture_time_ns))
            .filter(|&k| self.poses[k].capture_time_ns.abs_diff(capture_time_ns) <= tol_ns)
    }
}

/// Calls `f(frame_number, capture_time_ns, header, rgb)` for every `every`-th
/// frame of `camera` (RGB8; compressed frames are decoded).
pub fn for_each_frame(
    path: &Path,
    camera: &str,
    every: usize,
    mut f: impl FnMut(usize, u64, &ImageHeader, &[u8]) -> Result<(), DatasetError>,
) -> Result<(), DatasetError> {
    let rec = Recording::open(path)?;
    let image_topic = topics::camera_image(camera).name().to_string();
    let mut n = 0usize;
    let mut err = None;
    rec.for_each(|m| {
        if *m.topic != *image_topic {
            return Ok(());
        }
        n += 1;
        if !(n - 1).is_multiple_of(every.max(1)) {
            return Ok(());
        }
        let r = (|| {
            let (h, px): (ImageHeader, &[u8]) =
                wire::split_slice(&m.data).map_err(|e| e.to_string())?;
            farsight_imaging::decode_frame(h, px).map_err(|e| e.to_string())
        })();
        match r {
            Ok((h, px)) => {
                if let Err(e) = f(n - 1, h.stamp.capture_time_ns, &h, &px) {
                    err = Some(e);
                }
            }
            Err(why) => {
                err = Some(DatasetError::Message {
                    path: path.display().to_string(),
                    topic: image_topic.clone(),
                    why,
                })
            }
        }
        if err.is_some() {
            return Err(RecordingError::Topic {
                topic: image_topic.clone(),
                why: "stopped".into(),
            });
        }
        Ok(())
    })
    .map_err(|e| err.take().unwrap_or(DatasetError::from(e)))?;
    match err {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn costmaps_accumulate_in_world_cells_and_nan_keeps_what_was_seen() {
        let h = CostmapHeader {
            width: 3,
            height: 2,
            resolution_m: 1.0,
            x_min_m: 10.0,
            y_max_m: 5.0,
            ..Default::default()
        };
        let cell = |c: f32| CostCell {
            cost_s_per_m: c,
            variance: 0.0,
        };
        let mut m = SeenMap::default();
        m.add_costmap(
            &h,
            &[
                cell(0.5),
                cell(f32::INFINITY),
                cell(f32::NAN),
                cell(1.0),
                cell(2.0),
                cell(0.2),
            ],
        )
        .unwrap();
        assert_eq!(m.cost(10, 5), Some(0.5));
        assert_eq!(m.cost(11, 5), Some(f32::INFINITY));
        assert_eq!(m.cost(12, 5), None, "NaN is not an observation");
        assert_eq!(m.cost(12, 4), Some(0.2), "row 1 is one metre south");
        // A later map that did not see (11, 5) keeps it lethal.
        m.add_costmap(&h, &[cell(f32::NAN); 6]).unwrap();
        assert_eq!(m.cost(11, 5), Some(f32::INFINITY));
        let h2 = CostmapHeader {
            resolution_m: 0.5,
            ..h
        };
        let e = m.add_costmap(&h2, &[cell(0.5); 6]).unwrap_err();
        assert!(e.contains("0.5 m"), "{e}");
        assert!(
            m.add_costmap(&h, &[cell(0.5); 5]).is_err(),
            "wrong cell count"
        );
    }

    #[test]
    fn a_recording_cut_mid_write_is_used_up_to_the_cut_and_says_where() {
        let whole = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../tests/fixtures/heldout/recording.mcap");
        let full = RunIndex::read(&whole, "front").unwrap();
        assert!(full.truncated.is_none());
        let bytes = std::fs::read(&whole).unwrap();
        let cut = std::env::temp_dir().join(format!("farsight-cut-{}.mcap", std::process::id()));
        std::fs::write(&cut, &bytes[..bytes.len() * 3 / 5]).unwrap();
        let part = RunIndex::read(&cut, "front");
        std::fs::remove_file(&cut).unwrap();
        let part = part.unwrap();
        let t = part.truncated.expect("the cut is reported");
        assert!(t.offset <= (bytes.len() * 3 / 5) as u64, "{t}");
        assert!(
            part.frames > 0 && part.frames < full.frames,
            "{} of {}",
            part.frames,
            full.frames
        );
    }

    #[test]
    fn a_lethal_cell_between_blocks_sight_but_the_target_cell_does_not() {
        let mut m = SeenMap::new(1.0);
        m.set(5, 0, f32::INFINITY);
        assert!(m.blocks_sight([0.0, 0.0], [10.0, 0.0], 0.5));
        assert!(
            !m.blocks_sight([0.0, 0.0], [10.0, 3.0], 0.5),
            "passes beside"
        );
        assert!(
            !m.blocks_sight([0.0, 0.0], [5.0, 0.0], 1.0),
            "the end is skipped"
        );
    }
}
