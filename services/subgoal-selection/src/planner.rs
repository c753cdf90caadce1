//! D* Lite on the fused costmap in the world frame, for the subgoal stage
//! (FITAM section IV-E). The planning grid is fixed in the world: it covers
//! the start and the goal with a margin, so the incremental search survives
//! the costmap window scrolling with the robot. Cells the costmap has never
//! covered plan at the unknown cost; each costmap message hands D* Lite only
//! the cells whose cost changed.
//!
//! ```
//! use farsight_subgoal_selection::planner::{WorldPlanner, WorldPlannerConfig};
//!
//! let cfg = WorldPlannerConfig::default();
//! let mut p = WorldPlanner::new([0.0, 0.0], [30.0, 0.0], &cfg);
//! let (path, cost_s) = p.plan([0.0, 0.0]).unwrap();
//! assert_eq!(path.last(), Some(&[30.0, 0.0]));
//! assert!((cost_s - 30.0).abs() < 1e-9); // 30 m at the unknown cost, 1 s/m
//! ```

use crate::dstar_lite::{CostGrid, DStarLite};
use farsight_interfaces::msg::{CostCell, CostmapHeader};
use farsight_stage::{Range, Ranges, Validate};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct WorldPlannerConfig {
    pub resolution_m: f64,
    /// Room around the start-goal box, metres.
    pub margin_m: f64,
    /// Cost of never-seen cells (FITAM: 1 s/m).
    pub unknown_cost_s_per_m: f32,
    /// The cheapest cost any cell can have; scales the heuristic (FITAM's
    /// fastest class, 4.25 m/s, is 0.235 s/m; a road in its worlds is 0.2).
    pub min_cost_s_per_m: f64,
    /// The largest grid side, cells (memory bound: g, rhs and cost per cell).
    pub max_side_cells: usize,
    /// Lethal cells block every cell within this distance too (centre to
    /// centre): the robot's radius plus slack, where the robot's centre
    /// cannot go. With 1 m cells anything under 1 m blocks only the lethal
    /// cell itself: a neighbour's centre is 0.5 m from its edge, room for
    /// the simulator's 0.4 m radius. Diagonal steps past a blocked cell's
    /// corner are blocked by the planner itself.
    pub inscribed_radius_m: f64,
    /// Cells within this distance of a lethal cell cost at least
    /// `inflation_cost_s_per_m`: allowed but dear, as Nav2's inflation layer
    /// and the simulator's expert. The path keeps clear of obstacles where
    /// open ground is near (carrot tracking cuts the inside of turns), yet
    /// a forest whose gaps are only a cell wide stays passable. Blocking
    /// this margin instead sealed goals in dense forest (issue 20: 68% of
    /// forest cells blocked, "no path" while the true world was open).
    pub inflation_radius_m: f64,
    /// The least cost of a cell within `inflation_radius_m` of a lethal
    /// one (the expert's 4 s/m: a detour up to four times as long as the
    /// squeeze is preferred).
    pub inflation_cost_s_per_m: f32,
    /// What the planner remembers: `"world"` keeps every cell a costmap
    /// ever gave (FITAM's map with memory); `"costmap"` forgets a cell as
    /// soon as the latest costmap no longer covers it, so the plan knows
    /// only the local map and the unknown cost beyond (LRN section IV's
    /// myopic local stack: Spot's fixed 16 m local map).
    pub memory: PlannerMemory,
}

/// What a [`WorldPlanner`] remembers of past costmaps.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PlannerMemory {
    /// Every cell ever observed keeps its last cost.
    #[default]
    World,
    /// Only the latest costmap's cells; the rest is unknown.
    Costmap,
}

impl Default for WorldPlannerConfig {
    fn default() -> Self {
        Self {
            resolution_m: 1.0,
            margin_m: 100.0,
            unknown_cost_s_per_m: 1.0,
            min_cost_s_per_m: 0.2,
            max_side_cells: 4000,
            inscribed_radius_m: 0.5,
            inflation_radius_m: 1.5,
            inflation_cost_s_per_m: 4.0,
            memory: PlannerMemory::World,
        }
    }
}

impl Validate for WorldPlannerConfig {
    fn ranges(&self, r: &mut Ranges) {
        let cost = Range::above_to(0.0, 1000.0).unit("s/m");
        r.key(
            "resolution_m",
            self.resolution_m,
            Range::above_to(0.0, 100.0).unit("m"),
        )
        .key(
            "margin_m",
            self.margin_m,
            Range::between(0.0, 10_000.0).unit("m"),
        )
        .key("unknown_cost_s_per_m", self.unknown_cost_s_per_m, cost)
        .key("min_cost_s_per_m", self.min_cost_s_per_m, cost)
        .key(
            "max_side_cells",
            self.max_side_cells,
            Range::between(10.0, 20_000.0),
        )
        .key(
            "inscribed_radius_m",
            self.inscribed_radius_m,
            Range::between(0.0, 10.0).unit("m"),
        )
        .key(
            "inflation_radius_m",
            self.inflation_radius_m,
            Range::between(0.0, 10.0).unit("m"),
        )
        .key("inflation_cost_s_per_m", self.inflation_cost_s_per_m, cost);
    }
}

/// Why a plan could not be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlanError {
    #[error("the robot at ({0:.1}, {1:.1}) m is outside the planning grid")]
    OutsideGrid(f64, f64),
    #[error("no path to the goal: every way is blocked")]
    NoPath,
}

pub struct WorldPlanner {
    /// World coordinates of the centre of cell (0, 0).
    origin_m: [f64; 2],
    resolution_m: f64,
    /// Room kept round the start and the goal; [`Self::retarget`] keeps
    /// the grid while both stay half of it inside.
    margin_m: f64,
    goal_m: [f64; 2],
    dstar: DStarLite,
    /// Costs as the costmap gave them, before inflation.
    base: Vec<f32>,
    /// Per cell: lethal base cells within the inflation radius.
    lethal_near: Vec<u32>,
    /// Per cell: lethal base cells within the inscribed radius; `None` when
    /// that radius reaches no neighbour (a lethal cell blocks only itself).
    lethal_inscribed: Option<Vec<u32>>,
    /// Cell offsets within the inflation radius (the cell itself included),
    /// each with whether it is within the inscribed radius too.
    disk: Vec<(i64, i64, bool)>,
    inflation_cost_s_per_m: f32,
    unknown_cost_s_per_m: f32,
    memory: PlannerMemory,
    /// With [`PlannerMemory::Costmap`]: the cells the latest costmap gave,
    /// and a mark per cell for the one being applied.
    covered: Vec<usize>,
    marked: Vec<bool>,
}

impl WorldPlanner {
    /// A grid around `start_m` and `goal_m` (world ENU metres); if the pair is
    /// too far apart for `max_side_cells`, the grid is centred between them
    /// and the goal is clamped into it (the robot heads for its edge first).
    pub fn new(start_m: [f64; 2], goal_m: [f64; 2], cfg: &WorldPlannerConfig) -> Self {
        let r = cfg.resolution_m;
        let lo = [
            start_m[0].min(goal_m[0]) - cfg.margin_m,
            start_m[1].min(goal_m[1]) - cfg.margin_m,
        ];
        let hi = [
            start_m[0].max(goal_m[0]) + cfg.margin_m,
            start_m[1].max(goal_m[1]) + cfg.margin_m,
        ];
        // Clamped in f64: a far goal must not overflow the cell count.
        let side = |a: f64, b: f64| {
            (((b - a) / r).ceil() + 1.0).clamp(2.0, cfg.max_side_cells as f64) as usize
        };
        let (w, h) = (side(lo[0], hi[0]), side(lo[1], hi[1]));
        let mid = [(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0];
        let origin_m = [
            ((mid[0] - (w as f64 - 1.0) * r / 2.0) / r).round() * r,
            ((mid[1] - (h as f64 - 1.0) * r / 2.0) / r).round() * r,
        ];
        let to_cell = |p: [f64; 2]| {
            (
                (((p[0] - origin_m[0]) / r).round().max(0.0) as usize).min(w - 1),
                (((p[1] - origin_m[1]) / r).round().max(0.0) as usize).min(h - 1),
            )
        };
        let grid = CostGrid::new(w, h, r, cfg.unknown_cost_s_per_m);
        let dstar = DStarLite::new(
            grid,
            to_cell(start_m),
            to_cell(goal_m),
            cfg.min_cost_s_per_m,
        );
        let outer_m = cfg.inflation_radius_m.max(cfg.inscribed_radius_m);
        let k = (outer_m / r).floor() as i64;
        let disk: Vec<(i64, i64, bool)> = (-k..=k)
            .flat_map(|dy| (-k..=k).map(move |dx| (dx, dy)))
            .filter_map(|(dx, dy)| {
                let d_m = ((dx * dx + dy * dy) as f64).sqrt() * r;
                (d_m <= outer_m + 1e-9).then_some((dx, dy, d_m <= cfg.inscribed_radius_m + 1e-9))
            })
            .collect();
        let inscribed_reaches_out = disk.iter().any(|&(dx, dy, i)| i && (dx, dy) != (0, 0));
        Self {
            origin_m,
            resolution_m: r,
            margin_m: cfg.margin_m,
            goal_m,
            dstar,
            base: vec![cfg.unknown_cost_s_per_m; w * h],
            lethal_near: vec![0; w * h],
            lethal_inscribed: inscribed_reaches_out.then(|| vec![0; w * h]),
            disk,
            inflation_cost_s_per_m: cfg.inflation_cost_s_per_m,
            unknown_cost_s_per_m: cfg.unknown_cost_s_per_m,
            memory: cfg.memory,
            covered: Vec::new(),
            marked: match cfg.memory {
                PlannerMemory::World => Vec::new(),
                PlannerMemory::Costmap => vec![false; w * h],
            },
        }
    }

    pub fn goal_m(&self) -> [f64; 2] {
        self.goal_m
    }

    /// Moves the goal to `goal_m` on this grid, if the robot at `robot_m`
    /// and the goal both stay at least half the margin inside it (room to
    /// plan round what lies between); `false` when a new grid is needed.
    /// The grid keeps every cost it holds (with world memory, everything
    /// seen so far); only the search starts over. A guide moves the goal
    /// every frame: building a grid each time cost a fresh allocation and
    /// every costmap cell again, and forgot what the robot had seen.
    pub fn retarget(&mut self, robot_m: [f64; 2], goal_m: [f64; 2]) -> bool {
        let g = self.dstar.grid();
        let room = (self.margin_m / 2.0 / self.resolution_m).floor() as usize;
        let inside = |p: [f64; 2]| {
            self.cell(p).is_some_and(|(x, y)| {
                x >= room && y >= room && x + room < g.width && y + room < g.height
            })
        };
        if !inside(robot_m) || !inside(goal_m) {
            return false;
        }
        let goal = self.cell(goal_m).expect("inside the grid");
        self.goal_m = goal_m;
        self.dstar.retarget(goal);
        true
    }

    /// Whether world point `p_m` is on the planning grid.
    pub fn contains(&self, p_m: [f64; 2]) -> bool {
        self.cell(p_m).is_some()
    }

    fn cell(&self, p: [f64; 2]) -> Option<(usize, usize)> {
        Some((self.axis_cell(p[0], 0)?, self.axis_cell(p[1], 1)?))
    }

    /// The grid column (`axis` 0) or row (1) holding world coordinate `m`.
    fn axis_cell(&self, m: f64, axis: usize) -> Option<usize> {
        let g = self.dstar.grid();
        let len = [g.width, g.height][axis];
        let k = ((m - self.origin_m[axis]) / self.resolution_m).round();
        (k >= 0.0 && (k as usize) < len).then_some(k as usize)
    }

    fn world(&self, c: (usize, usize)) -> [f64; 2] {
        [
            self.origin_m[0] + c.0 as f64 * self.resolution_m,
            self.origin_m[1] + c.1 as f64 * self.resolution_m,
        ]
    }

    /// Copies a costmap message into the grid; returns how many cells changed.
    /// NaN cells (never observed) are left as they are, and so is every
    /// other cell unless the planner remembers only the latest costmap
    /// ([`PlannerMemory::Costmap`]): then the cells it does not cover go
    /// back to the unknown cost.
    pub fn apply_costmap(&mut self, header: &CostmapHeader, cells: &[CostCell]) -> usize {
        let w = self.dstar.grid().width;
        let forget = self.memory == PlannerMemory::Costmap;
        let mut touched = Vec::new();
        let mut covered = Vec::new();
        // A message cell's grid column depends only on its column and its
        // grid row only on its row: each is worked out once, not per cell.
        let row_len = (header.width as usize).max(1);
        let cells = &cells[..header.cell_count().min(cells.len())];
        let columns: Vec<Option<usize>> = (0..row_len.min(cells.len()))
            .map(|j| self.axis_cell(header.cell_centre_m(j)[0], 0))
            .collect();
        for (i, row) in cells.chunks(row_len).enumerate() {
            let Some(y) = self.axis_cell(header.cell_centre_m(i * row_len)[1], 1) else {
                continue;
            };
            for (c, &x) in row.iter().zip(&columns) {
                let Some(x) = x else { continue };
                if c.cost_s_per_m.is_nan() {
                    continue;
                }
                if forget {
                    self.marked[y * w + x] = true;
                    covered.push(y * w + x);
                }
                self.set_base(x, y, c.cost_s_per_m, &mut touched);
            }
        }
        if forget {
            let unknown = self.unknown_cost_s_per_m;
            for i in std::mem::take(&mut self.covered) {
                if !self.marked[i] {
                    self.set_base(i % w, i / w, unknown, &mut touched);
                }
            }
            for &i in &covered {
                self.marked[i] = false;
            }
            self.covered = covered;
        }
        let (base, near, inscribed) = (&self.base, &self.lethal_near, &self.lethal_inscribed);
        let dear = self.inflation_cost_s_per_m;
        self.dstar.set_costs(touched.into_iter().map(|(x, y)| {
            let i = y * w + x;
            let effective = if inscribed.as_ref().is_some_and(|l| l[i] > 0) {
                f32::INFINITY
            } else if near[i] > 0 && base[i] >= 0.0 {
                // A negative cost is blocked already and stays so.
                base[i].max(dear)
            } else {
                base[i]
            };
            (x, y, effective)
        }))
    }

    /// Sets one cell's base cost and keeps the lethal counts of the cells
    /// around it; every cell whose effective cost may change is pushed to
    /// `touched`.
    fn set_base(
        &mut self,
        x: usize,
        y: usize,
        cost_s_per_m: f32,
        touched: &mut Vec<(usize, usize)>,
    ) {
        let (w, h) = (self.dstar.grid().width, self.dstar.grid().height);
        let lethal = |c: f32| c.is_infinite();
        let i = y * w + x;
        let old = std::mem::replace(&mut self.base[i], cost_s_per_m);
        if old.to_bits() == cost_s_per_m.to_bits() {
            // Neither this cell's effective cost nor any lethal count moves.
            return;
        }
        touched.push((x, y));
        if lethal(old) == lethal(cost_s_per_m) {
            return;
        }
        let count = |n: &mut u32| {
            if lethal(cost_s_per_m) {
                *n += 1;
            } else {
                *n -= 1;
            }
        };
        for &(dx, dy, inscribed) in &self.disk {
            let (nx, ny) = (x as i64 + dx, y as i64 + dy);
            if nx >= 0 && ny >= 0 && (nx as usize) < w && (ny as usize) < h {
                let j = ny as usize * w + nx as usize;
                count(&mut self.lethal_near[j]);
                if let (true, Some(l)) = (inscribed, self.lethal_inscribed.as_mut()) {
                    count(&mut l[j]);
                }
                touched.push((nx as usize, ny as usize));
            }
        }
    }

    /// A goal in a blocked cell (lethal, or within the inscribed radius of
    /// one) has no path. For a goal that is only a direction (a guide's subgoal a
    /// fixed distance out along its heading) the place to head for is the
    /// farthest free cell on the straight line from `from_m` to the goal,
    /// before the first blocked one. When that line is blocked from its
    /// first step (the robot faces a wall), it is the free cell nearest the
    /// goal, as Nav2's planners take the nearest free cell within their goal
    /// tolerance: the way round is the planner's to find. `None` when the
    /// goal's cell is free, or no cell of the grid is.
    pub fn goal_pulled_back_from_blocked(&self, from_m: [f64; 2]) -> Option<[f64; 2]> {
        let grid = self.dstar.grid();
        let blocked = |p: [f64; 2]| self.cell(p).is_none_or(|(x, y)| grid.is_blocked(x, y));
        if !blocked(self.goal_m) {
            return None;
        }
        let (dx, dy) = (self.goal_m[0] - from_m[0], self.goal_m[1] - from_m[1]);
        let n = (dx.hypot(dy) / (0.5 * self.resolution_m)).ceil() as usize;
        let mut free = None;
        for i in 1..=n {
            let t = i as f64 / n as f64;
            let p = [from_m[0] + t * dx, from_m[1] + t * dy];
            if blocked(p) {
                break;
            }
            free = Some(p);
        }
        free.or_else(|| self.nearest_free_cell(self.goal_m).map(|c| self.world(c)))
    }

    /// The free cell nearest `p_m` (Euclidean, in cells; ties to the first
    /// found, so the answer is the same every run), searched ring by ring
    /// outward from `p_m`'s cell, clamped onto the grid.
    fn nearest_free_cell(&self, p_m: [f64; 2]) -> Option<(usize, usize)> {
        let grid = self.dstar.grid();
        let (w, h) = (grid.width as i64, grid.height as i64);
        let cx = (((p_m[0] - self.origin_m[0]) / self.resolution_m).round() as i64).clamp(0, w - 1);
        let cy = (((p_m[1] - self.origin_m[1]) / self.resolution_m).round() as i64).clamp(0, h - 1);
        let mut best: Option<(i64, (usize, usize))> = None;
        for d in 0..w.max(h) {
            // Every cell of ring d is at least d away: past the best, stop.
            if best.is_some_and(|(d2, _)| d * d > d2) {
                break;
            }
            for y in (cy - d).max(0)..=(cy + d).min(h - 1) {
                let on_edge = y == cy - d || y == cy + d;
                let xs: Vec<i64> = if on_edge {
                    ((cx - d).max(0)..=(cx + d).min(w - 1)).collect()
                } else {
                    [cx - d, cx + d]
                        .into_iter()
                        .filter(|&x| x >= 0 && x < w)
                        .collect()
                };
                for x in xs {
                    let (ux, uy) = (x as usize, y as usize);
                    if grid.is_blocked(ux, uy) {
                        continue;
                    }
                    let d2 = (x - cx).pow(2) + (y - cy).pow(2);
                    if best.is_none_or(|(b, _)| d2 < b) {
                        best = Some((d2, (ux, uy)));
                    }
                }
            }
        }
        best.map(|(_, c)| c)
    }

    /// Plans from the robot at `robot_m`: the world path (cell centres, the
    /// goal itself at the end) and its cost in seconds.
    pub fn plan(&mut self, robot_m: [f64; 2]) -> Result<(Vec<[f64; 2]>, f64), PlanError> {
        let start = self
            .cell(robot_m)
            .ok_or(PlanError::OutsideGrid(robot_m[0], robot_m[1]))?;
        self.dstar.move_start(start);
        let cost = self.dstar.compute().ok_or(PlanError::NoPath)?;
        let mut path: Vec<[f64; 2]> = self
            .dstar
            .path()
            .into_iter()
            .map(|c| self.world(c))
            .collect();
        if let Some(last) = path.last_mut() {
            if self.cell(self.goal_m) == Some(self.dstar.goal()) {
                *last = self.goal_m;
            }
        }
        Ok((path, cost))
    }

    /// Expanded vertices so far (incremental repairs stay small).
    pub fn expanded(&self) -> usize {
        self.dstar.expanded
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use farsight_interfaces::msg::{CostmapLayer, Stamp};

    #[test]
    fn the_grid_spans_start_and_goal_with_the_margin_and_nothing_beyond() {
        let cfg = WorldPlannerConfig {
            margin_m: 10.0,
            ..Default::default()
        };
        let pl = WorldPlanner::new([0.0, 0.0], [50.0, 0.0], &cfg);
        assert!(pl.contains([0.0, 0.0]) && pl.contains([50.0, 0.0]));
        assert!(pl.contains([-9.0, 9.0]) && pl.contains([59.0, -9.0]));
        assert!(!pl.contains([-20.0, 0.0]) && !pl.contains([25.0, 30.0]));
    }

    #[test]
    fn each_costmap_cell_lands_where_its_centre_is_even_half_off_the_grid() {
        // A 0.5 m message over a 1 m grid, hanging off its north-west
        // corner, with a short payload (the last row cut): every cell goes
        // to the grid cell its centre rounds to, the last one written
        // wins, and nothing outside the grid or past the payload is read.
        let cfg = WorldPlannerConfig {
            margin_m: 5.0,
            inflation_radius_m: 0.0,
            ..Default::default()
        };
        let mut p = WorldPlanner::new([0.0, 0.0], [10.0, 0.0], &cfg);
        let header = CostmapHeader {
            stamp: Stamp::default(),
            layer: CostmapLayer::FUSED,
            width: 13,
            height: 9,
            resolution_m: 0.5,
            x_min_m: -7.3,
            y_max_m: 6.2,
        };
        let cells: Vec<CostCell> = (0..13 * 9 - 5)
            .map(|k| CostCell {
                cost_s_per_m: 1.0 + k as f32,
                variance: 0.0,
            })
            .collect();
        let mut want = std::collections::BTreeMap::new();
        for (k, c) in cells.iter().enumerate() {
            if let Some(at) = p.cell(header.cell_centre_m(k)) {
                want.insert(at, c.cost_s_per_m);
            }
        }
        assert!(want.len() > 10, "some cells land on the grid");
        p.apply_costmap(&header, &cells);
        let w = p.dstar.grid().width;
        for y in 0..p.dstar.grid().height {
            for x in 0..w {
                let expected = want
                    .get(&(x, y))
                    .copied()
                    .unwrap_or(cfg.unknown_cost_s_per_m);
                assert_eq!(p.base[y * w + x], expected, "cell ({x}, {y})");
                assert_eq!(p.dstar.grid().get(x, y), expected, "cell ({x}, {y})");
            }
        }
    }

    #[test]
    fn a_wall_in_a_costmap_message_bends_the_path() {
        let cfg = WorldPlannerConfig {
            margin_m: 10.0,
            inflation_radius_m: 0.0,
            ..Default::default()
        };
        let mut p = WorldPlanner::new([0.0, 0.0], [20.0, 0.0], &cfg);
        let (straight, _) = p.plan([0.0, 0.0]).unwrap();
        assert!(straight.iter().all(|q| q[1].abs() < 1e-9));
        // A lethal wall x = 10, y in -5..=5, as a 1 m costmap, north up.
        let header = CostmapHeader {
            stamp: Stamp::default(),
            layer: CostmapLayer::FUSED,
            width: 3,
            height: 11,
            resolution_m: 1.0,
            x_min_m: 9.0,
            y_max_m: 5.0,
        };
        let cells: Vec<CostCell> = (0..33)
            .map(|k| CostCell {
                cost_s_per_m: if k % 3 == 1 { f32::INFINITY } else { f32::NAN },
                variance: 0.0,
            })
            .collect();
        assert_eq!(p.apply_costmap(&header, &cells), 11);
        let (around, cost) = p.plan([0.0, 0.0]).unwrap();
        assert!(
            around.iter().all(|q| q[0] != 10.0 || q[1].abs() > 5.0),
            "{around:?}"
        );
        assert!(cost > 20.0);
        assert_eq!(around.last(), Some(&[20.0, 0.0]));
        assert_eq!(
            p.plan([500.0, 0.0]),
            Err(PlanError::OutsideGrid(500.0, 0.0))
        );
    }

    #[test]
    fn a_retargeted_goal_keeps_the_grid_and_the_wall_it_remembers() {
        let cfg = WorldPlannerConfig {
            margin_m: 10.0,
            inflation_radius_m: 0.0,
            ..Default::default()
        };
        // The grid spans x -10..=30, y -10..=10; a lethal wall x = 10,
        // y in -5..=5, seen once.
        let mut p = WorldPlanner::new([0.0, 0.0], [20.0, 0.0], &cfg);
        let header = CostmapHeader {
            stamp: Stamp::default(),
            layer: CostmapLayer::FUSED,
            width: 1,
            height: 11,
            resolution_m: 1.0,
            x_min_m: 9.5,
            y_max_m: 5.0,
        };
        let wall = vec![
            CostCell {
                cost_s_per_m: f32::INFINITY,
                variance: 0.0,
            };
            11
        ];
        p.apply_costmap(&header, &wall);
        p.plan([0.0, 0.0]).unwrap();
        // The goal moves within the grid: the wall still bends the path to it.
        assert!(p.retarget([0.0, 0.0], [20.0, 3.0]));
        assert_eq!(p.goal_m(), [20.0, 3.0]);
        let (around, cost) = p.plan([0.0, 0.0]).unwrap();
        assert_eq!(around.last(), Some(&[20.0, 3.0]));
        assert!(
            around.iter().all(|q| q[0] != 10.0 || q[1].abs() > 5.0),
            "{around:?}"
        );
        let fresh = WorldPlanner::new([0.0, 0.0], [20.0, 3.0], &cfg).plan([0.0, 0.0]);
        assert!(
            cost > fresh.unwrap().1 + 1.0,
            "the open grid's path is shorter"
        );
        // Within half the margin (5 m) of an edge, or off the grid: no.
        assert!(!p.retarget([0.0, 0.0], [27.0, 0.0]));
        assert!(!p.retarget([0.0, 0.0], [20.0, 40.0]));
        assert!(!p.retarget([-8.0, 0.0], [20.0, 0.0]));
        assert_eq!(p.goal_m(), [20.0, 3.0], "a refused goal changes nothing");
        assert!(p.retarget([-5.0, 0.0], [25.0, 5.0]));
    }

    #[test]
    fn a_myopic_planner_forgets_a_wall_its_local_map_has_scrolled_past() {
        // A 5x11 local map (1 m), centred on x: the wall x = 10, y in -5..=5
        // while the map is at x = 10; open ground once it has moved to x = 4.
        let local = |centre_x: f64| {
            let header = CostmapHeader {
                stamp: Stamp::default(),
                layer: CostmapLayer::FUSED,
                width: 5,
                height: 11,
                resolution_m: 1.0,
                x_min_m: centre_x - 2.0,
                y_max_m: 5.0,
            };
            let cells: Vec<CostCell> = (0..55)
                .map(|k| {
                    let x = header.cell_centre_m(k)[0];
                    CostCell {
                        cost_s_per_m: if (x - 10.0).abs() < 0.1 {
                            f32::INFINITY
                        } else {
                            0.5
                        },
                        variance: 0.0,
                    }
                })
                .collect();
            (header, cells)
        };
        let plan_after = |memory: PlannerMemory| {
            let cfg = WorldPlannerConfig {
                margin_m: 10.0,
                inflation_radius_m: 0.0,
                memory,
                ..Default::default()
            };
            let mut p = WorldPlanner::new([0.0, 0.0], [20.0, 0.0], &cfg);
            for x in [10.0, 4.0] {
                let (h, c) = local(x);
                p.apply_costmap(&h, &c);
            }
            p.plan([0.0, 0.0]).unwrap()
        };
        let (remembered, _) = plan_after(PlannerMemory::World);
        assert!(
            remembered.iter().any(|q| q[1].abs() > 5.0),
            "with memory the path goes round the wall: {remembered:?}"
        );
        let (forgotten, cost) = plan_after(PlannerMemory::Costmap);
        assert!(
            forgotten.iter().all(|q| q[1].abs() < 1e-9),
            "the wall left the local map: straight on {forgotten:?}"
        );
        // Cells 2..=6 seen as grass (0.5 s/m), the other 15 steps unknown
        // (1 s/m).
        assert!((cost - (5.0 * 0.5 + 15.0 * 1.0)).abs() < 1e-6, "{cost}");
        assert_eq!(
            farsight_stage::parse_config::<crate::stage::SubgoalStageConfig>(
                "[planner]\nmemory = \"costmap\"",
                "t.toml"
            )
            .unwrap()
            .planner
            .memory,
            PlannerMemory::Costmap
        );
    }

    #[test]
    fn a_goal_inside_an_obstacle_is_pulled_back_to_the_free_ground_before_it() {
        let cfg = WorldPlannerConfig {
            margin_m: 10.0,
            inscribed_radius_m: 1.0,
            inflation_radius_m: 1.0,
            ..Default::default()
        };
        // A lethal block x = 8..=12 across y = -2..=2; the goal in its middle.
        let header = CostmapHeader {
            stamp: Stamp::default(),
            layer: CostmapLayer::FUSED,
            width: 5,
            height: 5,
            resolution_m: 1.0,
            x_min_m: 7.5,
            y_max_m: 2.5,
        };
        let cells = vec![
            CostCell {
                cost_s_per_m: f32::INFINITY,
                variance: 0.0,
            };
            25
        ];
        let mut p = WorldPlanner::new([0.0, 0.0], [10.0, 0.0], &cfg);
        assert_eq!(
            p.goal_pulled_back_from_blocked([0.0, 0.0]),
            None,
            "nothing seen yet"
        );
        p.apply_costmap(&header, &cells);
        assert_eq!(p.plan([0.0, 0.0]), Err(PlanError::NoPath));
        // The block starts at x = 8, its inscribed margin at x = 7: the last free
        // point on the line is short of 6.5 m (the cell boundary).
        let g = p.goal_pulled_back_from_blocked([0.0, 0.0]).unwrap();
        assert!(g[1] == 0.0 && g[0] > 5.5 && g[0] < 6.5, "{g:?}");
        let mut q = WorldPlanner::new([0.0, 0.0], g, &cfg);
        q.apply_costmap(&header, &cells);
        assert!(q.plan([0.0, 0.0]).is_ok());
        // A free goal stays where it is.
        let free = WorldPlanner::new([0.0, 0.0], [5.0, 0.0], &cfg);
        assert_eq!(free.goal_pulled_back_from_blocked([0.0, 0.0]), None);
    }

    #[test]
    fn facing_a_wall_the_goal_behind_it_becomes_the_free_cell_nearest_it() {
        let cfg = WorldPlannerConfig {
            margin_m: 10.0,
            inscribed_radius_m: 1.0,
            inflation_radius_m: 1.0,
            ..Default::default()
        };
        // A wall x = 1..=3, y = -5..=5 right in front of the robot at the
        // origin (its inscribed margin reaches x = 0: the line is blocked from its
        // first step), the goal in it at x = 3.
        let header = CostmapHeader {
            stamp: Stamp::default(),
            layer: CostmapLayer::FUSED,
            width: 3,
            height: 11,
            resolution_m: 1.0,
            x_min_m: 1.0,
            y_max_m: 5.0,
        };
        let cells = vec![
            CostCell {
                cost_s_per_m: f32::INFINITY,
                variance: 0.0,
            };
            3 * 11
        ];
        let mut p = WorldPlanner::new([0.0, 0.0], [3.0, 0.0], &cfg);
        p.apply_costmap(&header, &cells);
        assert_eq!(p.plan([0.0, 0.0]), Err(PlanError::NoPath));
        // The inscribed margin ends at x = 4: behind the wall, 2 m from the goal
        // (before it, x = -1, is 4 m; past its ends, 6 m).
        let g = p.goal_pulled_back_from_blocked([0.0, 0.0]).unwrap();
        assert_eq!(g, [5.0, 0.0]);
        let mut q = WorldPlanner::new([0.0, 0.0], g, &cfg);
        q.apply_costmap(&header, &cells);
        let (path, _) = q.plan([0.0, 0.0]).unwrap();
        assert!(
            path.iter().any(|c| c[1].abs() > 6.0),
            "round an end of the wall: {path:?}"
        );
        // Nothing free at all: no goal.
        let mut all = WorldPlanner::new([0.0, 0.0], [3.0, 0.0], &cfg);
        let (w, h) = (all.dstar.grid().width, all.dstar.grid().height);
        all.dstar
            .set_costs((0..h).flat_map(|y| (0..w).map(move |x| (x, y, f32::INFINITY))));
        assert_eq!(all.goal_pulled_back_from_blocked([0.0, 0.0]), None);
    }

    #[test]
    fn inflation_keeps_the_path_a_radius_away_and_clears_with_the_obstacle() {
        let cfg = WorldPlannerConfig {
            margin_m: 10.0,
            inflation_radius_m: 1.5,
            ..Default::default()
        };
        let mut p = WorldPlanner::new([0.0, 0.0], [20.0, 0.0], &cfg);
        // One rock at (10, 0), as a 1x1 costmap.
        let header = CostmapHeader {
            width: 1,
            height: 1,
            resolution_m: 1.0,
            x_min_m: 10.0,
            y_max_m: 0.0,
            ..Default::default()
        };
        let cell = |c: f32| {
            [CostCell {
                cost_s_per_m: c,
                variance: 0.0,
            }]
        };
        p.apply_costmap(&header, &cell(f32::INFINITY));
        let (path, _) = p.plan([0.0, 0.0]).unwrap();
        let clearance = path
            .iter()
            .map(|q| (q[0] - 10.0).hypot(q[1]))
            .fold(f64::INFINITY, f64::min);
        assert!(
            clearance > 1.5,
            "passes {clearance} m from the rock: {path:?}"
        );
        // The rock turns out to be a shadow: the inflated cells clear too.
        p.apply_costmap(&header, &cell(1.0));
        let (path, cost) = p.plan([0.0, 0.0]).unwrap();
        assert!(path.iter().all(|q| q[1] == 0.0), "straight again: {path:?}");
        assert!((cost - 20.0).abs() < 1e-9);
    }
    /// A 1 m costmap message from a list of lethal cells over a free square.
    fn lethal_cells_message(
        x_min_m: f64,
        y_max_m: f64,
        side: usize,
        lethal: &[(f64, f64)],
    ) -> (CostmapHeader, Vec<CostCell>) {
        let header = CostmapHeader {
            width: side as u32,
            height: side as u32,
            resolution_m: 1.0,
            x_min_m,
            y_max_m,
            ..Default::default()
        };
        let cells = (0..side * side)
            .map(|k| {
                let c = header.cell_centre_m(k);
                let hit = lethal
                    .iter()
                    .any(|&(x, y)| (c[0] - x).abs() < 0.1 && (c[1] - y).abs() < 0.1);
                CostCell {
                    cost_s_per_m: if hit { f32::INFINITY } else { 1.0 },
                    variance: 0.0,
                }
            })
            .collect();
        (header, cells)
    }

    #[test]
    fn a_goal_ringed_by_trees_a_cell_apart_is_reachable_through_the_dear_margin() {
        // Issue 20, seed 3: trees every other cell round the goal at (10, 0)
        // (a ring of side 6 m, gaps of one 1 m cell). Blocking the 1.5 m
        // margin sealed every gap; a dear margin leaves them open at a price.
        let ring: Vec<(f64, f64)> = (-3..=3)
            .flat_map(|i| [(i, -3), (i, 3), (-3, i), (3, i)])
            .filter(|&(a, b): &(i32, i32)| (a + b) % 2 != 0)
            .map(|(a, b)| (10.0 + a as f64, b as f64))
            .collect();
        let (header, cells) = lethal_cells_message(2.0, 8.0, 17, &ring);
        let cfg = WorldPlannerConfig {
            margin_m: 10.0,
            ..Default::default()
        };
        let mut p = WorldPlanner::new([0.0, 0.0], [10.0, 0.0], &cfg);
        p.apply_costmap(&header, &cells);
        let (path, cost_s) = p.plan([0.0, 0.0]).expect("a gap in the ring");
        assert_eq!(path.last(), Some(&[10.0, 0.0]));
        assert!(
            path.iter().all(|q| !ring.contains(&(q[0], q[1]))),
            "through a tree: {path:?}"
        );
        // The gap and the cells either side of it cost 4 s/m: dearer than
        // the 10 m of open ground, and no more than a few dear cells.
        assert!(cost_s > 12.0 && cost_s < 30.0, "{cost_s} s: {path:?}");
        // The margin blocked, as before issue 20: sealed.
        let blocked = WorldPlannerConfig {
            inscribed_radius_m: 1.5,
            ..cfg
        };
        let mut q = WorldPlanner::new([0.0, 0.0], [10.0, 0.0], &blocked);
        q.apply_costmap(&header, &cells);
        assert_eq!(q.plan([0.0, 0.0]), Err(PlanError::NoPath));
    }

    #[test]
    fn a_path_keeps_out_of_the_margin_while_a_cheaper_way_round_exists() {
        // Two rocks 2 m apart across the line: the 1-cell gap between them
        // is legal but dear; the way round is 2-3 m longer and taken.
        let (header, cells) = lethal_cells_message(5.0, 5.0, 11, &[(10.0, 1.0), (10.0, -1.0)]);
        let cfg = WorldPlannerConfig {
            margin_m: 10.0,
            ..Default::default()
        };
        let mut p = WorldPlanner::new([0.0, 0.0], [20.0, 0.0], &cfg);
        p.apply_costmap(&header, &cells);
        let (path, _) = p.plan([0.0, 0.0]).unwrap();
        assert!(
            !path.contains(&[10.0, 0.0]),
            "squeezed through the gap: {path:?}"
        );
        // Dear as it is, the margin is no wall: a goal inside it is planned to.
        let mut g = WorldPlanner::new([0.0, 0.0], [10.0, 0.0], &cfg);
        g.apply_costmap(&header, &cells);
        assert_eq!(g.goal_pulled_back_from_blocked([0.0, 0.0]), None);
        assert!(g.plan([0.0, 0.0]).is_ok());
    }
}
