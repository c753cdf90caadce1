//! A grid of cells fixed in the world frame that scrolls with the robot
//! (FITAM section IV-D keeps its map in a fixed frame; a robot on a long route
//! only needs a window of it around itself).
//!
//! Cells are named by global integer indices `(gx, gy)`: the cell centred at
//! `(gx * res, gy * res)` in the local ENU frame. Storage is toroidal (`gx mod
//! width`, `gy mod height`), so moving the window does not move any data: a
//! cell that stays inside keeps its value, and only the cells that scroll in
//! are reset.
//!
//! Exported rows follow the FITAM reference code: row-major, north up, with
//! `j = floor((x - x_min) / res + 0.5)` and `i = floor((y_max - y) / res + 0.5)`.
//!
//! ```
//! use farsight_costmap_fusion::grid::ScrollingGrid;
//!
//! let mut g = ScrollingGrid::new(10, 10, 1.0, 0.0f32);
//! g.recenter(0.0, 0.0);
//! *g.at_world_mut(2.0, 3.0).unwrap() = 7.0;
//! g.recenter(4.0, 0.0); // the robot drove 4 m east: the cell is still inside
//! assert_eq!(g.at_world(2.0, 3.0), Some(&7.0));
//! g.recenter(40.0, 0.0); // far away: it scrolled out
//! assert_eq!(g.at_world(2.0, 3.0), None);
//! ```

/// Global index of the cell holding world coordinate `x` (metres).
pub fn cell_of(x_m: f64, resolution_m: f64) -> i64 {
    (x_m / resolution_m + 0.5).floor() as i64
}

#[derive(Debug, Clone)]
pub struct ScrollingGrid<T> {
    width: usize,
    height: usize,
    resolution_m: f64,
    /// Global index of the south-west (first column, last row) cell.
    origin: (i64, i64),
    /// Where the origin cell is stored (`origin mod size`), so that finding
    /// a cell inside the window takes an add and a compare, not two
    /// divisions (a far-field frame looks up some 100,000 cells).
    origin_slot: (usize, usize),
    cells: Vec<T>,
    fill: T,
}

impl<T: Clone> ScrollingGrid<T> {
    /// A `width` x `height` grid of `resolution_m` cells, all `fill`,
    /// south-west corner at the world origin until [`Self::recenter`].
    pub fn new(width: usize, height: usize, resolution_m: f64, fill: T) -> Self {
        assert!(width > 0 && height > 0 && resolution_m > 0.0);
        Self {
            width,
            height,
            resolution_m,
            origin: (0, 0),
            origin_slot: (0, 0),
            cells: vec![fill.clone(); width * height],
            fill,
        }
    }

    pub fn width(&self) -> usize {
        self.width
    }
    pub fn height(&self) -> usize {
        self.height
    }
    pub fn resolution_m(&self) -> f64 {
        self.resolution_m
    }
    /// Global index of the south-west cell.
    pub fn origin(&self) -> (i64, i64) {
        self.origin
    }

    pub fn contains(&self, gx: i64, gy: i64) -> bool {
        (self.origin.0..self.origin.0 + self.width as i64).contains(&gx)
            && (self.origin.1..self.origin.1 + self.height as i64).contains(&gy)
    }

    /// The storage index of a cell inside the window: `gx mod width`,
    /// `gy mod height`.
    fn slot(&self, gx: i64, gy: i64) -> usize {
        debug_assert!(self.contains(gx, gy), "({gx}, {gy}) outside the window");
        let wrap = |offset: i64, first: usize, size: usize| {
            let k = first + offset as usize;
            if k >= size {
                k - size
            } else {
                k
            }
        };
        let x = wrap(gx - self.origin.0, self.origin_slot.0, self.width);
        let y = wrap(gy - self.origin.1, self.origin_slot.1, self.height);
        y * self.width + x
    }

    pub fn get(&self, gx: i64, gy: i64) -> Option<&T> {
        self.contains(gx, gy)
            .then(|| &self.cells[self.slot(gx, gy)])
    }

    pub fn get_mut(&mut self, gx: i64, gy: i64) -> Option<&mut T> {
        if self.contains(gx, gy) {
            let s = self.slot(gx, gy);
            Some(&mut self.cells[s])
        } else {
            None
        }
    }

    pub fn at_world(&self, x_m: f64, y_m: f64) -> Option<&T> {
        self.get(
            cell_of(x_m, self.resolution_m),
            cell_of(y_m, self.resolution_m),
        )
    }

    pub fn at_world_mut(&mut self, x_m: f64, y_m: f64) -> Option<&mut T> {
        let r = self.resolution_m;
        self.get_mut(cell_of(x_m, r), cell_of(y_m, r))
    }

    /// Moves the window so the cell holding `(x_m, y_m)` is in its middle.
    /// Cells that leave the window are forgotten; cells that enter it start
    /// as `fill`. Returns whether the window moved.
    pub fn recenter(&mut self, x_m: f64, y_m: f64) -> bool {
        let r = self.resolution_m;
        let new = (
            cell_of(x_m, r) - (self.width / 2) as i64,
            cell_of(y_m, r) - (self.height / 2) as i64,
        );
        if new == self.origin {
            return false;
        }
        let old = std::mem::replace(&mut self.origin, new);
        self.origin_slot = (
            new.0.rem_euclid(self.width as i64) as usize,
            new.1.rem_euclid(self.height as i64) as usize,
        );
        let stays = |gx: i64, gy: i64| {
            (old.0..old.0 + self.width as i64).contains(&gx)
                && (old.1..old.1 + self.height as i64).contains(&gy)
        };
        for gy in new.1..new.1 + self.height as i64 {
            for gx in new.0..new.0 + self.width as i64 {
                if !stays(gx, gy) {
                    let s = self.slot(gx, gy);
                    self.cells[s] = self.fill.clone();
                }
            }
        }
        true
    }

    /// World x of the centre of exported column 0.
    pub fn x_min_m(&self) -> f64 {
        self.origin.0 as f64 * self.resolution_m
    }

    /// World y of the centre of exported row 0 (the northmost row).
    pub fn y_max_m(&self) -> f64 {
        (self.origin.1 + self.height as i64 - 1) as f64 * self.resolution_m
    }

    /// Global index of exported row `i`, column `j`.
    pub fn global_of_row_col(&self, i: usize, j: usize) -> (i64, i64) {
        (
            self.origin.0 + j as i64,
            self.origin.1 + (self.height - 1 - i) as i64,
        )
    }

    /// Writes the cells in exported order (row-major, north up), mapped by
    /// `f`, into `out` (which holds `width * height` entries; a shorter one
    /// gets the first rows).
    pub fn write_rows_north_up<U>(&self, out: &mut [U], mut f: impl FnMut((i64, i64), &T) -> U) {
        // An exported row is one stored row, its columns two runs split where
        // the storage wraps: no slot is worked out per cell (the costmap is
        // exported every frame).
        let w = self.width;
        for (i, out_row) in out.chunks_mut(w).take(self.height).enumerate() {
            let (gx0, gy) = self.global_of_row_col(i, 0);
            let stored = &self.cells[self.slot(gx0, gy) - self.origin_slot.0..][..w];
            let (wrapped, first) = stored.split_at(self.origin_slot.0);
            for (j, (slot, cell)) in out_row
                .iter_mut()
                .zip(first.iter().chain(wrapped))
                .enumerate()
            {
                *slot = f((gx0 + j as i64, gy), cell);
            }
        }
    }

    /// Every cell with its global index, in storage order.
    pub fn iter_mut(&mut self) -> impl Iterator<Item = &mut T> {
        self.cells.iter_mut()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cell_convention_matches_the_reference_code() {
        // j = floor((x - xmin)/res + 0.5) with xmin = 0: x in [-0.5, 0.5) -> 0.
        assert_eq!(cell_of(0.49, 1.0), 0);
        assert_eq!(cell_of(0.5, 1.0), 1);
        assert_eq!(cell_of(-0.5, 1.0), 0);
        assert_eq!(cell_of(-0.51, 1.0), -1);
        let mut g = ScrollingGrid::new(5, 4, 2.0, 0u8);
        g.recenter(10.0, 20.0); // robot cell (5, 10); origin (3, 8)
        assert_eq!(g.origin(), (3, 8));
        assert_eq!(g.x_min_m(), 6.0);
        assert_eq!(g.y_max_m(), 22.0); // rows gy 8..=11, north row 11
        assert_eq!(g.global_of_row_col(0, 0), (3, 11));
        assert_eq!(g.global_of_row_col(3, 4), (7, 8));
    }

    #[test]
    fn a_cell_keeps_its_value_while_the_window_moves() {
        let mut g = ScrollingGrid::new(8, 6, 1.0, -1i32);
        g.recenter(0.0, 0.0);
        for gy in g.origin().1..g.origin().1 + 6 {
            for gx in g.origin().0..g.origin().0 + 8 {
                *g.get_mut(gx, gy).unwrap() = (gx * 100 + gy) as i32;
            }
        }
        // Move 3 east and 2 south: overlap keeps values, new cells are fill.
        assert!(g.recenter(3.0, -2.0));
        assert!(!g.recenter(3.2, -1.9), "same cell: no move");
        for gy in g.origin().1..g.origin().1 + 6 {
            for gx in g.origin().0..g.origin().0 + 8 {
                let was_inside = (-4..4).contains(&gx) && (-3..3).contains(&gy);
                let want = if was_inside {
                    (gx * 100 + gy) as i32
                } else {
                    -1
                };
                assert_eq!(g.get(gx, gy), Some(&want), "cell ({gx}, {gy})");
            }
        }
        // Exported rows, north up, with storage wrapped in both axes.
        let mut rows = vec![(0, (0, 0)); 48];
        g.write_rows_north_up(&mut rows, |at, &v| (v, at));
        for (k, &(v, at)) in rows.iter().enumerate() {
            let want = g.global_of_row_col(k / 8, k % 8);
            assert_eq!(at, want, "export cell {k}");
            assert_eq!(Some(&v), g.get(want.0, want.1), "export cell {k}");
        }
        let mut first_rows = vec![(0, (0, 0)); 11];
        g.write_rows_north_up(&mut first_rows, |at, &v| (v, at));
        assert_eq!(
            first_rows,
            rows[..11],
            "a shorter output gets the first rows"
        );
        // Wrap the torus several times over: still consistent.
        g.recenter(-100.0, 57.0);
        let mut all = vec![0; 48];
        g.write_rows_north_up(&mut all, |_, &v| v);
        assert!(all.iter().all(|&v| v == -1));
        assert_eq!(g.get(0, 0), None);
    }
}
