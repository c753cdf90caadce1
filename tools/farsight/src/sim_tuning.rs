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
        clock: ClockSource::Stamps,
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

/// The shipped models' configs (`cargo xtask train --ship`), relative to
/// the repository root.
pub const FITAM_MODEL: &str = "deploy/models/sim-fitam/model.toml";
pub const LRN_MODEL: &str = "deploy/models/sim-lrn/model.toml";

/// Where a shipped model is, looked for from the current folder up: the demo
/// and benchmark run from the repository root, tests from a crate's folder.
pub fn shipped_model(rel: &str) -> anyhow::Result<std::path::PathBuf> {
    let cwd = std::env::current_dir()?;
    let found = cwd.ancestors().map(|a| a.join(rel)).find(|p| p.exists());
    found.ok_or_else(|| {
        anyhow::anyhow!(
            "{rel} is in neither {} nor a folder above it: run from the farsight \
             repository (`cargo xtask train --ship` writes the models)",
            cwd.display()
        )
    })
}

/// LRN's bins for the shipped model: its heatmap peaks near 0.5-0.65 (a
/// sigmoid trained on rare, blurred hotspots), so the paper's h_thresh 0.7
/// applies to bin sums relative to the best bin, not to pixels, where it
/// would leave no bin at all.
pub fn lrn_bins() -> farsight_bin_projection::LrnBinsConfig {
    farsight_bin_projection::LrnBinsConfig {
        threshold_on: farsight_bin_projection::ThresholdOn::Bins,
        ..Default::default()
    }
}

/// LRN as the demo runs it: the shipped affordance model's bins, the
/// subgoal stage's head (Spot preset) on the stamps' clock.
pub fn lrn_subgoal_selection() -> SubgoalStageConfig {
    SubgoalStageConfig {
        method: "lrn".into(),
        clock: ClockSource::Stamps,
        ..Default::default()
    }
}

/// FITAM's fusion: the default 201 m window, so the far field's 100 m
/// predictions fit, on the stamps' clock.
pub fn fitam_costmap_fusion() -> FusionStageConfig {
    FusionStageConfig {
        clock: ClockSource::Stamps,
        ..Default::default()
    }
}

/// A config as the TOML file a stage reads.
pub fn to_toml<T: serde::Serialize>(config: &T) -> anyhow::Result<String> {
    Ok(toml::to_string(config)?)
}
