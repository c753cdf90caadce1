//! # farsight-subgoal-selection
//!
//! Picks where the robot should head next, from perception in image space:
//!
//! - [`povnav`]: POVNav (sections 4.3-4.7): visual horizon of the navigability
//!   image, peripheral optic goal, Pareto-optimal horizon optic goal, the visual
//!   path of Algorithm 1 and the proximity/alignment servo features.
//! - [`lrn_head`]: LRN's goal-conditioned heading choice over angular bins.
//! - [`dstar_lite`]: D* Lite (and A*) on the fused FITAM costmap, and
//!   [`planner`], its world-fixed grid for the stage.
//! - [`hip`]: HIP's trajectory library scored by eq. (1).
//! - [`subgoal_stage`]: the stage itself ([`subgoal_stage::SubgoalStage`]),
//!   one step per input over plain messages, on the stage runtime.
//!
//! Plain functions over plain data; the stage runtime wires the stage to
//! the bus.

pub mod dstar_lite;
pub mod hip;
pub mod lrn_head;
pub mod planner;
pub mod povnav;
pub mod stage;
pub mod subgoal_stage;
pub mod vmpp;
