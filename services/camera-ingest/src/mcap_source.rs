//! Frames from an MCAP recording: ROS 2 bags (`sensor_msgs/msg/Image` and
//! `CompressedImage`, CDR-encoded) and farsight's own recordings (channels with
//! message encoding `farsight-wire`, payload = [`farsight_interfaces::transport::wire`]
//! header + pixels). Messages of one topic are replayed in file order, paced by
//! their log times. The file is verified as it is read (farsight-recording's
//! `mcap_file`): not an MCAP file or damaged is an error naming the file and
//! the byte offset; a truncated file plays up to its last complete chunk.

use crate::ros_cdr;
use farsight_interfaces::msg::{ImageHeader, PixelEncoding};
use farsight_interfaces::transport::wire;
use farsight_recording::mcap_file::ReadEnd;
pub use farsight_recording::mcap_file::Truncation;
use std::ops::ControlFlow;
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

/// A memory-mapped MCAP file, read through farsight-recording's verified
/// reader: a file that is not an MCAP file, or is damaged (a bad chunk CRC),
/// is an error naming the file and the byte offset; a truncated one plays up
/// to its last complete chunk.
pub struct McapFile {
    file: farsight_recording::mcap_file::McapFile,
}

/// Channels of a file, and whether it was cut short.
pub struct Contents {
    /// Topic, message encoding and schema name of each channel.
    pub channels: Vec<(String, String, String)>,
    /// Where the file was cut (a recorder killed mid-write), if it was.
    pub truncated: Option<Truncation>,
}

/// How a pass over one topic ended.
#[derive(Debug)]
pub struct Played {
    /// Messages on the topic handed to the callback.
    pub frames: usize,
    /// Where the file was cut, if it was: every frame before it was played.
    pub truncated: Option<Truncation>,
}

impl McapFile {
    /// Opens `path`, refusing a file that does not start with the MCAP magic.
    pub fn open(path: &Path) -> Result<Self, String> {
        farsight_recording::mcap_file::McapFile::open(path)
            .map(|file| Self { file })
            .map_err(|e| e.to_string())
    }

    pub fn path(&self) -> &str {
        self.file.path()
    }

    /// Reads and checks the whole file: its channels, and where it was cut.
    /// Damage anywhere (a bad chunk CRC) is an error naming the offset.
    pub fn contents(&self) -> Result<Contents, String> {
        let mut out = std::collections::BTreeSet::new();
        let mut seen = std::collections::HashSet::new();
        let end = self
            .file
            .read(|m| {
                if seen.insert(m.channel.id) {
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
                ControlFlow::Continue(())
            })
            .map_err(|e| e.to_string())?;
        Ok(Contents {
            channels: out.into_iter().collect(),
            truncated: match end {
                ReadEnd::Truncated(t) => Some(t),
                ReadEnd::Complete | ReadEnd::Stopped => None,
            },
        })
    }

    /// Calls `f` for each message on `topic`, in file order; stops early
    /// when `f` returns false. A truncated file plays every frame of its
    /// complete chunks and says where it was cut; damage is an error
    /// naming the offset (after the frames of the chunks before it).
    pub fn for_each_frame(
        &self,
        topic: &str,
        mut f: impl FnMut(RecordedFrame) -> bool,
    ) -> Result<Played, String> {
        let mut frames = 0;
        let end = self
            .file
            .read(|m| {
                if m.channel.topic != topic {
                    return ControlFlow::Continue(());
                }
                frames += 1;
                let schema = m
                    .channel
                    .schema
                    .as_ref()
                    .map(|s| s.name.as_str())
                    .unwrap_or("");
                let image = decode(&m.channel.message_encoding, schema, m.data);
                if f(RecordedFrame {
                    log_time_ns: m.log_time,
                    image,
                }) {
                    ControlFlow::Continue(())
                } else {
                    ControlFlow::Break(())
                }
            })
            .map_err(|e| e.to_string())?;
        Ok(Played {
            frames,
            truncated: match end {
                ReadEnd::Truncated(t) => Some(t),
                ReadEnd::Complete | ReadEnd::Stopped => None,
            },
        })
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
