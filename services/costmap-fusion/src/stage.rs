//! The costmap-fusion stage's config (`costmap-fusion.toml`, defaults shown):
//!
//! ```toml
//! width_cells = 201              # the window that scrolls with the robot
//! height_cells = 201             # (FITAM: 1 m cells, predictions out to 100 m)
//! resolution_m = 1.0
//! use_far_field = true           # false: the "no far-field" baseline
//! local_costmaps = ["local"]     # near-field costmaps from other systems: costmap/<name>
//!                                # (NaN cells = not observed; inf = lethal)
//! publish_rate_hz = 2.0          # costmap/fused, costmap/far_field, costmap/near_field
//! clock = "wall"                 # "stamps": publish once per input message instead of
//!                                # at publish_rate_hz (lock-step simulation, replays)
//! answer_far_field = false       # with "stamps": publish once per far field (bins/polar),
//!                                # the frame's near field (in first) folded in; near
//!                                # fields alone update the map without publishing it.
//!                                # Which of the two reaches the stage first is the
//!                                # scheduler's choice, so publishing on each gave the
//!                                # planner a different first map per run
//! input_deadline_s = 1.0         # on capture time: an older far field is left out of
//!                                # costmap/fused (FITAM with no far field); the pose and
//!                                # the near field (any one of its sources; the far field
//!                                # when none is configured) are required, and the maps
//!                                # keep the stamp of the oldest of them
//! health_rate_hz = 1.0
//!
//! [near_field]                   # see farsight_costmap_fusion::near_field::NearFieldConfig
//! depth_cameras = []             # camera/<name>/depth -> slope/step rules
//! depth_scale_m = 0.001          # metres per MONO16 depth unit
//! class_map_cameras = []         # perception/<name>/classes projected onto flat ground
//! class_table = ""               # class -> cost_s_per_m (required with class_map_cameras)
//! range_m = 25.0                 # FITAM's local sensing radius
//! max_step_m = 0.3               # a cell spanning more height is an obstacle
//! max_slope_deg = 30.0           # ground rising faster from a neighbour is an obstacle
//! free_cost_s_per_m = 0.5        # a seen cell without an obstacle (depth)
//! pixel_stride = 2
//!
//! [far_field]                    # see farsight_costmap_fusion::kalman::FarFieldConfig
//! initial_mean_s_per_m = 1.0
//! initial_variance = 0.4
//! process_noise = 0.001
//! variance_threshold = 0.4
//! unknown_cost_s_per_m = 1.0
//! ```

use crate::kalman::FarFieldConfig;
use crate::near_field::NearFieldConfig;
use farsight_interfaces::topics;
use farsight_stage::inputs::INPUT_DEADLINE_S;
use farsight_stage::ranges::RATE_HZ;
use farsight_stage::{ConfigError, Io, Need, Range, Ranges, Validate};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FusionStageConfig {
    pub width_cells: usize,
    pub height_cells: usize,
    pub resolution_m: f64,
    pub use_far_field: bool,
    pub local_costmaps: Vec<String>,
    pub publish_rate_hz: f64,
    pub clock: farsight_stage::ClockSource,
    pub health_rate_hz: f64,
    pub input_deadline_s: f64,
    pub answer_far_field: bool,
    pub near_field: NearFieldConfig,
    pub far_field: FarFieldConfig,
}

impl Default for FusionStageConfig {
    fn default() -> Self {
        Self {
            width_cells: 201,
            height_cells: 201,
            resolution_m: 1.0,
            use_far_field: true,
            local_costmaps: vec!["local".into()],
            publish_rate_hz: 2.0,
            clock: Default::default(),
            health_rate_hz: 1.0,
            input_deadline_s: farsight_stage::inputs::DEFAULT_INPUT_DEADLINE_S,
            answer_far_field: false,
            near_field: NearFieldConfig::default(),
            far_field: FarFieldConfig::default(),
        }
    }
}

impl Validate for FusionStageConfig {
    fn ranges(&self, r: &mut Ranges) {
        r.key("width_cells", self.width_cells, Range::between(3.0, 4001.0))
            .key(
                "height_cells",
                self.height_cells,
                Range::between(3.0, 4001.0),
            )
            .key(
                "resolution_m",
                self.resolution_m,
                Range::above_to(0.0, 100.0).unit("m"),
            )
            .key("publish_rate_hz", self.publish_rate_hz, RATE_HZ)
            .key("health_rate_hz", self.health_rate_hz, RATE_HZ)
            .key("input_deadline_s", self.input_deadline_s, INPUT_DEADLINE_S)
            .nested("near_field", &self.near_field)
            .nested("far_field", &self.far_field);
    }

    fn check_rules(&self) -> Result<(), ConfigError> {
        for c in &self.local_costmaps {
            ConfigError::check(
                !["fused", "far_field", "near_field"].contains(&c.as_str()),
                "local_costmaps",
                c,
                "the name of another system's costmap, not one this stage publishes",
            )?;
            farsight_interfaces::topics::validate_name(c)
                .map_err(|e| ConfigError::invalid("local_costmaps", c, e.why))?;
        }
        if self.answer_far_field {
            ConfigError::check(
                self.use_far_field && self.clock == farsight_stage::ClockSource::Stamps,
                "answer_far_field",
                true,
                "false unless use_far_field = true and clock = \"stamps\"",
            )?;
        }
        self.near_field.check_rules()?;
        self.far_field.check_rules()
    }
}

impl farsight_stage::DeclaresTopics for FusionStageConfig {
    fn topics(&self, instance: &str, _: &std::path::Path) -> Result<Io, String> {
        let mut io = Io::for_instance(instance);
        io.read(topics::pose().name(), Need::Required);
        let nf = &self.near_field;
        let near_sources =
            self.local_costmaps.len() + nf.depth_cameras.len() + nf.class_map_cameras.len();
        if self.use_far_field {
            // The far field alone drives the map only when nothing near does.
            // Answering the far field: without one, no map goes out.
            let need = if near_sources == 0 || self.answer_far_field {
                Need::Required
            } else {
                Need::Optional
            };
            io.read(topics::polar_bins().name(), need);
        }
        for c in &self.local_costmaps {
            io.read(topics::costmap(c).name(), Need::Required);
        }
        for c in &nf.depth_cameras {
            io.read(topics::depth(c).name(), Need::Required)
                .read(topics::camera_info(c).name(), Need::Required);
        }
        for c in &nf.class_map_cameras {
            io.read(topics::class_map(c).name(), Need::Required)
                .read(topics::camera_info(c).name(), Need::Required);
        }
        for layer in ["fused", "far_field", "near_field"] {
            io.write(topics::costmap(layer).name());
        }
        Ok(io)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_far_field_is_required_only_when_nothing_near_feeds_the_map() {
        use farsight_stage::DeclaresTopics;
        let need_of = |c: &FusionStageConfig, topic: &str| {
            let io = c.topics("fusion", std::path::Path::new(".")).unwrap();
            io.reads.iter().find(|r| r.topic == topic).map(|r| r.need)
        };
        let far_only = FusionStageConfig {
            local_costmaps: vec![],
            ..Default::default()
        };
        assert_eq!(need_of(&far_only, "bins/polar"), Some(Need::Required));
        let both = FusionStageConfig::default();
        assert_eq!(need_of(&both, "bins/polar"), Some(Need::Optional));
        assert_eq!(need_of(&both, "costmap/local"), Some(Need::Required));
        assert_eq!(need_of(&both, "state/pose"), Some(Need::Required));
        let near_only = FusionStageConfig {
            use_far_field: false,
            ..Default::default()
        };
        assert_eq!(need_of(&near_only, "bins/polar"), None);
        let io = both.topics("fusion", std::path::Path::new(".")).unwrap();
        assert_eq!(
            io.writes,
            [
                "health/fusion",
                "costmap/fused",
                "costmap/far_field",
                "costmap/near_field"
            ]
        );
    }

    #[test]
    fn bad_values_are_named() {
        let e =
            farsight_stage::parse_config::<FusionStageConfig>("resolution_m = -1.0\n", "t.toml")
                .unwrap_err()
                .to_string();
        assert!(e.contains("resolution_m") && e.contains("-1"), "{e}");
        let e = farsight_stage::parse_config::<FusionStageConfig>(
            "local_costmaps = [\"fused\"]\n",
            "t.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("local_costmaps"), "{e}");
        assert!(farsight_stage::parse_config::<FusionStageConfig>("", "t.toml").is_ok());
    }
}
