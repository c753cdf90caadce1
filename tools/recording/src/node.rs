//! The recorder as a graph node (stage kind `recorder`, binary
//! `farsight-recorder`): its config names the topics it records, and each
//! is an edge of the graph read from the topic's queue
//! ([`farsight_stage::Io::read_queued`]), so `farsight run` declares a queue
//! of `queue_depth` messages for every publisher of those topics on the
//! recorder's machine and the recorder loses nothing while it is at most
//! that far behind. It reports on `health/<instance>`: messages in, and
//! with `ack` the frame number of each answer written (a lock-step
//! simulator's `--await-health`).
//!
//! What a crash loses: messages go into chunks closed when they have been
//! open `chunk_max_s` (on the recorder's wall clock) or hold
//! `chunk_max_bytes` of messages, whichever comes first, also while no
//! message arrives ([`crate::write`]). A recorder killed without a word
//! (SIGKILL, a panic, the OOM killer) loses at most its open chunk: less
//! than `chunk_max_bytes`, written in the last `chunk_max_s` and one
//! wake-up (50 ms). SIGTERM and SIGINT (`farsight run` stopping the graph)
//! finish the file and lose nothing. `chunk_max_s = 0` or
//! `chunk_max_bytes = 0` closes a chunk after every message (the demo's
//! farsight channels take 44% more disk so; `farsight bench recorder`).
//!
//! ```toml
//! [[node]]
//! name = "recorder"
//! stage = "recorder"
//! [node.config]
//! out = "recording.mcap"          # relative: to farsight run's --out folder
//! topics = ["camera/front/image", "state/pose", "cmd/velocity"]
//! queue_depth = 16                # messages of each topic it may fall behind
//! compression = true              # zstd chunks
//! foxglove = true                 # the live Foxglove server's channels too
//! chunk_max_s = 1.0               # a chunk is closed after this long (0..=60 s)
//! chunk_max_bytes = 1048576       # or once its messages reach this size (0..=64 MiB)
//! # ack = "cmd/velocity"          # lock-step: report each answer written
//! ```

use crate::write::{ChunkBounds, WriterOptions};
use farsight_interfaces::topics;
use farsight_interfaces::transport::ipc::MAX_QUEUE_DEPTH;
use farsight_stage::{ConfigError, DeclaresTopics, Io, Range, Ranges, Validate};
use serde::Deserialize;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// The folder a relative `out` resolves against: `farsight run` sets it to
/// its `--out` folder (the nodes' logs); elsewhere the working folder.
pub const RUN_OUT_ENV: &str = "FARSIGHT_RUN_OUT";

/// The recorder node's config; every key has the default shown in the
/// module docs.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RecorderConfig {
    /// The MCAP file written.
    pub out: PathBuf,
    /// Topics recorded, by name (each one an edge of the graph).
    pub topics: Vec<String>,
    /// How many messages of each topic the recorder may fall behind before
    /// it loses one.
    pub queue_depth: usize,
    /// zstd-compressed chunks (less disk, more CPU).
    pub compression: bool,
    /// Also write the live Foxglove server's channels (JPEG images, /tf,
    /// calibration, grids, paths), so the file opens in the Foxglove app.
    pub foxglove: bool,
    /// The longest a chunk stays open, in seconds: at most what a crash
    /// loses (with one wake-up). 0: every message its own chunk.
    pub chunk_max_s: f64,
    /// The uncompressed size, in bytes, at which a chunk is closed.
    /// 0: every message its own chunk.
    pub chunk_max_bytes: u64,
    /// Lock-step: the topic whose every message written is reported on
    /// `health/<instance>` (the graph's answer to a frame).
    pub ack: Option<String>,
}

impl Default for RecorderConfig {
    fn default() -> Self {
        Self {
            out: "recording.mcap".into(),
            topics: Vec::new(),
            queue_depth: 16,
            compression: true,
            foxglove: true,
            chunk_max_s: ChunkBounds::DEFAULT_MAX_AGE.as_secs_f64(),
            chunk_max_bytes: ChunkBounds::DEFAULT_MAX_BYTES,
            ack: None,
        }
    }
}

impl RecorderConfig {
    /// Where the recording goes: `out`, a relative one under
    /// [`RUN_OUT_ENV`]'s folder.
    pub fn out_path(&self) -> PathBuf {
        match std::env::var_os(RUN_OUT_ENV) {
            Some(dir) if self.out.is_relative() => Path::new(&dir).join(&self.out),
            _ => self.out.clone(),
        }
    }

    /// How the recording is written: Foxglove channels, compression and
    /// chunk bounds as configured.
    pub fn writer_options(&self) -> WriterOptions {
        WriterOptions {
            foxglove: self.foxglove,
            zstd: self.compression,
            chunks: ChunkBounds {
                // Validated to 0..=60 s; anything else (unvalidated) is
                // the most careful bound, not a panic.
                max_age: Duration::try_from_secs_f64(self.chunk_max_s).unwrap_or(Duration::ZERO),
                max_bytes: self.chunk_max_bytes,
            },
        }
    }
}

/// The largest `chunk_max_s`: a minute of messages at risk is already
/// more than a recorder should hold.
pub const CHUNK_MAX_S_LIMIT: f64 = 60.0;
/// The largest `chunk_max_bytes`: readers decompress a chunk whole.
pub const CHUNK_MAX_BYTES_LIMIT: u64 = 64 << 20;

impl Validate for RecorderConfig {
    fn ranges(&self, r: &mut Ranges) {
        r.key(
            "queue_depth",
            self.queue_depth,
            Range::between(1.0, MAX_QUEUE_DEPTH as f64),
        );
        r.key(
            "chunk_max_s",
            self.chunk_max_s,
            Range::between(0.0, CHUNK_MAX_S_LIMIT).unit("s"),
        );
        r.key(
            "chunk_max_bytes",
            self.chunk_max_bytes,
            Range::between(0.0, CHUNK_MAX_BYTES_LIMIT as f64).unit("bytes"),
        );
    }

    fn check_rules(&self) -> Result<(), ConfigError> {
        if self.topics.is_empty() {
            return Err(ConfigError::invalid(
                "topics",
                "[]",
                "the topics to record, by name",
            ));
        }
        for t in self.topics.iter().chain(&self.ack) {
            if topics::kind_of(t).is_none() {
                return Err(ConfigError::invalid(
                    "topics",
                    t,
                    "farsight topic names (globs are for `farsight record`)",
                ));
            }
        }
        if let Some(a) = &self.ack {
            if !self.topics.contains(a) {
                return Err(ConfigError::invalid("ack", a, "one of `topics`"));
            }
        }
        Ok(())
    }
}

impl DeclaresTopics for RecorderConfig {
    fn topics(&self, instance: &str, _config_dir: &Path) -> Result<Io, String> {
        let mut io = Io::for_instance(instance);
        for t in &self.topics {
            io.read_queued(t.clone(), self.queue_depth);
        }
        Ok(io)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_topic_is_a_queued_edge_and_bad_values_are_named() {
        let c: RecorderConfig = farsight_stage::parse_config(
            "topics = [\"state/pose\", \"cmd/velocity\"]\nqueue_depth = 4\nack = \"cmd/velocity\"\n",
            "test",
        )
        .unwrap();
        let io = c.topics("rec", Path::new(".")).unwrap();
        assert_eq!(io.writes, vec!["health/rec"]);
        assert_eq!(
            io.reads
                .iter()
                .map(|r| (r.topic.as_str(), r.queue_depth))
                .collect::<Vec<_>>(),
            vec![("state/pose", Some(4)), ("cmd/velocity", Some(4))]
        );
        for (text, key) in [
            ("topics = []\n", "topics"),
            ("topics = [\"camera/**\"]\n", "topics"),
            (
                "topics = [\"state/pose\"]\nqueue_depth = 0\n",
                "queue_depth",
            ),
            (
                "topics = [\"state/pose\"]\nqueue_depth = 5000\n",
                "queue_depth",
            ),
            ("topics = [\"state/pose\"]\nack = \"cmd/velocity\"\n", "ack"),
            (
                "topics = [\"state/pose\"]\nchunk_max_s = -0.5\n",
                "chunk_max_s",
            ),
            (
                "topics = [\"state/pose\"]\nchunk_max_s = 61.0\n",
                "chunk_max_s",
            ),
            (
                "topics = [\"state/pose\"]\nchunk_max_s = nan\n",
                "chunk_max_s",
            ),
            (
                "topics = [\"state/pose\"]\nchunk_max_bytes = 67108865\n",
                "chunk_max_bytes",
            ),
            (
                "topics = [\"state/pose\"]\nchunk_max_bytes = -1\n",
                "chunk_max_bytes",
            ),
        ] {
            let e = farsight_stage::parse_config::<RecorderConfig>(text, "test")
                .unwrap_err()
                .to_string();
            assert!(e.contains(key), "{text}: {e}");
        }
    }

    #[test]
    fn chunk_bounds_default_to_one_second_and_one_mib_and_are_configurable() {
        let c: RecorderConfig =
            farsight_stage::parse_config("topics = [\"state/pose\"]\n", "test").unwrap();
        let o = c.writer_options();
        assert_eq!(o.chunks, ChunkBounds::default());
        assert_eq!(
            (o.chunks.max_age, o.chunks.max_bytes),
            (Duration::from_secs(1), 1 << 20)
        );
        assert!(o.foxglove && o.zstd);
        let c: RecorderConfig = farsight_stage::parse_config(
            "topics = [\"state/pose\"]\nchunk_max_s = 0.25\nchunk_max_bytes = 4096\ncompression = false\n",
            "test",
        )
        .unwrap();
        let o = c.writer_options();
        assert_eq!(
            (o.chunks.max_age, o.chunks.max_bytes, o.zstd),
            (Duration::from_millis(250), 4096, false)
        );
        // 0 is allowed: every message its own chunk.
        let c: RecorderConfig = farsight_stage::parse_config(
            "topics = [\"state/pose\"]\nchunk_max_s = 0.0\nchunk_max_bytes = 0\n",
            "test",
        )
        .unwrap();
        assert_eq!(c.writer_options().chunks, ChunkBounds::EVERY_MESSAGE);
    }
}
