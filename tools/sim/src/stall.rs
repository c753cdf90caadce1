//! HIP's stall heuristics (section V, "Training"): a *stuck collision*
//! "triggers when the robot is stationary for over 4 seconds", a *trapped
//! collision* "when the robot does not move over 3m over a 10s period,
//! which prevents tight circular movement or very slow motion". The paper
//! used them to cut its data collection; HIP's evaluation counts a trial
//! "unharmed" only without them. One detector serves both here: the
//! sticky-action drive ([`crate::sticky`]) and the end-trial intervention
//! rule ([`crate::episode::InterventionRule::EndTrial`]), so the library's
//! data and the benchmark judge a stall the same way.

use std::collections::VecDeque;

/// A stuck robot has stayed within this of where it stands for `STUCK_S`.
pub const STATIONARY_TOLERANCE_M: f64 = 0.05;
pub const STUCK_S: f64 = 4.0;
pub const TRAPPED_S: f64 = 10.0;
pub const TRAPPED_MIN_TRAVEL_M: f64 = 3.0;

/// Which heuristic fired, and since when the robot has been in it: the
/// start of the window that showed it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Stall {
    Stuck { onset_s: f64 },
    Trapped { onset_s: f64 },
}

impl Stall {
    pub fn onset_s(self) -> f64 {
        match self {
            Stall::Stuck { onset_s } | Stall::Trapped { onset_s } => onset_s,
        }
    }
}

/// The robot's positions over the last `TRAPPED_S`, judged at every step.
#[derive(Debug, Clone, Default)]
pub struct StallDetector {
    history: VecDeque<(f64, [f64; 2])>,
}

impl StallDetector {
    /// Forgets the past: after a respawn or an operator's carry, the robot
    /// starts a new window.
    pub fn reset(&mut self) {
        self.history.clear();
    }

    /// Records the robot at `at` (m) at `t_s`; a stall once a full window
    /// shows one. Stuck is judged before trapped: its onset is the later.
    pub fn observe(&mut self, t_s: f64, at: [f64; 2]) -> Option<Stall> {
        self.history.push_back((t_s, at));
        // Keep one sample at or before the window's start, so the window
        // is judged over its whole length.
        while self.history.len() > 1 && t_s - self.history[1].0 >= TRAPPED_S {
            self.history.pop_front();
        }
        let dist = |p: &[f64; 2]| (p[0] - at[0]).hypot(p[1] - at[1]);
        let &(t0, _) = self.history.front()?;
        // Stationary: every position of the last STUCK_S within the
        // tolerance, and at least STUCK_S of them ("over 4 seconds").
        let mut still_since = t_s;
        for &(t, p) in self.history.iter().rev() {
            if dist(&p) > STATIONARY_TOLERANCE_M {
                break;
            }
            still_since = t;
        }
        if t_s - still_since > STUCK_S {
            return Some(Stall::Stuck {
                onset_s: still_since,
            });
        }
        if t_s - t0 >= TRAPPED_S && dist(&self.history[0].1) < TRAPPED_MIN_TRAVEL_M {
            return Some(Stall::Trapped { onset_s: t0 });
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Feeds positions at 10 Hz from `f(t)`; the first stall and its time.
    fn first_stall(f: impl Fn(f64) -> [f64; 2], until_s: f64) -> Option<(f64, Stall)> {
        let mut d = StallDetector::default();
        (0..=(until_s * 10.0) as usize).find_map(|k| {
            let t = k as f64 / 10.0;
            d.observe(t, f(t)).map(|s| (t, s))
        })
    }

    #[test]
    fn standing_still_is_stuck_just_after_four_seconds_from_when_it_stopped() {
        // Drives 1 m/s for 5 s, then stops at x = 5.
        let (t, s) = first_stall(|t| [t.min(5.0), 0.0], 30.0).expect("stuck");
        assert!((t - 9.1).abs() < 1e-9, "{t}");
        assert_eq!(s, Stall::Stuck { onset_s: 5.0 });
        // Creeping at 1 cm/s is stationary too (4 cm in 4 s); at 3 cm/s it
        // is not, but it is trapped after 10 s instead.
        let (t, s) = first_stall(|t| [0.01 * t, 0.0], 30.0).expect("stuck");
        assert!(matches!(s, Stall::Stuck { .. }) && t < 5.5, "{t} {s:?}");
        let (_, s) = first_stall(|t| [0.03 * t, 0.0], 30.0).expect("trapped");
        assert!(
            matches!(s, Stall::Trapped { onset_s } if onset_s.abs() < 1e-9),
            "{s:?}"
        );
    }

    #[test]
    fn circling_tightly_is_trapped_and_driving_on_is_neither() {
        // A 1 m circle at 1 m/s covers 10 m in 10 s and ends near where it began.
        let circle = |t: f64| [t.cos(), t.sin()];
        let (t, s) = first_stall(circle, 30.0).expect("trapped");
        assert!(matches!(s, Stall::Trapped { .. }), "{s:?}");
        assert!(t >= TRAPPED_S, "{t}");
        // 0.35 m/s straight: 3.5 m in every 10 s window.
        assert_eq!(first_stall(|t| [0.35 * t, 0.0], 60.0), None);
        // Slowing to 0.25 m/s is "very slow motion".
        assert!(matches!(
            first_stall(|t| [0.25 * t, 0.0], 60.0),
            Some((_, Stall::Trapped { .. }))
        ));
    }

    #[test]
    fn a_reset_starts_a_new_window() {
        let mut d = StallDetector::default();
        for k in 0..=38 {
            assert_eq!(d.observe(k as f64 / 10.0, [0.0, 0.0]), None);
        }
        d.reset();
        for k in 40..=80 {
            assert_eq!(d.observe(k as f64 / 10.0, [0.0, 0.0]), None, "{k}");
        }
        assert!(d.observe(8.1, [0.0, 0.0]).is_some());
    }
}
