//! # farsight-interfaces
//!
//! The contracts between farsight stages, in the one crate every binary links
//! (iceoryx2 requires shared-memory types to come from a single crate):
//!
//! - [`msg`]: the message types of every edge of the graph, each stamped with the
//!   frame it was derived from;
//! - [`topics`]: topic names and their iceoryx2 / zenoh spellings;
//! - [`camera`]: pinhole and fisheye camera models and mounts;
//! - [`geo`]: the local ENU frame that GPS goals are converted into;
//! - [`transport`]: publish / latest-value subscribe over iceoryx2 and zenoh;
//! - [`clock`]: injected time (wall clock on the robot, replay clock in tests);
//! - [`base`]: the base-side contract for velocity commands: obey each for
//!   its time-to-live from receipt, then stop.
//!
//! ```no_run
//! use farsight_interfaces::{msg::*, topics, transport::ipc::Bus};
//!
//! // Publisher side: write a 640x360 RGB frame straight into shared memory.
//! let bus = Bus::open("camera-ingest")?;
//! let frames = bus.slice_publisher(&topics::camera_image("front"), 640 * 360 * 3)?;
//! frames.publish_with(640 * 360 * 3, |pixels| {
//!     pixels.fill(128); // decode or capture straight into shared memory
//!     ImageHeader::packed(Stamp::new(0, 0), 0, 640, 360, PixelEncoding::RGB8)
//! })?;
//!
//! // Consumer side: read the newest frame in place.
//! let sub = bus.slice_subscriber(&topics::camera_image("front"))?;
//! if let Some(frame) = sub.latest()? {
//!     frame.header().validate(frame.data().len())?;
//! }
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub mod base;
pub mod camera;
pub mod clock;
pub mod fixed;
pub mod geo;
pub mod message;
pub mod msg;
pub mod pattern;
pub mod topics;
pub mod transport;
