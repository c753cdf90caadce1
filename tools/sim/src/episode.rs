//! One drive through a scenario: the robot, its metrics and its track, as
//! the demo and the navigation benchmark score them: reached (within the
//! goal radius), time, distance, traversal cost, collisions and
//! interventions. An intervention is acted on, as the papers' operators did
//! (they count interventions and let the trial go on), by one of two rules
//! ([`InterventionRule`]):
//!
//! - [`InterventionRule::CarryBack`] (the default; in the spirit of HIP's
//!   "trapped" rule): the robot is stuck when it is less than
//!   `stuck_min_progress_m` (1 m) from where it was 10 s earlier, or less
//!   than a quarter of what the terrain it stood on let it drive in those
//!   10 s when that is less (a detour away from the goal is not being
//!   stuck; counted once per 10 s window). The terrain's share matters in
//!   bushes (10 s/m, so at most 0.1 m/s): a robot crossing them at their
//!   speed limit covers 1 m in 10 s, and a fixed 1 m rule carried it back
//!   mid-crossing. The operator carries it `backup_m` back along its own
//!   track, stopped, facing the way it drove there, so a method that wedged
//!   itself against a tree gets another go.
//! - [`InterventionRule::Operator`] (LRN section IV): "interventions were
//!   taken when the system was not making progress ... performed by facing
//!   the robot towards the goal and seeing if it will head in a reasonable
//!   direction autonomously. If not, we would walk it towards the goal until
//!   we saw a reasonable navigation plan." Progress is judged as a person
//!   who knows the map judges it: by the expert's cost to go
//!   ([`crate::expert::expert_cost_to_go`]). When the best cost to go the
//!   robot has reached has not improved by `min_gain_s` for `patience_s`,
//!   the operator turns it in place to face the goal (one intervention);
//!   when another `patience_s` passes without progress, the operator walks
//!   it down the expert's cost to go until it is `walk_gain_s` below the
//!   best it had reached (part of the same intervention). A myopic robot in
//!   a dead end is thus carried out of it, as LRN's operators did, where
//!   the carry-back rule left it inside.
//!
//! - [`InterventionRule::EndTrial`] (HIP section V: success is "reaching
//!   the goal unharmed"): the first contact with anything lethal, or a
//!   stall by HIP's own heuristics ([`crate::stall`]: stationary for over
//!   4 s, or less than 3 m in 10 s), ends the trial as [`Outcome::Harmed`].
//!   Reaching the goal on the step a stall is noticed is reaching it.
//!
//! Carried stretches are not driven: they add neither distance, time nor
//! cost.

use crate::render::PALETTE;
use crate::stall::StallDetector;

/// Version of the stuck and intervention rule, hashed into every benchmark
/// result: change it whenever [`EpisodeConfig`]'s defaults or
/// [`Episode::step`]'s judgement of being stuck change.
/// 1: less than 1 m in 10 s, carried 3 m back.
/// 2: less than 1 m, or less than a quarter of what the terrain allowed
/// when that is less, in 10 s; carried 3 m back (commit 60a2c7e).
/// 3: the rule is chosen per run ([`InterventionRule`], recorded beside
/// this version); carry-back unchanged; LRN section IV's operator added.
/// 4: HIP's end-trial rule added; the other rules unchanged.
/// 5: the end-trial rule judges stalls by HIP's stuck and trapped
/// heuristics ([`crate::stall`]), not the carry-back window; the goal is
/// judged before a stall on the same step. The other rules unchanged.
pub const INTERVENTION_RULE_VERSION: u32 = 5;
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
    /// When an operator steps in and what they do.
    pub intervention: InterventionRule,
    pub limits: RobotLimits,
}

/// When an operator steps in and what they do (see the module comment).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum InterventionRule {
    /// Stuck in place: carried `backup_m` back along the robot's own track
    /// (0: only counted).
    CarryBack { backup_m: f64 },
    /// LRN section IV's operator: face the goal, then walk it.
    Operator(OperatorRule),
    /// HIP section V: a contact or being stuck ends the trial, harmed.
    EndTrial,
}

impl Default for InterventionRule {
    fn default() -> Self {
        Self::CarryBack { backup_m: 3.0 }
    }
}

impl InterventionRule {
    /// The rule by its name in benchmark flags and results files:
    /// `carry-back` or `operator`, with their default parameters.
    pub fn named(name: &str) -> Result<Self, String> {
        match name {
            "carry-back" => Ok(Self::default()),
            "operator" => Ok(Self::Operator(OperatorRule::default())),
            "end-trial" => Ok(Self::EndTrial),
            _ => Err(format!(
                "intervention rule {name:?}: expected \"carry-back\" (stuck in place: 3 m back along the track), \"operator\" (LRN section IV: face the goal, then walk it) or \"end-trial\" (HIP section V: a contact or being stuck fails the trial)"
            )),
        }
    }

    pub fn name(&self) -> &'static str {
        match self {
            Self::CarryBack { .. } => "carry-back",
            Self::Operator(_) => "operator",
            Self::EndTrial => "end-trial",
        }
    }
}

/// LRN section IV's operator, in the expert's seconds of cost to go.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OperatorRule {
    /// This long without a new best cost to go is not making progress (s).
    pub patience_s: f64,
    /// A new best must beat the old by this much (s of the expert's cost).
    pub min_gain_s: f64,
    /// A walk ends this far below the best cost to go reached (s)...
    pub walk_gain_s: f64,
    /// ...or this far (m) outside the goal radius: the operator hands the
    /// robot back before the goal, whose last stretch it drives itself.
    pub hand_back_m: f64,
}

impl Default for OperatorRule {
    fn default() -> Self {
        // 20 s: a robot that drives on at all gains a second of cost (2 m
        // of grass) well inside it; 10 s of walk is 20 m of grass, past the
        // place it stalled.
        Self {
            patience_s: 20.0,
            min_gain_s: 1.0,
            walk_gain_s: 10.0,
            hand_back_m: 5.0,
        }
    }
}

impl Default for EpisodeConfig {
    fn default() -> Self {
        Self {
            goal_radius_m: 2.0,
            max_time_s: 300.0,
            stuck_window_s: 10.0,
            stuck_min_progress_m: 1.0,
            stuck_progress_fraction: 0.25,
            intervention: InterventionRule::default(),
            limits: RobotLimits::default(),
        }
    }
}

impl EpisodeConfig {
    /// The defaults with a time limit, an intervention rule and the
    /// robot's disc footprint: what a simulated run and the benchmark's
    /// expert drive under.
    pub fn with_rules(max_time_s: f64, intervention: InterventionRule, radius_m: f64) -> Self {
        let defaults = Self::default();
        Self {
            max_time_s,
            intervention,
            limits: RobotLimits {
                radius_m,
                ..defaults.limits
            },
            ..defaults
        }
    }
}

/// How a drive ended (or that it has not).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Outcome {
    Driving,
    Reached,
    TimedOut,
    /// Touched something lethal or got stuck, under
    /// [`InterventionRule::EndTrial`].
    Harmed,
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
    /// The operator's state under [`InterventionRule::Operator`].
    operator: Option<Operator>,
    /// HIP's stall heuristics under [`InterventionRule::EndTrial`].
    stall: StallDetector,
    outcome: Outcome,
}

/// What LRN's operator knows and remembers during a drive.
struct Operator {
    rule: OperatorRule,
    /// The expert's cost to go per world cell (row-major).
    cost_to_go_s: Vec<f64>,
    /// The least cost to go the robot has stood at, and when it got there.
    best_s: f64,
    since_s: f64,
    /// The robot was turned to face the goal and has made no progress since.
    faced: bool,
}

impl Episode {
    pub fn new(scenario: Scenario, config: EpisodeConfig) -> Self {
        let robot = Robot::at(scenario.start);
        let mut stall = StallDetector::default();
        stall.observe(0.0, [robot.x_m, robot.y_m]);
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
            operator: None,
            stall,
            outcome: Outcome::Driving,
        }
        .with_operator()
    }

    fn with_operator(mut self) -> Self {
        if let InterventionRule::Operator(rule) = self.config.intervention {
            let cost_to_go_s =
                crate::expert::expert_cost_to_go(&self.scenario.world, self.scenario.goal);
            let mut op = Operator {
                rule,
                cost_to_go_s,
                best_s: f64::INFINITY,
                since_s: 0.0,
                faced: false,
            };
            op.best_s = op.at(&self.scenario.world, [self.robot.x_m, self.robot.y_m]);
            self.operator = Some(op);
        }
        self
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
        if self.operator.is_some() {
            self.operator_step(here);
        } else if self.config.intervention == InterventionRule::EndTrial {
            let stalled = self.stall.observe(self.time_s, here);
            if stalled.is_some() && d > self.config.goal_radius_m {
                self.interventions += 1;
                self.intervention_points.push(here);
                self.outcome = Outcome::Harmed;
                return self.outcome;
            }
        } else if self.time_s - self.window_start.0 >= self.config.stuck_window_s {
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
        let harmed =
            self.config.intervention == InterventionRule::EndTrial && self.robot.collisions > 0;
        self.outcome = if harmed {
            if self.intervention_points.is_empty() {
                self.intervention_points.push(here);
            }
            Outcome::Harmed
        } else if d <= self.config.goal_radius_m {
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
        let InterventionRule::CarryBack { backup_m: back } = self.config.intervention else {
            return;
        };
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
        self.carry_to([to[0], to[1], yaw]);
    }

    /// Puts the robot at `pose`, stopped; its counts are kept and the
    /// carried stretch is neither driven nor costed.
    fn carry_to(&mut self, pose: [f64; 3]) {
        let (collisions, distance_m, cost) = (
            self.robot.collisions,
            self.robot.distance_m,
            self.robot.traversal_cost_s,
        );
        self.robot = Robot::at(pose);
        self.robot.collisions = collisions;
        self.robot.distance_m = distance_m;
        self.robot.traversal_cost_s = cost;
        self.track.push([pose[0], pose[1]]);
    }

    /// LRN's operator, after a step that left the robot at `here`.
    fn operator_step(&mut self, here: [f64; 2]) {
        let world = &self.scenario.world;
        let Some(op) = self.operator.as_mut() else {
            return;
        };
        let now = op.at(world, here);
        // An infinite cost to go (no way to the goal from here) is never
        // progress, and inf <= inf would call it that.
        if now.is_finite() && now <= op.best_s - op.rule.min_gain_s {
            op.best_s = now;
            op.since_s = self.time_s;
            op.faced = false;
            return;
        }
        if self.time_s - op.since_s < op.rule.patience_s {
            return;
        }
        op.since_s = self.time_s;
        if !op.faced {
            op.faced = true;
            self.interventions += 1;
            self.intervention_points.push(here);
            let g = self.scenario.goal;
            let yaw = (g[1] - here[1]).atan2(g[0] - here[0]);
            self.carry_to([here[0], here[1], yaw]);
            return;
        }
        // Facing the goal did not help: walk it down the cost to go.
        op.faced = false;
        let target = op.best_s - op.rule.walk_gain_s;
        let stop = Stop {
            goal: self.scenario.goal,
            // The last stretch is the robot's own to drive: a walk that
            // ended at the goal would count as reached.
            short_of_goal_m: self.config.goal_radius_m + op.rule.hand_back_m,
            radius_m: self.config.limits.radius_m,
        };
        let walk = op.walk(world, here, target, &stop);
        if let Some(&end) = walk.last() {
            let prev = if walk.len() > 1 {
                walk[walk.len() - 2]
            } else {
                here
            };
            let yaw = (end[1] - prev[1]).atan2(end[0] - prev[0]);
            op.best_s = op.best_s.min(op.at(world, end));
            self.track.extend(&walk[..walk.len() - 1]);
            self.carry_to([end[0], end[1], yaw]);
        }
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

impl Operator {
    /// The cost to go at world point `p` (infinite off the world or where
    /// no path leads).
    fn at(&self, world: &crate::world::World, p: [f64; 2]) -> f64 {
        let (x, y) = world.cell_of(p[0], p[1]);
        if !world.contains(x, y) {
            return f64::INFINITY;
        }
        self.cost_to_go_s
            .get(y as usize * world.width + x as usize)
            .copied()
            .unwrap_or(f64::INFINITY)
    }

    /// Cell centres from `from` down the cost to go until it is at most
    /// `target_s`, the walk is `stop.short_of_goal_m` from the goal, or no
    /// step goes lower. A step goes to a neighbour where the robot's disc
    /// fits, never diagonally past a lethal cell's corner (the cost to go's
    /// own rule), so a walk never crosses an obstacle.
    fn walk(
        &self,
        world: &crate::world::World,
        from: [f64; 2],
        target_s: f64,
        stop: &Stop,
    ) -> Vec<[f64; 2]> {
        let r = world.resolution_m;
        let (mut x, mut y) = world.cell_of(from[0], from[1]);
        let mut out = Vec::new();
        let centre = |x: i64, y: i64| [x as f64 * r, y as f64 * r];
        let cost = |x: i64, y: i64| {
            let [cx, cy] = centre(x, y);
            if world.contains(x, y)
                && !world.lethal(x, y)
                && Robot::footprint_free(world, cx, cy, stop.radius_m)
            {
                self.cost_to_go_s[y as usize * world.width + x as usize]
            } else {
                f64::INFINITY
            }
        };
        let near_goal = |x: i64, y: i64| {
            let [cx, cy] = centre(x, y);
            (cx - stop.goal[0]).hypot(cy - stop.goal[1]) <= stop.short_of_goal_m
        };
        if !world.contains(x, y) {
            return out;
        }
        let mut c = self.cost_to_go_s[y as usize * world.width + x as usize];
        while c.is_finite() && c > target_s && !near_goal(x, y) {
            let mut next = (x, y, c);
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let corner_cut =
                        dx != 0 && dy != 0 && (world.lethal(x + dx, y) || world.lethal(x, y + dy));
                    if corner_cut {
                        continue;
                    }
                    let n = cost(x + dx, y + dy);
                    if n < next.2 {
                        next = (x + dx, y + dy, n);
                    }
                }
            }
            if next.2 >= c {
                break;
            }
            (x, y, c) = next;
            out.push(centre(x, y));
        }
        out
    }
}

/// Where an operator's walk must end besides its cost target.
struct Stop {
    goal: [f64; 2],
    short_of_goal_m: f64,
    radius_m: f64,
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
    fn under_the_end_trial_rule_the_first_contact_or_stall_fails_the_trial() {
        let rule = InterventionRule::named("end-trial").unwrap();
        assert_eq!(rule.name(), "end-trial");
        let cfg = EpisodeConfig {
            max_time_s: 45.0,
            intervention: rule,
            ..Default::default()
        };
        // Straight into the bug trap's wall: harmed on contact, about 34 m on.
        let mut e = Episode::new(scenario("bug-trap", 1).unwrap(), cfg);
        while e.step((2.0, 0.0), 0.1) == Outcome::Driving {}
        let sum = e.summary();
        assert_eq!(sum.outcome, Outcome::Harmed, "{sum:?}");
        assert!(sum.time_s < 25.0 && sum.collisions == 1, "{sum:?}");
        assert_eq!(e.intervention_points.len(), 1, "marked where it hit");
        // Standing still touches nothing but is stuck: harmed just after 4 s
        // (HIP's "stationary for over 4 seconds").
        let mut e = Episode::new(scenario("bug-trap", 1).unwrap(), cfg);
        while e.step((0.0, 0.0), 0.1) == Outcome::Driving {}
        let sum = e.summary();
        assert_eq!(
            (sum.outcome, sum.collisions, sum.interventions),
            (Outcome::Harmed, 0, 1)
        );
        assert!(sum.time_s > 4.0 && sum.time_s < 4.25, "{sum:?}");
        // Crawling at 0.2 m/s touches nothing and is never stationary, but
        // covers under 3 m in 10 s: trapped, harmed at 10 s.
        let mut e = Episode::new(scenario("bug-trap", 1).unwrap(), cfg);
        while e.step((0.2, 0.0), 0.1) == Outcome::Driving {}
        let sum = e.summary();
        assert_eq!((sum.outcome, sum.collisions), (Outcome::Harmed, 0));
        assert!((sum.time_s - 10.0).abs() < 0.11, "{sum:?}");
        // Once ended, further commands change nothing.
        assert_eq!(e.step((2.0, 0.0), 0.1), Outcome::Harmed);
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

    /// A myopic goal-seeker: turn toward the goal, drive when facing it.
    fn seek_goal(e: &Episode) -> (f64, f64) {
        let (g, r) = (e.scenario.goal, &e.robot);
        let bearing = (g[1] - r.y_m).atan2(g[0] - r.x_m);
        let err = (bearing - r.yaw_rad + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
            - std::f64::consts::PI;
        (if err.abs() < 0.3 { 2.0 } else { 0.0 }, 2.0 * err)
    }

    #[test]
    fn lrns_operator_faces_the_goal_then_walks_a_trapped_robot_out() {
        let drive = |intervention: InterventionRule| {
            let cfg = EpisodeConfig {
                max_time_s: 200.0,
                intervention,
                ..Default::default()
            };
            let mut e = Episode::new(scenario("bug-trap", 1).unwrap(), cfg);
            while e.step(seek_goal(&e), 0.1) == Outcome::Driving {}
            e
        };
        // Carried back along its own track, it drives into the cup again.
        let carried = drive(InterventionRule::default());
        assert_eq!(carried.outcome(), Outcome::TimedOut);
        assert!(carried.interventions >= 5, "{:?}", carried.summary());

        // The operator: pinned at the back wall (x = 55) from about 18 s,
        // faced to the goal at about 38 s (it already faces it), walked out
        // of the cup at about 58 s down the expert's cost to go, and in the
        // end it drives to the goal itself.
        let op = drive(InterventionRule::named("operator").unwrap());
        let sum = op.summary();
        assert_eq!(sum.outcome, Outcome::Reached, "{sum:?}");
        // The walk ends 10 s of cost below the best (near an arm's end);
        // the seeker turns back into the cup once more and is walked again.
        assert!(
            (1..=3).contains(&sum.interventions),
            "face and walk are one intervention: {sum:?}"
        );
        let p = op.intervention_points[0];
        assert!(
            (p[0] - 54.0).abs() < 1.5 && (p[1] - 50.0).abs() < 3.0,
            "{p:?}"
        );
        assert!(
            op.track.iter().any(|q| q[1] > 71.0 || q[1] < 29.0),
            "the walk leaves the cup past an arm's end"
        );
        assert!(
            sum.time_s > 55.0 && sum.time_s < 120.0,
            "two 20 s waits, then the drive: {sum:?}"
        );
        // Only the driven stretch counts: the walk is carried.
        assert!(sum.distance_m < 110.0, "{sum:?}");

        // A robot that drives straight to an open goal is left alone.
        let mut open = scenario("bug-trap", 1).unwrap();
        open.world = crate::world::World::new(120, 100, crate::world::Cover::Grass);
        let mut e = Episode::new(
            open,
            EpisodeConfig {
                intervention: InterventionRule::named("operator").unwrap(),
                ..Default::default()
            },
        );
        while e.step(seek_goal(&e), 0.1) == Outcome::Driving {}
        assert_eq!(
            (e.outcome(), e.interventions),
            (Outcome::Reached, 0),
            "{:?}",
            e.summary()
        );
        assert!(InterventionRule::named("walk")
            .unwrap_err()
            .contains("\"walk\""));
    }

    #[test]
    fn the_operator_hands_back_before_the_goal_steps_in_where_no_way_leads_and_walks_round_walls() {
        use crate::world::{Cover, Obstacle, World};
        let operator = EpisodeConfig {
            max_time_s: 200.0,
            intervention: InterventionRule::named("operator").unwrap(),
            ..Default::default()
        };
        let still = |s: Scenario| {
            let mut e = Episode::new(s, operator);
            while e.step((0.0, 0.0), 0.1) == Outcome::Driving {}
            e
        };
        // A robot that never moves, 15 m from the goal on open grass: walked
        // to 7 m (goal radius 2 + 5 m), never onto the goal.
        let mut near = scenario("bug-trap", 1).unwrap();
        near.world = World::new(120, 100, Cover::Grass);
        near.start = [65.0, 50.0, 0.0];
        let e = still(near);
        assert_eq!(e.outcome(), Outcome::TimedOut);
        let d = e.goal_distance_m();
        assert!((6.0..=8.0).contains(&d), "handed back {d} m from the goal");

        // The goal walled in: no way leads there, yet the operator steps in.
        let mut sealed = scenario("bug-trap", 1).unwrap();
        for (a, b) in [
            ((78, 48), (82, 48)),
            ((78, 52), (82, 52)),
            ((78, 48), (78, 52)),
            ((82, 48), (82, 52)),
        ] {
            sealed.world.line_obstacle(a, b, Obstacle::Wall);
        }
        let e = still(sealed);
        assert!(e.interventions >= 4, "{:?}", e.summary());

        // A diagonal wall of cells touching only at their corners, between
        // the robot and the goal: the walk goes round it, never through.
        let mut stair = scenario("bug-trap", 1).unwrap();
        stair.world = World::new(120, 100, Cover::Grass);
        for i in 0..60 {
            stair.world.set_obstacle(40 + i, 20 + i, Obstacle::Wall);
        }
        stair.start = [50.0, 50.0, 0.0]; // above the wall's line
        stair.goal = [80.0, 30.0]; // below it
        let e = still(stair);
        assert!(e.interventions >= 1);
        assert!(
            e.track.iter().any(|p| p[0] < 40.0),
            "walked round the wall's end: {:?}",
            e.track
        );
        let side = |p: &[f64; 2]| (p[1] - 20.0) - (p[0] - 40.0);
        for w in e.track.windows(2) {
            let beside_wall = (40.0..=99.0).contains(&w[0][0]) && (40.0..=99.0).contains(&w[1][0]);
            assert!(
                !beside_wall || side(&w[0]) * side(&w[1]) > 0.0,
                "crossed the wall between {:?} and {:?}",
                w[0],
                w[1]
            );
        }
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
