//! Reading MCAP files, verified. Everything in farsight that reads an MCAP
//! file (`farsight record --info`, `replay`, `diff`, `dataset`, and
//! camera-ingest's `mcap` source) goes through [`McapFile`], so every one
//! of them tells the same three cases apart, naming the file and the byte
//! offset:
//!
//! - **Not an MCAP file** (empty, text, random bytes: no MCAP magic at
//!   byte 0): [`McapFile::open`] refuses it.
//! - **Damaged**: a chunk whose CRC does not match what it decompresses to,
//!   a chunk that does not decompress, a record that does not parse, a
//!   message on a channel never defined, a bad data-section or summary CRC.
//!   [`McapFile::read`] stops with a [`McapDamage`]. A chunk is checked
//!   whole before any of its messages is handed out, so nothing from a bad
//!   chunk is ever used.
//! - **Truncated**: the file ends mid-record or without its summary, as a
//!   recorder killed mid-write leaves it. [`McapFile::read`] hands out every
//!   message of every complete chunk and then returns
//!   [`ReadEnd::Truncated`] with the offset where the whole data ends;
//!   callers decide what that means for them (the CLI plays what is there
//!   and exits non-zero). A file that does end in the MCAP magic is
//!   finished, so a record running past its end there is damage, not
//!   truncation.
//!
//! Records are walked here, at the top level, so every error has an
//! offset; the `mcap` crate parses each record and links channels to
//! schemas.

use mcap::read::ChannelAccumulator;
use mcap::records::{op, Record};
use mcap::{Channel, MAGIC};
use std::borrow::Cow;
use std::ops::ControlFlow;
use std::path::Path;
use std::sync::Arc;

/// Opcode (1 byte) and length (8 bytes) in front of every record.
const RECORD_HEADER: usize = 1 + 8;
/// A footer's body: summary start, summary offset start, summary CRC.
const FOOTER_BODY: usize = 8 + 8 + 4;

/// What kind of damage a [`McapDamage`] is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DamageKind {
    /// Empty, too short, or no MCAP magic at byte 0.
    NotMcap,
    /// A chunk, data-section or summary CRC does not match.
    BadCrc,
    /// A record that does not decompress, parse or link.
    Corrupt,
}

/// Why an MCAP file cannot be used: the file, the byte offset and what is
/// wrong there. Its text is `FILE: WHAT at byte N (...)`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{path}: {what}")]
pub struct McapDamage {
    pub path: String,
    /// Where the damaged record (or the magic) starts.
    pub offset: u64,
    pub kind: DamageKind,
    /// What is wrong, with the offset in it.
    pub what: String,
}

/// Where a file cut off mid-write ends: everything before `offset` was
/// read, whole. Its text is `FILE: truncated at byte N of M: WHY; ...`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Truncation {
    pub path: String,
    /// The end of the last complete record: where the whole data ends.
    pub offset: u64,
    /// The file's length.
    pub file_len: u64,
    /// Messages read before it (all channels).
    pub messages: u64,
    pub why: String,
}

impl std::fmt::Display for Truncation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}: truncated at byte {} of {}: {}; the {} messages before it are whole",
            self.path, self.offset, self.file_len, self.why, self.messages
        )
    }
}

/// How a [`McapFile::read`] ended.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ReadEnd {
    /// The whole file was read and checked.
    Complete,
    /// The callback asked to stop.
    Stopped,
    /// The file ends early; every message before the cut was handed out.
    Truncated(Truncation),
}

/// One message, linked to its channel (and the channel's schema).
#[derive(Debug, Clone)]
pub struct McapMessage<'a> {
    pub channel: Arc<Channel<'static>>,
    pub sequence: u32,
    pub log_time: u64,
    pub publish_time: u64,
    pub data: &'a [u8],
    /// Byte offset of the chunk (or top-level message record) it came from.
    pub offset: u64,
}

/// A memory-mapped MCAP file whose magic has been checked.
pub struct McapFile {
    map: Option<memmap2::Mmap>,
    path: String,
}

/// What [`record_at`] found at an offset.
enum At<'a> {
    /// The file ends exactly here.
    End,
    /// Something that is not a whole record: why.
    Cut(String),
    Record {
        opcode: u8,
        body: &'a [u8],
    },
}

fn record_name(opcode: u8) -> &'static str {
    match opcode {
        op::HEADER => "header",
        op::FOOTER => "footer",
        op::SCHEMA => "schema",
        op::CHANNEL => "channel",
        op::MESSAGE => "message",
        op::CHUNK => "chunk",
        op::MESSAGE_INDEX => "message index",
        op::CHUNK_INDEX => "chunk index",
        op::ATTACHMENT => "attachment",
        op::ATTACHMENT_INDEX => "attachment index",
        op::STATISTICS => "statistics",
        op::METADATA => "metadata",
        op::METADATA_INDEX => "metadata index",
        op::SUMMARY_OFFSET => "summary offset",
        op::DATA_END => "data end",
        _ => "unknown",
    }
}

fn record_at(buf: &[u8], pos: usize) -> At<'_> {
    let rest = &buf[pos..];
    if rest.is_empty() {
        return At::End;
    }
    if rest.len() < RECORD_HEADER {
        return At::Cut(format!(
            "only {} of the {RECORD_HEADER} bytes of a record header are there",
            rest.len()
        ));
    }
    let opcode = rest[0];
    // Opcode 0 is reserved: zeros where a record should start are what a
    // file system leaves of blocks allocated but never written.
    if opcode == 0 {
        return At::Cut("no record starts there (opcode 0)".into());
    }
    let len = u64::from_le_bytes(rest[1..RECORD_HEADER].try_into().expect("8 bytes"));
    let available = (rest.len() - RECORD_HEADER) as u64;
    if len > available {
        return At::Cut(format!(
            "the {} record there needs {len} bytes, {available} are there",
            record_name(opcode)
        ));
    }
    At::Record {
        opcode,
        body: &rest[RECORD_HEADER..RECORD_HEADER + len as usize],
    }
}

impl McapFile {
    /// Maps `path` and checks the MCAP magic at byte 0: an empty file, a
    /// shorter one or one that starts with anything else is refused here.
    pub fn open(path: &Path) -> Result<Self, crate::RecordingError> {
        let p = path.display().to_string();
        let io = |error| crate::RecordingError::Io {
            path: p.clone(),
            error,
        };
        let file = std::fs::File::open(path).map_err(io)?;
        let len = file.metadata().map_err(io)?.len();
        let file = Self {
            // SAFETY: the file is only read. One still being written is
            // read up to its length at this moment and reported truncated.
            map: if len == 0 {
                None
            } else {
                Some(unsafe { memmap2::Mmap::map(&file) }.map_err(io)?)
            },
            path: p,
        };
        file.check_magic()?;
        Ok(file)
    }

    pub fn path(&self) -> &str {
        &self.path
    }

    /// The file's bytes.
    pub fn bytes(&self) -> &[u8] {
        self.map.as_deref().unwrap_or(&[])
    }

    fn damage(&self, offset: usize, kind: DamageKind, what: String) -> McapDamage {
        McapDamage {
            path: self.path.clone(),
            offset: offset as u64,
            kind,
            what,
        }
    }

    fn check_magic(&self) -> Result<(), McapDamage> {
        let buf = self.bytes();
        let what = if buf.is_empty() {
            "not an MCAP file: it is empty (no MCAP magic at byte 0)".to_string()
        } else if buf.len() < MAGIC.len() {
            format!(
                "not an MCAP file: {} bytes, too short for the MCAP magic at byte 0",
                buf.len()
            )
        } else if &buf[..MAGIC.len()] != MAGIC {
            format!(
                "not an MCAP file: no MCAP magic at byte 0 (it starts \"{}\")",
                buf[..MAGIC.len()].escape_ascii()
            )
        } else {
            return Ok(());
        };
        Err(self.damage(0, DamageKind::NotMcap, what))
    }

    /// Reads and checks the whole file without looking at the messages.
    pub fn verify(&self) -> Result<ReadEnd, McapDamage> {
        self.read(|_| ControlFlow::Continue(()))
    }

    /// Calls `f` on every message in file order, until it breaks. Each
    /// chunk is decompressed and its CRC checked before any of its messages
    /// goes to `f`; the data-section and summary CRCs are checked when the
    /// reading gets there. A damaged file stops the reading with the error
    /// (after the messages of the chunks before the damage); a truncated
    /// one ends with [`ReadEnd::Truncated`] after every complete chunk.
    pub fn read(
        &self,
        mut f: impl FnMut(McapMessage<'_>) -> ControlFlow<()>,
    ) -> Result<ReadEnd, McapDamage> {
        let buf = self.bytes();
        // A file that ends in the magic was finished by its writer: from
        // then on, a record running past the end is damage, not a cut.
        let finished = buf.len() >= 2 * MAGIC.len() + RECORD_HEADER && buf.ends_with(MAGIC);
        let mut channels = ChannelAccumulator::default();
        let mut scratch: Vec<u8> = Vec::new();
        let mut zstd: Option<zstd::bulk::Decompressor<'static>> = None;
        let mut messages = 0u64;
        let mut pos = MAGIC.len();
        let cut = |pos: usize, messages: u64, why: String| -> Result<ReadEnd, McapDamage> {
            if finished {
                Err(self.damage(
                    pos,
                    DamageKind::Corrupt,
                    format!(
                        "damaged record at byte {pos}: {why}, but the file ends in the MCAP magic"
                    ),
                ))
            } else {
                Ok(ReadEnd::Truncated(Truncation {
                    path: self.path.clone(),
                    offset: pos as u64,
                    file_len: buf.len() as u64,
                    messages,
                    why,
                }))
            }
        };
        // The data section.
        let data_end = loop {
            let (opcode, body) = match record_at(buf, pos) {
                At::End => {
                    return cut(
                        pos,
                        messages,
                        "the file ends without its summary (its writer did not finish it)".into(),
                    )
                }
                At::Cut(why) => return cut(pos, messages, why),
                At::Record { opcode, body } => (opcode, body),
            };
            let at = pos;
            let next = pos + RECORD_HEADER + body.len();
            match opcode {
                op::DATA_END => break at,
                op::CHUNK => {
                    let bad = |why: String| {
                        self.damage(
                            at,
                            DamageKind::Corrupt,
                            format!("damaged chunk at byte {at}: {why}"),
                        )
                    };
                    let Record::Chunk { header, data } =
                        mcap::parse_record(opcode, body).map_err(|e| bad(e.to_string()))?
                    else {
                        unreachable!("a chunk opcode parses to a chunk")
                    };
                    let size = header.uncompressed_size;
                    let records: &[u8] = match header.compression.as_str() {
                        "" => {
                            if data.len() as u64 != size {
                                return Err(bad(format!(
                                    "{} bytes of records, its header says {size}",
                                    data.len()
                                )));
                            }
                            match data {
                                Cow::Borrowed(d) => d,
                                Cow::Owned(_) => unreachable!("parsed from the map"),
                            }
                        }
                        "zstd" => {
                            let size = usize::try_from(size)
                                .map_err(|_| bad(format!("uncompressed size {size}")))?;
                            scratch.clear();
                            scratch.try_reserve_exact(size).map_err(|_| {
                                bad(format!(
                                    "uncompressed size {size} is more than fits in memory"
                                ))
                            })?;
                            let z = match &mut zstd {
                                Some(z) => z,
                                None => zstd.insert(
                                    zstd::bulk::Decompressor::new()
                                        .map_err(|e| bad(format!("zstd: {e}")))?,
                                ),
                            };
                            let n = z
                                .decompress_to_buffer(&data, &mut scratch)
                                .map_err(|e| bad(format!("zstd data does not decompress ({e})")))?;
                            if n != size {
                                return Err(bad(format!(
                                    "decompresses to {n} bytes, its header says {size}"
                                )));
                            }
                            &scratch
                        }
                        other => {
                            return Err(bad(format!(
                                "compression {other:?} is not supported (zstd or none)"
                            )))
                        }
                    };
                    if header.uncompressed_crc != 0 {
                        let got = crc32fast::hash(records);
                        if got != header.uncompressed_crc {
                            return Err(self.damage(
                                at,
                                DamageKind::BadCrc,
                                format!(
                                    "bad chunk CRC at byte {at} (expected {:#010x}, got {got:#010x})",
                                    header.uncompressed_crc
                                ),
                            ));
                        }
                    }
                    // Records inside the chunk.
                    let mut inner = 0usize;
                    while inner < records.len() {
                        let (opcode, body) = match record_at(records, inner) {
                            At::Record { opcode, body } => (opcode, body),
                            At::End => break,
                            At::Cut(why) => {
                                return Err(bad(format!("at byte {inner} of its records: {why}")))
                            }
                        };
                        inner += RECORD_HEADER + body.len();
                        let flow = self
                            .take(&mut channels, opcode, body, at, &mut f)
                            .map_err(&bad)?;
                        if let Some(flow) = flow {
                            messages += 1;
                            if flow.is_break() {
                                return Ok(ReadEnd::Stopped);
                            }
                        }
                    }
                }
                _ => {
                    let flow =
                        self.take(&mut channels, opcode, body, at, &mut f)
                            .map_err(|why| {
                                self.damage(
                                    at,
                                    DamageKind::Corrupt,
                                    format!(
                                        "damaged {} record at byte {at}: {why}",
                                        record_name(opcode)
                                    ),
                                )
                            })?;
                    if let Some(flow) = flow {
                        messages += 1;
                        if flow.is_break() {
                            return Ok(ReadEnd::Stopped);
                        }
                    }
                }
            }
            pos = next;
        };
        // Data end: the CRC of everything before it.
        let (opcode, body) = match record_at(buf, data_end) {
            At::Record { opcode, body } => (opcode, body),
            _ => unreachable!("read above"),
        };
        match mcap::parse_record(opcode, body) {
            Ok(Record::DataEnd(end)) if end.data_section_crc != 0 => {
                let got = crc32fast::hash(&buf[..data_end]);
                if got != end.data_section_crc {
                    return Err(self.damage(
                        data_end,
                        DamageKind::BadCrc,
                        format!(
                            "bad data section CRC at byte {data_end} (expected {:#010x}, got {got:#010x}): \
                             the bytes before it are damaged outside the chunks",
                            end.data_section_crc
                        ),
                    ));
                }
            }
            Ok(_) => {}
            Err(e) => {
                return Err(self.damage(
                    data_end,
                    DamageKind::Corrupt,
                    format!("damaged data end record at byte {data_end}: {e}"),
                ))
            }
        }
        // The summary, up to the footer and the closing magic.
        let summary_start = data_end + RECORD_HEADER + body.len();
        pos = summary_start;
        loop {
            let (opcode, body) = match record_at(buf, pos) {
                At::End => {
                    return cut(
                        pos,
                        messages,
                        "the file ends inside its summary, before the footer".into(),
                    )
                }
                At::Cut(why) => return cut(pos, messages, why),
                At::Record { opcode, body } => (opcode, body),
            };
            if opcode != op::FOOTER {
                pos += RECORD_HEADER + body.len();
                continue;
            }
            let footer = match mcap::parse_record(opcode, body) {
                Ok(Record::Footer(footer)) if body.len() == FOOTER_BODY => footer,
                Ok(_) => {
                    return Err(self.damage(
                        pos,
                        DamageKind::Corrupt,
                        format!(
                            "damaged footer at byte {pos}: {} bytes long, not {FOOTER_BODY}",
                            body.len()
                        ),
                    ))
                }
                Err(e) => {
                    return Err(self.damage(
                        pos,
                        DamageKind::Corrupt,
                        format!("damaged footer at byte {pos}: {e}"),
                    ))
                }
            };
            if footer.summary_crc != 0 {
                let got = crc32fast::hash(&buf[summary_start..pos + RECORD_HEADER + 16]);
                if got != footer.summary_crc {
                    return Err(self.damage(
                        summary_start,
                        DamageKind::BadCrc,
                        format!(
                            "bad summary CRC at byte {summary_start} (expected {:#010x}, got {got:#010x})",
                            footer.summary_crc
                        ),
                    ));
                }
            }
            let end = pos + RECORD_HEADER + body.len();
            let rest = &buf[end..];
            if rest.len() < MAGIC.len() {
                return cut(
                    end,
                    messages,
                    "the closing MCAP magic after the footer is missing".into(),
                );
            }
            if &rest[..MAGIC.len()] != MAGIC || rest.len() > MAGIC.len() {
                return Err(self.damage(
                    end,
                    DamageKind::Corrupt,
                    format!(
                        "at byte {end}, after the footer: {} bytes that are not just the closing MCAP magic",
                        rest.len()
                    ),
                ));
            }
            return Ok(ReadEnd::Complete);
        }
    }

    /// One record of the data section (top level or inside a chunk): links
    /// schemas and channels, hands messages to `f`. `Some` when it was a
    /// message; `Err` says why the record is bad.
    fn take(
        &self,
        channels: &mut ChannelAccumulator<'static>,
        opcode: u8,
        body: &[u8],
        offset: usize,
        f: &mut impl FnMut(McapMessage<'_>) -> ControlFlow<()>,
    ) -> Result<Option<ControlFlow<()>>, String> {
        // Only the records that carry data are parsed; the rest (indexes,
        // statistics, metadata, records of later MCAP versions) are skipped,
        // their bytes covered by the data-section CRC.
        if !matches!(
            opcode,
            op::SCHEMA | op::CHANNEL | op::MESSAGE | op::ATTACHMENT
        ) {
            return Ok(None);
        }
        match mcap::parse_record(opcode, body).map_err(|e| e.to_string())? {
            Record::Schema { header, data } => {
                channels
                    .add_schema_from_slice(header, &data)
                    .map_err(|e| format!("schema: {e}"))?;
                Ok(None)
            }
            Record::Channel(c) => {
                channels
                    .add_channel(c)
                    .map_err(|e| format!("channel: {e}"))?;
                Ok(None)
            }
            Record::Message { header, data } => {
                let channel = channels.get(header.channel_id).ok_or_else(|| {
                    format!(
                        "a message on channel {}, which no channel record defines",
                        header.channel_id
                    )
                })?;
                let data: &[u8] = match data {
                    Cow::Borrowed(d) => d,
                    Cow::Owned(_) => unreachable!("parsed from a slice"),
                };
                Ok(Some(f(McapMessage {
                    channel,
                    sequence: header.sequence,
                    log_time: header.log_time,
                    publish_time: header.publish_time,
                    data,
                    offset: offset as u64,
                })))
            }
            // An attachment's own CRC is checked as it parses.
            _ => Ok(None),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::write::{ChunkBounds, RecordingWriter, WriterOptions};
    use farsight_interfaces::msg::Stamp;
    use std::path::PathBuf;

    /// A fresh directory for one test.
    fn dir(test: &str) -> PathBuf {
        let d =
            std::env::temp_dir().join(format!("farsight-mcap-file-{test}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    /// Bytes zstd cannot shrink (so a flipped one survives decompression
    /// and only the chunk CRC can tell).
    fn noise(seed: u64, n: usize) -> Vec<u8> {
        let mut x = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        (0..n)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                x as u8
            })
            .collect()
    }

    /// A finished recording of `n` messages (one chunk each) on two topics.
    fn recording(path: &Path, n: u64, zstd: bool) -> Vec<u8> {
        let opts = WriterOptions {
            foxglove: false,
            zstd,
            chunks: ChunkBounds::EVERY_MESSAGE,
        };
        let mut w = RecordingWriter::create_with_options(path, &opts).unwrap();
        for k in 1..=n {
            let topic = if k % 2 == 0 { "state/pose" } else { "nav/goal" };
            w.write(topic, Stamp::new(k, k * 1000), k * 1000, &noise(k, 300))
                .unwrap();
        }
        w.finish().unwrap();
        std::fs::read(path).unwrap()
    }

    /// Top-level records: (offset, opcode, whole length).
    fn records(buf: &[u8]) -> Vec<(usize, u8, usize)> {
        let mut out = Vec::new();
        let mut pos = MAGIC.len();
        while let At::Record { opcode, body } = record_at(buf, pos) {
            out.push((pos, opcode, RECORD_HEADER + body.len()));
            pos += RECORD_HEADER + body.len();
            if opcode == op::FOOTER {
                break;
            }
        }
        out
    }

    fn chunks(buf: &[u8]) -> Vec<(usize, usize)> {
        records(buf)
            .into_iter()
            .filter(|r| r.1 == op::CHUNK)
            .map(|(at, _, len)| (at, len))
            .collect()
    }

    fn write(path: &Path, bytes: &[u8]) -> McapFile {
        std::fs::write(path, bytes).unwrap();
        McapFile::open(path).unwrap()
    }

    /// Messages read (sequence numbers) and how the reading ended.
    fn read_all(file: &McapFile) -> (Vec<u32>, Result<ReadEnd, McapDamage>) {
        let mut seqs = Vec::new();
        let end = file.read(|m| {
            seqs.push(m.sequence);
            ControlFlow::Continue(())
        });
        (seqs, end)
    }

    #[test]
    fn not_an_mcap_file_is_refused_at_open_naming_it_and_byte_0() {
        let d = dir("notmcap");
        let magic_prefix = &MAGIC[..5];
        let text = b"Hello, world: this is a text file\n".as_slice();
        for (name, bytes, says) in [
            ("empty.mcap", &[][..], "it is empty"),
            ("short.mcap", magic_prefix, "5 bytes, too short"),
            ("text.mcap", text, "it starts \"Hello, w\""),
            (
                "random.mcap",
                &noise(7, 4096)[..],
                "no MCAP magic at byte 0",
            ),
        ] {
            let path = d.join(name);
            std::fs::write(&path, bytes).unwrap();
            let e = match McapFile::open(&path) {
                Err(crate::RecordingError::Damaged(e)) => e,
                Err(e) => panic!("{name}: {e}"),
                Ok(_) => panic!("{name} opened"),
            };
            assert_eq!((e.kind, e.offset), (DamageKind::NotMcap, 0), "{e}");
            let text = e.to_string();
            assert!(
                text.starts_with(&format!("{}: not an MCAP file", path.display()))
                    && text.contains("byte 0")
                    && text.contains(says),
                "{text}"
            );
        }
    }

    #[test]
    fn a_whole_file_reads_every_message_compressed_or_not() {
        let d = dir("whole");
        for zstd in [true, false] {
            let path = d.join(format!("run-{zstd}.mcap"));
            recording(&path, 12, zstd);
            let file = McapFile::open(&path).unwrap();
            let (seqs, end) = read_all(&file);
            assert_eq!(end, Ok(ReadEnd::Complete));
            assert_eq!(seqs, (1..=12).collect::<Vec<_>>());
            let mut k = 0;
            let end = file.read(|m| {
                assert_eq!(m.data, &noise(u64::from(m.sequence), 300)[..]);
                k += 1;
                if k == 3 {
                    ControlFlow::Break(())
                } else {
                    ControlFlow::Continue(())
                }
            });
            assert_eq!(end, Ok(ReadEnd::Stopped));
        }
    }

    #[test]
    fn a_flipped_byte_in_a_chunk_is_a_bad_crc_at_its_offset() {
        let d = dir("crc");
        for zstd in [true, false] {
            let path = d.join(format!("run-{zstd}.mcap"));
            let good = recording(&path, 6, zstd);
            let (at, len) = chunks(&good)[3];
            let mut bad = good.clone();
            // Well inside the records (past the chunk header and message header).
            bad[at + len - 100] ^= 0x20;
            let file = write(&path, &bad);
            let (seqs, end) = read_all(&file);
            let e = end.unwrap_err();
            assert_eq!(
                (e.kind, e.offset),
                (DamageKind::BadCrc, at as u64),
                "zstd {zstd}: {e}"
            );
            assert!(
                e.to_string().starts_with(&format!(
                    "{}: bad chunk CRC at byte {at} (expected 0x",
                    path.display()
                )),
                "{e}"
            );
            // Nothing of the bad chunk was handed out; the chunks before were.
            assert_eq!(seqs, vec![1, 2, 3]);
        }
    }

    #[test]
    fn damage_outside_the_chunks_is_caught_by_the_section_crcs() {
        let d = dir("sections");
        let path = d.join("run.mcap");
        let good = recording(&path, 4, true);
        let recs = records(&good);
        // A message index after a chunk: only the data-section CRC covers it.
        let (index, _, len) = *recs.iter().find(|r| r.1 == op::MESSAGE_INDEX).unwrap();
        let mut bad = good.clone();
        bad[index + len - 1] ^= 1;
        let e = read_all(&write(&path, &bad)).1.unwrap_err();
        let data_end = recs.iter().find(|r| r.1 == op::DATA_END).unwrap().0;
        assert_eq!(
            (e.kind, e.offset),
            (DamageKind::BadCrc, data_end as u64),
            "{e}"
        );
        assert!(e.to_string().contains("bad data section CRC"), "{e}");
        // A statistics record in the summary.
        let (stats, _, len) = *recs.iter().find(|r| r.1 == op::STATISTICS).unwrap();
        let mut bad = good.clone();
        bad[stats + len - 1] ^= 1;
        let e = read_all(&write(&path, &bad)).1.unwrap_err();
        assert_eq!(e.kind, DamageKind::BadCrc, "{e}");
        assert!(e.to_string().contains("bad summary CRC"), "{e}");
        // Garbage after the closing magic.
        let mut bad = good.clone();
        bad.extend_from_slice(b"junk");
        let e = read_all(&write(&path, &bad)).1.unwrap_err();
        assert_eq!(
            (e.kind, e.offset),
            (DamageKind::Corrupt, (good.len() - MAGIC.len()) as u64),
            "{e}"
        );
    }

    #[test]
    fn a_file_cut_anywhere_reads_its_complete_chunks_and_says_where_it_ends() {
        let d = dir("cut");
        let path = d.join("run.mcap");
        let good = recording(&path, 5, true);
        let chunks = chunks(&good);
        let data_end = records(&good)
            .into_iter()
            .find(|r| r.1 == op::DATA_END)
            .unwrap()
            .0;
        // Where each message's chunk ends.
        let ends: Vec<usize> = chunks.iter().map(|(at, len)| at + len).collect();
        // Every 5th byte, and around every record boundary.
        let mut cuts: Vec<usize> = (MAGIC.len()..good.len()).step_by(5).collect();
        for (at, _, _) in records(&good) {
            cuts.extend([
                at - 1,
                at,
                at + 1,
                at + RECORD_HEADER - 1,
                at + RECORD_HEADER,
            ]);
        }
        cuts.sort_unstable();
        cuts.dedup();
        cuts.retain(|&c| c >= MAGIC.len() && c < good.len());
        for cut in cuts {
            let file = write(&path, &good[..cut]);
            let (seqs, end) = read_all(&file);
            let t = match end {
                Ok(ReadEnd::Truncated(t)) => t,
                other => panic!("cut at {cut}: {other:?}"),
            };
            let whole = ends.iter().filter(|&&e| e <= cut).count();
            assert_eq!(seqs.len(), whole, "cut at {cut}: {t}");
            assert_eq!(t.messages, whole as u64);
            assert!(t.offset as usize <= cut && t.file_len == cut as u64, "{t}");
            // Cut inside a chunk: the data ends where that chunk starts.
            if let Some((at, _)) = chunks.iter().find(|(at, len)| *at < cut && cut < at + len) {
                assert_eq!(t.offset as usize, *at, "{t}");
                if cut >= at + RECORD_HEADER {
                    assert!(t.why.contains("the chunk record there needs"), "{t}");
                }
            }
            if cut > data_end {
                assert_eq!(seqs.len(), 5);
            }
            assert!(
                t.to_string().starts_with(&format!(
                    "{}: truncated at byte {} of {cut}: ",
                    path.display(),
                    t.offset
                )),
                "{t}"
            );
        }
        // What a killed recorder leaves: whole chunks, then no summary.
        let killed = &good[..ends[2] + 200.min(data_end - ends[2])];
        let t = match read_all(&write(&path, killed)).1 {
            Ok(ReadEnd::Truncated(t)) => t,
            other => panic!("{other:?}"),
        };
        assert_eq!(t.messages, 3);
        // Zeros where blocks were allocated but never written (a power cut).
        let mut zeros = good[..ends[1]].to_vec();
        zeros.extend(std::iter::repeat_n(0, 4096));
        let t = match read_all(&write(&path, &zeros)).1 {
            Ok(ReadEnd::Truncated(t)) => t,
            other => panic!("{other:?}"),
        };
        assert_eq!((t.offset as usize, t.messages), (ends[1], 2), "{t}");
        assert!(t.why.contains("opcode 0"), "{t}");
    }

    #[test]
    fn a_finished_file_with_a_record_running_past_its_end_is_damaged_not_cut() {
        let d = dir("finished");
        let path = d.join("run.mcap");
        let good = recording(&path, 3, true);
        let (at, _) = chunks(&good)[1];
        let mut bad = good.clone();
        // The chunk's length now claims far more than the file holds.
        bad[at + 8] = 0x7f;
        let (seqs, end) = read_all(&write(&path, &bad));
        let e = end.unwrap_err();
        assert_eq!((e.kind, e.offset), (DamageKind::Corrupt, at as u64), "{e}");
        assert_eq!(seqs, vec![1]);
    }
}
