//! The near-field sensor: FITAM's local observations, an occlusion-aware
//! costmap of the cells within 25 m. Rays every half degree walk the map
//! cell by cell from the robot; every cell a ray reaches is observed with its
//! true cost, and a ray stops two cells past the first thing taller than the
//! sensor (trees, walls, bushes, rocks, buildings), so what hides behind them
//! stays unknown.

use crate::world::World;
use farsight_interfaces::msg::{CostCell, CostmapHeader, CostmapLayer, Stamp};

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NearFieldSensor {
    pub range_m: f64,
    /// Height of the sensor above the ground; anything taller occludes.
    pub height_m: f64,
    /// Cells a ray goes on past its first occluder.
    pub past_occluder_cells: u32,
}

impl Default for NearFieldSensor {
    fn default() -> Self {
        Self {
            range_m: 25.0,
            height_m: 0.9,
            past_occluder_cells: 2,
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
                cells[i as usize * side + j as usize] = CostCell {
                    cost_s_per_m: world.cost_s_per_m(gx, gy),
                    variance: 0.0,
                };
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
}
