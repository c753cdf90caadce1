//! HIP's data collection (section V, "Training"): the robot drives "sticky"
//! random actions (each held for several frames) through a world, is
//! respawned at random after every collision, and the sequences that ended
//! in a collision are removed. What is left are collision-free pose
//! sequences, from which HIP's trajectory library (k-means centroids of the
//! futures, [`farsight_subgoal_selection::hip`]) is built, and on which its
//! learned density trains.
//!
//! A collision is the paper's three heuristics as this simulator can judge
//! them: a contact with anything lethal (the unicycle stops or slides), a
//! "stuck" robot (stationary for over 4 s) and a "trapped" one (less than
//! 3 m in 10 s), the last two by [`crate::stall`]. The last `horizon_s`
//! before a contact, or before a stall's onset, are cut, so no recorded
//! future leads into one.

use crate::rng::SplitMix64;
use crate::robot::{Robot, RobotLimits};
use crate::stall::{Stall, StallDetector};
use crate::world::World;
use farsight_subgoal_selection::hip::{future_trajectories, kmeans, LibraryFile};

/// The drive's parameters (the paper's, where it gives them).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StickyConfig {
    /// Simulated seconds of driving, respawns included.
    pub duration_s: f64,
    /// Simulator step (the paper's simulator ran at 30 Hz).
    pub dt_s: f64,
    /// An action is held for a uniform time in this range (s).
    pub hold_s: [f64; 2],
    /// Seconds cut before each collision (the library's horizon: H = 10
    /// points at 5 Hz).
    pub horizon_s: f64,
    /// Poses are recorded this often (the paper subsamples at 5 Hz).
    pub record_every_s: f64,
    pub limits: RobotLimits,
}

impl Default for StickyConfig {
    fn default() -> Self {
        Self {
            duration_s: 1800.0,
            dt_s: 1.0 / 30.0,
            hold_s: [0.5, 2.0],
            horizon_s: 2.0,
            record_every_s: 0.2,
            limits: RobotLimits::default(),
        }
    }
}

/// One collision-free pose sequence `(t_s, x_m, y_m, yaw_rad)`.
pub type Segment = Vec<(f64, f64, f64, f64)>;

/// What the drive produced.
#[derive(Debug, Clone, PartialEq)]
pub struct StickyDrive {
    pub segments: Vec<Segment>,
    /// Collisions (each ended a sequence and respawned the robot).
    pub collisions: usize,
}

/// A random spawn where the robot's disc fits.
fn spawn(world: &World, rng: &mut SplitMix64, radius_m: f64) -> [f64; 3] {
    let (w, h) = (
        world.width as f64 * world.resolution_m,
        world.height as f64 * world.resolution_m,
    );
    loop {
        let p = [rng.range(1.0, w - 1.0), rng.range(1.0, h - 1.0)];
        if Robot::footprint_free(world, p[0], p[1], radius_m) {
            return [
                p[0],
                p[1],
                rng.range(-std::f64::consts::PI, std::f64::consts::PI),
            ];
        }
    }
}

/// Drives sticky random actions through `world` (seeded), as HIP's data
/// collection. Forward speeds are drawn in [0, max], turn rates in
/// [-max, max]: a ground robot explores ahead.
pub fn sticky_random_drive(world: &World, cfg: &StickyConfig, seed: u64) -> StickyDrive {
    let mut rng = SplitMix64::new(seed ^ 0x571C);
    let lim = &cfg.limits;
    let mut robot = Robot::at(spawn(world, &mut rng, lim.radius_m));
    let mut out = StickyDrive {
        segments: Vec::new(),
        collisions: 0,
    };
    let mut segment: Segment = Vec::new();
    let (mut t, mut next_action, mut next_record) = (0.0, 0.0, 0.0);
    let mut action = (0.0, 0.0);
    let mut stall = StallDetector::default();
    while t < cfg.duration_s {
        if t >= next_action {
            action = (
                rng.range(0.0, lim.max_linear_mps),
                rng.range(-lim.max_angular_radps, lim.max_angular_radps),
            );
            next_action = t + rng.range(cfg.hold_s[0], cfg.hold_s[1]);
        }
        let before = robot.collisions;
        robot.step(world, action, cfg.dt_s, lim);
        t += cfg.dt_s;
        let stalled = stall.observe(t, [robot.x_m, robot.y_m]);
        if robot.collisions > before || stalled.is_some() {
            out.collisions += 1;
            // A stall began at its onset, not when the window showed it:
            // the standing or circling before it is cut with the horizon.
            let since = stalled.map_or(t, Stall::onset_s);
            let keep_until = since - cfg.horizon_s;
            segment.retain(|p| p.0 <= keep_until);
            if !segment.is_empty() {
                out.segments.push(std::mem::take(&mut segment));
            }
            robot = Robot::at(spawn(world, &mut rng, lim.radius_m));
            stall.reset();
            next_action = t;
            next_record = t;
            continue;
        }
        if t >= next_record {
            segment.push((t, robot.x_m, robot.y_m, robot.yaw_rad));
            next_record += cfg.record_every_s;
        }
    }
    if !segment.is_empty() {
        out.segments.push(segment);
    }
    out
}

/// HIP's trajectory library from a sticky drive: every recorded future of
/// `horizon` points `step_s` apart, within one collision-free sequence,
/// clustered into `k` centroids (section III; the paper: K = 200, H = 10,
/// 5 Hz).
pub fn trajectory_library(
    drive: &StickyDrive,
    k: usize,
    horizon: usize,
    step_s: f64,
    seed: u64,
) -> LibraryFile {
    let futures: Vec<_> = drive
        .segments
        .iter()
        .flat_map(|s| future_trajectories(s, horizon, step_s))
        .collect();
    LibraryFile {
        step_s,
        trajectories: kmeans(&futures, k, 50, seed)
            .into_iter()
            .map(|t| t.0)
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::{Cover, Obstacle};

    #[test]
    fn sequences_end_before_each_collision_and_never_cross_an_obstacle() {
        let mut world = World::new(30, 30, Cover::Grass);
        for k in 0..30 {
            world.set_obstacle(k, 15, Obstacle::Shrub);
            world.set_obstacle(15, k, Obstacle::Stone);
        }
        let cfg = StickyConfig {
            duration_s: 300.0,
            ..Default::default()
        };
        let drive = sticky_random_drive(&world, &cfg, 7);
        assert!(
            drive.collisions > 5,
            "small quadrants: {}",
            drive.collisions
        );
        assert!(!drive.segments.is_empty());
        for s in &drive.segments {
            // 5 Hz, time order, and never on a lethal cell.
            for w in s.windows(2) {
                assert!((w[1].0 - w[0].0 - 0.2).abs() < 0.05, "{:?}", w);
            }
            for &(_, x, y, _) in s {
                assert!(Robot::footprint_free(&world, x, y, cfg.limits.radius_m));
            }
            // Cut back to before each stall's onset: what is kept shows none.
            let mut stall = crate::stall::StallDetector::default();
            for &(t, x, y, _) in s {
                assert_eq!(stall.observe(t, [x, y]), None, "at {t} s");
            }
        }
        // The same seed drives the same sequences.
        assert_eq!(sticky_random_drive(&world, &cfg, 7), drive);
        let lib = trajectory_library(&drive, 20, 10, 0.2, 1);
        assert_eq!(lib.trajectories.len(), 20);
        assert!(lib.trajectories.iter().all(|t| t.len() == 10));
        // Forward actions: the centroids go ahead on average, and at most
        // the robot's top speed times the horizon.
        let mean_x: f64 = lib.trajectories.iter().map(|t| t[9][0]).sum::<f64>() / 20.0;
        assert!(mean_x > 0.5, "{mean_x}");
        for t in &lib.trajectories {
            assert!(t[9][0].hypot(t[9][1]) <= cfg.limits.max_linear_mps * 2.0 + 0.1);
        }
    }

    #[test]
    fn a_stall_cuts_back_to_its_onset_not_to_when_it_was_noticed() {
        // Open grass, but a robot too slow to count as moving: at 1 cm/s
        // it is stuck from its spawn, at 0.2 m/s trapped from it. Cutting
        // the horizon before the stall's onset keeps nothing; cutting it
        // before the moment the window noticed would keep 2 s of standing
        // and 8 s of crawling.
        let world = World::new(40, 40, Cover::Grass);
        for max_linear_mps in [0.01, 0.2] {
            let cfg = StickyConfig {
                duration_s: 120.0,
                limits: RobotLimits {
                    max_linear_mps,
                    ..Default::default()
                },
                ..Default::default()
            };
            let drive = sticky_random_drive(&world, &cfg, 3);
            assert!(
                drive.collisions >= 8,
                "{max_linear_mps}: {}",
                drive.collisions
            );
            let kept: usize = drive.segments.iter().map(Vec::len).sum();
            // Only the drive's unfinished tail can remain.
            assert!(kept <= 50, "{max_linear_mps}: {kept} poses kept");
        }
    }
}
