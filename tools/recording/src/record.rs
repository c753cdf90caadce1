//! The recorder: subscribes to every topic on the bus that matches the
//! patterns (topics that appear later are picked up within `rescan`), and
//! writes each message it receives. A topic with a declared queue
//! (`FARSIGHT_QUEUES`, from the graph's queued edges) is read from its
//! queue: every message, in order, as long as the recorder is no more than
//! the queue's depth behind. Other topics are latest-value, so a recorder
//! slower than a topic skips messages. Either way it counts what it missed
//! per topic from the gaps in the frame numbers instead of hiding them (not
//! on `health/*`, whose frame number is the stage's last output, not a
//! message count).
//!
//! In lock-step the recorder is part of the answer set (`--ack`): after it
//! has written the answer to frame k (the velocity command) and everything
//! published before it, it reports frame k on `health/<instance>`; a
//! simulator that waits for that report (`farsight-sim run --await-health`)
//! sends frame k+1 only then, so nothing runs ahead of the recorder and
//! latest-value delivery loses none of the frame's messages. The report
//! names the newest frame answered, never an older one: an answer-topic
//! message that answers no frame (a stop stamped frame 0) is written but
//! not reported, even when it comes just after the frame's answer. "Written"
//! there means handed to the [`RecordingWriter`], whose open chunk is in
//! memory until it is closed; the ack is about what the graph sent, not
//! about crashes.
//!
//! Chunks are closed by time and size ([`crate::write`]): every loop here
//! calls [`RecordingWriter::flush_if_due`] on each wake-up (at least every
//! 50 ms, every 10 ms over zenoh), so a recorder killed without a word
//! (SIGKILL, a panic) loses at most its open chunk, the messages of the last
//! chunk age bound (1 s by default) and one wake-up, even when nothing new
//! arrived. SIGTERM and SIGINT end the loop cleanly and the file is
//! finished with everything in it.

use crate::pattern::matches_any;
use crate::write::{ChannelStats, RecordingWriter};
use crate::RecordingError;
use farsight_interfaces::clock::{Clock, WallClock};
use farsight_interfaces::msg::{HealthState, Stamp};
use farsight_interfaces::transport::any::{wire_stamp, AnySubscriber};
use farsight_interfaces::transport::ipc::{self, Bus, LoopExit};
use farsight_interfaces::transport::net::NetBus;
use farsight_interfaces::transport::SkipCounter;
use farsight_stage::Health;
use std::collections::BTreeMap;
use std::ops::ControlFlow;
use std::time::{Duration, Instant};

/// What to record and for how long.
#[derive(Debug, Clone)]
pub struct RecordOptions {
    /// Topic glob patterns (see [`crate::pattern`]).
    pub patterns: Vec<String>,
    /// How often the bus is searched for new matching topics.
    pub rescan: Duration,
    /// Stop after this long (`None`: until SIGINT/SIGTERM).
    pub duration: Option<Duration>,
    /// Print a progress line this often (`None`: never).
    pub progress: Option<Duration>,
    /// The recorder's instance name: it reports on `health/<instance>`.
    pub instance: Option<String>,
    /// Lock-step (with `instance`): each message of this topic written (the
    /// graph's answer to a frame) is reported, with its frame number, once
    /// everything published before it is written too.
    pub ack: Option<String>,
}

impl Default for RecordOptions {
    fn default() -> Self {
        Self {
            patterns: vec!["**".into()],
            rescan: Duration::from_millis(500),
            duration: None,
            progress: Some(Duration::from_secs(5)),
            instance: None,
            ack: None,
        }
    }
}

/// Records what a robot's bridge sends over zenoh (`farsight/<robot>/**`,
/// filtered by the patterns): what a laptop sees. Messages are queued
/// (`capacity`) rather than latest-value; a full queue drops its oldest,
/// which shows up as skipped sequence numbers. Stops like [`record`].
pub fn record_zenoh(
    net: &NetBus,
    mut writer: RecordingWriter,
    opts: &RecordOptions,
    on_subscribed: impl FnOnce(),
) -> Result<BTreeMap<String, TopicReport>, RecordingError> {
    let tap = net.tap(1024)?;
    on_subscribed();
    let start = Instant::now();
    let mut skips: BTreeMap<String, SkipCounter> = BTreeMap::new();
    let mut failure: Option<RecordingError> = None;
    ipc::wait_loop(&[], Some(Duration::from_millis(10)), |_| {
        loop {
            let (topic, bytes) = match tap.try_next() {
                Ok(Some(m)) => m,
                Ok(None) => break,
                Err(e) => {
                    failure = Some(e.into());
                    return ControlFlow::Break(());
                }
            };
            if !matches_any(&opts.patterns, &topic) {
                continue;
            }
            let stamp = match wire_stamp(&topic, &bytes) {
                Ok(s) => s,
                Err(e) => {
                    tracing::warn!(topic, "not recorded: {e}");
                    continue;
                }
            };
            skips
                .entry(topic.clone())
                .or_default()
                .observe(stamp.frame_seq);
            if let Err(e) = writer.write(&topic, stamp, WallClock.now_ns(), &bytes) {
                failure = Some(e);
                return ControlFlow::Break(());
            }
        }
        // Idle or not, a chunk open for its age bound goes to the file.
        if let Err(e) = writer.flush_if_due(Instant::now()) {
            failure = Some(e);
            return ControlFlow::Break(());
        }
        if opts.duration.is_some_and(|d| start.elapsed() >= d) {
            return ControlFlow::Break(());
        }
        ControlFlow::Continue(())
    })?;
    let written = writer.finish()?;
    if let Some(e) = failure {
        return Err(e);
    }
    Ok(written
        .into_iter()
        .map(|(t, w)| {
            let skipped = frame_numbered(&t).then(|| skips.get(&t).map_or(0, |s| s.skipped));
            (
                t,
                TopicReport {
                    written: w,
                    skipped,
                },
            )
        })
        .collect())
}

/// Per topic: what was written, and what latest-value delivery skipped
/// (`None` where gaps in the frame numbers are not losses: `health/*`).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct TopicReport {
    pub written: ChannelStats,
    pub skipped: Option<u64>,
}

/// Records until the duration is up or the process is told to stop; the
/// file is finished (indexes written) either way. Plain names among the
/// patterns are subscribed before anything publishes them (an unknown name
/// is an error); globs match the topics that exist, checked every `rescan`.
pub fn record(
    bus: &Bus,
    mut writer: RecordingWriter,
    opts: &RecordOptions,
    on_subscribed: impl FnOnce(),
) -> Result<BTreeMap<String, TopicReport>, RecordingError> {
    let start = Instant::now();
    let mut subs: Vec<(String, AnySubscriber)> = Vec::new();
    let mut last_progress = Instant::now();
    let mut failure: Option<RecordingError> = None;
    // Plain topic names are subscribed at once, before their publishers
    // exist: a recorder started ahead of the graph misses nothing.
    for t in opts.patterns.iter().filter(|p| !p.contains('*')) {
        subs.push((t.clone(), subscribe(bus, t)?));
    }
    let mut health = match &opts.instance {
        Some(instance) => {
            let mut h = Health::new(bus, instance, 1.0)?;
            h.set(HealthState::OK, "recording");
            Some(h)
        }
        None => None,
    };
    let ack_topic = opts.ack.as_deref();
    // The newest frame reported as answered: a report never goes back to
    // an older frame.
    let mut acked_frame = 0u64;
    let mut on_subscribed = Some(on_subscribed);
    loop {
        for t in bus.topics()? {
            if matches_any(&opts.patterns, &t) && !subs.iter().any(|(n, _)| *n == t) {
                match subscribe(bus, &t) {
                    Ok(s) => {
                        tracing::info!(topic = t, "recording");
                        subs.push((t, s));
                    }
                    Err(e) => tracing::warn!(topic = t, "not recorded: {e}"),
                }
            }
        }
        if let Some(f) = on_subscribed.take() {
            f();
        }
        let listeners: Vec<&ipc::InputListener> = subs.iter().map(|(_, s)| s.listener()).collect();
        let scan_at = Instant::now() + opts.rescan;
        let mut done = false;
        let exit = ipc::wait_loop(&listeners, Some(Duration::from_millis(50)), |_| {
            let (answered, taken) = match take_all(&subs, &mut writer, ack_topic) {
                Ok(a) => a,
                Err(e) => {
                    failure = Some(e);
                    return ControlFlow::Break(());
                }
            };
            if let Some(h) = &mut health {
                (0..taken).for_each(|_| h.input());
            }
            if let (Some(first), Some(h)) = (answered, &mut health) {
                // What was published before the answer may have come in
                // after its topic's turn in this pass: one more pass takes
                // it before the answer is reported. That pass may take a
                // newer answer (the frame's, after a stop that answers no
                // frame), which needs a pass after it in turn. In lock-step
                // at most one newer answer can come (the next frame waits
                // for this report); the cap keeps a recorder given `--ack`
                // on a graph that is not lock-step from passing forever.
                const MAX_CATCH_UP_PASSES: usize = 8;
                let mut answer = first;
                for _ in 0..MAX_CATCH_UP_PASSES {
                    match take_all(&subs, &mut writer, ack_topic) {
                        Ok((late, taken)) => {
                            (0..taken).for_each(|_| h.input());
                            match late {
                                Some(l) if l.frame_seq > answer.frame_seq => answer = l,
                                _ => break,
                            }
                        }
                        Err(e) => {
                            failure = Some(e);
                            return ControlFlow::Break(());
                        }
                    }
                }
                if answer.frame_seq > acked_frame {
                    acked_frame = answer.frame_seq;
                    h.output(answer, WallClock.now_ns());
                    h.publish_now(WallClock.now_ns());
                }
            }
            if let Some(h) = &mut health {
                h.tick(WallClock.now_ns());
            }
            // Idle or not, a chunk open for its age bound goes to the file:
            // this runs on every input and at least every tick (50 ms).
            if let Err(e) = writer.flush_if_due(Instant::now()) {
                failure = Some(e);
                return ControlFlow::Break(());
            }
            if opts.progress.is_some_and(|p| last_progress.elapsed() >= p) {
                last_progress = Instant::now();
                let (n, b) = writer
                    .stats()
                    .values()
                    .fold((0, 0), |(n, b), s| (n + s.messages, b + s.bytes));
                eprintln!(
                    "recording {:.0} s: {} topics, {n} messages, {:.1} MB",
                    start.elapsed().as_secs_f64(),
                    writer.stats().len(),
                    b as f64 / 1e6
                );
            }
            if opts.duration.is_some_and(|d| start.elapsed() >= d) {
                done = true;
                return ControlFlow::Break(());
            }
            if Instant::now() >= scan_at {
                return ControlFlow::Break(());
            }
            ControlFlow::Continue(())
        })?;
        if failure.is_some() || done || exit == LoopExit::Terminated {
            break;
        }
    }
    if let Some(h) = &mut health {
        h.stopping(WallClock.now_ns());
    }
    let skipped: BTreeMap<String, u64> = subs
        .iter()
        .filter(|(t, _)| frame_numbered(t))
        .map(|(t, s)| (t.clone(), s.skips().skipped))
        .collect();
    let written = writer.finish()?;
    if let Some(e) = failure {
        return Err(e);
    }
    let mut report: BTreeMap<String, TopicReport> = BTreeMap::new();
    for (t, s) in skipped {
        report.entry(t).or_default().skipped = Some(s);
    }
    for (t, w) in written {
        report.entry(t).or_default().written = w;
    }
    Ok(report)
}

/// Takes what each subscription holds (a queue's every message, else the
/// newest) and writes it; returns the answer written on `answer_topic`
/// with the highest frame number ([`newest_answer`]), and how many
/// messages were written.
fn take_all(
    subs: &[(String, AnySubscriber)],
    writer: &mut RecordingWriter,
    answer_topic: Option<&str>,
) -> Result<(Option<Stamp>, u64), RecordingError> {
    let (mut answered, mut taken) = (None, 0);
    for (topic, s) in subs {
        match s.take_all_wire() {
            Ok(messages) => {
                for (stamp, bytes) in messages {
                    writer.write(topic, stamp, WallClock.now_ns(), &bytes)?;
                    taken += 1;
                    if Some(topic.as_str()) == answer_topic {
                        answered = newest_answer(answered, Some(stamp));
                    }
                }
            }
            Err(e) => tracing::warn!(topic, "dropped: {e}"),
        }
    }
    Ok((answered, taken))
}

/// Of two answers, the one to the later frame. The answer topic also
/// carries messages that answer no frame (the servo's stop while its input
/// is starved is stamped frame 0), and one can arrive just after the
/// frame's answer: the newest message is not always the newest answer, and
/// acknowledging it would leave the frame unacknowledged for good.
fn newest_answer(a: Option<Stamp>, b: Option<Stamp>) -> Option<Stamp> {
    match (a, b) {
        (Some(a), Some(b)) => Some(if b.frame_seq >= a.frame_seq { b } else { a }),
        (a, b) => a.or(b),
    }
}

/// A topic's queue where the bus declares one (every message, in order),
/// else its latest value.
fn subscribe(bus: &Bus, topic: &str) -> Result<AnySubscriber, RecordingError> {
    Ok(match bus.queue_depth(topic) {
        Some(_) => AnySubscriber::open_queued(bus, topic)?,
        None => AnySubscriber::open(bus, topic)?,
    })
}

/// Whether a gap in `topic`'s frame numbers is a lost message: not on
/// `health/*`, whose frame number is the stage's last output.
pub fn frame_numbered(topic: &str) -> bool {
    !topic.starts_with("health/")
}
