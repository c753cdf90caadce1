//! Frames from an MCAP recording: ROS 2 bags (`sensor_msgs/msg/Image` and
//! `CompressedImage`, CDR-encoded) and farsight's own recordings (channels with
//! message encoding `farsight-wire`, payload = [`farsight_interfaces::transport::wire`]
//! header + pixels). Messages of one topic are replayed in file order, paced by
//! their log times.

use crate::ros_cdr;
use farsight_interfaces::msg::{ImageHeader, PixelEncoding};
use farsight_interfaces::transport::wire;
use std::path::Path;

/// Message encoding of farsight's own MCAP channels.
pub const FARSIGHT_ENCODING: &str = wire::MCAP_MESSAGE_ENCODING;

/// One image message of a recording.
pub struct RecordedFrame {
    /// The message's log time, nanoseconds (paces the replay).
    pub log_time_ns: u64,
    /// The decoded image, or why it could not be used.
    pub image: Result<(ImageHeader, Vec<u8>), String>,
}

/// A memory-mapped MCAP file (recordings can be much larger than memory).
pub struct McapFile {
    map: memmap2::Mmap,
    path: String,
}

impl McapFile {
    pub fn open(path: &Path) -> Result<Self, String> {
        let file =
            std::fs::File::open(path).map_err(|e| format!("opening {}: {e}", path.display()))?;
        // SAFETY: the file is only read; a recording being appended to while
        // it is replayed shows up as a truncated stream, which is handled.
        let map = unsafe { memmap2::Mmap::map(&file) }
            .map_err(|e| format!("mapping {}: {e}", path.display()))?;
        Ok(Self {
            map,
            path: path.display().to_string(),
        })
    }

    /// Topics of the file's channels with their message encoding and schema name.
    pub fn channels(&self) -> Result<Vec<(String, String, String)>, String> {
        let mut out = std::collections::BTreeSet::new();
        let stream =
            mcap::MessageStream::new(&self.map).map_err(|e| format!("{}: {e}", self.path))?;
        for m in stream {
            let Ok(m) = m else { break };
            let schema = m
                .channel
                .schema
                .as_ref()
                .map(|s| s.name.clone())
                .unwrap_or_default();
            out.insert((
                m.channel.topic.clone(),
                m.channel.message_encoding.clone(),
                schema,
            ));
        }
        Ok(out.into_iter().collect())
    }

    /// Calls `f` for each message on `topic`, in file order; stops early when
    /// `f` returns false. A damaged tail ends the stream with an error after
    /// the last complete message.
    pub fn for_each_frame(
        &self,
        topic: &str,
        mut f: impl FnMut(RecordedFrame) -> bool,
    ) -> Result<usize, String> {
        let stream =
            mcap::MessageStream::new(&self.map).map_err(|e| format!("{}: {e}", self.path))?;
        let mut n = 0;
        for m in stream {
            let m = m.map_err(|e| {
                format!("{}: recording ends early after {n} frames: {e}", self.path)
            })?;
            if m.channel.topic != topic {
                continue;
            }
            n += 1;
            let schema = m
                .channel
                .schema
                .as_ref()
                .map(|s| s.name.as_str())
                .unwrap_or("");
            let image = decode(&m.channel.message_encoding, schema, &m.data);
            if !f(RecordedFrame {
                log_time_ns: m.log_time,
                image,
            }) {
                break;
            }
        }
        Ok(n)
    }
}

fn decode(encoding: &str, schema: &str, data: &[u8]) -> Result<(ImageHeader, Vec<u8>), String> {
    let (h, d) = match (encoding, schema) {
        ("cdr", "sensor_msgs/msg/Image") => ros_cdr::decode_image(data).map_err(|e| e.to_string())?,
        ("cdr", "sensor_msgs/msg/CompressedImage") => ros_cdr::decode_compressed(data).map_err(|e| format!("{e:#}"))?,
        (FARSIGHT_ENCODING, _) => {
            let (h, px): (ImageHeader, &[u8]) = wire::split_slice(data).map_err(|e| e.to_string())?;
            farsight_imaging::decode_frame(h, px).map_err(|e| e.to_string())?
        }
        (e, s) => return Err(format!("channel encoding {e:?} with schema {s:?} is not an image this stage reads (ROS 2 sensor_msgs/msg/Image or CompressedImage in cdr, or farsight-wire)")),
    };
    if h.encoding == PixelEncoding::YUYV {
        return farsight_imaging::yuyv_to_rgb(&h, &d).map_err(|e| e.to_string());
    }
    Ok((h, d))
}
