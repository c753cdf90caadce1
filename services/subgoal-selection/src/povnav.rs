//! POVNav: Pareto-optimal visual navigation in image space (sections 4.3-4.7).
//!
//! Planning frame (the paper's Fig. 3): origin at the bottom-centre pixel (the
//! robot), x up the image, y to the left. Angles are counter-clockwise (REP-103):
//! positive means left of straight ahead.
//!
//! ```
//! use farsight_subgoal_selection::povnav::{plan, PovnavConfig};
//!
//! // 40x30 navigability image: all navigable below row 10.
//! let (w, h) = (40, 30);
//! let nav: Vec<u8> = (0..w * h).map(|i| if i / w >= 10 { 255 } else { 0 }).collect();
//! let cfg = PovnavConfig::default();
//! let half_width = vec![2usize; h]; // safe half-width per row, pixels
//! let p = plan(&nav, w, h, 0.0, &half_width, &cfg);
//! assert_eq!(p.hog_px, (20.0, 10.0)); // straight ahead, at the horizon
//! ```

use farsight_stage::{ConfigError, Range, Ranges, Validate};
use serde::{Deserialize, Serialize};
use std::f64::consts::{FRAC_PI_2, PI};

/// POVNav's parameters (defaults from the paper and its code).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PovnavConfig {
    /// Column clean-up: a non-navigable run shorter than this (pixels) is noise.
    pub min_obstacle_px: usize,
    /// Horizon clean-up: a morphological opening of the horizon profile over
    /// this many columns removes narrow "cracks" that see far.
    pub opening_columns: usize,
    /// Weight of the navigation objective (angle deviation / pi).
    pub w_navigation: f64,
    /// Weight of the exploration objective (distance / image diagonal).
    pub w_exploration: f64,
    /// Rows between visual path points.
    pub path_row_step: usize,
    /// Largest look-ahead radius for the alignment feature (pixels);
    /// R = min(lambda / 2, max_lookahead_px) as the paper's section 4.8.
    pub max_lookahead_px: f64,
    /// Which of POVNav's parts steer (its section 5.3 ablations, or the
    /// VMPP baseline).
    pub components: PovnavComponents,
    /// VMPP's primitives and weights (`components = "vmpp"`).
    pub vmpp: crate::vmpp::VmppConfig,
}

/// POVNav's parts that steer the robot (section 5.3's ablation rows). The
/// proximity feature, and so the servo's speed law, is kept in every row.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PovnavComponents {
    /// POG, HOG and the visual path: the full system.
    #[default]
    Full,
    /// "POG+HOG": the robot aligns with the HOG itself, no visual path.
    PogHog,
    /// "POG only": the robot aligns with the peripheral optic goal.
    Pog,
    /// Not POVNav: its baseline VMPP (section 5.2.1, [`crate::vmpp`]), DWA's
    /// motion primitives checked against the same horizon.
    Vmpp,
}

impl Default for PovnavConfig {
    fn default() -> Self {
        Self {
            min_obstacle_px: 3,
            opening_columns: 5,
            w_navigation: 1.0,
            w_exploration: 0.5,
            path_row_step: 4,
            max_lookahead_px: 120.0,
            components: PovnavComponents::Full,
            vmpp: crate::vmpp::VmppConfig::default(),
        }
    }
}

impl Validate for PovnavConfig {
    fn ranges(&self, r: &mut Ranges) {
        r.key(
            "min_obstacle_px",
            self.min_obstacle_px,
            Range::between(1.0, 1000.0).unit("px"),
        )
        .key(
            "opening_columns",
            self.opening_columns,
            Range::between(1.0, 999.0).unit("columns"),
        )
        .key(
            "w_navigation",
            self.w_navigation,
            Range::between(0.0, 100.0),
        )
        .key(
            "w_exploration",
            self.w_exploration,
            Range::between(0.0, 100.0),
        )
        .key(
            "path_row_step",
            self.path_row_step,
            Range::between(1.0, 1000.0).unit("rows"),
        )
        .key(
            "max_lookahead_px",
            self.max_lookahead_px,
            Range::above_to(0.0, 10_000.0).unit("px"),
        )
        .nested("vmpp", &self.vmpp);
    }

    fn check_rules(&self) -> Result<(), ConfigError> {
        ConfigError::check(
            self.opening_columns % 2 == 1,
            "povnav.opening_columns",
            self.opening_columns,
            "an odd number of columns",
        )?;
        self.vmpp.check_rules()
    }
}

/// The visual horizon: per column, how many pixels from the bottom are
/// navigable and connected to the robot (0 = the bottom pixel is blocked).
#[derive(Debug, Clone, PartialEq)]
pub struct VisualHorizon {
    pub width: usize,
    pub height: usize,
    pub navigable_rows: Vec<usize>,
}

impl VisualHorizon {
    /// Image row of the topmost navigable pixel of column `u`, if any.
    pub fn top_row(&self, u: usize) -> Option<usize> {
        let n = self.navigable_rows[u];
        (n > 0).then(|| self.height - n)
    }
}

/// Computes the visual horizon (Definition 3) of a navigability image
/// (255 = navigable): each column is scanned up from the bottom until a
/// non-navigable run of `min_obstacle_px` (shorter runs are noise), then the
/// column profile is opened over `opening_columns` so a crack one or two
/// pixels wide cannot pull the horizon to the sky. Both are 1-D versions of
/// the paper's morphological clean-up, cheap enough for every frame.
pub fn visual_horizon(
    nav: &[u8],
    width: usize,
    height: usize,
    cfg: &PovnavConfig,
) -> VisualHorizon {
    // All columns advance together, one image row at a time from the
    // bottom: row-major reads of the image, and a loop body without branches
    // that the compiler vectorises. A column stops once it has met an
    // obstacle run; the scan ends when every column has.
    // u16 lanes: twice as many per vector as u32, and no image is 65535 rows.
    let min_run = cfg.min_obstacle_px.clamp(1, u16::MAX as usize) as u16;
    let rows_scanned = height.min(nav.len() / width.max(1)).min(u16::MAX as usize);
    let mut top = vec![0u16; width]; // navigable rows counted from the bottom
    let mut run = vec![0u16; width]; // current non-navigable run
    let mut open = vec![u16::MAX; width]; // all ones while the column is still being scanned
    for k in 0..rows_scanned {
        let row = &nav[(height - 1 - k) * width..][..width];
        let k1 = k as u16 + 1;
        let mut still_open = 0;
        // Masks and saturating adds only: the release profile checks
        // overflow, and a checked `+` or `*` here would stop vectorisation.
        for (((t, r), o), &p) in top
            .iter_mut()
            .zip(run.iter_mut())
            .zip(open.iter_mut())
            .zip(row)
        {
            let navigable = 0u16.wrapping_sub((p == 255) as u16); // 0 or 0xffff
            let extend = navigable & *o;
            *t = (k1 & extend) | (*t & !extend);
            *r = r.saturating_add(1) & !navigable;
            *o &= 0u16.wrapping_sub((*r < min_run) as u16);
            still_open |= *o;
        }
        if still_open == 0 {
            break;
        }
    }
    let mut rows: Vec<usize> = top.into_iter().map(|t| t as usize).collect();
    // Opening = erosion (min) then dilation (max) over the window.
    let k = cfg.opening_columns / 2;
    if k > 0 && width > 1 {
        let window = |src: &[usize], pick: fn(usize, usize) -> usize| -> Vec<usize> {
            (0..width)
                .map(|u| {
                    let lo = u.saturating_sub(k);
                    let hi = (u + k).min(width - 1);
                    src[lo..=hi].iter().copied().reduce(pick).unwrap_or(0)
                })
                .collect()
        };
        let eroded = window(&rows, usize::min);
        rows = window(&eroded, usize::max);
    }
    VisualHorizon {
        width,
        height,
        navigable_rows: rows,
    }
}

/// Planning-frame coordinates (x up, y left, pixels) of image pixel (u, v).
pub fn to_plan(u: f64, v: f64, width: usize, height: usize) -> (f64, f64) {
    let u0 = (width as f64 - 1.0) / 2.0;
    ((height as f64 - 1.0) - v, u0 - u)
}

/// Image pixel (u, v) of planning-frame coordinates.
pub fn to_image(x: f64, y: f64, width: usize, height: usize) -> (f64, f64) {
    let u0 = (width as f64 - 1.0) / 2.0;
    (u0 - y, (height as f64 - 1.0) - x)
}

/// The peripheral optic goal (section 4.3): the image-border pixel for goal
/// bearing `theta` (robot frame, counter-clockwise, any angle). Goals ahead map
/// to the left, top and right borders; goals behind map onto the bottom border
/// through the mirrored virtual borders, saturating at the bottom corners. A
/// goal exactly behind maps to the start pixel.
pub fn peripheral_optic_goal(theta: f64, width: usize, height: usize) -> (f64, f64) {
    let theta = (theta + PI).rem_euclid(2.0 * PI) - PI; // (-pi, pi]
    let top = height as f64 - 1.0;
    let left = (width as f64 - 1.0) / 2.0; // y of the left border; the right one is -left
    let (c, s) = (theta.cos(), theta.sin());
    // Ray from the origin to the (possibly mirrored) border rectangle
    // x in [-top, top], y in [-left, left]: first exit along (c, s).
    let tx = if c.abs() > 1e-12 {
        top / c.abs()
    } else {
        f64::INFINITY
    };
    let ty = if s.abs() > 1e-12 {
        left / s.abs()
    } else {
        f64::INFINITY
    };
    let t = tx.min(ty);
    let (x, y) = (c * t, s * t);
    let (x, y) = if c >= -1e-12 {
        (x.max(0.0), y)
    } else {
        // Behind: project the virtual border point back onto the bottom edge.
        (0.0, y)
    };
    let (u, v) = to_image(x, y.clamp(-left, left), width, height);
    // The POG is a border pixel.
    (
        u.round().clamp(0.0, width as f64 - 1.0),
        v.round().clamp(0.0, top),
    )
}

/// What POVNav decided for one navigability image.
#[derive(Debug, Clone, PartialEq)]
pub struct PovnavPlan {
    pub pog_px: (f64, f64),
    pub hog_px: (f64, f64),
    /// The visual path from the start to the HOG, image pixels.
    pub path_px: Vec<(f64, f64)>,
    /// Proximity feature lambda (pixels, Definition 8).
    pub proximity_px: f64,
    /// Alignment feature phi (radians, counter-clockwise, Definition 9).
    pub alignment_rad: f64,
    pub mode: Mode,
}

/// POVNav's operating mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// A safe visual path to the HOG exists.
    Safe,
    /// Part of the path could not keep the safe width (narrow gap, Fig. 7d).
    Fallback,
    /// Nothing navigable ahead (Fig. 7c): the HOG collapses to the start.
    Blocked,
}

fn angle_of(x: f64, y: f64) -> f64 {
    y.atan2(x)
}

/// Runs POVNav on one navigability image. `goal_bearing_rad` is the goal
/// direction in the robot frame; `half_width_px[v]` the safe half-width of the
/// robot footprint at image row `v` (see [`safe_half_widths`]).
pub fn plan(
    nav: &[u8],
    width: usize,
    height: usize,
    goal_bearing_rad: f64,
    half_width_px: &[usize],
    cfg: &PovnavConfig,
) -> PovnavPlan {
    let horizon = visual_horizon(nav, width, height, cfg);
    let pog = peripheral_optic_goal(goal_bearing_rad, width, height);
    let (pxg, pyg) = to_plan(pog.0, pog.1, width, height);
    // A POG at the start (goal exactly behind) has no direction: turn left.
    let theta_g = if pxg.hypot(pyg) < 0.5 {
        FRAC_PI_2
    } else {
        angle_of(pxg, pyg)
    };
    let diag = (width as f64).hypot(height as f64);

    // Horizon optic goal: the best horizon pixel whose footprint is navigable
    // (Lemma 1: Pareto-optimal subgoals lie on the horizon).
    let mut best: Option<((f64, f64), f64)> = None;
    let mut consider = |u: usize, v: usize| {
        // Near the side borders the footprint is clipped to the image: a
        // horizon pixel there is still a valid direction to head.
        let hw = half_width_px.get(v).copied().unwrap_or(0);
        let lo = u.saturating_sub(hw) as i64;
        let hi = u.saturating_add(hw).min(width - 1) as i64;
        if !footprint_clear(&nav[v * width..][..width], lo, hi, cfg.min_obstacle_px) {
            return;
        }
        let (x, y) = to_plan(u as f64, v as f64, width, height);
        let dist = x.hypot(y);
        let ang = if dist < 0.5 { theta_g } else { angle_of(x, y) };
        let cost = cfg.w_navigation * (ang - theta_g).abs() / PI - cfg.w_exploration * dist / diag;
        if best.is_none_or(|(_, c)| cost < c) {
            best = Some(((u as f64, v as f64), cost));
        }
    };
    for u in 0..width {
        if let Some(v) = horizon.top_row(u) {
            consider(u, v);
        }
    }
    // The side borders below the horizon belong to the horizon too.
    for u in [0, width - 1] {
        if let Some(top) = horizon.top_row(u) {
            for v in top..height {
                consider(u, v);
            }
        }
    }
    let start = ((width as f64 - 1.0) / 2.0, height as f64 - 1.0);
    let Some((hog, _)) = best else {
        // Fig. 7c: nothing navigable. The HOG collapses to the start; the
        // proximity drops to zero and the robot aligns with the POG.
        return PovnavPlan {
            pog_px: pog,
            hog_px: start,
            path_px: vec![start],
            proximity_px: 0.0,
            alignment_rad: theta_g,
            mode: Mode::Blocked,
        };
    };

    let proximity = proximity_px(&horizon);

    // The ablations steer by a straight line to the POG or the HOG (their
    // alignment is its direction), with no safe-width check.
    let straight_to = |target: (f64, f64)| {
        let (x, y) = to_plan(target.0, target.1, width, height);
        let alignment = if x.hypot(y) >= 0.5 {
            angle_of(x, y)
        } else {
            theta_g
        };
        PovnavPlan {
            pog_px: pog,
            hog_px: target,
            path_px: vec![start, target],
            proximity_px: proximity,
            alignment_rad: alignment,
            mode: Mode::Safe,
        }
    };
    match cfg.components {
        PovnavComponents::Pog => return straight_to(pog),
        PovnavComponents::PogHog => return straight_to(hog),
        // The stage calls crate::vmpp::plan for VMPP; here it is POVNav.
        PovnavComponents::Full | PovnavComponents::Vmpp => {}
    }
    let (path, mode) = visual_path(nav, width, height, hog, half_width_px, cfg);
    // Alignment (Definition 9): direction to the path point at radius R.
    let r = (proximity / 2.0).min(cfg.max_lookahead_px).max(1.0);
    let target = path
        .iter()
        .map(|&(u, v)| to_plan(u, v, width, height))
        .find(|&(x, y)| x.hypot(y) >= r)
        .or_else(|| path.last().map(|&(u, v)| to_plan(u, v, width, height)));
    let alignment = match target {
        Some((x, y)) if x.hypot(y) >= 0.5 => angle_of(x, y),
        _ => theta_g,
    };
    PovnavPlan {
        pog_px: pog,
        hog_px: hog,
        path_px: path,
        proximity_px: proximity,
        alignment_rad: alignment,
        mode,
    }
}

/// The proximity feature lambda (Definition 8, pixels): the distance from
/// the start (bottom centre) to the nearest horizon pixel.
pub fn proximity_px(horizon: &VisualHorizon) -> f64 {
    let (width, height) = (horizon.width, horizon.height);
    let mut proximity = f64::INFINITY;
    for u in 0..width {
        let n = horizon.navigable_rows[u];
        let v = (height - n).min(height - 1) as f64;
        let (x, y) = to_plan(u as f64, v, width, height);
        proximity = proximity.min(x.hypot(y));
        if (u == 0 || u == width - 1) && n > 0 {
            // Side border below the horizon: nearest is its bottom pixel.
            let (x, y) = to_plan(u as f64, height as f64 - 1.0, width, height);
            proximity = proximity.min(x.hypot(y));
        }
    }
    proximity
}

/// The footprint test along one image row, with the horizon's noise rule
/// turned sideways: only a non-navigable run of at least `min_obstacle_px`
/// pixels blocks the footprint, so speckle in a segmentation mask cannot throw
/// every wide footprint into fallback.
///
/// `fill` counts obstacle pixels in a prefix array once per row, which makes
/// [`Self::clear`] O(1) for any footprint width and the sideways search of
/// Algorithm 1 O(width) per row.
#[derive(Debug, Default)]
pub struct RowObstacles {
    /// `before[i]`: obstacle pixels among columns `0..i`.
    before: Vec<u32>,
}

impl RowObstacles {
    pub fn fill(&mut self, row: &[u8], min_obstacle_px: usize) {
        let min_run = min_obstacle_px.max(1);
        self.before.clear();
        self.before.resize(row.len() + 1, 0);
        let mut run_start = 0;
        for (i, &p) in row.iter().enumerate() {
            if p == 255 {
                run_start = i + 1;
            }
            // A pixel is an obstacle when the non-navigable run through it is
            // long enough; runs are only known at their end, so back-fill.
            let run = i + 1 - run_start;
            let ends = p != 255 && row.get(i + 1).is_none_or(|&q| q == 255);
            self.before[i + 1] = self.before[i];
            if ends && run >= min_run {
                for j in run_start..=i {
                    self.before[j + 1] = self.before[j] + 1;
                }
            }
        }
    }

    /// No obstacle pixel in columns `lo..=hi` (false when out of the row).
    pub fn clear(&self, lo: i64, hi: i64) -> bool {
        lo >= 0
            && hi >= lo
            && (hi as usize) < self.before.len() - 1
            && self.before[hi as usize + 1] == self.before[lo as usize]
    }
}

/// The same test as [`RowObstacles`] for a single footprint, by scanning it
/// (plus the runs that reach into it): cheaper when only one footprint of a
/// row is checked, as for each horizon pixel.
pub fn footprint_clear(row: &[u8], lo: i64, hi: i64, min_obstacle_px: usize) -> bool {
    if lo < 0 || hi < lo || hi as usize >= row.len() {
        return false;
    }
    let (lo, hi) = (lo as usize, hi as usize);
    let min_run = min_obstacle_px.max(1);
    let mut i = lo;
    while i <= hi {
        if row[i] == 255 {
            i += 1;
            continue;
        }
        let mut a = i;
        while a > 0 && row[a - 1] != 255 {
            a -= 1;
        }
        let mut b = i;
        while b + 1 < row.len() && row[b + 1] != 255 {
            b += 1;
        }
        if b + 1 - a >= min_run {
            return false;
        }
        i = b + 1;
    }
    true
}

/// Algorithm 1: march from the HOG toward the start, keeping the footprint's
/// safe half-width free of obstacles (see [`RowObstacles`]) on both sides,
/// shifting sideways when needed (the shift direction is chosen once). Rows
/// with no safe shift are skipped and the path is marked fallback. Returns the
/// path from the start to the HOG.
pub fn visual_path(
    nav: &[u8],
    width: usize,
    height: usize,
    hog: (f64, f64),
    half_width_px: &[usize],
    cfg: &PovnavConfig,
) -> (Vec<(f64, f64)>, Mode) {
    let start_u = (width as f64 - 1.0) / 2.0;
    let bottom = height - 1;
    let row_step = cfg.path_row_step.max(1);
    let mut obstacles = RowObstacles::default();
    let (mut u, mut v) = (hog.0, hog.1.round() as usize);
    let mut shift: Option<i64> = None;
    let mut mode = Mode::Safe;
    let mut path = Vec::new();
    while v < bottom {
        let row = &nav[v * width..][..width];
        let hw = half_width_px.get(v).copied().unwrap_or(0) as i64;
        // Footprints are centred on whole pixels: the path point itself may
        // be fractional, `c` is where its footprint is tested.
        let c = u.round() as i64;
        if !footprint_clear(row, c - hw, c + hw, cfg.min_obstacle_px) {
            // Only a blocked row pays for the prefix counts of the search.
            obstacles.fill(row, cfg.min_obstacle_px);
            let clear_at = |k: i64| obstacles.clear(c + k - hw, c + k + hw);
            let reach = |dir: i64| (1..width as i64).find(|&k| clear_at(dir * k));
            if shift.is_none() {
                // The direction with the nearest safe position at this row.
                shift = match (reach(-1), reach(1)) {
                    (Some(a), Some(b)) => Some(if a <= b { -1 } else { 1 }),
                    (Some(_), None) => Some(-1),
                    (None, Some(_)) => Some(1),
                    (None, None) => None,
                };
            }
            match shift.and_then(|d| reach(d).map(|k| d * k)) {
                Some(k) => u += k as f64,
                None => {
                    mode = Mode::Fallback;
                    let next = (v + row_step).min(bottom);
                    u += (start_u - u) * (next - v) as f64 / (bottom - v) as f64;
                    v = next;
                    continue;
                }
            }
        }
        path.push((u, v as f64));
        let next = (v + row_step).min(bottom);
        // Head straight for the start from here.
        u += (start_u - u) * (next - v) as f64 / (bottom - v) as f64;
        v = next;
    }
    path.push((start_u, bottom as f64));
    path.reverse();
    (path, mode)
}

/// Safe half-width of the robot footprint per image row, pixels, for a camera
/// `camera_height_m` above flat ground: a ground point at row v lies at depth
/// z = fy * h / (v - cy) (below the horizon line), where a half-width of
/// `robot_width_m / 2 + margin_m` spans fx * that / z pixels. Rows at or above
/// the horizon line get 0.
pub fn safe_half_widths(
    height: usize,
    fx: f64,
    fy: f64,
    cy: f64,
    camera_height_m: f64,
    robot_width_m: f64,
    margin_m: f64,
) -> Vec<usize> {
    let half = robot_width_m / 2.0 + margin_m;
    (0..height)
        .map(|v| {
            let below = v as f64 - cy;
            if below <= 0.0 || camera_height_m <= 0.0 {
                0
            } else {
                let z = fy * camera_height_m / below;
                // Wider than any image is as blocked as the whole row; the
                // cap keeps `u +- hw` far from overflow.
                (fx * half / z).round().clamp(0.0, 1_048_576.0) as usize
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(w: usize, h: usize, navigable: impl Fn(usize, usize) -> bool) -> Vec<u8> {
        (0..w * h)
            .map(|i| if navigable(i % w, i / w) { 255 } else { 0 })
            .collect()
    }

    #[test]
    fn horizon_ignores_noise_and_cracks() {
        let (w, h) = (11, 20);
        // Navigable below row 12; a 1-pixel noise hole at (5, 15); a crack of
        // column 8 open to the top.
        let nav = image(w, h, |u, v| (v >= 12 && !(u == 5 && v == 15)) || u == 8);
        let hz = visual_horizon(&nav, w, h, &PovnavConfig::default());
        assert_eq!(
            hz.navigable_rows,
            vec![8; 11],
            "noise ignored, crack opened away"
        );
        let raw = visual_horizon(
            &nav,
            w,
            h,
            &PovnavConfig {
                opening_columns: 1,
                min_obstacle_px: 1,
                ..Default::default()
            },
        );
        assert_eq!(
            raw.navigable_rows[5], 4,
            "without clean-up the hole stops column 5"
        );
        assert_eq!(raw.navigable_rows[8], 20, "and the crack reaches the sky");
    }

    #[test]
    fn peripheral_optic_goal_for_every_direction() {
        let (w, h) = (41, 21); // u0 = 20, bottom row 20
        let pog = |deg: f64| peripheral_optic_goal(deg.to_radians(), w, h);
        assert_eq!(
            pog(0.0),
            (20.0, 0.0),
            "ahead: top centre, no division by zero"
        );
        assert_eq!(pog(90.0), (0.0, 20.0), "left: bottom-left corner");
        assert_eq!(pog(-90.0), (40.0, 20.0));
        // 45 degrees left: the ray meets the top border (20 up) at 20 left -> corner (0, 0).
        assert_eq!(pog(45.0), (0.0, 0.0));
        // Behind-left at 135 degrees: the mirrored border meets the ray at y = 20: bottom-left corner.
        assert_eq!(pog(135.0), (0.0, 20.0));
        // 170 degrees: mirrored top at x = -20, y = 20 tan(10 deg) = 3.53 left of
        // centre: bottom row, column 20 - 3.53 -> pixel 16.
        assert_eq!(pog(170.0), (16.0, 20.0));
        // 30 degrees: top border at y = 20 tan(30 deg) = 11.55 left -> pixel 8.
        assert_eq!(pog(30.0), (8.0, 0.0));
        assert_eq!(pog(180.0), (20.0, 20.0), "exactly behind: the start pixel");
        assert_eq!(pog(-180.0), (20.0, 20.0));
        assert_eq!(pog(540.0), pog(180.0), "any angle is wrapped");
    }

    #[test]
    fn the_ablations_steer_by_the_pog_or_the_hog_alone() {
        // 41x21: open ground below row 4, and an obstacle block dead ahead
        // (columns 16-24, rows 4-14); the goal straight ahead.
        let (w, h) = (41, 21);
        let nav = image(w, h, |u, v| v >= 4 && !((16..=24).contains(&u) && v <= 14));
        let hw = vec![1usize; h];
        let run = |components| {
            let cfg = PovnavConfig {
                components,
                ..Default::default()
            };
            plan(&nav, w, h, 0.0, &hw, &cfg)
        };
        let full = run(PovnavComponents::Full);
        let pog_hog = run(PovnavComponents::PogHog);
        let pog = run(PovnavComponents::Pog);
        assert_eq!(pog.hog_px, pog.pog_px, "POG only: no HOG");
        assert_eq!(pog.alignment_rad, 0.0, "straight at the obstacle");
        assert_eq!(pog_hog.hog_px, full.hog_px, "the same HOG");
        assert_ne!(full.hog_px.0, 20.0, "the HOG is beside the block");
        let (x, y) = to_plan(full.hog_px.0, full.hog_px.1, w, h);
        assert!((pog_hog.alignment_rad - y.atan2(x)).abs() < 1e-12);
        assert_eq!(pog_hog.path_px.len(), 2, "no visual path");
        for p in [&full, &pog_hog, &pog] {
            assert_eq!(p.proximity_px, full.proximity_px, "the speed law is kept");
        }
    }

    #[test]
    fn hog_trades_angle_for_distance() {
        // Open ground ahead to row 5 except an obstacle straight ahead that ends
        // the left half's view early: goal slightly right.
        let (w, h) = (41, 31);
        let nav = image(w, h, |u, v| v >= 5 && !((15..=25).contains(&u) && v < 20));
        let cfg = PovnavConfig::default();
        let p = plan(&nav, w, h, 0.0, &vec![1; h], &cfg);
        assert_eq!(p.mode, Mode::Safe);
        // Straight ahead is blocked at row 20; the HOG goes around, far up a side.
        assert_eq!(p.hog_px.1, 5.0, "{:?}", p.hog_px);
        assert!(p.hog_px.0 < 15.0 || p.hog_px.0 > 25.0, "{:?}", p.hog_px);
        // Proximity: the obstacle's bottom edge, 10 rows up.
        assert!((p.proximity_px - 10.0).abs() < 1e-9, "{}", p.proximity_px);
        assert_eq!(
            p.path_px.first(),
            Some(&(20.0, 30.0)),
            "the path starts at the robot"
        );
    }

    #[test]
    fn fig7_downhill_all_navigable_puts_the_hog_on_the_pog() {
        let (w, h) = (41, 31);
        let nav = vec![255u8; w * h];
        for deg in [0.0f64, 30.0, -60.0] {
            let p = plan(
                &nav,
                w,
                h,
                deg.to_radians(),
                &vec![1; h],
                &PovnavConfig::default(),
            );
            assert_eq!(p.hog_px, p.pog_px, "goal {deg}");
            assert_eq!(p.mode, Mode::Safe);
        }
    }

    #[test]
    fn fig7_uphill_nothing_navigable_collapses_to_the_start() {
        let (w, h) = (41, 31);
        let p = plan(
            &vec![0u8; w * h],
            w,
            h,
            0.4,
            &vec![1; h],
            &PovnavConfig::default(),
        );
        assert_eq!(p.mode, Mode::Blocked);
        assert_eq!(p.hog_px, (20.0, 30.0));
        assert_eq!(p.proximity_px, 0.0);
        let (x, y) = to_plan(p.pog_px.0, p.pog_px.1, w, h);
        assert!(
            (p.alignment_rad - y.atan2(x)).abs() < 1e-12,
            "aligns with the POG"
        );
    }

    #[test]
    fn fig7_narrow_gap_gives_a_fallback_path() {
        // A wall at rows 10..14 with a 7-pixel gap (wider than the horizon
        // opening, so it stays open); the robot needs 9 pixels there.
        let (w, h) = (41, 31);
        let nav = image(w, h, |u, v| {
            !(10..15).contains(&v) || (17..=23).contains(&u)
        });
        let p = plan(&nav, w, h, 0.0, &vec![4; h], &PovnavConfig::default());
        assert_eq!(p.hog_px, (20.0, 0.0), "the goal is through the gap");
        assert_eq!(p.mode, Mode::Fallback);
        assert!(
            p.path_px.iter().all(|&(_, v)| !(10.0..15.0).contains(&v)),
            "no unsafe point in the path"
        );
        // A robot that fits (5 pixels) gets a safe path through the same gap.
        let p = plan(&nav, w, h, 0.0, &vec![2; h], &PovnavConfig::default());
        assert_eq!(p.mode, Mode::Safe);
        assert!(p.path_px.iter().any(|&(_, v)| (10.0..15.0).contains(&v)));
    }

    #[test]
    fn visual_path_shifts_away_from_an_obstacle_edge() {
        // Corridor of columns 10..=30; HOG at the top near the left wall.
        let (w, h) = (41, 21);
        let nav = image(w, h, |u, _| (10..=30).contains(&u));
        let cfg = PovnavConfig {
            path_row_step: 1,
            ..Default::default()
        };
        let (path, mode) = visual_path(&nav, w, h, (11.0, 0.0), &vec![3; h], &cfg);
        assert_eq!(mode, Mode::Safe);
        assert_eq!(path.first(), Some(&(20.0, 20.0)));
        for &(u, _) in &path[..path.len() - 1] {
            assert!(u - 3.0 >= 10.0 && u + 3.0 <= 30.0, "{u}");
        }
    }

    fn random_image(w: usize, h: usize, seed: u32, blocked_per_256: u32) -> Vec<u8> {
        let mut s = seed;
        (0..w * h)
            .map(|_| {
                s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                if s >> 24 < blocked_per_256 {
                    0
                } else {
                    255
                }
            })
            .collect()
    }

    #[test]
    fn horizon_scan_matches_a_plain_column_scan() {
        let cfg = PovnavConfig {
            opening_columns: 1,
            ..Default::default()
        };
        for seed in 0..20 {
            let (w, h) = (37, 29);
            let nav = random_image(w, h, seed, 60);
            let got = visual_horizon(&nav, w, h, &cfg).navigable_rows;
            for u in 0..w {
                // Up from the bottom until min_obstacle_px blocked in a row.
                let (mut run, mut top) = (0, 0);
                for k in 0..h {
                    if nav[(h - 1 - k) * w + u] == 255 {
                        run = 0;
                        top = k + 1;
                    } else {
                        run += 1;
                        if run >= cfg.min_obstacle_px {
                            break;
                        }
                    }
                }
                assert_eq!(got[u], top, "seed {seed} column {u}");
            }
        }
    }

    #[test]
    fn footprint_tests_agree_with_the_run_rule() {
        let mut rows = RowObstacles::default();
        for seed in 0..50 {
            let row = random_image(40, 1, seed, 110);
            rows.fill(&row, 3);
            for lo in -2i64..42 {
                for hi in lo..42 {
                    // By definition: some pixel in lo..=hi lies in a blocked run of >= 3.
                    let want = lo >= 0
                        && hi < 40
                        && (lo..=hi).all(|i| {
                            let i = i as usize;
                            if row[i] == 255 {
                                return true;
                            }
                            let a = (0..=i).rev().take_while(|&j| row[j] != 255).count();
                            let b = (i..40).take_while(|&j| row[j] != 255).count();
                            a + b - 1 < 3
                        });
                    assert_eq!(rows.clear(lo, hi), want, "seed {seed} {lo}..={hi}");
                    assert_eq!(
                        footprint_clear(&row, lo, hi, 3),
                        want,
                        "seed {seed} {lo}..={hi}"
                    );
                }
            }
        }
    }

    #[test]
    fn speckle_does_not_force_fallback_but_an_obstacle_does() {
        // All navigable but for isolated 1-2 pixel specks in every row.
        let (w, h) = (41, 21);
        let mut nav = image(w, h, |u, v| (u + 3 * v) % 7 != 0);
        let p = plan(&nav, w, h, 0.0, &vec![6; h], &PovnavConfig::default());
        assert_eq!(p.mode, Mode::Safe, "specks are noise");
        assert_eq!(p.hog_px, (20.0, 0.0), "the horizon is the top row");
        // A rock across the straight path (columns 14..=27, rows 9..=11) is
        // an obstacle: the path keeps its footprint off it.
        for v in 9..=11 {
            for u in 14..=27 {
                nav[v * w + u] = 0;
            }
        }
        let cfg = PovnavConfig {
            path_row_step: 1,
            ..Default::default()
        };
        let p = plan(&nav, w, h, 0.0, &vec![6; h], &cfg);
        assert_eq!(p.mode, Mode::Safe);
        let beside: Vec<_> = p
            .path_px
            .iter()
            .filter(|&&(_, v)| (9.0..=11.0).contains(&v))
            .collect();
        assert_eq!(beside.len(), 3, "{:?}", p.path_px);
        for &&(u, _) in &beside {
            assert!(u + 6.0 < 14.0 || u - 6.0 > 27.0, "{u}");
        }
    }

    #[test]
    fn safe_width_grows_toward_the_bottom() {
        // fx = fy = 400, cy = 180, camera 1 m up, 0.6 m robot + 0.2 m margin:
        // at row 380, z = 400 * 1 / 200 = 2 m, half-width 0.5 m -> 100 px.
        let hw = safe_half_widths(400, 400.0, 400.0, 180.0, 1.0, 0.6, 0.2);
        assert_eq!(hw[380], 100);
        assert_eq!(hw[180], 0, "at the horizon line");
        assert!(hw[300] < hw[380]);
    }
}
