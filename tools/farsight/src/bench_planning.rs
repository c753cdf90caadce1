//! `farsight bench planning`: what FITAM's map and planner cost per step on
//! this machine: a far-field observation into the fused map (FITAM default
//! geometry, 201x201 window), exporting the fused layer, and D* Lite on a
//! `side` x `side` grid: the first search, a repair after the robot moves and
//! 25 cells near it change, and A* from scratch on the same changed grid;
//! beside the first search, A* of the well-kept `pathfinding` crate and the
//! project's own A* on the same grid (issue 21, item 2: the yardstick);
//! D* Lite's repair on a 1360-cell grid after a FITAM step, from a
//! synthetic far field and from FITAM's own sense-plan-act loop, each
//! against A* from scratch; and what a guide's moving goal costs.

use crate::bench::PlanningArgs;
use anyhow::{Context, Result};
use farsight_costmap_fusion::kalman::FarFieldConfig;
use farsight_costmap_fusion::map::FusionMap;
use farsight_costmap_fusion::swath::{for_each_swath_cell, PolarGeometry};
use farsight_interfaces::msg::{CostmapLayer, PolarCell, Stamp};
use farsight_sim::rng::SplitMix64;
use farsight_subgoal_selection::dstar_lite::{astar, octile, CostGrid, DStarLite};
use std::time::Instant;

/// Edge costs in whole microseconds: the crate's A* needs an ordered
/// integer-like cost.
const MICROS: f64 = 1e6;

/// A* of the `pathfinding` crate over `grid`, 8-connected with the
/// planner's own step costs ([`CostGrid::step_cost`], no corner cutting),
/// the octile heuristic at `min_cost_s_per_m`; the path's cost in
/// microseconds.
fn pathfinding_astar(
    grid: &CostGrid,
    start: (usize, usize),
    goal: (usize, usize),
    min_cost_s_per_m: f64,
) -> Option<u64> {
    let scale = min_cost_s_per_m * grid.resolution_m * MICROS;
    let successors = |&c: &(usize, usize)| {
        grid.neighbours(c)
            .filter_map(|n| {
                let cost = grid.step_cost(c, n);
                cost.is_finite()
                    .then(|| (n, (cost * MICROS).round() as u64))
            })
            .collect::<Vec<_>>()
    };
    // The planner's octile heuristic, floored a little below so that
    // rounding the edges never makes it overestimate.
    let heuristic = |&c: &(usize, usize)| (octile(c, goal, scale) * 0.999).floor() as u64;
    pathfinding::directed::astar::astar(&start, successors, heuristic, |&c| c == goal).map(|p| p.1)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn median_ms(v: Vec<f64>) -> f64 {
    median(v) * 1e3
}

pub fn run(a: PlanningArgs) -> Result<()> {
    let runs = a.runs.max(1);
    println!(
        "FITAM map and planning, median of {runs} runs (one run, this machine's CPU, one core):\n"
    );
    println!("| step | median ms | notes |");
    println!("|---|---|---|");

    let geometry = PolarGeometry::fitam_default();
    let bins: Vec<PolarCell> = (0..32 * 3)
        .map(|k| PolarCell {
            cost_s_per_m: [2.0, 0.444, 0.235][k % 3],
            variance: 0.2,
            class_id: (k % 3) as u32,
            probability: 0.8,
        })
        .collect();
    let mut map = FusionMap::new(201, 201, 1.0, FarFieldConfig::default());
    let (mut obs, mut export) = (Vec::new(), Vec::new());
    let mut cells = 0;
    for i in 0..runs {
        let x = i as f64 * 0.7;
        map.recenter(x, 0.0);
        let t = Instant::now();
        cells = map.observe_far_field(&geometry, &bins, x, 0.0, 0.3).updated;
        map.add_process_noise();
        obs.push(t.elapsed().as_secs_f64());
        let t = Instant::now();
        std::hint::black_box(map.export(Stamp::default(), CostmapLayer::FUSED, true));
        export.push(t.elapsed().as_secs_f64());
    }
    println!("| far-field observation + process noise | {:.2} | 32x3 polar bins, {cells} cell updates, 201x201 window |", median_ms(obs));
    println!(
        "| fused costmap export | {:.2} | 40401 cells |",
        median_ms(export)
    );

    let side = a.side.max(10);
    let mut rng = SplitMix64::new(7);
    let mut grid = CostGrid::new(side, side, 1.0, 1.0);
    for y in 0..side {
        for x in 0..side {
            let r = rng.unit();
            grid.set(
                x,
                y,
                if r < 0.1 {
                    f32::INFINITY
                } else {
                    (0.2 + 2.0 * rng.unit()) as f32
                },
            );
        }
    }
    let (start, goal) = ((side / 10, side / 2), (side - 1 - side / 10, side / 2));
    grid.set(start.0, start.1, 1.0);
    grid.set(goal.0, goal.1, 1.0);
    let (mut first, mut repair, mut scratch) = (Vec::new(), Vec::new(), Vec::new());
    let (mut crate_astar, mut own_astar) = (Vec::new(), Vec::new());
    let mut first_cost = (0.0, 0.0, 0.0);
    let (mut first_exp, mut repair_exp) = (0, 0);
    for _ in 0..runs {
        let mut g = grid.clone();
        let mut d = DStarLite::new(g.clone(), start, goal, 0.2);
        let t = Instant::now();
        let dstar_cost = d.compute();
        first.push(t.elapsed().as_secs_f64());
        first_exp = d.expanded;
        let t = Instant::now();
        let theirs = pathfinding_astar(&g, start, goal, 0.2);
        crate_astar.push(t.elapsed().as_secs_f64());
        let t = Instant::now();
        let ours = astar(&g, start, goal, 0.2);
        own_astar.push(t.elapsed().as_secs_f64());
        first_cost = (
            dstar_cost.unwrap_or(f64::INFINITY),
            theirs.map_or(f64::INFINITY, |c| c as f64 / MICROS),
            ours.map_or(f64::INFINITY, |p| p.1),
        );
        // Drive 5 cells along the path; 25 cells within 20 m of the robot change.
        let path = d.path();
        let robot = path.get(5).copied().unwrap_or(start);
        d.move_start(robot);
        for _ in 0..25 {
            let x =
                (robot.0 as f64 + (rng.unit() - 0.5) * 40.0).clamp(0.0, side as f64 - 1.0) as usize;
            let y =
                (robot.1 as f64 + (rng.unit() - 0.5) * 40.0).clamp(0.0, side as f64 - 1.0) as usize;
            if (x, y) == robot || (x, y) == goal {
                continue;
            }
            let c = if rng.unit() < 0.5 { f32::INFINITY } else { 0.3 };
            g.set(x, y, c);
            d.set_cost(x, y, c);
        }
        let before = d.expanded;
        let t = Instant::now();
        d.compute();
        repair.push(t.elapsed().as_secs_f64());
        repair_exp = d.expanded - before;
        let t = Instant::now();
        std::hint::black_box(astar(&g, robot, goal, 0.2));
        scratch.push(t.elapsed().as_secs_f64());
    }
    let (f, r, s) = (median_ms(first), median_ms(repair), median_ms(scratch));
    let (pf, own) = (median_ms(crate_astar), median_ms(own_astar));
    println!("| D* Lite first search | {f:.1} | {side}x{side} grid, {first_exp} expansions; {:.2}x the pathfinding crate's A* |", f / pf.max(1e-9));
    println!(
        "| A* of the pathfinding crate | {pf:.1} | same grid and start and goal; path cost {:.3} s (D* Lite {:.3} s) |",
        first_cost.1, first_cost.0
    );
    println!(
        "| the project's A* | {own:.1} | same grid; path cost {:.3} s |",
        first_cost.2
    );
    println!("| D* Lite repair | {r:.2} | after 25 changed cells near the robot, {repair_exp} expansions |");
    println!(
        "| A* from scratch | {s:.1} | same changed grid; repair is {:.0}x faster |",
        s / r.max(1e-9)
    );
    fitam_repair(runs);
    fitam_loop_repair()?;
    guided_goal_moves(runs);
    Ok(())
}

/// A FITAM step on the grid a 2 km trial plans on: D* Lite repaired after
/// one far-field observation (every swath cell 25-100 m ahead) and the
/// 25 m near field change, against A* from scratch on the changed grid.
fn fitam_repair(runs: usize) {
    // A goal 1.84 km away diagonally (random-long) and the planner's 30 m
    // margin: about 1360 cells a side.
    let side = 1360;
    let mut rng = SplitMix64::new(11);
    let mut grid = CostGrid::new(side, side, 1.0, 1.0);
    for y in 0..side {
        for x in 0..side {
            if rng.unit() < 0.05 {
                grid.set(x, y, f32::INFINITY);
            }
        }
    }
    let (start, goal) = ((30, 30), (side - 31, side - 31));
    let geometry = PolarGeometry::fitam_default();
    let class_costs = [2.0f32, 0.444, 0.235];
    let (mut repair, mut scratch, mut cells, mut exp) = (Vec::new(), Vec::new(), 0, 0);
    let mut updates = Vec::new();
    let mut d = DStarLite::new(grid.clone(), start, goal, 0.2);
    d.compute();
    let mut robot = start;
    for _ in 0..runs {
        // 20 m along the plan, as FITAM's agent travels.
        let path = d.path();
        robot = path.get(20).copied().unwrap_or(robot);
        let next = path.get(21).copied().unwrap_or(goal);
        let yaw = (next.1 as f64 - robot.1 as f64).atan2(next.0 as f64 - robot.0 as f64);
        d.move_start(robot);
        let mut changed = Vec::new();
        for_each_swath_cell(
            &geometry,
            robot.0 as f64,
            robot.1 as f64,
            yaw,
            1.0,
            |gx, gy, h, r| {
                if gx >= 0 && gy >= 0 && (gx as usize) < side && (gy as usize) < side {
                    let c = class_costs[(h + r + gx as usize) % 3];
                    changed.push((gx as usize, gy as usize, c));
                }
            },
        );
        for dy in -25i64..=25 {
            for dx in -25i64..=25 {
                let (x, y) = (robot.0 as i64 + dx, robot.1 as i64 + dy);
                if x >= 0 && y >= 0 && (x as usize) < side && (y as usize) < side {
                    let lethal = rng.unit() < 0.05 && (dx, dy) != (0, 0);
                    changed.push((
                        x as usize,
                        y as usize,
                        if lethal { f32::INFINITY } else { 0.5 },
                    ));
                }
            }
        }
        changed.retain(|&(x, y, _)| (x, y) != goal);
        cells = changed.len();
        for &(x, y, c) in &changed {
            grid.set(x, y, c);
        }
        let before = d.expanded;
        let t = Instant::now();
        d.set_costs(changed.iter().copied());
        updates.push(t.elapsed().as_secs_f64());
        d.compute();
        repair.push(t.elapsed().as_secs_f64());
        exp = d.expanded - before;
        let t = Instant::now();
        std::hint::black_box(astar(&grid, robot, goal, 0.2));
        scratch.push(t.elapsed().as_secs_f64());
    }
    let (r, s, u) = (median_ms(repair), median_ms(scratch), median_ms(updates));
    println!("| D* Lite repair, FITAM step | {r:.1} | {side}x{side} grid (a 1.84 km diagonal goal), robot 20 m on, one far-field observation and the 51x51 near field: {cells} cells ({u:.1} ms of it updating their vertices), {exp} expansions |");
    println!(
        "| A* from scratch, same step | {s:.1} | repair is {:.0}x faster |",
        s / r.max(1e-9)
    );
}

/// The same grid size, but the updates FITAM's own loop makes
/// (`farsight_sim::fitam_protocol`, as `farsight bench fitam` runs it): a
/// random land-cover world, ground-truth far-field labels through the
/// Kalman map, the occlusion-aware 25 m near field, 20 m of travel per
/// iteration. [`fitam_repair`]'s synthetic pattern gives every swath cell
/// a new class at every step; here a cell changes only as the real loop
/// changes it (a swath's majority label shifting as it moves, a mean moved
/// part of the way by an unsure label), which is the question: is the
/// synthetic update a fair stand-in? A* from scratch runs on the
/// planner's own grid at every third step, and the ratio is of the two
/// medians.
fn fitam_loop_repair() -> Result<()> {
    use farsight_sim::fitam_protocol::{
        cheapest_cost_s_per_m, is_open_ground, sense_plan_act_observed, true_cost_grid, Problem,
        ProtocolConfig, Row,
    };
    let side = 1360;
    let seed = 3;
    let world = farsight_sim::scenario::random_world(seed, side).world;
    let truth = true_cost_grid(&world);
    // The corners 30 m in (the grid of a 1.84 km diagonal goal), moved
    // along the diagonal to the first cell the agent may stand on.
    let free = |from: (usize, usize), step: isize| {
        (0..side / 2)
            .map(|k| {
                let c = (from.0 as isize + step * k as isize) as usize;
                (c, (from.1 as isize + step * k as isize) as usize)
            })
            .find(|&(x, y)| is_open_ground(truth.get(x, y)))
            .with_context(|| {
                format!("random world seed {seed}: no open ground on the diagonal from {from:?}")
            })
    };
    let problem = Problem {
        start: free((30, 30), 1)?,
        goal: free((side - 31, side - 31), -1)?,
        // Only the protocol's statistics read it; none are made here.
        oracle_cost_s: f64::NAN,
    };
    let cfg = ProtocolConfig::default();
    let scale = cheapest_cost_s_per_m(&world, &cfg);
    let (mut repair, mut scratch, mut cells, mut expanded) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let result = sense_plan_act_observed(
        &world,
        &problem,
        Row::GroundTruthFarField,
        &cfg,
        None,
        &mut |step| {
            if step.iteration < 2 {
                return; // the first search, not a repair
            }
            repair.push(step.plan_s);
            cells.push(step.changed_cells as f64);
            expanded.push(step.expanded as f64);
            if step.iteration % 3 == 2 {
                let t = Instant::now();
                std::hint::black_box(astar(step.planner.grid(), step.at, problem.goal, scale));
                scratch.push(t.elapsed().as_secs_f64());
            }
        },
    );
    let steps = repair.len();
    if steps == 0 || scratch.is_empty() {
        println!("| D* Lite repair, FITAM's loop | - | no repair step ({result:?}) |");
        return Ok(());
    }
    let (r, s) = (median_ms(repair), median_ms(scratch));
    let (c, e) = (median(cells), median(expanded));
    let reached = result.as_ref().is_ok_and(|t| t.reached);
    println!("| D* Lite repair, FITAM's loop | {r:.2} | {side}x{side} random world (seed {seed}), ground-truth far field through the Kalman map and the 25 m near field, 20 m a step, as `bench fitam`'s agent: {steps} steps (goal reached: {reached}), median {c:.0} changed cells, {e:.0} expansions |");
    println!(
        "| A* from scratch, same steps | {s:.1} | every third step, on the planner's grid; repair is {:.0}x faster (medians) |",
        s / r.max(1e-9)
    );
    Ok(())
}

/// LRN's heading as D* Lite's goal (`graphs/sim/lrn-dstar.toml`: a 121 m
/// fused window, the subgoal 25 m out, a 30 m margin) on a fixed random
/// world the robot drives through at 0.5 m a frame: what the subgoal stage
/// pays per frame when the guide's goal moves, by building a planner on
/// the fused window and searching (before), against keeping the grid and
/// retargeting its search (`WorldPlanner::retarget`, building only when
/// the goal nears the grid's edge).
fn guided_goal_moves(runs: usize) {
    use farsight_interfaces::msg::{CostCell, CostmapHeader};
    use farsight_subgoal_selection::planner::{WorldPlanner, WorldPlannerConfig};
    let cfg = WorldPlannerConfig {
        margin_m: 30.0,
        ..WorldPlannerConfig::default()
    };
    let side = 121usize;
    let world_side = 4096usize;
    let mut rng = SplitMix64::new(5);
    let world: Vec<f32> = (0..world_side * world_side)
        .map(|_| {
            if rng.unit() < 0.05 {
                f32::INFINITY
            } else {
                (0.3 + rng.unit()) as f32
            }
        })
        .collect();
    // The fused window centred on the robot's cell; world cell (0, 0)
    // is at (-60, -2048) m.
    let costmap = |robot_x_m: f64| -> (CostmapHeader, Vec<CostCell>) {
        let x0 = robot_x_m.round() - 60.0;
        let header = CostmapHeader {
            stamp: Stamp::default(),
            layer: CostmapLayer::FUSED,
            width: side as u32,
            height: side as u32,
            resolution_m: 1.0,
            x_min_m: x0 - 0.5,
            y_max_m: 60.5,
        };
        let cells = (0..side * side)
            .map(|k| {
                let [x, y] = header.cell_centre_m(k);
                let (wx, wy) = ((x + 60.0) as usize, (y + 2048.0) as usize);
                CostCell {
                    cost_s_per_m: world[wy * world_side + wx],
                    variance: 0.0,
                }
            })
            .collect();
        (header, cells)
    };
    let frames = runs.clamp(1, (world_side - 200) * 2);
    let (mut rebuilt, mut kept, mut builds) = (Vec::new(), Vec::new(), 0);
    let mut planner: Option<WorldPlanner> = None;
    for i in 0..frames {
        let robot = [0.5 * i as f64, 0.0];
        let goal = [robot[0] + 25.0, 1.0 + (i % 3) as f64];
        let (h, c) = costmap(robot[0]);
        let t = Instant::now();
        let mut fresh = WorldPlanner::new(robot, goal, &cfg);
        fresh.apply_costmap(&h, &c);
        let want = fresh.plan(robot).ok().map(|p| p.1);
        rebuilt.push(t.elapsed().as_secs_f64());
        let t = Instant::now();
        if !planner.as_mut().is_some_and(|p| p.retarget(robot, goal)) {
            builds += 1;
            planner = Some(WorldPlanner::new(robot, goal, &cfg));
        }
        let p = planner.as_mut().expect("kept or built");
        p.apply_costmap(&h, &c);
        let got = p.plan(robot).ok().map(|p| p.1);
        kept.push(t.elapsed().as_secs_f64());
        // Both plans are kept from the optimiser; they may differ (the kept
        // grid also remembers cells behind the window).
        std::hint::black_box((want, got));
    }
    let (r, k) = (median_ms(rebuilt), median_ms(kept));
    println!("| guided goal moved: new planner + first search | {r:.2} | LRN's heading as D* Lite's goal, 121x121 fused window, 30 m margin, robot 0.5 m a frame: what each frame cost before |");
    println!(
        "| guided goal moved: retarget + search | {k:.2} | the grid kept while the goal is 15 m inside it ({builds} grids in {frames} frames); {:.1}x less |",
        r / k.max(1e-9)
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_crates_astar_finds_the_planners_path_cost_on_the_same_grid() {
        let mut rng = SplitMix64::new(3);
        let mut grid = CostGrid::new(60, 60, 1.0, 1.0);
        for y in 0..60 {
            for x in 0..60 {
                let c = if rng.unit() < 0.15 {
                    f32::INFINITY
                } else {
                    (0.2 + 2.0 * rng.unit()) as f32
                };
                grid.set(x, y, c);
            }
        }
        let (start, goal) = ((2, 30), (57, 30));
        grid.set(start.0, start.1, 1.0);
        grid.set(goal.0, goal.1, 1.0);
        let ours = astar(&grid, start, goal, 0.2).expect("a way across").1;
        let theirs =
            pathfinding_astar(&grid, start, goal, 0.2).expect("the same way") as f64 / MICROS;
        // Edges rounded to the microsecond: at most a microsecond per step apart.
        assert!((ours - theirs).abs() < 1e-4, "{ours} vs {theirs}");
        // A walled-off goal: neither finds a way.
        for y in 0..60 {
            grid.set(50, y, f32::INFINITY);
        }
        assert!(pathfinding_astar(&grid, start, goal, 0.2).is_none());
    }
}
