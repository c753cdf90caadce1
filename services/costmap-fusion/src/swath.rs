//! Polar bins -> map cells (FITAM section IV-B/IV-D): the *swath* of a
//! (heading bin, radial bin) pair is every cell whose centre lies inside the
//! bin's annular sector around the robot's cell.
//!
//! As in the reference code, distance is measured between cell centres
//! (`res * hypot(di, dj)`) and both radial bounds are inclusive, so a cell
//! exactly on an edge belongs to both neighbouring radial bins. Heading bins
//! are half-open `[start, start + width)`, taken modulo 2 pi so a bin may
//! straddle +-pi.

use crate::grid::cell_of;
use farsight_interfaces::msg::PolarBinsHeader;
use std::f64::consts::{PI, TAU};

/// The layout of a set of polar bins in the robot frame.
#[derive(Debug, Clone, PartialEq)]
pub struct PolarGeometry {
    pub heading_bins: usize,
    /// Bearing (robot frame, counter-clockwise) where heading bin 0 starts.
    pub first_heading_start_rad: f64,
    pub heading_width_rad: f64,
    /// Radial bin `r` covers `range_edges_m[r]..=range_edges_m[r + 1]`.
    pub range_edges_m: Vec<f64>,
}

impl PolarGeometry {
    /// FITAM's simulated default: 32 heading bins, radial edges 25/50/75/100 m,
    /// bin 0 starting at -pi.
    pub fn fitam_default() -> Self {
        Self {
            heading_bins: 32,
            first_heading_start_rad: -PI,
            heading_width_rad: TAU / 32.0,
            range_edges_m: vec![25.0, 50.0, 75.0, 100.0],
        }
    }

    /// The geometry a polar-bin message describes, checked: 1 to 360
    /// heading bins of a positive width covering at most a full turn, and 2
    /// to 16 increasing, finite range edges out to at most 1 km (a peer's
    /// absurd edge must not make the rasteriser walk millions of cells).
    pub fn from_header(h: &PolarBinsHeader) -> Result<Self, String> {
        let edges: Vec<f64> = h
            .range_edges_m
            .as_slice()
            .iter()
            .map(|&e| e as f64)
            .collect();
        let width = h.heading_width_rad as f64;
        if !(1..=360).contains(&h.heading_bins) {
            return Err(format!("{} heading bins: want 1..=360", h.heading_bins));
        }
        let turn_ok = width.is_finite()
            && width > 0.0
            && width * h.heading_bins as f64 <= TAU + 1e-3
            && h.first_heading_start_rad.is_finite();
        if !turn_ok {
            return Err(format!(
                "heading bins of {width} rad from {} rad: want a positive width, at most a full turn",
                h.first_heading_start_rad
            ));
        }
        let ok = edges.len() >= 2
            && edges
                .iter()
                .all(|e| e.is_finite() && (0.0..=1000.0).contains(e))
            && edges.windows(2).all(|w| w[0] < w[1]);
        if !ok {
            return Err(format!(
                "range edges {edges:?} m: want 2 or more increasing, in 0..=1000"
            ));
        }
        Ok(Self {
            heading_bins: h.heading_bins as usize,
            first_heading_start_rad: h.first_heading_start_rad as f64,
            heading_width_rad: width,
            range_edges_m: edges,
        })
    }

    pub fn radial_bins(&self) -> usize {
        self.range_edges_m.len().saturating_sub(1)
    }

    /// The heading bin of a robot-frame bearing, if one covers it.
    pub fn heading_bin(&self, bearing_rad: f64) -> Option<usize> {
        let a = turn_of(bearing_rad - self.first_heading_start_rad);
        // `a` is not negative, so the cast truncates as `floor` would (a
        // libm call per swath cell on x86-64's baseline).
        let k = (a / self.heading_width_rad) as usize;
        (k < self.heading_bins).then_some(k)
    }
}

/// `x.rem_euclid(TAU)`, bit for bit, without `fmod` for the angles a swath
/// cell's bearing minus a heading gives (within two turns): inside one turn
/// `fmod` returns `x` itself (so `x + TAU` below zero, as `rem_euclid`
/// adds; at exactly `-TAU`, `fmod` gives -0), and between one and two turns
/// `x - TAU` is exact (Sterbenz), which is what `fmod` returns there.
fn turn_of(x: f64) -> f64 {
    if (0.0..TAU).contains(&x) {
        x
    } else if x > -TAU && x < 0.0 {
        x + TAU
    } else if (TAU..2.0 * TAU).contains(&x) {
        x - TAU
    } else {
        x.rem_euclid(TAU)
    }
}

/// The cells of a swath pattern relative to the robot's cell, built once per
/// geometry and resolution: range and bearing of each offset are fixed, only
/// the robot's yaw moves the heading bins. A far-field frame walks some
/// 30,000 to 130,000 cells; computing `hypot` and `atan2` for each on every
/// frame was a sixth of the navigation benchmark's time.
#[derive(Debug, Clone)]
pub struct SwathTable {
    geometry: PolarGeometry,
    resolution_m: f64,
    offsets: Vec<SwathOffset>,
}

#[derive(Debug, Clone, Copy)]
struct SwathOffset {
    dx: i32,
    dy: i32,
    /// `atan2(dy, dx)`, world frame.
    bearing_rad: f64,
    /// The radial bins holding this range: `first..first + count` (two
    /// where the range lies exactly on an inner edge).
    first_radial: u8,
    radial_count: u8,
}

/// The most cells a table's square may span (a table holds about 79% of
/// them, 24 bytes each: at most 40 MB): FITAM's 100 m geometry on 0.2 m
/// cells fits. Past that (a peer's 1 km edges on a fine grid) swaths are
/// computed cell by cell instead of allocated.
const MAX_TABLE_OFFSETS: i64 = 1 << 21;

impl SwathOffset {
    /// The offset `(dx, dy)` cells from the robot's cell, if it lies in a
    /// radial bin (and is not the robot's own cell).
    fn of(geometry: &PolarGeometry, resolution_m: f64, dx: i64, dy: i64) -> Option<Self> {
        let max_range = *geometry.range_edges_m.last()?;
        let range = resolution_m * (dx as f64).hypot(dy as f64);
        if range > max_range || (dx == 0 && dy == 0) {
            return None;
        }
        let mut bins = geometry
            .range_edges_m
            .windows(2)
            .enumerate()
            .filter(|(_, e)| e[0] <= range && range <= e[1])
            .map(|(r, _)| r);
        let first = bins.next()?;
        Some(Self {
            dx: dx as i32,
            dy: dy as i32,
            bearing_rad: (dy as f64).atan2(dx as f64),
            first_radial: first as u8,
            radial_count: 1 + bins.count() as u8,
        })
    }

    fn visit(
        &self,
        geometry: &PolarGeometry,
        (cx, cy): (i64, i64),
        yaw_rad: f64,
        f: &mut impl FnMut(i64, i64, usize, usize),
    ) {
        let Some(h) = geometry.heading_bin(self.bearing_rad - yaw_rad) else {
            return;
        };
        let first = self.first_radial as usize;
        for r in first..first + self.radial_count as usize {
            f(cx + self.dx as i64, cy + self.dy as i64, h, r);
        }
    }
}

/// The half-width in cells of the square holding every swath.
fn reach_cells(geometry: &PolarGeometry, resolution_m: f64) -> i64 {
    geometry
        .range_edges_m
        .last()
        .map_or(0, |&m| (m / resolution_m).ceil() as i64)
}

impl SwathTable {
    /// Every cell centre within the outermost edge, with its bins; `None`
    /// when that would be more than [`MAX_TABLE_OFFSETS`] cells.
    pub fn new(geometry: &PolarGeometry, resolution_m: f64) -> Option<Self> {
        let n = reach_cells(geometry, resolution_m);
        if (2 * n + 1).saturating_mul(2 * n + 1) > MAX_TABLE_OFFSETS {
            return None;
        }
        let offsets = (-n..=n)
            .flat_map(|dy| (-n..=n).map(move |dx| (dx, dy)))
            .filter_map(|(dx, dy)| SwathOffset::of(geometry, resolution_m, dx, dy))
            .collect();
        Some(Self {
            geometry: geometry.clone(),
            resolution_m,
            offsets,
        })
    }

    /// Whether this table was built for `geometry` at `resolution_m`.
    pub fn fits(&self, geometry: &PolarGeometry, resolution_m: f64) -> bool {
        self.resolution_m == resolution_m && self.geometry == *geometry
    }

    /// Calls `f(gx, gy, heading_bin, radial_bin)` for every cell of every
    /// swath around a robot at `(x_m, y_m)` with heading `yaw_rad`.
    pub fn for_each(
        &self,
        x_m: f64,
        y_m: f64,
        yaw_rad: f64,
        mut f: impl FnMut(i64, i64, usize, usize),
    ) {
        let res = self.resolution_m;
        let centre = (cell_of(x_m, res), cell_of(y_m, res));
        for o in &self.offsets {
            o.visit(&self.geometry, centre, yaw_rad, &mut f);
        }
    }
}

/// Tables kept per thread: one per geometry a thread rasterises (the
/// simulator's labeller and the map it feeds see different ones, if only by
/// the f32 rounding of the message in between).
const KEPT_TABLES: usize = 4;

thread_local! {
    static TABLES: std::cell::RefCell<Vec<std::rc::Rc<SwathTable>>> =
        const { std::cell::RefCell::new(Vec::new()) };
}

/// Calls `f(gx, gy, heading_bin, radial_bin)` for every cell of every swath
/// around a robot at `(x_m, y_m)` with heading `yaw_rad` (ENU, counter-
/// clockwise from east), on a grid of `resolution_m` cells. The
/// [`SwathTable`] is built on the first call for a geometry and kept (the
/// last [`KEPT_TABLES`] of them).
pub fn for_each_swath_cell(
    geometry: &PolarGeometry,
    x_m: f64,
    y_m: f64,
    yaw_rad: f64,
    resolution_m: f64,
    f: impl FnMut(i64, i64, usize, usize),
) {
    let table = TABLES.with(|tables| {
        let mut tables = tables.borrow_mut();
        if let Some(t) = tables.iter().find(|t| t.fits(geometry, resolution_m)) {
            return Some(t.clone());
        }
        let t = std::rc::Rc::new(SwathTable::new(geometry, resolution_m)?);
        if tables.len() == KEPT_TABLES {
            tables.remove(0);
        }
        tables.push(t.clone());
        Some(t)
    });
    match table {
        Some(table) => table.for_each(x_m, y_m, yaw_rad, f),
        None => for_each_swath_cell_untabled(geometry, x_m, y_m, yaw_rad, resolution_m, f),
    }
}

/// [`for_each_swath_cell`] computing each cell's range and bearing in turn.
fn for_each_swath_cell_untabled(
    geometry: &PolarGeometry,
    x_m: f64,
    y_m: f64,
    yaw_rad: f64,
    resolution_m: f64,
    mut f: impl FnMut(i64, i64, usize, usize),
) {
    let centre = (cell_of(x_m, resolution_m), cell_of(y_m, resolution_m));
    let n = reach_cells(geometry, resolution_m);
    for dy in -n..=n {
        for dx in -n..=n {
            if let Some(o) = SwathOffset::of(geometry, resolution_m, dx, dy) {
                o.visit(geometry, centre, yaw_rad, &mut f);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashSet;

    fn cells_of(g: &PolarGeometry, yaw: f64, want_h: usize, want_r: usize) -> HashSet<(i64, i64)> {
        let mut s = HashSet::new();
        for_each_swath_cell(g, 0.0, 0.0, yaw, 1.0, |x, y, h, r| {
            if (h, r) == (want_h, want_r) {
                s.insert((x, y));
            }
        });
        s
    }

    #[test]
    fn turn_of_is_rem_euclid_bit_for_bit() {
        let mut x = -5.0 * TAU;
        while x < 5.0 * TAU {
            for v in [x, x.next_up(), x.next_down()] {
                assert_eq!(turn_of(v).to_bits(), v.rem_euclid(TAU).to_bits(), "{v}");
            }
            x += 0.0137;
        }
        for v in [
            0.0,
            -0.0,
            TAU,
            -TAU,
            2.0 * TAU,
            TAU.next_down(),
            (-TAU).next_up(),
            f64::INFINITY,
            f64::NAN,
        ] {
            assert_eq!(turn_of(v).to_bits(), v.rem_euclid(TAU).to_bits(), "{v}");
        }
    }

    #[test]
    fn message_geometry_is_checked_before_use() {
        use farsight_interfaces::fixed::FixedVec;
        let good = PolarBinsHeader {
            heading_bins: 32,
            first_heading_start_rad: -std::f32::consts::PI,
            heading_width_rad: std::f32::consts::TAU / 32.0,
            range_edges_m: FixedVec::from_slice(&[25.0, 50.0, 75.0, 100.0]).unwrap(),
            ..Default::default()
        };
        let g = PolarGeometry::from_header(&good).unwrap();
        let d = PolarGeometry::fitam_default();
        assert_eq!(
            (g.heading_bins, &g.range_edges_m),
            (d.heading_bins, &d.range_edges_m)
        );
        assert!(
            (g.heading_width_rad - d.heading_width_rad).abs() < 1e-6,
            "f32 on the wire"
        );
        let far = PolarBinsHeader {
            range_edges_m: FixedVec::from_slice(&[25.0, 1e9]).unwrap(),
            ..good
        };
        assert!(PolarGeometry::from_header(&far)
            .unwrap_err()
            .contains("range edges"));
        let zero = PolarBinsHeader {
            heading_bins: 0,
            ..good
        };
        assert!(PolarGeometry::from_header(&zero)
            .unwrap_err()
            .contains("0 heading bins"));
        let nan = PolarBinsHeader {
            heading_width_rad: f32::NAN,
            ..good
        };
        assert!(PolarGeometry::from_header(&nan)
            .unwrap_err()
            .contains("positive width"));
    }

    #[test]
    fn the_table_visits_what_the_cell_by_cell_walk_visits_in_the_same_order() {
        let g = PolarGeometry::fitam_default();
        let table = SwathTable::new(&g, 1.0).expect("100 m on 1 m cells fits");
        for (x, y, yaw) in [(0.0, 0.0, 0.0), (12.3, -4.6, 2.9), (-0.49, 0.51, -PI)] {
            let (mut a, mut b) = (Vec::new(), Vec::new());
            table.for_each(x, y, yaw, |gx, gy, h, r| a.push((gx, gy, h, r)));
            for_each_swath_cell_untabled(&g, x, y, yaw, 1.0, |gx, gy, h, r| b.push((gx, gy, h, r)));
            assert!(a.len() > 29_000, "the 25-100 m annulus: {}", a.len());
            assert_eq!(a, b, "at ({x}, {y}) yaw {yaw}");
        }
        // A peer's 1 km edges on 0.1 m cells would be 300 million cells:
        // no table, and the walk still answers.
        let far = PolarGeometry {
            range_edges_m: vec![0.0, 1000.0],
            ..g.clone()
        };
        assert!(SwathTable::new(&far, 0.1).is_none());
        assert!(SwathTable::new(&far, 2.0).is_some_and(|t| t.fits(&far, 2.0) && !t.fits(&g, 2.0)));
        let tiny = PolarGeometry {
            range_edges_m: vec![0.0, 0.5],
            ..g
        };
        let mut n = 0;
        for_each_swath_cell(&tiny, 0.0, 0.0, 0.0, 0.25, |_, _, _, _| n += 1);
        assert_eq!(n, 12, "the cells within 2 cells but the robot's own");
    }

    #[test]
    fn boundary_cells_belong_to_both_radial_bins() {
        // 4 heading bins of 90 deg starting at -45 deg: bin 0 looks ahead.
        let g = PolarGeometry {
            heading_bins: 4,
            first_heading_start_rad: -PI / 4.0,
            heading_width_rad: PI / 2.0,
            range_edges_m: vec![2.0, 4.0, 6.0],
        };
        let near = cells_of(&g, 0.0, 0, 0);
        let far = cells_of(&g, 0.0, 0, 1);
        // (4, 0) is exactly 4 m ahead: in both; (2, 0) only near; (6, 0) only far.
        assert!(near.contains(&(4, 0)) && far.contains(&(4, 0)));
        assert!(near.contains(&(2, 0)) && !far.contains(&(2, 0)));
        assert!(far.contains(&(6, 0)) && !near.contains(&(6, 0)));
        assert!(!near.contains(&(1, 0)), "inside the first edge");
        // (3, 1): 3.16 m at 18.4 deg: near, ahead bin. (3, 3): 45 deg is the
        // start of bin 1 (half-open), so not in bin 0.
        assert!(near.contains(&(3, 1)));
        assert!(!near.contains(&(2, 2)) && cells_of(&g, 0.0, 1, 0).contains(&(2, 2)));
        // The robot faces north: "ahead" is now +y.
        let north = cells_of(&g, PI / 2.0, 0, 0);
        assert!(north.contains(&(0, 3)) && !north.contains(&(3, 0)));
    }

    #[test]
    fn the_bin_behind_wraps_around_pi() {
        let g = PolarGeometry::fitam_default();
        // Bin 0 of the default starts at -pi: it holds bearings just past -pi
        // (behind, slightly right); the last bin holds bearings just below +pi.
        assert_eq!(g.heading_bin(-PI + 0.01), Some(0));
        assert_eq!(g.heading_bin(PI - 0.01), Some(31));
        assert_eq!(g.heading_bin(PI), Some(0), "+pi is -pi");
        assert_eq!(g.heading_bin(3.0 * PI - 0.01), Some(31));
        // A bin straddling +-pi: 8 bins, bin 0 from 157.5 deg to -157.5 deg.
        let s = PolarGeometry {
            heading_bins: 8,
            first_heading_start_rad: PI - PI / 8.0,
            heading_width_rad: PI / 4.0,
            range_edges_m: vec![0.5, 10.0],
        };
        let behind = cells_of(&s, 0.0, 0, 0);
        assert!(
            behind.contains(&(-5, 1)) && behind.contains(&(-5, -1)) && behind.contains(&(-5, 0))
        );
        assert!(!behind.contains(&(5, 0)));
        // Every cell in range is in exactly one heading bin.
        let mut count = std::collections::HashMap::new();
        for_each_swath_cell(&s, 0.0, 0.0, 0.3, 1.0, |x, y, _, _| {
            *count.entry((x, y)).or_insert(0) += 1
        });
        assert!(count.values().all(|&c| c == 1));
        assert_eq!(
            count.len(),
            (-10i64..=10)
                .flat_map(|x| (-10i64..=10).map(move |y| (x, y)))
                .filter(|&(x, y)| {
                    let d = ((x * x + y * y) as f64).sqrt();
                    (0.5..=10.0).contains(&d)
                })
                .count()
        );
    }
}
