//! The simulated robot: a unicycle that follows velocity commands within
//! its acceleration limits and the terrain's speed limit (FITAM's class
//! speeds: a cell costing c s/m cannot be crossed faster than 1/c m/s), and
//! stops against lethal cells (counted as collisions) instead of passing
//! through them.

use crate::world::World;

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

    /// Advances `dt_s` under the command (v, omega). Returns false on a
    /// collision (the robot stays where it was, stopped).
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
        if !Self::footprint_free(world, nx, ny, limits.radius_m) {
            self.linear_mps = 0.0;
            self.collisions += 1;
            // Turning in place: the disc stays where it is.
            self.yaw_rad = yaw;
            return false;
        }
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
}
