//! Per-topic rate limits on capture time, so what a live view sends fits
//! its link and a recording's Foxglove copy stays small.
//!
//! Rates are judged on the messages' capture times, not the wall clock: a
//! replay at ten times real speed is thinned to the same messages as the
//! original run, and a test gets the same answer on a busy machine.

use farsight_interfaces::pattern::matches;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;

/// At most `hz` messages per second of capture time on the Foxglove topics
/// matching `topic` (a glob: `*` one segment, `**` any; `/camera/*/image`).
/// `hz = 0` turns the topics off.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Rate {
    pub topic: String,
    pub hz: f64,
}

impl Rate {
    pub fn new(topic: &str, hz: f64) -> Self {
        Self {
            topic: topic.into(),
            hz,
        }
    }

    /// Parses `TOPIC=HZ` (the command line's `--rate`).
    pub fn parse(s: &str) -> Result<Self, String> {
        let (topic, hz) = s
            .split_once('=')
            .ok_or_else(|| format!("rate {s:?}: expected TOPIC=HZ, e.g. /camera/*/image=5"))?;
        let hz: f64 = hz
            .parse()
            .map_err(|_| format!("rate {s:?}: {hz:?} is not a number of messages per second"))?;
        let r = Self::new(topic, hz);
        r.validate().map_err(|e| format!("rate {s:?}: {e}"))?;
        Ok(r)
    }

    pub fn validate(&self) -> Result<(), String> {
        if !self.hz.is_finite() || self.hz < 0.0 {
            return Err(format!(
                "rate for {:?}: hz = {} must be a finite number >= 0",
                self.topic, self.hz
            ));
        }
        if !self.topic.starts_with('/') {
            return Err(format!(
                "rate for {:?}: Foxglove topics start with '/' (e.g. /camera/*/image)",
                self.topic
            ));
        }
        Ok(())
    }
}

/// Decides, per topic, whether a message at a capture time goes out.
#[derive(Debug, Clone, Default)]
pub struct Throttle {
    rates: Vec<Rate>,
    next_due_ns: HashMap<String, u64>,
}

impl Throttle {
    /// The first rule whose pattern matches a topic sets its rate; a topic
    /// no rule matches is not limited.
    pub fn new(rates: Vec<Rate>) -> Self {
        Self {
            rates,
            next_due_ns: HashMap::new(),
        }
    }

    /// The rate for `topic` (`None`: every message).
    pub fn hz(&self, topic: &str) -> Option<f64> {
        self.rates
            .iter()
            .find(|r| matches(&r.topic, topic))
            .map(|r| r.hz)
    }

    /// Whether a message of `topic` captured at `t_ns` goes out; if so, the
    /// topic's next slot is booked. Slots advance by whole intervals, so a
    /// 30 Hz camera thinned to 10 Hz sends every third frame rather than
    /// drifting; a message up to a tenth of an interval early counts (the
    /// jitter of a camera's clock). Time going backwards (a replay started
    /// again) or a long gap restarts the schedule.
    pub fn admit(&mut self, topic: &str, t_ns: u64) -> bool {
        let hz = match self.hz(topic) {
            None => return true,
            Some(hz) if hz <= 0.0 => return false,
            Some(hz) => hz,
        };
        let interval = (1e9 / hz) as u64;
        let next = self.next_due_ns.entry(topic.to_string()).or_insert(0);
        let restart =
            *next == 0 || t_ns + 2 * interval < *next || t_ns >= next.saturating_add(interval);
        if restart {
            *next = t_ns.saturating_add(interval);
            return true;
        }
        if t_ns + interval / 10 >= *next {
            *next = next.saturating_add(interval);
            return true;
        }
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    #[test]
    fn a_30_hz_stream_limited_to_10_hz_keeps_every_third_message() {
        let mut t = Throttle::new(vec![Rate::new("/camera/*/image", 10.0)]);
        let kept: Vec<u64> = (0..30u64)
            .map(|i| 1_000 * MS + i * 33_333_333)
            .filter(|&ns| t.admit("/camera/front/image", ns))
            .collect();
        assert_eq!(kept.len(), 10, "{kept:?}");
        for w in kept.windows(2) {
            assert!((w[1] - w[0]).abs_diff(100 * MS) < 2 * MS, "{kept:?}");
        }
    }

    #[test]
    fn the_first_matching_rule_wins_and_unmatched_topics_pass() {
        let mut t = Throttle::new(vec![
            Rate::new("/camera/rear/image", 0.0),
            Rate::new("/camera/*/image", 1.0),
        ]);
        assert!(!t.admit("/camera/rear/image", 5 * MS), "0 Hz is off");
        assert!(t.admit("/camera/front/image", 5 * MS));
        assert!(!t.admit("/camera/front/image", 500 * MS));
        assert!(t.admit("/camera/front/image", 1_005 * MS));
        assert!(t.admit("/state/pose", 5 * MS) && t.admit("/state/pose", 6 * MS));
    }

    #[test]
    fn a_replay_started_again_is_not_starved() {
        let mut t = Throttle::new(vec![Rate::new("/**", 1.0)]);
        assert!(t.admit("/a", 100_000 * MS));
        assert!(!t.admit("/a", 100_500 * MS));
        assert!(t.admit("/a", 1_000 * MS), "time went back: restart");
        assert!(t.admit("/a", 900_000 * MS), "a long gap: restart");
    }

    #[test]
    fn rates_parse_from_the_command_line_and_bad_ones_are_named() {
        assert_eq!(
            Rate::parse("/costmap/*=0.5").unwrap(),
            Rate::new("/costmap/*", 0.5)
        );
        for bad in ["/a", "/a=fast", "/a=-1", "/a=inf", "a=1"] {
            let e = Rate::parse(bad).unwrap_err();
            assert!(e.contains(bad), "{e}");
        }
    }
}
