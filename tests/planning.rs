//! FITAM's claim on a constructed world (Fig. 1): a road 60 m to the side of
//! the straight line to the goal, behind forest. Near-field sensing alone
//! (25 m) never sees it, so the "no far-field" baseline ploughs through the
//! forest; with ground-truth far-field observations the planner finds the
//! road and the drive costs less.
//!
//! The loop is FITAM's sense-plan-act evaluation: far-field observe + Kalman
//! update, fix the near-field cells, repair D* Lite with the changed cells,
//! drive along the path until 10 m travelled or the next cell was not seen
//! by near-field sensing, repeat. Library code only: the fused map of
//! `farsight-costmap-fusion` and the D* Lite of `farsight-subgoal-selection`.

use farsight_costmap_fusion::grid::cell_of;
use farsight_costmap_fusion::kalman::FarFieldConfig;
use farsight_costmap_fusion::map::FusionMap;
use farsight_costmap_fusion::swath::{for_each_swath_cell, PolarGeometry};
use farsight_interfaces::msg::PolarCell;
use farsight_subgoal_selection::dstar_lite::{CostGrid, DStarLite};

/// FITAM's speed classes: 0.5, 2.25, 4.25 m/s.
const CLASS_COST: [f32; 3] = [2.0, 1.0 / 2.25, 1.0 / 4.25];
const FOREST: u8 = 0;
const ROAD: u8 = 2;
const SIZE: usize = 240;
const NEAR_RANGE_M: f64 = 25.0;

/// The world: forest, with a road north-south 60 m east of the start and a
/// road west to the goal along its row.
fn road_forest() -> Vec<u8> {
    let mut w = vec![FOREST; SIZE * SIZE];
    for y in 0..SIZE {
        for x in 178..=182 {
            w[y * SIZE + x] = ROAD;
        }
    }
    for y in 218..=222 {
        for x in 120..=182 {
            w[y * SIZE + x] = ROAD;
        }
    }
    w
}

fn class_at(world: &[u8], x: i64, y: i64) -> Option<u8> {
    (x >= 0 && y >= 0 && (x as usize) < SIZE && (y as usize) < SIZE)
        .then(|| world[y as usize * SIZE + x as usize])
}

/// Ground-truth far-field labels (FITAM section IV-B): per swath, the
/// cheapest class covering at least rho_class = 0.2 of it.
fn ground_truth_bins(world: &[u8], g: &PolarGeometry, x: f64, y: f64, yaw: f64) -> Vec<PolarCell> {
    let radial = g.radial_bins();
    let mut counts = vec![[0usize; 3]; g.heading_bins * radial];
    for_each_swath_cell(g, x, y, yaw, 1.0, |gx, gy, h, r| {
        if let Some(c) = class_at(world, gx, gy) {
            counts[h * radial + r][c as usize] += 1;
        }
    });
    counts
        .iter()
        .map(|n| {
            let total: usize = n.iter().sum();
            let mut by_cost: Vec<usize> = (0..3).collect();
            by_cost.sort_by(|&a, &b| CLASS_COST[a].total_cmp(&CLASS_COST[b]));
            match by_cost
                .into_iter()
                .find(|&c| total > 0 && n[c] * 5 >= total)
            {
                Some(c) => PolarCell {
                    cost_s_per_m: CLASS_COST[c],
                    variance: 0.1,
                    class_id: c as u32,
                    probability: 0.9,
                },
                None => PolarCell {
                    cost_s_per_m: f32::NAN,
                    variance: f32::INFINITY,
                    class_id: u32::MAX,
                    probability: 0.0,
                },
            }
        })
        .collect()
}

struct Drive {
    reached: bool,
    cost_s: f64,
    road_cells: usize,
    cells: usize,
}

fn drive(world: &[u8], use_far_field: bool) -> Drive {
    let geometry = PolarGeometry::fitam_default();
    let cfg = FarFieldConfig::default();
    let mut map = FusionMap::new(201, 201, 1.0, cfg);
    let (mut pos, goal) = ((120usize, 20usize), (120usize, 220usize));
    let mut planner = DStarLite::new(
        CostGrid::new(SIZE, SIZE, 1.0, cfg.unknown_cost_s_per_m),
        pos,
        goal,
        CLASS_COST[2] as f64,
    );
    let mut yaw = std::f64::consts::FRAC_PI_2;
    let mut out = Drive {
        reached: false,
        cost_s: 0.0,
        road_cells: 0,
        cells: 0,
    };
    for _ in 0..200 {
        let (x, y) = (pos.0 as f64, pos.1 as f64);
        map.recenter(x, y);
        if use_far_field {
            map.observe_far_field(
                &geometry,
                &ground_truth_bins(world, &geometry, x, y, yaw),
                x,
                y,
                yaw,
            );
            map.add_process_noise();
        }
        let n = NEAR_RANGE_M as i64;
        for dy in -n..=n {
            for dx in -n..=n {
                if ((dx * dx + dy * dy) as f64).sqrt() <= NEAR_RANGE_M {
                    let (gx, gy) = (pos.0 as i64 + dx, pos.1 as i64 + dy);
                    if let Some(c) = class_at(world, gx, gy) {
                        map.fix_local(gx, gy, CLASS_COST[c as usize]);
                    }
                }
            }
        }
        // Hand D* Lite only the cells whose planning cost changed.
        for gy in 0..SIZE {
            for gx in 0..SIZE {
                let c = map
                    .planning_cost(gx as i64, gy as i64, use_far_field)
                    .unwrap_or(cfg.unknown_cost_s_per_m);
                planner.set_cost(gx, gy, c);
            }
        }
        planner.compute().expect("a path exists");
        let path = planner.path();
        let mut travelled = 0.0;
        for w in path.windows(2) {
            let next = w[1];
            if map.local_cost(next.0 as i64, next.1 as i64).is_none() || travelled >= 10.0 {
                break;
            }
            let step = ((w[0].0.abs_diff(next.0) + w[0].1.abs_diff(next.1)) as f64).min(2.0);
            let len = if step > 1.0 {
                std::f64::consts::SQRT_2
            } else {
                1.0
            };
            let class = class_at(world, next.0 as i64, next.1 as i64).unwrap();
            out.cost_s += CLASS_COST[class as usize] as f64 * len;
            out.road_cells += (class == ROAD) as usize;
            out.cells += 1;
            travelled += len;
            yaw = (next.1 as f64 - pos.1 as f64).atan2(next.0 as f64 - pos.0 as f64);
            pos = next;
        }
        planner.move_start(pos);
        if pos == goal {
            out.reached = true;
            break;
        }
    }
    out
}

#[test]
fn far_field_finds_the_road_behind_the_forest() {
    let world = road_forest();
    let base = drive(&world, false);
    let fitam = drive(&world, true);
    eprintln!(
        "no far-field: {:.0} s over {} cells ({} road); far-field: {:.0} s over {} cells ({} road)",
        base.cost_s, base.cells, base.road_cells, fitam.cost_s, fitam.cells, fitam.road_cells
    );
    assert!(base.reached && fitam.reached);
    assert!(
        fitam.road_cells * 2 > fitam.cells,
        "the far-field route mostly uses the road: {} of {} cells",
        fitam.road_cells,
        fitam.cells
    );
    assert!(
        fitam.cost_s < 0.8 * base.cost_s,
        "far-field {:.0} s vs no far-field {:.0} s",
        fitam.cost_s,
        base.cost_s
    );
}
