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
//!
//! Also the top-down map picture ([`map_picture`]): the world by class, the
//! driven track, the expert's path, start, goal and the interventions, as
//! `farsight bench nav --trace` draws each trial that got stuck (issue 20,
//! item 1: where and why trials strand the robot).

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
    [150, 165, 70],  // tall grass
    [70, 110, 50],   // shrub
];

/// Per-camera tables: each column's azimuth, and per pixel the tangent of
/// its elevation and the factor from horizontal distance to optical depth
/// (column-major, `u * height + v`: a ray walks its column).
pub struct Renderer {
    camera: Camera,
    width: usize,
    height: usize,
    azimuth_rad: Vec<f64>,
    tan_elevation: Vec<f64>,
    depth_per_m: Vec<f64>,
    /// Each row's sky colour (lighter toward the horizon).
    sky_rgb: Vec<[u8; 3]>,
    pub max_range_m: f64,
    /// Bands of columns rendered at once: this machine's cores, at most 4.
    pub threads: usize,
    /// Each band's column-major pixels, kept between frames.
    scratch: Vec<Frame>,
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
                    tan_elevation[u * height + v] = r.z / horizontal;
                    depth_per_m[u * height + v] = optical.z / horizontal;
                }
            }
        }
        let sky_rgb = (0..height)
            .map(|v| {
                let up = (v as f64 / height as f64).clamp(0.0, 1.0);
                shaded(class::SKY, 0.85 + 0.15 * up, 0.0)
            })
            .collect();
        Self {
            camera: camera.clone(),
            width,
            height,
            azimuth_rad,
            tan_elevation,
            depth_per_m,
            sky_rgb,
            max_range_m,
            threads: std::thread::available_parallelism().map_or(1, |n| n.get().min(4)),
            scratch: Vec::new(),
        }
    }

    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    /// Renders the view from a robot at `pose` (x, y, yaw) into `out`.
    ///
    /// Columns are independent rays: the frame is cut into one band of
    /// columns per core ([`Self::threads`]), each marched into column-major
    /// scratch, then copied into the row-major frame [`COLUMN_BLOCK`]
    /// columns at a time (writing a row-major frame one column at a time
    /// touches a new cache line for every pixel). The result does not depend
    /// on the number of bands.
    pub fn render(&mut self, world: &World, pose: [f64; 3], out: &mut Frame) {
        self.render_channels(world, pose, out, Channels::ALL);
    }

    /// [`Self::render`] filling only `channels` of `out` (the others keep
    /// their size and whatever they held): copying a channel nobody reads
    /// into the frame was most of a frame's cost.
    pub fn render_channels(
        &mut self,
        world: &World,
        pose: [f64; 3],
        out: &mut Frame,
        channels: Channels,
    ) {
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
        let band = w.div_ceil(self.threads.max(1)).max(1);
        let mut scratch = std::mem::take(&mut self.scratch);
        scratch.resize_with(w.div_ceil(band), Frame::default);
        let this = &*self;
        let march = |k: usize, col: &mut Frame| {
            let u0 = k * band;
            let n = band.min(w - u0);
            col.width = n;
            col.height = h;
            col.rgb.resize(n * h * 3, 0);
            col.depth_m.resize(n * h, 0.0);
            col.class_ids.resize(n * h, 0);
            for j in 0..n {
                this.march_column(world, pose[2], cam, cam_z, u0 + j, col, j * h, channels);
            }
        };
        std::thread::scope(|scope| {
            let (first, others) = scratch.split_first_mut().expect("one band at least");
            for (k, col) in others.iter_mut().enumerate() {
                scope.spawn(move || march(k + 1, col));
            }
            march(0, first);
        });
        // Pixels as [u8; 3]: a pixel is one move, not a three-byte slice copy.
        let rgb_out = out.rgb.as_chunks_mut::<3>().0;
        for (k, col) in scratch.iter().enumerate() {
            let u0 = k * band;
            let rgb_in = col.rgb.as_chunks::<3>().0;
            for b0 in (0..col.width).step_by(COLUMN_BLOCK) {
                let n = COLUMN_BLOCK.min(col.width - b0);
                for v in 0..h {
                    let (from, to) = (b0 * h + v, v * w + u0 + b0);
                    let pixels = (0..n).map(|j| (from + j * h, to + j));
                    if channels.rgb {
                        for (from, to) in pixels.clone() {
                            rgb_out[to] = rgb_in[from];
                        }
                    }
                    if channels.class_ids {
                        for (from, to) in pixels.clone() {
                            out.class_ids[to] = col.class_ids[from];
                        }
                    }
                    if channels.depth {
                        for (from, to) in pixels {
                            out.depth_m[to] = col.depth_m[from];
                        }
                    }
                }
            }
        }
        self.scratch = scratch;
    }

    /// Column `u`'s ray from the camera at `cam` (height `cam_z`), written
    /// into `col` from pixel `at` on (its rows in order, `at + v`); only
    /// `channels` are worked out and written.
    #[allow(clippy::too_many_arguments)]
    fn march_column(
        &self,
        world: &World,
        yaw_rad: f64,
        cam: [f64; 2],
        cam_z: f64,
        u: usize,
        col: &mut Frame,
        at: usize,
        channels: Channels,
    ) {
        let h = self.height;
        let res = world.resolution_m;
        let table = u * h;
        let a = yaw_rad + self.azimuth_rad[u];
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
        // How far the world's tallest possible top rises above the camera.
        let rise_m = world.top_bound_m() as f64 - cam_z;
        while next >= 0 && t_in < self.max_range_m {
            // A cell from `t_in` on covers no row whose tangent exceeds
            // rise_m / t_in (or 0 when nothing rises above the camera), so
            // once the lowest undrawn row is above that, the rest is sky:
            // the march ends where the image ends, not at the range (on
            // open ground that is most of a column's cells). Past 5 cm,
            // where `near` is `t_in` itself, the bound holds as computed.
            if t_in >= 0.05 {
                let reach = if rise_m > 0.0 { rise_m / t_in } else { 0.0 };
                if self.tan_elevation[table + next as usize] > reach {
                    break;
                }
            }
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
            let haze = || (t_in / self.max_range_m).min(1.0).powi(2) * 0.6;
            // A cell's face and its ground each have one colour: shade
            // them once, not per pixel (most of a frame is ground).
            let face_shade = if side_x { 0.78 } else { 0.95 };
            let (mut face_rgb, mut ground_rgb) = (None, None);
            while next >= 0 {
                let v = next as usize;
                let te = self.tan_elevation[table + v];
                if te > cover_tan {
                    break;
                }
                let on_face = stands && te >= face_lo;
                let i = at + v;
                if on_face {
                    if channels.rgb {
                        let rgb = *face_rgb
                            .get_or_insert_with(|| shaded(look.top_class, face_shade, haze()));
                        col.rgb[i * 3..i * 3 + 3].copy_from_slice(&rgb);
                    }
                    if channels.depth {
                        col.depth_m[i] = (near * self.depth_per_m[table + v]) as f32;
                    }
                    col.class_ids[i] = look.top_class;
                } else {
                    if channels.rgb {
                        let rgb = *ground_rgb.get_or_insert_with(|| {
                            let noise = crate::rng::cell_noise(cx, cy, 17);
                            shaded(look.ground_class, 0.8 + 0.35 * noise, haze())
                        });
                        col.rgb[i * 3..i * 3 + 3].copy_from_slice(&rgb);
                    }
                    if channels.depth {
                        // Where the ray meets this cell's ground (clamped into the cell).
                        let t = if te < 0.0 {
                            (ground / te).clamp(near, t_out)
                        } else {
                            t_out
                        };
                        col.depth_m[i] = (t * self.depth_per_m[table + v]) as f32;
                    }
                    col.class_ids[i] = look.ground_class;
                }
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
            let (v, i) = (next as usize, at + next as usize);
            if channels.rgb {
                col.rgb[i * 3..i * 3 + 3].copy_from_slice(&self.sky_rgb[v]);
            }
            if channels.depth {
                col.depth_m[i] = f32::INFINITY;
            }
            col.class_ids[i] = class::SKY;
            next -= 1;
        }
    }
}

/// The parts of a [`Frame`] a render fills.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Channels {
    pub rgb: bool,
    pub depth: bool,
    pub class_ids: bool,
}

impl Channels {
    pub const ALL: Self = Self {
        rgb: true,
        depth: true,
        class_ids: true,
    };
}

/// What [`map_picture`] draws over the world (world metres).
#[derive(Debug, Clone, Copy, Default)]
pub struct MapMarks<'a> {
    /// The robot's track (drawn last, on top).
    pub track: &'a [[f64; 2]],
    /// The expert's path.
    pub expert_path: &'a [[f64; 2]],
    /// Where frames went without a command.
    pub no_command: &'a [[f64; 2]],
    /// Where interventions happened.
    pub interventions: &'a [[f64; 2]],
    pub start: [f64; 2],
    pub goal: [f64; 2],
}

/// The map picture's colours.
pub mod map_colour {
    pub const TRACK: [u8; 3] = [255, 255, 255];
    pub const EXPERT: [u8; 3] = [0, 230, 255];
    pub const NO_COMMAND: [u8; 3] = [255, 150, 0];
    pub const INTERVENTION: [u8; 3] = [255, 0, 255];
    pub const START: [u8; 3] = [40, 80, 255];
    pub const GOAL: [u8; 3] = [255, 30, 30];
}

/// A top-down picture of `world` (north up, `crate::run::map_scale`
/// pixels per cell) with `marks`: the expert's path (cyan), the driven
/// track (white), frames without a command (orange dots), each
/// intervention (a magenta cross), the start (blue) and goal (red).
/// Returns width, height and packed RGB8.
pub fn map_picture(world: &World, marks: &MapMarks) -> (usize, usize, Vec<u8>) {
    let k = crate::run::map_scale(world.width, world.height);
    let (w, h) = (world.width * k, world.height * k);
    let mut rgb = vec![0u8; w * h * 3];
    for py in 0..h {
        for px in 0..w {
            let (cx, cy) = ((px / k) as i64, (world.height - 1 - py / k) as i64);
            let c = PALETTE[world.look(cx, cy).top_class as usize];
            rgb[(py * w + px) * 3..][..3].copy_from_slice(&c);
        }
    }
    // Picture coordinates of a world point: cell (cx, cy) spans pixels
    // [cx k, (cx + 1) k) across and its row, counted from the top, down.
    let r = world.resolution_m;
    let to_px = |p: [f64; 2]| {
        (
            (p[0] / r + 0.5) * k as f64,
            (world.height as f64 - (p[1] / r + 0.5)) * k as f64,
        )
    };
    let mut put = |x: f64, y: f64, c: [u8; 3]| {
        if x >= 0.0 && y >= 0.0 && (x as usize) < w && (y as usize) < h {
            let i = (y as usize * w + x as usize) * 3;
            rgb[i..i + 3].copy_from_slice(&c);
        }
    };
    let line = |points: &[[f64; 2]], c: [u8; 3], put: &mut dyn FnMut(f64, f64, [u8; 3])| {
        for pair in points.windows(2) {
            let (a, b) = (to_px(pair[0]), to_px(pair[1]));
            let n = ((b.0 - a.0).abs().max((b.1 - a.1).abs()) * 2.0)
                .ceil()
                .max(1.0) as usize;
            for i in 0..=n {
                let t = i as f64 / n as f64;
                put(a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1), c);
            }
        }
        if let [p] = points {
            let q = to_px(*p);
            put(q.0, q.1, c);
        }
    };
    line(marks.expert_path, map_colour::EXPERT, &mut put);
    line(marks.track, map_colour::TRACK, &mut put);
    let spot = (k as f64).max(2.0);
    for p in marks.no_command {
        let (x, y) = to_px(*p);
        put(x, y, map_colour::NO_COMMAND);
        put(x + 1.0, y, map_colour::NO_COMMAND);
    }
    for p in marks.interventions {
        let (x, y) = to_px(*p);
        for d in -3..=3 {
            let d = d as f64 * spot / 2.0;
            put(x + d, y + d, map_colour::INTERVENTION);
            put(x + d, y - d, map_colour::INTERVENTION);
        }
    }
    for (p, c) in [
        (marks.start, map_colour::START),
        (marks.goal, map_colour::GOAL),
    ] {
        let (x, y) = to_px(p);
        for dy in -2..=2 {
            for dx in -2..=2 {
                put(x + dx as f64 * spot / 2.0, y + dy as f64 * spot / 2.0, c);
            }
        }
    }
    (w, h, rgb)
}

/// Columns copied into the row-major frame together.
const COLUMN_BLOCK: usize = 16;

/// A class's colour, lit by `shade` and faded toward the sky by `haze`.
fn shaded(class_id: u8, shade: f64, haze: f64) -> [u8; 3] {
    let base = PALETTE[class_id as usize];
    let sky = PALETTE[class::SKY as usize];
    std::array::from_fn(|k| {
        let lit = base[k] as f64 * shade;
        (lit * (1.0 - haze) + sky[k] as f64 * haze).clamp(0.0, 255.0) as u8
    })
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
        let mut r = Renderer::new(&cam, 150.0);
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
    fn bands_and_channels_do_not_change_a_pixel() {
        let mut world = World::new(200, 200, Cover::Grass);
        world.line_obstacle((110, 80), (110, 120), Obstacle::Wall);
        world.fill_cover(103, 99, 106, 104, Cover::Bushes);
        let cam = level_camera();
        let mut one = Renderer::new(&cam, 150.0);
        one.threads = 1;
        let mut full = Frame::default();
        one.render(&world, [100.0, 101.3, 0.2], &mut full);
        for threads in [2, 3, 64] {
            let mut r = Renderer::new(&cam, 150.0);
            r.threads = threads;
            let mut f = Frame::default();
            r.render(&world, [100.0, 101.3, 0.2], &mut f);
            assert_eq!(
                (&f.rgb, &f.class_ids, &f.depth_m),
                (&full.rgb, &full.class_ids, &full.depth_m),
                "{threads} bands"
            );
        }
        let mut rgb_only = Frame::default();
        let only = Channels {
            rgb: true,
            depth: false,
            class_ids: false,
        };
        one.render_channels(&world, [100.0, 101.3, 0.2], &mut rgb_only, only);
        assert_eq!(rgb_only.rgb, full.rgb);
        assert!(rgb_only.class_ids.iter().all(|&c| c == 0), "not filled");
        for (depth, class_ids) in [(true, false), (false, true)] {
            let mut f = Frame::default();
            let only = Channels {
                rgb: false,
                depth,
                class_ids,
            };
            one.render_channels(&world, [100.0, 101.3, 0.2], &mut f, only);
            assert!(f.rgb.iter().all(|&c| c == 0), "{only:?}: colour not filled");
            if depth {
                assert_eq!(f.depth_m, full.depth_m, "{only:?}");
            } else {
                assert_eq!(f.class_ids, full.class_ids, "{only:?}");
            }
        }
        assert!(full.class_ids.contains(&class::WALL) && full.class_ids.contains(&class::BUSHES));
    }

    #[test]
    fn ending_the_march_where_nothing_can_rise_into_view_changes_no_pixel() {
        // The same view of a wall and bushes on a slope, in a world whose
        // tallest top is the wall and in one that also holds a 1 km pillar
        // out of sight behind the camera: there no column can end before
        // its range, here most end early, and every pixel must agree.
        // Uphill to the east, so the ground fills the rows below the
        // horizon early and the far tree line must still be drawn above.
        let slope: Vec<f32> = (0..200 * 200).map(|i| (i % 200) as f32 * 0.04).collect();
        let mut world = World::new(200, 200, Cover::Grass);
        world.set_ground(slope.clone());
        world.line_obstacle((110, 80), (110, 120), Obstacle::Wall);
        world.fill_cover(103, 99, 106, 104, Cover::Bushes);
        world.line_obstacle((80, 160), (100, 170), Obstacle::Tree);
        world.line_obstacle((185, 60), (185, 140), Obstacle::Tree);
        let mut pillar = world.clone();
        let mut high = slope;
        high[100 * 200] = 1000.0; // cell (0, 100), west of every pose
        pillar.set_ground(high);
        assert!(pillar.top_bound_m() > 1000.0 && world.top_bound_m() < 20.0);
        let cam = level_camera();
        let mut r = Renderer::new(&cam, 150.0);
        for pose in [
            [100.0, 101.3, 0.2],
            [100.0, 101.3, -0.4],
            [60.0, 150.0, 0.5],
        ] {
            let (mut early, mut full) = (Frame::default(), Frame::default());
            r.render(&world, pose, &mut early);
            r.render(&pillar, pose, &mut full);
            assert_eq!(
                (&early.rgb, &early.class_ids, &early.depth_m),
                (&full.rgb, &full.class_ids, &full.depth_m),
                "{pose:?}"
            );
            assert!(early.class_ids.contains(&class::SKY), "{pose:?}");
        }
    }

    #[test]
    fn the_map_picture_draws_the_track_over_the_expert_and_marks_interventions() {
        use map_colour::*;
        let mut world = World::new(100, 50, Cover::Grass);
        world.line_obstacle((50, 10), (50, 40), Obstacle::Wall);
        let track: Vec<[f64; 2]> = (10..=40).map(|x| [x as f64, 25.0]).collect();
        let expert = [[10.0, 25.0], [30.0, 5.0], [90.0, 25.0]];
        let marks = MapMarks {
            track: &track,
            expert_path: &expert,
            interventions: &[[40.0, 25.0]],
            start: [10.0, 25.0],
            goal: [90.0, 25.0],
            ..Default::default()
        };
        let (w, h, rgb) = map_picture(&world, &marks);
        let k = crate::run::map_scale(100, 50);
        assert_eq!((w, h, rgb.len()), (100 * k, 50 * k, 100 * k * 50 * k * 3));
        let at = |x: f64, y: f64| {
            let (px, py) = ((x + 0.5) * k as f64, (50.0 - (y + 0.5)) * k as f64);
            let i = (py as usize * w + px as usize) * 3;
            [rgb[i], rgb[i + 1], rgb[i + 2]]
        };
        assert_eq!(at(20.0, 25.0), TRACK);
        assert_eq!(
            at(20.0, 15.0),
            EXPERT,
            "halfway down the expert's first leg"
        );
        assert_eq!(at(40.0, 25.0), INTERVENTION);
        assert_eq!(at(90.0, 25.0), GOAL);
        assert_eq!(at(50.0, 30.0), PALETTE[class::WALL as usize]);
        assert_eq!(at(70.0, 45.0), PALETTE[class::GRASS as usize]);
        let count = |c: [u8; 3]| rgb.chunks(3).filter(|p| *p == c).count();
        assert!(count(TRACK) >= 25 * k, "{}", count(TRACK));
    }

    #[test]
    fn a_wall_ahead_fills_its_rows_at_its_distance() {
        let mut world = World::new(200, 200, Cover::Grass);
        // A wall across x = 110 (10 m ahead; its near face is at 9.5 m).
        world.line_obstacle((110, 80), (110, 120), Obstacle::Wall);
        let cam = level_camera();
        let mut r = Renderer::new(&cam, 150.0);
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
