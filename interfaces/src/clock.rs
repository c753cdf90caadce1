//! Injected time.
//!
//! Stages never read the system clock directly: on the robot they get a
//! [`WallClock`], in replays and lock-step simulation a [`ManualClock`] driven by
//! the replay, so the same inputs give the same outputs.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{SystemTime, UNIX_EPOCH};

/// A source of "now" in nanoseconds since the Unix epoch.
pub trait Clock: Send + Sync {
    fn now_ns(&self) -> u64;
}

/// The system's real-time clock.
#[derive(Debug, Clone, Copy, Default)]
pub struct WallClock;

impl Clock for WallClock {
    fn now_ns(&self) -> u64 {
        SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map(|d| d.as_nanos() as u64)
            .unwrap_or(0)
    }
}

/// A clock that only moves when told to (replays, lock-step simulation, tests).
/// Clones share the same time.
#[derive(Debug, Clone, Default)]
pub struct ManualClock(Arc<AtomicU64>);

impl ManualClock {
    pub fn new(start_ns: u64) -> Self {
        Self(Arc::new(AtomicU64::new(start_ns)))
    }

    /// Sets the time; a replay clock never goes backwards, so earlier values are ignored.
    pub fn set_ns(&self, t_ns: u64) {
        self.0.fetch_max(t_ns, Ordering::SeqCst);
    }

    pub fn advance_ns(&self, dt_ns: u64) {
        self.0.fetch_add(dt_ns, Ordering::SeqCst);
    }
}

impl Clock for ManualClock {
    fn now_ns(&self) -> u64 {
        self.0.load(Ordering::SeqCst)
    }
}

/// Tracks whether an input is fresh enough to act on.
///
/// The servo stage stops the robot when its inputs are older than their
/// deadline; ages are measured on the injected clock, so a replay behaves as the
/// robot would.
#[derive(Debug, Clone, Copy)]
pub struct InputDeadline {
    pub max_age_ns: u64,
    last_seen_ns: Option<u64>,
}

impl InputDeadline {
    pub fn new(max_age_s: f64) -> Self {
        Self {
            max_age_ns: (max_age_s.max(0.0) * 1e9) as u64,
            last_seen_ns: None,
        }
    }

    /// Records that the input arrived at `now_ns`.
    pub fn seen(&mut self, now_ns: u64) {
        self.last_seen_ns = Some(now_ns);
    }

    /// `true` if the input never arrived or is older than the deadline.
    pub fn is_stale(&self, now_ns: u64) -> bool {
        match self.last_seen_ns {
            None => true,
            Some(t) => now_ns.saturating_sub(t) > self.max_age_ns,
        }
    }

    /// Age in seconds, `None` if never seen.
    pub fn age_s(&self, now_ns: u64) -> Option<f64> {
        self.last_seen_ns
            .map(|t| now_ns.saturating_sub(t) as f64 * 1e-9)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn manual_clock_is_shared_and_monotonic() {
        let c = ManualClock::new(10);
        let c2 = c.clone();
        c.set_ns(100);
        c.set_ns(50);
        assert_eq!(c2.now_ns(), 100);
        c2.advance_ns(5);
        assert_eq!(c.now_ns(), 105);
    }

    #[test]
    fn deadline_goes_stale_after_max_age() {
        let mut d = InputDeadline::new(0.2);
        assert!(d.is_stale(0));
        d.seen(1_000_000_000);
        assert!(!d.is_stale(1_200_000_000));
        assert!(d.is_stale(1_200_000_001));
        assert_eq!(d.age_s(1_100_000_000), Some(0.1));
    }

    #[test]
    fn wall_clock_is_after_2020() {
        assert!(WallClock.now_ns() > 1_577_836_800_000_000_000);
    }
}
