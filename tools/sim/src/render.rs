//! The camera renderer: column-wise ray marching over the map, as the
//! "voxel space" terrain renderers do. Each image column is one azimuth; its
//! ray walks the map cell by cell (a grid DDA, so no 1 m tree is skipped),
//! front to back, and every cell fills the rows its ground and whatever stands
//! on it cover that nearer cells did not. Out come RGB (per-class colours,
//! shading, texture noise, distance haze and sky), exact depth along the
//! optical axis, and the class id of every pixel.
//!
//! Each column uses the azimuth of its principal-row pixel: exact for a level
//! pinhole camera, an approximation for pitched or fisheye cameras (whose
//! columns bend), which is what column marching buys its speed with.

use crate::world::{class, World};
use farsight_interfaces::camera::Camera;

/// One rendered view.
#[derive(Debug, Clone, Default)]
pub struct Frame {
    pub width: usize,
    pub height: usize,
    /// Packed RGB8.
    pub rgb: Vec<u8>,
    /// Metres along the optical axis; infinite for sky.
    pub depth_m: Vec<f32>,
    pub class_ids: Vec<u8>,
}

/// Base colour of each class id.
pub const PALETTE: [[u8; 3]; class::COUNT] = [
    [135, 180, 230], // sky
    [165, 150, 125], // road
    [140, 115, 85],  // trail
    [85, 150, 60],   // grass
    [175, 180, 95],  // field
    [40, 95, 40],    // bushes
    [95, 75, 45],    // forest floor
    [55, 95, 165],   // water
    [125, 125, 125], // rock
    [160, 85, 75],   // building
    [55, 70, 35],    // tree
    [205, 205, 200], // wall
];

/// Per-camera tables: each column's azimuth, and per pixel the tangent of
/// its elevation and the factor from horizontal distance to optical depth.
pub struct Renderer {
    camera: Camera,
    width: usize,
    height: usize,
    azimuth_rad: Vec<f64>,
    tan_elevation: Vec<f64>,
    depth_per_m: Vec<f64>,
    pub max_range_m: f64,
}

impl Renderer {
    pub fn new(camera: &Camera, max_range_m: f64) -> Self {
        let (width, height) = (camera.model.width as usize, camera.model.height as usize);
        let mut azimuth_rad = Vec::with_capacity(width);
        let mut tan_elevation = vec![f64::NEG_INFINITY; width * height];
        let mut depth_per_m = vec![0.0; width * height];
        for u in 0..width {
            let r = camera.pixel_ray_robot(u as f64, camera.model.cy);
            azimuth_rad.push(r.y.atan2(r.x));
            for v in 0..height {
                let optical = camera.model.unproject(u as f64, v as f64);
                let r = camera.mount.robot_from_optical * optical;
                let horizontal = r.x.hypot(r.y);
                if horizontal > 1e-9 && optical.z > 0.0 {
                    tan_elevation[v * width + u] = r.z / horizontal;
                    depth_per_m[v * width + u] = optical.z / horizontal;
                }
            }
        }
        Self {
            camera: camera.clone(),
            width,
            height,
            azimuth_rad,
            tan_elevation,
            depth_per_m,
            max_range_m,
        }
    }

    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    /// Renders the view from a robot at `pose` (x, y, yaw) into `out`.
    pub fn render(&self, world: &World, pose: [f64; 3], out: &mut Frame) {
        let (w, h) = (self.width, self.height);
        out.width = w;
        out.height = h;
        out.rgb.resize(w * h * 3, 0);
        out.depth_m.resize(w * h, 0.0);
        out.class_ids.resize(w * h, 0);
        let (s, c) = pose[2].sin_cos();
        let m = self.camera.mount.translation_m;
        let cam = [pose[0] + c * m.x - s * m.y, pose[1] + s * m.x + c * m.y];
        let (rx, ry) = world.cell_of(pose[0], pose[1]);
        let cam_z = world.ground_m(rx, ry) as f64 + m.z;
        let res = world.resolution_m;
        for u in 0..w {
            let a = pose[2] + self.azimuth_rad[u];
            let (dx, dy) = (a.cos(), a.sin());
            // Rows are filled from the bottom (v = h - 1) up; `next` is the
            // lowest row not yet drawn.
            let mut next = h as isize - 1;
            // Grid DDA from the camera's cell (cells are centred on multiples of res).
            let (mut cx, mut cy) = world.cell_of(cam[0], cam[1]);
            let step_x = if dx >= 0.0 { 1 } else { -1 };
            let step_y = if dy >= 0.0 { 1 } else { -1 };
            let edge = |cell: i64, step: i64| (cell as f64 + 0.5 * step as f64) * res;
            let mut t_max_x = if dx.abs() > 1e-12 {
                (edge(cx, step_x) - cam[0]) / dx
            } else {
                f64::INFINITY
            };
            let mut t_max_y = if dy.abs() > 1e-12 {
                (edge(cy, step_y) - cam[1]) / dy
            } else {
                f64::INFINITY
            };
            let t_dx = if dx.abs() > 1e-12 {
                res / dx.abs()
            } else {
                f64::INFINITY
            };
            let t_dy = if dy.abs() > 1e-12 {
                res / dy.abs()
            } else {
                f64::INFINITY
            };
            let mut t_in = 0.0f64;
            let mut side_x = true;
            while next >= 0 && t_in < self.max_range_m {
                let t_out = t_max_x.min(t_max_y);
                let look = world.look(cx, cy);
                let ground = look.ground_m as f64 - cam_z;
                let near = t_in.max(0.05);
                let ground_tan = ground / t_out;
                let stands = look.top_m > look.ground_m;
                let face_lo = ground / near;
                let face_hi = (look.top_m as f64 - cam_z) / near;
                let cover_tan = if stands {
                    face_hi.max(ground_tan)
                } else {
                    ground_tan
                };
                let haze = (t_in / self.max_range_m).min(1.0).powi(2) * 0.6;
                let noise = crate::rng::cell_noise(cx, cy, 17);
                while next >= 0 {
                    let i = next as usize * w + u;
                    let te = self.tan_elevation[i];
                    if te > cover_tan {
                        break;
                    }
                    let on_face = stands && te >= face_lo;
                    let (class_id, t_hit, shade) = if on_face {
                        (look.top_class, near, if side_x { 0.78 } else { 0.95 })
                    } else {
                        // Where the ray meets this cell's ground (clamped into the cell).
                        let t = if te < 0.0 {
                            (ground / te).clamp(near, t_out)
                        } else {
                            t_out
                        };
                        (look.ground_class, t, 0.8 + 0.35 * noise)
                    };
                    write_pixel(
                        out,
                        i,
                        class_id,
                        shade,
                        haze,
                        (t_hit * self.depth_per_m[i]) as f32,
                    );
                    next -= 1;
                }
                // Step to the next cell.
                t_in = t_out;
                if t_max_x < t_max_y {
                    cx += step_x;
                    t_max_x += t_dx;
                    side_x = true;
                } else {
                    cy += step_y;
                    t_max_y += t_dy;
                    side_x = false;
                }
            }
            while next >= 0 {
                let i = next as usize * w + u;
                // Sky: lighter toward the horizon.
                let up = (next as f64 / h as f64).clamp(0.0, 1.0);
                write_pixel(out, i, class::SKY, 0.85 + 0.15 * up, 0.0, f32::INFINITY);
                next -= 1;
            }
        }
    }
}

fn write_pixel(out: &mut Frame, i: usize, class_id: u8, shade: f64, haze: f64, depth_m: f32) {
    let base = PALETTE[class_id as usize];
    let sky = PALETTE[class::SKY as usize];
    for k in 0..3 {
        let lit = base[k] as f64 * shade;
        out.rgb[i * 3 + k] = (lit * (1.0 - haze) + sky[k] as f64 * haze).clamp(0.0, 255.0) as u8;
    }
    out.class_ids[i] = class_id;
    out.depth_m[i] = depth_m;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::{Cover, Obstacle};
    use farsight_interfaces::camera::{CameraModel, Mount};

    fn level_camera() -> Camera {
        Camera::new(
            0,
            "front",
            CameraModel::pinhole(64, 48, 32.0, 32.0, 31.5, 23.5),
            Mount::from_xyz_rpy_deg([0.0, 0.0, 1.0], [0.0; 3]),
        )
    }

    #[test]
    fn flat_ground_depth_and_sky_are_exact() {
        let world = World::new(200, 200, Cover::Grass);
        let cam = level_camera();
        let r = Renderer::new(&cam, 150.0);
        let mut f = Frame::default();
        r.render(&world, [100.0, 100.0, 0.0], &mut f);
        // Row v below the centre sees the ground at z = f * h / (v - cy).
        for v in [30usize, 35, 47] {
            let want = 32.0 * 1.0 / (v as f64 - 23.5);
            let got = f.depth_m[v * 64 + 32] as f64;
            assert!(
                (got - want).abs() < 1e-6 * want.max(1.0),
                "row {v}: {got} vs {want}"
            );
            assert_eq!(f.class_ids[v * 64 + 32], class::GRASS);
        }
        assert_eq!(f.class_ids[10 * 64 + 32], class::SKY);
        assert!(f.depth_m[10 * 64 + 32].is_infinite());
    }

    #[test]
    fn a_wall_ahead_fills_its_rows_at_its_distance() {
        let mut world = World::new(200, 200, Cover::Grass);
        // A wall across x = 110 (10 m ahead; its near face is at 9.5 m).
        world.line_obstacle((110, 80), (110, 120), Obstacle::Wall);
        let cam = level_camera();
        let r = Renderer::new(&cam, 150.0);
        let mut f = Frame::default();
        r.render(&world, [100.0, 100.0, 0.0], &mut f);
        // The wall is 2.5 m tall, the camera 1 m up: it spans from the ground at
        // 9.5 m (row 23.5 + 32/9.5 = 26.9) up to 1.5 m above the camera
        // (row 23.5 - 32 * 1.5 / 9.5 = 18.4).
        for v in 19..=26 {
            assert_eq!(f.class_ids[v * 64 + 32], class::WALL, "row {v}");
            assert!((f.depth_m[v * 64 + 32] - 9.5).abs() < 1e-4);
        }
        assert_eq!(f.class_ids[17 * 64 + 32], class::SKY);
        assert_eq!(f.class_ids[28 * 64 + 32], class::GRASS);
        // Turned around, the wall is behind and unseen.
        r.render(&world, [100.0, 100.0, std::f64::consts::PI], &mut f);
        assert!(!f.class_ids.contains(&class::WALL));
    }
}
