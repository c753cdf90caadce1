//! FITAM's far-field observation (section IV-C; the reference code's
//! equations): the model sees one image slice per heading bin and outputs,
//! per radial bin, the logits of an ensemble of classifiers over speed
//! classes. Per (heading, radial) bin:
//!
//! - p = mean over members of softmax(logits);
//! - class = argmax p, measurement z = 1 / class_speed (s/m), or, with
//!   `measurement = "expected_cost"` (not the paper's), sum of p / speed;
//! - variance R = 1 - max p (the reference code, the default), or the
//!   normalised entropy of p (the paper's text, `variance = "entropy"`).
//!
//! Heading bins no slice looks into come out as "no measurement": cost NaN,
//! variance infinite, which the Kalman update skips.
//!
//! ```
//! use farsight_bin_projection::fitam::{ensemble_observation, FitamBinsConfig};
//!
//! let cfg = FitamBinsConfig::default(); // class speeds 0.5, 2.25, 4.25 m/s
//! // One radial bin, two members, both sure of class 2 (the fast one).
//! let logits = [0.0, 0.0, 9.0, 0.0, 0.0, 9.0];
//! let cells = ensemble_observation(&logits, 1, 2, 3, &cfg).unwrap();
//! assert_eq!(cells[0].class_id, 2);
//! assert!((cells[0].cost_s_per_m - 1.0 / 4.25).abs() < 1e-6);
//! assert!(cells[0].variance < 0.01);
//! ```

use farsight_interfaces::camera::Camera;
use farsight_interfaces::msg::PolarCell;
use farsight_stage::{ConfigError, Range, Ranges, Validate};
use serde::{Deserialize, Serialize};
use std::f64::consts::{PI, TAU};

/// How the measurement variance R is derived from the class distribution.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum VarianceRule {
    /// `1 - max p`, as the reference code.
    #[default]
    MaxProbability,
    /// Entropy of p divided by ln(classes), as the paper's text.
    Entropy,
}

/// What a bin's measurement z is, given the class distribution p.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum MeasurementRule {
    /// The cost of the most likely class, as FITAM (paper and code).
    #[default]
    MostLikelyClass,
    /// The expected cost, sum of p_k / speed_k: the estimate of least
    /// squared error. A slow swath the model half-believes fast is not
    /// planned on as a road: with FITAM's classes (2.0, 0.444 and
    /// 0.235 s/m) p = (0.3, 0.2, 0.5) gives 0.81 s/m where argmax gives
    /// 0.235. Not the paper's; a deviation to measure (issue 22).
    ExpectedCost,
}

/// FITAM's far-field bin parameters (simulated defaults).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FitamBinsConfig {
    pub heading_bins: usize,
    /// Radial bin edges, metres.
    pub range_edges_m: Vec<f64>,
    /// Speed of each class (m/s); its cost is the inverse.
    pub class_speeds_mps: Vec<f64>,
    pub variance: VarianceRule,
    pub measurement: MeasurementRule,
    /// Radial bins that start at or beyond this range (m) go out as "no
    /// measurement", whatever the model says: for a model that tells the
    /// classes apart near by but is at chance further out. Every
    /// observation, however unsure, takes a cell's variance under the
    /// filter's threshold (R = 1 - max p is at most 2/3 with three
    /// classes), so a guess at chance is planned on as if measured; a bin
    /// left unmeasured plans at the unknown cost instead. A bin that
    /// starts nearer is measured whole, even if it reaches past this
    /// range (60 keeps the 50-75 m bin). Unset (the default, and FITAM's):
    /// every radial bin.
    pub max_range_m: Option<f64>,
}

impl Default for FitamBinsConfig {
    fn default() -> Self {
        Self {
            heading_bins: 32,
            range_edges_m: vec![25.0, 50.0, 75.0, 100.0],
            class_speeds_mps: vec![0.5, 2.25, 4.25],
            variance: VarianceRule::MaxProbability,
            measurement: MeasurementRule::MostLikelyClass,
            max_range_m: None,
        }
    }
}

impl FitamBinsConfig {
    /// Whether radial bin `r` is measured (see [`Self::max_range_m`]).
    pub fn measures_radial_bin(&self, r: usize) -> bool {
        self.max_range_m
            .is_none_or(|m| self.range_edges_m.get(r).is_some_and(|&lo| lo < m))
    }
}

impl Validate for FitamBinsConfig {
    fn ranges(&self, r: &mut Ranges) {
        r.key(
            "heading_bins",
            self.heading_bins,
            Range::between(1.0, 360.0),
        )
        .each(
            "range_edges_m",
            &self.range_edges_m,
            Range::between(0.0, 10_000.0).unit("m"),
        )
        .each(
            "class_speeds_mps",
            &self.class_speeds_mps,
            Range::above_to(0.0, 100.0).unit("m/s"),
        )
        .optional(
            "max_range_m",
            self.max_range_m,
            Range::above_to(0.0, 10_000.0).unit("m"),
        );
    }

    fn check_rules(&self) -> Result<(), ConfigError> {
        let edges_ok = self.range_edges_m.len() >= 2
            && self.range_edges_m.len() <= farsight_interfaces::msg::MAX_RANGE_EDGES
            && self.range_edges_m.windows(2).all(|w| w[0] < w[1]);
        ConfigError::check(
            edges_ok,
            "fitam.range_edges_m",
            format!("{:?}", self.range_edges_m),
            "2..=16 increasing distances",
        )?;
        ConfigError::check(
            self.class_speeds_mps.len() >= 2,
            "fitam.class_speeds_mps",
            format!("{:?}", self.class_speeds_mps),
            "two or more speeds",
        )?;
        ConfigError::check(
            self.max_range_m.is_none_or(|m| m > self.range_edges_m[0]),
            "fitam.max_range_m",
            self.max_range_m
                .map_or_else(String::new, |m| format!("{m} m")),
            &format!(
                "beyond the first radial edge ({} m): nearer, nothing is measured",
                self.range_edges_m[0]
            ),
        )
    }
}

/// Why an ensemble output cannot be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FitamError {
    #[error("ensemble output holds {got} values, [{radial} radial x {members} members x {classes} classes] needs {want}")]
    Size {
        got: usize,
        want: usize,
        radial: usize,
        members: usize,
        classes: usize,
    },
    #[error("the model has {got} classes but class_speeds_mps lists {want}")]
    Classes { got: usize, want: usize },
    #[error("the model has {got} radial bins but range_edges_m describes {want}")]
    Radial { got: usize, want: usize },
    #[error("non-finite logit in the ensemble output")]
    NonFinite,
}

/// One slice's ensemble logits `[radial, members, classes]` -> one polar cell
/// per radial bin.
pub fn ensemble_observation(
    logits: &[f32],
    radial: usize,
    members: usize,
    classes: usize,
    cfg: &FitamBinsConfig,
) -> Result<Vec<PolarCell>, FitamError> {
    let want = radial * members * classes;
    if logits.len() != want || members == 0 {
        return Err(FitamError::Size {
            got: logits.len(),
            want,
            radial,
            members,
            classes,
        });
    }
    if classes != cfg.class_speeds_mps.len() {
        return Err(FitamError::Classes {
            got: classes,
            want: cfg.class_speeds_mps.len(),
        });
    }
    if logits.iter().any(|v| !v.is_finite()) {
        return Err(FitamError::NonFinite);
    }
    let mut out = Vec::with_capacity(radial);
    let mut p = vec![0f64; classes];
    for r in 0..radial {
        p.iter_mut().for_each(|v| *v = 0.0);
        for m in 0..members {
            let l = &logits[(r * members + m) * classes..][..classes];
            let max = l.iter().copied().fold(f32::NEG_INFINITY, f32::max) as f64;
            let e: Vec<f64> = l.iter().map(|&v| (v as f64 - max).exp()).collect();
            let sum: f64 = e.iter().sum();
            for (pc, ec) in p.iter_mut().zip(&e) {
                *pc += ec / sum / members as f64;
            }
        }
        let (class, &pmax) = p
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
            .expect("two or more classes");
        let variance = match cfg.variance {
            VarianceRule::MaxProbability => 1.0 - pmax,
            VarianceRule::Entropy => {
                -p.iter()
                    .filter(|&&v| v > 0.0)
                    .map(|&v| v * v.ln())
                    .sum::<f64>()
                    / (classes as f64).ln()
            }
        };
        let cost_s_per_m = match cfg.measurement {
            MeasurementRule::MostLikelyClass => 1.0 / cfg.class_speeds_mps[class],
            MeasurementRule::ExpectedCost => (p.iter().zip(&cfg.class_speeds_mps))
                .map(|(pk, speed)| pk / speed)
                .sum(),
        };
        out.push(PolarCell {
            cost_s_per_m: cost_s_per_m as f32,
            variance: variance.max(0.0) as f32,
            class_id: class as u32,
            probability: pmax as f32,
        });
    }
    Ok(out)
}

/// The heading bin each of `slices` vertical image slices looks into: the
/// bearing of the slice's centre column on the principal row, through the
/// camera model and mount. Bins start at -pi, as the LRN bins. A model
/// should cut the image into as many slices as heading bins its field of view
/// spans (FITAM's slices are one heading bin wide): with fewer, the bins
/// between slice centres stay unmeasured.
pub fn slice_heading_bins(
    camera: &Camera,
    slices: usize,
    heading_bins: usize,
) -> Vec<Option<usize>> {
    let (w, cy) = (camera.model.width as f64, camera.model.cy);
    (0..slices)
        .map(|s| {
            let u = (s as f64 + 0.5) * w / slices as f64 - 0.5;
            camera.pixel_bearing_rad(u, cy).map(|b| {
                let a = (b + PI).rem_euclid(TAU);
                ((a / (TAU / heading_bins as f64)) as usize).min(heading_bins - 1)
            })
        })
        .collect()
}

/// A whole ensemble output `[slices, radial, members, classes]` -> polar
/// cells, heading-major (`heading * radial + r`). Where two slices look into
/// the same heading bin, the more certain (lower variance) one is kept.
pub fn polar_observation(
    logits: &[f32],
    shape: [usize; 4],
    slice_bins: &[Option<usize>],
    cfg: &FitamBinsConfig,
) -> Result<Vec<PolarCell>, FitamError> {
    let [slices, radial, members, classes] = shape;
    let want_radial = cfg.range_edges_m.len() - 1;
    if radial != want_radial {
        return Err(FitamError::Radial {
            got: radial,
            want: want_radial,
        });
    }
    let per_slice = radial * members * classes;
    if logits.len() != slices * per_slice {
        return Err(FitamError::Size {
            got: logits.len(),
            want: slices * per_slice,
            radial,
            members,
            classes,
        });
    }
    let mut out = vec![PolarCell::NO_MEASUREMENT; cfg.heading_bins * radial];
    for (s, bin) in slice_bins.iter().enumerate().take(slices) {
        let Some(h) = *bin else { continue };
        let cells = ensemble_observation(
            &logits[s * per_slice..][..per_slice],
            radial,
            members,
            classes,
            cfg,
        )?;
        for (r, c) in cells.into_iter().enumerate() {
            if !cfg.measures_radial_bin(r) {
                continue;
            }
            let slot = &mut out[h * radial + r];
            if c.variance < slot.variance {
                *slot = c;
            }
        }
    }
    Ok(out)
}

/// Several cameras' polar cells -> one set: per bin, the most certain
/// (lowest variance) measurement.
pub fn merge_cameras(per_camera: &[&[PolarCell]]) -> Vec<PolarCell> {
    let n = per_camera.iter().map(|c| c.len()).max().unwrap_or(0);
    (0..n)
        .map(|k| {
            per_camera.iter().filter_map(|c| c.get(k)).fold(
                PolarCell::NO_MEASUREMENT,
                |best, &c| {
                    if c.variance < best.variance {
                        c
                    } else {
                        best
                    }
                },
            )
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use farsight_interfaces::camera::{CameraModel, Mount};

    #[test]
    fn mean_of_member_softmax_by_hand() {
        let cfg = FitamBinsConfig::default();
        // Member 1: logits (0, ln 3, 0) -> p = (0.2, 0.6, 0.2).
        // Member 2: logits (ln 2, ln 2, 0) -> p = (0.4, 0.4, 0.2).
        // Mean (0.3, 0.5, 0.2): class 1 (2.25 m/s -> 0.444 s/m), R = 0.5.
        let l = [0.0, 3f32.ln(), 0.0, 2f32.ln(), 2f32.ln(), 0.0];
        let c = ensemble_observation(&l, 1, 2, 3, &cfg).unwrap()[0];
        assert_eq!(c.class_id, 1);
        assert!((c.probability - 0.5).abs() < 1e-6);
        assert!((c.cost_s_per_m - 1.0 / 2.25).abs() < 1e-6);
        assert!((c.variance - 0.5).abs() < 1e-6);
        // The paper's entropy rule: -(0.3 ln .3 + .5 ln .5 + .2 ln .2) / ln 3.
        let e = FitamBinsConfig {
            variance: VarianceRule::Entropy,
            ..cfg.clone()
        };
        let c = ensemble_observation(&l, 1, 2, 3, &e).unwrap()[0];
        let want = -(0.3f64 * 0.3f64.ln() + 0.5 * 0.5f64.ln() + 0.2 * 0.2f64.ln()) / 3f64.ln();
        assert!((c.variance as f64 - want).abs() < 1e-6, "{}", c.variance);
        // The expected cost: 0.3 / 0.5 + 0.5 / 2.25 + 0.2 / 4.25; the class,
        // its probability and the variance stay the argmax's.
        let x = FitamBinsConfig {
            measurement: MeasurementRule::ExpectedCost,
            ..cfg.clone()
        };
        let c = ensemble_observation(&l, 1, 2, 3, &x).unwrap()[0];
        let want = 0.3 / 0.5 + 0.5 / 2.25 + 0.2 / 4.25;
        assert!(
            (c.cost_s_per_m as f64 - want).abs() < 1e-6,
            "{}",
            c.cost_s_per_m
        );
        assert_eq!(c.class_id, 1);
        assert!((c.variance - 0.5).abs() < 1e-6);
    }

    #[test]
    fn cameras_merge_by_certainty() {
        let cell = |cost, variance| PolarCell {
            cost_s_per_m: cost,
            variance,
            class_id: 0,
            probability: 1.0 - variance,
        };
        let front = [cell(2.0, 0.3), PolarCell::NO_MEASUREMENT];
        let rear = [cell(0.5, 0.1), cell(0.4, 0.2)];
        let m = merge_cameras(&[&front, &rear]);
        assert_eq!((m[0].cost_s_per_m, m[1].cost_s_per_m), (0.5, 0.4));
        let m = merge_cameras(&[&front]);
        assert!(m[1].cost_s_per_m.is_nan());
    }

    #[test]
    fn bad_outputs_are_refused_with_the_reason() {
        let cfg = FitamBinsConfig::default();
        assert!(matches!(
            ensemble_observation(&[0.0; 5], 1, 2, 3, &cfg),
            Err(FitamError::Size {
                got: 5,
                want: 6,
                ..
            })
        ));
        assert_eq!(
            ensemble_observation(&[0.0; 8], 1, 2, 4, &cfg),
            Err(FitamError::Classes { got: 4, want: 3 })
        );
        let mut nan = [0.0f32; 6];
        nan[3] = f32::NAN;
        assert_eq!(
            ensemble_observation(&nan, 1, 2, 3, &cfg),
            Err(FitamError::NonFinite)
        );
        assert!(matches!(
            polar_observation(&[0.0; 12], [1, 2, 2, 3], &[Some(0)], &cfg),
            Err(FitamError::Radial { got: 2, want: 3 })
        ));
    }

    #[test]
    fn radial_bins_from_max_range_on_go_out_unmeasured() {
        let bins = [Some(3)];
        // One slice, three radial bins, two members, sure of class 2.
        let logits: Vec<f32> = (0..3 * 2).flat_map(|_| [0.0, 0.0, 9.0]).collect();
        let measured = |max_range_m: Option<f64>| -> Vec<bool> {
            let cfg = FitamBinsConfig {
                heading_bins: 8,
                max_range_m,
                ..Default::default()
            };
            let cells = polar_observation(&logits, [1, 3, 2, 3], &bins, &cfg).unwrap();
            (0..3)
                .map(|r| {
                    let c = cells[3 * 3 + r];
                    assert!(c.cost_s_per_m.is_nan() == c.variance.is_infinite());
                    !c.cost_s_per_m.is_nan()
                })
                .collect()
        };
        // Edges 25, 50, 75, 100 m: a bin is measured if it starts nearer.
        assert_eq!(measured(None), [true, true, true]);
        assert_eq!(measured(Some(50.0)), [true, false, false]);
        assert_eq!(measured(Some(50.1)), [true, true, false]);
        assert_eq!(measured(Some(1000.0)), [true, true, true]);
    }

    #[test]
    fn a_max_range_that_would_measure_nothing_is_refused_by_name() {
        for (toml, why) in [
            ("max_range_m = 25.0", "first radial edge"),
            ("max_range_m = 10.0", "first radial edge"),
            ("max_range_m = -5.0", "0 < x <= 10000 m"),
            ("max_range_m = nan", "max_range_m"),
            ("max_range_m = 20000.0", "0 < x <= 10000 m"),
        ] {
            let e = farsight_stage::parse_config::<FitamBinsConfig>(toml, "fitam")
                .expect_err(toml)
                .to_string();
            assert!(e.contains("max_range_m") && e.contains(why), "{toml}: {e}");
        }
        let ok: FitamBinsConfig =
            farsight_stage::parse_config("max_range_m = 50.0", "fitam").unwrap();
        assert_eq!(ok.max_range_m, Some(50.0));
    }

    #[test]
    fn slices_land_in_their_heading_bins_and_the_rest_is_unmeasured() {
        // 90 deg field of view: f = 32 on a 64 px image. 4 slices of 16 px,
        // centres at u = 7.5, 23.5, 39.5, 55.5 -> bearings +35.1, +12.1, -12.1,
        // -35.1 deg. With 16 bins of 22.5 deg from -180: bins 9, 8, 7, 6.
        let cam = Camera::new(
            0,
            "front",
            CameraModel::pinhole(64, 32, 32.0, 32.0, 31.5, 15.5),
            Mount::from_xyz_rpy_deg([0.0; 3], [0.0; 3]),
        );
        let bins = slice_heading_bins(&cam, 4, 16);
        assert_eq!(bins, vec![Some(9), Some(8), Some(7), Some(6)]);
        let cfg = FitamBinsConfig {
            heading_bins: 16,
            ..Default::default()
        };
        // Every slice, radial bin and member votes class 0 (slow).
        let logits: Vec<f32> = (0..4 * 3 * 2).flat_map(|_| [5.0, 0.0, 0.0]).collect();
        let cells = polar_observation(&logits, [4, 3, 2, 3], &bins, &cfg).unwrap();
        assert_eq!(cells.len(), 16 * 3);
        for h in 0..16 {
            for r in 0..3 {
                let c = cells[h * 3 + r];
                if (6..=9).contains(&h) {
                    assert_eq!((c.class_id, c.cost_s_per_m), (0, 2.0));
                } else {
                    assert!(
                        c.cost_s_per_m.is_nan() && c.variance.is_infinite(),
                        "bin {h}"
                    );
                }
            }
        }
    }
}
