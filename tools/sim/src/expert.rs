//! The expert driver: a person who knows the whole map, as the papers'
//! training data came from (LRN's and HIP's teleoperated runs, FITAM's
//! oracle). It follows the cheapest A* path over the true world (cells next
//! to an obstacle made dear) with the graph's carrot law and rate
//! limits, and replans from wherever it is after an intervention moved it.
//! `farsight-sim run --drive expert` uses it to make training recordings
//! without the stage graph.

use crate::world::World;
use farsight_subgoal_selection::dstar_lite::{astar, CostGrid};
use farsight_velocity_servoing::{carrot_command, carrot_point, RateLimiter, ServoConfig};

pub struct Expert {
    grid: CostGrid,
    goal: (usize, usize),
    /// World metres, start to goal.
    path: Vec<[f64; 2]>,
    /// Index of the path point nearest the robot.
    progress: usize,
    servo: ServoConfig,
    limiter: RateLimiter,
}

impl Expert {
    /// `None` when no path reaches the goal.
    pub fn new(
        world: &World,
        start: [f64; 2],
        goal: [f64; 2],
        max_linear_mps: f64,
    ) -> Option<Self> {
        let mut grid = CostGrid::new(world.width, world.height, world.resolution_m, 1.0);
        for y in 0..world.height as i64 {
            for x in 0..world.width as i64 {
                // Beside an obstacle is allowed but dear: forests with 1 m
                // gaps stay passable, and open ground is preferred.
                let near_lethal =
                    (-1..=1).any(|dy| (-1..=1).any(|dx| world.lethal(x + dx, y + dy)));
                let c = world.cost_s_per_m(x, y);
                let c = if near_lethal && c.is_finite() {
                    c.max(4.0)
                } else {
                    c
                };
                grid.set(x as usize, y as usize, c);
            }
        }
        let g = world.cell_of(goal[0], goal[1]);
        let mut e = Self {
            grid,
            goal: (g.0.max(0) as usize, g.1.max(0) as usize),
            path: Vec::new(),
            progress: 0,
            servo: ServoConfig {
                max_linear_mps,
                goal_radius_m: 0.0,
                ..Default::default()
            },
            limiter: RateLimiter::default(),
        };
        e.replan(world, start).then_some(e)
    }

    fn replan(&mut self, world: &World, from: [f64; 2]) -> bool {
        let (x, y) = world.cell_of(from[0], from[1]);
        let start = (x.max(0) as usize, y.max(0) as usize);
        match astar(&self.grid, start, self.goal, 0.2) {
            Some((cells, _)) => {
                let r = world.resolution_m;
                self.path = cells
                    .iter()
                    .map(|&(cx, cy)| [cx as f64 * r, cy as f64 * r])
                    .collect();
                self.progress = 0;
                true
            }
            None => false,
        }
    }

    /// The command for a robot at `pose` (x, y, yaw) after `dt_s`.
    pub fn command(&mut self, world: &World, pose: [f64; 3], dt_s: f64) -> (f64, f64) {
        let d = |p: &[f64; 2]| (p[0] - pose[0]).hypot(p[1] - pose[1]);
        let window = self.path.len().min(self.progress + 40);
        if let Some((i, _)) = self.path[self.progress..window]
            .iter()
            .enumerate()
            .min_by(|a, b| d(a.1).total_cmp(&d(b.1)))
        {
            self.progress += i;
        }
        // Carried off the path (an intervention): plan again from here.
        let off = self.path.get(self.progress).is_none_or(|p| d(p) > 3.0);
        if off && !self.replan(world, [pose[0], pose[1]]) {
            return self.limiter.stop();
        }
        let (s, c) = pose[2].sin_cos();
        let ahead: Vec<[f64; 2]> = self.path[self.progress..]
            .iter()
            .take(60)
            .map(|p| {
                let (dx, dy) = (p[0] - pose[0], p[1] - pose[1]);
                [c * dx + s * dy, -s * dx + c * dy]
            })
            .collect();
        let target = carrot_point(&ahead, self.servo.lookahead_m)
            .map_or((0.0, 0.0), |p| carrot_command(p, &self.servo));
        self.limiter.limit(target, dt_s, &self.servo)
    }
}
