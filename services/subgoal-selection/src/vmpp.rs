//! VMPP, the Visual Motion Primitive Planner: POVNav's baseline (section
//! 5.2.1). The dynamic window approach's circular motion primitives (Fox et
//! al. 1997) are projected onto the image, as Chen et al. (2022, 2023a) do,
//! and checked against POVNav's navigability image: "for collision checking,
//! we assume that H [the visual horizon] represents an obstruction", and "for
//! a fair comparison, we use our proposed Navigability Image as the local
//! representation". Each admissible primitive is scored by DWA's objective
//! (heading to the goal, clearance, speed) and the best one steers.
//!
//! A primitive is admissible when every point of its arc that falls in the
//! image lies below the horizon with the robot's safe half-width on both
//! sides; points below the image's bottom edge (under the robot) or beside
//! it are not seen and not checked, as a depth camera's view limits VMPP's.

use crate::povnav::{
    peripheral_optic_goal, proximity_px, to_plan, visual_horizon, Mode, PovnavConfig, PovnavPlan,
    VisualHorizon,
};
use farsight_stage::{ConfigError, Range, Ranges, Validate};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// The primitives and DWA's weights.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct VmppConfig {
    /// Forward speeds sampled, evenly up to `max_linear_mps`.
    pub linear_samples: usize,
    /// Turn rates sampled, evenly over +-`max_angular_radps`.
    pub angular_samples: usize,
    pub max_linear_mps: f64,
    pub max_angular_radps: f64,
    /// How far ahead each arc is simulated (s), and its step.
    pub horizon_s: f64,
    pub step_s: f64,
    /// DWA's objective: heading, as the arc end's progress along the goal's
    /// direction...
    pub w_heading: f64,
    /// ...the least image clearance to the horizon along it...
    pub w_clearance: f64,
    /// ...and speed.
    pub w_velocity: f64,
}

impl Default for VmppConfig {
    fn default() -> Self {
        // POVNav's simulation limits (2 m/s, pi rad/s); Fox et al.'s
        // weights, normalised to heading 1.
        Self {
            linear_samples: 4,
            angular_samples: 15,
            max_linear_mps: 2.0,
            max_angular_radps: PI,
            horizon_s: 2.0,
            step_s: 0.2,
            w_heading: 1.0,
            w_clearance: 0.1,
            w_velocity: 0.1,
        }
    }
}

impl Validate for VmppConfig {
    fn ranges(&self, r: &mut Ranges) {
        r.key(
            "linear_samples",
            self.linear_samples,
            Range::between(1.0, 100.0),
        )
        .key(
            "angular_samples",
            self.angular_samples,
            Range::between(1.0, 1000.0),
        )
        .key(
            "max_linear_mps",
            self.max_linear_mps,
            Range::above_to(0.0, 100.0).unit("m/s"),
        )
        .key(
            "max_angular_radps",
            self.max_angular_radps,
            Range::above_to(0.0, 100.0).unit("rad/s"),
        )
        .key(
            "horizon_s",
            self.horizon_s,
            Range::above_to(0.0, 60.0).unit("s"),
        )
        .key("step_s", self.step_s, Range::above_to(0.0, 10.0).unit("s"))
        .key("w_heading", self.w_heading, Range::between(0.0, 100.0))
        .key("w_clearance", self.w_clearance, Range::between(0.0, 100.0))
        .key("w_velocity", self.w_velocity, Range::between(0.0, 100.0));
    }

    /// The primitives' arc points are allocated at start-up and projected
    /// every frame: bounded before anything is allocated.
    fn check_rules(&self) -> Result<(), ConfigError> {
        let points = (self.horizon_s / self.step_s).ceil()
            * self.linear_samples as f64
            * self.angular_samples as f64;
        ConfigError::check(
            points <= MAX_ARC_POINTS,
            "povnav.vmpp.horizon_s / step_s",
            format!(
                "{} s / {} s x {} x {} primitives = {points} arc points",
                self.horizon_s, self.step_s, self.linear_samples, self.angular_samples
            ),
            "at most 100000 arc points in all",
        )
    }
}

/// The most arc points all primitives together may have.
const MAX_ARC_POINTS: f64 = 100_000.0;

/// One motion primitive: a constant (v, w) for `horizon_s`, its arc's
/// points on the ground (robot frame: x ahead, y left) and its end heading.
#[derive(Debug, Clone, PartialEq)]
pub struct Primitive {
    pub linear_mps: f64,
    pub angular_radps: f64,
    pub ground_m: Vec<(f64, f64)>,
    pub end_yaw_rad: f64,
}

/// The dynamic window's primitives (every sampled speed and turn rate).
pub fn primitives(cfg: &VmppConfig) -> Vec<Primitive> {
    let steps = (cfg.horizon_s / cfg.step_s).ceil().max(1.0) as usize;
    let mut out = Vec::new();
    for i in 1..=cfg.linear_samples.max(1) {
        let v = cfg.max_linear_mps * i as f64 / cfg.linear_samples.max(1) as f64;
        let k = cfg.angular_samples.max(1);
        for j in 0..k {
            let w = if k == 1 {
                0.0
            } else {
                -cfg.max_angular_radps + 2.0 * cfg.max_angular_radps * j as f64 / (k - 1) as f64
            };
            let (mut x, mut y, mut yaw) = (0.0f64, 0.0f64, 0.0f64);
            let mut ground_m = Vec::with_capacity(steps);
            for _ in 0..steps {
                x += v * cfg.step_s * yaw.cos();
                y += v * cfg.step_s * yaw.sin();
                yaw += w * cfg.step_s;
                ground_m.push((x, y));
            }
            out.push(Primitive {
                linear_mps: v,
                angular_radps: w,
                ground_m,
                end_yaw_rad: yaw,
            });
        }
    }
    out
}

/// VMPP's choice: the index of the best admissible primitive, and its
/// score; `None` when none is admissible. `pixels[i][k]` is primitive `i`'s
/// k-th ground point in the image (`None`: behind the camera);
/// `half_width_px[v]` the robot's safe half-width at row `v`.
pub fn choose(
    horizon: &VisualHorizon,
    half_width_px: &[usize],
    prims: &[Primitive],
    pixels: &[Vec<Option<(f64, f64)>>],
    goal_bearing_rad: f64,
    cfg: &VmppConfig,
) -> Option<(usize, f64)> {
    let (w, h) = (horizon.width, horizon.height);
    let mut best: Option<(usize, f64)> = None;
    for (i, (p, px)) in prims.iter().zip(pixels).enumerate() {
        // Least clearance (rows from the point up to the horizon) along
        // the arc's seen points; `None` if a point is at or past the horizon.
        let mut clearance = h as f64;
        let mut seen = false;
        let mut admissible = true;
        for &(u, v) in px.iter().flatten() {
            if u < 0.0 || u > w as f64 - 1.0 || v < 0.0 {
                continue; // beside or above the view: not seen
            }
            if v > h as f64 - 1.0 {
                continue; // under the robot, below the image
            }
            seen = true;
            let (uc, vr) = (u.round() as usize, v.round() as usize);
            let hw = half_width_px.get(vr).copied().unwrap_or(0);
            let lo = uc.saturating_sub(hw);
            let hi = (uc + hw).min(w - 1);
            for col in lo..=hi {
                match horizon.top_row(col) {
                    Some(top) if vr >= top => clearance = clearance.min((vr - top) as f64),
                    _ => admissible = false,
                }
            }
            if !admissible {
                break;
            }
        }
        if !admissible {
            continue;
        }
        if !seen {
            // An arc the camera never sees earns no clearance: a blind turn
            // must not beat a seen, clear way.
            clearance = 0.0;
        }
        // Heading as progress: how far the arc's end gets along the goal's
        // direction, over the farthest any arc can. (The end yaw alone
        // would rate a full circle as well as a straight line.)
        let (ex, ey) = p.ground_m.last().copied().unwrap_or((0.0, 0.0));
        let progress = (ex * goal_bearing_rad.cos() + ey * goal_bearing_rad.sin())
            / (cfg.max_linear_mps * cfg.horizon_s);
        let score = cfg.w_heading * progress
            + cfg.w_clearance * clearance / h as f64
            + cfg.w_velocity * p.linear_mps / cfg.max_linear_mps;
        if best.is_none_or(|(_, s)| score > s) {
            best = Some((i, score));
        }
    }
    best
}

/// POVNav's plan with VMPP steering: the same horizon, POG and proximity
/// (so the same speed law), the alignment toward the best primitive's arc
/// at its last seen pixel (the image point it drives for), the arc as the
/// path.
/// [`Mode::Blocked`] when no primitive is admissible: the robot stops and
/// turns toward the POG, as POVNav's own blocked case.
#[allow(clippy::too_many_arguments)]
pub fn plan(
    nav: &[u8],
    width: usize,
    height: usize,
    goal_bearing_rad: f64,
    half_width_px: &[usize],
    prims: &[Primitive],
    pixels: &[Vec<Option<(f64, f64)>>],
    cfg: &PovnavConfig,
) -> PovnavPlan {
    let horizon = visual_horizon(nav, width, height, cfg);
    let pog = peripheral_optic_goal(goal_bearing_rad, width, height);
    let start = ((width as f64 - 1.0) / 2.0, height as f64 - 1.0);
    // POVNav's angle toward the POG, in the image (a POG at the start, the
    // goal exactly behind, turns left), for the blocked case.
    let (pxg, pyg) = to_plan(pog.0, pog.1, width, height);
    let theta_g = if pxg.hypot(pyg) < 0.5 {
        std::f64::consts::FRAC_PI_2
    } else {
        pyg.atan2(pxg)
    };
    let Some((i, _)) = choose(
        &horizon,
        half_width_px,
        prims,
        pixels,
        goal_bearing_rad,
        &cfg.vmpp,
    ) else {
        return PovnavPlan {
            pog_px: pog,
            hog_px: start,
            path_px: vec![start],
            proximity_px: 0.0,
            alignment_rad: theta_g,
            mode: Mode::Blocked,
        };
    };
    let seen: Vec<(f64, f64)> = pixels[i]
        .iter()
        .flatten()
        .copied()
        .filter(|&(u, v)| {
            u >= 0.0 && u <= width as f64 - 1.0 && v >= 0.0 && v <= height as f64 - 1.0
        })
        .collect();
    let mut path = vec![start];
    path.extend(&seen);
    let hog = seen.last().copied().unwrap_or(start);
    // The alignment is an image angle, as POVNav's (the servo's gain is
    // tuned for it): toward the arc's last seen pixel. An arc the image
    // never shows, or one that turns more than half a circle, steers by its
    // turn's side.
    let p = &prims[i];
    let (x, y) = to_plan(hog.0, hog.1, width, height);
    let alignment = if (p.angular_radps * cfg.vmpp.horizon_s).abs() > PI || x.hypot(y) < 0.5 {
        p.angular_radps.signum() * std::f64::consts::FRAC_PI_2
    } else {
        y.atan2(x)
    };
    PovnavPlan {
        pog_px: pog,
        hog_px: hog,
        path_px: path,
        proximity_px: proximity_px(&horizon),
        alignment_rad: alignment,
        mode: Mode::Safe,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::povnav::{visual_horizon, PovnavConfig};

    /// A 60x40 image seen from above: pixel (u, v) is the ground point
    /// x = (40 - v) / 4 m ahead, y = (30 - u) / 4 m left.
    fn top_down(x: f64, y: f64) -> Option<(f64, f64)> {
        Some((30.0 - 4.0 * y, 40.0 - 4.0 * x))
    }

    #[test]
    fn too_many_arc_points_are_refused_by_name_before_any_is_made() {
        let e = farsight_stage::parse_config::<crate::stage::SubgoalStageConfig>(
            "[povnav.vmpp]\nstep_s = 0.000001",
            "s.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("povnav.vmpp.horizon_s / step_s"), "{e}");
        assert!(VmppConfig::default().check_rules().is_ok());
    }

    #[test]
    fn the_best_primitive_heads_for_the_goal_and_avoids_the_horizon() {
        let cfg = VmppConfig::default();
        let prims = primitives(&cfg);
        assert_eq!(prims.len(), 4 * 15);
        let straight = prims
            .iter()
            .position(|p| p.angular_radps == 0.0 && p.linear_mps == 2.0)
            .unwrap();
        assert!((prims[straight].ground_m.last().unwrap().0 - 4.0).abs() < 1e-9);
        let pixels: Vec<Vec<Option<(f64, f64)>>> = prims
            .iter()
            .map(|p| p.ground_m.iter().map(|&(x, y)| top_down(x, y)).collect())
            .collect();
        let (w, h) = (60, 40);
        let run = |nav: &[u8], bearing: f64| {
            let hz = visual_horizon(nav, w, h, &PovnavConfig::default());
            choose(&hz, &vec![1; h], &prims, &pixels, bearing, &cfg)
        };
        // Open ground: full speed straight at a goal ahead.
        let open = vec![255u8; w * h];
        let (i, _) = run(&open, 0.0).unwrap();
        assert_eq!(i, straight);
        // A goal to the left: a left turn.
        let (i, _) = run(&open, 1.0).unwrap();
        assert!(prims[i].angular_radps > 0.0, "{:?}", prims[i].angular_radps);
        // A block 2 m ahead, columns 20-40: the straight arcs cross it.
        let blocked: Vec<u8> = (0..w * h)
            .map(|k| {
                let (u, v) = (k % w, k / w);
                if (20..=40).contains(&u) && (28..=32).contains(&v) {
                    0
                } else {
                    255
                }
            })
            .collect();
        let (i, _) = run(&blocked, 0.0).unwrap();
        assert!(prims[i].angular_radps != 0.0, "it turns away");
        for &(x, y) in &prims[i].ground_m {
            let (u, v) = top_down(x, y).unwrap();
            assert!(
                !((19.5..=40.5).contains(&u) && (27.5..=32.5).contains(&v)),
                "its arc misses the block: ({u}, {v})"
            );
        }
        // Nothing navigable: only a turn on the spot, whose arc never
        // leaves the ground under the robot (below the image), is left.
        let (i, _) = run(&vec![0u8; w * h], 0.0).expect("a turn on the spot");
        assert!(
            pixels[i].iter().flatten().all(|&(_, v)| v > h as f64 - 1.0),
            "{:?}",
            prims[i]
        );
        assert!(prims[i].angular_radps.abs() > 3.0, "{:?}", prims[i]);
    }
}
