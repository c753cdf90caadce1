//! FITAM's per-cell cost filter (section IV-D; constants from the reference
//! code): each map cell holds a mean cost (s/m) and its variance; a far-field
//! measurement z with variance R updates it as a 1-D Kalman filter, and every
//! map update adds process noise Q so old far-field guesses fade back toward
//! "unknown".

use farsight_stage::{Range, Ranges, Validate};
use serde::{Deserialize, Serialize};

/// Mean cost and variance of one cell.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KalmanCell {
    pub mean_s_per_m: f32,
    pub variance: f32,
}

/// The far-field filter's constants (FITAM defaults).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FarFieldConfig {
    pub initial_mean_s_per_m: f32,
    pub initial_variance: f32,
    /// Q, added to every far-field cell's variance after each map update.
    pub process_noise: f32,
    /// Cells with a larger variance plan at `unknown_cost_s_per_m`.
    pub variance_threshold: f32,
    pub unknown_cost_s_per_m: f32,
}

impl Default for FarFieldConfig {
    fn default() -> Self {
        Self {
            initial_mean_s_per_m: 1.0,
            initial_variance: 0.4,
            process_noise: 0.001,
            variance_threshold: 0.4,
            unknown_cost_s_per_m: 1.0,
        }
    }
}

impl Validate for FarFieldConfig {
    fn ranges(&self, r: &mut Ranges) {
        let cost = Range::above_to(0.0, 1000.0).unit("s/m");
        let variance = Range::between(0.0, 1e6);
        r.key("initial_mean_s_per_m", self.initial_mean_s_per_m, cost)
            .key("unknown_cost_s_per_m", self.unknown_cost_s_per_m, cost)
            .key("initial_variance", self.initial_variance, variance)
            .key("process_noise", self.process_noise, variance)
            .key("variance_threshold", self.variance_threshold, variance);
    }
}

impl KalmanCell {
    pub fn initial(cfg: &FarFieldConfig) -> Self {
        Self {
            mean_s_per_m: cfg.initial_mean_s_per_m,
            variance: cfg.initial_variance,
        }
    }

    /// The cost a planner should use: the mean once the filter is confident,
    /// the unknown-space cost until then.
    pub fn planning_cost(&self, cfg: &FarFieldConfig) -> f32 {
        if self.variance > cfg.variance_threshold {
            cfg.unknown_cost_s_per_m
        } else {
            self.mean_s_per_m
        }
    }
}

/// One measurement `z` (s/m) with variance `r`: `K = P / (P + R)` (0 where
/// `P = 0`), `x += K (z - x)`, `P = (1 - K) P`. A non-finite measurement or
/// variance leaves the cell as it was and returns false.
pub fn kalman_update(cell: &mut KalmanCell, z_s_per_m: f32, r: f32) -> bool {
    if !(z_s_per_m.is_finite() && r.is_finite() && r >= 0.0) {
        return false;
    }
    let p = cell.variance;
    let k = if p + r > 0.0 { p / (p + r) } else { 0.0 };
    cell.mean_s_per_m += k * (z_s_per_m - cell.mean_s_per_m);
    cell.variance = (1.0 - k) * p;
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kalman_update_by_hand() {
        let cfg = FarFieldConfig::default();
        let mut c = KalmanCell::initial(&cfg);
        // P = 0.4, R = 0.1: K = 0.8; x = 1 + 0.8 (2 - 1) = 1.8; P = 0.2 * 0.4 = 0.08.
        assert!(kalman_update(&mut c, 2.0, 0.1));
        assert!((c.mean_s_per_m - 1.8).abs() < 1e-6 && (c.variance - 0.08).abs() < 1e-6);
        // Again with z = 0.235, R = 0.32: K = 0.08 / 0.4 = 0.2;
        // x = 1.8 + 0.2 (0.235 - 1.8) = 1.487; P = 0.8 * 0.08 = 0.064.
        assert!(kalman_update(&mut c, 0.235, 0.32));
        assert!((c.mean_s_per_m - 1.487).abs() < 1e-6, "{c:?}");
        assert!((c.variance - 0.064).abs() < 1e-6);
        // Confident now: the planner uses the mean.
        assert_eq!(c.planning_cost(&cfg), c.mean_s_per_m);
    }

    #[test]
    fn zero_variance_cells_and_bad_measurements_do_not_move() {
        let mut fixed = KalmanCell {
            mean_s_per_m: 0.2,
            variance: 0.0,
        };
        assert!(kalman_update(&mut fixed, 10.0, 0.5));
        assert_eq!(fixed.mean_s_per_m, 0.2, "K = 0 where P = 0");
        let mut c = KalmanCell::initial(&FarFieldConfig::default());
        let before = c;
        assert!(!kalman_update(&mut c, f32::NAN, 0.1));
        assert!(!kalman_update(&mut c, 1.0, f32::INFINITY));
        assert!(!kalman_update(&mut c, 1.0, -0.1));
        assert_eq!(c, before);
    }

    #[test]
    fn unconfident_cells_plan_at_the_unknown_cost() {
        let cfg = FarFieldConfig::default();
        let c = KalmanCell {
            mean_s_per_m: 0.2,
            variance: 0.41,
        };
        assert_eq!(c.planning_cost(&cfg), 1.0);
    }
}
