//! # farsight-inference
//!
//! Reads camera frames and turns them into what the navigation stages consume:
//! a per-pixel class id map with confidence, a navigability image (POVNav's
//! input, 255 = navigable), an affordance heatmap (LRN) or far-field
//! cost-class ensembles per image slice (FITAM).
//!
//! Backends:
//! - [`onnx`]: any ONNX model described by a [`model_config::ModelConfig`];
//! - [`hsv`]: colour thresholds (POVNav section 4.2's colour-based detection);
//! - [`normals`]: depth surface normals with the paper's clean-up.
//!
//! The library is plain functions over frames; `farsight-inference` (the
//! stage) and `farsight infer` (offline) both call [`Perception`] through
//! [`Backend::run`], so a model checked offline behaves the same on the robot.

pub mod class_table;
pub mod hsv;
pub mod model_config;
pub mod normals;
pub mod onnx;
pub mod postprocess;
pub mod preprocess;
pub mod stage;

use class_table::ClassTable;
use farsight_interfaces::msg::ImageHeader;
use model_config::OutputKind;
use onnx::{InferError, OnnxModel, Timings};
use postprocess::{ClassMap, PostprocessError};

/// What one frame produced. Images are `width` x `height` (the model's output
/// size), covering the whole camera frame.
#[derive(Debug, Clone, Default)]
pub struct Perception {
    pub width: usize,
    pub height: usize,
    pub classes: Option<ClassMap>,
    /// 255 = navigable, 0 = not.
    pub navigability: Option<Vec<u8>>,
    pub heatmap: Option<Vec<f32>>,
    /// `[slices, radial bins, members, classes]` logits.
    pub far_field: Option<([usize; 4], Vec<f32>)>,
}

/// Why a frame produced no output. The stage counts and logs these and
/// publishes nothing for the frame.
#[derive(Debug, thiserror::Error)]
pub enum FrameError {
    #[error(transparent)]
    Infer(#[from] InferError),
    #[error(transparent)]
    Post(#[from] PostprocessError),
    #[error("outputs disagree on size: {0}x{1} vs {2}x{3}")]
    SizeMismatch(usize, usize, usize, usize),
}

impl Perception {
    fn set_size(&mut self, w: usize, h: usize) -> Result<(), FrameError> {
        if self.width == 0 {
            (self.width, self.height) = (w, h);
        } else if (self.width, self.height) != (w, h) {
            return Err(FrameError::SizeMismatch(self.width, self.height, w, h));
        }
        Ok(())
    }

    /// Turns raw model outputs into a perception result; the class table maps
    /// class ids to navigability when the model gives classes.
    pub fn from_outputs(
        outputs: &[(&model_config::OutputSpec, Vec<usize>, &[f32])],
        table: Option<&ClassTable>,
    ) -> Result<Self, FrameError> {
        let mut p = Perception::default();
        for (spec, shape, data) in outputs {
            match spec.kind {
                OutputKind::ClassLogits | OutputKind::ClassProbabilities => {
                    let m = postprocess::class_map(spec, shape, data)?;
                    p.set_size(m.width, m.height)?;
                    if let Some(t) = table {
                        p.navigability = Some(t.navigability(&m.ids));
                    }
                    p.classes = Some(m);
                }
                OutputKind::DrivableMask => {
                    let (w, h, mask) = postprocess::drivable_mask(spec, shape, data)?;
                    p.set_size(w, h)?;
                    p.navigability = Some(mask);
                }
                OutputKind::AffordanceHeatmap => {
                    let (w, h, v) = postprocess::heatmap(spec, shape, data)?;
                    p.set_size(w, h)?;
                    p.heatmap = Some(v);
                }
                OutputKind::FarFieldEnsemble => {
                    let s = postprocess::far_field(spec, shape, data)?;
                    p.far_field = Some((s, data.to_vec()));
                }
            }
        }
        Ok(p)
    }
}

/// A loaded backend.
pub enum Backend {
    Onnx(Box<OnnxModel>),
}

impl Backend {
    /// Runs one frame through the backend.
    pub fn run(
        &mut self,
        header: &ImageHeader,
        frame: &[u8],
        table: Option<&ClassTable>,
        timings: &mut Timings,
    ) -> Result<Perception, FrameError> {
        match self {
            Backend::Onnx(model) => model.run(header, frame, timings, |outputs| {
                Perception::from_outputs(outputs, table)
            })?,
        }
    }
}
