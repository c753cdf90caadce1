//! Reading recordings: messages in file order, and a summary of what a file
//! holds. Reading is verified ([`crate::mcap_file`]): a file that is not an
//! MCAP file or is damaged is an error naming the file and the offset. A
//! file whose writer was killed ends mid-record; reading stops after the
//! last complete chunk and says where the file was cut ([`Truncation`]).

pub use crate::mcap_file::Truncation;
use crate::mcap_file::{McapFile, ReadEnd};
use crate::{RecordingError, MESSAGE_ENCODING};
use std::collections::BTreeMap;
use std::ops::ControlFlow;
use std::path::Path;
use std::sync::Arc;

/// One message of a recording.
#[derive(Debug, Clone)]
pub struct RecordedMessage<'a> {
    pub topic: Arc<str>,
    /// `farsight-wire` for farsight's channels, `json` for Foxglove's.
    pub encoding: Arc<str>,
    /// When the recorder received it (ns).
    pub log_time_ns: u64,
    /// Capture time of the frame it came from (ns).
    pub capture_time_ns: u64,
    pub sequence: u32,
    pub data: std::borrow::Cow<'a, [u8]>,
}

/// A memory-mapped recording whose MCAP magic has been checked.
pub struct Recording {
    file: McapFile,
}

/// Per topic: how many messages, over what time, how many bytes.
#[derive(Debug, Clone, PartialEq)]
pub struct TopicInfo {
    pub topic: String,
    pub encoding: String,
    pub count: u64,
    pub bytes: u64,
    pub first_log_ns: u64,
    pub last_log_ns: u64,
    pub first_seq: u32,
    pub last_seq: u32,
    /// Capture times of the first and last message (the recording's clock).
    pub first_capture_ns: u64,
    pub last_capture_ns: u64,
}

impl TopicInfo {
    /// Messages per second between the first and the last.
    pub fn rate_hz(&self) -> f64 {
        let span = self.last_log_ns.saturating_sub(self.first_log_ns) as f64 * 1e-9;
        if self.count < 2 || span <= 0.0 {
            0.0
        } else {
            (self.count - 1) as f64 / span
        }
    }
}

/// What a recording holds.
#[derive(Debug, Clone, PartialEq)]
pub struct Info {
    pub path: String,
    pub topics: Vec<TopicInfo>,
    pub duration_s: f64,
    /// Where and why reading stopped early (a recorder killed mid-write).
    pub truncated: Option<Truncation>,
}

impl std::fmt::Display for Info {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let total: u64 = self.topics.iter().map(|t| t.count).sum();
        writeln!(
            f,
            "{}: {} topics, {total} messages, {:.2} s",
            self.path,
            self.topics.len(),
            self.duration_s
        )?;
        writeln!(
            f,
            "{:<34} {:>8} {:>9} {:>11} {:>14} {:>10}",
            "topic", "messages", "rate Hz", "MB", "seq", "capture s"
        )?;
        for t in &self.topics {
            writeln!(
                f,
                "{:<34} {:>8} {:>9.2} {:>11.3} {:>6}..{:<6} {:>10.2}{}",
                t.topic,
                t.count,
                t.rate_hz(),
                t.bytes as f64 / 1e6,
                t.first_seq,
                t.last_seq,
                t.last_capture_ns.saturating_sub(t.first_capture_ns) as f64 * 1e-9,
                if t.encoding == MESSAGE_ENCODING {
                    ""
                } else {
                    " (foxglove)"
                }
            )?;
        }
        if let Some(t) = &self.truncated {
            writeln!(f, "{t}")?;
        }
        Ok(())
    }
}

impl Recording {
    /// Opens `path`: an empty file, or one that does not start with the
    /// MCAP magic, is refused here.
    pub fn open(path: &Path) -> Result<Self, RecordingError> {
        Ok(Self {
            file: McapFile::open(path)?,
        })
    }

    pub fn path(&self) -> &str {
        self.file.path()
    }

    /// Calls `f` on every message in file order (Foxglove's channels too:
    /// check `encoding`). A damaged file is an error (after the messages of
    /// the chunks before the damage: check it before acting on any, as
    /// replay does); a truncated one returns where it was cut, after every
    /// message of its complete chunks.
    pub fn for_each(
        &self,
        mut f: impl FnMut(RecordedMessage<'_>) -> Result<(), RecordingError>,
    ) -> Result<Option<Truncation>, RecordingError> {
        let mut names: BTreeMap<u16, (Arc<str>, Arc<str>)> = BTreeMap::new();
        let mut failed = None;
        let end = self.file.read(|m| {
            let (topic, encoding) = names
                .entry(m.channel.id)
                .or_insert_with(|| {
                    (
                        Arc::from(m.channel.topic.as_str()),
                        Arc::from(m.channel.message_encoding.as_str()),
                    )
                })
                .clone();
            match f(RecordedMessage {
                topic,
                encoding,
                log_time_ns: m.log_time,
                capture_time_ns: m.publish_time,
                sequence: m.sequence,
                data: std::borrow::Cow::Borrowed(m.data),
            }) {
                Ok(()) => ControlFlow::Continue(()),
                Err(e) => {
                    failed = Some(e);
                    ControlFlow::Break(())
                }
            }
        })?;
        if let Some(e) = failed {
            return Err(e);
        }
        Ok(match end {
            ReadEnd::Truncated(t) => Some(t),
            ReadEnd::Complete | ReadEnd::Stopped => None,
        })
    }

    /// Reads and checks the whole file; where it was cut, if it was.
    pub fn verify(&self) -> Result<Option<Truncation>, RecordingError> {
        self.for_each(|_| Ok(()))
    }

    /// Every farsight message, in file order, copied out.
    pub fn messages(
        &self,
    ) -> Result<(Vec<RecordedMessage<'static>>, Option<Truncation>), RecordingError> {
        let mut out = Vec::new();
        let cut = self.for_each(|m| {
            if &*m.encoding == MESSAGE_ENCODING {
                out.push(RecordedMessage {
                    data: std::borrow::Cow::Owned(m.data.into_owned()),
                    ..m
                });
            }
            Ok(())
        })?;
        Ok((out, cut))
    }

    /// The summary `farsight record --info` prints.
    pub fn info(&self) -> Result<Info, RecordingError> {
        let mut topics: BTreeMap<Arc<str>, TopicInfo> = BTreeMap::new();
        let (mut first, mut last) = (u64::MAX, 0u64);
        let truncated = self.for_each(|m| {
            first = first.min(m.log_time_ns);
            last = last.max(m.log_time_ns);
            let t = topics.entry(m.topic.clone()).or_insert_with(|| TopicInfo {
                topic: m.topic.to_string(),
                encoding: m.encoding.to_string(),
                count: 0,
                bytes: 0,
                first_log_ns: m.log_time_ns,
                last_log_ns: m.log_time_ns,
                first_seq: m.sequence,
                last_seq: m.sequence,
                first_capture_ns: m.capture_time_ns,
                last_capture_ns: m.capture_time_ns,
            });
            t.last_capture_ns = m.capture_time_ns;
            t.count += 1;
            t.bytes += m.data.len() as u64;
            t.last_log_ns = m.log_time_ns;
            t.last_seq = m.sequence;
            Ok(())
        })?;
        Ok(Info {
            path: self.path().to_string(),
            topics: topics.into_values().collect(),
            duration_s: if last >= first {
                (last - first) as f64 * 1e-9
            } else {
                0.0
            },
            truncated,
        })
    }
}
