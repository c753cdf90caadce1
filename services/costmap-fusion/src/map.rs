//! The fused costmap of FITAM section IV-D: a near-field (local) layer whose
//! cells are *fixed* at the cost near-range sensing observed (variance 0, may
//! be lethal), and a far-field layer of per-cell Kalman filters fed by polar
//! bins. Far-field never overwrites a locally observed cell. The planning map
//! is the local cost where observed, else the far-field mean where its
//! variance is under the threshold, else the unknown cost; with the far-field
//! layer off (the "no far-field" baseline) unobserved cells are simply unknown.

use crate::grid::{cell_of, ScrollingGrid};
use crate::kalman::{kalman_update, FarFieldConfig, KalmanCell};
use crate::swath::{for_each_swath_cell, PolarGeometry};
use farsight_interfaces::msg::{CostCell, CostmapHeader, CostmapLayer, PolarCell, Stamp};

/// What one far-field observation did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FarFieldUpdate {
    /// Cell updates applied (a cell on a radial edge counts twice).
    pub updated: usize,
    /// Cells skipped because near-field sensing fixed them.
    pub skipped_local: usize,
    /// Polar cells without a usable measurement (non-finite cost or variance).
    pub rejected_bins: usize,
}

pub struct FusionMap {
    pub far_field: FarFieldConfig,
    /// Fixed near-field cost per cell; NaN where near-field never looked.
    local: ScrollingGrid<f32>,
    far: ScrollingGrid<KalmanCell>,
}

impl FusionMap {
    pub fn new(width: usize, height: usize, resolution_m: f64, far_field: FarFieldConfig) -> Self {
        Self {
            far_field,
            local: ScrollingGrid::new(width, height, resolution_m, f32::NAN),
            far: ScrollingGrid::new(width, height, resolution_m, KalmanCell::initial(&far_field)),
        }
    }

    pub fn grid(&self) -> &ScrollingGrid<f32> {
        &self.local
    }

    /// Keeps the window centred on the robot.
    pub fn recenter(&mut self, x_m: f64, y_m: f64) {
        self.local.recenter(x_m, y_m);
        self.far.recenter(x_m, y_m);
    }

    /// Near-field sensing saw cell `(gx, gy)` with this cost (infinite =
    /// lethal). Later near-field observations may change it; far-field may not.
    pub fn fix_local(&mut self, gx: i64, gy: i64, cost_s_per_m: f32) -> bool {
        if cost_s_per_m.is_nan() || cost_s_per_m < 0.0 {
            return false;
        }
        match self.local.get_mut(gx, gy) {
            Some(c) => {
                *c = cost_s_per_m;
                true
            }
            None => false,
        }
    }

    pub fn local_cost(&self, gx: i64, gy: i64) -> Option<f32> {
        self.local.get(gx, gy).copied().filter(|c| !c.is_nan())
    }

    pub fn far_cell(&self, gx: i64, gy: i64) -> Option<KalmanCell> {
        self.far.get(gx, gy).copied()
    }

    /// One far-field observation: every swath cell of every polar bin gets
    /// the bin's cost as a Kalman measurement with the bin's variance.
    pub fn observe_far_field(
        &mut self,
        geometry: &PolarGeometry,
        bins: &[PolarCell],
        x_m: f64,
        y_m: f64,
        yaw_rad: f64,
    ) -> FarFieldUpdate {
        let radial = geometry.radial_bins();
        let mut out = FarFieldUpdate {
            rejected_bins: bins
                .iter()
                .filter(|b| !(b.cost_s_per_m.is_finite() && b.variance.is_finite()))
                .count(),
            ..Default::default()
        };
        let res = self.local.resolution_m();
        for_each_swath_cell(geometry, x_m, y_m, yaw_rad, res, |gx, gy, h, r| {
            let Some(b) = bins.get(h * radial + r) else {
                return;
            };
            if !self.local.get(gx, gy).is_some_and(|c| c.is_nan()) {
                out.skipped_local += self.local.contains(gx, gy) as usize;
                return;
            }
            if let Some(cell) = self.far.get_mut(gx, gy) {
                out.updated += kalman_update(cell, b.cost_s_per_m, b.variance) as usize;
            }
        });
        out
    }

    /// Process noise after a map update: `P += Q` for every cell.
    /// (Locally observed cells do not use the far-field layer at all.)
    pub fn add_process_noise(&mut self) {
        let q = self.far_field.process_noise;
        for c in self.far.iter_mut() {
            c.variance += q;
        }
    }

    /// The cost a planner should use for a cell (`None` outside the window).
    pub fn planning_cost(&self, gx: i64, gy: i64, use_far_field: bool) -> Option<f32> {
        let local = *self.local.get(gx, gy)?;
        Some(if !local.is_nan() {
            local
        } else if use_far_field {
            self.far.get(gx, gy)?.planning_cost(&self.far_field)
        } else {
            self.far_field.unknown_cost_s_per_m
        })
    }

    fn header(&self, stamp: Stamp, layer: CostmapLayer) -> CostmapHeader {
        let g = &self.local;
        CostmapHeader {
            stamp,
            layer,
            width: g.width() as u32,
            height: g.height() as u32,
            resolution_m: g.resolution_m() as f32,
            x_min_m: g.x_min_m(),
            y_max_m: g.y_max_m(),
        }
    }

    /// A layer as a costmap message: `fused` (planning costs, variance 0 for
    /// local cells), `local` (NaN where unobserved), or `far_field` (the
    /// filter's mean and variance).
    pub fn export(
        &self,
        stamp: Stamp,
        layer: CostmapLayer,
        use_far_field: bool,
    ) -> (CostmapHeader, Vec<CostCell>) {
        let mut cells = vec![CostCell::default(); self.local.width() * self.local.height()];
        let header = self.export_into(stamp, layer, use_far_field, &mut cells);
        (header, cells)
    }

    /// [`Self::export`] into a caller's buffer (the stage writes straight
    /// into a shared-memory sample; `out` holds width x height cells).
    pub fn export_into(
        &self,
        stamp: Stamp,
        layer: CostmapLayer,
        use_far_field: bool,
        out: &mut [CostCell],
    ) -> CostmapHeader {
        match layer {
            CostmapLayer::LOCAL => self.local.write_rows_north_up(out, |_, &c| CostCell {
                cost_s_per_m: c,
                variance: if c.is_nan() { f32::NAN } else { 0.0 },
            }),
            CostmapLayer::FAR_FIELD => self.far.write_rows_north_up(out, |_, c| CostCell {
                cost_s_per_m: c.mean_s_per_m,
                variance: c.variance,
            }),
            _ => self.local.write_rows_north_up(out, |(gx, gy), &c| {
                if !c.is_nan() {
                    return CostCell {
                        cost_s_per_m: c,
                        variance: 0.0,
                    };
                }
                if !use_far_field {
                    return CostCell {
                        cost_s_per_m: self.far_field.unknown_cost_s_per_m,
                        variance: f32::INFINITY,
                    };
                }
                let far = self
                    .far
                    .get(gx, gy)
                    .copied()
                    .unwrap_or(KalmanCell::initial(&self.far_field));
                CostCell {
                    cost_s_per_m: far.planning_cost(&self.far_field),
                    variance: far.variance,
                }
            }),
        }
        self.header(stamp, layer)
    }

    /// Fixes every observed cell of a costmap from another system (a lidar
    /// stack, the simulator's near-field sensor) into the local layer. Cells
    /// whose cost is NaN were not observed. Returns how many were fixed.
    pub fn apply_local_costmap(&mut self, header: &CostmapHeader, cells: &[CostCell]) -> usize {
        let r = self.local.resolution_m();
        let mut fixed = 0;
        for (k, c) in cells.iter().enumerate().take(header.cell_count()) {
            let [x, y] = header.cell_centre_m(k);
            fixed += self.fix_local(cell_of(x, r), cell_of(y, r), c.cost_s_per_m) as usize;
        }
        fixed
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn one_bin_geometry() -> PolarGeometry {
        PolarGeometry {
            heading_bins: 1,
            first_heading_start_rad: -std::f64::consts::PI,
            heading_width_rad: std::f64::consts::TAU,
            range_edges_m: vec![2.0, 5.0],
        }
    }

    #[test]
    fn far_field_fills_unobserved_cells_and_never_overwrites_local_ones() {
        let mut m = FusionMap::new(21, 21, 1.0, FarFieldConfig::default());
        m.recenter(0.0, 0.0);
        assert!(m.fix_local(3, 0, f32::INFINITY), "a rock 3 m east");
        let road = PolarCell {
            cost_s_per_m: 0.235,
            variance: 0.0,
            class_id: 2,
            probability: 1.0,
        };
        let u = m.observe_far_field(&one_bin_geometry(), &[road], 0.0, 0.0, 0.0);
        assert_eq!(u.skipped_local, 1);
        assert!(u.updated > 20);
        assert_eq!(m.planning_cost(3, 0, true), Some(f32::INFINITY));
        // R = 0: the measurement is taken as it is.
        assert!((m.planning_cost(0, 3, true).unwrap() - 0.235).abs() < 1e-6);
        assert_eq!(
            m.planning_cost(0, 3, false),
            Some(1.0),
            "baseline ignores far-field"
        );
        assert_eq!(
            m.planning_cost(0, 8, true),
            Some(1.0),
            "out of range: unknown"
        );
        // Process noise: P grows by Q per update until the cell is unknown again.
        for _ in 0..401 {
            m.add_process_noise();
        }
        assert_eq!(m.planning_cost(0, 3, true), Some(1.0));
        assert_eq!(
            m.planning_cost(3, 0, true),
            Some(f32::INFINITY),
            "local stays fixed"
        );
    }

    #[test]
    fn exports_are_north_up_with_the_reference_conventions() {
        let mut m = FusionMap::new(5, 3, 2.0, FarFieldConfig::default());
        m.recenter(0.0, 0.0); // cells gx -2..=2, gy -1..=1
        m.fix_local(2, 1, 0.5); // north-east corner
        let (h, cells) = m.export(Stamp::default(), CostmapLayer::FUSED, true);
        assert_eq!((h.width, h.height, h.x_min_m, h.y_max_m), (5, 3, -4.0, 2.0));
        assert_eq!(cells[4].cost_s_per_m, 0.5);
        assert_eq!(cells[4].variance, 0.0);
        assert_eq!(cells[0].cost_s_per_m, 1.0, "unknown");
        // Round trip through apply_local_costmap lands on the same cell.
        let (lh, lc) = m.export(Stamp::default(), CostmapLayer::LOCAL, true);
        let mut other = FusionMap::new(9, 9, 2.0, FarFieldConfig::default());
        other.recenter(0.0, 0.0);
        assert_eq!(other.apply_local_costmap(&lh, &lc), 1);
        assert_eq!(other.local_cost(2, 1), Some(0.5));
    }
}
