//! # farsight-recording
//!
//! Recorded frame replays, the way the graph is integration-tested: record
//! any farsight topics into an [MCAP](https://mcap.dev) file, read it back,
//! replay it into the graph, and compare a run against a golden recording.
//!
//! Every topic gets its own channel whose messages are the topic's
//! [wire](farsight_interfaces::transport::wire) bytes (message encoding
//! `farsight-wire`, schema `farsight.<Kind>`); the log time is when the
//! recorder received the message and the publish time the capture time of
//! the frame it came from. With `foxglove` on (the default of `farsight
//! record` and the recorder node), the file also holds the live Foxglove
//! server's channels (`/camera/front/image`, `/tf`, `/costmap/fused`, ...:
//! official protobuf schemas, JPEG images, transforms and calibration, all
//! on capture time), so it opens in the Foxglove app with the shipped layout.
//!
//! ```no_run
//! use farsight_recording::{read::Recording, write::RecordingWriter};
//! use farsight_interfaces::{msg::{Pose, Stamp}, transport::wire};
//!
//! let mut w = RecordingWriter::create("run.mcap".as_ref(), true)?;
//! let pose = Pose { stamp: Stamp::new(1, 5), ..Default::default() };
//! w.write("state/pose", pose.stamp, 7, &wire::encode_message(&pose)?)?;
//! w.finish()?;
//! let info = Recording::open("run.mcap".as_ref())?.info()?;
//! assert_eq!(info.topics[0].count, 1);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! Writing is incremental: messages go into chunks that are closed when
//! they have been open 1 s or hold 1 MiB (by default; [`write`]), also
//! while no message arrives, so a recorder killed mid-run loses at most
//! its open chunk and leaves a file that reads (and replays) up to the
//! last closed one. A clean stop loses nothing.
//!
//! Reading is verified ([`mcap_file`]): a file that is not an MCAP file, or
//! is damaged (a bad chunk CRC), is an error naming the file and the byte
//! offset; a truncated one reads up to its last complete chunk and says
//! where it was cut.

pub mod diff;
pub mod mcap_file;
pub mod node;
pub use farsight_interfaces::pattern;
pub mod read;
pub mod record;
pub mod replay;
pub mod write;

/// Message encoding of farsight's own channels: the wire format.
pub const MESSAGE_ENCODING: &str = farsight_interfaces::transport::wire::MCAP_MESSAGE_ENCODING;

/// Errors of reading and writing recordings.
#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    // The cause is in the text, not a `source` (which `{:#}` would print
    // a second time).
    #[error("{path}: {error}")]
    Io { path: String, error: std::io::Error },
    #[error("{path}: {error}")]
    Mcap {
        path: String,
        error: mcap::McapError,
    },
    #[error("{0}")]
    Transport(#[from] farsight_interfaces::transport::TransportError),
    #[error("{0}")]
    Wire(#[from] farsight_interfaces::transport::wire::WireError),
    #[error("topic {topic:?}: {why}")]
    Topic { topic: String, why: String },
    /// Not an MCAP file, or a damaged one: names the file and the offset.
    #[error(transparent)]
    Damaged(#[from] mcap_file::McapDamage),
    /// A truncated file where a whole one is needed (a diff).
    #[error("{0}")]
    Truncated(mcap_file::Truncation),
}
