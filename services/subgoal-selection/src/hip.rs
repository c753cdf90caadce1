//! HIP's trajectory-library planner (sections II-III): K candidate futures
//! of the robot (k-means centroids of recorded trajectories, H positions
//! each, robot frame), each scored by eq. (1):
//!
//! `L(tau) = C_directive(tau) + (1 - phi) C_learned(tau) + phi sum_i C_costmap(tau_i)`
//!
//! - `C_directive = delta` unless the trajectory ends inside the goal region:
//!   a rectangle 2 m wide whose centre axis points at the goal, "offset
//!   towards d by 3m" (section III). The paper gives no length; it must
//!   reach back within a Husky's 2 s of travel (at most 2 m at the 1 m/s
//!   of Clearpath's specification), or none of the paper's trajectories
//!   could end in it. So the offset places the rectangle's centre and
//!   `region_length_m` (5 m: 0.5-5.5 m toward the goal) is ours;
//! - `C_learned = -log q(tau | o)` from a learned density model when one is
//!   configured (0 otherwise, which leaves the hybrid with its geometric and
//!   directive terms);
//! - `C_costmap` is the fused costmap rescaled as the paper
//!   (`farsight_costmap_fusion::hip::hip_scaled_costmap`); a trajectory
//!   that takes the robot's disc (`robot_radius_m`) over a lethal cell is
//!   never chosen ([`disc_touches_lethal`]: costmap_2d's inscribed
//!   inflation, which the paper's costmap had, done on the exact disc);
//!   a robot already nearer than its radius may turn or back away but
//!   not get closer ([`required_clearance_m`]).
//!
//! The planner picks the argmin. [`kmeans`] and [`future_trajectories`] build
//! the library from recorded poses (`farsight hip-library`).
//!
//! ```
//! use farsight_subgoal_selection::hip::{choose, HipPlannerConfig, Trajectory};
//!
//! let straight = Trajectory((1..=10).map(|i| [0.5 * i as f64, 0.0]).collect());
//! let left = Trajectory((1..=10).map(|i| [0.4 * i as f64, 0.2 * i as f64]).collect());
//! let cfg = HipPlannerConfig::default();
//! // Goal 20 m ahead, flat cost everywhere, no learned model: straight ahead wins.
//! let pick = choose(&[straight, left], [20.0, 0.0], |_| 0.01, None, &cfg).unwrap();
//! assert_eq!(pick.index, 0);
//! ```

use farsight_costmap_fusion::hip::hip_combined;
use farsight_stage::{ConfigError, Range, Ranges, Validate};
use serde::{Deserialize, Serialize};

/// H future positions in the robot frame (x ahead, y left), metres.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Trajectory(pub Vec<[f64; 2]>);

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HipPlannerConfig {
    /// Weight of the geometric term (the paper's phi* = 0.75). 1 is the
    /// paper's Geometric Costmap component, 0 its Learner alone: the
    /// costmap then takes no part, lethal cells included, and nothing is
    /// planned without a fresh learned term ([`Self::learner_only`]).
    pub phi: f64,
    /// Scale of the softmax-rescaled costmap: eta / H = 64 / 10.
    pub alpha: f64,
    /// Directive penalty for missing the goal region.
    pub delta: f64,
    /// The goal region: how far toward the goal its centre is (the
    /// paper's 3 m), its width across that line (the paper's 2 m) and its
    /// length along it, which the paper does not give. 5 m was chosen on
    /// spawns 301-400 of hip-in-distribution, apart from the 300 that
    /// judge (README, HIP's protocol): 2, 4, 5 and 6 m (regions from 2, 1,
    /// 0.5 and 0 m) took the Geometric Costmap component to 15, 18, 23 and
    /// 19 of 98 spawns reached (intervals overlapping), against 9 for a
    /// region from 3 m on (the reading before), which at most 8 of the
    /// library's 200 trajectories (ending 0.2-3.6 m out) reach, and none
    /// with the goal 60 degrees or more to a side. The trajectories all end
    /// within 3.6 m, so what was chosen is the near edge (0.5 m).
    pub region_offset_m: f64,
    pub region_width_m: f64,
    pub region_length_m: f64,
    /// The robot's footprint: no trajectory point may bring a disc this
    /// wide over a lethal cell.
    pub robot_radius_m: f64,
}

impl Default for HipPlannerConfig {
    fn default() -> Self {
        Self {
            phi: 0.75,
            alpha: 6.4,
            delta: 100.0,
            region_offset_m: 3.0,
            region_width_m: 2.0,
            region_length_m: 5.0,
            robot_radius_m: 0.4,
        }
    }
}

impl HipPlannerConfig {
    /// phi = 0: HIP's Learner component alone (section V, Fig. 4), which
    /// sees the camera and no costmap.
    pub fn learner_only(&self) -> bool {
        self.phi == 0.0
    }
}

impl Validate for HipPlannerConfig {
    fn ranges(&self, r: &mut Ranges) {
        r.key("phi", self.phi, Range::between(0.0, 1.0))
            .key("alpha", self.alpha, Range::between(0.0, 1000.0))
            .key("delta", self.delta, Range::between(0.0, 1000.0))
            .key(
                "region_offset_m",
                self.region_offset_m,
                Range::above_to(0.0, 100.0).unit("m"),
            )
            .key(
                "region_width_m",
                self.region_width_m,
                Range::between(0.0, 100.0).unit("m"),
            )
            .key(
                "region_length_m",
                self.region_length_m,
                Range::above_to(0.0, 200.0).unit("m"),
            )
            .key(
                "robot_radius_m",
                self.robot_radius_m,
                Range::between(0.0, 10.0).unit("m"),
            );
    }

    /// The region's near edge: a region reaching behind the robot would
    /// count a trajectory that backs away as heading for the goal.
    fn check_rules(&self) -> Result<(), ConfigError> {
        ConfigError::check(
            self.region_length_m <= 2.0 * self.region_offset_m,
            "hip.region_length_m (with hip.region_offset_m)",
            self.region_length_m,
            &format!(
                "at most twice hip.region_offset_m ({} m): the region, centred that far toward the goal, must start at or ahead of the robot",
                self.region_offset_m
            ),
        )
    }
}

/// The directive cost of a trajectory ending at `end` for a goal at `goal`
/// (both robot frame): 0 inside the region, `delta` outside. A goal closer
/// than the region's near edge moves that edge to the goal.
pub fn directive_cost(end: [f64; 2], goal: [f64; 2], cfg: &HipPlannerConfig) -> f64 {
    let d = goal[0].hypot(goal[1]);
    if d < 1e-9 {
        return 0.0;
    }
    let (ux, uy) = (goal[0] / d, goal[1] / d);
    let along = end[0] * ux + end[1] * uy;
    let across = -end[0] * uy + end[1] * ux;
    let near_m = (cfg.region_offset_m - cfg.region_length_m / 2.0).min(d);
    let far_m = cfg.region_offset_m + cfg.region_length_m / 2.0;
    let inside =
        along >= near_m - 1e-9 && along <= far_m + 1e-9 && across.abs() <= cfg.region_width_m / 2.0;
    if inside {
        0.0
    } else {
        cfg.delta
    }
}

/// Whether a disc of `radius_m` centred on world point `w` overlaps a
/// lethal (infinite) cell of the costmap `costs` described by `h` (cell
/// `(i, j)` is the square of side `resolution_m` centred on `x_min_m + j
/// res`, `y_max_m - i res`, as `CostmapHeader::cell_index`). Cells off the
/// map are not lethal: unknown, as the planner counts them.
pub fn disc_touches_lethal(
    h: &farsight_interfaces::msg::CostmapHeader,
    costs: &[f32],
    w: [f64; 2],
    radius_m: f64,
) -> bool {
    lethal_clearance_m(h, costs, w, radius_m) < radius_m
}

/// Distance (m) from world point `w` to the nearest lethal cell's square
/// (cells as [`disc_touches_lethal`]), or `max_m` when none is nearer.
pub fn lethal_clearance_m(
    h: &farsight_interfaces::msg::CostmapHeader,
    costs: &[f32],
    w: [f64; 2],
    max_m: f64,
) -> f64 {
    let res = h.resolution_m as f64;
    let col = |x: f64| ((x - h.x_min_m) / res + 0.5).floor() as i64;
    let row = |y: f64| ((h.y_max_m - y) / res + 0.5).floor() as i64;
    let (j0, j1) = (
        col(w[0] - max_m).max(0),
        col(w[0] + max_m).min(h.width as i64 - 1),
    );
    let (i0, i1) = (
        row(w[1] + max_m).max(0),
        row(w[1] - max_m).min(h.height as i64 - 1),
    );
    let mut nearest_sq = max_m * max_m;
    for i in i0..=i1 {
        for j in j0..=j1 {
            let Some(&c) = costs.get(i as usize * h.width as usize + j as usize) else {
                continue;
            };
            if !c.is_infinite() {
                continue;
            }
            let (xc, yc) = (h.x_min_m + j as f64 * res, h.y_max_m - i as f64 * res);
            let dx = ((w[0] - xc).abs() - res / 2.0).max(0.0);
            let dy = ((w[1] - yc).abs() - res / 2.0).max(0.0);
            nearest_sq = nearest_sq.min(dx * dx + dy * dy);
        }
    }
    nearest_sq.sqrt()
}

/// The clearance from lethal cells every point of a chosen trajectory
/// keeps: the robot's `radius_m`, or, where the robot already stands
/// nearer than that (an obstacle seen late, a body smaller than the
/// planner's disc, a slide along a trunk), the clearance it has now. It
/// may then turn or back away, never get closer; without this every
/// trajectory fails the disc check and the planner sends nothing until
/// the command goes stale.
pub fn required_clearance_m(
    h: &farsight_interfaces::msg::CostmapHeader,
    costs: &[f32],
    robot_w: [f64; 2],
    radius_m: f64,
) -> f64 {
    lethal_clearance_m(h, costs, robot_w, radius_m)
}

/// The chosen trajectory and its cost terms.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Choice {
    pub index: usize,
    pub total: f64,
    pub directive: f64,
    pub learned: f64,
    pub geometric: f64,
}

/// Scores every trajectory by eq. (1) and returns the argmin. `costmap_at`
/// gives the (HIP-scaled) costmap value at a robot-frame point; `learned`
/// holds -log q per trajectory when a model is configured. `None` when every
/// trajectory crosses a lethal cell (or the library is empty).
pub fn choose(
    library: &[Trajectory],
    goal_robot_m: [f64; 2],
    costmap_at: impl Fn([f64; 2]) -> f64,
    learned: Option<&[f64]>,
    cfg: &HipPlannerConfig,
) -> Option<Choice> {
    library
        .iter()
        .enumerate()
        .filter_map(|(k, t)| {
            let end = *t.0.last()?;
            let geometric: f64 = t.0.iter().map(|&p| costmap_at(p)).sum();
            if !geometric.is_finite() {
                return None;
            }
            let learned = learned.and_then(|l| l.get(k).copied()).unwrap_or(0.0);
            if !learned.is_finite() {
                return None;
            }
            let directive = directive_cost(end, goal_robot_m, cfg);
            Some(Choice {
                index: k,
                total: directive + hip_combined(learned, geometric, cfg.phi),
                directive,
                learned,
                geometric,
            })
        })
        .min_by(|a, b| a.total.total_cmp(&b.total))
}

/// HIP's past-position input (section V: the learner's "10 past
/// timesteps"): `points` positions `step_s` apart before capture time
/// `t_ns`, oldest first, in the robot's frame at `t_ns` (x ahead, y left),
/// flattened (x, y). `pose_at(t)` gives the world pose `[x_m, y_m,
/// yaw_rad]` the robot had at `t` (the subgoal stage: the newest kept
/// at or before it, else the oldest, so a short history repeats its first
/// pose, as the training data repeats a respawn's). `None` without one.
pub fn past_positions(
    pose_at: impl Fn(u64) -> Option<[f64; 3]>,
    t_ns: u64,
    points: usize,
    step_s: f64,
) -> Option<Vec<f32>> {
    let [x0, y0, yaw0] = pose_at(t_ns)?;
    let (s, c) = yaw0.sin_cos();
    let mut out = Vec::with_capacity(2 * points);
    for k in (1..=points).rev() {
        let back_ns = (k as f64 * step_s * 1e9).round() as u64;
        let [x, y, _] = pose_at(t_ns.saturating_sub(back_ns))?;
        let (dx, dy) = (x - x0, y - y0);
        out.push((c * dx + s * dy) as f32);
        out.push((-s * dx + c * dy) as f32);
    }
    Some(out)
}

/// From a recorded pose sequence `(t_s, x_m, y_m, yaw_rad)` (time order), the
/// future of every `step_s`-spaced sample: the next `horizon` positions
/// `step_s` apart, in that sample's robot frame. Positions are taken at the
/// first recorded pose at or after each time (no interpolation); samples
/// whose future runs past the recording are left out.
pub fn future_trajectories(
    poses: &[(f64, f64, f64, f64)],
    horizon: usize,
    step_s: f64,
) -> Vec<Trajectory> {
    let mut out = Vec::new();
    if poses.is_empty() || horizon == 0 || step_s <= 0.0 {
        return out;
    }
    // A microsecond of slack: sample times are sums of float steps.
    let at_or_after = |t: f64| poses.partition_point(|p| p.0 < t - 1e-6);
    let (t0, end) = (poses[0].0, poses[poses.len() - 1].0);
    for n in 0.. {
        let t = t0 + n as f64 * step_s;
        if t + horizon as f64 * step_s > end + 1e-6 {
            break;
        }
        let i0 = at_or_after(t);
        let (_, x0, y0, yaw0) = poses[i0];
        let (s, c) = yaw0.sin_cos();
        let points: Vec<[f64; 2]> = (1..=horizon)
            .filter_map(|k| poses.get(at_or_after(t + k as f64 * step_s)))
            .map(|&(_, x, y, _)| {
                let (dx, dy) = (x - x0, y - y0);
                [c * dx + s * dy, -s * dx + c * dy]
            })
            .collect();
        if points.len() == horizon {
            out.push(Trajectory(points));
        }
    }
    out
}

fn sq_dist(a: &Trajectory, b: &Trajectory) -> f64 {
    a.0.iter()
        .zip(&b.0)
        .map(|(p, q)| (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2))
        .sum()
}

/// k-means (k-means++ seeding from `seed`, then Lloyd iterations until no
/// assignment changes or `max_iterations`) over trajectories of equal
/// length, as HIP builds its library (K = 200). Returns at most `k`
/// centroids, fewer if there are fewer distinct trajectories.
pub fn kmeans(data: &[Trajectory], k: usize, max_iterations: usize, seed: u64) -> Vec<Trajectory> {
    if data.is_empty() || k == 0 {
        return Vec::new();
    }
    let mut rng = seed.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut uniform = move || {
        rng = rng
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (rng >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut centroids = vec![data[(uniform() * data.len() as f64) as usize % data.len()].clone()];
    let mut nearest: Vec<f64> = data.iter().map(|d| sq_dist(d, &centroids[0])).collect();
    while centroids.len() < k {
        let total: f64 = nearest.iter().sum();
        if total <= 0.0 {
            break; // every point is already a centroid
        }
        let mut r = uniform() * total;
        let pick = nearest
            .iter()
            .position(|&d| {
                r -= d;
                r <= 0.0
            })
            .unwrap_or(data.len() - 1);
        centroids.push(data[pick].clone());
        for (n, d) in nearest.iter_mut().zip(data) {
            *n = n.min(sq_dist(d, &centroids[centroids.len() - 1]));
        }
    }
    let h = data[0].0.len();
    let mut assignment = vec![usize::MAX; data.len()];
    for _ in 0..max_iterations {
        let mut changed = false;
        for (a, d) in assignment.iter_mut().zip(data) {
            let best = (0..centroids.len())
                .min_by(|&i, &j| sq_dist(d, &centroids[i]).total_cmp(&sq_dist(d, &centroids[j])))
                .expect("at least one centroid");
            changed |= *a != best;
            *a = best;
        }
        if !changed {
            break;
        }
        let mut sums = vec![vec![[0.0f64; 2]; h]; centroids.len()];
        let mut counts = vec![0usize; centroids.len()];
        for (&a, d) in assignment.iter().zip(data) {
            counts[a] += 1;
            for (s, p) in sums[a].iter_mut().zip(&d.0) {
                s[0] += p[0];
                s[1] += p[1];
            }
        }
        for ((c, s), &n) in centroids.iter_mut().zip(sums).zip(&counts) {
            if n > 0 {
                c.0 = s
                    .into_iter()
                    .map(|p| [p[0] / n as f64, p[1] / n as f64])
                    .collect();
            }
        }
    }
    centroids
}

/// The library file (`hip-library.toml`): written by `farsight hip-library`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LibraryFile {
    /// Seconds between trajectory points.
    pub step_s: f64,
    pub trajectories: Vec<Vec<[f64; 2]>>,
}

impl Validate for LibraryFile {
    fn check_rules(&self) -> Result<(), ConfigError> {
        ConfigError::check(
            !self.trajectories.is_empty(),
            "trajectories",
            "[]",
            "at least one trajectory",
        )?;
        let h = self.trajectories[0].len();
        for (i, t) in self.trajectories.iter().enumerate() {
            ConfigError::check(
                t.len() == h && h > 0,
                &format!("trajectories[{i}]"),
                format!("{} points", t.len()),
                &format!("{h} points like trajectories[0]"),
            )?;
            ConfigError::check(
                t.iter().all(|p| p[0].is_finite() && p[1].is_finite()),
                &format!("trajectories[{i}]"),
                "a non-finite point",
                "finite coordinates",
            )?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn past_positions_are_the_poses_before_in_the_robot_frame_oldest_first() {
        // Driving north (yaw 90 degrees) at 1 m/s since t = 10 s, having
        // stood at (0, 0) before: at t = 11 s the robot is at (0, 1).
        let pose_at = |t: u64| {
            let t_s = t as f64 / 1e9;
            Some([0.0, (t_s - 10.0).max(0.0), std::f64::consts::FRAC_PI_2])
        };
        let past = past_positions(pose_at, 11_000_000_000, 3, 0.5).unwrap();
        // 1.5 s and 1 s before: at the stand, 1 m behind; 0.5 s before:
        // 0.5 m behind. Behind is -x in the robot's frame.
        let want = [-1.0, 0.0, -1.0, 0.0, -0.5, 0.0];
        for (g, w) in past.iter().zip(want) {
            assert!((g - w).abs() < 1e-6, "{past:?}");
        }
        assert_eq!(past.len(), 6);
        assert_eq!(past_positions(|_| None, 5, 3, 0.2), None);
    }

    #[test]
    fn the_disc_touches_a_lethal_cell_by_its_square_not_its_centre() {
        use farsight_interfaces::msg::{CostmapHeader, CostmapLayer, Stamp};
        // 5 x 5 cells of 1 m, x in [-0.5, 4.5], y in [-0.5, 4.5]; a tree at (2, 2).
        let h = CostmapHeader {
            stamp: Stamp::default(),
            layer: CostmapLayer::FUSED,
            width: 5,
            height: 5,
            resolution_m: 1.0,
            x_min_m: 0.0,
            y_max_m: 4.0,
        };
        let mut costs = vec![0.5f32; 25];
        costs[2 * 5 + 2] = f32::INFINITY;
        let r = 0.4;
        // The tree's square spans x, y in [1.5, 2.5].
        assert!(disc_touches_lethal(&h, &costs, [2.0, 2.0], r));
        assert!(
            disc_touches_lethal(&h, &costs, [1.2, 2.0], r),
            "0.3 m from its edge"
        );
        assert!(
            !disc_touches_lethal(&h, &costs, [1.0, 2.0], r),
            "0.5 m from its edge"
        );
        // Diagonally: 0.35 m from the corner on each axis is 0.49 m away.
        assert!(!disc_touches_lethal(&h, &costs, [1.15, 1.15], r));
        assert!(
            disc_touches_lethal(&h, &costs, [1.3, 1.3], r),
            "0.28 m from the corner"
        );
        // Off the map is not lethal; a point far outside touches nothing.
        assert!(!disc_touches_lethal(&h, &costs, [-30.0, 2.0], r));

        // In the open the rule is the disc: the radius.
        assert_eq!(required_clearance_m(&h, &costs, [0.0, 0.0], r), r);
        // A robot 0.3 m from the trunk may keep or grow that, not shrink it.
        let need = required_clearance_m(&h, &costs, [1.2, 2.0], r);
        assert!((need - 0.3).abs() < 1e-9, "{need}");
        let keeps = |w: [f64; 2]| lethal_clearance_m(&h, &costs, w, r) >= need;
        assert!(keeps([0.9, 2.0]), "backing away");
        assert!(keeps([1.2, 2.3]), "along the trunk");
        assert!(!keeps([1.3, 2.0]), "closer");
        assert!(!keeps([2.0, 2.0]), "into it");
    }

    fn line(dx: f64, dy: f64) -> Trajectory {
        Trajectory((1..=10).map(|i| [dx * i as f64, dy * i as f64]).collect())
    }

    #[test]
    fn directive_region_by_hand() {
        let cfg = HipPlannerConfig::default();
        // Goal 10 m to the left (+y): the region is x in [-1, 1], y in
        // [0.5, 5.5] (centred 3 m out, 5 m long).
        assert_eq!(directive_cost([0.5, 4.0], [0.0, 10.0], &cfg), 0.0);
        assert_eq!(
            directive_cost([0.0, 1.0], [0.0, 10.0], &cfg),
            0.0,
            "within a Husky's reach"
        );
        assert_eq!(
            directive_cost([1.5, 4.0], [0.0, 10.0], &cfg),
            100.0,
            "too far to the side"
        );
        assert_eq!(
            directive_cost([0.0, 0.3], [0.0, 10.0], &cfg),
            100.0,
            "short of the near edge"
        );
        assert_eq!(
            directive_cost([0.0, 6.0], [0.0, 10.0], &cfg),
            100.0,
            "past the far edge"
        );
        // A goal 0.3 m ahead: its region starts at the goal.
        assert_eq!(directive_cost([0.4, 0.0], [0.3, 0.0], &cfg), 0.0);
        assert_eq!(directive_cost([0.2, 0.0], [0.3, 0.0], &cfg), 100.0);
    }

    #[test]
    fn a_goal_region_reaching_behind_the_robot_or_of_no_length_is_refused() {
        assert!(HipPlannerConfig::default().validate().is_ok());
        let behind = HipPlannerConfig {
            region_length_m: 7.0,
            ..Default::default()
        };
        let e = behind.validate().unwrap_err().to_string();
        assert!(e.contains("hip.region_length_m") && e.contains('7'), "{e}");
        let empty = HipPlannerConfig {
            region_length_m: 0.0,
            ..Default::default()
        };
        let e = empty.validate().unwrap_err().to_string();
        assert!(e.contains("region_length_m"), "{e}");
    }

    #[test]
    fn eq1_picks_by_directive_costmap_and_learned_terms() {
        let cfg = HipPlannerConfig::default();
        let lib = [line(0.5, 0.0), line(0.4, 0.3), line(0.4, -0.3)];
        // Goal to the front-left: only the left trajectory ends in the region.
        let goal = [8.0, 6.0];
        let c = choose(&lib, goal, |_| 0.1, None, &cfg).unwrap();
        assert_eq!((c.index, c.directive), (1, 0.0));
        // A lethal cell on it: the next best by cost (all miss the region now).
        let rock = |p: [f64; 2]| {
            if (p[0] - 2.0).abs() < 0.3 && (p[1] - 1.5).abs() < 0.3 {
                f64::INFINITY
            } else {
                0.1
            }
        };
        let c = choose(&lib, goal, rock, None, &cfg).unwrap();
        assert_ne!(c.index, 1);
        // By hand: L = 0 + 0.25 * learned + 0.75 * 10 * 0.1 for the left one.
        let learned = [5.0, 2.0, 0.0];
        let c = choose(&lib, goal, |_| 0.1, Some(&learned), &cfg).unwrap();
        assert_eq!(c.index, 1);
        assert!((c.total - (0.25 * 2.0 + 0.75 * 1.0)).abs() < 1e-12, "{c:?}");
        // With phi = 0 only learned + directive count; a huge learned cost on
        // the left one makes missing the region (delta 100) cheaper.
        let l2 = [5.0, 1000.0, 0.0];
        let c = choose(
            &lib,
            goal,
            |_| 0.1,
            Some(&l2),
            &HipPlannerConfig { phi: 0.0, ..cfg },
        )
        .unwrap();
        assert_eq!(c.index, 2);
        assert!(choose(&lib, goal, |_| f64::INFINITY, None, &cfg).is_none());
    }

    #[test]
    fn future_trajectories_are_in_each_samples_robot_frame() {
        // Driving north at 1 m/s, facing north: the future is straight ahead.
        let poses: Vec<_> = (0..=40)
            .map(|i| {
                (
                    i as f64 * 0.1,
                    5.0,
                    i as f64 * 0.1,
                    std::f64::consts::FRAC_PI_2,
                )
            })
            .collect();
        let t = future_trajectories(&poses, 5, 0.2);
        assert_eq!(t.len(), 16, "t = 0.0, 0.2, ... 3.0");
        for tr in &t {
            for (k, p) in tr.0.iter().enumerate() {
                let want = 0.2 * (k + 1) as f64;
                assert!((p[0] - want).abs() < 1e-9 && p[1].abs() < 1e-9, "{p:?}");
            }
        }
    }

    #[test]
    fn kmeans_recovers_separated_groups() {
        // Three groups (left, straight, right) with small jitter.
        let mut data = Vec::new();
        for j in 0..30 {
            let e = (j % 5) as f64 * 0.01;
            data.push(line(0.5, 0.3 + e));
            data.push(line(0.5 + e, 0.0));
            data.push(line(0.5, -0.3 - e));
        }
        let c = kmeans(&data, 3, 50, 7);
        assert_eq!(c.len(), 3);
        let mut ends: Vec<f64> = c.iter().map(|t| t.0.last().unwrap()[1]).collect();
        ends.sort_by(f64::total_cmp);
        assert!(
            (ends[0] + 3.2).abs() < 0.1 && ends[1].abs() < 1e-9 && (ends[2] - 3.2).abs() < 0.1,
            "{ends:?}"
        );
        assert_eq!(kmeans(&data, 3, 50, 7), c, "deterministic for a seed");
        // Fewer distinct trajectories than k: no duplicates invented.
        assert_eq!(kmeans(&[line(1.0, 0.0), line(1.0, 0.0)], 5, 10, 1).len(), 1);
    }
}
