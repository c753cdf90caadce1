//! The stage configs the simulator's demo runs, in one place: the demo
//! writes them as the stages' TOML files, and the navigation benchmark runs
//! POVNav's library code with the same values, so a benchmark trial and a
//! demo run of the same seed drive the same track. Every stage runs on the
//! stamps' clock (`clock = "stamps"`: one output per input, time from the
//! capture times), so two runs of a seed drive the same track.
//!
//! What differs from the stages' defaults for POVNav, and why:
//! - POVNav's desired proximity (the paper's lambda* = 50 px) is for its
//!   robot's camera; on the simulator's 640x360, 120 degree camera a horizon
//!   pixel 20 px above the bottom centre is 1.2 m ahead, which is where the
//!   robot should stop closing in.
//! - The safety margin beside the footprint is 0.35 m: trees that have left
//!   the view beside the robot are still passed with room.
//!
//! D* Lite: a 121 m fused map (the 25 m near-field sensor and room to plan
//! round a trap), the subgoal 5 m along the path, the carrot tracker.

use farsight_costmap_fusion::stage::FusionStageConfig;
use farsight_subgoal_selection::stage::SubgoalStageConfig;
use farsight_velocity_servoing::stage::{ClockSource, ServoStageConfig, Track};

/// Camera frames (and control steps) per second of simulated time.
pub const RATE_HZ: f64 = 10.0;

/// The simulator's image size: the benchmark renders what the demo renders.
pub const IMAGE_SIZE: (u32, u32) = (640, 360);

pub fn povnav_subgoal_selection() -> SubgoalStageConfig {
    SubgoalStageConfig {
        method: "povnav".into(),
        camera: "front".into(),
        safety_margin_m: 0.35,
        ..Default::default()
    }
}

pub fn dstar_costmap_fusion() -> FusionStageConfig {
    FusionStageConfig {
        width_cells: 121,
        height_cells: 121,
        clock: ClockSource::Stamps,
        ..Default::default()
    }
}

pub fn dstar_subgoal_selection() -> SubgoalStageConfig {
    let mut c = SubgoalStageConfig {
        method: "dstar_lite".into(),
        subgoal_distance_m: 5.0,
        clock: ClockSource::Stamps,
        ..Default::default()
    };
    c.planner.margin_m = 30.0;
    c
}

pub fn dstar_servo() -> ServoStageConfig {
    ServoStageConfig {
        track: Track::Path,
        ..povnav_servo()
    }
}

pub fn povnav_servo() -> ServoStageConfig {
    let mut c = ServoStageConfig {
        output_rate_hz: RATE_HZ,
        clock: ClockSource::Stamps,
        subgoal_deadline_s: 2.0,
        ..Default::default()
    };
    c.servo.desired_proximity_px = 20.0;
    c.servo.max_linear_mps = 1.5;
    c.servo.goal_radius_m = 2.0;
    c
}

/// A config as the TOML file a stage reads.
pub fn to_toml<T: serde::Serialize>(config: &T) -> anyhow::Result<String> {
    Ok(toml::to_string(config)?)
}
