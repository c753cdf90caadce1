//! Writing recordings: one channel per topic, each message flushed as it is
//! written (a killed recorder loses nothing it had finished writing).
//!
//! Beside farsight's own lossless channels, a recording holds what the live
//! Foxglove server shows (`farsight_foxglove::View`): the same topic names
//! (`/camera/front/image`, `/tf`, ...), the same official protobuf schemas,
//! images as downscaled JPEG, transforms and calibration, every message
//! logged on its capture time, so the shipped layout opens a recording as
//! it opens the live robot. Recordings keep every message (no throttling).

use crate::{RecordingError, MESSAGE_ENCODING};
use farsight_foxglove::{View, ViewConfig};
use farsight_interfaces::message::Message;
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
    /// The Foxglove copy, when asked for.
    view: Option<View>,
    foxglove_channels: HashMap<String, u16>,
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
    /// Creates `path` (replacing it). `foxglove` adds the Foxglove channels
    /// (see the module docs). Messages are
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
        let view = foxglove
            .then(|| {
                View::new(ViewConfig {
                    rate: Vec::new(),
                    ..ViewConfig::default()
                })
            })
            .transpose()
            .map_err(|why| RecordingError::Topic {
                topic: "foxglove".into(),
                why,
            })?;
        Ok(Self {
            out,
            path: p,
            channels: HashMap::new(),
            view,
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

    /// Writes the Foxglove messages the view makes of one farsight message.
    fn write_foxglove(
        &mut self,
        topic: &str,
        kind: TopicKind,
        wire_bytes: &[u8],
    ) -> Result<(), RecordingError> {
        let Some(view) = self.view.as_mut() else {
            return Ok(());
        };
        let msg = match Message::from_wire(kind, wire_bytes) {
            Ok(m) => m,
            Err(e) => {
                // farsight's own channel keeps the bytes; only the copy is lost.
                tracing::warn!(topic, "no Foxglove copy: {e}");
                return Ok(());
            }
        };
        for out in view.on_message(topic, &msg) {
            let id = match self.foxglove_channels.get(&out.topic) {
                Some(&id) => id,
                None => {
                    let (schema, encoding) = out.message.schema();
                    let path = self.path.clone();
                    let err = |error| RecordingError::Mcap { path, error };
                    let s = self
                        .out
                        .add_schema(&schema.name, &schema.encoding, &schema.data)
                        .map_err(err.clone())?;
                    let id = self
                        .out
                        .add_channel(s, &out.topic, &encoding, &BTreeMap::new())
                        .map_err(err)?;
                    self.foxglove_channels.insert(out.topic.clone(), id);
                    id
                }
            };
            let header = mcap::records::MessageHeader {
                channel_id: id,
                sequence: 0,
                log_time: out.log_time_ns,
                publish_time: out.log_time_ns,
            };
            self.out
                .write_to_known_channel(&header, &out.message.encode())
                .map_err(self.mcap_err())?;
        }
        Ok(())
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
        if let Some(kind) = kind_of(topic) {
            self.write_foxglove(topic, kind, wire_bytes)?;
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::read::Recording;
    use farsight_interfaces::msg::Pose;
    use farsight_interfaces::transport::wire;

    #[test]
    fn foxglove_channels_are_the_live_servers_on_capture_time_and_can_be_left_out() {
        let dir = std::env::temp_dir().join(format!("farsight-write-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let pose = Pose {
            stamp: Stamp::new(7, 2_000_000_000),
            position_m: [1.0, 2.0, 0.0],
            ..Default::default()
        };
        let bytes = wire::encode_message(&pose).unwrap();
        for foxglove in [true, false] {
            let path = dir.join(format!("fox-{foxglove}.mcap"));
            let mut w = RecordingWriter::create(&path, foxglove).unwrap();
            // Received late on the wall clock: Foxglove's copy keeps capture time.
            w.write("state/pose", pose.stamp, 9_000_000_000, &bytes)
                .unwrap();
            w.finish().unwrap();
            let info = Recording::open(&path).unwrap().info().unwrap();
            let topic = |t: &str| info.topics.iter().find(|i| i.topic == t);
            assert_eq!(topic("state/pose").unwrap().count, 1, "{info}");
            if foxglove {
                for t in ["/state/pose", "/tf"] {
                    let i = topic(t).unwrap_or_else(|| panic!("{t}: {info}"));
                    assert_eq!(
                        (i.encoding.as_str(), i.first_log_ns),
                        ("protobuf", 2_000_000_000),
                        "{info}"
                    );
                }
            } else {
                assert_eq!(info.topics.len(), 1, "{info}");
            }
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
}
