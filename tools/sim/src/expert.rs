//! The expert driver: a person who knows the whole map, as the papers'
//! training data came from (LRN's and HIP's teleoperated runs, FITAM's
//! oracle). It follows the cheapest A* path over the true world (cells next
//! to an obstacle made dear) with the graph's carrot law and rate
//! limits, and replans from wherever it is after an intervention moved it.
//! `farsight-sim run --drive expert` uses it to make training recordings
//! without the stage graph.
//!
//! [`expert_plan`] is the same path without driving it, and its time: the
//! yardstick of the navigation benchmark's time limit (issue 20, item 1:
//! a trial may take [`TimeLimitRule::factor`] times the expert's time on
//! the same world, start and goal). LRN (section IV) and HIP (section V)
//! judge a method's time against a privileged driver's the same way.

use crate::world::World;
use farsight_subgoal_selection::dstar_lite::{astar, cost_to_go, CostGrid};
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

/// The expert's planning grid: the world's costs, cells next to an
/// obstacle made dear.
fn expert_grid(world: &World) -> CostGrid {
    let mut grid = CostGrid::new(world.width, world.height, world.resolution_m, 1.0);
    for y in 0..world.height as i64 {
        for x in 0..world.width as i64 {
            // Beside an obstacle is allowed but dear: forests with 1 m
            // gaps stay passable, and open ground is preferred.
            let near_lethal = (-1..=1).any(|dy| (-1..=1).any(|dx| world.lethal(x + dx, y + dy)));
            let c = world.cost_s_per_m(x, y);
            let c = if near_lethal && c.is_finite() {
                c.max(4.0)
            } else {
                c
            };
            grid.set(x as usize, y as usize, c);
        }
    }
    grid
}

/// The grid cell of a world point, if it is on the world.
fn grid_cell(world: &World, p: [f64; 2]) -> Option<(usize, usize)> {
    let (x, y) = world.cell_of(p[0], p[1]);
    world.contains(x, y).then_some((x as usize, y as usize))
}

/// Version of the time-limit rule ([`TimeLimitRule`], [`expert_plan`]'s
/// time), hashed into every benchmark result: change it whenever either
/// changes what a trial is allowed.
/// 1: the limit is `factor` x the expert's time (A* path, each cell at the
/// speed the robot may drive there), capped by an absolute limit if given.
/// 2: the A* path may not cut a blocked cell's corner diagonally (issue 20),
/// which changes the expert's path and time on forested worlds.
pub const TIME_LIMIT_RULE_VERSION: u32 = 2;

/// The expert's path from start to goal and how long driving it takes.
#[derive(Debug, Clone, PartialEq)]
pub struct ExpertPlan {
    /// Cell centres (world metres), start to goal.
    pub path: Vec<[f64; 2]>,
    /// [`traversal_time_s`] of the path.
    pub time_s: f64,
}

/// The expert's path (the A* path [`Expert`] drives) and its time, without
/// driving it; `None` when the start or goal is off the world or no path
/// joins them.
pub fn expert_plan(
    world: &World,
    start: [f64; 2],
    goal: [f64; 2],
    max_linear_mps: f64,
) -> Option<ExpertPlan> {
    let (s, g) = (grid_cell(world, start)?, grid_cell(world, goal)?);
    let (cells, _) = astar(&expert_grid(world), s, g, 0.2)?;
    let r = world.resolution_m;
    let path: Vec<[f64; 2]> = cells
        .iter()
        .map(|&(x, y)| [x as f64 * r, y as f64 * r])
        .collect();
    let time_s = traversal_time_s(world, &path, max_linear_mps);
    Some(ExpertPlan { path, time_s })
}

/// The expert's cost to reach `goal` from every cell of `world` (row-major,
/// seconds over the expert's grid, infinite where no path leads): what the
/// operator of [`crate::episode::InterventionRule::Operator`] knows about
/// the map. Empty when the goal is off the world.
pub fn expert_cost_to_go(world: &World, goal: [f64; 2]) -> Vec<f64> {
    match grid_cell(world, goal) {
        Some(g) => cost_to_go(&expert_grid(world), g),
        None => Vec::new(),
    }
}

/// The length (m) of the shortest path from `start` to `goal` for a disc
/// of `radius_m`, every metre alike (terrain costs ignored): A* over cell
/// centres where the disc fits (8-connected, never diagonally past a
/// blocked cell's corner), then pulled straight wherever the disc fits
/// along the chord, so it is not longer than an any-angle path by the
/// grid's 45-degree bends. POVNav's path-length yardstick: "the deviation
/// from the shortest obstacle-free path". Measured from the exact start to
/// where the path first comes within `goal_radius_m` of the goal, as a
/// drive ends. `None` when no such path exists.
pub fn shortest_path_m(
    world: &World,
    start: [f64; 2],
    goal: [f64; 2],
    radius_m: f64,
    goal_radius_m: f64,
) -> Option<f64> {
    let (s, g) = (grid_cell(world, start)?, grid_cell(world, goal)?);
    let r = world.resolution_m;
    let mut grid = CostGrid::new(world.width, world.height, r, 1.0);
    for y in 0..world.height {
        for x in 0..world.width {
            let fits =
                crate::robot::Robot::footprint_free(world, x as f64 * r, y as f64 * r, radius_m);
            if !fits && (x, y) != s && (x, y) != g {
                grid.set(x, y, f32::INFINITY);
            }
        }
    }
    let (cells, _) = astar(&grid, s, g, 1.0)?;
    // The grid's path bends at 45 degrees; a straight line need not. Pull
    // the string: from each kept point, go to the farthest later point in
    // clear sight (the disc fits every 0.1 m along the segment).
    // From the exact start to the exact goal, through the cells between.
    let mut pts = vec![start];
    pts.extend(
        cells[1..cells.len().saturating_sub(1)]
            .iter()
            .map(|&(x, y)| [x as f64 * r, y as f64 * r]),
    );
    pts.push(goal);
    let clear = |a: [f64; 2], b: [f64; 2]| {
        let n = ((b[0] - a[0]).hypot(b[1] - a[1]) / 0.1).ceil().max(1.0) as usize;
        (0..=n).all(|k| {
            let t = k as f64 / n as f64;
            crate::robot::Robot::footprint_free(
                world,
                a[0] + t * (b[0] - a[0]),
                a[1] + t * (b[1] - a[1]),
                radius_m,
            )
        })
    };
    let mut pulled = vec![pts[0]];
    let mut i = 0;
    while i + 1 < pts.len() {
        let mut j = i + 1;
        while j + 1 < pts.len() && clear(pts[i], pts[j + 1]) {
            j += 1;
        }
        pulled.push(pts[j]);
        i = j;
    }
    // A drive ends on reaching the goal radius: measure to where the path
    // first comes that close.
    let d_goal = |p: [f64; 2]| (p[0] - goal[0]).hypot(p[1] - goal[1]);
    let mut length_m = 0.0;
    for w in pulled.windows(2) {
        let (a, b) = (w[0], w[1]);
        let seg = (b[0] - a[0]).hypot(b[1] - a[1]);
        if d_goal(b) <= goal_radius_m {
            // The segment's first point within the radius (a is outside).
            let (dx, dy) = (
                (b[0] - a[0]) / seg.max(1e-12),
                (b[1] - a[1]) / seg.max(1e-12),
            );
            let (fx, fy) = (a[0] - goal[0], a[1] - goal[1]);
            let bq = fx * dx + fy * dy;
            let c = fx * fx + fy * fy - goal_radius_m * goal_radius_m;
            let t = (-bq - (bq * bq - c).max(0.0).sqrt()).clamp(0.0, seg);
            return Some(length_m + t);
        }
        length_m += seg;
    }
    Some(length_m)
}

/// Time to drive along `path` (cell centres) at the fastest speed the
/// simulated robot may drive, as it enforces it (`crate::robot`): in a cell
/// costing c s/m at most min(1 / c, `max_linear_mps`). Each step between two
/// cell centres is half in each cell, so a step of length L from a to b
/// takes L/2 x max(c_a, 1/v) + L/2 x max(c_b, 1/v). Acceleration and
/// turning are not counted: this is a lower bound on any drive of the path
/// (the expert's own drive takes a little longer), the true world's costs,
/// not the expert's dearer margins beside obstacles. A lethal cell on the
/// path makes it infinite.
pub fn traversal_time_s(world: &World, path: &[[f64; 2]], max_linear_mps: f64) -> f64 {
    let floor = 1.0 / max_linear_mps;
    let s_per_m = |p: &[f64; 2]| {
        let (x, y) = world.cell_of(p[0], p[1]);
        (world.cost_s_per_m(x, y) as f64).max(floor)
    };
    path.windows(2)
        .map(|w| {
            let l = (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]);
            0.5 * l * (s_per_m(&w[0]) + s_per_m(&w[1]))
        })
        .sum()
}

/// How long a benchmark trial may take: `factor` x the expert's time on the
/// same world, start and goal ([`expert_plan`]), at most `cap_s`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TimeLimitRule {
    pub factor: f64,
    /// An absolute limit (s): the limit when there is no expert time.
    pub cap_s: Option<f64>,
}

impl TimeLimitRule {
    /// The limit for a trial whose expert took `expert_time_s` (`None`: no
    /// expert path). An error names the bad value: a factor or cap that is
    /// not a positive number, or no expert time and no cap.
    pub fn limit_s(&self, expert_time_s: Option<f64>) -> Result<f64, String> {
        if !(self.factor.is_finite() && self.factor > 0.0) {
            return Err(format!(
                "time limit factor {}: expected a positive number",
                self.factor
            ));
        }
        if let Some(cap) = self.cap_s.filter(|c| !(c.is_finite() && *c > 0.0)) {
            return Err(format!(
                "absolute time limit {cap} s: expected a positive number of seconds"
            ));
        }
        match (expert_time_s.filter(|t| t.is_finite()), self.cap_s) {
            (Some(t), cap) => Ok((self.factor * t).min(cap.unwrap_or(f64::INFINITY))),
            (None, Some(cap)) => Ok(cap),
            (None, None) => {
                Err("no expert path to the goal and no absolute time limit to fall back on".into())
            }
        }
    }
}

/// The expert driven through a whole episode under `config` (10 Hz, its
/// A* path on the true map, replanned as it drives): HIP section V's
/// privileged planner, whose success normalises the methods' (the paper's
/// `move_base` with a global obstacle map). `None` when no path reaches
/// the goal.
pub fn expert_drive(
    scenario: &crate::scenario::Scenario,
    config: crate::episode::EpisodeConfig,
) -> Option<crate::episode::Summary> {
    use crate::episode::{Episode, Outcome};
    let dt_s = 0.1;
    let start = [scenario.start[0], scenario.start[1]];
    let mut expert = Expert::new(
        &scenario.world,
        start,
        scenario.goal,
        config.limits.max_linear_mps,
    )?;
    let mut e = Episode::new(scenario.clone(), config);
    loop {
        let command = expert.command(&e.scenario.world, e.robot.pose(), dt_s);
        if e.step(command, dt_s) != Outcome::Driving {
            return Some(e.summary());
        }
    }
}

impl Expert {
    /// `None` when no path reaches the goal.
    pub fn new(
        world: &World,
        start: [f64; 2],
        goal: [f64; 2],
        max_linear_mps: f64,
    ) -> Option<Self> {
        let g = world.cell_of(goal[0], goal[1]);
        let mut e = Self {
            grid: expert_grid(world),
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_expert_drives_the_hip_spawns_to_their_goals() {
        use crate::episode::{EpisodeConfig, InterventionRule, Outcome};
        let cfg = EpisodeConfig {
            max_time_s: 120.0,
            intervention: InterventionRule::EndTrial,
            ..Default::default()
        };
        let reached = (1..=10)
            .filter(|&seed| {
                let s = crate::scenario::scenario("hip-in-distribution", seed).unwrap();
                expert_drive(&s, cfg).unwrap().outcome == Outcome::Reached
            })
            .count();
        assert!(reached >= 8, "{reached} of 10");
        // A goal sealed off has no expert.
        let mut sealed = crate::scenario::scenario("bug-trap", 1).unwrap();
        for y in 0..100 {
            sealed
                .world
                .set_obstacle(70, y, crate::world::Obstacle::Wall);
        }
        assert!(expert_drive(&sealed, cfg).is_none());
    }
    use crate::world::Cover;

    /// A road 12 x 7 m with a column of bushes across it at x = 5; start
    /// (2, 3), goal (9, 3): the straight path, 7 steps of 1 m.
    fn road_with_bushes() -> World {
        let mut w = World::new(12, 7, Cover::Road);
        w.fill_cover(5, 0, 5, 6, Cover::Bushes);
        w
    }

    #[test]
    fn the_expert_time_is_the_paths_time_at_the_speed_each_cell_allows() {
        let w = road_with_bushes();
        let plan = expert_plan(&w, [2.0, 3.0], [9.0, 3.0], 2.0).unwrap();
        let straight: Vec<[f64; 2]> = (2..=9).map(|x| [x as f64, 3.0]).collect();
        assert_eq!(plan.path, straight);
        // Road costs 0.2 s/m, but the robot drives 2 m/s at most: 0.5 s/m.
        // Five steps on road (0.5 s each), two half in bushes (10 s/m):
        // 2 x (0.5 x 0.5 + 0.5 x 10) = 10.5 s. 2.5 + 10.5 = 13.0 s.
        assert!((plan.time_s - 13.0).abs() < 1e-9, "{}", plan.time_s);
        // At 1 m/s: 5 x 1 + 2 x (0.5 + 5) = 16 s.
        let slow = expert_plan(&w, [2.0, 3.0], [9.0, 3.0], 1.0).unwrap();
        assert!((slow.time_s - 16.0).abs() < 1e-9, "{}", slow.time_s);
        // A diagonal step on open road: sqrt(2) x 0.5 s/m.
        let d = traversal_time_s(&w, &[[1.0, 1.0], [2.0, 2.0]], 2.0);
        assert!((d - std::f64::consts::SQRT_2 * 0.5).abs() < 1e-12, "{d}");
    }

    #[test]
    fn the_shortest_path_ignores_terrain_and_needs_room_for_the_disc() {
        // Bushes cost nothing extra here: straight across, 7 m; and a
        // diagonal that the grid would bend is straight: (1, 0) to (11, 5).
        let w = road_with_bushes();
        let d = shortest_path_m(&w, [2.0, 3.0], [9.0, 3.0], 0.25, 0.0).unwrap();
        assert!((d - 7.0).abs() < 1e-6, "{d}");
        // A drive ends 2 m from the goal: 5 m.
        let d = shortest_path_m(&w, [2.0, 3.0], [9.0, 3.0], 0.25, 2.0).unwrap();
        assert!((d - 5.0).abs() < 1e-6, "{d}");
        let d = shortest_path_m(&w, [1.0, 0.0], [11.0, 5.0], 0.25, 0.0).unwrap();
        assert!((d - 125f64.sqrt()).abs() < 1e-6, "{d}");
        // A wall at x = 5 with a 1-cell gap at y = 6: a 0.25 m disc passes
        // through it, nearer the straight chords through the gap's centre
        // ((2, 3) -> (5, 6) -> (9, 3): 3 sqrt 2 + 5 = 9.24 m) than the
        // grid's 10.07 m; a 0.6 m disc does not.
        let mut walled = World::new(12, 8, Cover::Grass);
        for y in 0..6 {
            walled.set_obstacle(5, y, crate::world::Obstacle::Wall);
        }
        walled.set_obstacle(5, 7, crate::world::Obstacle::Wall);
        let d = shortest_path_m(&walled, [2.0, 3.0], [9.0, 3.0], 0.25, 0.0).unwrap();
        assert!(d > 9.2 && d < 10.0, "{d}");
        assert_eq!(
            shortest_path_m(&walled, [2.0, 3.0], [9.0, 3.0], 0.6, 0.0),
            None
        );
    }

    #[test]
    fn no_path_or_an_off_world_end_has_no_expert_time() {
        let mut w = road_with_bushes();
        w.fill_cover(6, 0, 6, 6, Cover::Water);
        assert_eq!(expert_plan(&w, [2.0, 3.0], [9.0, 3.0], 2.0), None);
        let w = road_with_bushes();
        assert_eq!(expert_plan(&w, [2.0, 3.0], [90.0, 3.0], 2.0), None);
    }

    #[test]
    fn the_time_limit_is_the_factor_times_the_expert_capped_and_bad_values_are_named() {
        let rule = TimeLimitRule {
            factor: 3.0,
            cap_s: None,
        };
        assert_eq!(rule.limit_s(Some(13.0)), Ok(39.0));
        let capped = TimeLimitRule {
            cap_s: Some(30.0),
            ..rule
        };
        assert_eq!(capped.limit_s(Some(13.0)), Ok(30.0));
        assert_eq!(capped.limit_s(Some(5.0)), Ok(15.0));
        assert_eq!(capped.limit_s(None), Ok(30.0));
        let e = rule.limit_s(None).unwrap_err();
        assert!(e.contains("no expert path"), "{e}");
        for factor in [0.0, -1.0, f64::NAN] {
            let e = TimeLimitRule {
                factor,
                cap_s: None,
            }
            .limit_s(Some(1.0))
            .unwrap_err();
            assert!(e.contains(&format!("{factor}")), "{e}");
        }
        let e = TimeLimitRule {
            factor: 3.0,
            cap_s: Some(-5.0),
        }
        .limit_s(Some(1.0))
        .unwrap_err();
        assert!(e.contains("-5"), "{e}");
    }
}
