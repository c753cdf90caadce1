//! `farsight bench planning`: what FITAM's map and planner cost per step on
//! this machine: a far-field observation into the fused map (FITAM default
//! geometry, 201x201 window), exporting the fused layer, and D* Lite on a
//! `side` x `side` grid: the first search, a repair after the robot moves and
//! 25 cells near it change, and A* from scratch on the same changed grid.

use crate::bench::PlanningArgs;
use anyhow::Result;
use farsight_costmap_fusion::kalman::FarFieldConfig;
use farsight_costmap_fusion::map::FusionMap;
use farsight_costmap_fusion::swath::PolarGeometry;
use farsight_interfaces::msg::{CostmapLayer, PolarCell, Stamp};
use farsight_sim::rng::SplitMix64;
use farsight_subgoal_selection::dstar_lite::{astar, CostGrid, DStarLite};
use std::time::Instant;

fn median_ms(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2] * 1e3
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
    let (mut first_exp, mut repair_exp) = (0, 0);
    for _ in 0..runs {
        let mut g = grid.clone();
        let mut d = DStarLite::new(g.clone(), start, goal, 0.2);
        let t = Instant::now();
        d.compute();
        first.push(t.elapsed().as_secs_f64());
        first_exp = d.expanded;
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
    println!("| D* Lite first search | {f:.1} | {side}x{side} grid, {first_exp} expansions |");
    println!("| D* Lite repair | {r:.2} | after 25 changed cells near the robot, {repair_exp} expansions |");
    println!(
        "| A* from scratch | {s:.1} | same changed grid; repair is {:.0}x faster |",
        s / r.max(1e-9)
    );
    Ok(())
}
