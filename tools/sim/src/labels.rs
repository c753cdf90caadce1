//! Ground-truth far-field labels (FITAM section IV-B): for each (heading,
//! radial) bin around the robot, the cheapest speed class that covers at
//! least `rho_class` of the bin's swath, and nothing where under `rho_bin` of
//! the swath lies inside the world. The navigation benchmark feeds these to
//! the fused map as "FITAM with ground-truth labels"; the training issue
//! uses the same rule on recorded local maps.

use crate::world::World;
use farsight_costmap_fusion::labels::swath_labels;
pub use farsight_costmap_fusion::labels::LabelRules;
use farsight_costmap_fusion::swath::PolarGeometry;
use farsight_interfaces::msg::PolarCell;

/// Polar cells (heading-major) labelled from the true world around a robot
/// at `pose` (x, y, yaw); unlabelled swaths carry NaN (no measurement).
pub fn ground_truth_bins(
    world: &World,
    geometry: &PolarGeometry,
    pose: [f64; 3],
    rules: &LabelRules,
) -> Vec<PolarCell> {
    swath_labels(geometry, pose, world.resolution_m, rules, |gx, gy| {
        world.contains(gx, gy).then(|| world.cost_s_per_m(gx, gy))
    })
    .into_iter()
    .map(|label| match label {
        Some(l) => l.to_polar_cell(rules),
        None => PolarCell::NO_MEASUREMENT,
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
