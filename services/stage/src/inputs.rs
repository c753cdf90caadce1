//! Staleness on capture time: which inputs a stage needs, how old they are,
//! and the stamp its outputs carry (the design notes' safety
//! contract: every message carries the capture time of the oldest source
//! behind it).
//!
//! Each stage declares its inputs as *required* or *optional*, in groups:
//! a group is as fresh as its freshest member, so several cameras in one
//! group mean a dead camera degrades the stage and only all of them dead
//! stops it. The stamp of an output is the *minimum*, over required groups,
//! of the newest capture time consumed; a stage that republishes (a map on a
//! timer, a replan) keeps that stamp, so data never looks younger than the
//! oldest thing it was made from. The servo at the end of the graph then
//! judges one number, now minus its input's stamp, whichever stage upstream
//! died or froze.
//!
//! Ages are measured on the stage's clock: the wall clock on a robot, the
//! newest capture time consumed on the stamps' clock (replays, lock-step
//! simulation), where an input is stale relative to the others.

use farsight_interfaces::msg::Stamp;

/// Whether a group's staleness stops the stage or degrades it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Need {
    /// Stale or never seen: the stage's outputs are not fit to act on.
    Required,
    /// Stale: the stage goes on without it (FITAM without its far field).
    Optional,
}

/// One declared input, returned by [`StageInputs::add`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct InputId(usize);

#[derive(Debug, Clone)]
struct Input {
    name: String,
    group: usize,
    newest: Option<Stamp>,
}

#[derive(Debug, Clone)]
struct Group {
    name: String,
    need: Need,
}

/// What a stage may do with its inputs now.
#[derive(Debug, Clone, PartialEq)]
pub enum Freshness {
    /// Every input is within the deadline.
    Fresh,
    /// Some optional input (or a member of a group) is stale; the reason
    /// names it and its age.
    Degraded(String),
    /// A required group is stale or was never seen: nothing the stage makes
    /// now is fit to act on. The reason names it and its age.
    Stale(String),
}

impl Freshness {
    pub fn is_stale(&self) -> bool {
        matches!(self, Self::Stale(_))
    }

    /// The reason, empty when fresh.
    pub fn reason(&self) -> &str {
        match self {
            Self::Fresh => "",
            Self::Degraded(r) | Self::Stale(r) => r,
        }
    }
}

/// A stage's inputs with the newest capture time consumed from each.
#[derive(Debug, Clone)]
pub struct StageInputs {
    max_age_ns: u64,
    max_age_s: f64,
    inputs: Vec<Input>,
    groups: Vec<Group>,
}

/// The range of a stage's `input_deadline_s` config key.
pub const INPUT_DEADLINE_S: crate::Range = crate::Range::above_to(0.0, 60.0).unit("s");

/// The default `input_deadline_s` of the stages before the servo: an
/// input older than this degrades (optional) or stops (required) the stage.
pub const DEFAULT_INPUT_DEADLINE_S: f64 = 1.0;

impl StageInputs {
    /// Inputs older than `max_age_s` (on the stage's clock) are stale.
    pub fn new(max_age_s: f64) -> Self {
        Self {
            max_age_ns: (max_age_s.max(0.0) * 1e9) as u64,
            max_age_s,
            inputs: Vec::new(),
            groups: Vec::new(),
        }
    }

    /// Declares an input that is a group of its own (e.g. `state/pose`).
    pub fn add(&mut self, name: &str, need: Need) -> InputId {
        self.add_to(name, name, need)
    }

    /// Declares an input as a member of `group` (created with `need` on its
    /// first member; later members share the first one's need).
    pub fn add_to(&mut self, group: &str, name: &str, need: Need) -> InputId {
        let g = match self.groups.iter().position(|g| g.name == group) {
            Some(g) => g,
            None => {
                self.groups.push(Group {
                    name: group.to_string(),
                    need,
                });
                self.groups.len() - 1
            }
        };
        self.inputs.push(Input {
            name: name.to_string(),
            group: g,
            newest: None,
        });
        InputId(self.inputs.len() - 1)
    }

    /// Changes a group's need (pose is required once there is a goal).
    pub fn set_need(&mut self, id: InputId, need: Need) {
        let g = self.inputs[id.0].group;
        self.groups[g].need = need;
    }

    /// Records the newest message taken from input `id`. Its stamp replaces
    /// the last one even when older: a topic delivers its newest message, so
    /// time going back means its source restarted (a replay played again, a
    /// clock stepped back), and judging by the older time errs to stale.
    pub fn consumed(&mut self, id: InputId, stamp: Stamp) {
        self.inputs[id.0].newest = Some(stamp);
    }

    /// The stamp of the newest message consumed from `id`.
    pub fn newest(&self, id: InputId) -> Option<Stamp> {
        self.inputs[id.0].newest
    }

    /// The newest capture time consumed from any input: "now" on the stamps'
    /// clock.
    pub fn newest_capture_ns(&self) -> Option<u64> {
        self.inputs
            .iter()
            .filter_map(|i| i.newest)
            .map(|s| s.capture_time_ns)
            .max()
    }

    /// The stage's "now": the wall clock, or on the stamps' clock the newest
    /// capture time consumed (0 before any).
    pub fn now_ns(&self, clock: crate::ClockSource) -> u64 {
        use farsight_interfaces::clock::{Clock, WallClock};
        self.now_at(clock, WallClock.now_ns())
    }

    /// The stage's "now" given the runner's wall time (a step's
    /// [`crate::Step::wall_ns`]: the system clock in a process, the
    /// simulated clock in the in-process executor).
    pub fn now_at(&self, clock: crate::ClockSource, wall_ns: u64) -> u64 {
        match clock {
            crate::ClockSource::Wall => wall_ns,
            crate::ClockSource::Stamps => self.newest_capture_ns().unwrap_or(0),
        }
    }

    /// `true` if `id` was consumed and is at most the deadline old at `now_ns`.
    pub fn is_fresh(&self, id: InputId, now_ns: u64) -> bool {
        self.inputs[id.0]
            .newest
            .is_some_and(|s| self.within_deadline(age_ns(s, now_ns)))
    }

    /// An age (ns, negative for a capture time ahead of `now`) within the
    /// deadline either way: a stamp from the future (a clock out of step)
    /// would otherwise stay "fresh" until now caught up with it.
    fn within_deadline(&self, age_ns: i128) -> bool {
        age_ns.unsigned_abs() <= u128::from(self.max_age_ns)
    }

    /// The freshest message of each group, in declaration order.
    fn group_newest(&self) -> impl Iterator<Item = (&Group, Option<Stamp>)> {
        self.groups.iter().enumerate().map(|(g, group)| {
            let newest = self
                .inputs
                .iter()
                .filter(|i| i.group == g)
                .filter_map(|i| i.newest)
                .max_by_key(|s| s.capture_time_ns);
            (group, newest)
        })
    }

    /// The stamp outputs carry: the capture time is the oldest, over
    /// required groups, of each group's newest message; the frame number is
    /// the first declared group's (the primary input, the frame an output
    /// answers: what a lock-step player waits for). `None` while a required
    /// group has never been seen; with no required group, the newest of any
    /// input.
    pub fn output_stamp(&self) -> Option<Stamp> {
        let mut out: Option<Stamp> = None;
        let mut any_required = false;
        for (group, newest) in self.group_newest() {
            if group.need != Need::Required {
                continue;
            }
            any_required = true;
            let newest = newest?;
            out = Some(match out {
                None => newest,
                Some(o) => Stamp::new(o.frame_seq, o.capture_time_ns.min(newest.capture_time_ns)),
            });
        }
        if any_required {
            out
        } else {
            self.inputs
                .iter()
                .filter_map(|i| i.newest)
                .max_by_key(|s| s.capture_time_ns)
        }
    }

    /// Judges every input at `now_ns`: stale required groups first, then
    /// stale optional groups and stale members of fresh groups.
    pub fn check(&self, now_ns: u64) -> Freshness {
        let age = |s: Option<Stamp>| s.map(|s| age_ns(s, now_ns));
        let stale = |a: Option<i128>| a.is_none_or(|a| !self.within_deadline(a));
        let describe = |name: &str, a: Option<i128>| match a {
            None => format!("no {name} yet"),
            Some(a) if a < 0 => format!(
                "{name} is stamped {:.2} s in the future (deadline {} s): clocks out of step?",
                -a as f64 * 1e-9,
                self.max_age_s
            ),
            Some(a) => format!(
                "{name} is {:.2} s old (deadline {} s)",
                a as f64 * 1e-9,
                self.max_age_s
            ),
        };
        let mut stale_required = Vec::new();
        let mut degraded = Vec::new();
        for (g, (group, newest)) in self.group_newest().enumerate() {
            let a = age(newest);
            if stale(a) {
                match group.need {
                    Need::Required => stale_required.push(describe(&group.name, a)),
                    Need::Optional => degraded.push(describe(&group.name, a)),
                }
                continue;
            }
            for i in self.inputs.iter().filter(|i| i.group == g) {
                let a = age(i.newest);
                if stale(a) {
                    degraded.push(describe(&i.name, a));
                }
            }
        }
        if !stale_required.is_empty() {
            Freshness::Stale(stale_required.join("; "))
        } else if !degraded.is_empty() {
            Freshness::Degraded(degraded.join("; "))
        } else {
            Freshness::Fresh
        }
    }
}

/// `now_ns` minus the capture time, negative for a stamp from the future.
fn age_ns(stamp: Stamp, now_ns: u64) -> i128 {
    i128::from(now_ns) - i128::from(stamp.capture_time_ns)
}

#[cfg(test)]
mod tests {
    use super::*;

    const S: u64 = 1_000_000_000;

    fn at(seq: u64, t_s: f64) -> Stamp {
        Stamp::new(seq, (t_s * 1e9) as u64)
    }

    #[test]
    fn the_output_stamp_is_the_oldest_required_input_and_republishing_keeps_it() {
        let mut inputs = StageInputs::new(2.0);
        let map = inputs.add("costmap/fused", Need::Required);
        let pose = inputs.add("state/pose", Need::Required);
        let image = inputs.add("camera/front/image", Need::Optional);
        assert_eq!(inputs.output_stamp(), None, "nothing consumed yet");
        inputs.consumed(map, at(7, 10.0));
        assert_eq!(inputs.output_stamp(), None, "pose is required and unseen");
        inputs.consumed(pose, at(90, 9.8));
        inputs.consumed(image, at(8, 10.9));
        // The frame number is the primary (first declared) input's, the
        // capture time the oldest required input's; optional ones count not.
        assert_eq!(inputs.output_stamp(), Some(at(7, 9.8)));
        inputs.consumed(pose, at(91, 10.4));
        assert_eq!(inputs.output_stamp(), Some(at(7, 10.0)));
        // The map's producer dies; poses go on: the output stamp stays the map's.
        for k in 0..30 {
            inputs.consumed(pose, at(92 + k, 10.5 + k as f64 * 0.1));
        }
        assert_eq!(inputs.output_stamp(), Some(at(7, 10.0)));
        assert_eq!(inputs.newest_capture_ns(), Some(13_400_000_000));
        // A replay played again: its first frame is the newest message.
        inputs.consumed(map, at(1, 0.5));
        inputs.consumed(pose, at(1, 0.5));
        assert_eq!(inputs.output_stamp(), Some(at(1, 0.5)));
        inputs.consumed(image, at(1, 0.5));
        assert_eq!(inputs.newest_capture_ns(), Some(500_000_000));
    }

    #[test]
    fn a_stale_required_input_stops_and_a_stale_optional_one_degrades() {
        let mut inputs = StageInputs::new(2.0);
        let pose = inputs.add("state/pose", Need::Required);
        let far = inputs.add("bins/polar", Need::Optional);
        assert_eq!(
            inputs.check(0),
            Freshness::Stale("no state/pose yet".into())
        );
        inputs.consumed(pose, at(1, 100.0));
        inputs.consumed(far, at(1, 100.0));
        assert_eq!(inputs.check(102 * S), Freshness::Fresh);
        assert!(inputs.is_fresh(far, 102 * S));
        inputs.consumed(pose, at(2, 102.5));
        let d = inputs.check(102 * S + 600_000_000);
        assert_eq!(
            d,
            Freshness::Degraded("bins/polar is 2.60 s old (deadline 2 s)".into())
        );
        assert!(!inputs.is_fresh(far, 102 * S + 600_000_000));
        let s = inputs.check(105 * S);
        assert!(s.is_stale(), "{s:?}");
        assert_eq!(
            s.reason(),
            "state/pose is 2.50 s old (deadline 2 s)",
            "only the required input's age stops the stage"
        );
    }

    #[test]
    fn a_stamp_from_the_future_beyond_the_deadline_is_stale_not_fresh_forever() {
        let mut inputs = StageInputs::new(1.0);
        let path = inputs.add("nav/path/planned", Need::Required);
        // Within the deadline ahead (small clock offsets between machines): fine.
        inputs.consumed(path, at(1, 10.5));
        assert!(inputs.is_fresh(path, 10 * S));
        assert_eq!(inputs.check(10 * S), Freshness::Fresh);
        // A minute ahead: stale, and the reason says why.
        inputs.consumed(path, at(2, 70.0));
        assert!(!inputs.is_fresh(path, 10 * S));
        let s = inputs.check(10 * S);
        assert!(s.is_stale(), "{s:?}");
        assert!(
            s.reason()
                .starts_with("nav/path/planned is stamped 60.00 s in the future"),
            "{s:?}"
        );
    }

    #[test]
    fn a_group_is_as_fresh_as_its_freshest_member() {
        let mut inputs = StageInputs::new(1.0);
        let front = inputs.add_to("cameras", "front", Need::Required);
        let rear = inputs.add_to("cameras", "rear", Need::Required);
        inputs.consumed(front, at(1, 10.0));
        inputs.consumed(rear, at(1, 10.0));
        assert_eq!(inputs.check(10 * S), Freshness::Fresh);
        // The rear camera dies; the front one goes on: degraded, not stopped,
        // and the output stamp follows the live camera.
        inputs.consumed(front, at(30, 13.0));
        assert_eq!(
            inputs.check(13 * S),
            Freshness::Degraded("rear is 3.00 s old (deadline 1 s)".into())
        );
        assert_eq!(inputs.output_stamp(), Some(at(30, 13.0)));
        // Both dead: stopped.
        assert!(inputs.check(15 * S).is_stale());
    }

    #[test]
    fn need_can_change_and_without_required_inputs_the_newest_stamps_outputs() {
        let mut inputs = StageInputs::new(1.0);
        let subgoal = inputs.add("nav/subgoal", Need::Required);
        let pose = inputs.add("state/pose", Need::Optional);
        inputs.consumed(subgoal, at(4, 5.0));
        assert_eq!(
            inputs.check(5 * S),
            Freshness::Degraded("no state/pose yet".into())
        );
        inputs.set_need(pose, Need::Required);
        assert!(inputs.check(5 * S).is_stale());
        assert_eq!(inputs.output_stamp(), None);

        let mut loose = StageInputs::new(1.0);
        let a = loose.add("a", Need::Optional);
        let b = loose.add("b", Need::Optional);
        loose.consumed(a, at(1, 1.0));
        loose.consumed(b, at(2, 2.0));
        assert_eq!(loose.output_stamp(), Some(at(2, 2.0)));
    }
}
