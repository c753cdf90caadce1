//! FITAM's far-field label rule (section IV-B): a swath (one heading bin by
//! one radial bin around the robot) is labelled with the cheapest speed class
//! that covers at least `rho_class` of its observed cells, weighted by the
//! fraction of the swath that was observed, and not labelled at all when less
//! than `rho_bin` of it was. The simulator applies the rule to its true world
//! ("ground-truth labels"); `farsight dataset` applies it to the local
//! costmaps a robot recorded over a whole run.

use crate::swath::{for_each_swath_cell, PolarGeometry};
use farsight_interfaces::msg::PolarCell;

/// FITAM's speed classes (m/s) and the label thresholds.
#[derive(Debug, Clone, PartialEq)]
pub struct LabelRules {
    pub class_speeds_mps: Vec<f64>,
    pub rho_class: f64,
    pub rho_bin: f64,
    /// Variance given to a ground-truth measurement.
    pub variance: f32,
}

impl Default for LabelRules {
    fn default() -> Self {
        Self {
            class_speeds_mps: vec![0.5, 2.25, 4.25],
            rho_class: 0.2,
            rho_bin: 0.2,
            variance: 0.05,
        }
    }
}

impl LabelRules {
    /// The class of a cell cost: the fastest class no faster than the cell
    /// allows (lethal cells count as the slowest class, as FITAM's far-field
    /// classes have no lethal one).
    pub fn class_of(&self, cost_s_per_m: f32) -> usize {
        self.classifier()(cost_s_per_m)
    }

    /// [`Self::class_of`] with the classes' order worked out once: a
    /// labeller classifies every cell of every swath, 30,000 or more a frame.
    pub fn classifier(&self) -> impl Fn(f32) -> usize + '_ {
        let order = self.fastest_first();
        let slowest = *order.last().expect("classes");
        move |cost_s_per_m| {
            let speed = 1.0 / cost_s_per_m as f64;
            order
                .iter()
                .copied()
                .find(|&c| self.class_speeds_mps[c] <= speed + 1e-9)
                .unwrap_or(slowest)
        }
    }

    fn fastest_first(&self) -> Vec<usize> {
        let mut order: Vec<usize> = (0..self.class_speeds_mps.len()).collect();
        order.sort_by(|&a, &b| self.class_speeds_mps[b].total_cmp(&self.class_speeds_mps[a]));
        order
    }

    /// The label of one swath from its cell counts per class (`seen[c]`) and
    /// its size in cells; `None` below `rho_bin`.
    pub fn label(&self, seen: &[usize], swath_cells: usize) -> Option<SwathLabel> {
        let observed: usize = seen.iter().sum();
        if swath_cells == 0 || (observed as f64) < self.rho_bin * swath_cells as f64 {
            return None;
        }
        let class = self
            .fastest_first()
            .into_iter()
            .find(|&c| seen[c] as f64 >= self.rho_class * observed as f64)?;
        Some(SwathLabel {
            class_id: class,
            observed_fraction: observed as f32 / swath_cells as f32,
            class_fraction: seen[class] as f32 / observed as f32,
        })
    }
}

/// One labelled swath.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SwathLabel {
    pub class_id: usize,
    /// Observed cells / swath cells: the training weight.
    pub observed_fraction: f32,
    /// Cells of the winning class / observed cells.
    pub class_fraction: f32,
}

impl SwathLabel {
    /// The label as a far-field observation (cost 1/speed of its class).
    pub fn to_polar_cell(self, rules: &LabelRules) -> PolarCell {
        PolarCell {
            cost_s_per_m: (1.0 / rules.class_speeds_mps[self.class_id]) as f32,
            variance: rules.variance,
            class_id: self.class_id as u32,
            probability: self.class_fraction,
        }
    }
}

/// Labels of every swath around a robot at `pose` (x, y, yaw), heading-major
/// (`heading * radial + r`). `cost_at(gx, gy)` is a cell's cost, or `None`
/// where it was never observed (or lies outside the world).
pub fn swath_labels(
    geometry: &PolarGeometry,
    pose: [f64; 3],
    resolution_m: f64,
    rules: &LabelRules,
    mut cost_at: impl FnMut(i64, i64) -> Option<f32>,
) -> Vec<Option<SwathLabel>> {
    let radial = geometry.radial_bins();
    let classes = rules.class_speeds_mps.len();
    // Per swath: cells per class, then all cells.
    if classes == 0 {
        // No class to label a swath with.
        return vec![None; geometry.heading_bins * radial];
    }
    let mut counts = vec![vec![0usize; classes + 1]; geometry.heading_bins * radial];
    let class_of = rules.classifier();
    for_each_swath_cell(
        geometry,
        pose[0],
        pose[1],
        pose[2],
        resolution_m,
        |gx, gy, h, r| {
            let slot = &mut counts[h * radial + r];
            slot[classes] += 1;
            if let Some(cost) = cost_at(gx, gy) {
                slot[class_of(cost)] += 1;
            }
        },
    );
    counts
        .iter()
        .map(|n| rules.label(&n[..classes], n[classes]))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn classes_by_speed() {
        let rules = LabelRules::default();
        assert_eq!(rules.class_of(0.2), 2, "road: 5 m/s >= 4.25");
        assert_eq!(rules.class_of(0.5), 0, "grass: 2 m/s < 2.25");
        assert_eq!(rules.class_of(0.4), 1);
        assert_eq!(rules.class_of(f32::INFINITY), 0);
    }

    #[test]
    fn the_cheapest_class_covering_rho_class_wins_weighted_by_what_was_seen() {
        let rules = LabelRules::default();
        // 100 cells, 50 seen: 30 slow, 11 medium, 9 fast. Fast covers 9/50 =
        // 18% < 20%; medium 22% -> medium, weight 0.5.
        let l = rules.label(&[30, 11, 9], 100).unwrap();
        assert_eq!(l.class_id, 1);
        assert_eq!(l.observed_fraction, 0.5);
        assert!((l.class_fraction - 0.22).abs() < 1e-6);
        // 10 fast of 50 is exactly 20%: fast.
        assert_eq!(rules.label(&[30, 10, 10], 100).unwrap().class_id, 2);
        // 19 of 100 seen: under rho_bin.
        assert_eq!(rules.label(&[19, 0, 0], 100), None);
        assert_eq!(rules.label(&[0, 0, 0], 0), None);
    }

    #[test]
    fn unobserved_cells_lower_the_weight_not_the_class() {
        let g = PolarGeometry::fitam_default();
        let rules = LabelRules::default();
        // Road (0.2 s/m) everywhere east of x = 0, nothing observed west.
        let labels = swath_labels(&g, [0.0, 0.0, 0.0], 1.0, &rules, |gx, _| {
            (gx > 0).then_some(0.2)
        });
        let ahead = g.heading_bin(0.01).unwrap();
        let l = labels[ahead * 3 + 1].unwrap();
        assert_eq!(l.class_id, 2);
        assert_eq!(l.observed_fraction, 1.0);
        let behind = g.heading_bin(std::f64::consts::PI - 0.01).unwrap();
        assert_eq!(labels[behind * 3], None, "nothing seen behind");
    }
}
