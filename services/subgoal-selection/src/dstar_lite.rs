//! Grid planning for FITAM's sense-plan-act loop (section IV-E): D* Lite
//! (Koenig & Likhachev 2002, the optimised version) on an 8-connected grid,
//! and plain A* as its reference.
//!
//! Moving from a cell into cell `v` costs `cost[v] * resolution` (times
//! sqrt 2 on a diagonal), as the FITAM reference code; an infinite (or NaN)
//! cost blocks the cell, and a diagonal step may not cut a blocked cell's
//! corner. The heuristic is the octile distance times the
//! cheapest cost per metre any cell can have, so it stays admissible.
//!
//! D* Lite searches backward from the goal. After the robot moves and cells
//! change, only the vertices whose edges changed are updated and the search
//! repairs from there, instead of planning again from scratch.
//!
//! ```
//! use farsight_subgoal_selection::dstar_lite::{CostGrid, DStarLite};
//!
//! // 5x3 grid of 1 s/m cells with a wall in column 2 except row 0: the way
//! // round passes (2,0) straight, as diagonals may not cut the wall's top
//! // corners: two diagonal steps and four straight ones.
//! let mut grid = CostGrid::new(5, 3, 1.0, 1.0);
//! grid.set(2, 1, f32::INFINITY);
//! grid.set(2, 2, f32::INFINITY);
//! let mut planner = DStarLite::new(grid, (0, 2), (4, 2), 1.0);
//! let cost = planner.compute().expect("a way around the wall");
//! assert!((cost - (4.0 + 2.0 * 2f64.sqrt())).abs() < 1e-9);
//! let path = planner.path();
//! assert_eq!(path.first(), Some(&(0, 2)));
//! assert!(path.windows(3).any(|w| w == [(1, 0), (2, 0), (3, 0)]));
//! assert_eq!(path.last(), Some(&(4, 2)));
//! ```

use std::cmp::Ordering;
use std::collections::BinaryHeap;

const SQRT2: f64 = std::f64::consts::SQRT_2;
/// Slots of a vertex's `[g, rhs]` pair in [`DStarLite`].
const G: usize = 0;
const RHS: usize = 1;
const NEIGHBOURS: [(i64, i64); 8] = [
    (1, 0),
    (-1, 0),
    (0, 1),
    (0, -1),
    (1, 1),
    (1, -1),
    (-1, 1),
    (-1, -1),
];

/// Cell costs (s/m) of a grid, row-major by `(x, y)`; infinite = blocked.
#[derive(Debug, Clone, PartialEq)]
pub struct CostGrid {
    pub width: usize,
    pub height: usize,
    pub resolution_m: f64,
    costs: Vec<f32>,
}

impl CostGrid {
    pub fn new(width: usize, height: usize, resolution_m: f64, fill_s_per_m: f32) -> Self {
        Self {
            width,
            height,
            resolution_m,
            costs: vec![fill_s_per_m; width * height],
        }
    }

    pub fn get(&self, x: usize, y: usize) -> f32 {
        self.costs[y * self.width + x]
    }

    pub fn set(&mut self, x: usize, y: usize, cost_s_per_m: f32) {
        self.costs[y * self.width + x] = cost_s_per_m;
    }

    fn blocked(c: f32) -> bool {
        !c.is_finite() || c < 0.0
    }

    /// Whether cell `(x, y)` cannot be entered.
    pub fn is_blocked(&self, x: usize, y: usize) -> bool {
        Self::blocked(self.get(x, y))
    }

    /// Cost of stepping from `a` into its neighbour `b` (seconds). Only the
    /// entered cell counts, as FITAM's code: a robot standing in a cell the
    /// map now calls lethal (an inflated margin, a late detection) can still
    /// plan its way out. A diagonal step past the corner of a blocked cell
    /// is blocked: the robot's centre would run along the obstacle's corner,
    /// and two diagonal trees would leave no gap at all.
    pub fn step_cost(&self, a: (usize, usize), b: (usize, usize)) -> f64 {
        let c = self.get(b.0, b.1);
        if Self::blocked(c) {
            return f64::INFINITY;
        }
        let diagonal = a.0 != b.0 && a.1 != b.1;
        if diagonal && (self.is_blocked(a.0, b.1) || self.is_blocked(b.0, a.1)) {
            return f64::INFINITY;
        }
        c as f64 * self.resolution_m * if diagonal { SQRT2 } else { 1.0 }
    }

    /// The up-to-eight cells next to `(x, y)` inside the grid.
    pub fn neighbours(&self, (x, y): (usize, usize)) -> impl Iterator<Item = (usize, usize)> + '_ {
        NEIGHBOURS.iter().filter_map(move |&(dx, dy)| {
            let (nx, ny) = (x as i64 + dx, y as i64 + dy);
            (nx >= 0 && ny >= 0 && (nx as usize) < self.width && (ny as usize) < self.height)
                .then_some((nx as usize, ny as usize))
        })
    }

    /// Cell `i`'s neighbourhood by index: which of the eight neighbours (in
    /// [`NEIGHBOURS`] order) are inside the grid, and between which of
    /// them and `i` a step is open, blocked cells aside (not past a blocked
    /// corner). A corner test is symmetric, so one mask serves the steps out
    /// of `i` and the steps into it. Interior cells, nearly all of them, are
    /// read as one 3x3 block without coordinate arithmetic: the search's
    /// inner loops spent most of their time in the general neighbour walk.
    fn around(&self, i: usize) -> Around {
        let w = self.width;
        let (x, y) = self.cell_of(i);
        if x > 0 && y > 0 && x + 1 < w && y + 1 < self.height {
            let b = |j: usize| Self::blocked(self.costs[j]);
            let (east, west, south, north) = (b(i + 1), b(i - 1), b(i + w), b(i - w));
            let open = 0b1111
                | u8::from(!(east || south)) << 4
                | u8::from(!(east || north)) << 5
                | u8::from(!(west || south)) << 6
                | u8::from(!(west || north)) << 7;
            return Around {
                cells: [
                    i + 1,
                    i - 1,
                    i + w,
                    i - w,
                    i + w + 1,
                    i + 1 - w,
                    i + w - 1,
                    i - w - 1,
                ],
                inside: 0xff,
                open,
            };
        }
        let mut a = Around {
            cells: [0; 8],
            inside: 0,
            open: 0,
        };
        for (k, &(dx, dy)) in NEIGHBOURS.iter().enumerate() {
            let (nx, ny) = (x as i64 + dx, y as i64 + dy);
            if nx < 0 || ny < 0 || nx as usize >= w || ny as usize >= self.height {
                continue;
            }
            let (nx, ny) = (nx as usize, ny as usize);
            a.cells[k] = ny * w + nx;
            a.inside |= 1 << k;
            if k < 4 || !(self.is_blocked(x, ny) || self.is_blocked(nx, y)) {
                a.open |= 1 << k;
            }
        }
        a
    }

    /// Cell `i`'s `(x, y)`, in one 32-bit division where the grid allows
    /// (D* Lite's always does): every key and neighbourhood read computes
    /// a cell, and a 64-bit division was a tenth of a repair.
    fn cell_of(&self, i: usize) -> (usize, usize) {
        match (u32::try_from(i), u32::try_from(self.width)) {
            (Ok(i), Ok(w)) => {
                let y = i / w;
                ((i - y * w) as usize, y as usize)
            }
            _ => (i % self.width, i / self.width),
        }
    }

    /// [`Self::step_cost`] of a step between `i` and its `k`-th neighbour
    /// that enters the cell `entered` (one of the two).
    fn step_cost_around(&self, a: &Around, k: usize, entered: usize) -> f64 {
        let c = self.costs[entered];
        if a.open & (1 << k) == 0 || Self::blocked(c) {
            return f64::INFINITY;
        }
        c as f64 * self.resolution_m * if k < 4 { 1.0 } else { SQRT2 }
    }

    /// Total cost of a path of neighbouring cells.
    pub fn path_cost(&self, path: &[(usize, usize)]) -> f64 {
        path.windows(2).map(|w| self.step_cost(w[0], w[1])).sum()
    }
}

/// A cell's neighbourhood: see [`CostGrid::around`].
#[derive(Debug, Clone, Copy)]
struct Around {
    /// Neighbour indices in [`NEIGHBOURS`] order, where `inside` is set.
    cells: [usize; 8],
    /// Bit k: neighbour k is inside the grid.
    inside: u8,
    /// Bit k: the step between the cell and neighbour k does not cut a
    /// blocked corner (whether either end is blocked is checked apart).
    open: u8,
}

impl Around {
    /// The inside neighbours as (direction, index) pairs.
    fn iter(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        (0..8)
            .filter(|&k| self.inside & (1 << k) != 0)
            .map(|k| (k, self.cells[k]))
    }
}

/// Octile distance in metres times the cheapest cost per metre.
pub fn octile(a: (usize, usize), b: (usize, usize), scale: f64) -> f64 {
    let dx = a.0.abs_diff(b.0) as f64;
    let dy = a.1.abs_diff(b.1) as f64;
    scale * (dx.max(dy) + (SQRT2 - 1.0) * dx.min(dy))
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Key(f64, f64);

impl Eq for Key {}
impl PartialOrd for Key {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Key {
    fn cmp(&self, other: &Self) -> Ordering {
        self.0.total_cmp(&other.0).then(self.1.total_cmp(&other.1))
    }
}

/// Min-heap entry.
#[derive(Debug, PartialEq, Eq)]
struct Entry(Key, usize);
impl PartialOrd for Entry {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Entry {
    fn cmp(&self, other: &Self) -> Ordering {
        other.0.cmp(&self.0).then(other.1.cmp(&self.1))
    }
}

/// Plain A* from `start` to `goal`: the cheapest path and its cost.
pub fn astar(
    grid: &CostGrid,
    start: (usize, usize),
    goal: (usize, usize),
    min_cost_s_per_m: f64,
) -> Option<(Vec<(usize, usize)>, f64)> {
    let scale = min_cost_s_per_m * grid.resolution_m;
    let idx = |c: (usize, usize)| c.1 * grid.width + c.0;
    let mut g = vec![f64::INFINITY; grid.width * grid.height];
    let mut parent = vec![usize::MAX; grid.width * grid.height];
    let mut open = BinaryHeap::new();
    g[idx(start)] = 0.0;
    open.push(Entry(Key(octile(start, goal, scale), 0.0), idx(start)));
    while let Some(Entry(Key(f, _), i)) = open.pop() {
        let c = (i % grid.width, i / grid.width);
        if f > g[i] + octile(c, goal, scale) + 1e-9 {
            continue; // stale entry
        }
        if c == goal {
            let mut path = vec![c];
            let mut k = i;
            while parent[k] != usize::MAX {
                k = parent[k];
                path.push((k % grid.width, k / grid.width));
            }
            path.reverse();
            return Some((path, g[i]));
        }
        for n in grid.neighbours(c) {
            let cand = g[i] + grid.step_cost(c, n);
            if cand < g[idx(n)] {
                g[idx(n)] = cand;
                parent[idx(n)] = i;
                open.push(Entry(Key(cand + octile(n, goal, scale), 0.0), idx(n)));
            }
        }
    }
    None
}

/// Every cell's cost to reach `goal` (seconds, as [`CostGrid::step_cost`]
/// sums them; infinite where no path leads): Dijkstra outward from the goal
/// over reversed steps. The simulator's operator judges progress by it, as a
/// person who knows the map sees whether the robot is getting closer.
pub fn cost_to_go(grid: &CostGrid, goal: (usize, usize)) -> Vec<f64> {
    let idx = |c: (usize, usize)| c.1 * grid.width + c.0;
    let mut g = vec![f64::INFINITY; grid.width * grid.height];
    if goal.0 >= grid.width || goal.1 >= grid.height {
        return g;
    }
    let mut open = BinaryHeap::new();
    g[idx(goal)] = 0.0;
    open.push(Entry(Key(0.0, 0.0), idx(goal)));
    while let Some(Entry(Key(d, _), i)) = open.pop() {
        if d > g[i] {
            continue; // stale entry
        }
        let b = (i % grid.width, i / grid.width);
        for a in grid.neighbours(b) {
            let cand = d + grid.step_cost(a, b);
            if cand < g[idx(a)] {
                g[idx(a)] = cand;
                open.push(Entry(Key(cand, 0.0), idx(a)));
            }
        }
    }
    g
}

/// D* Lite's priority queue (a 4-ary heap): each vertex at most once, ordered by its key
/// and then its index, with every vertex's place in the heap kept so that
/// re-keying or removing it happens in place. (A heap that leaves stale
/// entries behind grows to several entries per vertex when a far-field
/// frame changes tens of thousands of cells; popping those was a fifth of
/// the navigation benchmark's time.) The vertex on top is the same one a
/// lazy heap would give: the order is total.
///
/// A repair pops only the vertices keyed below the start's key; the many
/// a far-field frame queues beside and behind the robot stay queued,
/// frame after frame. Those keyed at or above [`Self::bound`] wait in an
/// unordered list (`far`) instead of the heap: queuing, re-keying and
/// removing them is O(1), and the heap the search works in stays small.
/// They join the heap when the search reaches the bound
/// ([`Self::top`]), so what comes out on top is unchanged.
#[derive(Debug)]
struct VertexQueue {
    /// The heap. Vertex indices fit in u32: the planner's grid side is at
    /// most 20,000 cells (`max_side_cells`).
    heap: Vec<(Key, u32)>,
    /// Queued vertices keyed (first component) at or above `bound`.
    far: Vec<(Key, u32)>,
    /// No vertex in `far` has a first key component below this.
    bound: f64,
    /// Nor below this (a lower bound, exact after each scan of `far`): a
    /// far-field trial's `far` grows to hundreds of thousands of vertices
    /// behind the robot that no rise of the bound reaches (FITAM's loop
    /// raised it at 43 of 127 repairs, each scanning ~142,000), so a rise
    /// below it skips the scan.
    far_least: f64,
    /// Where each vertex sits: its index in `heap`, [`Self::FAR`] with its
    /// index in `far`, or [`Self::ABSENT`].
    place: Vec<u32>,
}

impl Default for VertexQueue {
    fn default() -> Self {
        Self::new(0)
    }
}

impl VertexQueue {
    const ABSENT: u32 = u32::MAX;
    /// Marks a place in `far`: heap and list places stay below it, as
    /// vertex counts do ([`DStarLite::new`] refuses more).
    const FAR: u32 = 1 << 31;

    fn new(vertices: usize) -> Self {
        Self {
            heap: Vec::new(),
            far: Vec::new(),
            bound: f64::INFINITY,
            far_least: f64::INFINITY,
            place: vec![Self::ABSENT; vertices],
        }
    }

    /// Children per node. Four halves the depth a key travels on every
    /// pop and re-key (the search's hottest loop) and keeps a node's
    /// children in two cache lines.
    const ARITY: usize = 4;

    /// `a` comes out before `b`: by key, then by vertex. Keys are sums of
    /// non-negative costs, the heuristic and km (never negative or NaN), and
    /// for those an f64's bits order as its value: integer compares, where
    /// `total_cmp` cost a fifth of every heap step.
    fn before(a: &(Key, u32), b: &(Key, u32)) -> bool {
        debug_assert!(a.0 .0 >= 0.0 && a.0 .1 >= 0.0 && b.0 .0 >= 0.0 && b.0 .1 >= 0.0);
        // Without branches: which child is least is a coin toss the branch
        // predictor loses, at every level of every pop.
        let (a1, b1) = (a.0 .0.to_bits(), b.0 .0.to_bits());
        let (a2, b2) = (a.0 .1.to_bits(), b.0 .1.to_bits());
        (a1 < b1) | ((a1 == b1) & ((a2 < b2) | ((a2 == b2) & (a.1 < b.1))))
    }

    /// The place of the least of the entries at `i` and `j`.
    fn least_of(&self, i: usize, j: usize) -> usize {
        if Self::before(&self.heap[j], &self.heap[i]) {
            j
        } else {
            i
        }
    }

    /// The first vertex in key order, moving waiting ones into the heap
    /// when the heap's top is at or past the bound.
    fn top(&mut self) -> Option<(Key, usize)> {
        loop {
            match self.heap.first() {
                Some(&(k, v)) if k.0 < self.bound || self.far.is_empty() => {
                    return Some((k, v as usize))
                }
                None if self.far.is_empty() => return None,
                _ => {
                    // The smallest waiting key and a margin above it: at
                    // least it joins (keys in `far` are finite, see
                    // `waits`), so the loop ends.
                    let least = self
                        .far
                        .iter()
                        .map(|e| e.0 .0)
                        .fold(f64::INFINITY, f64::min);
                    self.raise_bound(least + Self::margin(least));
                }
            }
        }
    }

    /// How far above the start's key the bound is set: vertices just
    /// above it are popped when the start's key rises in a repair.
    fn margin(k: f64) -> f64 {
        (0.01 * k).max(1.0)
    }

    /// Vertices keyed at or above `k1` (plus [`Self::margin`]) may wait
    /// outside the heap from now on.
    fn set_bound(&mut self, k1: f64) {
        let b = k1 + Self::margin(k1);
        if b > self.bound {
            self.raise_bound(b);
        } else {
            self.lower_bound(b);
        }
    }

    /// Moves the heap's vertices keyed at or above `b` out to wait, and
    /// rebuilds the heap from the rest. The start's key falls as the robot
    /// moves (its g drops by the cost travelled, km rises only by the
    /// heuristic's cheaper distance), so each repair's bound is below the
    /// last: what the last search left in the heap between the two would
    /// otherwise stay there, and every pop of every later repair walks
    /// past it (the synthetic FITAM step of `bench planning`: a repair
    /// started from 16,000-19,000 heap vertices, 8,000-9,000 with this).
    fn lower_bound(&mut self, b: f64) {
        self.bound = b;
        if self.heap.iter().all(|e| !self.waits(e.0)) {
            return;
        }
        let mut kept = 0;
        for i in 0..self.heap.len() {
            let e = self.heap[i];
            if self.waits(e.0) {
                self.far_push(e);
            } else {
                self.heap[kept] = e;
                kept += 1;
            }
        }
        self.heap.truncate(kept);
        for (i, e) in self.heap.iter().enumerate() {
            self.place[e.1 as usize] = i as u32;
        }
        if kept > 1 {
            for i in (0..=(kept - 2) / Self::ARITY).rev() {
                self.sift_down(i);
            }
        }
    }

    /// Moves the waiting vertices keyed below `b` into the heap.
    fn raise_bound(&mut self, b: f64) {
        self.bound = b;
        if self.far_least >= b {
            return;
        }
        let (mut i, mut least) = (0, f64::INFINITY);
        while i < self.far.len() {
            let k1 = self.far[i].0 .0;
            if k1 < b {
                let e = self.far_take(i);
                self.heap_push(e);
            } else {
                least = least.min(k1);
                i += 1;
            }
        }
        self.far_least = least;
    }

    /// Puts `e` in `far` (its vertex's place included).
    fn far_push(&mut self, e: (Key, u32)) {
        self.place[e.1 as usize] = Self::FAR | self.far.len() as u32;
        self.far_least = self.far_least.min(e.0 .0);
        self.far.push(e);
    }

    /// Takes entry `i` out of `far` (its vertex's place is the caller's).
    fn far_take(&mut self, i: usize) -> (Key, u32) {
        let e = self.far.swap_remove(i);
        if let Some(moved) = self.far.get(i) {
            self.place[moved.1 as usize] = Self::FAR | i as u32;
        }
        e
    }

    fn heap_push(&mut self, e: (Key, u32)) {
        self.heap.push(e);
        self.sift_up(self.heap.len() - 1);
    }

    /// Whether a vertex keyed `k` waits outside the heap. Never an
    /// infinite key (D* Lite queues none: a queued vertex has g != rhs, so
    /// the smaller is finite), which no finite bound would ever let in.
    fn waits(&self, k: Key) -> bool {
        k.0 >= self.bound && k.0.is_finite()
    }

    /// Queues `v` with key `k`, or re-keys it if queued.
    fn set(&mut self, v: usize, k: Key) {
        match self.place[v] {
            Self::ABSENT if self.waits(k) => self.far_push((k, v as u32)),
            Self::ABSENT => self.heap_push((k, v as u32)),
            p if p & Self::FAR != 0 => {
                let i = (p & !Self::FAR) as usize;
                if self.waits(k) {
                    self.far[i].0 = k;
                    self.far_least = self.far_least.min(k.0);
                } else {
                    self.far_take(i);
                    self.heap_push((k, v as u32));
                }
            }
            p => {
                let p = p as usize;
                let raised = Self::before(&self.heap[p], &(k, v as u32));
                self.heap[p].0 = k;
                if raised {
                    self.sift_down(p);
                } else {
                    self.sift_up(p);
                }
            }
        }
    }

    fn remove(&mut self, v: usize) {
        let p = self.place[v];
        if p == Self::ABSENT {
            return;
        }
        self.place[v] = Self::ABSENT;
        if p & Self::FAR != 0 {
            self.far_take((p & !Self::FAR) as usize);
            return;
        }
        let last = self.heap.pop().expect("a queued vertex is in the heap");
        let p = p as usize;
        if p < self.heap.len() {
            self.heap[p] = last;
            let p = self.sift_down(p);
            self.sift_up(p);
        }
    }

    /// Empties the queue (every vertex absent, no bound).
    fn clear(&mut self) {
        for &(_, v) in self.heap.iter().chain(&self.far) {
            self.place[v as usize] = Self::ABSENT;
        }
        self.heap.clear();
        self.far.clear();
        self.bound = f64::INFINITY;
        self.far_least = f64::INFINITY;
    }

    /// How many vertices are queued.
    #[cfg(test)]
    fn len(&self) -> usize {
        self.heap.len() + self.far.len()
    }

    /// Moves the entry at `i` up to its place (entries it passes move down
    /// into the hole) and records every moved entry's place; returns where
    /// it ends.
    fn sift_up(&mut self, mut i: usize) -> usize {
        let e = self.heap[i];
        while i > 0 {
            let parent = (i - 1) / Self::ARITY;
            if !Self::before(&e, &self.heap[parent]) {
                break;
            }
            self.heap[i] = self.heap[parent];
            self.place[self.heap[i].1 as usize] = i as u32;
            i = parent;
        }
        self.heap[i] = e;
        self.place[e.1 as usize] = i as u32;
        i
    }

    /// As [`Self::sift_up`], downwards.
    fn sift_down(&mut self, mut i: usize) -> usize {
        let e = self.heap[i];
        let n = self.heap.len();
        loop {
            let first = Self::ARITY * i + 1;
            if first >= n {
                break;
            }
            let least = if first + Self::ARITY <= n {
                // A tournament of two pairs: two compares deep, not three.
                let a = self.least_of(first, first + 1);
                let b = self.least_of(first + 2, first + 3);
                self.least_of(a, b)
            } else {
                (first + 1..n).fold(first, |least, c| self.least_of(least, c))
            };
            if !Self::before(&self.heap[least], &e) {
                break;
            }
            self.heap[i] = self.heap[least];
            self.place[self.heap[i].1 as usize] = i as u32;
            i = least;
        }
        self.heap[i] = e;
        self.place[e.1 as usize] = i as u32;
        i
    }
}

/// An incremental planner over a [`CostGrid`].
pub struct DStarLite {
    grid: CostGrid,
    start: (usize, usize),
    last_start: (usize, usize),
    goal: (usize, usize),
    scale: f64,
    km: f64,
    /// Each vertex's [g, rhs], side by side: nearly every read of one
    /// (a key, a consistency test) reads the other, so one cache line
    /// serves both on grids tens of megabytes large.
    gr: Vec<[f64; 2]>,
    open: VertexQueue,
    /// Vertices waiting in [`Self::set_costs`] for their update, and
    /// which are (so each is updated once).
    to_update: Vec<usize>,
    dirty: Vec<bool>,
    /// No search since the planner was made or retargeted: every g is
    /// infinite, so a cost change moves no rhs but the goal's (always 0)
    /// and [`Self::set_costs`] only writes the grid.
    unsearched: bool,
    /// Vertices expanded over the planner's life (to show the repair is cheap).
    pub expanded: usize,
}

impl DStarLite {
    /// A planner over `grid` from `start` to `goal`. Panics on a grid of
    /// 2^31 cells or more (the planner's config keeps grids far below).
    pub fn new(
        grid: CostGrid,
        start: (usize, usize),
        goal: (usize, usize),
        min_cost_s_per_m: f64,
    ) -> Self {
        let n = grid.width * grid.height;
        // The queue names vertices in u32 (WorldPlanner's grids are at most
        // 20,000 x 20,000 cells; g and rhs alone would need 64 GB past this).
        assert!(
            n < VertexQueue::FAR as usize,
            "a {} x {} grid has more cells than D* Lite's queue can name",
            grid.width,
            grid.height
        );
        // The heuristic a millionth under the cheapest cell. A key is a sum
        // of step costs plus the heuristic plus km; where the heuristic is
        // tight (road cells at exactly the cheapest cost) the key of a
        // vertex on the start's path equals the start's key on paper and can
        // exceed it by one bit in floating point, which ended the search
        // with that vertex unsettled and the greedy path cycling through it.
        // A millionth keeps every such key below the start's by far more
        // than rounding, and costs the search nothing measurable.
        let scale = min_cost_s_per_m * grid.resolution_m * (1.0 - 1e-6);
        let mut p = Self {
            grid,
            start,
            last_start: start,
            goal,
            scale,
            km: 0.0,
            gr: vec![[f64::INFINITY; 2]; n],
            open: VertexQueue::new(n),
            to_update: Vec::new(),
            dirty: vec![false; n],
            expanded: 0,
            unsearched: true,
        };
        let gi = p.idx(goal);
        p.gr[gi][RHS] = 0.0;
        let k = p.key(gi);
        p.open.set(gi, k);
        p
    }

    pub fn grid(&self) -> &CostGrid {
        &self.grid
    }

    pub fn start(&self) -> (usize, usize) {
        self.start
    }

    pub fn goal(&self) -> (usize, usize) {
        self.goal
    }

    fn idx(&self, c: (usize, usize)) -> usize {
        c.1 * self.grid.width + c.0
    }

    fn cell(&self, i: usize) -> (usize, usize) {
        self.grid.cell_of(i)
    }

    fn key(&self, i: usize) -> Key {
        let m = self.gr[i][G].min(self.gr[i][RHS]);
        Key(
            m + octile(self.start, self.cell(i), self.scale) + self.km,
            m,
        )
    }

    fn top(&mut self) -> Option<(Key, usize)> {
        self.open.top()
    }

    /// rhs(u) = min over successors s of c(u, s) + g(s).
    fn best_successor(&self, u: usize) -> f64 {
        let grid = &self.grid;
        let w = grid.width;
        let (x, y) = self.cell(u);
        if x > 0 && y > 0 && x + 1 < w && y + 1 < grid.height {
            // An interior cell, unrolled: the 3x3 block read once, each
            // neighbour's cost and g once (as `around` + `step_cost_around`
            // compute them, to the bit). Updating a far-field frame's
            // vertices is mostly this.
            let (c, gr, r) = (&grid.costs, &self.gr, grid.resolution_m);
            let via = |j: usize, diagonal: bool| {
                let cj = c[j];
                if CostGrid::blocked(cj) {
                    f64::INFINITY
                } else {
                    cj as f64 * r * if diagonal { SQRT2 } else { 1.0 } + gr[j][G]
                }
            };
            let (east, west, south, north) = (u + 1, u - 1, u + w, u - w);
            let mut best = via(east, false)
                .min(via(west, false))
                .min(via(south, false))
                .min(via(north, false));
            let free = |j: usize| !CostGrid::blocked(c[j]);
            let (fe, fw, fs, fn_) = (free(east), free(west), free(south), free(north));
            if fe && fs {
                best = best.min(via(south + 1, true));
            }
            if fe && fn_ {
                best = best.min(via(north + 1, true));
            }
            if fw && fs {
                best = best.min(via(south - 1, true));
            }
            if fw && fn_ {
                best = best.min(via(north - 1, true));
            }
            return best;
        }
        let a = self.grid.around(u);
        a.iter()
            .map(|(k, s)| self.grid.step_cost_around(&a, k, s) + self.gr[s][G])
            .fold(f64::INFINITY, f64::min)
    }

    /// Recomputes rhs(u) and queues or unqueues `u` to match. A queued
    /// vertex whose rhs did not change keeps its key: keys only grow as
    /// the robot moves (km), so the queued one stays a lower bound, which
    /// is all the search needs (it re-keys a vertex it finds stale on
    /// top); re-keying it here was a heap operation for each of the
    /// thousands of cells a far-field frame leaves as they were.
    fn update_vertex(&mut self, u: usize) {
        if u != self.goal_index() {
            let rhs = self.best_successor(u);
            if rhs == self.gr[u][RHS] {
                return;
            }
            self.gr[u][RHS] = rhs;
        }
        self.requeue(u);
    }

    fn goal_index(&self) -> usize {
        self.idx(self.goal)
    }

    /// Queues `u` if it is inconsistent, takes it out otherwise.
    fn requeue(&mut self, u: usize) {
        if self.gr[u][G] != self.gr[u][RHS] {
            let k = self.key(u);
            self.open.set(u, k);
        } else {
            self.open.remove(u);
        }
    }

    /// Runs the search until the start's cost is settled; returns it (`None`
    /// if the goal cannot be reached).
    pub fn compute(&mut self) -> Option<f64> {
        self.unsearched = false;
        let (si, goal) = (self.idx(self.start), self.goal_index());
        while let Some((k_old, ui)) = self.top() {
            if k_old >= self.key(si) && self.gr[si][RHS] == self.gr[si][G] {
                break;
            }
            let k_new = self.key(ui);
            self.expanded += 1;
            if k_old < k_new {
                self.open.set(ui, k_new);
            } else if self.gr[ui][G] > self.gr[ui][RHS] {
                // u got cheaper: a predecessor's rhs can only drop to the
                // way through u (the optimised version's O(1) update).
                self.gr[ui][G] = self.gr[ui][RHS];
                self.open.remove(ui);
                // Only the vertices whose rhs dropped change: the rest keep
                // their queue place and key (km is fixed during a search).
                let a = self.grid.around(ui);
                for (k, s) in a.iter() {
                    if s != goal {
                        let via_u = self.grid.step_cost_around(&a, k, ui) + self.gr[ui][G];
                        if via_u < self.gr[s][RHS] {
                            self.gr[s][RHS] = via_u;
                            self.requeue(s);
                        }
                    }
                }
            } else {
                // u got dearer: only predecessors whose best way was through
                // u need their rhs recomputed.
                let g_old = self.gr[ui][G];
                self.gr[ui][G] = f64::INFINITY;
                let a = self.grid.around(ui);
                for (k, s) in a.iter() {
                    if s != goal && self.gr[s][RHS] == self.grid.step_cost_around(&a, k, ui) + g_old
                    {
                        self.gr[s][RHS] = self.best_successor(s);
                        self.requeue(s);
                    }
                }
                if ui != goal {
                    self.gr[ui][RHS] = self.best_successor(ui);
                }
                self.requeue(ui);
            }
        }
        let c = self.gr[si][G];
        c.is_finite().then_some(c)
    }

    /// The robot is now at `start`.
    pub fn move_start(&mut self, start: (usize, usize)) {
        self.start = start;
    }

    /// The goal is now `goal`. Every g and rhs measured the way to the old
    /// goal, so the search starts over, but on the grid as it is: where a
    /// new planner allocates and fills its arrays and is handed every cost
    /// again (a guide moves the goal every frame), this only resets the
    /// search's values.
    pub fn retarget(&mut self, goal: (usize, usize)) {
        self.gr.fill([f64::INFINITY; 2]);
        self.open.clear();
        self.km = 0.0;
        self.last_start = self.start;
        self.goal = goal;
        self.unsearched = true;
        let gi = self.idx(goal);
        self.gr[gi][RHS] = 0.0;
        let k = self.key(gi);
        self.open.set(gi, k);
    }

    /// Cell `(x, y)` now costs `cost_s_per_m`. The edges into it change,
    /// and (when it turns blocked or free) the diagonal edges past its
    /// corners; every one of them leaves one of its eight neighbours, so
    /// only those (and itself) are updated. Returns whether anything changed.
    pub fn set_cost(&mut self, x: usize, y: usize, cost_s_per_m: f32) -> bool {
        self.set_costs([(x, y, cost_s_per_m)]) == 1
    }

    /// Several cells' new costs at once: every cost is changed first, then
    /// each vertex next to a changed cell is updated once (D* Lite's "for
    /// all changed edges ... UpdateVertex"), where one call per cell would
    /// update a far-field frame's tens of thousands of cells nine times
    /// each. The same queue results either way. Returns how many cells
    /// changed.
    pub fn set_costs(&mut self, cells: impl IntoIterator<Item = (usize, usize, f32)>) -> usize {
        let mut changed = 0;
        for (x, y, cost_s_per_m) in cells {
            let old = self.grid.get(x, y);
            if old == cost_s_per_m || (old.is_nan() && cost_s_per_m.is_nan()) {
                continue;
            }
            if changed == 0 && self.last_start != self.start {
                // The heuristic's origin moved since the last change: raise
                // every queued key by that much instead of re-keying the queue.
                self.km += octile(self.last_start, self.start, self.scale);
                self.last_start = self.start;
            }
            changed += 1;
            self.grid.set(x, y, cost_s_per_m);
            if self.unsearched {
                continue;
            }
            let c = self.idx((x, y));
            let w = self.grid.width;
            let interior = x > 0 && y > 0 && x + 1 < w && y + 1 < self.grid.height;
            let mut mark = |i: usize| {
                if !self.dirty[i] {
                    self.dirty[i] = true;
                    self.to_update.push(i);
                }
            };
            if interior {
                // The 3x3 block by index, no corner tests: which vertices
                // to update does not depend on what is blocked.
                let block = [
                    c - w - 1,
                    c - w,
                    c - w + 1,
                    c - 1,
                    c,
                    c + 1,
                    c + w - 1,
                    c + w,
                    c + w + 1,
                ];
                block.into_iter().for_each(&mut mark);
            } else {
                let a = self.grid.around(c);
                a.iter().map(|(_, i)| i).chain([c]).for_each(&mut mark);
            }
        }
        // Vertices the repair will not reach wait outside the heap.
        let si = self.idx(self.start);
        self.open.set_bound(self.key(si).0);
        let mut to_update = std::mem::take(&mut self.to_update);
        for &i in &to_update {
            self.dirty[i] = false;
            self.update_vertex(i);
        }
        to_update.clear();
        self.to_update = to_update;
        changed
    }

    /// The current best path from the start to the goal, following the
    /// cheapest successor; empty when there is none.
    pub fn path(&self) -> Vec<(usize, usize)> {
        let mut path = vec![self.start];
        let mut c = self.start;
        let limit = self.grid.width * self.grid.height;
        while c != self.goal && path.len() <= limit {
            let next = self
                .grid
                .neighbours(c)
                .map(|s| (s, self.grid.step_cost(c, s) + self.gr[self.idx(s)][G]))
                .min_by(|a, b| a.1.total_cmp(&b.1));
            match next {
                // Costs are not negative, so along a settled path g never
                // rises; a step that raises it means the
                // search left an inconsistent vertex here, and following
                // it could cycle. No path is the safe answer.
                Some((s, _)) if self.gr[self.idx(s)][G] > self.gr[self.idx(c)][G] => {
                    return Vec::new()
                }
                Some((s, v)) if v.is_finite() => {
                    path.push(s);
                    c = s;
                }
                _ => return Vec::new(),
            }
        }
        path
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Lcg(u64);
    impl Lcg {
        fn next(&mut self) -> f64 {
            self.0 = self
                .0
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (self.0 >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    fn random_grid(rng: &mut Lcg, w: usize, h: usize) -> CostGrid {
        let mut g = CostGrid::new(w, h, 1.0, 1.0);
        for y in 0..h {
            for x in 0..w {
                let r = rng.next();
                g.set(
                    x,
                    y,
                    if r < 0.2 {
                        f32::INFINITY
                    } else {
                        (0.2 + 3.0 * rng.next()) as f32
                    },
                );
            }
        }
        g
    }

    #[test]
    fn the_vertex_queue_gives_what_a_sorted_set_gives_under_any_mix_of_operations() {
        use std::collections::BTreeMap;
        let mut rng = Lcg(7);
        let mut q = VertexQueue::new(64);
        let mut want: BTreeMap<usize, Key> = BTreeMap::new();
        let least = |w: &BTreeMap<usize, Key>| {
            w.iter()
                .map(|(&v, &k)| (k, v))
                .min_by(|a, b| a.0.cmp(&b.0).then(a.1.cmp(&b.1)))
        };
        for step in 0..5000 {
            let v = (rng.next() * 64.0) as usize;
            // Few distinct keys, so ties are common and the index decides.
            let k = Key((rng.next() * 8.0).floor(), (rng.next() * 3.0).floor());
            match (rng.next() * 4.0) as usize {
                0 => {
                    q.remove(v);
                    want.remove(&v);
                }
                1 => {
                    if let Some((_, top)) = q.top() {
                        q.remove(top);
                        want.remove(&top);
                    }
                }
                _ => {
                    q.set(v, k);
                    want.insert(v, k);
                }
            }
            assert_eq!(q.top(), least(&want), "step {step}");
            assert_eq!(q.heap.len(), want.len(), "one entry per vertex");
        }
    }

    /// The queue against a plain ordered set, under random queuing,
    /// re-keying (up and down), removal, popping and bounds that move
    /// both ways: the same vertex comes out on top every time, whether
    /// the vertices wait in the heap or outside it.
    #[test]
    fn the_queue_gives_the_same_top_as_an_ordered_set_whatever_its_bound() {
        use std::collections::BTreeMap;
        let mut rng = Lcg(5);
        let n = 300;
        let mut q = VertexQueue::new(n);
        // vertex -> key, and the keys in order.
        let mut model: BTreeMap<usize, Key> = BTreeMap::new();
        let ordered = |m: &BTreeMap<usize, Key>| {
            m.iter()
                .map(|(&v, &k)| (k, v))
                .min_by(|a, b| a.0.cmp(&b.0).then(a.1.cmp(&b.1)))
        };
        let (mut spilled, mut waited, mut evicted) = (0, 0, 0);
        for step in 0..20_000 {
            let v = (rng.next() * n as f64) as usize;
            let r = rng.next();
            if r < 0.5 {
                // Now and then an infinite key: it must never wait
                // outside the heap, where no bound would let it in.
                let k1 = if rng.next() < 0.02 {
                    f64::INFINITY
                } else {
                    (rng.next() * 100.0).floor()
                };
                let k = Key(k1, (rng.next() * k1.min(100.0)).floor());
                q.set(v, k);
                model.insert(v, k);
            } else if r < 0.65 {
                q.remove(v);
                model.remove(&v);
            } else if r < 0.9 {
                let top = q.top();
                assert_eq!(top, ordered(&model), "step {step}");
                if let Some((_, v)) = top {
                    q.remove(v);
                    model.remove(&v);
                }
            } else {
                let (before, heap_before) = (q.far.len(), q.heap.len());
                q.set_bound((rng.next() * 100.0).floor());
                spilled += usize::from(q.far.len() < before);
                evicted += usize::from(q.heap.len() < heap_before);
            }
            waited = waited.max(q.far.len());
            // The scan a rising bound skips must have nothing to move.
            assert!(
                q.far.iter().all(|e| e.0 .0 >= q.far_least),
                "step {step}: a waiting key below far_least {}",
                q.far_least
            );
            assert_eq!(q.len(), model.len());
            for (&v, &k) in &model {
                let p = q.place[v];
                let e = if p & VertexQueue::FAR != 0 {
                    q.far[(p & !VertexQueue::FAR) as usize]
                } else {
                    q.heap[p as usize]
                };
                assert_eq!(e, (k, v as u32), "step {step}: vertex {v}'s place");
            }
        }
        // Both halves were used, both ways.
        assert!(
            waited > 20 && spilled > 20 && evicted > 20,
            "{waited} waiting at most, {spilled} spills, {evicted} evictions"
        );
        q.clear();
        assert_eq!((q.len(), q.top()), (0, None));
    }

    #[test]
    fn changing_cells_together_leaves_the_planner_as_changing_them_one_by_one() {
        let mut rng = Lcg(11);
        for _ in 0..20 {
            let grid = random_grid(&mut rng, 30, 20);
            let (start, goal) = ((1, 1), (28, 18));
            let mut one = DStarLite::new(grid.clone(), start, goal, 0.2);
            let mut all = DStarLite::new(grid, start, goal, 0.2);
            one.compute();
            all.compute();
            for round in 0..3 {
                let moved = (2 + round, 1 + round);
                one.move_start(moved);
                all.move_start(moved);
                // A block of changes, some cells twice, some unchanged.
                let changes: Vec<(usize, usize, f32)> = (0..120)
                    .map(|_| {
                        let (x, y) = ((rng.next() * 30.0) as usize, (rng.next() * 20.0) as usize);
                        let c = if rng.next() < 0.3 {
                            f32::INFINITY
                        } else {
                            (0.2 + 3.0 * rng.next()) as f32
                        };
                        (x, y, c)
                    })
                    .collect();
                let n_one = changes
                    .iter()
                    .filter(|&&(x, y, c)| one.set_cost(x, y, c))
                    .count();
                assert_eq!(all.set_costs(changes.iter().copied()), n_one);
                assert_eq!(one.compute(), all.compute());
                assert_eq!(one.path(), all.path());
                assert_eq!((&one.gr, one.km), (&all.gr, all.km));
                // The same vertices queued, in the heap or waiting outside
                // it as each one's bound had it. (Their keys may differ:
                // a key is a lower bound, renewed when its vertex is
                // popped, and which are popped depends on that split.)
                let queued = |d: &DStarLite| {
                    let mut q: Vec<u32> =
                        d.open.heap.iter().chain(&d.open.far).map(|e| e.1).collect();
                    q.sort();
                    q
                };
                assert_eq!(one.open.len(), all.open.len());
                assert_eq!(queued(&one), queued(&all));
            }
        }
    }

    /// D* Lite's invariant after a batch of changes: every rhs is the best
    /// way through its successors, and the queue holds exactly the
    /// inconsistent vertices. Mostly small finite-to-finite changes, as a
    /// Kalman update moves a cell, some blocking or clearing a cell (which
    /// moves corner tests too), over a searched and repaired planner.
    #[test]
    fn after_any_batch_of_changes_every_rhs_is_its_best_successor_and_the_queue_the_inconsistent() {
        let mut rng = Lcg(5);
        for trial in 0..30 {
            let (w, h) = (28, 22);
            let grid = random_grid(&mut rng, w, h);
            let (start, goal) = ((1, 1), (w - 2, h - 2));
            let mut d = DStarLite::new(grid, start, goal, 0.2);
            d.compute();
            for round in 0..4 {
                let p = d.path();
                if p.len() > 3 {
                    d.move_start(p[2]);
                }
                let changes: Vec<(usize, usize, f32)> = (0..150)
                    .map(|_| {
                        let (x, y) = (
                            (rng.next() * w as f64) as usize,
                            (rng.next() * h as f64) as usize,
                        );
                        let r = rng.next();
                        let c = if r < 0.1 {
                            f32::INFINITY
                        } else if r < 0.55 {
                            // Dearer or cheaper by a little, as a Kalman
                            // update moves a cell.
                            let old = d.grid().get(x, y);
                            if old.is_finite() {
                                old * (0.8 + 0.4 * rng.next() as f32)
                            } else {
                                1.0
                            }
                        } else {
                            (0.2 + 3.0 * rng.next()) as f32
                        };
                        (x, y, c)
                    })
                    .collect();
                d.set_costs(changes);
                let gi = d.goal_index();
                for u in 0..w * h {
                    if u == gi {
                        continue;
                    }
                    assert_eq!(
                        d.gr[u][RHS].to_bits(),
                        d.best_successor(u).to_bits(),
                        "trial {trial} round {round}: vertex {:?}'s rhs",
                        d.cell(u)
                    );
                }
                let mut queued: Vec<u32> =
                    d.open.heap.iter().chain(&d.open.far).map(|e| e.1).collect();
                queued.sort();
                let inconsistent: Vec<u32> = (0..w * h)
                    .filter(|&u| d.gr[u][G] != d.gr[u][RHS])
                    .map(|u| u as u32)
                    .collect();
                assert_eq!(queued, inconsistent, "trial {trial} round {round}");
                assert!(d.dirty.iter().all(|&m| !m), "no vertex left marked");
                let want = astar(d.grid(), d.start(), goal, 0.2).map(|(_, c)| c);
                match (want, d.compute()) {
                    (Some(a), Some(b)) => assert!((a - b).abs() < 1e-6, "A* {a} vs {b}"),
                    (None, None) => {}
                    other => panic!("trial {trial} round {round}: {other:?}"),
                }
            }
        }
    }

    #[test]
    fn a_retargeted_planner_plans_as_a_new_one_on_the_same_grid() {
        let mut rng = Lcg(23);
        for trial in 0..20 {
            let (w, h) = (30, 22);
            let mut grid = random_grid(&mut rng, w, h);
            let start = (1, 1);
            grid.set(start.0, start.1, 1.0);
            let mut d = DStarLite::new(grid.clone(), start, (28, 20), 0.2);
            d.compute();
            // The robot moves, cells change, the search repairs.
            let moved = (3, 2);
            grid.set(moved.0, moved.1, 1.0);
            d.move_start(moved);
            d.set_cost(moved.0, moved.1, 1.0);
            for _ in 0..30 {
                let (x, y) = (
                    (rng.next() * w as f64) as usize,
                    (rng.next() * h as f64) as usize,
                );
                if (x, y) != moved {
                    grid.set(x, y, 0.7);
                    d.set_cost(x, y, 0.7);
                }
            }
            d.compute();
            // A new goal on the same grid, and more changes before the search.
            let goal = (5 + trial % 20, 18);
            grid.set(goal.0, goal.1, 1.0);
            d.retarget(goal);
            let mut late = vec![(goal.0, goal.1, 1.0)];
            for _ in 0..30 {
                let (x, y) = (
                    (rng.next() * w as f64) as usize,
                    (rng.next() * h as f64) as usize,
                );
                if (x, y) != moved && (x, y) != goal {
                    late.push((x, y, f32::INFINITY));
                    grid.set(x, y, f32::INFINITY);
                }
            }
            d.set_costs(late);
            let mut fresh = DStarLite::new(grid.clone(), moved, goal, 0.2);
            assert_eq!(d.compute(), fresh.compute(), "trial {trial}");
            assert_eq!(d.path(), fresh.path(), "trial {trial}");
            assert_eq!(d.grid(), fresh.grid());
            assert!(d.gr == fresh.gr, "trial {trial}: the same search");
            assert_eq!(d.open.heap.len(), fresh.open.heap.len(), "trial {trial}");
            let want = astar(&grid, moved, goal, 0.2).map(|(_, c)| c);
            match (d.compute(), want) {
                (Some(a), Some(b)) => assert!((a - b).abs() < 1e-6, "trial {trial}: {a} vs A* {b}"),
                (a, b) => assert_eq!(a, b, "trial {trial}"),
            }
            // And it keeps repairing as any planner does.
            let p = d.path();
            if p.len() > 3 {
                d.move_start(p[2]);
                d.set_cost(p[p.len() / 2].0, p[p.len() / 2].1, f32::INFINITY);
                grid.set(p[p.len() / 2].0, p[p.len() / 2].1, f32::INFINITY);
                let want = astar(&grid, p[2], goal, 0.2).map(|(_, c)| c);
                match (d.compute(), want) {
                    (Some(a), Some(b)) => assert!((a - b).abs() < 1e-6, "trial {trial}"),
                    (a, b) => assert_eq!(a, b, "trial {trial}"),
                }
            }
        }
    }

    #[test]
    fn cost_to_go_is_the_astar_cost_from_every_cell() {
        let mut rng = Lcg(5);
        for _ in 0..5 {
            let grid = random_grid(&mut rng, 25, 18);
            let goal = (20, 12);
            let mut grid = grid;
            grid.set(goal.0, goal.1, 1.0);
            let field = cost_to_go(&grid, goal);
            assert_eq!(field[goal.1 * 25 + goal.0], 0.0);
            let mut reachable = 0;
            for y in 0..18 {
                for x in 0..25 {
                    let want = astar(&grid, (x, y), goal, 0.0).map_or(f64::INFINITY, |p| p.1);
                    let got = field[y * 25 + x];
                    assert!(
                        (got - want).abs() < 1e-9 || (got.is_infinite() && want.is_infinite()),
                        "({x}, {y}): {got} vs A* {want}"
                    );
                    reachable += usize::from(got.is_finite());
                }
            }
            assert!(reachable > 100, "the grids are mostly open: {reachable}");
        }
        let off = cost_to_go(&CostGrid::new(4, 4, 1.0, 1.0), (9, 0));
        assert!(off.iter().all(|c| c.is_infinite()), "a goal off the grid");
    }

    #[test]
    fn dstar_lite_matches_astar_on_random_grids_before_and_after_changes() {
        let mut rng = Lcg(42);
        let mut compared = 0;
        for trial in 0..40 {
            let (w, h) = (24, 18);
            let mut grid = random_grid(&mut rng, w, h);
            let (start, goal) = ((0, 0), (w - 1, h - 1));
            grid.set(start.0, start.1, 1.0);
            grid.set(goal.0, goal.1, 1.0);
            let mut d = DStarLite::new(grid.clone(), start, goal, 0.2);
            let check = |d: &mut DStarLite, grid: &CostGrid, what: &str| {
                let want = astar(grid, d.start(), goal, 0.2).map(|(_, c)| c);
                let got = d.compute();
                match (want, got) {
                    (Some(a), Some(b)) => {
                        assert!(
                            (a - b).abs() < 1e-6,
                            "trial {trial} {what}: A* {a} vs D* Lite {b}"
                        );
                        let p = d.path();
                        assert_eq!(p.first(), Some(&d.start()));
                        assert_eq!(p.last(), Some(&goal));
                        assert!(
                            (grid.path_cost(&p) - a).abs() < 1e-6,
                            "its path costs what it says"
                        );
                        1
                    }
                    (None, None) => 0,
                    other => panic!("trial {trial} {what}: {other:?}"),
                }
            };
            compared += check(&mut d, &grid, "initial");
            // The robot moves two cells along its path, then cells change
            // (some blocked, some cleared, some cheaper) around and ahead of it.
            for round in 0..3 {
                let p = d.path();
                if p.len() > 3 {
                    d.move_start(p[2]);
                }
                for _ in 0..25 {
                    let (x, y) = (
                        (rng.next() * w as f64) as usize,
                        (rng.next() * h as f64) as usize,
                    );
                    if (x, y) == d.start() || (x, y) == goal {
                        continue;
                    }
                    let c = if rng.next() < 0.3 {
                        f32::INFINITY
                    } else {
                        (0.2 + 3.0 * rng.next()) as f32
                    };
                    grid.set(x, y, c);
                    d.set_cost(x, y, c);
                }
                compared += check(&mut d, &grid, &format!("after change {round}"));
            }
        }
        assert!(compared > 80, "only {compared} solvable cases");
    }

    /// FITAM's sense-plan-act (section V-A4) on a road beside a forest:
    /// unknown cells plan at 1 s/m, the agent sees a 25 m disc of true costs
    /// (forest 2, road 0.2) and travels up to 20 m a round. Key sums tie on
    /// paper here (road steps cost exactly the heuristic's 0.2 s/m) and
    /// differ in the last bit; ending the search on such a tie left an
    /// unsettled vertex on the path, and the greedy path went back and
    /// forth between two road cells until the iteration limit.
    #[test]
    fn paths_stay_settled_when_keys_tie_up_to_rounding() {
        let (w, h) = (400, 200);
        let mut truth = CostGrid::new(w, h, 1.0, 2.0);
        let mut road = |x0: usize, y0: usize, x1: usize, y1: usize| {
            for y in y0..=y1 {
                for x in x0..=x1 {
                    truth.set(x, y, 0.2);
                }
            }
        };
        road(40, 160, 360, 164);
        road(38, 100, 42, 164);
        road(358, 100, 362, 164);
        let (start, goal) = ((20, 100), (380, 100));
        // The heuristic's scale is the cheapest cell cost as the map holds
        // it (f32), so road steps cost exactly what the heuristic says.
        let mut d = DStarLite::new(CostGrid::new(w, h, 1.0, 1.0), start, goal, 0.2f32 as f64);
        let mut at = start;
        for round in 0..200 {
            d.move_start(at);
            let mut seen = Vec::new();
            for y in at.1.saturating_sub(25)..(at.1 + 26).min(h) {
                for x in at.0.saturating_sub(25)..(at.0 + 26).min(w) {
                    if (x as f64 - at.0 as f64).hypot(y as f64 - at.1 as f64) <= 25.0 {
                        seen.push((x, y, truth.get(x, y)));
                    }
                }
            }
            d.set_costs(seen);
            let cost = d.compute().expect("the world is open");
            let p = d.path();
            let mut cells = p.clone();
            cells.sort_unstable();
            cells.dedup();
            assert!(
                !p.is_empty() && cells.len() == p.len(),
                "round {round} at {at:?}: {} path cells, {} distinct",
                p.len(),
                cells.len()
            );
            assert!(
                (d.grid().path_cost(&p) - cost).abs() < 1e-6 * cost,
                "round {round}"
            );
            // Up to 20 cells along it.
            at = p[p.len().min(21) - 1];
            if at == goal {
                return;
            }
        }
        panic!("the goal was not reached in 200 rounds");
    }

    #[test]
    fn repairs_expand_fewer_vertices_than_planning_again() {
        let mut grid = CostGrid::new(120, 120, 1.0, 1.0);
        for y in 20..100 {
            grid.set(60, y, f32::INFINITY);
        }
        let mut d = DStarLite::new(grid.clone(), (5, 60), (115, 60), 1.0);
        d.compute().unwrap();
        let first = d.expanded;
        // One new obstacle cell near the far end of the path.
        let p = d.path();
        let (x, y) = p[p.len() - 10];
        d.set_cost(x, y, f32::INFINITY);
        grid.set(x, y, f32::INFINITY);
        let cost = d.compute().unwrap();
        let repair = d.expanded - first;
        let (_, want) = astar(&grid, (5, 60), (115, 60), 1.0).unwrap();
        assert!((cost - want).abs() < 1e-9);
        assert!(
            repair * 5 < first,
            "repair expanded {repair}, first search {first}"
        );
    }

    #[test]
    fn diagonal_steps_do_not_squeeze_between_diagonal_obstacles() {
        // Trees at (1, 0) and (0, 1) touch at one corner: the step from
        // (0, 0) to (1, 1) would pass through them, so (0, 0) is shut in.
        let mut grid = CostGrid::new(3, 3, 1.0, 1.0);
        grid.set(1, 0, f32::INFINITY);
        grid.set(0, 1, f32::INFINITY);
        assert_eq!(grid.step_cost((0, 0), (1, 1)), f64::INFINITY);
        assert_eq!(grid.step_cost((1, 1), (0, 0)), f64::INFINITY);
        assert_eq!(astar(&grid, (0, 0), (2, 2), 1.0), None);
        let mut d = DStarLite::new(grid.clone(), (0, 0), (2, 2), 1.0);
        assert_eq!(d.compute(), None);
        // One tree gone: the way is open again, and the repair finds it.
        d.set_costs([(1, 0, 1.0)]);
        let cost = d.compute().expect("open past (1, 0)");
        assert!((cost - (2.0 + SQRT2)).abs() < 1e-9, "{cost}");
        assert!(d.path().contains(&(1, 0)), "{:?}", d.path());
    }

    #[test]
    fn no_path_through_a_closed_wall() {
        let mut grid = CostGrid::new(10, 10, 1.0, 1.0);
        for y in 0..10 {
            grid.set(5, y, f32::INFINITY);
        }
        let mut d = DStarLite::new(grid.clone(), (0, 0), (9, 9), 1.0);
        assert_eq!(d.compute(), None);
        assert!(d.path().is_empty());
        assert!(astar(&grid, (0, 0), (9, 9), 1.0).is_none());
        // Open a door: found incrementally.
        d.set_cost(5, 7, 1.0);
        assert!(d.compute().is_some());
        assert!(d.path().contains(&(5, 7)));
    }
}
