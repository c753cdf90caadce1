//! The inference stage's config (`inference.toml`, defaults shown):
//!
//! ```toml
//! camera = "front"               # reads camera/<camera>/image (camera/<camera>/depth for normals)
//! cameras = []                   # several cameras through one backend (one ONNX Runtime
//!                                # session, batched where the model's batch dimension is
//!                                # open); replaces `camera`. Each camera's own health goes
//!                                # out on health/<instance>-<camera>. Not for normals.
//! backend = "onnx"               # "onnx", "hsv" (colour thresholds) or "normals" (depth)
//! model_config = "models/twinlitenet.toml"   # onnx: relative to this file
//! class_table = ""               # onnx: overrides the model config's class table
//! class_table_poll_s = 1.0       # how often the class table file is checked for edits
//! health_rate_hz = 1.0
//! max_frame_px = 2073600         # hsv, normals: the largest camera frame (pixels,
//!                                # 1920 x 1080) whose navigability image can go out
//!
//! [[hsv.ranges]]                 # hsv: see farsight_inference::hsv
//! hue_deg = [20.0, 50.0]
//! saturation = [0.0, 0.35]
//! value = [0.35, 1.0]
//!
//! [normals]                      # normals: see farsight_inference::normals
//! max_tilt_deg = 20.0
//! step_px = 4
//! min_obstacle_px = 6
//! depth_scale_m = 0.001          # metres per unit of mono16 depth
//! ```

use crate::hsv::HsvRange;
use crate::normals::NormalsConfig;
use farsight_interfaces::topics;
use farsight_stage::ranges::RATE_HZ;
use farsight_stage::{ConfigError, Io, Need, Range, Ranges, Validate};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct InferenceConfig {
    pub camera: String,
    /// Several cameras served by one backend; empty: `camera` alone.
    pub cameras: Vec<String>,
    pub backend: String,
    pub model_config: String,
    pub class_table: String,
    pub class_table_poll_s: f64,
    pub health_rate_hz: f64,
    /// The hsv and normals backends' output is as large as the camera frame,
    /// which is not known at start, and an output's shared memory is
    /// allocated at start: this many pixels at most (an onnx model's output
    /// size comes from the model). A larger frame is dropped and counted,
    /// naming this key.
    pub max_frame_px: u64,
    pub hsv: HsvConfig,
    pub normals: NormalsConfig,
}

/// The colour ranges of the hsv backend.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HsvConfig {
    pub ranges: Vec<HsvRange>,
}

impl Default for InferenceConfig {
    fn default() -> Self {
        Self {
            camera: "front".into(),
            cameras: Vec::new(),
            backend: "onnx".into(),
            model_config: "models/twinlitenet.toml".into(),
            class_table: String::new(),
            class_table_poll_s: 1.0,
            health_rate_hz: 1.0,
            max_frame_px: 1920 * 1080,
            hsv: HsvConfig::default(),
            normals: NormalsConfig::default(),
        }
    }
}

impl Validate for InferenceConfig {
    fn ranges(&self, r: &mut Ranges) {
        r.key(
            "class_table_poll_s",
            self.class_table_poll_s,
            Range::above_to(0.0, 3600.0).unit("s"),
        )
        .key("health_rate_hz", self.health_rate_hz, RATE_HZ)
        // Up to the largest image farsight decodes (8192 x 8192).
        .key(
            "max_frame_px",
            self.max_frame_px,
            Range::between(1.0, 8192.0 * 8192.0).unit("px"),
        )
        .nested("normals", &self.normals);
        for (i, range) in self.hsv.ranges.iter().enumerate() {
            r.nested(&format!("hsv.ranges[{i}]"), range);
        }
    }

    fn check_rules(&self) -> Result<(), ConfigError> {
        farsight_interfaces::topics::validate_name(&self.camera)
            .map_err(|e| ConfigError::invalid("camera", &self.camera, e.why))?;
        let list = || format!("{:?}", self.cameras);
        if !self.cameras.is_empty() && self.camera != Self::default().camera {
            return Err(ConfigError::invalid(
                "camera",
                &self.camera,
                "left out when `cameras` lists the cameras",
            ));
        }
        for (i, c) in self.cameras.iter().enumerate() {
            farsight_interfaces::topics::validate_name(c)
                .map_err(|e| ConfigError::invalid(format!("cameras[{i}]"), c, e.why))?;
            ConfigError::check(
                !self.cameras[..i].contains(c),
                "cameras",
                list(),
                "each camera once",
            )?;
        }
        ConfigError::check(
            self.cameras.len() <= 1 || self.backend != "normals",
            "cameras",
            list(),
            "one camera with backend = \"normals\" (its camera model and ray table are per camera: run one instance per depth camera)",
        )?;
        match self.backend.as_str() {
            "onnx" => ConfigError::check(
                !self.model_config.is_empty(),
                "model_config",
                "\"\"",
                "the path of a model config TOML",
            ),
            "hsv" => {
                ConfigError::check(
                    !self.hsv.ranges.is_empty(),
                    "hsv.ranges",
                    "[]",
                    "at least one [[hsv.ranges]] table",
                )?;
                self.hsv.ranges.iter().try_for_each(|r| r.check_rules())
            }
            "normals" => Ok(()),
            other => Err(ConfigError::invalid(
                "backend",
                other,
                "\"onnx\", \"hsv\" or \"normals\"",
            )),
        }
    }
}

impl InferenceConfig {
    /// The cameras this instance serves: `cameras`, or `camera` alone.
    pub fn camera_names(&self) -> Vec<&str> {
        if self.cameras.is_empty() {
            vec![self.camera.as_str()]
        } else {
            self.cameras.iter().map(String::as_str).collect()
        }
    }

    /// The per-camera health topic of a camera in `cameras`; `None` for a
    /// single `camera`, whose health is the instance's.
    pub fn camera_health_topic(&self, instance: &str, camera: &str) -> Option<String> {
        (!self.cameras.is_empty()).then(|| {
            topics::health(&format!("{instance}-{camera}"))
                .name()
                .to_string()
        })
    }
}

impl farsight_stage::DeclaresTopics for InferenceConfig {
    fn topics(&self, instance: &str, config_dir: &std::path::Path) -> Result<Io, String> {
        let mut io = Io::for_instance(instance);
        for c in self.camera_names() {
            if let Some(t) = self.camera_health_topic(instance, c) {
                io.write(t);
            }
            self.camera_topics(c, config_dir, &mut io)?;
        }
        Ok(io)
    }
}

impl InferenceConfig {
    fn camera_topics(
        &self,
        c: &str,
        config_dir: &std::path::Path,
        io: &mut Io,
    ) -> Result<(), String> {
        use crate::model_config::{ModelConfig, OutputKind};
        match self.backend.as_str() {
            "normals" => {
                // The camera model gives the mount: no normals without it.
                io.read(topics::depth(c).name(), Need::Required)
                    .read(topics::camera_info(c).name(), Need::Required)
                    .write(topics::navigability(c).name());
            }
            "hsv" => {
                io.read(topics::camera_image(c).name(), Need::Required)
                    .write(topics::navigability(c).name());
            }
            _ => {
                io.read(topics::camera_image(c).name(), Need::Required);
                let model = ModelConfig::load(&config_dir.join(&self.model_config))
                    .map_err(|e| e.to_string())?;
                let has_table = !self.class_table.is_empty() || model.class_table_path().is_some();
                for o in &model.outputs {
                    match o.kind {
                        OutputKind::ClassLogits | OutputKind::ClassProbabilities => {
                            io.write(topics::class_map(c).name())
                                .write(topics::class_confidence(c).name());
                            if has_table {
                                io.write(topics::navigability(c).name());
                            }
                        }
                        OutputKind::DrivableMask => {
                            io.write(topics::navigability(c).name());
                        }
                        OutputKind::AffordanceHeatmap => {
                            io.write(topics::affordance_heatmap(c).name());
                        }
                        OutputKind::FarFieldEnsemble => {
                            io.write(topics::far_field_logits(c).name());
                        }
                        // Computed for HIP's planner, not published.
                        OutputKind::TrajectoryLogLikelihood => {}
                    }
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backend_settings_are_checked_by_name() {
        let e = farsight_stage::parse_config::<InferenceConfig>("backend = \"hsv\"", "i.toml")
            .unwrap_err();
        assert_eq!(
            e.to_string(),
            "config key `hsv.ranges` = []: expected at least one [[hsv.ranges]] table"
        );
        let e = farsight_stage::parse_config::<InferenceConfig>(
            "backend = \"normals\"\n[normals]\nstep_px = 0",
            "i.toml",
        )
        .unwrap_err();
        assert!(
            e.to_string()
                .starts_with("config key `normals.step_px` = 0"),
            "{e}"
        );
        let e = farsight_stage::parse_config::<InferenceConfig>("backend = \"yolo\"", "i.toml")
            .unwrap_err();
        assert!(
            e.to_string().contains("\"onnx\", \"hsv\" or \"normals\""),
            "{e}"
        );
    }
}
