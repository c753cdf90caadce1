//! # farsight-velocity-servoing
//!
//! Turns a subgoal into a velocity command the platform can follow:
//!
//! - [`povnav_command`]: POVNav's control law (section 4.7, eq. 12-13):
//!   v from the proximity error, omega from the alignment, both clamped, with
//!   the optional friction-circle bound on the lateral acceleration v * omega;
//! - [`heading_command`]: tracking a heading (LRN's chosen bin) with the same
//!   bounds;
//! - [`carrot_point`] + [`carrot_command`]: tracking a planner's path (D* Lite,
//!   HIP) by steering at a carrot point `lookahead_m` along it, bounded the
//!   same way;
//! - [`RateLimiter`]: linear and angular acceleration limits between commands;
//! - [`decide`]: the safety rules: stale inputs or an active e-stop give zero
//!   velocity with the reason, inside the goal radius the robot stops.
//!
//! Angles are counter-clockwise (REP-103), so a positive alignment (path bends
//! left) gives a positive (left) turn rate: omega = k_omega * phi, the paper's
//! omega = -k_omega * phi in its clockwise convention.
//!
//! ```
//! use farsight_velocity_servoing::{povnav_command, ServoConfig};
//!
//! let cfg = ServoConfig::default();
//! // Far from obstacles (lambda 200 px), path 0.2 rad to the left.
//! let (v, w) = povnav_command(200.0, 0.2, &cfg);
//! assert_eq!(v, cfg.max_linear_mps);
//! assert!(w > 0.0);
//! ```

pub mod servo_stage;
pub mod stage;

use farsight_interfaces::msg::{CommandReason, Path, PathFrame, Pose};
use farsight_stage::{Range, Ranges, Validate};
use serde::{Deserialize, Serialize};

/// Servo parameters (defaults from the POVNav code: |v| <= 0.5 m/s,
/// |omega| <= pi rad/s (the reference code writes 3.14), lambda* = 50 px, stop within 0.5 m of the goal).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ServoConfig {
    /// Desired proximity lambda* (pixels).
    pub desired_proximity_px: f64,
    /// k_v: m/s per pixel of proximity error.
    pub k_linear: f64,
    /// k_omega: rad/s per rad of alignment.
    pub k_angular: f64,
    pub max_linear_mps: f64,
    pub max_angular_radps: f64,
    pub max_linear_accel_mps2: f64,
    pub max_angular_accel_radps2: f64,
    /// Friction-circle bound on |v * omega| (m/s^2), mu * g; 0 = off.
    pub max_lateral_accel_mps2: f64,
    /// Whether the law may command reverse (the paper backs away when the
    /// proximity is below lambda*); off by default, as cameras face forward.
    pub allow_reverse: bool,
    /// Stop inside this distance of the goal.
    pub goal_radius_m: f64,
    /// Carrot distance along a tracked path (metres).
    pub lookahead_m: f64,
}

impl Default for ServoConfig {
    fn default() -> Self {
        Self {
            desired_proximity_px: 50.0,
            k_linear: 0.01,
            k_angular: 1.5,
            max_linear_mps: 0.5,
            max_angular_radps: std::f64::consts::PI,
            max_linear_accel_mps2: 1.0,
            max_angular_accel_radps2: 3.0,
            max_lateral_accel_mps2: 0.0,
            allow_reverse: false,
            goal_radius_m: 0.5,
            lookahead_m: 2.0,
        }
    }
}

impl Validate for ServoConfig {
    fn ranges(&self, r: &mut Ranges) {
        r.key(
            "desired_proximity_px",
            self.desired_proximity_px,
            Range::between(0.0, 10_000.0).unit("px"),
        )
        .key(
            "k_linear",
            self.k_linear,
            Range::above_to(0.0, 10.0).unit("m/s per px"),
        )
        .key(
            "k_angular",
            self.k_angular,
            Range::above_to(0.0, 100.0).unit("rad/s per rad"),
        )
        .key(
            "max_linear_mps",
            self.max_linear_mps,
            Range::above_to(0.0, 20.0).unit("m/s"),
        )
        .key(
            "max_angular_radps",
            self.max_angular_radps,
            Range::above_to(0.0, 10.0).unit("rad/s"),
        )
        .key(
            "max_linear_accel_mps2",
            self.max_linear_accel_mps2,
            Range::above_to(0.0, 50.0).unit("m/s^2"),
        )
        .key(
            "max_angular_accel_radps2",
            self.max_angular_accel_radps2,
            Range::above_to(0.0, 100.0).unit("rad/s^2"),
        )
        // 0: no lateral limit.
        .key(
            "max_lateral_accel_mps2",
            self.max_lateral_accel_mps2,
            Range::between(0.0, 50.0).unit("m/s^2"),
        )
        .key(
            "goal_radius_m",
            self.goal_radius_m,
            Range::between(0.0, 100.0).unit("m"),
        )
        .key(
            "lookahead_m",
            self.lookahead_m,
            Range::above_to(0.0, 100.0).unit("m"),
        );
    }
}

fn clamp_command(v: f64, w: f64, cfg: &ServoConfig) -> (f64, f64) {
    let v_min = if cfg.allow_reverse {
        -cfg.max_linear_mps
    } else {
        0.0
    };
    let mut v = v.clamp(v_min, cfg.max_linear_mps);
    let w = w.clamp(-cfg.max_angular_radps, cfg.max_angular_radps);
    // Friction circle: slow down rather than turn less, so the robot still
    // follows the path it was told to.
    if cfg.max_lateral_accel_mps2 > 0.0 && (v * w).abs() > cfg.max_lateral_accel_mps2 {
        v = v.signum() * cfg.max_lateral_accel_mps2 / w.abs();
    }
    (v, w)
}

/// POVNav's law (eq. 13): `v = k_v (lambda - lambda*)`, `omega = k_omega phi`, bounded.
pub fn povnav_command(proximity_px: f64, alignment_rad: f64, cfg: &ServoConfig) -> (f64, f64) {
    if !proximity_px.is_finite() || !alignment_rad.is_finite() {
        return (0.0, 0.0);
    }
    clamp_command(
        cfg.k_linear * (proximity_px - cfg.desired_proximity_px),
        cfg.k_angular * alignment_rad,
        cfg,
    )
}

/// Tracks a heading (robot frame, counter-clockwise): turn toward it, and slow
/// down the further off it is (full speed when aligned, none beyond 90 deg).
pub fn heading_command(heading_rad: f64, cfg: &ServoConfig) -> (f64, f64) {
    if !heading_rad.is_finite() {
        return (0.0, 0.0);
    }
    let h = (heading_rad + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI)
        - std::f64::consts::PI;
    clamp_command(
        cfg.max_linear_mps * h.cos().max(0.0),
        cfg.k_angular * h,
        cfg,
    )
}

/// The carrot on a path (robot frame, metres, in driving order): from the
/// path vertex nearest the robot, the first point along the path at
/// `lookahead_m` from the robot, interpolated on the segment that crosses that
/// circle; the path's end when all of the rest is closer. Starting from the
/// nearest vertex means a path planned a moment ago, whose first points the
/// robot has already passed, is still followed forward. `None` for an empty
/// path or one with a non-finite point (never steer at garbage).
pub fn carrot_point(path_robot_m: &[[f64; 2]], lookahead_m: f64) -> Option<[f64; 2]> {
    if path_robot_m
        .iter()
        .any(|p| !(p[0].is_finite() && p[1].is_finite()))
    {
        return None;
    }
    let dist = |p: &[f64; 2]| p[0].hypot(p[1]);
    let nearest = path_robot_m
        .iter()
        .enumerate()
        .min_by(|a, b| dist(a.1).total_cmp(&dist(b.1)))?
        .0;
    let rest = &path_robot_m[nearest..];
    for w in rest.windows(2) {
        let (a, b) = (w[0], w[1]);
        if dist(&b) >= lookahead_m {
            if dist(&a) >= lookahead_m {
                return Some(a);
            }
            // |a + t (b - a)| = L on t in [0, 1], the root past a.
            let d = [b[0] - a[0], b[1] - a[1]];
            let (qa, qb, qc) = (
                d[0] * d[0] + d[1] * d[1],
                2.0 * (a[0] * d[0] + a[1] * d[1]),
                a[0] * a[0] + a[1] * a[1] - lookahead_m * lookahead_m,
            );
            let t = (-qb + (qb * qb - 4.0 * qa * qc).max(0.0).sqrt()) / (2.0 * qa);
            let t = t.clamp(0.0, 1.0);
            return Some([a[0] + t * d[0], a[1] + t * d[1]]);
        }
    }
    rest.last().copied()
}

/// Steers at a carrot (robot frame, metres) as [`heading_command`] does, and
/// slows in proportion once the carrot is closer than `lookahead_m` (the end
/// of the path), so the robot arrives rather than overshoots.
pub fn carrot_command(carrot_m: [f64; 2], cfg: &ServoConfig) -> (f64, f64) {
    let (v, w) = heading_command(carrot_m[1].atan2(carrot_m[0]), cfg);
    let d = carrot_m[0].hypot(carrot_m[1]);
    (v * (d / cfg.lookahead_m).min(1.0), w)
}

/// A planner's path in the robot frame now: a world-frame path is moved into
/// the frame of `pose`; a robot-frame one is used as it is. The error says why
/// the path cannot be tracked (image-frame paths are for inspection only).
pub fn path_in_robot_frame(path: &Path, pose: Option<&Pose>) -> Result<Vec<[f64; 2]>, String> {
    let points = path
        .points
        .as_slice()
        .iter()
        .map(|p| [p[0] as f64, p[1] as f64]);
    match path.frame {
        PathFrame::ROBOT => Ok(points.collect()),
        PathFrame::WORLD => {
            let pose = pose.ok_or("a world-frame path needs a pose, none received yet")?;
            Ok(points.map(|p| pose.to_robot_frame(p)).collect())
        }
        other => Err(format!("cannot track a path in the {other} frame")),
    }
}

/// Limits how fast the command may change between two outputs.
#[derive(Debug, Clone, Copy, Default)]
pub struct RateLimiter {
    last: (f64, f64),
}

impl RateLimiter {
    /// The command `target` limited by the acceleration bounds over `dt_s`.
    pub fn limit(&mut self, target: (f64, f64), dt_s: f64, cfg: &ServoConfig) -> (f64, f64) {
        let dt = dt_s.clamp(0.0, 1.0);
        let step = |from: f64, to: f64, a: f64| from + (to - from).clamp(-a * dt, a * dt);
        self.last = (
            step(self.last.0, target.0, cfg.max_linear_accel_mps2),
            step(self.last.1, target.1, cfg.max_angular_accel_radps2),
        );
        self.last
    }

    /// An emergency stop skips the ramp: the output is zero at once.
    pub fn stop(&mut self) -> (f64, f64) {
        self.last = (0.0, 0.0);
        self.last
    }
}

/// What the servo knows when it must publish.
#[derive(Debug, Clone, Copy)]
pub struct Inputs {
    /// Its subgoal input is older than the deadline (or never arrived).
    pub subgoal_stale: bool,
    pub estop_active: bool,
    /// Distance to the goal, if known.
    pub goal_distance_m: Option<f64>,
}

/// The safety rules, before any control law: `Some(reason)` means publish zero.
pub fn decide(inputs: &Inputs, cfg: &ServoConfig) -> Option<CommandReason> {
    if inputs.estop_active {
        Some(CommandReason::ESTOP)
    } else if inputs
        .goal_distance_m
        .is_some_and(|d| d <= cfg.goal_radius_m)
    {
        Some(CommandReason::GOAL_REACHED)
    } else if inputs.subgoal_stale {
        Some(CommandReason::STALE_INPUT)
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn law_by_hand_and_its_bounds() {
        let cfg = ServoConfig::default();
        // lambda 80 px: v = 0.01 * 30 = 0.3 m/s; phi -0.1 rad: omega = -0.15 rad/s.
        let (v, w) = povnav_command(80.0, -0.1, &cfg);
        assert!(
            (v - 0.3).abs() < 1e-12 && (w + 0.15).abs() < 1e-12,
            "{v} {w}"
        );
        assert_eq!(
            povnav_command(1000.0, 5.0, &cfg),
            (0.5, std::f64::consts::PI),
            "clamped to the limits"
        );
        assert_eq!(
            povnav_command(10.0, 0.0, &cfg).0,
            0.0,
            "too close: no reverse by default"
        );
        let rev = ServoConfig {
            allow_reverse: true,
            ..cfg
        };
        assert!(
            (povnav_command(10.0, 0.0, &rev).0 + 0.4).abs() < 1e-12,
            "the paper's law backs away"
        );
        assert_eq!(
            povnav_command(f64::NAN, 0.0, &cfg),
            (0.0, 0.0),
            "a NaN feature never moves the robot"
        );
    }

    #[test]
    fn friction_circle_caps_v_times_omega() {
        let cfg = ServoConfig {
            max_lateral_accel_mps2: 0.2,
            ..Default::default()
        };
        let (v, w) = povnav_command(1000.0, 0.5, &cfg); // v 0.5, omega 0.75 -> 0.375 > 0.2
        assert!(
            (v * w - 0.2).abs() < 1e-12 && (w - 0.75).abs() < 1e-12,
            "{v} {w}"
        );
    }

    #[test]
    fn acceleration_limits_ramp_and_estop_does_not() {
        let cfg = ServoConfig::default();
        let mut r = RateLimiter::default();
        let near =
            |a: (f64, f64), b: (f64, f64)| (a.0 - b.0).abs() < 1e-12 && (a.1 - b.1).abs() < 1e-12;
        // 1 m/s^2 and 3 rad/s^2 over 0.1 s: steps of 0.1 m/s and 0.3 rad/s.
        assert!(near(r.limit((0.5, 1.0), 0.1, &cfg), (0.1, 0.3)));
        assert!(near(r.limit((0.5, 1.0), 0.1, &cfg), (0.2, 0.6)));
        assert_eq!(r.stop(), (0.0, 0.0));
    }

    #[test]
    fn heading_tracking_turns_toward_and_slows_when_off() {
        let cfg = ServoConfig::default();
        assert_eq!(heading_command(0.0, &cfg), (0.5, 0.0));
        let (v, w) = heading_command(std::f64::consts::FRAC_PI_3, &cfg);
        assert!((v - 0.25).abs() < 1e-12 && w > 0.0);
        let (v, w) = heading_command(3.0, &cfg);
        assert_eq!(v, 0.0, "turn in place toward a goal behind");
        assert!(w > 0.0);
    }

    #[test]
    fn carrot_on_a_path_by_hand() {
        let near =
            |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).abs() < 1e-9 && (a[1] - b[1]).abs() < 1e-9;
        // Straight ahead then a left turn: (0,0) -> (1,0) -> (1,3). With L = 2 the
        // circle crosses the second segment at x = 1, y = sqrt(3).
        let path = [[0.0, 0.0], [1.0, 0.0], [1.0, 3.0]];
        assert!(near(carrot_point(&path, 2.0).unwrap(), [1.0, 3f64.sqrt()]));
        // The robot has driven past the first vertices: the path now starts
        // behind it, and the carrot is still found ahead along the path.
        let behind = [[-4.0, 0.0], [-2.0, 0.0], [0.5, 0.0], [3.0, 0.0], [6.0, 0.0]];
        assert!(near(carrot_point(&behind, 2.0).unwrap(), [2.0, 0.0]));
        // All of the path inside the circle: its end.
        assert!(near(
            carrot_point(&[[0.0, 0.0], [0.5, 0.5]], 2.0).unwrap(),
            [0.5, 0.5]
        ));
        assert_eq!(carrot_point(&[], 2.0), None);
        assert_eq!(carrot_point(&[[0.0, 0.0], [f64::NAN, 1.0]], 2.0), None);
    }

    #[test]
    fn carrot_command_turns_toward_it_and_slows_at_the_end() {
        let cfg = ServoConfig::default();
        // Carrot 2 m away at 45 deg left: v = 0.5 cos 45, omega = 1.5 * pi/4.
        let (v, w) = carrot_command([2f64.sqrt(), 2f64.sqrt()], &cfg);
        assert!(
            (v - 0.5 * std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-12,
            "{v}"
        );
        assert!((w - 1.5 * std::f64::consts::FRAC_PI_4).abs() < 1e-12, "{w}");
        // The path's end 0.5 m ahead with L = 2: a quarter of full speed.
        let (v, w) = carrot_command([0.5, 0.0], &cfg);
        assert!((v - 0.125).abs() < 1e-12 && w == 0.0, "{v} {w}");
        // A carrot behind: turn in place, never reverse.
        let (v, w) = carrot_command([-3.0, -0.1], &cfg);
        assert_eq!(v, 0.0);
        assert!(w < 0.0, "turns right toward a carrot behind-right");
    }

    #[test]
    fn safety_rules_in_order() {
        let cfg = ServoConfig::default();
        let i = |stale, estop, d| Inputs {
            subgoal_stale: stale,
            estop_active: estop,
            goal_distance_m: d,
        };
        assert_eq!(decide(&i(false, false, Some(5.0)), &cfg), None);
        assert_eq!(
            decide(&i(true, false, None), &cfg),
            Some(CommandReason::STALE_INPUT)
        );
        assert_eq!(
            decide(&i(true, true, None), &cfg),
            Some(CommandReason::ESTOP)
        );
        assert_eq!(
            decide(&i(false, false, Some(0.3)), &cfg),
            Some(CommandReason::GOAL_REACHED)
        );
    }
}
