//! # farsight-bin-projection
//!
//! LRN's affordance backbone after the heatmap (section III-B, Algorithm 2):
//! every heatmap pixel goes to the angular bin of its bearing in the robot
//! frame (from the camera model and mount: pinhole or fisheye, any facing),
//! scores are summed per bin, thresholded, combined across cameras by max,
//! normalised by their sum and smoothed over time with an EMA. A bin no camera
//! sees is *unobserved*, which is not the same as a bin with no affordance.
//!
//! [`fitam`] is FITAM's counterpart: far-field ensemble outputs per image
//! slice -> polar (heading x range) cost bins with a measurement variance.
//!
//! [`projection_stage`] is the stage that runs either per frame (its binary
//! is only the wiring); `farsight_stage::CameraModels` keeps each camera's
//! newest model.
//!
//! ```
//! use farsight_bin_projection::{BinGeometry, CameraBins, LrnBinsConfig, LrnBins};
//! use farsight_interfaces::camera::{Camera, CameraModel, Mount};
//!
//! let geometry = BinGeometry::from_width_deg(5.0);
//! let cam = Camera::new(0, "front", CameraModel::pinhole(64, 32, 40.0, 40.0, 32.0, 16.0),
//!                       Mount::from_xyz_rpy_deg([0.0; 3], [0.0; 3]));
//! let map = CameraBins::new(&cam, 64, 32, &geometry);
//! let mut bins = LrnBins::new(geometry, LrnBinsConfig::default());
//! let heatmap = vec![1.0f32; 64 * 32];
//! let out = bins.update(&[(map.project(&heatmap, 0.5))]);
//! assert!(out.observed.iter().any(|&o| o) && !out.observed.iter().all(|&o| o));
//! ```

pub mod fitam;
pub mod projection_stage;
pub mod stage;

use farsight_interfaces::camera::Camera;
use farsight_stage::{Range, Ranges, Validate};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// Angular bins all around the robot: bin `i` covers
/// `[-pi + i * width, -pi + (i + 1) * width)`, counter-clockwise, 0 = ahead.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BinGeometry {
    pub count: usize,
}

impl BinGeometry {
    /// Bins of (about) `width_deg` degrees: 360 / width, rounded.
    pub fn from_width_deg(width_deg: f64) -> Self {
        Self {
            count: (360.0 / width_deg).round().max(1.0) as usize,
        }
    }

    pub fn width_rad(&self) -> f64 {
        2.0 * PI / self.count as f64
    }

    pub fn start_rad(&self) -> f64 {
        -PI
    }

    /// The bin of a bearing (any angle, wrapped).
    pub fn bin_of(&self, bearing_rad: f64) -> usize {
        let a = (bearing_rad + PI).rem_euclid(2.0 * PI);
        ((a / self.width_rad()) as usize).min(self.count - 1)
    }

    /// Bearing of the centre of bin `i`.
    pub fn center_rad(&self, i: usize) -> f64 {
        -PI + (i as f64 + 0.5) * self.width_rad()
    }
}

/// One camera's projection: per-bin score sums, and which bins it sees.
pub type Projection = (Vec<f64>, Vec<bool>);

/// Which pixel of one camera's heatmap falls in which bin (computed once per
/// camera and heatmap size: un-projecting a fisheye is iterative).
///
/// Along an image row the bearing changes monotonically for most lenses, so
/// the table is stored as runs of consecutive pixels in the same bin: the
/// per-frame work is then a contiguous (vectorised) sum per run rather than a
/// scatter-add per pixel, which is what keeps 1280x720 inside the budget.
#[derive(Debug, Clone)]
pub struct CameraBins {
    pub width: usize,
    pub height: usize,
    runs: Vec<BinRun>,
    seen: Vec<bool>,
    count: usize,
}

/// Pixels `start..end` of the flattened image all fall in `bin`.
#[derive(Debug, Clone, Copy)]
struct BinRun {
    start: u32,
    end: u32,
    bin: u32,
}

const NO_BIN: u32 = u32::MAX;

/// Sum of the values of `xs` that are finite and at least `threshold`, in
/// eight independent lanes so the compiler can vectorise it (a plain `sum`
/// must keep the sequential order of float additions).
fn thresholded_sum(xs: &[f32], threshold: f32) -> f64 {
    let keep = |h: f32| {
        if h >= threshold && h <= f32::MAX {
            h
        } else {
            0.0
        }
    };
    let mut lanes = [0f32; 8];
    let mut chunks = xs.chunks_exact(8);
    for c in &mut chunks {
        for (l, &h) in lanes.iter_mut().zip(c) {
            *l += keep(h);
        }
    }
    let tail: f32 = chunks.remainder().iter().map(|&h| keep(h)).sum();
    lanes.iter().map(|&l| l as f64).sum::<f64>() + tail as f64
}

impl CameraBins {
    pub fn new(camera: &Camera, width: usize, height: usize, geometry: &BinGeometry) -> Self {
        let scaled = Camera {
            model: camera.model.scaled_to(width as u32, height as u32),
            ..camera.clone()
        };
        let mut runs: Vec<BinRun> = Vec::new();
        let mut seen = vec![false; geometry.count];
        for v in 0..height {
            for u in 0..width {
                let bin = match scaled.pixel_bearing_rad(u as f64, v as f64) {
                    Some(b) => geometry.bin_of(b) as u32,
                    None => NO_BIN,
                };
                let i = (v * width + u) as u32;
                match runs.last_mut() {
                    // Runs never cross a row end: `bin_at` and the heatmap
                    // length check stay simple.
                    Some(r) if r.bin == bin && r.end == i && u > 0 => r.end += 1,
                    _ => runs.push(BinRun {
                        start: i,
                        end: i + 1,
                        bin,
                    }),
                }
                if bin != NO_BIN {
                    seen[bin as usize] = true;
                }
            }
        }
        runs.retain(|r| r.bin != NO_BIN);
        Self {
            width,
            height,
            runs,
            seen,
            count: geometry.count,
        }
    }

    /// The bin of pixel (u, v), `None` for a pixel straight up or down.
    pub fn bin_at(&self, u: usize, v: usize) -> Option<usize> {
        let i = (v * self.width + u) as u32;
        let k = self.runs.partition_point(|r| r.end <= i);
        self.runs
            .get(k)
            .filter(|r| r.start <= i)
            .map(|r| r.bin as usize)
    }

    /// Per-bin sums of the heatmap values that reach `pixel_threshold` (NaN
    /// and infinities count as nothing), and which bins this camera sees at
    /// all. A heatmap of the wrong size sums only the pixels both share.
    pub fn project(&self, heatmap: &[f32], pixel_threshold: f32) -> Projection {
        let mut sums = vec![0.0; self.count];
        for r in &self.runs {
            let (start, end) = (r.start as usize, (r.end as usize).min(heatmap.len()));
            if start < end {
                sums[r.bin as usize] += thresholded_sum(&heatmap[start..end], pixel_threshold);
            }
        }
        (sums, self.seen.clone())
    }
}

/// Per pixel of a `width` x `height` image from `camera`, the range (m) at
/// which its ray meets flat ground, at most `cap_m`; 0 for a ray at or
/// above the horizon. The depth of [`LrnInput::Navigability`]: on flat
/// ground it is the true depth of every ground pixel, which is all the
/// navigability keeps.
pub fn ground_range_table(camera: &Camera, width: usize, height: usize, cap_m: f64) -> Vec<f32> {
    let scaled = Camera {
        model: camera.model.scaled_to(width as u32, height as u32),
        ..camera.clone()
    };
    let mut out = Vec::with_capacity(width * height);
    for v in 0..height {
        for u in 0..width {
            let r = scaled
                .ground_point_m(u as f64, v as f64)
                .map_or(0.0, |(x, y)| x.hypot(y).min(cap_m));
            out.push(r as f32);
        }
    }
    out
}

/// LRN section IV-D's "Traversability + Depth" heatmap into `out` (reused
/// frame to frame): each navigable pixel (mono8 at least 128) scores its
/// range over the farthest navigable pixel's, the rest 0. All zeros when
/// nothing navigable has a range.
pub fn traversability_depth_heatmap(navigability: &[u8], range_m: &[f32], out: &mut Vec<f32>) {
    let n = navigability.len().min(range_m.len());
    out.clear();
    out.extend(
        navigability[..n]
            .iter()
            .zip(&range_m[..n])
            .map(|(&nav, &r)| if nav >= 128 { r } else { 0.0 }),
    );
    let far = out.iter().copied().fold(0.0f32, f32::max);
    if far > 0.0 {
        out.iter_mut().for_each(|v| *v /= far);
    }
}

/// Where LRN's `h_thresh` applies. The paper's text thresholds bin scores; its
/// Remark III treats it as the heatmap's quality knob. Pixels is the default:
/// a bin sum grows with the bin's pixel count, so one threshold cannot serve
/// both narrow fisheye bins and wide pinhole ones.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum ThresholdOn {
    #[default]
    Pixels,
    /// Bin sums relative to the largest bin.
    Bins,
}

/// What LRN's bins are summed from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum LrnInput {
    /// An affordance heatmap (`perception/<camera>/heatmap`, f32): LRN.
    #[default]
    Heatmap,
    /// A segmentation's navigability (`perception/<camera>/navigability`,
    /// mono8, 255 = navigable) times each pixel's flat-ground range,
    /// normalised by the frame's farthest navigable pixel: LRN section
    /// IV-D's "Traversability + Depth" baseline ("distant traversable
    /// points should be hotspots"; the scores normalised and multiplied).
    /// For users without a trained heatmap.
    Navigability,
}

/// LRN bin parameters (Spot preset: 5 degree bins, h_thresh 0.7, alpha 0.1).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LrnBinsConfig {
    pub bin_width_deg: f64,
    pub h_thresh: f32,
    pub threshold_on: ThresholdOn,
    /// EMA weight of the newest scores.
    pub alpha: f64,
    pub input: LrnInput,
    /// With `input = "navigability"`: ranges beyond this count as this
    /// (m); rays near the horizon meet flat ground arbitrarily far away.
    pub range_cap_m: f64,
}

impl Default for LrnBinsConfig {
    fn default() -> Self {
        Self {
            bin_width_deg: 5.0,
            h_thresh: 0.7,
            threshold_on: ThresholdOn::Pixels,
            alpha: 0.1,
            input: LrnInput::Heatmap,
            range_cap_m: 100.0,
        }
    }
}

impl LrnBinsConfig {
    /// The threshold [`CameraBins::project`] applies to each pixel: `h_thresh`
    /// when thresholding pixels, otherwise 0 (every non-negative score counts).
    pub fn pixel_threshold(&self) -> f32 {
        match self.threshold_on {
            ThresholdOn::Pixels => self.h_thresh,
            ThresholdOn::Bins => 0.0,
        }
    }
}

impl Validate for LrnBinsConfig {
    fn ranges(&self, r: &mut Ranges) {
        r.key(
            "bin_width_deg",
            self.bin_width_deg,
            Range::between(1.0, 90.0).unit("deg"),
        )
        .key("h_thresh", self.h_thresh, Range::between(0.0, 1.0))
        .key("alpha", self.alpha, Range::above_to(0.0, 1.0))
        .key(
            "range_cap_m",
            self.range_cap_m,
            Range::above_to(0.0, 10_000.0).unit("m"),
        );
    }
}

/// One update's result.
#[derive(Debug, Clone, PartialEq)]
pub struct BinScores {
    /// EMA-filtered, normalised scores (0 where unobserved).
    pub scores: Vec<f64>,
    pub observed: Vec<bool>,
}

/// The filtered bin state across frames.
pub struct LrnBins {
    pub geometry: BinGeometry,
    cfg: LrnBinsConfig,
    filtered: Vec<f64>,
}

impl LrnBins {
    pub fn new(geometry: BinGeometry, cfg: LrnBinsConfig) -> Self {
        Self {
            geometry,
            cfg,
            filtered: vec![0.0; geometry.count],
        }
    }

    /// Combines one projection per camera: max across cameras, threshold,
    /// normalise by the sum, EMA.
    pub fn update(&mut self, per_camera: &[Projection]) -> BinScores {
        let k = self.geometry.count;
        let mut b = vec![0.0f64; k];
        let mut observed = vec![false; k];
        for (sums, seen) in per_camera {
            for i in 0..k {
                b[i] = b[i].max(sums[i]);
                observed[i] |= seen[i];
            }
        }
        if self.cfg.threshold_on == ThresholdOn::Bins {
            let max = b.iter().copied().fold(0.0, f64::max);
            if max > 0.0 {
                for v in b.iter_mut() {
                    if *v / max < self.cfg.h_thresh as f64 {
                        *v = 0.0;
                    }
                }
            }
        }
        let total: f64 = b.iter().sum();
        if total > 0.0 {
            for v in b.iter_mut() {
                *v /= total;
            }
        }
        let a = self.cfg.alpha;
        for i in 0..k {
            self.filtered[i] = a * b[i] + (1.0 - a) * self.filtered[i];
            if !observed[i] {
                self.filtered[i] = 0.0;
            }
        }
        BinScores {
            scores: self.filtered.clone(),
            observed,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use farsight_interfaces::camera::{CameraModel, Lens, Mount};

    #[test]
    fn the_traversability_heatmap_is_navigable_range_over_the_farthest() {
        let mut h = Vec::new();
        traversability_depth_heatmap(&[255, 255, 0, 200, 90], &[2.0, 8.0, 50.0, 4.0, 9.0], &mut h);
        assert_eq!(h, vec![0.25, 1.0, 0.0, 0.5, 0.0]);
        traversability_depth_heatmap(&[0, 255], &[3.0, 0.0], &mut h);
        assert_eq!(h, vec![0.0, 0.0], "the buffer is refilled, not appended to");
        // 1 m up, level: the lower half meets the ground, nearer lower down;
        // the upper half never does.
        let cam = Camera::new(
            0,
            "c",
            farsight_interfaces::camera::CameraModel::pinhole(8, 8, 4.0, 4.0, 3.5, 3.5),
            farsight_interfaces::camera::Mount::from_xyz_rpy_deg([0.0, 0.0, 1.0], [0.0; 3]),
        );
        let r = ground_range_table(&cam, 8, 8, 50.0);
        assert!(r[..4 * 8].iter().all(|&x| x == 0.0));
        assert!(
            r[4 * 8 + 3] == 50.0 || r[4 * 8 + 3] > r[5 * 8 + 3],
            "capped"
        );
        assert!(r[5 * 8 + 3] > r[7 * 8 + 3] && r[7 * 8 + 3] > 1.0);
    }

    #[test]
    fn bins_wrap_and_centre() {
        let g = BinGeometry::from_width_deg(90.0); // 4 bins: back-right, right-front... from -pi
        assert_eq!(g.count, 4);
        assert_eq!(g.bin_of(0.0), 2, "ahead is the first bin past 0");
        assert_eq!(g.bin_of(-0.1), 1);
        assert_eq!(g.bin_of(PI), 0, "+pi wraps to -pi");
        assert_eq!(g.bin_of(3.0 * PI), 0);
        assert!((g.center_rad(2) - PI / 4.0).abs() < 1e-12);
    }

    #[test]
    fn pinhole_pixels_by_hand() {
        // 20 px wide, f = 10, cx = 10: pixel u has bearing atan((10 - u) / 10)
        // (left is positive). 10-degree bins; bin 18 covers [0, 10) degrees.
        let cam = Camera::new(
            0,
            "f",
            CameraModel::pinhole(20, 2, 10.0, 10.0, 10.0, 1.0),
            Mount::from_xyz_rpy_deg([0.0; 3], [0.0; 3]),
        );
        let g = BinGeometry::from_width_deg(10.0);
        let m = CameraBins::new(&cam, 20, 2, &g);
        // u = 9: atan(0.1) = 5.7 deg -> bin 18; u = 8: atan(0.2) = 11.3 deg -> bin 19;
        // u = 10: 0 deg -> bin 18; u = 11: -5.7 deg -> bin 17; u = 0: 45 deg -> bin 22.
        assert_eq!(m.bin_at(9, 0), Some(18));
        assert_eq!(m.bin_at(8, 0), Some(19));
        assert_eq!(m.bin_at(10, 0), Some(18));
        assert_eq!(m.bin_at(11, 0), Some(17));
        assert_eq!(m.bin_at(0, 0), Some(22));
    }

    #[test]
    fn rear_and_fisheye_cameras_by_hand() {
        let g = BinGeometry::from_width_deg(10.0);
        // Rear pinhole: its centre looks at 180 deg -> bin 0 (or 35 at -180).
        let rear = Camera::new(
            1,
            "r",
            CameraModel::pinhole(20, 2, 10.0, 10.0, 10.0, 1.0),
            Mount::from_xyz_rpy_deg([0.0; 3], [0.0, 0.0, 180.0]),
        );
        let m = CameraBins::new(&rear, 20, 2, &g);
        // u = 9 is left in the rear image, i.e. the robot's right-behind: 180 - 5.7 = -174.3 deg -> bin 0.
        assert_eq!(m.bin_at(9, 0), Some(0));
        // u = 11: 180 + 5.7 = -174.3... mirrored: 174.3 deg -> bin 35.
        assert_eq!(m.bin_at(11, 0), Some(35));
        // Equidistant fisheye, f chosen so the left edge (u = 0) is 95 deg off-axis.
        let f = 32.0 / 95f64.to_radians();
        let fish = CameraModel {
            width: 64,
            height: 64,
            fx: f,
            fy: f,
            cx: 32.0,
            cy: 32.0,
            lens: Lens::KannalaBrandt {
                k1: 0.0,
                k2: 0.0,
                k3: 0.0,
                k4: 0.0,
            },
        };
        let cam = Camera::new(2, "fish", fish, Mount::from_xyz_rpy_deg([0.0; 3], [0.0; 3]));
        let m = CameraBins::new(&cam, 64, 64, &g);
        assert_eq!(
            m.bin_at(0, 32),
            Some(g.bin_of(95f64.to_radians())),
            "95 deg left: behind the side"
        );
        assert_eq!(g.bin_of(95f64.to_radians()), 27);
    }

    #[test]
    fn run_sums_equal_a_per_pixel_scatter() {
        // A pitched, rolled fisheye: bins change within rows and columns, and
        // some pixels see straight down.
        let fish = CameraModel {
            width: 97,
            height: 61,
            fx: 30.0,
            fy: 30.0,
            cx: 48.0,
            cy: 30.0,
            lens: Lens::KannalaBrandt {
                k1: 0.05,
                k2: 0.0,
                k3: 0.0,
                k4: 0.0,
            },
        };
        let cam = Camera::new(
            0,
            "f",
            fish,
            Mount::from_xyz_rpy_deg([0.0; 3], [10.0, 60.0, 30.0]),
        );
        let g = BinGeometry::from_width_deg(5.0);
        let m = CameraBins::new(&cam, 97, 61, &g);
        let mut seed = 7u32;
        let heat: Vec<f32> = (0..97 * 61)
            .map(|i| match i % 301 {
                0 => f32::NAN,
                1 => f32::INFINITY,
                _ => {
                    seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                    (seed >> 8) as f32 / (1u32 << 24) as f32
                }
            })
            .collect();
        let (mut want, mut want_seen) = (vec![0.0f64; g.count], vec![false; g.count]);
        for v in 0..61 {
            for u in 0..97 {
                if let Some(b) = cam
                    .pixel_bearing_rad(u as f64, v as f64)
                    .map(|a| g.bin_of(a))
                {
                    assert_eq!(m.bin_at(u, v), Some(b), "pixel ({u}, {v})");
                    want_seen[b] = true;
                    let h = heat[v * 97 + u];
                    if h.is_finite() && h >= 0.3 {
                        want[b] += h as f64;
                    }
                }
            }
        }
        let (sums, seen) = m.project(&heat, 0.3);
        assert_eq!(seen, want_seen);
        for (b, (s, w)) in sums.iter().zip(&want).enumerate() {
            assert!((s - w).abs() < 1e-3 * w.max(1.0), "bin {b}: {s} vs {w}");
        }
        assert!(want.iter().filter(|&&w| w > 0.0).count() > 5, "{want:?}");
    }

    #[test]
    fn threshold_max_across_cameras_normalise_and_ema() {
        let g = BinGeometry { count: 4 };
        let cfg = LrnBinsConfig {
            alpha: 0.5,
            ..Default::default()
        };
        let mut bins = LrnBins::new(g, cfg);
        let front = (vec![0.0, 2.0, 6.0, 0.0], vec![false, true, true, false]);
        let side = (vec![0.0, 4.0, 0.0, 0.0], vec![false, true, false, true]);
        let out = bins.update(&[front.clone(), side.clone()]);
        // max -> [0, 4, 6, 0]; normalised [0, .4, .6, 0]; EMA from 0 with alpha .5.
        assert_eq!(out.observed, vec![false, true, true, true]);
        let close = |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-12);
        assert!(
            close(&out.scores, &[0.0, 0.2, 0.3, 0.0]),
            "{:?}",
            out.scores
        );
        let out = bins.update(&[front, side]);
        // 0.5 * 0.4 + 0.5 * 0.2 = 0.3; 0.5 * 0.6 + 0.5 * 0.3 = 0.45.
        assert!(
            close(&out.scores, &[0.0, 0.3, 0.45, 0.0]),
            "{:?}",
            out.scores
        );
        // Pixel threshold: values below h_thresh contribute nothing.
        let cam = Camera::new(
            0,
            "f",
            CameraModel::pinhole(4, 1, 2.0, 2.0, 2.0, 0.5),
            Mount::from_xyz_rpy_deg([0.0; 3], [0.0; 3]),
        );
        let m = CameraBins::new(&cam, 4, 1, &BinGeometry::from_width_deg(90.0));
        let (sums, _) = m.project(&[0.9, 0.5, f32::NAN, 0.8], 0.7);
        assert!((sums.iter().sum::<f64>() - 1.7).abs() < 1e-6, "{sums:?}");
    }
}
