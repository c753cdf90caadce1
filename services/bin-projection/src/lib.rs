//! # farsight-bin-projection
//!
//! LRN's affordance backbone after the heatmap (section III-B, Algorithm 2):
//! every heatmap pixel goes to the angular bin of its bearing in the robot
//! frame (from the camera model and mount: pinhole or fisheye, any facing),
//! scores are summed per bin, thresholded, combined across cameras by max,
//! normalised by their sum and smoothed over time with an EMA. A bin no camera
//! sees is *unobserved*, which is not the same as a bin with no affordance.
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

use farsight_interfaces::camera::Camera;
use farsight_stage::{ConfigError, Validate};
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
#[derive(Debug, Clone)]
pub struct CameraBins {
    pub width: usize,
    pub height: usize,
    bin_of_pixel: Vec<u32>,
    count: usize,
}

const NO_BIN: u32 = u32::MAX;

impl CameraBins {
    pub fn new(camera: &Camera, width: usize, height: usize, geometry: &BinGeometry) -> Self {
        let scaled = Camera {
            model: camera.model.scaled_to(width as u32, height as u32),
            ..camera.clone()
        };
        let bin_of_pixel = (0..height)
            .flat_map(|v| (0..width).map(move |u| (u, v)))
            .map(
                |(u, v)| match scaled.pixel_bearing_rad(u as f64, v as f64) {
                    Some(b) => geometry.bin_of(b) as u32,
                    None => NO_BIN,
                },
            )
            .collect();
        Self {
            width,
            height,
            bin_of_pixel,
            count: geometry.count,
        }
    }

    /// The bin of pixel (u, v), `None` for a pixel straight up or down.
    pub fn bin_at(&self, u: usize, v: usize) -> Option<usize> {
        let b = self.bin_of_pixel[v * self.width + u];
        (b != NO_BIN).then_some(b as usize)
    }

    /// Per-bin sums of the heatmap values that reach `pixel_threshold`, and
    /// which bins this camera sees at all.
    pub fn project(&self, heatmap: &[f32], pixel_threshold: f32) -> Projection {
        let mut sums = vec![0.0; self.count];
        let mut seen = vec![false; self.count];
        for (&b, &h) in self.bin_of_pixel.iter().zip(heatmap) {
            if b == NO_BIN {
                continue;
            }
            seen[b as usize] = true;
            if h.is_finite() && h >= pixel_threshold {
                sums[b as usize] += h as f64;
            }
        }
        (sums, seen)
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

/// LRN bin parameters (Spot preset: 5 degree bins, h_thresh 0.7, alpha 0.1).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LrnBinsConfig {
    pub bin_width_deg: f64,
    pub h_thresh: f32,
    pub threshold_on: ThresholdOn,
    /// EMA weight of the newest scores.
    pub alpha: f64,
}

impl Default for LrnBinsConfig {
    fn default() -> Self {
        Self {
            bin_width_deg: 5.0,
            h_thresh: 0.7,
            threshold_on: ThresholdOn::Pixels,
            alpha: 0.1,
        }
    }
}

impl Validate for LrnBinsConfig {
    fn validate(&self) -> Result<(), ConfigError> {
        ConfigError::check(
            self.bin_width_deg >= 1.0 && self.bin_width_deg <= 90.0,
            "bins.bin_width_deg",
            self.bin_width_deg,
            "1..=90 degrees (at most 360 bins)",
        )?;
        ConfigError::check(
            (0.0..=1.0).contains(&self.h_thresh),
            "bins.h_thresh",
            self.h_thresh,
            "0..=1",
        )?;
        ConfigError::check(
            self.alpha > 0.0 && self.alpha <= 1.0,
            "bins.alpha",
            self.alpha,
            "(0, 1]",
        )
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
