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
//! stage, [`inference_stage::InferenceStage`]) and `farsight infer`
//! (offline) both call [`Perception`] through [`Backend::run`], so a model
//! checked offline behaves the same on the robot.

pub mod class_table;
pub mod hsv;
pub mod inference_stage;
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
    /// HIP: log q(tau | o) per library trajectory.
    pub trajectory_log_q: Option<Vec<f32>>,
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
    #[error(transparent)]
    Frame(#[from] preprocess::PreprocessError),
    #[error("no camera model received yet on camera/<name>/info: depth cannot be turned into normals without it")]
    NoCamera,
    #[error("depth image: {0}")]
    Depth(String),
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
                OutputKind::TrajectoryLogLikelihood => {
                    p.trajectory_log_q = Some(postprocess::trajectory_log_q(spec, shape, data)?);
                }
            }
        }
        Ok(p)
    }
}

/// A loaded backend.
pub enum Backend {
    /// A model described by a model config.
    Onnx(Box<OnnxModel>),
    /// Colour thresholds on the camera frame.
    Hsv(Vec<hsv::HsvRange>),
    /// Surface normals of the depth image; needs the camera's model and mount.
    Normals(
        normals::NormalsConfig,
        Option<Box<farsight_interfaces::camera::Camera>>,
        Option<Box<normals::RayTable>>,
    ),
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
            Backend::Hsv(ranges) => {
                let t = std::time::Instant::now();
                let nav = hsv::navigability(header, frame, ranges)?;
                timings.inference_s = t.elapsed().as_secs_f64();
                Ok(Perception {
                    width: header.width as usize,
                    height: header.height as usize,
                    navigability: Some(nav),
                    ..Default::default()
                })
            }
            Backend::Normals(cfg, camera, rays) => {
                let camera = camera.as_deref().ok_or(FrameError::NoCamera)?;
                let t = std::time::Instant::now();
                let depth = depth_metres(header, frame, cfg.depth_scale_m)?;
                let (w, h) = (header.width as usize, header.height as usize);
                if !rays.as_ref().is_some_and(|r| r.fits(camera, w, h)) {
                    *rays = Some(Box::new(normals::RayTable::new(camera, w, h)));
                }
                let table = rays.as_deref().expect("just built");
                let nav = normals::navigability_with_rays(&depth, table, cfg);
                timings.inference_s = t.elapsed().as_secs_f64();
                Ok(Perception {
                    width: w,
                    height: h,
                    navigability: Some(nav),
                    ..Default::default()
                })
            }
        }
    }
}

impl Backend {
    /// Runs several frames (one per camera): through one `session.run` when
    /// an onnx model batches, else one after another. Each frame gets its
    /// own result, in order; `timings` covers them all.
    pub fn run_batch(
        &mut self,
        frames: &[(&ImageHeader, &[u8])],
        table: Option<&ClassTable>,
        timings: &mut Timings,
    ) -> Vec<Result<Perception, FrameError>> {
        match self {
            Backend::Onnx(model) => model
                .run_batch(frames, timings, |_, outputs| {
                    Perception::from_outputs(outputs, table)
                })
                .into_iter()
                .map(|r| r.map_err(FrameError::from).and_then(|p| p))
                .collect(),
            _ => {
                let mut total = Timings::default();
                let results = frames
                    .iter()
                    .map(|(h, f)| {
                        // Fresh per frame: one that fails early leaves none
                        // of an earlier frame's time behind.
                        let mut t = Timings::default();
                        let r = self.run(h, f, table, &mut t);
                        total += t;
                        r
                    })
                    .collect();
                *timings = total;
                results
            }
        }
    }
}

/// Depth in metres from a MONO16 (times `scale_m`) or F32 (metres) image; 0 = no data.
pub fn depth_metres(
    header: &ImageHeader,
    data: &[u8],
    scale_m: f32,
) -> Result<Vec<f32>, FrameError> {
    use farsight_interfaces::msg::PixelEncoding;
    header
        .validate(data.len())
        .map_err(|e| FrameError::Depth(e.to_string()))?;
    let (w, h, stride) = (
        header.width as usize,
        header.height as usize,
        header.stride_bytes as usize,
    );
    let mut out = Vec::with_capacity(w * h);
    for row in 0..h {
        let line = &data[row * stride..];
        match header.encoding {
            PixelEncoding::MONO16 => out.extend(
                line[..w * 2]
                    .chunks_exact(2)
                    .map(|b| u16::from_le_bytes([b[0], b[1]]) as f32 * scale_m),
            ),
            PixelEncoding::F32 => out.extend(
                line[..w * 4]
                    .chunks_exact(4)
                    .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            ),
            e => {
                return Err(FrameError::Depth(format!(
                    "{e} is not a depth encoding (mono16 or f32)"
                )))
            }
        }
    }
    Ok(out)
}
