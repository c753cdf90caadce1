//! One drive through a scenario: the robot, its metrics and its track, as
//! the demo and the navigation benchmark score them: reached (within the
//! goal radius), time, distance, traversal cost, collisions and
//! interventions (stuck, in the spirit of HIP's "trapped" rule: less than
//! `stuck_min_progress_m` (1 m) from where it was 10 s earlier, or less
//! than a quarter of what the terrain it stood on let it drive in those
//! 10 s when that is less; a detour away from the goal is not being stuck;
//! counted once per 10 s window). The terrain's share matters in bushes
//! (10 s/m, so at most 0.1 m/s): a robot crossing them at their speed limit
//! covers 1 m in 10 s, and a fixed 1 m rule carried it back mid-crossing.
//!
//! An intervention is also acted on, as the papers' operators did (POVNav and
//! HIP count interventions and let the trial go on): the robot is carried
//! `intervention_backup_m` back along its own track, stopped, facing the way
//! it drove there, so a method that wedged itself against a tree gets another
//! go instead of spending the rest of the trial pinned. Set the distance to
//! 0 to only count.

use crate::render::PALETTE;

/// Version of the stuck and intervention rule, hashed into every benchmark
/// result: change it whenever [`EpisodeConfig`]'s defaults or
/// [`Episode::step`]'s judgement of being stuck change.
/// 1: less than 1 m in 10 s, carried 3 m back.
/// 2: less than 1 m, or less than a quarter of what the terrain allowed
/// when that is less, in 10 s; carried 3 m back (commit 60a2c7e).
pub const INTERVENTION_RULE_VERSION: u32 = 2;
use crate::robot::{Robot, RobotLimits};
use crate::scenario::Scenario;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EpisodeConfig {
    pub goal_radius_m: f64,
    pub max_time_s: f64,
    pub stuck_window_s: f64,
    /// Progress in a window below this is being stuck...
    pub stuck_min_progress_m: f64,
    /// ...or below this fraction of the distance the terrain under the
    /// robot allowed in the window (its speed limit, 1 / cost, times the
    /// time), when that is less.
    pub stuck_progress_fraction: f64,
    /// How far back along the track an intervention carries the robot (m).
    pub intervention_backup_m: f64,
    pub limits: RobotLimits,
}

impl Default for EpisodeConfig {
    fn default() -> Self {
        Self {
            goal_radius_m: 2.0,
            max_time_s: 300.0,
            stuck_window_s: 10.0,
            stuck_min_progress_m: 1.0,
            stuck_progress_fraction: 0.25,
            intervention_backup_m: 3.0,
            limits: RobotLimits::default(),
        }
    }
}

/// How a drive ended (or that it has not).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Outcome {
    Driving,
    Reached,
    TimedOut,
}

#[derive(Debug, Clone, PartialEq)]
pub struct Summary {
    pub scenario: String,
    pub outcome: Outcome,
    pub time_s: f64,
    pub distance_m: f64,
    pub traversal_cost_s: f64,
    pub collisions: u32,
    pub interventions: u32,
    pub final_goal_distance_m: f64,
}

pub struct Episode {
    pub scenario: Scenario,
    pub config: EpisodeConfig,
    pub robot: Robot,
    pub time_s: f64,
    pub track: Vec<[f64; 2]>,
    pub interventions: u32,
    /// Where the robot stood at each intervention, before it was carried.
    pub intervention_points: Vec<[f64; 2]>,
    /// Time and position at the start of the current stuck window.
    window_start: (f64, [f64; 2]),
    /// How far the terrain's speed limits let the robot drive since then.
    window_reach_m: f64,
    outcome: Outcome,
}

impl Episode {
    pub fn new(scenario: Scenario, config: EpisodeConfig) -> Self {
        let robot = Robot::at(scenario.start);
        Self {
            track: vec![[robot.x_m, robot.y_m]],
            scenario,
            config,
            robot,
            time_s: 0.0,
            interventions: 0,
            intervention_points: Vec::new(),
            window_start: (0.0, [robot.x_m, robot.y_m]),
            window_reach_m: 0.0,
            outcome: Outcome::Driving,
        }
    }

    pub fn outcome(&self) -> Outcome {
        self.outcome
    }

    pub fn goal_distance_m(&self) -> f64 {
        goal_distance(&self.robot, &self.scenario)
    }

    /// Drives `dt_s` under the command; returns the outcome so far.
    pub fn step(&mut self, command: (f64, f64), dt_s: f64) -> Outcome {
        if self.outcome != Outcome::Driving {
            return self.outcome;
        }
        let world = &self.scenario.world;
        let (cx, cy) = world.cell_of(self.robot.x_m, self.robot.y_m);
        let terrain_mps =
            (1.0 / world.cost_s_per_m(cx, cy) as f64).min(self.config.limits.max_linear_mps);
        self.window_reach_m += terrain_mps * dt_s;
        self.robot.step(world, command, dt_s, &self.config.limits);
        self.time_s += dt_s;
        let last = self.track.last().copied().unwrap_or([0.0; 2]);
        if (last[0] - self.robot.x_m).hypot(last[1] - self.robot.y_m) >= 0.25 {
            self.track.push([self.robot.x_m, self.robot.y_m]);
        }
        let d = self.goal_distance_m();
        let here = [self.robot.x_m, self.robot.y_m];
        if self.time_s - self.window_start.0 >= self.config.stuck_window_s {
            let moved = (here[0] - self.window_start.1[0]).hypot(here[1] - self.window_start.1[1]);
            let needed = self
                .config
                .stuck_min_progress_m
                .min(self.config.stuck_progress_fraction * self.window_reach_m);
            if moved < needed {
                self.interventions += 1;
                self.intervention_points.push(here);
                self.carry_back();
            }
            self.window_start = (self.time_s, [self.robot.x_m, self.robot.y_m]);
            self.window_reach_m = 0.0;
        }
        self.outcome = if d <= self.config.goal_radius_m {
            Outcome::Reached
        } else if self.time_s >= self.config.max_time_s {
            Outcome::TimedOut
        } else {
            Outcome::Driving
        };
        self.outcome
    }

    /// The operator's intervention: back along the track by
    /// `intervention_backup_m` (to the start at most), stopped, facing along
    /// the track. The collision count and distance are kept; the carried
    /// stretch is not driven, so it adds neither distance nor cost.
    fn carry_back(&mut self) {
        let back = self.config.intervention_backup_m;
        if back <= 0.0 || self.track.len() < 2 {
            return;
        }
        let here = [self.robot.x_m, self.robot.y_m];
        let mut i = self.track.len() - 1;
        while i > 0 {
            let p = self.track[i];
            if (p[0] - here[0]).hypot(p[1] - here[1]) >= back {
                break;
            }
            i -= 1;
        }
        let to = self.track[i];
        let next = self.track[(i + 1).min(self.track.len() - 1)];
        let yaw = if next != to {
            (next[1] - to[1]).atan2(next[0] - to[0])
        } else {
            self.robot.yaw_rad
        };
        let (collisions, distance_m, cost) = (
            self.robot.collisions,
            self.robot.distance_m,
            self.robot.traversal_cost_s,
        );
        self.robot = Robot::at([to[0], to[1], yaw]);
        self.robot.collisions = collisions;
        self.robot.distance_m = distance_m;
        self.robot.traversal_cost_s = cost;
        self.track.push(to);
    }

    pub fn summary(&self) -> Summary {
        Summary {
            scenario: self.scenario.name.clone(),
            outcome: self.outcome,
            time_s: self.time_s,
            distance_m: self.robot.distance_m,
            traversal_cost_s: self.robot.traversal_cost_s,
            collisions: self.robot.collisions,
            interventions: self.interventions,
            final_goal_distance_m: self.goal_distance_m(),
        }
    }

    /// The map (north up) with the driven track (white), the start (blue) and
    /// the goal (red): packed RGB8, `world.width` x `world.height`.
    pub fn map_rgb(&self) -> (usize, usize, Vec<u8>) {
        let w = &self.scenario.world;
        let (mw, mh) = (w.width, w.height);
        let mut rgb = vec![0u8; mw * mh * 3];
        let mut put = |x: i64, y: i64, c: [u8; 3]| {
            if w.contains(x, y) {
                let row = mh - 1 - y as usize;
                rgb[(row * mw + x as usize) * 3..][..3].copy_from_slice(&c);
            }
        };
        for y in 0..mh as i64 {
            for x in 0..mw as i64 {
                put(x, y, PALETTE[w.look(x, y).top_class as usize]);
            }
        }
        for p in &self.track {
            let (x, y) = w.cell_of(p[0], p[1]);
            put(x, y, [255, 255, 255]);
        }
        for (p, c) in [
            (
                [self.scenario.start[0], self.scenario.start[1]],
                [40, 80, 255],
            ),
            (self.scenario.goal, [255, 30, 30]),
        ] {
            let (cx, cy) = w.cell_of(p[0], p[1]);
            for dy in -1..=1 {
                for dx in -1..=1 {
                    put(cx + dx, cy + dy, c);
                }
            }
        }
        (mw, mh, rgb)
    }
}

/// The robot's pose after every step, as CSV (`t_s,x_m,y_m,yaw_rad`, each
/// float written so it reads back bit for bit): the trace two runs are
/// compared by. Written as the drive goes, so a killed run keeps its trace.
pub struct PoseLog {
    out: std::io::BufWriter<std::fs::File>,
}

impl PoseLog {
    pub fn create(path: &std::path::Path) -> std::io::Result<Self> {
        use std::io::Write;
        let mut out = std::io::BufWriter::new(std::fs::File::create(path)?);
        writeln!(out, "t_s,x_m,y_m,yaw_rad")?;
        Ok(Self { out })
    }

    pub fn record(&mut self, e: &Episode) -> std::io::Result<()> {
        use std::io::Write;
        let r = &e.robot;
        writeln!(self.out, "{},{},{},{}", e.time_s, r.x_m, r.y_m, r.yaw_rad)
    }

    pub fn flush(&mut self) -> std::io::Result<()> {
        use std::io::Write;
        self.out.flush()
    }
}

fn goal_distance(r: &Robot, s: &Scenario) -> f64 {
    (s.goal[0] - r.x_m).hypot(s.goal[1] - r.y_m)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenario::scenario;

    #[test]
    fn the_same_seed_and_commands_drive_the_same_track() {
        let drive = || {
            let s = scenario("obstacle-field-3", 9).unwrap();
            let mut e = Episode::new(
                s,
                EpisodeConfig {
                    max_time_s: 30.0,
                    ..Default::default()
                },
            );
            let mut k = 0u32;
            while e.step((1.5, 0.6 * ((k as f64) * 0.05).sin()), 0.1) == Outcome::Driving {
                k += 1;
            }
            (e.track.clone(), e.summary())
        };
        let (a, b) = (drive(), drive());
        assert_eq!(a.0, b.0);
        assert_eq!(a.1, b.1);
        assert!(a.0.len() > 20);
    }

    #[test]
    fn a_straight_drive_reaches_an_open_goal_and_a_blocked_one_counts_interventions() {
        // Straight into bug-trap's wall (34 m ahead, reached after ~18 s):
        // the 10 s window from 20 s shows no progress, so at 30 s the
        // operator carries the robot 3 m back; it drives those 3 m again
        // (the window from 30 s has progress) and is pinned once more.
        let s = scenario("bug-trap", 1).unwrap();
        let cfg = EpisodeConfig {
            max_time_s: 45.0,
            ..Default::default()
        };
        let mut e = Episode::new(s, cfg);
        while e.step((2.0, 0.0), 0.1) == Outcome::Driving {}
        let sum = e.summary();
        assert_eq!(sum.outcome, Outcome::TimedOut);
        assert!(sum.collisions > 0 && sum.interventions == 1, "{sum:?}");

        assert!(sum.distance_m > 36.0 && sum.distance_m < 40.0, "{sum:?}");
        let wall_x = e.track.iter().map(|p| p[0]).fold(0.0, f64::max);
        assert_eq!(e.intervention_points.len(), 1);
        assert!(
            (e.intervention_points[0][0] - wall_x).abs() < 0.3,
            "the intervention is marked where the robot was pinned: {:?} (wall at x = {wall_x})",
            e.intervention_points
        );
        let at_wall = e.track.iter().position(|p| p[0] == wall_x).unwrap();
        assert!(
            e.track[at_wall..]
                .iter()
                .any(|p| (wall_x - p[0] - 3.0).abs() < 0.3),
            "after the wall at x = {wall_x}, carried 3 m back"
        );

        // An open field: straight to the goal 60 m away at up to 2 m/s.
        let mut open = scenario("bug-trap", 1).unwrap();
        open.world = crate::world::World::new(120, 100, crate::world::Cover::Grass);
        let mut e = Episode::new(open, EpisodeConfig::default());
        while e.step((2.0, 0.0), 0.1) == Outcome::Driving {}
        let sum = e.summary();
        assert_eq!(
            (sum.outcome, sum.collisions, sum.interventions),
            (Outcome::Reached, 0, 0)
        );
        assert!((sum.traversal_cost_s - 0.5 * sum.distance_m).abs() < 1e-6);
        let (w, h, rgb) = e.map_rgb();
        assert_eq!(rgb.len(), w * h * 3);
        assert!(
            rgb.chunks(3).filter(|p| p == &[255, 255, 255]).count() > 50,
            "the track is drawn"
        );
    }

    #[test]
    fn crossing_bushes_at_their_speed_limit_is_not_being_stuck_but_pinned_in_them_is() {
        // A field of bushes (10 s/m: at most 0.1 m/s) with the goal far ahead.
        let mut bushes = scenario("bug-trap", 1).unwrap();
        bushes.world = crate::world::World::new(120, 100, crate::world::Cover::Bushes);
        // A little under their limit, as a controller that slows in them does.
        let drive = |config: EpisodeConfig| {
            let mut e = Episode::new(bushes.clone(), config);
            while e.step((0.09, 0.0), 0.1) == Outcome::Driving {}
            e.summary()
        };
        let cfg = EpisodeConfig {
            max_time_s: 45.0,
            ..Default::default()
        };
        let crossing = drive(cfg);
        assert_eq!(crossing.interventions, 0, "{crossing:?}");
        assert!(crossing.distance_m > 3.9, "{crossing:?}");
        // The fixed 1 m rule (no terrain share) carries it back mid-crossing.
        let fixed = drive(EpisodeConfig {
            stuck_progress_fraction: f64::INFINITY,
            ..cfg
        });
        assert!(fixed.interventions >= 3, "{fixed:?}");

        // Pinned: the same bushes with a wall 1 m ahead of the start.
        let mut pinned = bushes.clone();
        let (sx, sy) = pinned.world.cell_of(pinned.start[0] + 1.5, pinned.start[1]);
        for dy in -20..=20 {
            pinned
                .world
                .set_obstacle(sx, sy + dy, crate::world::Obstacle::Wall);
        }
        // Against it within 10 s, carried 3 m back, back at it 30 s later.
        let mut e = Episode::new(pinned, cfg);
        while e.step((2.0, 0.0), 0.1) == Outcome::Driving {}
        assert_eq!(e.summary().interventions, 2, "{:?}", e.summary());
    }
}
