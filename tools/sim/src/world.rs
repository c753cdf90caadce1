//! The simulated world: a land-cover raster with obstacles on it, 1 m cells,
//! local ENU metres with cell (x, y) centred at (x * res, y * res).
//!
//! Costs are FITAM's simulated terrain costs (s/m): road 0.2, field 1/3,
//! grass 0.5, forest 2, bushes 10; trees, rocks, buildings, walls and water
//! are lethal. Trails (0.3) sit between road and field.

/// Land cover of a cell.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum Cover {
    Road,
    Trail,
    Grass,
    Field,
    Bushes,
    Forest,
    Water,
    Rock,
    Building,
}

/// Something standing on a cell.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum Obstacle {
    None,
    Tree,
    Bush,
    Rock,
    Wall,
    /// HIP's traversable tall grass (section III): taller than a height
    /// threshold, yet the robot drives through it.
    TallGrass,
    /// HIP's low untraversable obstacles: a shrub and a stone, under a
    /// height threshold, yet they stop the robot.
    Shrub,
    Stone,
}

/// Class ids of the rendered class image (and the oracle perception's class
/// map). 0 is sky.
pub mod class {
    pub const SKY: u8 = 0;
    pub const ROAD: u8 = 1;
    pub const TRAIL: u8 = 2;
    pub const GRASS: u8 = 3;
    pub const FIELD: u8 = 4;
    pub const BUSHES: u8 = 5;
    pub const FOREST_FLOOR: u8 = 6;
    pub const WATER: u8 = 7;
    pub const ROCK: u8 = 8;
    pub const BUILDING: u8 = 9;
    pub const TREE: u8 = 10;
    pub const WALL: u8 = 11;
    pub const TALL_GRASS: u8 = 12;
    pub const SHRUB: u8 = 13;
    pub const COUNT: usize = 14;
    /// Names, by id.
    pub const NAMES: [&str; COUNT] = [
        "sky",
        "road",
        "trail",
        "grass",
        "field",
        "bushes",
        "forest_floor",
        "water",
        "rock",
        "building",
        "tree",
        "wall",
        "tall_grass",
        "shrub",
    ];
}

impl Cover {
    pub fn cost_s_per_m(self) -> f32 {
        match self {
            Cover::Road => 0.2,
            Cover::Trail => 0.3,
            Cover::Field => 1.0 / 3.0,
            Cover::Grass => 0.5,
            Cover::Forest => 2.0,
            Cover::Bushes => 10.0,
            Cover::Water | Cover::Rock | Cover::Building => f32::INFINITY,
        }
    }

    pub fn class_id(self) -> u8 {
        match self {
            Cover::Road => class::ROAD,
            Cover::Trail => class::TRAIL,
            Cover::Grass => class::GRASS,
            Cover::Field => class::FIELD,
            Cover::Bushes => class::BUSHES,
            Cover::Forest => class::FOREST_FLOOR,
            Cover::Water => class::WATER,
            Cover::Rock => class::ROCK,
            Cover::Building => class::BUILDING,
        }
    }

    /// Height above the ground of what the cover itself presents (a
    /// building's walls, bushes), metres.
    pub fn height_m(self) -> f32 {
        match self {
            Cover::Building => 6.0,
            Cover::Bushes => 1.0,
            _ => 0.0,
        }
    }
}

impl Obstacle {
    pub fn height_m(self) -> f32 {
        match self {
            Obstacle::None => 0.0,
            Obstacle::Tree => 8.0,
            Obstacle::Bush => 1.2,
            Obstacle::Rock => 1.0,
            Obstacle::Wall => 2.5,
            Obstacle::TallGrass => 1.2,
            Obstacle::Shrub => 0.4,
            Obstacle::Stone => 0.3,
        }
    }

    pub fn class_id(self) -> Option<u8> {
        match self {
            Obstacle::None => None,
            Obstacle::Tree => Some(class::TREE),
            Obstacle::Bush => Some(class::BUSHES),
            Obstacle::Rock => Some(class::ROCK),
            Obstacle::Wall => Some(class::WALL),
            Obstacle::TallGrass => Some(class::TALL_GRASS),
            Obstacle::Shrub => Some(class::SHRUB),
            Obstacle::Stone => Some(class::ROCK),
        }
    }

    /// Cost of a cell holding it (bushes can be pushed through, slowly;
    /// tall grass a little slower than grass).
    pub fn cost_s_per_m(self) -> Option<f32> {
        match self {
            Obstacle::None => None,
            Obstacle::Bush => Some(10.0),
            Obstacle::TallGrass => Some(1.0),
            _ => Some(f32::INFINITY),
        }
    }
}

/// What a ray meets at a cell.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CellLook {
    pub ground_m: f32,
    /// Top of whatever stands there (= ground when nothing does).
    pub top_m: f32,
    pub ground_class: u8,
    pub top_class: u8,
}

#[derive(Debug, Clone)]
pub struct World {
    pub width: usize,
    pub height: usize,
    pub resolution_m: f64,
    cover: Vec<Cover>,
    obstacle: Vec<Obstacle>,
    /// Terrain height per cell, metres; `None` = flat.
    ground_m: Option<Vec<f32>>,
    /// The highest ground (at least 0 m, the flat ground outside) and the
    /// tallest cover or obstacle ever set: together an upper bound on every
    /// cell's top, so a renderer can tell when nothing farther can rise
    /// into view.
    max_ground_m: f32,
    max_stands_m: f32,
}

impl World {
    pub fn new(width: usize, height: usize, fill: Cover) -> Self {
        Self {
            width,
            height,
            resolution_m: 1.0,
            cover: vec![fill; width * height],
            obstacle: vec![Obstacle::None; width * height],
            ground_m: None,
            max_ground_m: 0.0,
            max_stands_m: fill.height_m(),
        }
    }

    /// An upper bound on every cell's [`CellLook::top_m`], inside the
    /// world or out (outside is flat grass at 0 m).
    pub fn top_bound_m(&self) -> f32 {
        self.max_ground_m + self.max_stands_m
    }

    pub fn contains(&self, x: i64, y: i64) -> bool {
        x >= 0 && y >= 0 && (x as usize) < self.width && (y as usize) < self.height
    }

    fn idx(&self, x: i64, y: i64) -> Option<usize> {
        self.contains(x, y)
            .then(|| y as usize * self.width + x as usize)
    }

    /// The cell holding world point (x, y).
    pub fn cell_of(&self, x_m: f64, y_m: f64) -> (i64, i64) {
        (
            (x_m / self.resolution_m + 0.5).floor() as i64,
            (y_m / self.resolution_m + 0.5).floor() as i64,
        )
    }

    pub fn cover(&self, x: i64, y: i64) -> Option<Cover> {
        self.idx(x, y).map(|i| self.cover[i])
    }

    pub fn obstacle(&self, x: i64, y: i64) -> Obstacle {
        self.idx(x, y).map_or(Obstacle::None, |i| self.obstacle[i])
    }

    pub fn set_cover(&mut self, x: i64, y: i64, c: Cover) {
        if let Some(i) = self.idx(x, y) {
            self.cover[i] = c;
            self.max_stands_m = self.max_stands_m.max(c.height_m());
        }
    }

    pub fn set_obstacle(&mut self, x: i64, y: i64, o: Obstacle) {
        if let Some(i) = self.idx(x, y) {
            self.obstacle[i] = o;
            self.max_stands_m = self.max_stands_m.max(o.height_m());
        }
    }

    /// Sets the terrain height field (one value per cell).
    pub fn set_ground(&mut self, heights_m: Vec<f32>) {
        assert_eq!(heights_m.len(), self.width * self.height);
        // A NaN height bounds nothing: the renderer then never ends early.
        self.max_ground_m =
            heights_m.iter().fold(
                0.0f32,
                |m, &h| {
                    if h.is_nan() {
                        f32::INFINITY
                    } else {
                        m.max(h)
                    }
                },
            );
        self.ground_m = Some(heights_m);
    }

    pub fn ground_m(&self, x: i64, y: i64) -> f32 {
        match (&self.ground_m, self.idx(x, y)) {
            (Some(g), Some(i)) => g[i],
            _ => 0.0,
        }
    }

    /// Traversal cost of a cell (s/m); outside the world is lethal.
    pub fn cost_s_per_m(&self, x: i64, y: i64) -> f32 {
        let Some(i) = self.idx(x, y) else {
            return f32::INFINITY;
        };
        self.obstacle[i]
            .cost_s_per_m()
            .map_or(self.cover[i].cost_s_per_m(), |c| {
                c.max(self.cover[i].cost_s_per_m())
            })
    }

    pub fn lethal(&self, x: i64, y: i64) -> bool {
        self.cost_s_per_m(x, y).is_infinite()
    }

    /// What a camera ray sees at a cell (outside the world: flat grass).
    pub fn look(&self, x: i64, y: i64) -> CellLook {
        let ground = self.ground_m(x, y);
        let (cover, obstacle) = match self.idx(x, y) {
            Some(i) => (self.cover[i], self.obstacle[i]),
            None => (Cover::Grass, Obstacle::None),
        };
        let (top, top_class) = match obstacle.class_id() {
            Some(c) => (ground + obstacle.height_m(), c),
            None => (ground + cover.height_m(), cover.class_id()),
        };
        CellLook {
            ground_m: ground,
            top_m: top,
            ground_class: cover.class_id(),
            top_class,
        }
    }

    /// Fills an axis-aligned rectangle of cells (inclusive corners).
    pub fn fill_cover(&mut self, x0: i64, y0: i64, x1: i64, y1: i64, c: Cover) {
        for y in y0.min(y1)..=y0.max(y1) {
            for x in x0.min(x1)..=x0.max(x1) {
                self.set_cover(x, y, c);
            }
        }
    }

    /// Places an obstacle on every cell of a straight segment.
    pub fn line_obstacle(&mut self, from: (i64, i64), to: (i64, i64), o: Obstacle) {
        let n = (to.0 - from.0).abs().max((to.1 - from.1).abs()).max(1);
        for k in 0..=n {
            let x = from.0 + ((to.0 - from.0) as f64 * k as f64 / n as f64).round() as i64;
            let y = from.1 + ((to.1 - from.1) as f64 * k as f64 / n as f64).round() as i64;
            self.set_obstacle(x, y, o);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_top_bound_covers_every_cell_and_a_nan_height_lifts_it_away() {
        let mut w = World::new(20, 10, Cover::Grass);
        assert_eq!(w.top_bound_m(), 0.0);
        w.set_obstacle(3, 4, Obstacle::Tree);
        w.set_ground((0..200).map(|i| i as f32 * 0.01).collect());
        let highest = (0..20)
            .flat_map(|x| (0..10).map(move |y| (x, y)))
            .map(|(x, y)| w.look(x, y).top_m)
            .fold(f32::MIN, f32::max);
        assert!(w.top_bound_m() >= highest && highest > 8.0, "{highest}");
        // A NaN height bounds nothing: no march may end early.
        let mut heights = vec![0.0; 200];
        heights[7] = f32::NAN;
        w.set_ground(heights);
        assert_eq!(w.top_bound_m(), f32::INFINITY);
    }

    #[test]
    fn costs_follow_fitam_and_obstacles_dominate() {
        let mut w = World::new(10, 10, Cover::Grass);
        w.set_cover(1, 1, Cover::Road);
        w.set_obstacle(2, 2, Obstacle::Tree);
        w.set_obstacle(3, 3, Obstacle::Bush);
        assert_eq!(w.cost_s_per_m(1, 1), 0.2);
        assert_eq!(w.cost_s_per_m(0, 0), 0.5);
        assert!(w.lethal(2, 2));
        assert_eq!(w.cost_s_per_m(3, 3), 10.0);
        assert!(w.lethal(-1, 0), "outside is lethal");
        assert_eq!(w.cell_of(2.49, 1.5), (2, 2));
        let look = w.look(2, 2);
        assert_eq!(
            (look.top_m, look.top_class, look.ground_class),
            (8.0, class::TREE, class::GRASS)
        );
    }
}
