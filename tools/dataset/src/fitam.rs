//! FITAM's self-supervised far-field labels (FITAM section IV-B): each image
//! slice looks into one heading bin; each of that bin's radial swaths is
//! labelled by the shared rule ([`farsight_costmap_fusion::labels`]) over the
//! cells the robot's local costmaps observed during the whole run, weighted
//! by the fraction observed.

use crate::run::{RecordedPose, SeenMap};
use farsight_costmap_fusion::labels::{swath_labels, LabelRules, SwathLabel};
use farsight_costmap_fusion::swath::PolarGeometry;

/// Labels of every (slice, radial bin), slice-major (`slice * radial + r`);
/// `slice_bins[s]` is the heading bin slice `s` looks into
/// ([`farsight_bin_projection::fitam::slice_heading_bins`]).
pub fn slice_labels(
    geometry: &PolarGeometry,
    slice_bins: &[Option<usize>],
    pose: &RecordedPose,
    seen: &SeenMap,
    rules: &LabelRules,
) -> Vec<Option<SwathLabel>> {
    let at = [pose.position_m[0], pose.position_m[1], pose.yaw_rad];
    let bins = swath_labels(geometry, at, seen.resolution_m, rules, |gx, gy| {
        seen.cost(gx, gy)
    });
    let radial = geometry.radial_bins();
    slice_bins
        .iter()
        .flat_map(|b| {
            (0..radial)
                .map(|r| b.and_then(|h| bins[h * radial + r]))
                .collect::<Vec<_>>()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slices_take_the_labels_of_the_bins_they_look_into() {
        let g = PolarGeometry::fitam_default();
        let rules = LabelRules::default();
        // Observed: road (0.2 s/m) north of y = 0 out to 100 m, forest
        // (2 s/m) south; nothing else.
        let mut seen = SeenMap::new(1.0);
        for x in -100..=100 {
            for y in -100..=100 {
                seen.set(x, y, if y > 0 { 0.2 } else { 2.0 });
            }
        }
        let north = g.heading_bin(std::f64::consts::FRAC_PI_2 + 0.05);
        let south = g.heading_bin(-std::f64::consts::FRAC_PI_2 + 0.05);
        let robot = RecordedPose {
            capture_time_ns: 0,
            position_m: [0.0, 0.0, 0.0],
            yaw_rad: 0.0,
        };
        let labels = slice_labels(&g, &[north, None, south], &robot, &seen, &rules);
        assert_eq!(labels.len(), 9);
        for r in 0..3 {
            assert_eq!(labels[r].unwrap().class_id, 2, "road to the north");
            assert_eq!(labels[3 + r], None, "a slice that looks nowhere");
            assert_eq!(labels[6 + r].unwrap().class_id, 0, "forest to the south");
        }
        // 75-100 m swaths reach past the observed square's corners only
        // diagonally; to the north they are fully inside it.
        assert_eq!(labels[2].unwrap().observed_fraction, 1.0);
        // Turned to face west, the slice that looked north looks south.
        let turned = RecordedPose {
            yaw_rad: std::f64::consts::PI,
            ..robot
        };
        let labels = slice_labels(&g, &[north], &turned, &seen, &rules);
        assert_eq!(labels[0].unwrap().class_id, 0, "forest");
    }
}
