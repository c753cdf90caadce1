//! # farsight-sim
//!
//! The closed-loop simulator the demo and the navigation benchmark drive: the
//! papers evaluate in simulation too (FITAM's land-cover worlds, POVNav's
//! obstacle fields, HIP's forest, LRN's bug trap, bridge and bush wall).
//!
//! - [`world`]: land cover with FITAM's costs, obstacles, optional height;
//! - [`scenario`]: the named scenarios and random worlds, from a seed;
//! - [`render`]: a column ray-marching camera renderer: RGB, depth, class ids;
//! - [`robot`]: a unicycle with acceleration and terrain speed limits, collisions;
//! - [`sensor`]: the occlusion-aware 25 m near-field costmap;
//! - [`fitam_protocol`]: FITAM's kinematic sense-plan-act evaluation (section V);
//! - [`stall`]: HIP's stuck and trapped heuristics, for [`sticky`] and [`episode`]'s end-trial rule;
//! - [`sticky`]: HIP's data collection (sticky random actions) and its trajectory library;
//! - [`hip_dataset`]: the examples HIP's learned density trains on (a view and the future after it);
//! - [`episode`]: one drive: robot, metrics (reached, time, distance, cost,
//!   collisions, interventions) and the map PNG with the track.
//!
//! ```
//! use farsight_sim::{render::{Frame, Renderer}, scenario::scenario};
//! use farsight_interfaces::camera::{Camera, CameraModel, Mount};
//!
//! let s = scenario("bug-trap", 1).unwrap();
//! let cam = Camera::new(0, "front", CameraModel::pinhole(160, 90, 80.0, 80.0, 79.5, 44.5),
//!                       Mount::from_xyz_rpy_deg([0.0, 0.0, 1.0], [0.0; 3]));
//! let mut frame = Frame::default();
//! Renderer::new(&cam, 150.0).render(&s.world, s.start, &mut frame);
//! assert_eq!(frame.rgb.len(), 160 * 90 * 3);
//! ```

pub mod episode;
pub mod expert;
pub mod fitam_protocol;
pub mod hip_dataset;
pub mod labels;
pub mod render;
pub mod rng;
pub mod robot;
pub mod run;
pub mod scenario;
pub mod sensor;
pub mod sim_robot;
pub mod stall;
pub mod sticky;
pub mod world;
