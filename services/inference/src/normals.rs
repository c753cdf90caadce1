//! POVNav's depth surface-normal navigability (section 4.2): the surface at
//! each pixel is approximated by the triangle through it and its neighbours a
//! `step` above and to the left; the cross product of the two edges is the
//! normal (eq. 3-4), and a pixel is ground when that normal, turned into the
//! robot frame by the camera mount, is within `max_tilt_deg` of vertical (eq. 5).
//!
//! Clean-up as the paper describes: ground not connected to the bottom of the
//! image is unreachable and becomes non-navigable, and everything behind
//! (above, in the image) a non-navigable structure is non-navigable too.

use farsight_interfaces::camera::Camera;
use farsight_stage::{Range, Ranges, Validate};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;

/// Settings of the surface-normal backend.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NormalsConfig {
    /// How far a normal may lean from vertical and still be ground.
    pub max_tilt_deg: f32,
    /// Pixel distance to the neighbours that span the triangle (larger = smoother).
    pub step_px: usize,
    /// A non-navigable run at least this tall in a column hides what is above it.
    pub min_obstacle_px: usize,
    /// Metres per depth unit for MONO16 depth (ignored for f32 depth in metres).
    pub depth_scale_m: f32,
}

impl Default for NormalsConfig {
    fn default() -> Self {
        Self {
            max_tilt_deg: 20.0,
            step_px: 4,
            min_obstacle_px: 6,
            depth_scale_m: 0.001,
        }
    }
}

impl Validate for NormalsConfig {
    fn ranges(&self, r: &mut Ranges) {
        r.key(
            "max_tilt_deg",
            self.max_tilt_deg,
            Range::from_below(0.0, 90.0).unit("deg"),
        )
        .key(
            "step_px",
            self.step_px,
            Range::between(1.0, 64.0).unit("px"),
        )
        .key(
            "min_obstacle_px",
            self.min_obstacle_px,
            Range::between(1.0, 1000.0).unit("px"),
        )
        .key(
            "depth_scale_m",
            self.depth_scale_m,
            Range::above_to(0.0, 1000.0).unit("m per unit"),
        );
    }
}

/// Each pixel's ray scaled to unit depth (z = 1), so a point is depth * ray.
/// Un-projecting a distorted lens is iterative, so the table is built once per
/// camera and image size and reused for every frame.
pub struct RayTable {
    pub width: usize,
    pub height: usize,
    camera: Camera,
    rays: Vec<Vector3<f64>>,
}

impl RayTable {
    pub fn new(camera: &Camera, width: usize, height: usize) -> Self {
        let model = camera.model.scaled_to(width as u32, height as u32);
        let rays = (0..height)
            .flat_map(|v| (0..width).map(move |u| (u, v)))
            .map(|(u, v)| {
                let r = model.unproject(u as f64, v as f64);
                if r.z > 1e-6 {
                    r / r.z
                } else {
                    Vector3::zeros()
                }
            })
            .collect();
        Self {
            width,
            height,
            camera: camera.clone(),
            rays,
        }
    }

    /// The ray of pixel `i` (row-major), scaled to unit optical depth; zero
    /// for a pixel whose ray does not point forward (a fisheye's rim).
    pub fn ray(&self, i: usize) -> Vector3<f64> {
        self.rays[i]
    }

    /// Whether this table was built for `camera` at this size.
    pub fn fits(&self, camera: &Camera, width: usize, height: usize) -> bool {
        self.width == width && self.height == height && self.camera == *camera
    }
}

/// Per-pixel ground test before clean-up (1 = ground), POVNav eq. 3-5.
pub fn ground_with_rays(depth_m: &[f32], table: &RayTable, cfg: &NormalsConfig) -> Vec<u8> {
    let (width, height) = (table.width, table.height);
    let rot = table.camera.mount.robot_from_optical;
    let cos_tilt = cfg.max_tilt_deg.to_radians().cos() as f64;
    let rays = &table.rays;
    let point = |i: usize| -> Option<Vector3<f64>> {
        let z = depth_m[i];
        (z.is_finite() && z > 0.0 && rays[i].z > 0.0).then(|| rays[i] * z as f64)
    };
    let s = cfg.step_px;
    let mut ground = vec![0u8; width * height];
    for v in s..height {
        for u in s..width {
            let i = v * width + u;
            let (Some(p), Some(up), Some(left)) = (point(i), point(i - s * width), point(i - s))
            else {
                continue;
            };
            let n = (p - up).cross(&(p - left));
            let norm = n.norm();
            if norm < 1e-12 {
                continue;
            }
            let n_robot = rot * (n / norm);
            if n_robot.z.abs() >= cos_tilt {
                ground[i] = 1;
            }
        }
    }
    ground
}

/// The paper's clean-up: keep ground reachable from the bottom row, then mark
/// everything above a tall enough non-navigable run in each column.
pub fn clean_up(ground: &[u8], width: usize, height: usize, min_obstacle_px: usize) -> Vec<u8> {
    // Reachable ground: 4-connected flood fill from the bottom row.
    let mut reach = vec![0u8; width * height];
    let mut queue = VecDeque::new();
    let bottom = (height - 1) * width;
    for u in 0..width {
        if ground[bottom + u] == 1 {
            reach[bottom + u] = 1;
            queue.push_back(bottom + u);
        }
    }
    while let Some(i) = queue.pop_front() {
        let (u, v) = (i % width, i / width);
        let mut visit = |j: usize| {
            if ground[j] == 1 && reach[j] == 0 {
                reach[j] = 1;
                queue.push_back(j);
            }
        };
        if u > 0 {
            visit(i - 1);
        }
        if u + 1 < width {
            visit(i + 1);
        }
        if v > 0 {
            visit(i - width);
        }
        if v + 1 < height {
            visit(i + width);
        }
    }
    // Occlusion: scanning up each column, a non-navigable run of
    // `min_obstacle_px` hides the rest of the column.
    let mut out = vec![0u8; width * height];
    for u in 0..width {
        let mut run = 0;
        for v in (0..height).rev() {
            let i = v * width + u;
            if reach[i] == 1 {
                // A gap shorter than min_obstacle_px is noise: it stays
                // non-navigable itself but hides nothing above it.
                run = 0;
                out[i] = 255;
            } else {
                run += 1;
                if run >= min_obstacle_px {
                    break;
                }
            }
        }
    }
    out
}

/// Depth image -> navigability (255 = navigable), with clean-up.
pub fn navigability(
    depth_m: &[f32],
    width: usize,
    height: usize,
    camera: &Camera,
    cfg: &NormalsConfig,
) -> Vec<u8> {
    navigability_with_rays(depth_m, &RayTable::new(camera, width, height), cfg)
}

/// [`navigability`] with a prepared ray table (what the stage uses per frame).
pub fn navigability_with_rays(depth_m: &[f32], table: &RayTable, cfg: &NormalsConfig) -> Vec<u8> {
    let ground = ground_with_rays(depth_m, table, cfg);
    clean_up(&ground, table.width, table.height, cfg.min_obstacle_px)
}

#[cfg(test)]
mod tests {
    use super::*;
    use farsight_interfaces::camera::{CameraModel, Mount};

    fn camera(w: u32, h: u32, pitch_deg: f64) -> Camera {
        Camera::new(
            0,
            "c",
            CameraModel::pinhole(
                w,
                h,
                w as f64 * 0.8,
                w as f64 * 0.8,
                w as f64 / 2.0,
                h as f64 / 2.0,
            ),
            Mount::from_xyz_rpy_deg([0.0, 0.0, 1.0], [0.0, pitch_deg, 0.0]),
        )
    }

    /// Depth of a flat floor 1 m below a level camera, and a wall `wall_m` ahead.
    fn floor_and_wall(cam: &Camera, wall_m: f64) -> Vec<f32> {
        let (w, h) = (cam.model.width as usize, cam.model.height as usize);
        let mut d = vec![0.0f32; w * h];
        for v in 0..h {
            for u in 0..w {
                let r = cam.model.unproject(u as f64, v as f64);
                let r = r / r.z; // optical z = 1
                                 // Level camera: optical y points down; the floor is y = 1 m.
                let floor = if r.y > 1e-6 { 1.0 / r.y } else { f64::INFINITY };
                d[v * w + u] = floor.min(wall_m) as f32;
            }
        }
        d
    }

    #[test]
    fn floor_is_ground_and_the_wall_and_what_is_above_it_are_not() {
        let cam = camera(64, 48, 0.0);
        let depth = floor_and_wall(&cam, 5.0);
        let nav = navigability(&depth, 64, 48, &cam, &NormalsConfig::default());
        // Bottom rows: floor closer than the wall.
        assert_eq!(nav[47 * 64 + 32], 255);
        assert_eq!(nav[40 * 64 + 10], 255);
        // The wall (depth 5 m: floor rows above v = cy + f/5) and everything above it.
        let wall_row = (24.0 + 51.2 / 5.0) as usize - 3;
        assert_eq!(nav[wall_row * 64 + 32], 0);
        assert!(
            nav[..10 * 64].iter().all(|&v| v == 0),
            "above the wall is hidden"
        );
    }

    #[test]
    fn unreachable_island_is_removed() {
        // 5x5: ground everywhere except a ring of obstacle around a 1-pixel island.
        let (w, h) = (5, 5);
        let mut g = vec![1u8; w * h];
        for (u, v) in [
            (1, 1),
            (2, 1),
            (3, 1),
            (1, 2),
            (3, 2),
            (1, 3),
            (2, 3),
            (3, 3),
        ] {
            g[v * w + u] = 0;
        }
        let out = clean_up(&g, w, h, 10);
        assert_eq!(out[2 * w + 2], 0, "the enclosed island is unreachable");
        assert_eq!(out[4 * w + 2], 255);
        assert_eq!(out[2 * w], 255, "the open side column is reachable");
    }

    #[test]
    fn a_tall_enough_obstacle_hides_the_column_above_it() {
        // 3 columns so the flood fill can pass beside the middle column's gaps.
        let (w, h) = (3, 10);
        let mut g = vec![1u8; w * h];
        let mid = |v: usize| v * w + 1;
        g[mid(6)] = 0; // a 1-pixel gap (noise) hides nothing above it
        let out = clean_up(&g, w, h, 2);
        assert_eq!(out[mid(6)], 0);
        assert_eq!(out[mid(5)], 255);
        g[mid(3)] = 0;
        g[mid(2)] = 0; // a 2-pixel obstacle hides rows 0..=3 of its column
        let out = clean_up(&g, w, h, 2);
        assert!((0..4).all(|v| out[mid(v)] == 0));
        assert_eq!(out[mid(4)], 255);
        assert_eq!(out[0], 255, "neighbouring columns are unaffected");
    }
}
