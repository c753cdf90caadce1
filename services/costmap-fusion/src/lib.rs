//! # farsight-costmap-fusion
//!
//! FITAM's map (section IV-D) and HIP's cost combination (section II):
//!
//! - [`grid`]: a world-frame grid that scrolls with the robot;
//! - [`kalman`]: the per-cell far-field filter;
//! - [`swath`]: polar bins rasterised into the cells they cover;
//! - [`labels`]: FITAM's far-field label rule over a swath's cells;
//! - [`map`]: the fused map: fixed near-field cells, Kalman far-field cells,
//!   the planning cost, and costmap messages for each layer;
//! - [`near_field`]: depth images and class maps -> fixed near-field cells;
//! - [`hip`]: HIP's scaling of a geometric costmap and its phi-weighted sum
//!   with a learned cost;
//! - [`fusion_stage`]: the stage that runs all of it per input (its binary is
//!   only the wiring), with `farsight_stage::CameraModels` keeping each
//!   near-field camera's newest model.
//!
//! ```
//! use farsight_costmap_fusion::{kalman::FarFieldConfig, map::FusionMap, swath::PolarGeometry};
//! use farsight_interfaces::msg::PolarCell;
//!
//! let geometry = PolarGeometry::fitam_default();
//! let mut map = FusionMap::new(201, 201, 1.0, FarFieldConfig::default());
//! map.recenter(0.0, 0.0);
//! // Every bin says "road" (0.235 s/m) with variance 0.1.
//! let road = PolarCell { cost_s_per_m: 0.235, variance: 0.1, class_id: 2, probability: 0.9 };
//! map.observe_far_field(&geometry, &vec![road; 32 * 3], 0.0, 0.0, 0.0);
//! map.add_process_noise();
//! let c = map.planning_cost(60, 0, true).unwrap(); // 60 m east
//! assert!(c < 0.5, "{c}");
//! ```

pub mod fusion_stage;
pub mod grid;
pub mod hip;
pub mod kalman;
pub mod labels;
pub mod map;
pub mod near_field;
pub mod stage;
pub mod swath;
