//! LRN's self-supervised affordance labels (LRN section III-A). From a frame
//! and the path the robot then drove, the end of the stretch of that path
//! the frame can see (before it passes out of range or goes behind an
//! obstacle or a crest) is an affordable "hotspot" (1, a Gaussian blob); the
//! path leading to it and the image column above it are not (0); every other
//! pixel is unlabelled. With the simulator's poses and camera model the
//! projection is exact; on a real robot it is as good as the recorded poses.
//!
//! A path that leaves the image through its side gives the frame no label.
//! The paper's hotspot is a frontier, where the tracked path disappears
//! from view; the last point before a side exit is only where the lens
//! ends. Labelled, those points sit on the image's edge columns (a narrow
//! pinhole sees many turns leave it), and a fully convolutional model
//! learns that the image's edges are affordable, which turns LRN's head to
//! the edge bins on every frame.

use crate::run::{RecordedPose, SeenMap};
use farsight_interfaces::camera::Camera;
use nalgebra::Vector3;

/// Label parameters (`farsight dataset` writes them into `dataset.toml`).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LrnLabelConfig {
    /// Path points further from the camera than this are out of sight.
    pub max_range_m: f64,
    /// Frames whose visible stretch of path is shorter get no label (the
    /// robot stood still or turned away).
    pub min_visible_m: f64,
    /// The hotspot blob's standard deviation, in label pixels.
    pub hotspot_sigma_px: f64,
    /// Half the width of the path drawn as "not a hotspot", metres.
    pub path_half_width_m: f64,
    /// A crest hides a path point when a nearer path point within this
    /// bearing rises above its line of sight.
    pub crest_bearing_rad: f64,
}

impl Default for LrnLabelConfig {
    fn default() -> Self {
        Self {
            max_range_m: 100.0,
            min_visible_m: 3.0,
            hotspot_sigma_px: 2.0,
            path_half_width_m: 0.4,
            crest_bearing_rad: 0.1,
        }
    }
}

/// One frame's label, at the camera model's size.
#[derive(Debug, Clone, PartialEq)]
pub struct LrnLabel {
    pub width: usize,
    pub height: usize,
    /// Affordance x 255 where labelled.
    pub value: Vec<u8>,
    pub labelled: Vec<bool>,
    pub hotspot_px: [f64; 2],
    /// Horizontal distance from the camera to the hotspot.
    pub hotspot_range_m: f64,
}

/// A world point seen from a camera on a robot at a pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sighting {
    pub px: [f64; 2],
    /// Along the optical axis, metres.
    pub depth_m: f64,
    /// Horizontal distance from the camera, metres.
    pub range_m: f64,
    pub bearing_rad: f64,
    /// Rise over run of the line of sight (positive = above the camera).
    pub elevation_tan: f64,
}

/// Where a world point appears to `camera` on a robot at `pose`; `None`
/// behind the camera.
pub fn sight(camera: &Camera, pose: &RecordedPose, p: [f64; 3]) -> Option<Sighting> {
    let (s, c) = pose.yaw_rad.sin_cos();
    let d = [
        p[0] - pose.position_m[0],
        p[1] - pose.position_m[1],
        p[2] - pose.position_m[2],
    ];
    let robot = Vector3::new(c * d[0] + s * d[1], -s * d[0] + c * d[1], d[2]);
    let rel = robot - camera.mount.translation_m;
    let optical = camera.mount.robot_from_optical.inverse() * rel;
    let px = camera.model.project(&optical)?;
    let range_m = rel.x.hypot(rel.y);
    Some(Sighting {
        px: [px.x, px.y],
        depth_m: optical.z,
        range_m,
        bearing_rad: rel.y.atan2(rel.x),
        elevation_tan: rel.z / range_m.max(1e-9),
    })
}

/// What a frame sees of the path driven after it (see [`visible_path`]);
/// derefs to the sightings, nearest first.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct VisiblePath {
    pub sightings: Vec<Sighting>,
    /// The path went on out of the image (through a side, or behind the
    /// camera) rather than out of range or out of sight.
    pub left_image: bool,
}

impl std::ops::Deref for VisiblePath {
    type Target = [Sighting];
    fn deref(&self) -> &[Sighting] {
        &self.sightings
    }
}

/// The stretch of `future` (the poses after the frame, in order) that the
/// frame sees: from the first path point inside the image to the last one
/// before the path leaves the image or range, or is hidden by a lethal cell
/// of `seen` or by a crest of the path itself.
pub fn visible_path(
    camera: &Camera,
    pose: &RecordedPose,
    future: &[RecordedPose],
    seen: &SeenMap,
    cfg: &LrnLabelConfig,
) -> VisiblePath {
    let (w, h) = (camera.model.width as f64, camera.model.height as f64);
    let (s, c) = pose.yaw_rad.sin_cos();
    let m = camera.mount.translation_m;
    let eye = [
        pose.position_m[0] + c * m.x - s * m.y,
        pose.position_m[1] + s * m.x + c * m.y,
    ];
    let mut out: Vec<Sighting> = Vec::new();
    for f in future {
        let p = f.position_m;
        let inside = sight(camera, pose, p).filter(|v| {
            v.px[0] >= 0.0 && v.px[0] < w && v.px[1] >= 0.0 && v.px[1] < h && v.depth_m > 0.0
        });
        let visible = inside.filter(|v| {
            v.range_m <= cfg.max_range_m
                && !seen.blocks_sight(eye, [p[0], p[1]], seen.resolution_m)
                && !out.iter().any(|n| {
                    n.range_m < v.range_m - 1.0
                        && (n.bearing_rad - v.bearing_rad).abs() < cfg.crest_bearing_rad
                        && n.elevation_tan > v.elevation_tan + 1e-3
                })
        });
        match (visible, out.is_empty()) {
            (Some(v), _) => out.push(v),
            // Not yet in view (the ground just ahead is below the image).
            (None, true) => {
                if inside.is_some_and(|v| v.range_m > cfg.max_range_m) {
                    break;
                }
            }
            (None, false) => {
                return VisiblePath {
                    sightings: out,
                    left_image: inside.is_none(),
                }
            }
        }
    }
    VisiblePath {
        sightings: out,
        left_image: false,
    }
}

/// Draws the label of a visible path (see the module comment); `None` when
/// the path shows less than `min_visible_m` or leaves the image.
pub fn lrn_label(camera: &Camera, path: &VisiblePath, cfg: &LrnLabelConfig) -> Option<LrnLabel> {
    let (first, last) = (path.first()?, path.last()?);
    if last.range_m - first.range_m < cfg.min_visible_m || path.left_image {
        return None;
    }
    let (w, h) = (camera.model.width as usize, camera.model.height as usize);
    let mut label = LrnLabel {
        width: w,
        height: h,
        value: vec![0; w * h],
        labelled: vec![false; w * h],
        hotspot_px: last.px,
        hotspot_range_m: last.range_m,
    };
    let mark = |x: f64, y: f64, r: f64, value: u8, l: &mut LrnLabel| {
        let (x0, x1) = ((x - r).floor().max(0.0) as usize, (x + r).ceil() as usize);
        let (y0, y1) = ((y - r).floor().max(0.0) as usize, (y + r).ceil() as usize);
        for v in y0..=y1.min(h - 1) {
            for u in x0..=x1.min(w - 1) {
                if (u as f64 - x).hypot(v as f64 - y) <= r {
                    l.labelled[v * w + u] = true;
                    l.value[v * w + u] = value;
                }
            }
        }
    };
    // The path leading to the hotspot: 0, as wide as the robot.
    let fx = camera.model.fx;
    for pair in path.windows(2) {
        let (a, b) = (pair[0], pair[1]);
        let n = ((b.px[0] - a.px[0]).hypot(b.px[1] - a.px[1]) * 2.0)
            .ceil()
            .max(1.0) as usize;
        for k in 0..=n {
            let t = k as f64 / n as f64;
            let depth = a.depth_m + t * (b.depth_m - a.depth_m);
            let r = (fx * cfg.path_half_width_m / depth.max(1e-3)).max(0.5);
            mark(
                a.px[0] + t * (b.px[0] - a.px[0]),
                a.px[1] + t * (b.px[1] - a.px[1]),
                r,
                0,
                &mut label,
            );
        }
    }
    // The column above the hotspot: 0 (sky, canopy, whatever stands beyond).
    let sigma = cfg.hotspot_sigma_px;
    let [hu, hv] = last.px;
    let top = (hv - 2.0 * sigma).floor();
    if top > 0.0 {
        for v in 0..top as usize {
            let (u0, u1) = (
                (hu - sigma).round().max(0.0) as usize,
                (hu + sigma).round() as usize,
            );
            for u in u0..=u1.min(w - 1) {
                label.labelled[v * w + u] = true;
                label.value[v * w + u] = 0;
            }
        }
    }
    // The hotspot: a Gaussian blob of 1.
    let r = 3.0 * sigma;
    for v in (hv - r).floor().max(0.0) as usize..=((hv + r).ceil() as usize).min(h - 1) {
        for u in (hu - r).floor().max(0.0) as usize..=((hu + r).ceil() as usize).min(w - 1) {
            let d2 = (u as f64 - hu).powi(2) + (v as f64 - hv).powi(2);
            if d2 <= r * r {
                let g = (255.0 * (-d2 / (2.0 * sigma * sigma)).exp()).round() as u8;
                let i = v * w + u;
                label.value[i] = if label.labelled[i] {
                    label.value[i].max(g)
                } else {
                    g
                };
                label.labelled[i] = true;
            }
        }
    }
    Some(label)
}

#[cfg(test)]
mod tests {
    use super::*;
    use farsight_interfaces::camera::{CameraModel, Mount};

    /// A level 64x48 pinhole, f = 32, 1 m above the ground at the robot's
    /// origin, looking ahead.
    fn camera() -> Camera {
        Camera::new(
            0,
            "front",
            CameraModel::pinhole(64, 48, 32.0, 32.0, 31.5, 23.5),
            Mount::from_xyz_rpy_deg([0.0, 0.0, 1.0], [0.0, 0.0, 0.0]),
        )
    }

    fn pose(x: f64, y: f64, z: f64) -> RecordedPose {
        RecordedPose {
            capture_time_ns: 0,
            position_m: [x, y, z],
            yaw_rad: 0.0,
        }
    }

    fn straight(to_m: f64) -> Vec<RecordedPose> {
        (1..=(to_m * 10.0) as usize)
            .map(|k| pose(k as f64 * 0.1, 0.0, 0.0))
            .collect()
    }

    #[test]
    fn a_point_on_the_ground_projects_by_hand() {
        // 10 m ahead, 1 m below the eye: v = 23.5 + 32 * 1 / 10 = 26.7.
        let s = sight(&camera(), &pose(0.0, 0.0, 0.0), [10.0, 0.0, 0.0]).unwrap();
        assert!(
            (s.px[0] - 31.5).abs() < 1e-9 && (s.px[1] - 26.7).abs() < 1e-9,
            "{s:?}"
        );
        assert!((s.range_m - 10.0).abs() < 1e-9);
        // 2 m to the left at 10 m: u = 31.5 - 32 * 0.2 = 25.1.
        let s = sight(&camera(), &pose(0.0, 0.0, 0.0), [10.0, 2.0, 0.0]).unwrap();
        assert!((s.px[0] - 25.1).abs() < 1e-9, "{s:?}");
        // The robot turned left by 90 deg: the same point is now to its right.
        let turned = RecordedPose {
            yaw_rad: std::f64::consts::FRAC_PI_2,
            ..pose(0.0, 0.0, 0.0)
        };
        assert!(
            sight(&camera(), &turned, [0.0, -10.0, 0.0]).is_none(),
            "behind"
        );
        let s = sight(&camera(), &turned, [2.0, 10.0, 0.0]).unwrap();
        assert!((s.px[0] - 37.9).abs() < 1e-9, "{s:?}");
        // Standing on a 2 m hill, a point at ground level 0 is 3 m below.
        let s = sight(&camera(), &pose(0.0, 0.0, 2.0), [10.0, 0.0, 0.0]).unwrap();
        assert!((s.px[1] - (23.5 + 32.0 * 0.3)).abs() < 1e-9);
    }

    #[test]
    fn the_visible_path_starts_in_view_and_ends_at_the_range_limit() {
        let cfg = LrnLabelConfig {
            max_range_m: 20.05,
            ..Default::default()
        };
        let path = visible_path(
            &camera(),
            &pose(0.0, 0.0, 0.0),
            &straight(40.0),
            &SeenMap::new(1.0),
            &cfg,
        );
        // The ground enters the image where 23.5 + 32/x < 48: x > 1.306 m.
        assert!((path[0].range_m - 1.4).abs() < 1e-9, "{:?}", path[0]);
        let last = path.last().unwrap();
        assert!((last.range_m - 20.0).abs() < 1e-6, "{last:?}");
        assert!(!path.left_image);
        let label = lrn_label(&camera(), &path, &cfg).unwrap();
        let at = |u: usize, v: usize| (label.labelled[v * 64 + u], label.value[v * 64 + u]);
        // Hotspot at (31.5, 23.5 + 32/20 = 25.1).
        assert!((label.hotspot_px[1] - 25.1).abs() < 1e-6);
        assert_eq!(at(31, 25), (true, 247), "255 exp(-(0.5^2 + 0.1^2) / 8)");
        assert_eq!(at(31, 40), (true, 0), "the path near the robot");
        assert_eq!(at(31, 5), (true, 0), "the column above the hotspot");
        assert_eq!(at(5, 5), (false, 0), "everything else is unlabelled");
        assert_eq!(at(5, 40), (false, 0));
    }

    #[test]
    fn an_obstacle_or_a_crest_hides_the_rest_of_the_path() {
        let cfg = LrnLabelConfig::default();
        let mut seen = SeenMap::new(1.0);
        seen.set(12, 1, f32::INFINITY);
        // The robot stepped aside to y = 2 before the tree and drove on; from
        // the frame the line of sight to (x, 2) crosses the tree's cell
        // (y in [0.5, 1.5) at x = 12) once 24 / x < 1.5, past x = 16.
        let mut around = straight(11.0);
        around.extend((0..60).map(|k| pose(11.0 + k as f64 * 0.25, 2.0, 0.0)));
        let path = visible_path(&camera(), &pose(0.0, 0.0, 0.0), &around, &seen, &cfg);
        let last = path.last().unwrap();
        assert!((15.5..17.5).contains(&last.range_m), "{last:?}");
        assert!(path.len() < 110 + 60, "the path after the tree is cut");
        // A crest: the ground rises 1 m over 10 m, then drops 3 m.
        let hill: Vec<RecordedPose> = (1..=300)
            .map(|k| {
                let x = k as f64 * 0.1;
                pose(
                    x,
                    0.0,
                    if x <= 10.0 {
                        x * 0.1
                    } else {
                        1.0 - (x - 10.0) * 0.3
                    },
                )
            })
            .collect();
        let path = visible_path(
            &camera(),
            &pose(0.0, 0.0, 0.0),
            &hill,
            &SeenMap::new(1.0),
            &cfg,
        );
        let last = path.last().unwrap();
        // Hidden from just past the crest (a nearer point within 1 m does
        // not count, so the cut comes up to half a metre late).
        assert!((10.0..10.6).contains(&last.range_m), "{last:?}");
    }

    #[test]
    fn a_path_that_turns_out_of_the_image_or_a_short_one_is_no_label() {
        let cfg = LrnLabelConfig::default();
        // 5 m ahead, then hard left: the image's left edge is at 31.5/32 ~
        // 44.5 deg.
        let mut turn = straight(5.0);
        turn.extend((1..100).map(|k| pose(5.0, k as f64 * 0.1, 0.0)));
        let path = visible_path(
            &camera(),
            &pose(0.0, 0.0, 0.0),
            &turn,
            &SeenMap::new(1.0),
            &cfg,
        );
        let last = path.last().unwrap();
        assert!(
            last.bearing_rad < (31.5f64 / 32.0).atan() + 1e-9,
            "{last:?}"
        );
        assert!(last.px[0] >= 0.0 && last.px[0] < 1.5, "{last:?}");
        assert!(path.left_image && path.len() > 30, "{path:?}");
        assert!(
            lrn_label(&camera(), &path, &cfg).is_none(),
            "the edge of the lens is no frontier"
        );
        // Standing still: no label.
        let still = vec![pose(0.0, 0.0, 0.0); 50];
        assert!(visible_path(
            &camera(),
            &pose(0.0, 0.0, 0.0),
            &still,
            &SeenMap::new(1.0),
            &cfg
        )
        .is_empty());
        let short = visible_path(
            &camera(),
            &pose(0.0, 0.0, 0.0),
            &straight(3.0),
            &SeenMap::new(1.0),
            &cfg,
        );
        assert!(
            lrn_label(&camera(), &short, &cfg).is_none(),
            "1.4..3 m is under min_visible_m"
        );
    }
}
