//! The transport layer: one publish / latest-value-subscribe API over iceoryx2
//! shared memory on the vehicle ([`ipc`]) and over zenoh across machines
//! ([`net`]), plus the byte format used on zenoh ([`wire`]).
//!
//! Sensor streams have latest-value semantics: a slow consumer skips to the
//! newest message and the skipped ones are counted, never queued.

pub mod any;
pub mod ipc;
pub mod net;
pub mod wire;

use crate::msg::*;

/// A message or header that carries a [`Stamp`].
pub trait Stamped {
    fn stamp(&self) -> Stamp;
}

macro_rules! stamped {
    ($($t:ty),+) => {$(
        impl Stamped for $t {
            fn stamp(&self) -> Stamp { self.stamp }
        }
    )+};
}
stamped!(
    ImageHeader,
    TensorHeader,
    AngularBins,
    PolarBinsHeader,
    CostmapHeader,
    Subgoal,
    Path,
    VelocityCommand,
    Pose,
    NavGoal,
    EStop,
    StageHealth,
    CameraInfo
);

/// Counts messages that latest-value delivery skipped, from gaps in the
/// sequence numbers of what was received.
#[derive(Debug, Default, Clone, Copy)]
pub struct SkipCounter {
    last_seq: Option<u64>,
    /// Messages that arrived in order.
    pub received: u64,
    /// Sequence numbers jumped over (the consumer was slower than the producer).
    pub skipped: u64,
    /// Times the sequence went backwards: a producer restarted or a replay looped.
    pub restarts: u64,
}

impl SkipCounter {
    pub fn observe(&mut self, seq: u64) {
        self.received += 1;
        match self.last_seq {
            Some(last) if seq > last => self.skipped += seq - last - 1,
            Some(last) if seq <= last => self.restarts += 1,
            _ => {}
        }
        self.last_seq = Some(seq);
    }
}

/// A transport-level failure, with the topic it concerns.
#[derive(Debug, thiserror::Error)]
pub enum TransportError {
    #[error("iceoryx2 {what} for topic '{topic}': {detail}")]
    Ipc {
        what: &'static str,
        topic: String,
        detail: String,
    },
    #[error("zenoh {what} for '{key}': {detail}")]
    Zenoh {
        what: &'static str,
        key: String,
        detail: String,
    },
    #[error("message on '{topic}' does not fit: {detail}")]
    TooLarge { topic: String, detail: String },
    #[error("decoding '{topic}': {source}")]
    Decode {
        topic: String,
        #[source]
        source: wire::WireError,
    },
    #[error("bad transport setting {key} = {value:?}: {expected}")]
    Setting {
        key: &'static str,
        value: String,
        expected: &'static str,
    },
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn skip_counter_counts_gaps_and_restarts() {
        let mut c = SkipCounter::default();
        for s in [1, 2, 5, 6, 1, 2] {
            c.observe(s);
        }
        assert_eq!(c.received, 6);
        assert_eq!(c.skipped, 2);
        assert_eq!(c.restarts, 1);
    }
}
