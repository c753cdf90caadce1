//! Writing recordings: one channel per topic, messages gathered into chunks
//! bounded by time and size.
//!
//! # What a crash loses
//!
//! Messages go into the file's open chunk. The writer closes it (writes it
//! whole, its header and CRC in place, and hands the file's bytes to the
//! OS) when it has been open for [`ChunkBounds::max_age`] (1 s by default,
//! on the writer's wall clock: what a crash loses is what is still in
//! memory, however fast the capture clock runs) or when its messages reach
//! [`ChunkBounds::max_bytes`] (1 MiB uncompressed by default), whichever
//! comes first. A chunk that has grown old is closed by the next write or by
//! [`RecordingWriter::flush_if_due`], which the recorder loops call on every
//! wake-up, so an idle recorder closes it too (`farsight record` and the
//! recorder node wake at least every 50 ms, zenoh recording every 10 ms).
//!
//! **The promise:** a recorder that dies without finishing its file
//! (SIGKILL, a panic, the OOM killer) loses at most its open chunk: less
//! than `max_bytes` of messages, all written in the last `max_age` plus one
//! wake-up. Everything older is in closed chunks, and the file reads and
//! replays up to the last of them ([`crate::mcap_file`] reports it
//! truncated there). A clean stop (SIGTERM, SIGINT, a `--duration-s` that
//! ran out) finishes the file and loses nothing. A closed chunk is in the
//! OS's page cache, which outlives the recorder; a power loss or a kernel
//! crash also loses what the OS had not yet written to the disk (Linux
//! writes dirty pages back within `vm.dirty_expire_centisecs`, 30 s by
//! default): the writer does not fsync, which would stall it for as long
//! as the disk takes to write the chunk.
//!
//! [`ChunkBounds::EVERY_MESSAGE`] closes a chunk after every message (how
//! recordings were written before): a crash loses only a message being
//! written, for larger files and more CPU (`farsight bench recorder`).
//!
//! # Foxglove channels
//!
//! Beside farsight's own lossless channels, a recording holds what the live
//! Foxglove server shows (`farsight_foxglove::View`): the same topic names
//! (`/camera/front/image`, `/tf`, ...), the same official protobuf schemas,
//! images as downscaled JPEG, transforms and calibration, every message
//! logged on its capture time, so the shipped layout opens a recording as
//! it opens the live robot. Recordings keep every message (no throttling).
//! A message that has no Foxglove copy (its bytes do not decode, or the
//! view refuses it: a NaN pose, a camera model that does not validate)
//! keeps its farsight channel; it is counted per topic
//! ([`ChannelStats::foxglove_dropped`]) and logged on the first and every
//! hundredth.

use crate::{RecordingError, MESSAGE_ENCODING};
use farsight_foxglove::{View, ViewConfig};
use farsight_interfaces::message::Message;
use farsight_interfaces::msg::Stamp;
use farsight_interfaces::topics::{kind_of, TopicKind};
use std::collections::{BTreeMap, HashMap};
use std::io::BufWriter;
use std::path::Path;
use std::time::{Duration, Instant};

/// How much one topic's channel has taken.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ChannelStats {
    pub messages: u64,
    /// Wire bytes of those messages.
    pub bytes: u64,
    /// Messages written with no Foxglove copy (only with Foxglove channels
    /// on): their bytes did not decode, or the view refused them
    /// (`farsight_foxglove::View::dropped`).
    pub foxglove_dropped: u64,
}

/// When the writer closes its open chunk (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ChunkBounds {
    /// The longest a chunk stays open, from its first message, on the
    /// writer's wall clock.
    pub max_age: Duration,
    /// The uncompressed bytes of message records at which it is closed.
    pub max_bytes: u64,
}

impl ChunkBounds {
    pub const DEFAULT_MAX_AGE: Duration = Duration::from_secs(1);
    pub const DEFAULT_MAX_BYTES: u64 = 1 << 20;
    /// Every message its own chunk.
    pub const EVERY_MESSAGE: Self = Self {
        max_age: Duration::ZERO,
        max_bytes: 0,
    };
}

impl Default for ChunkBounds {
    /// 1 s, 1 MiB.
    fn default() -> Self {
        Self {
            max_age: Self::DEFAULT_MAX_AGE,
            max_bytes: Self::DEFAULT_MAX_BYTES,
        }
    }
}

/// How a recording is written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WriterOptions {
    /// The live Foxglove server's channels too (see the module docs).
    pub foxglove: bool,
    /// zstd-compressed chunks (level 1: rendered frames shrink about 70x,
    /// camera frames less; see `farsight bench recorder`).
    pub zstd: bool,
    pub chunks: ChunkBounds,
}

impl Default for WriterOptions {
    /// Foxglove channels, zstd, chunks of at most 1 s and 1 MiB.
    fn default() -> Self {
        Self {
            foxglove: true,
            zstd: true,
            chunks: ChunkBounds::default(),
        }
    }
}

/// Opcode and length in front of a record, and a message record's header
/// (channel id, sequence, log and publish time): a message record's bytes
/// beyond its data.
const MESSAGE_RECORD_OVERHEAD: u64 = 1 + 8 + 2 + 4 + 8 + 8;

/// The chunk being filled.
#[derive(Debug, Clone, Copy)]
struct OpenChunk {
    /// When its first message was written.
    since: Instant,
    /// Uncompressed bytes of its message records.
    bytes: u64,
}

/// An MCAP file being written.
pub struct RecordingWriter {
    out: mcap::Writer<BufWriter<std::fs::File>>,
    path: String,
    channels: HashMap<String, u16>,
    /// The Foxglove copy, when asked for.
    view: Option<View>,
    foxglove_channels: HashMap<String, u16>,
    /// Per topic: messages whose bytes did not decode for the Foxglove copy.
    undecodable: HashMap<String, u64>,
    stats: BTreeMap<String, ChannelStats>,
    bounds: ChunkBounds,
    open: Option<OpenChunk>,
    chunks_closed: u64,
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
    /// (see the module docs). Messages are zstd-compressed, in chunks of at
    /// most 1 s and 1 MiB ([`WriterOptions::default`]).
    pub fn create(path: &Path, foxglove: bool) -> Result<Self, RecordingError> {
        Self::create_with(path, foxglove, true)
    }

    /// [`Self::create`], with compression on or off.
    pub fn create_with(path: &Path, foxglove: bool, zstd: bool) -> Result<Self, RecordingError> {
        Self::create_with_options(
            path,
            &WriterOptions {
                foxglove,
                zstd,
                ..WriterOptions::default()
            },
        )
    }

    /// Creates `path` (replacing it), written as `opts` says.
    pub fn create_with_options(path: &Path, opts: &WriterOptions) -> Result<Self, RecordingError> {
        let p = path.display().to_string();
        let file = std::fs::File::create(path).map_err(|error| RecordingError::Io {
            path: p.clone(),
            error,
        })?;
        let mut out = mcap::WriteOptions::new()
            .profile("farsight")
            .library(concat!("farsight-recording ", env!("CARGO_PKG_VERSION")))
            .compression(opts.zstd.then_some(mcap::Compression::Zstd))
            .compression_level(1)
            // The writer closes chunks itself, on its bounds.
            .chunk_size(None)
            .create(BufWriter::new(file))
            .map_err(|error| RecordingError::Mcap {
                path: p.clone(),
                error,
            })?;
        // The magic and header go to the file at once: a recorder killed
        // before its first chunk closes leaves an MCAP file that holds no
        // message yet, not an empty file.
        out.flush().map_err(|error| RecordingError::Mcap {
            path: p.clone(),
            error,
        })?;
        let view = opts
            .foxglove
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
            undecodable: HashMap::new(),
            stats: BTreeMap::new(),
            bounds: opts.chunks,
            open: None,
            chunks_closed: 0,
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

    /// Writes one message record into the open chunk (opening one at `now`).
    fn put(
        &mut self,
        now: Instant,
        header: &mcap::records::MessageHeader,
        data: &[u8],
    ) -> Result<(), RecordingError> {
        self.out
            .write_to_known_channel(header, data)
            .map_err(self.mcap_err())?;
        let chunk = self.open.get_or_insert(OpenChunk {
            since: now,
            bytes: 0,
        });
        chunk.bytes += MESSAGE_RECORD_OVERHEAD + data.len() as u64;
        Ok(())
    }

    /// Writes the Foxglove messages the view makes of one farsight message.
    fn write_foxglove(
        &mut self,
        now: Instant,
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
                // farsight's own channel keeps the bytes; only the copy is
                // lost. Logged on the first and then every hundredth: a
                // broken publisher at 30 Hz must not flood the log.
                let n = self.undecodable.entry(topic.to_string()).or_default();
                *n += 1;
                if *n % 100 == 1 {
                    tracing::warn!(topic, dropped = *n, "no Foxglove copy: {e}");
                }
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
            self.put(now, &header, &out.message.encode())?;
        }
        Ok(())
    }

    /// Appends one message of `topic`: its wire bytes, the capture time from
    /// its stamp (publish time) and when it was received (log time). The
    /// chunk it goes into is closed when it is due (see the module docs).
    pub fn write(
        &mut self,
        topic: &str,
        stamp: Stamp,
        received_ns: u64,
        wire_bytes: &[u8],
    ) -> Result<(), RecordingError> {
        self.write_at(Instant::now(), topic, stamp, received_ns, wire_bytes)
    }

    /// [`Self::write`] at `now` on the writer's clock (which decides when a
    /// chunk has been open too long).
    pub fn write_at(
        &mut self,
        now: Instant,
        topic: &str,
        stamp: Stamp,
        received_ns: u64,
        wire_bytes: &[u8],
    ) -> Result<(), RecordingError> {
        // A chunk that has grown old goes out before this message: no chunk
        // spans more than its age bound.
        self.flush_if_due(now)?;
        let id = self.channel(topic)?;
        let header = mcap::records::MessageHeader {
            channel_id: id,
            sequence: stamp.frame_seq as u32,
            log_time: received_ns,
            publish_time: stamp.capture_time_ns,
        };
        self.put(now, &header, wire_bytes)?;
        if let Some(kind) = kind_of(topic) {
            self.write_foxglove(now, topic, kind, wire_bytes)?;
        }
        let foxglove_dropped = self.undecodable.get(topic).copied().unwrap_or(0)
            + self
                .view
                .as_ref()
                .and_then(|v| v.dropped().get(topic).copied())
                .unwrap_or(0);
        let s = self.stats.entry(topic.to_string()).or_default();
        s.messages += 1;
        s.bytes += wire_bytes.len() as u64;
        s.foxglove_dropped = foxglove_dropped;
        self.flush_if_due(now)?;
        Ok(())
    }

    /// Closes the open chunk if it is due at `now`: open for its age bound,
    /// or as large as its size bound. Recorder loops call this on every
    /// wake-up, so a chunk is closed in time with no new message. Returns
    /// whether it closed one.
    pub fn flush_if_due(&mut self, now: Instant) -> Result<bool, RecordingError> {
        let due = self.open.is_some_and(|c| {
            c.bytes >= self.bounds.max_bytes
                || now.saturating_duration_since(c.since) >= self.bounds.max_age
        });
        if due {
            // Finishes the chunk (header, CRC, message indexes) and flushes
            // the file's buffer to the OS.
            self.out.flush().map_err(self.mcap_err())?;
            self.open = None;
            self.chunks_closed += 1;
        }
        Ok(due)
    }

    /// The bounds chunks are closed on.
    pub fn chunk_bounds(&self) -> ChunkBounds {
        self.bounds
    }

    /// Chunks closed so far (the open one not counted).
    pub fn chunks_closed(&self) -> u64 {
        self.chunks_closed
    }

    /// Messages and bytes written per topic so far.
    pub fn stats(&self) -> &BTreeMap<String, ChannelStats> {
        &self.stats
    }

    /// Closes the open chunk, writes the summary (indexes, statistics) and
    /// closes the file. Topics with messages that have no Foxglove copy are
    /// logged with their count.
    pub fn finish(mut self) -> Result<BTreeMap<String, ChannelStats>, RecordingError> {
        self.out.finish().map_err(self.mcap_err())?;
        for (topic, s) in &self.stats {
            if s.foxglove_dropped > 0 {
                tracing::warn!(
                    topic,
                    foxglove_dropped = s.foxglove_dropped,
                    messages = s.messages,
                    "messages recorded with no Foxglove copy"
                );
            }
        }
        Ok(self.stats)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mcap_file::{McapFile, ReadEnd};
    use crate::read::Recording;
    use farsight_interfaces::msg::Pose;
    use farsight_interfaces::transport::wire;
    use std::ops::ControlFlow;
    use std::path::PathBuf;

    /// A fresh directory for one test.
    fn dir(test: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("farsight-write-{test}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    /// The sequence numbers of the messages in each chunk of `path`, in
    /// file order, and how the reading ended.
    fn layout(path: &Path) -> (Vec<Vec<u32>>, ReadEnd) {
        let file = McapFile::open(path).unwrap();
        let mut chunks: Vec<(u64, Vec<u32>)> = Vec::new();
        let end = file
            .read(|m| {
                match chunks.last_mut() {
                    Some((at, seqs)) if *at == m.offset => seqs.push(m.sequence),
                    _ => chunks.push((m.offset, vec![m.sequence])),
                }
                ControlFlow::Continue(())
            })
            .unwrap();
        (chunks.into_iter().map(|(_, s)| s).collect(), end)
    }

    /// What a SIGKILL of the writer's process would leave now: the file's
    /// bytes as the OS has them, unfinished, read as a reader would.
    fn killed_now(path: &Path) -> (Vec<Vec<u32>>, u64) {
        let copy = path.with_extension("killed.mcap");
        std::fs::copy(path, &copy).unwrap();
        match layout(&copy) {
            (chunks, ReadEnd::Truncated(t)) => {
                assert_eq!(
                    t.messages,
                    chunks.iter().map(|c| c.len() as u64).sum::<u64>()
                );
                (chunks, t.messages)
            }
            (_, end) => panic!("an unfinished file read to {end:?}"),
        }
    }

    fn seqs(chunks: &[&[u32]]) -> Vec<Vec<u32>> {
        chunks.iter().map(|c| c.to_vec()).collect()
    }

    #[test]
    fn chunks_close_at_the_age_and_size_bounds_and_when_idle_and_a_kill_loses_only_the_open_one() {
        let d = dir("bounds");
        let path = d.join("run.mcap");
        let opts = WriterOptions {
            foxglove: false,
            zstd: true,
            chunks: ChunkBounds {
                max_age: Duration::from_secs(1),
                max_bytes: 10_000,
            },
        };
        let mut w = RecordingWriter::create_with_options(&path, &opts).unwrap();
        // The writer's clock is injected: seconds from t0.
        let t0 = Instant::now();
        let at = |s: f64| t0 + Duration::from_secs_f64(s);
        let put = |w: &mut RecordingWriter, k: u64, s: f64, len: usize| {
            w.write_at(
                at(s),
                "state/pose",
                Stamp::new(k, k),
                k,
                &vec![k as u8; len],
            )
            .unwrap()
        };
        // Killed before any chunk closed: the file is an MCAP file holding
        // nothing yet, not an empty one.
        assert_eq!(killed_now(&path), (vec![], 0));
        // Messages within 1 s of a chunk's first share it; it stays open
        // (in memory) until the bound.
        put(&mut w, 1, 0.0, 100);
        put(&mut w, 2, 0.5, 100);
        put(&mut w, 3, 0.99, 100);
        assert!(!w.flush_if_due(at(0.999)).unwrap());
        assert_eq!(killed_now(&path), (vec![], 0));
        // The next message at 1 s closes it first, and opens the next.
        put(&mut w, 4, 1.0, 100);
        assert_eq!(killed_now(&path), (seqs(&[&[1, 2, 3]]), 3));
        // Idle: no new message, and the chunk still closes at its bound.
        assert!(!w.flush_if_due(at(1.999)).unwrap());
        assert_eq!(killed_now(&path).1, 3);
        assert!(w.flush_if_due(at(2.0)).unwrap());
        assert_eq!(killed_now(&path), (seqs(&[&[1, 2, 3], &[4]]), 4));
        assert!(!w.flush_if_due(at(9.0)).unwrap(), "nothing is open");
        // The size bound (uncompressed, though these compress to nearly
        // nothing): two 4000-byte messages stay open, the third reaches
        // 10 000 bytes and closes the chunk at once.
        put(&mut w, 5, 10.0, 4000);
        put(&mut w, 6, 10.0, 4000);
        assert_eq!(killed_now(&path).1, 4);
        put(&mut w, 7, 10.0, 4000);
        assert_eq!(
            killed_now(&path),
            (seqs(&[&[1, 2, 3], &[4], &[5, 6, 7]]), 7)
        );
        // A message larger than the bound is a chunk of its own.
        put(&mut w, 8, 10.0, 20_000);
        // What a kill loses is the open chunk: message 9.
        put(&mut w, 9, 10.1, 100);
        let closed = seqs(&[&[1, 2, 3], &[4], &[5, 6, 7], &[8]]);
        assert_eq!(killed_now(&path), (closed, 8));
        assert_eq!(w.chunks_closed(), 4);
        // A clean stop loses nothing.
        w.finish().unwrap();
        let (chunks, end) = layout(&path);
        assert_eq!(end, ReadEnd::Complete);
        assert_eq!(chunks, seqs(&[&[1, 2, 3], &[4], &[5, 6, 7], &[8], &[9]]));
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn every_message_bounds_flush_each_message_as_its_own_chunk() {
        let d = dir("every");
        let path = d.join("run.mcap");
        let opts = WriterOptions {
            foxglove: false,
            zstd: true,
            chunks: ChunkBounds::EVERY_MESSAGE,
        };
        let mut w = RecordingWriter::create_with_options(&path, &opts).unwrap();
        let now = Instant::now();
        for k in 1..=3u64 {
            w.write_at(now, "state/pose", Stamp::new(k, k), k, &[k as u8; 10])
                .unwrap();
        }
        assert_eq!(killed_now(&path), (seqs(&[&[1], &[2], &[3]]), 3));
        drop(w);
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn recordings_default_to_chunks_of_one_second_and_one_mib() {
        let d = dir("default");
        let w = RecordingWriter::create(&d.join("run.mcap"), false).unwrap();
        assert_eq!(
            w.chunk_bounds(),
            ChunkBounds {
                max_age: Duration::from_secs(1),
                max_bytes: 1024 * 1024,
            }
        );
        assert_eq!(WriterOptions::default().chunks, w.chunk_bounds());
        drop(w);
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn messages_with_no_foxglove_copy_are_counted_per_topic_and_keep_their_channel() {
        let d = dir("dropped");
        let path = d.join("run.mcap");
        let mut w = RecordingWriter::create(&path, true).unwrap();
        let pose = Pose {
            stamp: Stamp::new(1, 1_000_000_000),
            position_m: [1.0, 2.0, 0.0],
            ..Default::default()
        };
        let good = wire::encode_message(&pose).unwrap();
        let nan = wire::encode_message(&Pose {
            stamp: Stamp::new(2, 2_000_000_000),
            position_m: [f64::NAN, 0.0, 0.0],
            ..pose
        })
        .unwrap();
        w.write("state/pose", pose.stamp, 1, &good).unwrap();
        // Garbage on a known topic: not decodable, 250 times.
        for k in 0..250u64 {
            w.write("state/pose", Stamp::new(k, k), k, b"not wire bytes at all")
                .unwrap();
        }
        // Decodable, but the view refuses a NaN pose.
        w.write("state/pose", Stamp::new(2, 2_000_000_000), 2, &nan)
            .unwrap();
        w.write("state/pose", pose.stamp, 3, &good).unwrap();
        let s = w.stats()["state/pose"];
        assert_eq!((s.messages, s.foxglove_dropped), (253, 251), "{s:?}");
        let stats = w.finish().unwrap();
        assert_eq!(stats["state/pose"].foxglove_dropped, 251);
        let info = Recording::open(&path).unwrap().info().unwrap();
        let count = |t: &str| info.topics.iter().find(|i| i.topic == t).map(|i| i.count);
        // farsight's channel keeps every message; Foxglove's has the two
        // good ones.
        assert_eq!(count("state/pose"), Some(253), "{info}");
        assert_eq!(count("/state/pose"), Some(2), "{info}");
        // Without Foxglove channels nothing is counted.
        let mut w = RecordingWriter::create(&d.join("plain.mcap"), false).unwrap();
        w.write("state/pose", Stamp::new(1, 1), 1, b"garbage")
            .unwrap();
        assert_eq!(w.stats()["state/pose"].foxglove_dropped, 0);
        let _ = std::fs::remove_dir_all(&d);
    }

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
