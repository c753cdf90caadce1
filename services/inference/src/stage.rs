//! The inference stage's config (`inference.toml`, defaults shown):
//!
//! ```toml
//! camera = "front"               # reads camera/<camera>/image
//! backend = "onnx"               # only "onnx" in this version
//! model_config = "models/twinlitenet.toml"   # relative to this file
//! class_table = ""               # overrides the model config's class table
//! class_table_poll_s = 1.0       # how often the class table file is checked for edits
//! health_rate_hz = 1.0
//! ```

use farsight_stage::{ConfigError, Validate};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct InferenceConfig {
    pub camera: String,
    pub backend: String,
    pub model_config: String,
    pub class_table: String,
    pub class_table_poll_s: f64,
    pub health_rate_hz: f64,
}

impl Default for InferenceConfig {
    fn default() -> Self {
        Self {
            camera: "front".into(),
            backend: "onnx".into(),
            model_config: "models/twinlitenet.toml".into(),
            class_table: String::new(),
            class_table_poll_s: 1.0,
            health_rate_hz: 1.0,
        }
    }
}

impl Validate for InferenceConfig {
    fn validate(&self) -> Result<(), ConfigError> {
        farsight_interfaces::topics::validate_name(&self.camera)
            .map_err(|e| ConfigError::invalid("camera", &self.camera, e.why))?;
        ConfigError::check(self.backend == "onnx", "backend", &self.backend, "\"onnx\"")?;
        ConfigError::check(
            !self.model_config.is_empty(),
            "model_config",
            "\"\"",
            "the path of a model config TOML",
        )?;
        ConfigError::check(
            self.class_table_poll_s > 0.0,
            "class_table_poll_s",
            self.class_table_poll_s,
            "a positive period in seconds",
        )?;
        ConfigError::check(
            self.health_rate_hz > 0.0,
            "health_rate_hz",
            self.health_rate_hz,
            "a positive rate in Hz",
        )
    }
}
