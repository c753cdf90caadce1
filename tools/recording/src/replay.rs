//! Replaying a recording into the graph: at the recorded pace (or a factor
//! of it), as fast as possible, or lock-step, where the next frame goes out
//! only when the graph has answered the last one. Topics can be selected
//! by pattern and renamed. Stages configured with `clock = "stamps"` run
//! on the recording's capture times, so a lock-step replay gives the same
//! outputs on any machine.
//!
//! Nothing is dropped silently: with answer topics named, every frame of
//! the driving topic that some answer topic never carried (a stage skipped
//! it, or answered too late in lock-step) is listed in the report. An
//! answer topic with a declared queue (`FARSIGHT_QUEUES`) is read from it,
//! so the replay itself misses no answer however late it gets to look; a
//! latest-value answer topic read by a descheduled replay can hide an
//! answer under the next one, and is listed as not consumed. The
//! answers can be written to a recording as they are taken: in lock-step
//! each stage answers a frame before the next goes out, so that recording
//! holds every output of every frame (the golden tests compare it).
//!
//! Messages go out in capture-time order, the driving topic's message last
//! among those of one capture time: a frame's pose and camera model are
//! there before the frame that triggers the graph, whatever order the
//! recorder happened to write them in.

use crate::pattern::matches_any;
use crate::read::{RecordedMessage, Recording, Truncation};
use crate::write::RecordingWriter;
use crate::{RecordingError, MESSAGE_ENCODING};
use farsight_interfaces::clock::{Clock, WallClock};
use farsight_interfaces::topics::kind_of;
use farsight_interfaces::transport::any::{AnyPublisher, AnySubscriber};
use farsight_interfaces::transport::ipc::Bus;
use std::cmp::Reverse;
use std::collections::{BTreeMap, BTreeSet, BinaryHeap};
use std::time::{Duration, Instant};

/// How fast messages go out.
#[derive(Debug, Clone, PartialEq)]
pub enum Pace {
    /// The recorded capture times (the recording's clock: wall time on a
    /// robot, simulated time from the simulator), sped up by the factor
    /// (1 = recorded speed), from the driving topic's first frame on;
    /// anything stamped earlier (a goal stamped 0) goes at once.
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
    /// The graph's answers (e.g. `cmd/velocity`): their stamps carry the
    /// sequence number of the frame they were computed from. Lock-step
    /// waits for all of them.
    pub answer_topics: Vec<String>,
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
            answer_topics: Vec::new(),
            drain: Duration::from_millis(500),
        }
    }
}

/// What a replay did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ReplayReport {
    /// Messages published per topic (as published).
    pub published: BTreeMap<String, u64>,
    /// Frames of the driving topic some answer topic never carried.
    pub unanswered: Vec<u64>,
    /// Answers taken per answer topic.
    pub answers: BTreeMap<String, u64>,
    /// Frames of the driving topic published.
    pub driving_frames: u64,
    pub wall_s: f64,
    /// Where reading stopped early (a truncated recording: everything
    /// before the cut was replayed).
    pub truncated: Option<Truncation>,
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
        for (t, n) in &self.answers {
            writeln!(f, "  answers on {t:<24} {n:>8}")?;
        }
        if let Some(t) = &self.truncated {
            writeln!(f, "{t}")?;
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

/// How far (capture time) a message may be recorded out of order and still
/// go out in order.
const REORDER_WINDOW_NS: u64 = 1_000_000_000;

/// A message waiting in the reorder window, ordered by capture time, the
/// driving topic last among equal times, then file order.
#[derive(Debug, PartialEq, Eq, PartialOrd, Ord)]
struct Pending {
    capture_time_ns: u64,
    driving: bool,
    index: u64,
    topic: String,
    data: Vec<u8>,
}

/// An answer topic's subscriber and the frames it has carried.
struct Answers {
    topics: Vec<(String, AnySubscriber, BTreeSet<u64>, u64)>,
}

impl Answers {
    /// Takes whatever each answer topic has now, into `out` when given.
    fn take(&mut self, out: &mut Option<&mut RecordingWriter>) -> Result<(), RecordingError> {
        for (topic, sub, seen, count) in &mut self.topics {
            // A queue subscriber hands over every answer since the last
            // look, a latest-value one at most the newest.
            for (stamp, bytes) in sub.take_all_wire()? {
                seen.insert(stamp.frame_seq);
                *count += 1;
                if let Some(w) = out.as_deref_mut() {
                    w.write(topic, stamp, WallClock.now_ns(), &bytes)?;
                }
            }
        }
        // The replay looks for answers every few milliseconds however
        // quiet the graph is: a chunk open for its age bound goes out.
        if let Some(w) = out.as_deref_mut() {
            w.flush_if_due(Instant::now())?;
        }
        Ok(())
    }

    fn all_carry(&self, k: u64) -> bool {
        self.topics.iter().all(|(_, _, seen, _)| seen.contains(&k))
    }
}

/// Replays `rec` into `bus`; the answers taken go into `answers_out` when given.
pub fn replay(
    bus: &Bus,
    rec: &Recording,
    opts: &ReplayOptions,
    mut answers_out: Option<&mut RecordingWriter>,
) -> Result<ReplayReport, RecordingError> {
    for (from, to) in &opts.remap {
        if kind_of(from).is_none() || kind_of(from) != kind_of(to) {
            return Err(RecordingError::Topic {
                topic: format!("{from}={to}"),
                why: "a remap needs two farsight topics of the same kind".into(),
            });
        }
    }
    let selected = |m: &RecordedMessage| {
        &*m.encoding == MESSAGE_ENCODING && matches_any(&opts.topics, &m.topic)
    };
    let is_driving =
        |topic: &str| opts.driving_topic.as_deref() == Some(published_name(opts, topic).as_str());
    // A first pass over the file keeps nothing but sizes and the start of
    // the clock: a recording of rendered frames can decompress to a hundred
    // times its size, so the messages are streamed, never all held. It also
    // checks the whole file: a damaged one is refused before anything goes
    // out.
    let mut largest: BTreeMap<String, usize> = BTreeMap::new();
    let (mut first_driving, mut first_stamped) = (None, None);
    let cut = rec.for_each(|m| {
        if selected(&m) {
            let e = largest.entry(m.topic.to_string()).or_default();
            *e = (*e).max(m.data.len());
            if is_driving(&m.topic) {
                first_driving.get_or_insert(m.capture_time_ns);
            }
            if m.capture_time_ns > 0 {
                first_stamped.get_or_insert(m.capture_time_ns);
            }
        }
        Ok(())
    })?;
    if let Some(t) = cut {
        tracing::warn!("{t}; replaying those");
    }
    // The clock starts at the driving topic's first frame (else the first
    // stamped message): a goal stamped 0 must not count as the start of a
    // recording made on the wall clock.
    let first_capture = first_driving.or(first_stamped).unwrap_or(0);
    // Slice publishers allocate once: size each for its topic's largest message.
    let mut publishers: BTreeMap<String, (String, AnyPublisher)> = BTreeMap::new();
    for (t, &bytes) in &largest {
        let name = published_name(opts, t);
        let p = AnyPublisher::open(bus, &name, bytes)?;
        publishers.insert(t.clone(), (name, p));
    }
    let mut answers = Answers {
        topics: opts
            .answer_topics
            .iter()
            .map(|t| {
                let sub = match bus.queue_depth(t) {
                    Some(_) => AnySubscriber::open_queued(bus, t)?,
                    None => AnySubscriber::open(bus, t)?,
                };
                Ok((t.clone(), sub, BTreeSet::new(), 0))
            })
            .collect::<Result<Vec<_>, RecordingError>>()?,
    };
    // The graph's subscribers find new publishers when they next look;
    // give them a moment before the first message, which some (the goal)
    // only ever get once.
    std::thread::sleep(Duration::from_millis(200));
    let mut report = ReplayReport::default();
    let mut driving: Vec<u64> = Vec::new();
    let start = Instant::now();
    let mut emit = |m: &Pending| -> Result<(), RecordingError> {
        if let Pace::Recorded { factor } = opts.pace {
            let due = Duration::from_secs_f64(
                m.capture_time_ns.saturating_sub(first_capture) as f64 * 1e-9 / factor.max(1e-6),
            );
            // Answers keep arriving while we wait: take each one as it comes.
            while start.elapsed() < due {
                answers.take(&mut answers_out)?;
                std::thread::sleep(
                    due.saturating_sub(start.elapsed())
                        .min(Duration::from_micros(500)),
                );
            }
        }
        if m.driving {
            // Stages that connected after a fixed-size message went out
            // (the goal is sent once) get it before the frame that needs it.
            for (_, p) in publishers.values() {
                p.deliver_history()?;
            }
        }
        let (name, p) = publishers.get_mut(&m.topic).expect("opened above");
        let stamp = p.publish_wire(&m.data)?;
        *report.published.entry(name.clone()).or_default() += 1;
        answers.take(&mut answers_out)?;
        if m.driving {
            driving.push(stamp.frame_seq);
            if let Pace::Lockstep { timeout } = opts.pace {
                let end = Instant::now() + timeout;
                while !answers.all_carry(stamp.frame_seq) && Instant::now() < end {
                    std::thread::sleep(Duration::from_micros(200));
                    answers.take(&mut answers_out)?;
                }
            }
        }
        Ok(())
    };
    // Messages go out in capture-time order, the driving topic's last among
    // equal times, through a reorder window of REORDER_WINDOW_NS of capture
    // time (the recorder writes what arrives together in its own order).
    let mut window: BinaryHeap<Reverse<Pending>> = BinaryHeap::new();
    let mut newest = 0u64;
    let mut index = 0u64;
    let truncated = rec.for_each(|m| {
        if !selected(&m) {
            return Ok(());
        }
        newest = newest.max(m.capture_time_ns);
        index += 1;
        window.push(Reverse(Pending {
            capture_time_ns: m.capture_time_ns,
            driving: is_driving(&m.topic),
            index,
            topic: m.topic.to_string(),
            data: m.data.into_owned(),
        }));
        while window
            .peek()
            .is_some_and(|Reverse(p)| p.capture_time_ns + REORDER_WINDOW_NS <= newest)
        {
            let Reverse(p) = window.pop().expect("peeked");
            emit(&p)?;
        }
        Ok(())
    })?;
    while let Some(Reverse(p)) = window.pop() {
        emit(&p)?;
    }
    report.truncated = truncated;
    let end = Instant::now() + opts.drain;
    while Instant::now() < end {
        answers.take(&mut answers_out)?;
        std::thread::sleep(Duration::from_millis(1));
    }
    report.driving_frames = driving.len() as u64;
    if !answers.topics.is_empty() {
        report.unanswered = driving
            .into_iter()
            .filter(|&k| !answers.all_carry(k))
            .collect();
    }
    report.answers = answers
        .topics
        .iter()
        .map(|(t, _, _, n)| (t.clone(), *n))
        .collect();
    report.wall_s = start.elapsed().as_secs_f64();
    Ok(report)
}
