//! The bin-projection stage's config (`bin-projection.toml`, defaults shown):
//!
//! ```toml
//! method = "lrn"                 # or "fitam"
//! cameras = ["front"]            # reads perception/<camera>/heatmap (lrn), .../navigability
//!                                # (lrn, bins.input = "navigability") or .../far_field
//!                                # (fitam), and camera/<camera>/info
//! input_deadline_s = 1.0         # a camera whose newest capture is this much older than
//!                                # the newest of any camera drops out of the bins
//! health_rate_hz = 1.0
//! join_cameras_by_frame = false  # true: one output per frame number, once every camera's
//!                                # input of that frame is in (lock-step simulation, whose
//!                                # cameras share frame numbers); false: one per input
//! [bins]                         # see farsight_bin_projection::LrnBinsConfig (Spot preset)
//! bin_width_deg = 5.0
//! h_thresh = 0.7
//! threshold_on = "pixels"        # or "bins"
//! alpha = 0.1
//! input = "heatmap"              # or "navigability": a segmentation's navigable pixels
//!                                # times their ground range (LRN IV-D's Traversability +
//!                                # Depth baseline)
//! range_cap_m = 100.0            # navigability: farther ground counts as this far
//! [fitam]                        # see farsight_bin_projection::fitam::FitamBinsConfig
//! heading_bins = 32
//! range_edges_m = [25.0, 50.0, 75.0, 100.0]
//! class_speeds_mps = [0.5, 2.25, 4.25]
//! variance = "max_probability"   # R = 1 - max p (reference code), or "entropy" (paper)
//! measurement = "most_likely_class"  # z = the argmax class's cost (FITAM), or
//!                                # "expected_cost": sum of p / speed (not the paper's)
//! # max_range_m = 50.0           # unset: every radial bin; set: bins from here out unmeasured
//! ```

use crate::fitam::FitamBinsConfig;
use crate::LrnBinsConfig;
use farsight_interfaces::topics;
use farsight_stage::inputs::INPUT_DEADLINE_S;
use farsight_stage::ranges::RATE_HZ;
use farsight_stage::{ConfigError, Io, Need, Ranges, Validate};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BinProjectionConfig {
    pub method: String,
    pub cameras: Vec<String>,
    pub input_deadline_s: f64,
    pub health_rate_hz: f64,
    /// One output per frame number, once every camera's input of that
    /// frame has arrived; otherwise one output per input. For lock-step
    /// runs, where the cameras' frames share numbers and the order several
    /// inference processes answer in must not change the bins.
    pub join_cameras_by_frame: bool,
    pub bins: LrnBinsConfig,
    pub fitam: FitamBinsConfig,
}

impl Default for BinProjectionConfig {
    fn default() -> Self {
        Self {
            method: "lrn".into(),
            cameras: vec!["front".into()],
            input_deadline_s: farsight_stage::inputs::DEFAULT_INPUT_DEADLINE_S,
            health_rate_hz: 1.0,
            join_cameras_by_frame: false,
            bins: LrnBinsConfig::default(),
            fitam: FitamBinsConfig::default(),
        }
    }
}

impl Validate for BinProjectionConfig {
    fn ranges(&self, r: &mut Ranges) {
        r.key("input_deadline_s", self.input_deadline_s, INPUT_DEADLINE_S)
            .key("health_rate_hz", self.health_rate_hz, RATE_HZ)
            .nested("bins", &self.bins)
            .nested("fitam", &self.fitam);
    }

    fn check_rules(&self) -> Result<(), ConfigError> {
        ConfigError::check(
            ["lrn", "fitam"].contains(&self.method.as_str()),
            "method",
            &self.method,
            "\"lrn\" or \"fitam\"",
        )?;
        ConfigError::check(
            !self.cameras.is_empty(),
            "cameras",
            "[]",
            "at least one camera name",
        )?;
        for c in &self.cameras {
            farsight_interfaces::topics::validate_name(c)
                .map_err(|e| ConfigError::invalid("cameras", c, e.why))?;
        }
        self.bins.check_rules()?;
        self.fitam.check_rules()
    }
}

impl BinProjectionConfig {
    /// The perception topic read from `camera`: FITAM's far-field tensor,
    /// or for LRN the heatmap or the navigability its bins are summed from.
    pub fn perception_topic(&self, camera: &str) -> String {
        if self.method == "fitam" {
            topics::far_field_logits(camera).name().to_string()
        } else if self.bins.input == crate::LrnInput::Navigability {
            topics::navigability(camera).name().to_string()
        } else {
            topics::affordance_heatmap(camera).name().to_string()
        }
    }
}

impl farsight_stage::DeclaresTopics for BinProjectionConfig {
    fn topics(&self, instance: &str, _: &std::path::Path) -> Result<Io, String> {
        let mut io = Io::for_instance(instance);
        for c in &self.cameras {
            // The cameras are one group: one fresh camera keeps the bins
            // going. Each is still a required edge: a camera nothing feeds
            // is a wiring mistake.
            io.read(self.perception_topic(c), Need::Required)
                .read(topics::camera_info(c).name(), Need::Required);
        }
        io.write(if self.method == "fitam" {
            topics::polar_bins().name().to_string()
        } else {
            topics::angular_bins().name().to_string()
        });
        Ok(io)
    }
}
