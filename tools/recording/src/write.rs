//! Writing recordings: one channel per topic, each message flushed as it is
//! written (a killed recorder loses nothing it had finished writing).

use crate::{foxglove, RecordingError, MESSAGE_ENCODING};
use farsight_interfaces::msg::Stamp;
use farsight_interfaces::topics::{kind_of, TopicKind};
use std::collections::{BTreeMap, HashMap};
use std::io::BufWriter;
use std::path::Path;

/// How much one topic's channel has taken.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ChannelStats {
    pub messages: u64,
    pub bytes: u64,
}

/// An MCAP file being written.
pub struct RecordingWriter {
    out: mcap::Writer<BufWriter<std::fs::File>>,
    path: String,
    channels: HashMap<String, u16>,
    foxglove: bool,
    foxglove_channels: HashMap<String, Option<u16>>,
    stats: BTreeMap<String, ChannelStats>,
}

/// The schema record of a farsight topic kind: its name and a description of
/// the bytes (the wire format is not self-describing).
pub fn schema_of(kind: TopicKind) -> (String, String) {
    (
        format!("farsight.{kind:?}"),
        format!(
            "farsight wire bytes of a {kind:?} message: \"FS\\x01M\" + postcard for fixed-size \
             messages, \"FS\\x01S\" + header length + postcard header + raw elements for \
             header+slice messages (farsight_interfaces::transport::wire)"
        ),
    )
}

impl RecordingWriter {
    /// Creates `path` (replacing it). `foxglove` adds Foxglove-viewable
    /// channels for the topics that have a well-known schema. Messages are
    /// zstd-compressed (level 1: rendered frames shrink about 70x, camera
    /// frames less; see `farsight bench recorder`).
    pub fn create(path: &Path, foxglove: bool) -> Result<Self, RecordingError> {
        Self::create_with(path, foxglove, true)
    }

    /// [`Self::create`], with compression on or off.
    pub fn create_with(path: &Path, foxglove: bool, zstd: bool) -> Result<Self, RecordingError> {
        let p = path.display().to_string();
        let file = std::fs::File::create(path).map_err(|error| RecordingError::Io {
            path: p.clone(),
            error,
        })?;
        let out = mcap::WriteOptions::new()
            .profile("farsight")
            .library(concat!("farsight-recording ", env!("CARGO_PKG_VERSION")))
            .compression(zstd.then_some(mcap::Compression::Zstd))
            .compression_level(1)
            .create(BufWriter::new(file))
            .map_err(|error| RecordingError::Mcap {
                path: p.clone(),
                error,
            })?;
        Ok(Self {
            out,
            path: p,
            channels: HashMap::new(),
            foxglove,
            foxglove_channels: HashMap::new(),
            stats: BTreeMap::new(),
        })
    }

    fn mcap_err(&self) -> impl FnOnce(mcap::McapError) -> RecordingError + '_ {
        move |error| RecordingError::Mcap {
            path: self.path.clone(),
            error,
        }
    }

    fn channel(&mut self, topic: &str) -> Result<u16, RecordingError> {
        if let Some(&id) = self.channels.get(topic) {
            return Ok(id);
        }
        let kind = kind_of(topic).ok_or_else(|| RecordingError::Topic {
            topic: topic.into(),
            why: "not a farsight topic".into(),
        })?;
        let (name, text) = schema_of(kind);
        let path = self.path.clone();
        let err = |error| RecordingError::Mcap { path, error };
        let schema = self
            .out
            .add_schema(&name, MESSAGE_ENCODING, text.as_bytes())
            .map_err(err.clone())?;
        let meta = BTreeMap::from([("kind".to_string(), format!("{kind:?}"))]);
        let id = self
            .out
            .add_channel(schema, topic, MESSAGE_ENCODING, &meta)
            .map_err(err)?;
        self.channels.insert(topic.to_string(), id);
        Ok(id)
    }

    fn foxglove_channel(&mut self, topic: &str, schema: &str) -> Result<u16, RecordingError> {
        if let Some(Some(id)) = self.foxglove_channels.get(topic) {
            return Ok(*id);
        }
        let path = self.path.clone();
        let err = |error| RecordingError::Mcap { path, error };
        let s = self
            .out
            .add_schema(
                schema,
                "jsonschema",
                foxglove::json_schema(schema).as_bytes(),
            )
            .map_err(err.clone())?;
        let id = self
            .out
            .add_channel(s, &format!("/foxglove/{topic}"), "json", &BTreeMap::new())
            .map_err(err)?;
        self.foxglove_channels.insert(topic.to_string(), Some(id));
        Ok(id)
    }

    /// Appends one message of `topic`: its wire bytes, the capture time from
    /// its stamp (publish time) and when it was received (log time), then
    /// flushes it to the file.
    pub fn write(
        &mut self,
        topic: &str,
        stamp: Stamp,
        received_ns: u64,
        wire_bytes: &[u8],
    ) -> Result<(), RecordingError> {
        let id = self.channel(topic)?;
        let header = mcap::records::MessageHeader {
            channel_id: id,
            sequence: stamp.frame_seq as u32,
            log_time: received_ns,
            publish_time: stamp.capture_time_ns,
        };
        self.out
            .write_to_known_channel(&header, wire_bytes)
            .map_err(self.mcap_err())?;
        if self.foxglove {
            if let Some((schema, json)) = foxglove::to_json(topic, wire_bytes)? {
                let id = self.foxglove_channel(topic, schema)?;
                let header = mcap::records::MessageHeader {
                    channel_id: id,
                    ..header
                };
                self.out
                    .write_to_known_channel(&header, &json)
                    .map_err(self.mcap_err())?;
            }
        }
        self.out.flush().map_err(self.mcap_err())?;
        let s = self.stats.entry(topic.to_string()).or_default();
        s.messages += 1;
        s.bytes += wire_bytes.len() as u64;
        Ok(())
    }

    /// Messages and bytes written per topic so far.
    pub fn stats(&self) -> &BTreeMap<String, ChannelStats> {
        &self.stats
    }

    /// Writes the summary (indexes, statistics) and closes the file.
    pub fn finish(mut self) -> Result<BTreeMap<String, ChannelStats>, RecordingError> {
        self.out.finish().map_err(self.mcap_err())?;
        Ok(self.stats)
    }
}
