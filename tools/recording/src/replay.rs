//! Replaying a recording into the graph: at the recorded pace (or a factor
//! of it), as fast as possible, or lock-step, where the next frame goes out
//! only when the graph has answered the last one. Topics can be selected
//! by pattern and renamed. Stages configured with `clock = "stamps"` run
//! on the recording's capture times, so a lock-step replay gives the same
//! outputs on any machine.
//!
//! Nothing is dropped silently: with an answer topic named, every frame of
//! the driving topic the graph never answered (it skipped it, or answered
//! too late in lock-step) is listed in the report.

use crate::pattern::matches_any;
use crate::read::{RecordedMessage, Recording};
use crate::{RecordingError, MESSAGE_ENCODING};
use farsight_interfaces::topics::kind_of;
use farsight_interfaces::transport::any::{AnyPublisher, AnySubscriber};
use farsight_interfaces::transport::ipc::Bus;
use std::collections::{BTreeMap, BTreeSet};
use std::time::{Duration, Instant};

/// How fast messages go out.
#[derive(Debug, Clone, PartialEq)]
pub enum Pace {
    /// The recorded receive times, sped up by the factor (1 = recorded speed).
    Recorded { factor: f64 },
    /// Back to back.
    AsFast,
    /// After each message of the driving topic, wait (up to `timeout`) for
    /// the answer topic to carry that frame's sequence number.
    Lockstep { timeout: Duration },
}

/// What to replay and how.
#[derive(Debug, Clone)]
pub struct ReplayOptions {
    /// Topic patterns to replay (recorded names, before remapping).
    pub topics: Vec<String>,
    /// `(recorded name, name to publish as)`; both must be the same kind.
    pub remap: Vec<(String, String)>,
    pub pace: Pace,
    /// The topic whose frames the graph answers (e.g. `camera/front/image`),
    /// as published (after remapping).
    pub driving_topic: Option<String>,
    /// The graph's answer (e.g. `cmd/velocity`): its stamp carries the
    /// sequence number of the frame it was computed from.
    pub answer_topic: Option<String>,
    /// How long to keep listening for answers after the last message.
    pub drain: Duration,
}

impl Default for ReplayOptions {
    fn default() -> Self {
        Self {
            topics: vec!["**".into()],
            remap: Vec::new(),
            pace: Pace::Recorded { factor: 1.0 },
            driving_topic: None,
            answer_topic: None,
            drain: Duration::from_millis(500),
        }
    }
}

/// What a replay did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ReplayReport {
    /// Messages published per topic (as published).
    pub published: BTreeMap<String, u64>,
    /// Frames of the driving topic the graph never answered.
    pub unanswered: Vec<u64>,
    /// Frames of the driving topic published.
    pub driving_frames: u64,
    pub wall_s: f64,
    /// Where reading stopped early (a truncated recording).
    pub truncated: Option<String>,
}

impl std::fmt::Display for ReplayReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let total: u64 = self.published.values().sum();
        writeln!(
            f,
            "replayed {total} messages on {} topics in {:.2} s",
            self.published.len(),
            self.wall_s
        )?;
        for (t, n) in &self.published {
            writeln!(f, "  {t:<34} {n:>8}")?;
        }
        if self.driving_frames > 0 {
            writeln!(
                f,
                "frames answered: {} of {}{}",
                self.driving_frames - self.unanswered.len() as u64,
                self.driving_frames,
                if self.unanswered.is_empty() {
                    String::new()
                } else {
                    format!("; not consumed: {:?}", self.unanswered)
                }
            )?;
        }
        if let Some(t) = &self.truncated {
            writeln!(f, "recording truncated: {t}")?;
        }
        Ok(())
    }
}

fn published_name(opts: &ReplayOptions, recorded: &str) -> String {
    opts.remap
        .iter()
        .find(|(from, _)| from == recorded)
        .map_or_else(|| recorded.to_string(), |(_, to)| to.clone())
}

/// Replays `rec` into `bus`.
pub fn replay(
    bus: &Bus,
    rec: &Recording,
    opts: &ReplayOptions,
) -> Result<ReplayReport, RecordingError> {
    for (from, to) in &opts.remap {
        if kind_of(from).is_none() || kind_of(from) != kind_of(to) {
            return Err(RecordingError::Topic {
                topic: format!("{from}={to}"),
                why: "a remap needs two farsight topics of the same kind".into(),
            });
        }
    }
    let (messages, truncated) = rec.messages()?;
    let selected: Vec<&RecordedMessage> = messages
        .iter()
        .filter(|m| &*m.encoding == MESSAGE_ENCODING && matches_any(&opts.topics, &m.topic))
        .collect();
    // Slice publishers allocate once: size each for its topic's largest message.
    let mut largest: BTreeMap<&str, usize> = BTreeMap::new();
    for m in &selected {
        let e = largest.entry(&m.topic).or_default();
        *e = (*e).max(m.data.len());
    }
    let mut publishers: BTreeMap<&str, (String, AnyPublisher)> = BTreeMap::new();
    for (&t, &bytes) in &largest {
        let name = published_name(opts, t);
        let p = AnyPublisher::open(bus, &name, bytes)?;
        publishers.insert(t, (name, p));
    }
    let answers = opts
        .answer_topic
        .as_deref()
        .map(|t| AnySubscriber::open(bus, t))
        .transpose()?;
    let mut answered: BTreeSet<u64> = BTreeSet::new();
    let take_answers = |answered: &mut BTreeSet<u64>| -> Result<(), RecordingError> {
        if let Some(a) = &answers {
            while let Some((stamp, _)) = a.take_wire()? {
                answered.insert(stamp.frame_seq);
            }
        }
        Ok(())
    };
    let mut report = ReplayReport {
        truncated,
        ..Default::default()
    };
    let mut driving: Vec<u64> = Vec::new();
    let start = Instant::now();
    let first_log = selected.first().map_or(0, |m| m.log_time_ns);
    for m in &selected {
        if let Pace::Recorded { factor } = opts.pace {
            let due = Duration::from_secs_f64(
                m.log_time_ns.saturating_sub(first_log) as f64 * 1e-9 / factor.max(1e-6),
            );
            std::thread::sleep(due.saturating_sub(start.elapsed()));
        }
        let (name, p) = publishers.get_mut(&*m.topic).expect("opened above");
        let stamp = p.publish_wire(&m.data)?;
        *report.published.entry(name.clone()).or_default() += 1;
        take_answers(&mut answered)?;
        if opts.driving_topic.as_deref() == Some(name.as_str()) {
            driving.push(stamp.frame_seq);
            if let Pace::Lockstep { timeout } = opts.pace {
                let end = Instant::now() + timeout;
                while !answered.contains(&stamp.frame_seq) && Instant::now() < end {
                    std::thread::sleep(Duration::from_micros(200));
                    take_answers(&mut answered)?;
                }
            }
        }
    }
    let end = Instant::now() + opts.drain;
    while Instant::now() < end {
        take_answers(&mut answered)?;
        std::thread::sleep(Duration::from_millis(1));
    }
    report.driving_frames = driving.len() as u64;
    if answers.is_some() {
        report.unanswered = driving
            .into_iter()
            .filter(|k| !answered.contains(k))
            .collect();
    }
    report.wall_s = start.elapsed().as_secs_f64();
    Ok(report)
}
