//! Near-field sensing for the local layer (FITAM's local observations, out
//! to 25 m): cells seen up close are fixed at a cost with zero variance.
//! Two camera sources, besides costmaps from other systems:
//!
//! - [`depth_cells`]: a depth image through the camera model and mount.
//!   Points are binned into cells; a cell whose points span more than
//!   `max_step_m` in height holds an obstacle (lethal), and so does a cell
//!   whose ground (lowest point) rises more than `max_slope_deg` from a
//!   neighbour's; other seen cells cost `free_cost_s_per_m`.
//! - [`class_map_cells`]: the inference stage's class map projected onto flat
//!   ground from the mount height; a cell takes the highest class cost any
//!   of its pixels gives it (the conservative choice).
//!
//! Both return `(cell, cost)` pairs in the world frame of the pose given.

use crate::grid::cell_of;
use farsight_inference::normals::RayTable;
use farsight_interfaces::camera::Camera;
use farsight_interfaces::msg::Pose;
use farsight_stage::{ConfigError, Range, Ranges, Validate};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NearFieldConfig {
    /// Cameras whose depth images (`camera/<name>/depth`) feed the local layer.
    pub depth_cameras: Vec<String>,
    /// Metres per unit of MONO16 depth (f32 depth is metres already).
    pub depth_scale_m: f32,
    /// Cameras whose class maps (`perception/<name>/classes`) feed it.
    pub class_map_cameras: Vec<String>,
    /// Class -> cost table for class maps (the inference stage's format;
    /// relative to the config file).
    pub class_table: std::path::PathBuf,
    /// Only points this close (horizontally) are used: FITAM's local radius.
    pub range_m: f64,
    pub max_step_m: f64,
    pub max_slope_deg: f64,
    /// Cost of a seen cell that holds no obstacle (depth source).
    pub free_cost_s_per_m: f32,
    /// Use every n-th pixel in each direction.
    pub pixel_stride: usize,
}

impl Default for NearFieldConfig {
    fn default() -> Self {
        Self {
            depth_cameras: Vec::new(),
            depth_scale_m: 0.001,
            class_map_cameras: Vec::new(),
            class_table: Default::default(),
            range_m: 25.0,
            max_step_m: 0.3,
            max_slope_deg: 30.0,
            free_cost_s_per_m: 0.5,
            pixel_stride: 2,
        }
    }
}

impl Validate for NearFieldConfig {
    fn ranges(&self, r: &mut Ranges) {
        r.key(
            "depth_scale_m",
            self.depth_scale_m,
            Range::above_to(0.0, 1000.0).unit("m per unit"),
        )
        .key(
            "range_m",
            self.range_m,
            Range::above_to(0.0, 1000.0).unit("m"),
        )
        .key(
            "max_step_m",
            self.max_step_m,
            Range::above_to(0.0, 10.0).unit("m"),
        )
        .key(
            "max_slope_deg",
            self.max_slope_deg,
            Range::open(0.0, 90.0).unit("deg"),
        )
        .key(
            "free_cost_s_per_m",
            self.free_cost_s_per_m,
            Range::above_to(0.0, 1000.0).unit("s/m"),
        )
        .key("pixel_stride", self.pixel_stride, Range::between(1.0, 64.0));
    }

    fn check_rules(&self) -> Result<(), ConfigError> {
        for c in self.depth_cameras.iter().chain(&self.class_map_cameras) {
            farsight_interfaces::topics::validate_name(c)
                .map_err(|e| ConfigError::invalid("near_field cameras", c, e.why))?;
        }
        ConfigError::check(
            self.class_map_cameras.is_empty() || !self.class_table.as_os_str().is_empty(),
            "near_field.class_table",
            "\"\"",
            "a class table file when class_map_cameras is set",
        )?;
        Ok(())
    }
}

/// A cell's global index and the cost near-field sensing fixes it at.
pub type FixedCell = ((i64, i64), f32);

fn pixels(width: usize, height: usize, stride: usize) -> impl Iterator<Item = usize> {
    (0..height)
        .step_by(stride)
        .flat_map(move |v| (0..width).step_by(stride).map(move |u| v * width + u))
}

/// Depth (metres along the optical axis, per pixel of `table`'s size) ->
/// fixed cells. Non-finite or non-positive depths are skipped.
pub fn depth_cells(
    depth_m: &[f32],
    table: &RayTable,
    camera: &Camera,
    pose: &Pose,
    resolution_m: f64,
    rules: &NearFieldConfig,
) -> Vec<FixedCell> {
    // Per cell: lowest and highest point above the robot's ground plane.
    let mut span: HashMap<(i64, i64), (f64, f64)> = HashMap::new();
    for i in pixels(table.width, table.height, rules.pixel_stride.max(1)) {
        let d = depth_m.get(i).copied().unwrap_or(f32::NAN) as f64;
        let ray = table.ray(i);
        if !(d.is_finite() && d > 0.0) || ray.z == 0.0 {
            continue;
        }
        let p = camera.mount.translation_m + camera.mount.robot_from_optical * (ray * d);
        if p.x.hypot(p.y) > rules.range_m {
            continue;
        }
        let w = pose.to_world_frame([p.x, p.y]);
        let cell = (cell_of(w[0], resolution_m), cell_of(w[1], resolution_m));
        let e = span.entry(cell).or_insert((p.z, p.z));
        e.0 = e.0.min(p.z);
        e.1 = e.1.max(p.z);
    }
    let rise = rules.max_slope_deg.to_radians().tan() * resolution_m;
    span.iter()
        .map(|(&(x, y), &(lo, hi))| {
            let step = hi - lo > rules.max_step_m;
            let steep = [(1, 0), (-1, 0), (0, 1), (0, -1)].iter().any(|(dx, dy)| {
                span.get(&(x + dx, y + dy))
                    .is_some_and(|&(n_lo, _)| lo - n_lo > rise)
            });
            let cost = if step || steep {
                f32::INFINITY
            } else {
                rules.free_cost_s_per_m
            };
            ((x, y), cost)
        })
        .collect()
}

/// Class ids (per pixel of `table`'s size) projected onto flat ground ->
/// fixed cells with the highest class cost seen in each.
pub fn class_map_cells(
    class_ids: &[u8],
    table: &RayTable,
    camera: &Camera,
    pose: &Pose,
    resolution_m: f64,
    rules: &NearFieldConfig,
    cost_of: impl Fn(u8) -> f32,
) -> Vec<FixedCell> {
    let mut cells: HashMap<(i64, i64), f32> = HashMap::new();
    for i in pixels(table.width, table.height, rules.pixel_stride.max(1)) {
        let Some(&class) = class_ids.get(i) else {
            continue;
        };
        let ray = camera.mount.robot_from_optical * table.ray(i);
        let Some((x, y)) = camera.mount.ground_point_m(&ray) else {
            continue; // at or above the horizon: never meets the ground
        };
        if x.hypot(y) > rules.range_m {
            continue;
        }
        let w = pose.to_world_frame([x, y]);
        let cell = (cell_of(w[0], resolution_m), cell_of(w[1], resolution_m));
        let c = cost_of(class);
        let e = cells.entry(cell).or_insert(c);
        *e = e.max(c);
    }
    cells.into_iter().collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use farsight_interfaces::camera::{CameraModel, Mount};

    /// A camera 1 m up looking level ahead; depth rendered for flat ground
    /// with a 1.5 m tall box 5..6 m ahead across |y| < 0.5 m.
    fn scene() -> (Camera, RayTable, Vec<f32>) {
        let (w, h) = (80usize, 60usize);
        let cam = Camera::new(
            0,
            "front",
            CameraModel::pinhole(w as u32, h as u32, 40.0, 40.0, 39.5, 29.5),
            Mount::from_xyz_rpy_deg([0.0, 0.0, 1.0], [0.0; 3]),
        );
        let table = RayTable::new(&cam, w, h);
        let depth = (0..w * h)
            .map(|i| {
                let r = cam.mount.robot_from_optical * table.ray(i); // depth 1 m along the axis
                                                                     // March the ray (x forward, z up) to the box face or the ground.
                let t_box = 5.0 / r.x;
                let hit_box = r.x > 0.0
                    && (r.y * t_box).abs() < 0.5
                    && 1.0 + r.z * t_box > 0.0
                    && 1.0 + r.z * t_box < 1.5;
                if hit_box {
                    t_box as f32
                } else if r.z < -1e-6 {
                    (1.0 / -r.z) as f32
                } else {
                    f32::INFINITY // sky
                }
            })
            .collect();
        (cam, table, depth)
    }

    #[test]
    fn depth_marks_the_box_lethal_and_flat_ground_free() {
        let (cam, table, depth) = scene();
        let rules = NearFieldConfig {
            pixel_stride: 1,
            ..Default::default()
        };
        // Robot at (100, 50) facing north: "ahead" is +y in the world.
        let pose = Pose {
            position_m: [100.0, 50.0, 0.0],
            yaw_rad: std::f64::consts::FRAC_PI_2,
            ..Default::default()
        };
        let cells: HashMap<_, _> = depth_cells(&depth, &table, &cam, &pose, 1.0, &rules)
            .into_iter()
            .collect();
        assert_eq!(
            cells.get(&(100, 55)),
            Some(&f32::INFINITY),
            "the box face, 5 m ahead"
        );
        assert_eq!(cells.get(&(100, 53)), Some(&0.5), "flat ground 3 m ahead");
        assert!(!cells.contains_key(&(100, 48)), "behind the camera: unseen");
        assert!(cells.keys().all(|&(_, y)| y >= 50), "nothing behind");
        assert!(cells
            .keys()
            .all(|&(x, y)| (((x - 100).pow(2) + (y - 50).pow(2)) as f64).sqrt() <= 26.0));
    }

    #[test]
    fn class_map_projects_onto_the_ground_with_the_highest_cost_per_cell() {
        let (cam, table, _) = scene();
        // Left half of the image (robot's left, +y) is class 1 (bushes, 10 s/m),
        // the right half class 0 (grass, 0.5 s/m).
        let ids: Vec<u8> = (0..80 * 60)
            .map(|i| if i % 80 < 40 { 1 } else { 0 })
            .collect();
        let rules = NearFieldConfig {
            pixel_stride: 1,
            ..Default::default()
        };
        let cost = |c: u8| if c == 1 { 10.0 } else { 0.5 };
        let cells: HashMap<_, _> =
            class_map_cells(&ids, &table, &cam, &Pose::default(), 1.0, &rules, cost)
                .into_iter()
                .collect();
        assert_eq!(cells.get(&(5, 2)), Some(&10.0));
        assert_eq!(cells.get(&(5, -2)), Some(&0.5));
        assert_eq!(
            cells.get(&(5, 0)),
            Some(&10.0),
            "the seam cell takes the higher cost"
        );
        assert!(
            cells.keys().all(|&(x, _)| x > 0),
            "only ground ahead of the camera"
        );
    }
}
