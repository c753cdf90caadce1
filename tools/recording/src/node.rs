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
//! # ack = "cmd/velocity"          # lock-step: report each answer written
//! ```

use farsight_interfaces::topics;
use farsight_interfaces::transport::ipc::MAX_QUEUE_DEPTH;
use farsight_stage::{ConfigError, DeclaresTopics, Io, Range, Ranges, Validate};
use serde::Deserialize;
use std::path::{Path, PathBuf};

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
}

impl Validate for RecorderConfig {
    fn ranges(&self, r: &mut Ranges) {
        r.key(
            "queue_depth",
            self.queue_depth,
            Range::between(1.0, MAX_QUEUE_DEPTH as f64),
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
        ] {
            let e = farsight_stage::parse_config::<RecorderConfig>(text, "test")
                .unwrap_err()
                .to_string();
            assert!(e.contains(key), "{text}: {e}");
        }
    }
}
