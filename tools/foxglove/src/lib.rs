//! farsight in Foxglove: the topics of the graph as Foxglove's well-known
//! messages ([`view`]), thinned to fit a link ([`throttle`]), served live
//! over the Foxglove WebSocket protocol ([`live`]).
//!
//! On the robot the server is read-only: it advertises no client-publish
//! capability, so nothing the app sends can reach the robot through it.
//! The WebSocket protocol has no authentication; on the robot the server
//! binds to 127.0.0.1 by default and a laptop reaches the robot through
//! zenoh, whose access control is the door. The laptop's server
//! (`farsight foxglove --connect`) takes the operator's goals, e-stop and
//! teleop from the app ([`operator`]) only when its zenoh login is the
//! operator's, the one login the robot's router lets command.

pub mod live;
pub mod operator;
pub mod throttle;
pub mod view;

pub use live::{serve_shm, serve_zenoh, LiveServer, OperatorInput, OperatorStats, ServeOptions};
pub use operator::{OperatorCommand, OperatorConfig};
pub use throttle::{Rate, Throttle};
pub use view::{FoxMessage, Out, View, ViewConfig};
