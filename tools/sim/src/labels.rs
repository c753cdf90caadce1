//! Ground-truth far-field labels (FITAM section IV-B): for each (heading,
//! radial) bin around the robot, the cheapest speed class that covers at
//! least `rho_class` of the bin's swath, and nothing where under `rho_bin` of
//! the swath lies inside the world. The navigation benchmark feeds these to
//! the fused map as "FITAM with ground-truth labels"; the training issue
//! uses the same rule on recorded local maps.

use crate::world::World;
use farsight_costmap_fusion::swath::{for_each_swath_cell, PolarGeometry};
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
        let speed = 1.0 / cost_s_per_m as f64;
        let mut order: Vec<usize> = (0..self.class_speeds_mps.len()).collect();
        order.sort_by(|&a, &b| self.class_speeds_mps[b].total_cmp(&self.class_speeds_mps[a]));
        order
            .into_iter()
            .find(|&c| self.class_speeds_mps[c] <= speed + 1e-9)
            .unwrap_or_else(|| {
                (0..self.class_speeds_mps.len())
                    .min_by(|&a, &b| self.class_speeds_mps[a].total_cmp(&self.class_speeds_mps[b]))
                    .expect("classes")
            })
    }
}

/// Polar cells (heading-major) labelled from the true world around a robot
/// at `pose` (x, y, yaw).
pub fn ground_truth_bins(
    world: &World,
    geometry: &PolarGeometry,
    pose: [f64; 3],
    rules: &LabelRules,
) -> Vec<PolarCell> {
    let radial = geometry.radial_bins();
    let classes = rules.class_speeds_mps.len();
    let mut counts = vec![vec![0usize; classes + 1]; geometry.heading_bins * radial];
    for_each_swath_cell(
        geometry,
        pose[0],
        pose[1],
        pose[2],
        world.resolution_m,
        |gx, gy, h, r| {
            let slot = &mut counts[h * radial + r];
            slot[classes] += 1; // every swath cell
            if world.contains(gx, gy) {
                slot[rules.class_of(world.cost_s_per_m(gx, gy))] += 1;
            }
        },
    );
    counts
        .iter()
        .map(|n| {
            let swath = n[classes];
            let seen: usize = n[..classes].iter().sum();
            if swath == 0 || (seen as f64) < rules.rho_bin * swath as f64 {
                return PolarCell {
                    cost_s_per_m: f32::NAN,
                    variance: f32::INFINITY,
                    class_id: u32::MAX,
                    probability: 0.0,
                };
            }
            let mut by_speed: Vec<usize> = (0..classes).collect();
            by_speed
                .sort_by(|&a, &b| rules.class_speeds_mps[b].total_cmp(&rules.class_speeds_mps[a]));
            let c = by_speed
                .into_iter()
                .find(|&c| n[c] as f64 >= rules.rho_class * seen as f64)
                .expect("some class covers rho_class <= 1/classes of the seen cells");
            PolarCell {
                cost_s_per_m: (1.0 / rules.class_speeds_mps[c]) as f32,
                variance: rules.variance,
                class_id: c as u32,
                probability: n[c] as f32 / seen as f32,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::Cover;

    #[test]
    fn the_cheapest_class_covering_rho_class_wins() {
        let rules = LabelRules::default();
        assert_eq!(rules.class_of(0.2), 2, "road: 5 m/s >= 4.25");
        assert_eq!(rules.class_of(0.5), 0, "grass: 2 m/s < 2.25");
        assert_eq!(rules.class_of(0.4), 1);
        assert_eq!(rules.class_of(f32::INFINITY), 0);
        // Forest, with a 12 m wide road north-south 30 m east of the robot.
        let mut w = World::new(300, 300, Cover::Forest);
        w.fill_cover(178, 0, 189, 299, Cover::Road);
        let g = PolarGeometry::fitam_default();
        let bins = ground_truth_bins(&w, &g, [150.0, 150.0, 0.0], &rules);
        // Looking east (bin of bearing 0), 25-50 m: the road covers about
        // 40% of the swath, over rho_class -> the road's (fastest) class.
        let ahead = g.heading_bin(0.01).unwrap();
        assert_eq!(bins[ahead * 3].class_id, 2, "{:?}", bins[ahead * 3]);
        let behind = g.heading_bin(std::f64::consts::PI - 0.01).unwrap();
        assert_eq!(bins[behind * 3].class_id, 0, "forest behind");
        // Near the world's edge, swaths mostly outside are unlabelled.
        let edge = ground_truth_bins(&w, &g, [2.0, 150.0, 0.0], &rules);
        assert!(edge[behind * 3 + 2].cost_s_per_m.is_nan());
    }
}
