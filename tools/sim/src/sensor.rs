//! The near-field sensor: FITAM's local observations, an occlusion-aware
//! costmap of the cells within 25 m. Rays every half degree walk the map
//! cell by cell from the robot; every cell a ray reaches is observed with its
//! true cost, and a ray stops two cells past the first thing taller than the
//! sensor (trees, walls, bushes, rocks, buildings), so what hides behind them
//! stays unknown.
//!
//! What an observed cell reports is the sensor's [`CostModel`]: its true cost
//! (the default, an oracle of terrain), or HIP's geometric costmap (section
//! III: a LiDAR height threshold), which errs as the paper's did: tall grass
//! looks lethal, a shrub or a stone under the threshold looks free, water
//! looks like flat ground.

use crate::world::World;
use farsight_interfaces::msg::{CostCell, CostmapHeader, CostmapLayer, Stamp};

/// What an observed cell's cost is.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum CostModel {
    /// The cell's true traversal cost.
    #[default]
    TrueCost,
    /// Lethal where whatever stands on the cell is taller than
    /// `threshold_m` above the ground, `free_cost_s_per_m` elsewhere.
    HeightThreshold {
        threshold_m: f32,
        free_cost_s_per_m: f32,
    },
}

impl CostModel {
    /// HIP's geometric costmap: a 0.5 m threshold (above the shrubs and
    /// stones, below the tall grass), grass's cost where free.
    pub const HEIGHT_THRESHOLD: CostModel = CostModel::HeightThreshold {
        threshold_m: 0.5,
        free_cost_s_per_m: 0.5,
    };

    /// `true-cost` or `height-threshold` (the `--near-field` flag's values).
    pub fn named(name: &str) -> Option<Self> {
        match name {
            "true-cost" => Some(CostModel::TrueCost),
            "height-threshold" => Some(CostModel::HEIGHT_THRESHOLD),
            _ => None,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            CostModel::TrueCost => "true-cost",
            CostModel::HeightThreshold { .. } => "height-threshold",
        }
    }

    /// The name with the model's parameters, as a benchmark's protocol
    /// records (and hashes) it: `height-threshold (0.5 m, free 0.5 s/m)`.
    pub fn describe(self) -> String {
        match self {
            CostModel::TrueCost => self.name().into(),
            CostModel::HeightThreshold {
                threshold_m,
                free_cost_s_per_m,
            } => format!(
                "{} ({threshold_m} m, free {free_cost_s_per_m} s/m)",
                self.name()
            ),
        }
    }

    /// The cost this model reports for cell (x, y) of `world`.
    pub fn cost_s_per_m(self, world: &World, x: i64, y: i64) -> f32 {
        match self {
            CostModel::TrueCost => world.cost_s_per_m(x, y),
            CostModel::HeightThreshold {
                threshold_m,
                free_cost_s_per_m,
            } => {
                if !world.contains(x, y) {
                    return f32::INFINITY;
                }
                let look = world.look(x, y);
                if look.top_m - look.ground_m > threshold_m {
                    f32::INFINITY
                } else {
                    free_cost_s_per_m
                }
            }
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NearFieldSensor {
    pub range_m: f64,
    /// Height of the sensor above the ground; anything taller occludes.
    pub height_m: f64,
    /// Cells a ray goes on past its first occluder.
    pub past_occluder_cells: u32,
    pub cost_model: CostModel,
}

impl Default for NearFieldSensor {
    fn default() -> Self {
        Self {
            range_m: 25.0,
            height_m: 0.9,
            past_occluder_cells: 2,
            cost_model: CostModel::TrueCost,
        }
    }
}

impl NearFieldSensor {
    /// A world-frame costmap around the robot at (x, y): observed cells hold
    /// their cost with variance 0, the rest NaN.
    pub fn observe(
        &self,
        world: &World,
        x_m: f64,
        y_m: f64,
        stamp: Stamp,
    ) -> (CostmapHeader, Vec<CostCell>) {
        let res = world.resolution_m;
        let half = (self.range_m / res).ceil() as i64;
        let side = (2 * half + 1) as usize;
        let (cx, cy) = world.cell_of(x_m, y_m);
        let mut cells = vec![
            CostCell {
                cost_s_per_m: f32::NAN,
                variance: f32::NAN,
            };
            side * side
        ];
        let mut mark = |gx: i64, gy: i64| {
            let (j, i) = (gx - (cx - half), (cy + half) - gy);
            if (0..side as i64).contains(&j) && (0..side as i64).contains(&i) {
                // Rays overlap near the robot: a cell's cost is worked out once.
                let cell = &mut cells[i as usize * side + j as usize];
                if cell.variance.is_nan() {
                    *cell = CostCell {
                        cost_s_per_m: self.cost_model.cost_s_per_m(world, gx, gy),
                        variance: 0.0,
                    };
                }
            }
        };
        mark(cx, cy);
        let rays = 720;
        let ground = world.ground_m(cx, cy) as f64 + self.height_m;
        for k in 0..rays {
            let a = k as f64 * std::f64::consts::TAU / rays as f64;
            let (dx, dy) = (a.cos(), a.sin());
            let (mut gx, mut gy) = (cx, cy);
            let sx = if dx >= 0.0 { 1 } else { -1 };
            let sy = if dy >= 0.0 { 1 } else { -1 };
            let (ox, oy) = (x_m - cx as f64 * res, y_m - cy as f64 * res);
            let mut tx = if dx.abs() > 1e-12 {
                ((0.5 * sx as f64) * res - ox) / dx
            } else {
                f64::INFINITY
            };
            let mut ty = if dy.abs() > 1e-12 {
                ((0.5 * sy as f64) * res - oy) / dy
            } else {
                f64::INFINITY
            };
            let (tdx, tdy) = (res / dx.abs().max(1e-12), res / dy.abs().max(1e-12));
            let mut past: Option<u32> = None;
            loop {
                let t = tx.min(ty);
                if t > self.range_m {
                    break;
                }
                if tx < ty {
                    gx += sx;
                    tx += tdx;
                } else {
                    gy += sy;
                    ty += tdy;
                }
                mark(gx, gy);
                if let Some(n) = &mut past {
                    if *n == 0 {
                        break;
                    }
                    *n -= 1;
                } else if world.look(gx, gy).top_m as f64 > ground {
                    past = Some(self.past_occluder_cells);
                }
            }
        }
        let header = CostmapHeader {
            stamp,
            layer: CostmapLayer::LOCAL,
            width: side as u32,
            height: side as u32,
            resolution_m: res as f32,
            x_min_m: (cx - half) as f64 * res,
            y_max_m: (cy + half) as f64 * res,
        };
        (header, cells)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::{Cover, Obstacle};

    #[test]
    fn sees_25_m_around_but_not_behind_a_wall() {
        let mut world = World::new(100, 100, Cover::Grass);
        world.line_obstacle((55, 40), (55, 60), Obstacle::Wall);
        let sensor = NearFieldSensor::default();
        let (h, cells) = sensor.observe(&world, 50.0, 50.0, Stamp::default());
        assert_eq!((h.width, h.height), (51, 51));
        let at = |x: f64, y: f64| cells[h.cell_index(x, y).unwrap()];
        assert_eq!(at(50.0, 70.0).cost_s_per_m, 0.5, "20 m north, in the open");
        assert!(at(55.0, 50.0).cost_s_per_m.is_infinite(), "the wall itself");
        assert!(
            !at(56.0, 50.0).cost_s_per_m.is_nan(),
            "just past it (two cells)"
        );
        assert!(
            at(65.0, 50.0).cost_s_per_m.is_nan(),
            "hidden behind the wall"
        );
        assert_eq!(
            at(50.0, 74.0).cost_s_per_m,
            0.5,
            "24 m north: still in range"
        );
        assert!(
            at(70.0, 70.0).cost_s_per_m.is_nan(),
            "28 m away: beyond range"
        );
        assert_eq!(at(50.0, 50.0).variance, 0.0);
    }

    #[test]
    fn the_height_threshold_errs_as_hips_geometric_costmap() {
        let mut world = World::new(60, 60, Cover::Grass);
        world.set_obstacle(35, 30, Obstacle::TallGrass);
        world.set_obstacle(30, 35, Obstacle::Shrub);
        world.set_obstacle(25, 30, Obstacle::Stone);
        world.set_obstacle(30, 25, Obstacle::Tree);
        world.set_cover(33, 33, Cover::Water);
        let truth = NearFieldSensor::default();
        let geometric = NearFieldSensor {
            cost_model: CostModel::named("height-threshold").unwrap(),
            ..truth
        };
        let cost = |s: &NearFieldSensor, x: f64, y: f64| {
            let (h, cells) = s.observe(&world, 30.0, 30.0, Stamp::default());
            cells[h.cell_index(x, y).unwrap()].cost_s_per_m
        };
        // Truth: grass passable, shrub, stone, tree and water lethal.
        assert_eq!(cost(&truth, 35.0, 30.0), 1.0, "tall grass");
        for (x, y) in [(30.0, 35.0), (25.0, 30.0), (30.0, 25.0), (33.0, 33.0)] {
            assert!(cost(&truth, x, y).is_infinite(), "({x}, {y})");
        }
        // Geometry: tall grass and the tree lethal; shrub, stone and water free.
        assert!(
            cost(&geometric, 35.0, 30.0).is_infinite(),
            "tall grass looks lethal"
        );
        assert!(cost(&geometric, 30.0, 25.0).is_infinite(), "the tree");
        for (x, y) in [(30.0, 35.0), (25.0, 30.0), (33.0, 33.0)] {
            assert_eq!(cost(&geometric, x, y), 0.5, "({x}, {y}) looks free");
        }
        assert_eq!(CostModel::named("lidar"), None);
        assert_eq!(CostModel::HEIGHT_THRESHOLD.name(), "height-threshold");
    }
}
