//! LRN's goal-conditioned head (Algorithm 1): the filtered bin scores times a
//! Gaussian around the goal bearing (sigma_g) times a Gaussian around the
//! previous choice (sigma_p); the argmax bin is the heading. Near the goal
//! sigma_g shrinks linearly, and closer still the robot heads straight for it
//! (the paper's Spot and Racer Heavy presets). With uniform bins the same head
//! is the "goal heuristic" baseline.

use farsight_stage::{Range, Ranges, Validate};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// The head's parameters.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LrnHeadConfig {
    pub sigma_goal_deg: f64,
    pub sigma_previous_deg: f64,
    /// Within this distance sigma_g shrinks linearly with the distance (0 = never).
    pub shrink_within_m: f64,
    /// Within this distance the heading is the goal bearing itself.
    pub straight_within_m: f64,
    /// The "goal heuristic" baseline: ignore the bin scores.
    pub goal_heuristic: bool,
    /// What the head does when no observed bin has any score.
    pub no_hotspot: NoHotspot,
}

/// What LRN's head does when bins were observed but none has any score (a
/// threshold above everything the model gives, a view with nothing
/// affordable). Scores are EMA-filtered, so once a bin has scored it keeps
/// a (fading) score until it is next unobserved: this applies only while
/// nothing observed has passed the threshold. With no bin observed at all
/// (no camera frame, the goal's side unseen) the head never heads anywhere.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum NoHotspot {
    /// No heading: the stage reports DEGRADED and answers the frame with a
    /// `BLOCKED` subgoal (no heading, no point), which the servo answers
    /// with a stop on that frame.
    #[default]
    Stop,
    /// Head for the goal, as LRN's robot did with nothing affordable
    /// (section V-B: at h_thresh 1.0 "the robot switches between heading
    /// directly towards the goal and a random hotspot that appear
    /// infrequently"). The goal bearing also becomes the previous choice.
    /// The stage reports DEGRADED while it does.
    Goal,
}

impl LrnHeadConfig {
    /// Spot (LRN section IV): sigma_g 90, sigma_p 110, shrink within 30 m,
    /// straight within 12 m.
    pub fn spot() -> Self {
        Self {
            sigma_goal_deg: 90.0,
            sigma_previous_deg: 110.0,
            shrink_within_m: 30.0,
            straight_within_m: 12.0,
            goal_heuristic: false,
            no_hotspot: NoHotspot::Stop,
        }
    }

    /// Racer Heavy: sigma_g 70, sigma_p 100, straight within 75 m, no shrinking.
    pub fn racer_heavy() -> Self {
        Self {
            sigma_goal_deg: 70.0,
            sigma_previous_deg: 100.0,
            shrink_within_m: 0.0,
            straight_within_m: 75.0,
            goal_heuristic: false,
            no_hotspot: NoHotspot::Stop,
        }
    }
}

impl Default for LrnHeadConfig {
    fn default() -> Self {
        Self::spot()
    }
}

impl Validate for LrnHeadConfig {
    fn ranges(&self, r: &mut Ranges) {
        r.key(
            "sigma_goal_deg",
            self.sigma_goal_deg,
            Range::above_to(0.0, 360.0).unit("deg"),
        )
        .key(
            "sigma_previous_deg",
            self.sigma_previous_deg,
            Range::above_to(0.0, 360.0).unit("deg"),
        )
        // 0: off.
        .key(
            "shrink_within_m",
            self.shrink_within_m,
            Range::between(0.0, 1000.0).unit("m"),
        )
        .key(
            "straight_within_m",
            self.straight_within_m,
            Range::between(0.0, 1000.0).unit("m"),
        );
    }
}

fn wrap(a: f64) -> f64 {
    (a + PI).rem_euclid(2.0 * PI) - PI
}

fn gaussian(x: f64, mu: f64, sigma: f64) -> f64 {
    let d = wrap(x - mu);
    (-0.5 * (d / sigma).powi(2)).exp()
}

/// The head's state: the previous choice.
///
/// Bins and choices are bearings in the robot frame, but the previous
/// choice is a direction in the world: when the robot turns toward a
/// heading, that heading must stay where it was, not turn with the robot
/// (which would make the head chase its own tail). [`LrnHead::set_robot_yaw`]
/// keeps it there; a head never told the yaw keeps it in the robot frame.
#[derive(Debug, Clone, Default)]
pub struct LrnHead {
    previous_rad: Option<f64>,
    yaw_rad: Option<f64>,
    fell_back: bool,
}

impl LrnHead {
    /// The robot's yaw (any fixed frame) at the frame about to be selected
    /// on: the previous choice turns the other way by as much as the robot
    /// turned since the last call.
    pub fn set_robot_yaw(&mut self, yaw_rad: f64) {
        if !yaw_rad.is_finite() {
            return;
        }
        if let (Some(prev), Some(last)) = (self.previous_rad.as_mut(), self.yaw_rad) {
            *prev = wrap(*prev - (yaw_rad - last));
        }
        self.yaw_rad = Some(yaw_rad);
    }

    /// Whether the last [`Self::select`] found no observed bin with any
    /// score and headed for the goal ([`NoHotspot::Goal`]).
    pub fn fell_back(&self) -> bool {
        self.fell_back
    }

    /// The heading to take. `centers_rad[i]` is bin i's bearing; unobserved
    /// bins cannot be chosen. When bins were observed but none has any
    /// score: `None`, or the goal's bearing with [`NoHotspot::Goal`]. With
    /// no bin observed: `None` (nothing seen is not "nothing affordable").
    pub fn select(
        &mut self,
        cfg: &LrnHeadConfig,
        scores: &[f64],
        observed: &[bool],
        centers_rad: &[f64],
        goal_bearing_rad: f64,
        goal_distance_m: f64,
    ) -> Option<f64> {
        self.fell_back = false;
        if goal_distance_m <= cfg.straight_within_m {
            self.previous_rad = Some(wrap(goal_bearing_rad));
            return self.previous_rad;
        }
        let mut sigma_g = cfg.sigma_goal_deg.to_radians();
        if cfg.shrink_within_m > 0.0 && goal_distance_m < cfg.shrink_within_m {
            sigma_g *= (goal_distance_m / cfg.shrink_within_m).max(1e-3);
        }
        let sigma_p = cfg.sigma_previous_deg.to_radians();
        let mut best: Option<(f64, f64)> = None;
        for i in 0..scores.len() {
            if !observed[i] {
                continue;
            }
            let b = if cfg.goal_heuristic { 1.0 } else { scores[i] };
            let g = gaussian(centers_rad[i], goal_bearing_rad, sigma_g);
            // Algorithm 1 starts with p = 1 everywhere.
            let p = self
                .previous_rad
                .map_or(1.0, |prev| gaussian(centers_rad[i], prev, sigma_p));
            let v = b * g * p;
            if v > 0.0 && best.is_none_or(|(_, bv)| v > bv) {
                best = Some((centers_rad[i], v));
            }
        }
        let mut choice = best.map(|(c, _)| c);
        let seen = observed.iter().take(scores.len()).any(|&o| o);
        if choice.is_none() && seen && cfg.no_hotspot == NoHotspot::Goal {
            choice = Some(wrap(goal_bearing_rad));
            self.fell_back = true;
        }
        if choice.is_some() {
            self.previous_rad = choice;
        }
        choice
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 8 bins of 45 degrees; centres -157.5 .. 157.5.
    fn centers() -> Vec<f64> {
        (0..8).map(|i| -PI + (i as f64 + 0.5) * PI / 4.0).collect()
    }

    #[test]
    fn goal_ahead_picks_the_affordable_bin_nearest_the_goal() {
        let c = centers();
        // Bins 3 (-22.5) and 4 (+22.5) straight ahead; bin 4 affordable, bin 6 (+112.5) more so.
        let scores = [0.0, 0.0, 0.0, 0.0, 0.3, 0.0, 0.7, 0.0];
        let mut head = LrnHead::default();
        let h = head
            .select(&LrnHeadConfig::spot(), &scores, &[true; 8], &c, 0.0, 100.0)
            .unwrap();
        // v4 = 0.3 * exp(-0.5 (22.5/90)^2) = 0.291; v6 = 0.7 * exp(-0.5 (112.5/90)^2) = 0.320:
        // with sigma_g 90 the stronger side bin wins...
        assert!((h - c[6]).abs() < 1e-12);
        // ...and a narrower goal Gaussian (Racer Heavy, 70) keeps the robot near the goal.
        let mut head = LrnHead::default();
        let h = head
            .select(
                &LrnHeadConfig::racer_heavy(),
                &scores,
                &[true; 8],
                &c,
                0.0,
                100.0,
            )
            .unwrap();
        assert!((h - c[4]).abs() < 1e-12);
    }

    #[test]
    fn with_nothing_affordable_the_head_stops_or_heads_for_the_goal_as_configured() {
        let c = centers();
        let none = [0.0; 8];
        let goal = 1.0; // rad, left of ahead
        let mut head = LrnHead::default();
        let stop = LrnHeadConfig::spot();
        assert_eq!(head.select(&stop, &none, &[true; 8], &c, goal, 100.0), None);
        assert!(!head.fell_back());
        let to_goal = LrnHeadConfig {
            no_hotspot: NoHotspot::Goal,
            ..stop
        };
        let h = head.select(&to_goal, &none, &[true; 8], &c, goal, 100.0);
        assert_eq!(h, Some(goal));
        assert!(head.fell_back());
        // Nothing observed is not nothing affordable: no heading, even
        // where unobserved bins carry scores.
        let mut blind = LrnHead::default();
        assert_eq!(
            blind.select(&to_goal, &[0.9; 8], &[false; 8], &c, goal, 100.0),
            None
        );
        assert!(!blind.fell_back());
        // The goal became the previous choice, which sigma_p then favours:
        // with the goal now straight ahead and two hotspots either side of
        // it, a fresh head takes the stronger one (-67.5 deg), the head
        // that fell back the one near its last heading (+67.5 deg, 10
        // degrees from the old goal at 57.3).
        let mut two = [0.0; 8];
        two[2] = 0.55;
        two[5] = 0.5;
        let fresh = LrnHead::default()
            .select(&to_goal, &two, &[true; 8], &c, 0.0, 100.0)
            .unwrap();
        assert!((fresh - c[2]).abs() < 1e-12);
        let h = head
            .select(&to_goal, &two, &[true; 8], &c, 0.0, 100.0)
            .unwrap();
        assert!((h - c[5]).abs() < 1e-12);
        assert!(!head.fell_back(), "a hotspot: no fallback");
    }

    #[test]
    fn goal_behind_an_unaffordable_front_goes_round_the_open_side() {
        let c = centers();
        // Goal behind (180 deg); the front camera sees bins 2..=5 only: the right
        // side (bin 2, -67.5) is affordable, the left side is not.
        let scores = [0.0, 0.0, 0.5, 0.1, 0.0, 0.0, 0.0, 0.0];
        let observed = [false, false, true, true, true, true, false, false];
        let mut head = LrnHead::default();
        let h = head
            .select(&LrnHeadConfig::spot(), &scores, &observed, &c, PI, 100.0)
            .unwrap();
        assert!((h - c[2]).abs() < 1e-12, "{}", h.to_degrees());
        // The goal heuristic ignores affordance: the observed bin nearest the goal.
        let mut base = LrnHead::default();
        let cfg = LrnHeadConfig {
            goal_heuristic: true,
            ..LrnHeadConfig::spot()
        };
        let h = base
            .select(&cfg, &scores, &observed, &c, PI, 100.0)
            .unwrap();
        assert!(
            (h - c[2]).abs() < 1e-12 || (h - c[5]).abs() < 1e-12,
            "a bin at +-67.5 deg"
        );
    }

    #[test]
    fn near_goal_schedule() {
        let c = centers();
        // Bin 4 (+22.5 deg) 0.3, bin 6 (+112.5 deg) 0.7; goal straight ahead.
        let scores = [0.0, 0.0, 0.0, 0.0, 0.3, 0.0, 0.7, 0.0];
        let observed = [true; 8];
        let cfg = LrnHeadConfig::spot();
        // Within 12 m: straight to the goal whatever the bins say.
        let mut head = LrnHead::default();
        let h = head
            .select(&cfg, &scores, &observed, &c, 0.3, 11.0)
            .unwrap();
        assert!((h - 0.3).abs() < 1e-12);
        // At 100 m (sigma_g 90): 0.7 exp(-0.5 (112.5/90)^2) = 0.320 beats
        // 0.3 exp(-0.5 (22.5/90)^2) = 0.291, so the robot swings wide.
        let mut head = LrnHead::default();
        assert_eq!(
            head.select(&cfg, &scores, &observed, &c, 0.0, 100.0),
            Some(c[6])
        );
        // At 20 m sigma_g has shrunk to 90 * 20/30 = 60 deg: 0.3 exp(-0.5 (22.5/60)^2)
        // = 0.280 beats 0.7 exp(-0.5 (112.5/60)^2) = 0.120: it turns in.
        let mut head = LrnHead::default();
        assert_eq!(
            head.select(&cfg, &scores, &observed, &c, 0.0, 20.0),
            Some(c[4])
        );
    }

    #[test]
    fn previous_choice_damps_switching() {
        let c = centers();
        let mut head = LrnHead::default();
        let cfg = LrnHeadConfig::spot();
        // Two equal bins symmetric about the goal; the first pick is kept after.
        let scores = [0.0, 0.0, 0.0, 0.5, 0.5, 0.0, 0.0, 0.0];
        let first = head
            .select(&cfg, &scores, &[true; 8], &c, 0.0, 100.0)
            .unwrap();
        let slightly_other = [0.0, 0.0, 0.0, 0.49, 0.51, 0.0, 0.0, 0.0];
        let prefer = if (first - c[3]).abs() < 1e-12 {
            c[3]
        } else {
            c[4]
        };
        let swapped = if prefer == c[3] {
            slightly_other
        } else {
            [0.0, 0.0, 0.0, 0.51, 0.49, 0.0, 0.0, 0.0]
        };
        let second = head
            .select(&cfg, &swapped, &[true; 8], &c, 0.0, 100.0)
            .unwrap();
        assert_eq!(second, prefer, "a 2% difference does not flip the choice");
        // The robot turns 45 degrees toward its choice: in the robot frame
        // the remembered heading is now 45 degrees nearer straight ahead.
        let mut turning = head.clone();
        turning.set_robot_yaw(1.0);
        let side = prefer.signum();
        turning.set_robot_yaw(1.0 + side * PI / 4.0);
        assert!(
            (turning.previous_rad.unwrap() - (prefer - side * PI / 4.0)).abs() < 1e-12,
            "{:?}",
            turning.previous_rad
        );
        assert_eq!(
            head.select(&cfg, &[0.0; 8], &[true; 8], &c, 0.0, 100.0),
            None
        );
    }
}
