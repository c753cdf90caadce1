//! farsight in Foxglove: the topics of the graph as Foxglove's well-known
//! messages ([`view`]), thinned to fit a link ([`throttle`]), served live
//! over the Foxglove WebSocket protocol ([`live`]).
//!
//! The server is read-only: it advertises no client-publish capability, so
//! nothing the app sends can reach the robot through it. The WebSocket
//! protocol has no authentication; on the robot the server binds to
//! 127.0.0.1 by default and a laptop reaches the robot through zenoh,
//! whose access control is the door.

pub mod live;
pub mod throttle;
pub mod view;

pub use live::{serve_shm, serve_zenoh, LiveServer, ServeOptions};
pub use throttle::{Rate, Throttle};
pub use view::{FoxMessage, Out, View, ViewConfig};
