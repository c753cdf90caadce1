//! The model config: a TOML file beside an ONNX model that says everything
//! needed to use it without code: input name, layout, size, resize, colour
//! order and normalisation, and what each output means.
//!
//! ```toml
//! model = "best.onnx"                # relative to this file
//! execution_provider = "cpu"         # "cpu", "cuda" or "tensorrt"
//! threads = 0                        # intra-op threads, 0 = ONNX Runtime's choice
//! class_table = "classes.toml"       # optional: class -> navigable/cost (POVNav)
//!
//! [input]
//! name = "images"
//! layout = "nchw"                    # or "nhwc"
//! width = 640
//! height = 360
//! resize = "bilinear"                # antialiased as PIL's BILINEAR, or "nearest"; the whole frame is resized (stretched)
//! color = "rgb"                      # or "bgr"
//! scale = 0.00392156862745098        # value = (pixel * scale - mean) / std
//! mean = [0.0, 0.0, 0.0]
//! std = [1.0, 1.0, 1.0]
//!
//! [[outputs]]
//! name = "da"
//! kind = "class_logits"              # class_logits | class_probabilities | drivable_mask
//!                                    # | affordance_heatmap | far_field_ensemble
//! layout = "nchw"
//! classes = 2
//! ```
//!
//! The whole frame is stretched to the input size (no crop or letterbox), so an
//! output pixel maps to the camera through the camera model scaled to the
//! output size, as bin projection and POVNav assume.

use farsight_stage::{ConfigError, Range, Ranges, Validate};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Layout {
    #[default]
    Nchw,
    Nhwc,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Resize {
    #[default]
    Bilinear,
    Nearest,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum ColorOrder {
    #[default]
    Rgb,
    Bgr,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum ExecutionProvider {
    #[default]
    Cpu,
    Cuda,
    Tensorrt,
}

impl ExecutionProvider {
    /// The name the model config spells it with.
    pub fn name(self) -> &'static str {
        match self {
            Self::Cpu => "cpu",
            Self::Cuda => "cuda",
            Self::Tensorrt => "tensorrt",
        }
    }
}

/// The model's image input.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputSpec {
    pub name: String,
    #[serde(default)]
    pub layout: Layout,
    pub width: u32,
    pub height: u32,
    #[serde(default)]
    pub resize: Resize,
    #[serde(default)]
    pub color: ColorOrder,
    #[serde(default = "one")]
    pub scale: f32,
    #[serde(default)]
    pub mean: [f32; 3],
    #[serde(default = "ones")]
    pub std: [f32; 3],
}

fn one() -> f32 {
    1.0
}
fn ones() -> [f32; 3] {
    [1.0; 3]
}
fn half() -> f32 {
    0.5
}

/// The robot's past positions as a model input (HIP's learner, section V:
/// "10 past timesteps"): `points` positions `step_s` apart before the
/// frame's capture time, oldest first, in the robot's frame at capture (x
/// ahead, y left, metres), flattened (x, y) into a `[1, 2 * points]`
/// tensor. The subgoal stage fills it from its pose history; the inference
/// stage, which has none, refuses a model that wants it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PastInputSpec {
    pub name: String,
    pub points: usize,
    pub step_s: f64,
}

/// What an output tensor means.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OutputKind {
    /// Per-pixel class scores before softmax: -> class id map + confidence.
    ClassLogits,
    /// Per-pixel class probabilities: -> class id map + confidence.
    ClassProbabilities,
    /// A drivable mask: 2 channels (argmax = 1 is drivable) or 1 channel
    /// thresholded (after `activation`).
    DrivableMask,
    /// LRN affordance heatmap, 1 channel, values in [0, 1] after `activation`.
    AffordanceHeatmap,
    /// FITAM far-field ensemble logits `[slices, radial bins, members, classes]`
    /// (a leading batch dimension of 1 is allowed).
    FarFieldEnsemble,
    /// HIP's learned density: log q(tau | observation) for each of the
    /// `classes` trajectories of the library, shape `[1, K]` or `[K]`.
    TrajectoryLogLikelihood,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Activation {
    #[default]
    None,
    Sigmoid,
}

/// One model output.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutputSpec {
    pub name: String,
    pub kind: OutputKind,
    /// Where the channel axis is, for image-like outputs.
    #[serde(default)]
    pub layout: Layout,
    /// Channels (classes) of image-like outputs.
    #[serde(default = "one_usize")]
    pub classes: usize,
    /// For 1-channel drivable masks: drivable where value > threshold.
    #[serde(default = "half")]
    pub threshold: f32,
    #[serde(default)]
    pub activation: Activation,
    /// Far-field ensembles: `[slices, radial_bins, members, classes]`.
    #[serde(default)]
    pub ensemble_shape: Option<[usize; 4]>,
}

fn one_usize() -> usize {
    1
}

/// A model config file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelConfig {
    pub model: PathBuf,
    #[serde(default)]
    pub execution_provider: ExecutionProvider,
    #[serde(default)]
    pub threads: usize,
    #[serde(default)]
    pub class_table: Option<PathBuf>,
    pub input: InputSpec,
    /// A second input: the robot's past positions (HIP's learned density).
    #[serde(default)]
    pub past_input: Option<PastInputSpec>,
    pub outputs: Vec<OutputSpec>,
    /// Directory of the config file; relative paths resolve against it.
    #[serde(skip)]
    pub base_dir: PathBuf,
}

impl ModelConfig {
    /// Loads and validates a model config; relative paths are resolved against its directory.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let mut c: ModelConfig = farsight_stage::load_config_file(path)?;
        c.base_dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
        Ok(c)
    }

    pub fn model_path(&self) -> PathBuf {
        self.base_dir.join(&self.model)
    }

    pub fn class_table_path(&self) -> Option<PathBuf> {
        self.class_table.as_ref().map(|p| self.base_dir.join(p))
    }

    /// The input tensor shape this config describes.
    pub fn input_shape(&self) -> [i64; 4] {
        let (w, h) = (self.input.width as i64, self.input.height as i64);
        match self.input.layout {
            Layout::Nchw => [1, 3, h, w],
            Layout::Nhwc => [1, h, w, 3],
        }
    }
}

impl Validate for ModelConfig {
    fn ranges(&self, r: &mut Ranges) {
        let i = &self.input;
        // threads 0: ONNX Runtime's choice.
        r.key("threads", self.threads, Range::between(0.0, 256.0));
        r.key(
            "input.width",
            i.width,
            Range::between(1.0, 8192.0).unit("px"),
        )
        .key(
            "input.height",
            i.height,
            Range::between(1.0, 8192.0).unit("px"),
        )
        .key("input.scale", i.scale, Range::finite())
        .each("input.mean", &i.mean, Range::finite())
        .each("input.std", &i.std, Range::above_to(0.0, 1e6));
        if let Some(p) = &self.past_input {
            r.key("past_input.points", p.points, Range::between(1.0, 100.0))
                .key(
                    "past_input.step_s",
                    p.step_s,
                    Range::above_to(0.0, 10.0).unit("s"),
                );
        }
        for (n, o) in self.outputs.iter().enumerate() {
            r.key(
                &format!("outputs[{n}].classes"),
                o.classes,
                Range::between(1.0, 65_536.0),
            )
            .key(
                &format!("outputs[{n}].threshold"),
                o.threshold,
                Range::finite(),
            );
            if let Some(shape) = &o.ensemble_shape {
                let name = format!("outputs[{n}].ensemble_shape");
                r.each(&name, shape, Range::between(1.0, 65_536.0));
            }
        }
    }

    fn check_rules(&self) -> Result<(), ConfigError> {
        let i = &self.input;
        ConfigError::check(
            !i.name.is_empty(),
            "input.name",
            "\"\"",
            "the model's input name",
        )?;
        ConfigError::check(i.scale != 0.0, "input.scale", i.scale, "a non-zero factor")?;
        ConfigError::check(
            !self.outputs.is_empty(),
            "outputs",
            "[]",
            "at least one [[outputs]] table",
        )?;
        for (n, o) in self.outputs.iter().enumerate() {
            let key = |k: &str| format!("outputs[{n}].{k}");
            ConfigError::check(
                !o.name.is_empty(),
                &key("name"),
                "\"\"",
                "the model's output name",
            )?;
            match o.kind {
                OutputKind::ClassLogits | OutputKind::ClassProbabilities => ConfigError::check(
                    (2..=256).contains(&o.classes),
                    &key("classes"),
                    o.classes,
                    "2..=256 classes",
                )?,
                OutputKind::DrivableMask => ConfigError::check(
                    matches!(o.classes, 1 | 2),
                    &key("classes"),
                    o.classes,
                    "1 (thresholded) or 2 (argmax)",
                )?,
                OutputKind::AffordanceHeatmap => {
                    ConfigError::check(o.classes == 1, &key("classes"), o.classes, "1 channel")?
                }
                OutputKind::TrajectoryLogLikelihood => ConfigError::check(
                    o.classes >= 1,
                    &key("classes"),
                    o.classes,
                    "the library size K (1 or more)",
                )?,
                OutputKind::FarFieldEnsemble => {
                    let ok = o.ensemble_shape.is_some_and(|s| s.iter().all(|&d| d > 0));
                    ConfigError::check(
                        ok,
                        &key("ensemble_shape"),
                        format!("{:?}", o.ensemble_shape),
                        "[slices, radial_bins, members, classes], all positive",
                    )?
                }
            }
        }
        let class_outputs = self
            .outputs
            .iter()
            .filter(|o| {
                matches!(
                    o.kind,
                    OutputKind::ClassLogits | OutputKind::ClassProbabilities
                )
            })
            .count();
        ConfigError::check(
            class_outputs <= 1,
            "outputs",
            class_outputs,
            "at most one class_logits/class_probabilities output",
        )?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TWIN: &str = r#"
model = "best.onnx"
[input]
name = "images"
width = 640
height = 360
scale = 0.00392156862745098
[[outputs]]
name = "da"
kind = "class_logits"
classes = 2
"#;

    #[test]
    fn parses_and_derives_the_input_shape() {
        let c: ModelConfig = farsight_stage::parse_config(TWIN, "m.toml").unwrap();
        assert_eq!(c.input_shape(), [1, 3, 360, 640]);
        assert_eq!(c.input.std, [1.0; 3]);
        assert_eq!(c.execution_provider, ExecutionProvider::Cpu);
    }

    #[test]
    fn bad_values_are_named() {
        let bad = TWIN.replace("scale = 0.00392156862745098", "std = [1.0, 0.0, 1.0]");
        let e = farsight_stage::parse_config::<ModelConfig>(&bad, "m.toml").unwrap_err();
        assert_eq!(
            e.to_string(),
            "config key `input.std[1]` = 0: expected 0 < x <= 1000000"
        );
        let bad = TWIN.replace("classes = 2", "classes = 1");
        let e = farsight_stage::parse_config::<ModelConfig>(&bad, "m.toml").unwrap_err();
        assert!(
            e.to_string()
                .starts_with("config key `outputs[0].classes` = 1"),
            "{e}"
        );
        let bad = TWIN.replace("kind = \"class_logits\"", "kind = \"segmentation\"");
        let e = farsight_stage::parse_config::<ModelConfig>(&bad, "m.toml").unwrap_err();
        assert!(
            e.to_string().contains("unknown variant `segmentation`"),
            "{e}"
        );
    }
}
