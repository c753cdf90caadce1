//! FITAM's simulated evaluation protocol (section V-A4, Table I): a
//! kinematic sense-plan-act agent, not a driven robot.
//!
//! Each iteration the agent adds its local observations (the occlusion-aware
//! 25 m sensor of [`crate::sensor`], true costs, fixed in the map) and, for
//! the rows that have one, a far-field observation (32 heading bins x 3
//! radial bins to 100 m, Kalman-fused) to a costmap of the whole world,
//! plans with D* Lite (initialised once, then repaired from the changed
//! cells), and travels along the plan until the next cell was not observed
//! locally or 20 m were covered. A trial fails after 1000 iterations (or
//! when no path is left); failures are reported apart and excluded from the
//! paired statistics. The metric is the total cost accumulated on the way,
//! `cost[next] * resolution` (times sqrt 2 on a diagonal), in seconds.
//!
//! The rows (section V-A3):
//! - [`Row::NoFarField`]: local observations only, unknown cells at the
//!   unknown cost (the paper's *No FF*);
//! - [`Row::GroundTruthFarField`]: plus far-field labels made from the true
//!   world by FITAM's label rule (section IV-B) over all 32 heading bins, a
//!   full 360 degree ring as the paper's panoramas gave (*GT FF*);
//! - [`Row::LearnedFarField`]: plus the far field a learned model predicts
//!   from rendered camera images, through a [`FarFieldSource`] the caller
//!   gives (`farsight bench fitam` builds it from the shipped graph's
//!   inference and bin-projection configs on a rig of cameras all round the
//!   robot, as the paper's panoramas) (*Learned FF*);
//! - [`Row::PerfectVision`]: no far field, local observations out to 100 m
//!   instead of 25 m (occlusion kept: local observations are what an
//!   unobstructed ray reaches) (*Perfect Vision*).
//!
//! The map, the Kalman filter and the planner are the stages' own library
//! code (`farsight_costmap_fusion::map::FusionMap`,
//! `farsight_subgoal_selection::dstar_lite::DStarLite`) with the config the
//! shipped graph gives them; only the map covers the whole world instead of
//! the stage's scrolling window, as the paper's agent planned over the whole
//! map.
//!
//! Statistics (Table I): per problem, paired against *No FF* over the
//! problems both reached: "% trials improved" (strictly lower cost) and
//! "average % difference" `100 (cost_noff - cost) / cost_noff` (positive =
//! cheaper), each with a 95% interval from the standard error of the mean.

use crate::labels::{ground_truth_bins, LabelRules};
use crate::rng::SplitMix64;
use crate::sensor::NearFieldSensor;
use crate::world::World;
use farsight_costmap_fusion::kalman::FarFieldConfig;
use farsight_costmap_fusion::map::FusionMap;
use farsight_costmap_fusion::swath::{for_each_swath_cell, PolarGeometry};
use farsight_interfaces::msg::{PolarCell, Stamp};
use farsight_subgoal_selection::dstar_lite::{astar, CostGrid, DStarLite};
use std::time::Instant;

/// Version of this module's rules (the agent's sensing, travel and failure
/// rules, the problem sampler, the cost metric and the paired statistics),
/// hashed into every `farsight bench fitam` result: change it whenever any
/// of them changes what a trial measures.
/// 1: as the module comment says; D* Lite may not cut a blocked cell's corner.
/// 2: the learned row; a far-field source's observation is checked against
/// the geometry before it is fused (the rows of version 1 are unchanged).
pub const AGENT_RULES_VERSION: u32 = 2;

/// Where a row's far-field observation comes from: polar cells at a pose,
/// heading-major in the protocol's [`PolarGeometry`] (heading bin `h`,
/// radial bin `r` at `h * radial + r`), a NaN cost for "no measurement".
pub trait FarFieldSource {
    fn observe(&mut self, world: &World, pose: [f64; 3]) -> anyhow::Result<Vec<PolarCell>>;
}

/// FITAM's ground-truth labels (section IV-B) from the true world over every
/// heading bin.
pub struct GroundTruthFarField<'a> {
    pub geometry: &'a PolarGeometry,
    pub rules: &'a LabelRules,
}

impl FarFieldSource for GroundTruthFarField<'_> {
    fn observe(&mut self, world: &World, pose: [f64; 3]) -> anyhow::Result<Vec<PolarCell>> {
        Ok(ground_truth_bins(world, self.geometry, pose, self.rules))
    }
}

/// One row of Table I.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Row {
    NoFarField,
    GroundTruthFarField,
    LearnedFarField,
    PerfectVision,
}

impl Row {
    pub const ALL: [Row; 4] = [
        Row::NoFarField,
        Row::GroundTruthFarField,
        Row::LearnedFarField,
        Row::PerfectVision,
    ];

    /// The row's name in tables and result files.
    pub fn name(self) -> &'static str {
        match self {
            Row::NoFarField => "no_far_field",
            Row::GroundTruthFarField => "gt_far_field",
            Row::LearnedFarField => "learned_far_field",
            Row::PerfectVision => "perfect_vision",
        }
    }

    pub fn from_name(name: &str) -> Option<Row> {
        Row::ALL.into_iter().find(|r| r.name() == name)
    }
}

/// The protocol's constants (FITAM's simulated configuration).
#[derive(Debug, Clone, PartialEq)]
pub struct ProtocolConfig {
    /// The fused map's far-field filter: the shipped graph's.
    pub far_field: FarFieldConfig,
    pub geometry: PolarGeometry,
    pub label_rules: LabelRules,
    /// Local observations (25 m).
    pub sensor: NearFieldSensor,
    /// Local observation range of [`Row::PerfectVision`].
    pub perfect_vision_range_m: f64,
    /// Most distance travelled per iteration.
    pub max_travel_m: f64,
    pub max_iterations: usize,
}

impl Default for ProtocolConfig {
    fn default() -> Self {
        Self {
            far_field: FarFieldConfig::default(),
            geometry: PolarGeometry::fitam_default(),
            label_rules: LabelRules::default(),
            sensor: NearFieldSensor::default(),
            perfect_vision_range_m: 100.0,
            max_travel_m: 20.0,
            max_iterations: 1000,
        }
    }
}

/// One planning problem on a world.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Problem {
    /// World cells.
    pub start: (usize, usize),
    pub goal: (usize, usize),
    /// The cheapest cost on the fully known world (A*), seconds.
    pub oracle_cost_s: f64,
}

impl Problem {
    pub fn straight_line_m(&self, resolution_m: f64) -> f64 {
        let d = |a: usize, b: usize| a as f64 - b as f64;
        d(self.start.0, self.goal.0).hypot(d(self.start.1, self.goal.1)) * resolution_m
    }
}

/// How a trial ended.
#[derive(Debug, Clone, PartialEq)]
pub struct TrialResult {
    pub reached: bool,
    /// Accumulated true cost, seconds.
    pub cost_s: f64,
    pub distance_m: f64,
    pub iterations: usize,
    /// Cells visited, start first.
    pub track: Vec<(usize, usize)>,
}

/// The world's true costs as a planning grid (lethal = infinite).
pub fn true_cost_grid(world: &World) -> CostGrid {
    let mut grid = CostGrid::new(world.width, world.height, world.resolution_m, 1.0);
    for y in 0..world.height {
        for x in 0..world.width {
            grid.set(x, y, world.cost_s_per_m(x as i64, y as i64));
        }
    }
    grid
}

/// The cheapest cost per metre a cell of `world` can have, in truth or in
/// the map (far-field classes, unknown): the planners' heuristic scale, so
/// that it stays admissible.
pub fn cheapest_cost_s_per_m(world: &World, cfg: &ProtocolConfig) -> f64 {
    let mut cheapest = cfg.far_field.unknown_cost_s_per_m as f64;
    for speed in &cfg.label_rules.class_speeds_mps {
        cheapest = cheapest.min(1.0 / speed);
    }
    for y in 0..world.height as i64 {
        for x in 0..world.width as i64 {
            cheapest = cheapest.min(world.cost_s_per_m(x, y) as f64);
        }
    }
    cheapest
}

/// Whether a cell of true cost `cost_s_per_m` may hold a start or a goal:
/// free space, not lethal and cheaper than bushes (10 s/m).
pub fn is_open_ground(cost_s_per_m: f32) -> bool {
    cost_s_per_m < 5.0
}

/// Samples up to `count` problems as the paper did: start and goal in free
/// space (not lethal, cheaper than bushes), at least `edge_margin_m` from the
/// world's edge, at least `min_goal_m` apart, with a path between them. Fewer
/// come back when the world does not have them (after `count * 50` draws).
pub fn sample_problems(
    world: &World,
    count: usize,
    min_goal_m: f64,
    edge_margin_m: f64,
    seed: u64,
) -> Vec<Problem> {
    let truth = true_cost_grid(world);
    let res = world.resolution_m;
    let margin = (edge_margin_m / res).ceil() as usize;
    if world.width <= 2 * margin || world.height <= 2 * margin {
        return Vec::new();
    }
    let mut rng = SplitMix64::new(seed ^ 0x000F_17A3);
    let draw = |rng: &mut SplitMix64| -> Option<(usize, usize)> {
        let x = rng.range(margin as f64, (world.width - margin) as f64) as usize;
        let y = rng.range(margin as f64, (world.height - margin) as f64) as usize;
        is_open_ground(truth.get(x, y)).then_some((x, y))
    };
    let scale = cheapest_cost_s_per_m(world, &ProtocolConfig::default());
    let mut out = Vec::new();
    for _ in 0..count * 50 {
        if out.len() == count {
            break;
        }
        let (Some(start), Some(goal)) = (draw(&mut rng), draw(&mut rng)) else {
            continue;
        };
        let d = (start.0 as f64 - goal.0 as f64).hypot(start.1 as f64 - goal.1 as f64) * res;
        if d < min_goal_m {
            continue;
        }
        if let Some((_, oracle_cost_s)) = astar(&truth, start, goal, scale) {
            out.push(Problem {
                start,
                goal,
                oracle_cost_s,
            });
        }
    }
    out
}

/// Cells whose planning cost may have changed since the planner last saw
/// them: every cell any observation touched (process noise moves far-field
/// cells back over the variance threshold later), each listed once.
struct Touched {
    width: usize,
    listed: Vec<bool>,
    cells: Vec<u32>,
}

impl Touched {
    fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            listed: vec![false; width * height],
            cells: Vec::new(),
        }
    }

    fn add(&mut self, gx: i64, gy: i64) {
        let height = self.listed.len() / self.width;
        if gx < 0 || gy < 0 || gx as usize >= self.width || gy as usize >= height {
            return;
        }
        let i = gy as usize * self.width + gx as usize;
        if !self.listed[i] {
            self.listed[i] = true;
            self.cells.push(i as u32);
        }
    }
}

/// One iteration's plan, as [`sense_plan_act_observed`] hands it out:
/// what the planner was given and what repairing it cost.
pub struct PlanStep<'a> {
    /// 1 for the first iteration (D* Lite's first search), then 2, 3, ...
    pub iteration: usize,
    /// The planner after its search: its grid is the map the agent plans on.
    pub planner: &'a DStarLite,
    /// The agent's cell.
    pub at: (usize, usize),
    /// Cells whose planning cost changed since the last plan.
    pub changed_cells: usize,
    /// D* Lite's update of those cells and its search, wall time.
    pub plan_s: f64,
    /// Vertices the search expanded.
    pub expanded: usize,
}

/// Runs one row of the protocol on one problem. [`Row::LearnedFarField`]
/// observes through `learned`, and is refused without one; the other rows
/// ignore it. Fails only when the far-field source does, or its
/// observation does not fit the geometry.
pub fn sense_plan_act(
    world: &World,
    problem: &Problem,
    row: Row,
    cfg: &ProtocolConfig,
    learned: Option<&mut dyn FarFieldSource>,
) -> anyhow::Result<TrialResult> {
    sense_plan_act_observed(world, problem, row, cfg, learned, &mut |_| {})
}

/// [`sense_plan_act`], handing each iteration's plan to `on_plan` (after
/// the search, before the agent moves): `farsight bench planning` times
/// D* Lite's repairs on the updates this loop really makes.
pub fn sense_plan_act_observed(
    world: &World,
    problem: &Problem,
    row: Row,
    cfg: &ProtocolConfig,
    learned: Option<&mut dyn FarFieldSource>,
    on_plan: &mut dyn FnMut(&PlanStep),
) -> anyhow::Result<TrialResult> {
    let (w, h, res) = (world.width, world.height, world.resolution_m);
    // The map's window is the whole world: its cell (gx, gy) is the world's.
    let mut map = FusionMap::new(w, h, res, cfg.far_field);
    let mut ground_truth = GroundTruthFarField {
        geometry: &cfg.geometry,
        rules: &cfg.label_rules,
    };
    let mut far_field: Option<&mut dyn FarFieldSource> = match row {
        Row::GroundTruthFarField => Some(&mut ground_truth),
        Row::LearnedFarField => Some(learned.ok_or_else(|| {
            anyhow::anyhow!(
                "the learned_far_field row needs a far-field source (a model and a camera rig)"
            )
        })?),
        Row::NoFarField | Row::PerfectVision => None,
    };
    let use_far_field = far_field.is_some();
    let want_cells = cfg.geometry.heading_bins * cfg.geometry.radial_bins();
    let sensor = match row {
        Row::PerfectVision => NearFieldSensor {
            range_m: cfg.perfect_vision_range_m,
            ..cfg.sensor
        },
        _ => cfg.sensor,
    };
    let first_cost = map.planning_cost(0, 0, use_far_field).unwrap_or(1.0);
    let mut planner = DStarLite::new(
        CostGrid::new(w, h, res, first_cost),
        problem.start,
        problem.goal,
        cheapest_cost_s_per_m(world, cfg),
    );
    let mut touched = Touched::new(w, h);
    let mut at = problem.start;
    let mut yaw_rad =
        (problem.goal.1 as f64 - at.1 as f64).atan2(problem.goal.0 as f64 - at.0 as f64);
    let mut result = TrialResult {
        reached: false,
        cost_s: 0.0,
        distance_m: 0.0,
        iterations: 0,
        track: vec![at],
    };
    let mut updates: Vec<(usize, usize, f32)> = Vec::new();
    while result.iterations < cfg.max_iterations {
        result.iterations += 1;
        let (x_m, y_m) = (at.0 as f64 * res, at.1 as f64 * res);
        // Sense: the far field first, so that this iteration's local
        // observations are not overwritten (they never are: fixed cells
        // skip far-field updates), then the local fix.
        if let Some(source) = far_field.as_deref_mut() {
            let bins = source.observe(world, [x_m, y_m, yaw_rad])?;
            anyhow::ensure!(
                bins.len() == want_cells,
                "{} far field: {} polar cells, the geometry's {} heading x {} radial bins need {want_cells}",
                row.name(),
                bins.len(),
                cfg.geometry.heading_bins,
                cfg.geometry.radial_bins()
            );
            map.observe_far_field(&cfg.geometry, &bins, x_m, y_m, yaw_rad);
            for_each_swath_cell(&cfg.geometry, x_m, y_m, yaw_rad, res, |gx, gy, _, _| {
                touched.add(gx, gy)
            });
            map.add_process_noise();
        }
        let (header, cells) = sensor.observe(world, x_m, y_m, Stamp::default());
        let side = header.width as i64;
        let (cx, cy) = (at.0 as i64, at.1 as i64);
        let half = side / 2;
        for (k, c) in cells.iter().enumerate() {
            if c.cost_s_per_m.is_nan() {
                continue;
            }
            let (i, j) = (k as i64 / side, k as i64 % side);
            let (gx, gy) = (cx - half + j, cy + half - i);
            if map.fix_local(gx, gy, c.cost_s_per_m) {
                touched.add(gx, gy);
            }
        }
        // Plan: hand D* Lite the cells whose planning cost changed.
        updates.clear();
        for &i in &touched.cells {
            let (x, y) = (i as usize % w, i as usize / w);
            let cost = map
                .planning_cost(x as i64, y as i64, use_far_field)
                .unwrap_or(f32::INFINITY);
            let old = planner.grid().get(x, y);
            if old.to_bits() != cost.to_bits() {
                updates.push((x, y, cost));
            }
        }
        // Cells fixed by local sensing never change again but stay listed:
        // dropping them would save a scan, but the list is small next to the
        // world and one rule is easier to trust.
        // D* Lite's order: the start moves first, so that the key offset
        // km accounts for the move when the changed cells are queued.
        planner.move_start(at);
        let (t, expanded_before) = (Instant::now(), planner.expanded);
        planner.set_costs(updates.iter().copied());
        let reachable = planner.compute().is_some();
        on_plan(&PlanStep {
            iteration: result.iterations,
            planner: &planner,
            at,
            changed_cells: updates.len(),
            plan_s: t.elapsed().as_secs_f64(),
            expanded: planner.expanded - expanded_before,
        });
        if !reachable {
            break;
        }
        let path = planner.path();
        // Act: along the plan while the next cell was observed locally, at
        // most max_travel_m.
        let mut travelled_m = 0.0;
        for next in path.iter().skip(1) {
            if map.local_cost(next.0 as i64, next.1 as i64).is_none() {
                break;
            }
            let diagonal = next.0 != at.0 && next.1 != at.1;
            let step_m = if diagonal {
                res * std::f64::consts::SQRT_2
            } else {
                res
            };
            if travelled_m + step_m > cfg.max_travel_m + 1e-9 {
                break;
            }
            let true_cost = world.cost_s_per_m(next.0 as i64, next.1 as i64) as f64;
            if !true_cost.is_finite() {
                // A fixed cell holds its true cost, so a plan never enters
                // a lethal one; stop rather than count an impossible step.
                break;
            }
            yaw_rad = (next.1 as f64 - at.1 as f64).atan2(next.0 as f64 - at.0 as f64);
            travelled_m += step_m;
            result.cost_s += true_cost * step_m;
            at = *next;
            result.track.push(at);
            if at == problem.goal {
                result.reached = true;
                break;
            }
        }
        result.distance_m += travelled_m;
        if result.reached {
            break;
        }
    }
    Ok(result)
}

/// A mean with its 95% half-width from the standard error of the mean.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeanCi {
    pub mean: f64,
    pub half_width: f64,
    pub n: usize,
}

impl MeanCi {
    pub fn of(values: &[f64]) -> Option<Self> {
        if values.is_empty() {
            return None;
        }
        let n = values.len() as f64;
        let mean = values.iter().sum::<f64>() / n;
        let half_width = if values.len() < 2 {
            f64::NAN
        } else {
            let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
            1.96 * (var / n).sqrt()
        };
        Some(Self {
            mean,
            half_width,
            n: values.len(),
        })
    }
}

/// Table I's statistics of one row against *No FF*, over the same problems.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Paired {
    /// % of the problems both reached where the row cost strictly less.
    pub trials_improved_pct: Option<MeanCi>,
    /// Mean of `100 (cost_noff - cost) / cost_noff` over those problems.
    pub avg_diff_pct: Option<MeanCi>,
    /// % of all the row's problems that failed.
    pub failed_pct: f64,
    /// Problems both reached.
    pub paired: usize,
}

/// Pairs a row's costs with the baseline's, problem by problem (`None` =
/// failed).
pub fn paired_against(baseline: &[Option<f64>], row: &[Option<f64>]) -> Paired {
    assert_eq!(baseline.len(), row.len(), "the same problems");
    let (mut improved, mut diff) = (Vec::new(), Vec::new());
    for (b, r) in baseline.iter().zip(row) {
        if let (Some(b), Some(r)) = (b, r) {
            improved.push(if r < b { 100.0 } else { 0.0 });
            diff.push(100.0 * (b - r) / b);
        }
    }
    let failed = row.iter().filter(|r| r.is_none()).count();
    Paired {
        trials_improved_pct: MeanCi::of(&improved),
        avg_diff_pct: MeanCi::of(&diff),
        failed_pct: 100.0 * failed as f64 / row.len().max(1) as f64,
        paired: improved.len(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::{Cover, Obstacle};

    /// Forest (2 s/m) between start and goal, a 12 m road (0.2 s/m) 55 m
    /// off the straight line and parallel to it: FITAM Fig. 1 in miniature.
    /// The road lies beyond local sensing (25 m), inside the far field
    /// (100 m).
    fn road_beside_forest() -> (World, Problem) {
        let mut w = World::new(400, 200, Cover::Forest);
        w.fill_cover(0, 155, 399, 166, Cover::Road);
        let truth = true_cost_grid(&w);
        let (start, goal) = ((20, 100), (380, 100));
        let (_, oracle_cost_s) = astar(&truth, start, goal, 0.2).unwrap();
        (
            w,
            Problem {
                start,
                goal,
                oracle_cost_s,
            },
        )
    }

    #[test]
    fn the_far_field_finds_the_road_no_far_field_cannot() {
        let (w, p) = road_beside_forest();
        let cfg = ProtocolConfig::default();
        let noff = sense_plan_act(&w, &p, Row::NoFarField, &cfg, None).unwrap();
        let gt = sense_plan_act(&w, &p, Row::GroundTruthFarField, &cfg, None).unwrap();
        assert!(noff.reached && gt.reached, "{noff:?} {gt:?}");
        // Straight through 320 m of forest costs ~700 s; the road way is
        // ~460 m at 0.2 s/m plus a little forest.
        assert!(
            gt.cost_s < 0.6 * noff.cost_s,
            "gt {} vs no ff {}",
            gt.cost_s,
            noff.cost_s
        );
        assert!(
            gt.cost_s >= p.oracle_cost_s - 1e-6,
            "never below the oracle"
        );
        assert!(noff.cost_s >= p.oracle_cost_s - 1e-6);
        // Every iteration travels at most 20 m.
        assert!(noff.distance_m <= 20.0 * noff.iterations as f64 + 1e-9);
        let stats = paired_against(&[Some(noff.cost_s)], &[Some(gt.cost_s)]);
        assert_eq!(stats.trials_improved_pct.unwrap().mean, 100.0);
        assert!(stats.avg_diff_pct.unwrap().mean > 40.0);
    }

    /// A far-field source that counts its calls and answers with what it
    /// is given (`None`: ground truth).
    struct Scripted {
        calls: usize,
        answer: Option<Vec<PolarCell>>,
    }

    impl FarFieldSource for Scripted {
        fn observe(&mut self, world: &World, pose: [f64; 3]) -> anyhow::Result<Vec<PolarCell>> {
            self.calls += 1;
            let cfg = ProtocolConfig::default();
            Ok(match &self.answer {
                Some(a) => a.clone(),
                None => ground_truth_bins(world, &cfg.geometry, pose, &cfg.label_rules),
            })
        }
    }

    #[test]
    fn each_iteration_hands_out_its_plan_and_the_trial_is_unchanged() {
        let (w, p) = road_beside_forest();
        let cfg = ProtocolConfig::default();
        let mut steps = Vec::new();
        let observed =
            sense_plan_act_observed(&w, &p, Row::GroundTruthFarField, &cfg, None, &mut |s| {
                steps.push((s.iteration, s.at, s.changed_cells, s.expanded))
            })
            .unwrap();
        let plain = sense_plan_act(&w, &p, Row::GroundTruthFarField, &cfg, None).unwrap();
        assert_eq!(observed, plain, "watching the plans changes nothing");
        assert!(plain.reached);
        let iterations: Vec<usize> = steps.iter().map(|s| s.0).collect();
        assert_eq!(iterations, (1..=plain.iterations).collect::<Vec<_>>());
        // Each plan is made where that iteration's travel starts: the
        // track's cells at the iteration boundaries, in order.
        let plan_cells: Vec<(usize, usize)> = steps.iter().map(|s| s.1).collect();
        let mut on_track = plain.track.iter();
        for c in &plan_cells {
            assert!(on_track.any(|t| t == c), "{c:?} not next on the track");
        }
        assert_eq!(plan_cells[0], p.start);
        // The first plan takes in the whole first view and searches the
        // whole way; later ones repair, expanding less.
        assert!(steps[0].2 > 1000, "first view: {} cells", steps[0].2);
        for s in &steps[1..] {
            assert!(
                s.2 < steps[0].2 && s.3 < steps[0].3,
                "{s:?} vs {:?}",
                steps[0]
            );
        }
    }

    #[test]
    fn the_learned_row_fuses_its_sources_observation_each_iteration() {
        let (w, p) = road_beside_forest();
        let cfg = ProtocolConfig::default();
        let gt = sense_plan_act(&w, &p, Row::GroundTruthFarField, &cfg, None).unwrap();
        // A source that sees the truth drives the ground-truth row's track.
        let mut truth = Scripted {
            calls: 0,
            answer: None,
        };
        let learned = sense_plan_act(&w, &p, Row::LearnedFarField, &cfg, Some(&mut truth)).unwrap();
        assert_eq!(learned, gt);
        assert_eq!(truth.calls, gt.iterations, "one observation per iteration");
        // One that never measures anything is No FF.
        let noff = sense_plan_act(&w, &p, Row::NoFarField, &cfg, None).unwrap();
        let mut blind = Scripted {
            calls: 0,
            answer: Some(vec![PolarCell::NO_MEASUREMENT; 32 * 3]),
        };
        let r = sense_plan_act(&w, &p, Row::LearnedFarField, &cfg, Some(&mut blind)).unwrap();
        assert_eq!(r.cost_s, noff.cost_s);
        // The other rows never ask the source.
        let mut unused = Scripted {
            calls: 0,
            answer: None,
        };
        sense_plan_act(&w, &p, Row::NoFarField, &cfg, Some(&mut unused)).unwrap();
        assert_eq!(unused.calls, 0);
    }

    #[test]
    fn a_learned_row_without_a_source_or_with_a_misshapen_one_is_refused() {
        let (w, p) = road_beside_forest();
        let cfg = ProtocolConfig::default();
        let e = sense_plan_act(&w, &p, Row::LearnedFarField, &cfg, None).unwrap_err();
        assert!(e.to_string().contains("needs a far-field source"), "{e}");
        let mut short = Scripted {
            calls: 0,
            answer: Some(vec![PolarCell::NO_MEASUREMENT; 30]),
        };
        let e = sense_plan_act(&w, &p, Row::LearnedFarField, &cfg, Some(&mut short)).unwrap_err();
        assert_eq!(
            e.to_string(),
            "learned_far_field far field: 30 polar cells, the geometry's 32 heading x 3 radial bins need 96"
        );
    }

    #[test]
    fn the_agent_stops_where_local_sensing_ends() {
        // A wall of trees across the way with one gap: the agent cannot see
        // past the trees, so it must stop at unobserved cells and re-plan,
        // never step into a cell it has not observed locally.
        let mut w = World::new(200, 100, Cover::Grass);
        for y in 0..100 {
            if !(70..=73).contains(&y) {
                w.set_obstacle(100, y, Obstacle::Tree);
            }
        }
        let truth = true_cost_grid(&w);
        let (start, goal) = ((20, 50), (180, 50));
        let oracle_cost_s = astar(&truth, start, goal, 0.2).unwrap().1;
        let p = Problem {
            start,
            goal,
            oracle_cost_s,
        };
        let cfg = ProtocolConfig::default();
        let r = sense_plan_act(&w, &p, Row::NoFarField, &cfg, None).unwrap();
        assert!(r.reached, "{r:?}");
        assert!(r.track.iter().all(|&(x, y)| !w.lethal(x as i64, y as i64)));
        assert!(
            r.track
                .iter()
                .any(|&(x, y)| x == 100 && (70..=73).contains(&y)),
            "through the gap"
        );
        // 160 m at 20 m an iteration needs at least 8.
        assert!(r.iterations >= 8, "{}", r.iterations);
        assert!(r.cost_s >= oracle_cost_s - 1e-6);
    }

    #[test]
    fn a_trial_without_a_way_fails_and_the_iteration_limit_holds() {
        let mut w = World::new(120, 60, Cover::Grass);
        for y in 0..60 {
            w.set_obstacle(60, y, Obstacle::Wall);
        }
        let p = Problem {
            start: (10, 30),
            goal: (110, 30),
            oracle_cost_s: f64::NAN,
        };
        let r = sense_plan_act(&w, &p, Row::NoFarField, &ProtocolConfig::default(), None).unwrap();
        assert!(!r.reached);
        let cfg = ProtocolConfig {
            max_iterations: 2,
            ..Default::default()
        };
        let open = World::new(200, 60, Cover::Grass);
        let far = Problem {
            start: (10, 30),
            goal: (190, 30),
            oracle_cost_s: 90.0,
        };
        let r = sense_plan_act(&open, &far, Row::NoFarField, &cfg, None).unwrap();
        assert!(
            !r.reached && r.iterations == 2 && r.distance_m <= 40.0 + 1e-9,
            "{r:?}"
        );
    }

    #[test]
    fn perfect_vision_sees_the_road_from_further_away() {
        let (w, p) = road_beside_forest();
        let cfg = ProtocolConfig::default();
        let noff = sense_plan_act(&w, &p, Row::NoFarField, &cfg, None).unwrap();
        let pv = sense_plan_act(&w, &p, Row::PerfectVision, &cfg, None).unwrap();
        assert!(
            pv.reached && pv.cost_s < noff.cost_s,
            "{} vs {}",
            pv.cost_s,
            noff.cost_s
        );
    }

    #[test]
    fn problems_are_far_apart_free_and_solvable() {
        let s = crate::scenario::random_world(3, 600);
        let ps = sample_problems(&s.world, 5, 300.0, 50.0, 7);
        assert_eq!(ps.len(), 5);
        for p in &ps {
            assert!(p.straight_line_m(1.0) >= 300.0);
            for c in [p.start, p.goal] {
                assert!(
                    (50..550).contains(&c.0) && (50..550).contains(&c.1),
                    "{c:?}"
                );
                assert!(s.world.cost_s_per_m(c.0 as i64, c.1 as i64) < 5.0);
            }
            assert!(p.oracle_cost_s.is_finite() && p.oracle_cost_s > 0.0);
        }
        assert_eq!(ps, sample_problems(&s.world, 5, 300.0, 50.0, 7), "seeded");
        assert!(sample_problems(&s.world, 5, 5000.0, 50.0, 7).is_empty());
    }

    #[test]
    fn paired_statistics_by_hand() {
        let base = [Some(100.0), Some(200.0), None, Some(50.0)];
        let row = [Some(80.0), Some(200.0), Some(10.0), None];
        let s = paired_against(&base, &row);
        assert_eq!(s.paired, 2);
        assert_eq!(s.trials_improved_pct.unwrap().mean, 50.0);
        assert!((s.avg_diff_pct.unwrap().mean - 10.0).abs() < 1e-12);
        assert_eq!(s.failed_pct, 25.0);
        // Two values 20 and 0: sd 14.14, sem 10, half-width 19.6.
        assert!((s.avg_diff_pct.unwrap().half_width - 19.6).abs() < 1e-9);
    }
}
