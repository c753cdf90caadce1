//! The simulated robot: a unicycle that follows velocity commands within
//! its acceleration limits and the terrain's speed limit (FITAM's class
//! speeds: a cell costing c s/m cannot be crossed faster than 1/c m/s).
//! Its disc footprint never enters a lethal cell: head-on it stops, at a
//! glancing contact it slides along the obstacle (both counted as
//! collisions).

use crate::world::World;

/// Version of the robot model (footprint, contact and speed rules), hashed
/// into every `farsight bench nav` result: change it whenever the same
/// commands would drive a different track.
/// 1: a disc footprint that stops head-on and slides at a glancing
/// contact (issue 20; before, five points sampled on the body stopped it).
pub const ROBOT_MODEL_VERSION: u32 = 1;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RobotLimits {
    pub max_linear_mps: f64,
    pub max_angular_radps: f64,
    pub max_linear_accel_mps2: f64,
    pub max_angular_accel_radps2: f64,
    /// The footprint is a disc of this radius; it may not overlap a lethal
    /// cell.
    pub radius_m: f64,
}

impl Default for RobotLimits {
    fn default() -> Self {
        Self {
            max_linear_mps: 2.0,
            max_angular_radps: 1.5,
            max_linear_accel_mps2: 1.5,
            max_angular_accel_radps2: 3.0,
            radius_m: 0.4,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Robot {
    pub x_m: f64,
    pub y_m: f64,
    pub yaw_rad: f64,
    pub linear_mps: f64,
    pub angular_radps: f64,
    pub collisions: u32,
    pub distance_m: f64,
    /// Sum of cost x distance over the cells driven (seconds).
    pub traversal_cost_s: f64,
}

impl Robot {
    pub fn at(pose: [f64; 3]) -> Self {
        Self {
            x_m: pose[0],
            y_m: pose[1],
            yaw_rad: pose[2],
            ..Default::default()
        }
    }

    pub fn pose(&self) -> [f64; 3] {
        [self.x_m, self.y_m, self.yaw_rad]
    }

    /// Whether the robot's disc of radius `r` centred at (x, y) touches no
    /// lethal cell (each a square of the world's resolution). A disc's
    /// footprint does not depend on the heading, so turning in place never
    /// collides; sampling points on the body instead let a turn pin the
    /// robot against a tree it was already beside (issue 20, bench nav
    /// random seed 4: stuck 3 m from the goal for 400 s), and missed the
    /// corners a diagonal approach runs into.
    pub fn footprint_free(world: &World, x: f64, y: f64, r: f64) -> bool {
        let res = world.resolution_m;
        let (x0, y0) = world.cell_of(x - r, y - r);
        let (x1, y1) = world.cell_of(x + r, y + r);
        (y0..=y1).all(|cy| {
            (x0..=x1).all(|cx| {
                if !world.lethal(cx, cy) {
                    return true;
                }
                let dx = ((x - cx as f64 * res).abs() - res / 2.0).max(0.0);
                let dy = ((y - cy as f64 * res).abs() - res / 2.0).max(0.0);
                dx * dx + dy * dy >= r * r
            })
        })
    }

    /// Where a move `m` (metres) that hits an obstacle ends instead: the
    /// disc slides along the obstacle nearest it, keeping the part of the
    /// move that does not push into it, as a round robot glancing off a
    /// tree's corner. `None` head-on, or where the slide hits something
    /// too. Without it a glancing contact pinned the robot for good: its
    /// controller asked for the same move every step (issue 20, bench nav
    /// obstacle-field-3).
    fn slide(&self, world: &World, m: [f64; 2], r: f64) -> Option<[f64; 2]> {
        let reach = r + m[0].hypot(m[1]);
        let res = world.resolution_m;
        let (x0, y0) = world.cell_of(self.x_m - reach, self.y_m - reach);
        let (x1, y1) = world.cell_of(self.x_m + reach, self.y_m + reach);
        let mut nearest: Option<(f64, [f64; 2])> = None;
        for cy in y0..=y1 {
            for cx in x0..=x1 {
                if !world.lethal(cx, cy) {
                    continue;
                }
                let (ccx, ccy) = (cx as f64 * res, cy as f64 * res);
                let p = [
                    self.x_m.clamp(ccx - res / 2.0, ccx + res / 2.0),
                    self.y_m.clamp(ccy - res / 2.0, ccy + res / 2.0),
                ];
                let d = (self.x_m - p[0]).hypot(self.y_m - p[1]);
                if nearest.is_none_or(|(b, _)| d < b) {
                    nearest = Some((d, p));
                }
            }
        }
        let (d, p) = nearest?;
        if d < 1e-9 {
            return None;
        }
        let n = [(self.x_m - p[0]) / d, (self.y_m - p[1]) / d];
        let into = m[0] * n[0] + m[1] * n[1];
        if into >= 0.0 {
            return None;
        }
        let t = [m[0] - into * n[0], m[1] - into * n[1]];
        // Head-on: nothing left to slide with.
        if t[0].hypot(t[1]) < 0.05 * m[0].hypot(m[1]) {
            return None;
        }
        let q = [self.x_m + t[0], self.y_m + t[1]];
        Self::footprint_free(world, q[0], q[1], r).then_some(q)
    }

    /// Advances `dt_s` under the command (v, omega). Returns false when the
    /// robot hit an obstacle head-on and stopped where it was; a glancing
    /// contact slides ([`Robot::slide`]). Both count a collision.
    pub fn step(
        &mut self,
        world: &World,
        command: (f64, f64),
        dt_s: f64,
        limits: &RobotLimits,
    ) -> bool {
        let (cx, cy) = world.cell_of(self.x_m, self.y_m);
        let terrain_speed = (1.0 / world.cost_s_per_m(cx, cy) as f64).min(limits.max_linear_mps);
        let target_v = command.0.clamp(-terrain_speed, terrain_speed);
        let target_w = command
            .1
            .clamp(-limits.max_angular_radps, limits.max_angular_radps);
        let ramp = |from: f64, to: f64, a: f64| from + (to - from).clamp(-a * dt_s, a * dt_s);
        self.linear_mps = ramp(self.linear_mps, target_v, limits.max_linear_accel_mps2);
        self.angular_radps = ramp(
            self.angular_radps,
            target_w,
            limits.max_angular_accel_radps2,
        );
        let yaw = self.yaw_rad + self.angular_radps * dt_s;
        let mid = self.yaw_rad + 0.5 * self.angular_radps * dt_s;
        let (nx, ny) = (
            self.x_m + self.linear_mps * dt_s * mid.cos(),
            self.y_m + self.linear_mps * dt_s * mid.sin(),
        );
        let (nx, ny) = if Self::footprint_free(world, nx, ny, limits.radius_m) {
            (nx, ny)
        } else {
            self.collisions += 1;
            self.yaw_rad = yaw;
            match self.slide(world, [nx - self.x_m, ny - self.y_m], limits.radius_m) {
                Some(p) => {
                    let (m, t) = (
                        (nx - self.x_m).hypot(ny - self.y_m),
                        (p[0] - self.x_m).hypot(p[1] - self.y_m),
                    );
                    self.linear_mps *= t / m;
                    (p[0], p[1])
                }
                None => {
                    self.linear_mps = 0.0;
                    return false;
                }
            }
        };
        let d = (nx - self.x_m).hypot(ny - self.y_m);
        self.distance_m += d;
        self.traversal_cost_s += d * world.cost_s_per_m(cx, cy) as f64;
        (self.x_m, self.y_m, self.yaw_rad) = (nx, ny, yaw);
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::{Cover, Obstacle};

    #[test]
    fn accelerates_within_limits_and_terrain_caps_speed() {
        let world = World::new(100, 100, Cover::Grass); // grass: 0.5 s/m -> 2 m/s
        let limits = RobotLimits {
            max_linear_mps: 5.0,
            ..Default::default()
        };
        let mut r = Robot::at([10.0, 50.0, 0.0]);
        r.step(&world, (5.0, 0.0), 0.1, &limits);
        assert!((r.linear_mps - 0.15).abs() < 1e-12, "1.5 m/s^2 for 0.1 s");
        for _ in 0..50 {
            r.step(&world, (5.0, 0.0), 0.1, &limits);
        }
        assert!(
            (r.linear_mps - 2.0).abs() < 1e-12,
            "grass caps at 2 m/s: {}",
            r.linear_mps
        );
        assert!((r.traversal_cost_s - 0.5 * r.distance_m).abs() < 1e-9);
    }

    #[test]
    fn lethal_cells_stop_the_robot_and_count_a_collision() {
        let mut world = World::new(100, 100, Cover::Grass);
        world.line_obstacle((20, 40), (20, 60), Obstacle::Wall);
        let mut r = Robot::at([15.0, 50.0, 0.0]);
        let limits = RobotLimits::default();
        for _ in 0..200 {
            r.step(&world, (2.0, 0.0), 0.1, &limits);
        }
        assert!(
            r.x_m < 19.5 - limits.radius_m + 0.3,
            "stopped before the wall: {}",
            r.x_m
        );
        assert!(r.collisions > 0);
        // It can still turn away and leave.
        for _ in 0..30 {
            r.step(&world, (0.0, 1.5), 0.1, &limits);
        }
        let before = r.x_m;
        for _ in 0..20 {
            r.step(&world, (1.0, 0.0), 0.1, &limits);
        }
        assert!(r.x_m < before, "drove back the way it came");
    }

    #[test]
    fn the_disc_footprint_is_exact_at_corners_and_free_to_turn() {
        let mut world = World::new(20, 20, Cover::Grass);
        world.set_obstacle(10, 10, Obstacle::Wall); // the square [9.5, 10.5]^2
        let r = 0.4;
        // Beside a face: free until the disc reaches it.
        assert!(Robot::footprint_free(&world, 9.0, 10.0, r));
        assert!(!Robot::footprint_free(&world, 9.2, 10.0, r));
        // Diagonally off the corner (9.5, 9.5): 0.35 m away collides, 0.45 m
        // does not; points sampled on the body axes saw neither.
        let off = |d: f64| 9.5 - d / 2f64.sqrt();
        assert!(!Robot::footprint_free(&world, off(0.35), off(0.35), r));
        assert!(Robot::footprint_free(&world, off(0.45), off(0.45), r));
        // A robot pressed against the face turns in place whatever it faces.
        let mut robot = Robot::at([9.05, 10.0, 0.0]);
        let limits = RobotLimits::default();
        for _ in 0..40 {
            robot.step(&world, (1.0, 1.5), 0.1, &limits);
        }
        assert!(robot.yaw_rad > 1.0, "turned: {}", robot.yaw_rad);
        assert!(Robot::footprint_free(&world, robot.x_m, robot.y_m, r));
    }

    #[test]
    fn a_glancing_contact_slides_past_the_corner_and_a_head_on_one_stops() {
        let mut world = World::new(30, 30, Cover::Grass);
        world.set_obstacle(15, 15, Obstacle::Wall); // the square [14.5, 15.5]^2
        let limits = RobotLimits::default();
        // Driving east 0.2 m left of the disc's clear line: it meets the
        // corner (14.5, 15.5) off-centre and slides over it.
        let mut glancing = Robot::at([10.0, 15.7, 0.0]);
        for _ in 0..100 {
            glancing.step(&world, (1.0, 0.0), 0.1, &limits);
        }
        assert!(glancing.collisions > 0, "it touched the corner");
        assert!(glancing.x_m > 16.0, "and went past: {:?}", glancing.pose());
        assert!(Robot::footprint_free(
            &world,
            glancing.x_m,
            glancing.y_m,
            0.4
        ));
        // Straight at the face: it stops before it.
        let mut head_on = Robot::at([10.0, 15.0, 0.0]);
        for _ in 0..100 {
            head_on.step(&world, (1.0, 0.0), 0.1, &limits);
        }
        assert!(head_on.x_m < 14.1 + 1e-9, "{:?}", head_on.pose());
        assert!(head_on.collisions > 10);
    }
}
