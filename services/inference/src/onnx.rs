//! ONNX Runtime backend: the runtime library is loaded dynamically (path from
//! `ORT_DYLIB_PATH`, which `cargo xtask setup` provides), the model's real input
//! and output shapes are checked against its config at load, and a mismatch is
//! refused with both shapes in the message.

use crate::model_config::{ExecutionProvider, Layout, ModelConfig, OutputKind, OutputSpec};
use crate::preprocess::{PreprocessError, Preprocessor};
use farsight_interfaces::msg::ImageHeader;
use ort::session::Session;
use ort::value::{TensorRef, ValueType};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::time::Instant;

/// A model that cannot be loaded or does not match its config.
#[derive(Debug, thiserror::Error)]
pub enum LoadError {
    #[error("ONNX Runtime library not found: set ORT_DYLIB_PATH (`cargo xtask setup` fetches the library and prints its path)")]
    NoRuntimePath,
    #[error("loading ONNX Runtime from {path}: {detail}")]
    Runtime { path: String, detail: String },
    #[error("model file {0} does not exist")]
    MissingModel(String),
    #[error("loading model {path}: {detail}")]
    Session { path: String, detail: String },
    #[error("execution provider \"{}\" is not available in this ONNX Runtime ({detail}); use a build with it (e.g. the onnxruntime-gpu wheel) or execution_provider = \"cpu\"", provider.name())]
    Provider {
        provider: ExecutionProvider,
        detail: String,
    },
    #[error("model {path} has no {what} named '{name}' (it has {available:?})")]
    NoSuchTensor {
        path: String,
        what: &'static str,
        name: String,
        available: Vec<String>,
    },
    #[error(
        "model {what} '{name}' has shape {model:?} but the model config says {config} ({hint})"
    )]
    ShapeMismatch {
        what: &'static str,
        name: String,
        model: Vec<i64>,
        config: String,
        hint: String,
    },
    #[error("model {what} '{name}' is {ty}, farsight feeds and reads float32 tensors")]
    NotFloat {
        what: &'static str,
        name: String,
        ty: String,
    },
}

/// A frame that could not be run through the model.
#[derive(Debug, thiserror::Error)]
pub enum InferError {
    #[error(transparent)]
    Preprocess(#[from] PreprocessError),
    #[error("onnx runtime: {0}")]
    Run(String),
    #[error("input '{0}' wants the robot's past positions and none were given for this frame")]
    NoPast(String),
}

static RUNTIME: OnceLock<Result<ort::environment::Environment, String>> = OnceLock::new();

/// The process's ONNX Runtime, loaded once from `lib` or `ORT_DYLIB_PATH`.
pub fn runtime(lib: Option<&Path>) -> Result<&'static ort::environment::Environment, LoadError> {
    let path: PathBuf = match lib {
        Some(p) => p.to_path_buf(),
        None => std::env::var_os("ORT_DYLIB_PATH")
            .filter(|p| !p.is_empty())
            .map(PathBuf::from)
            .ok_or(LoadError::NoRuntimePath)?,
    };
    let env = RUNTIME.get_or_init(|| {
        if !path.exists() {
            return Err(format!("{} does not exist", path.display()));
        }
        ort::init_from(&path)
            .map_err(|e| e.to_string())?
            .with_name("farsight")
            .build()
            .map_err(|e| e.to_string())
    });
    env.as_ref().map_err(|detail| LoadError::Runtime {
        path: path.display().to_string(),
        detail: detail.clone(),
    })
}

/// Per-frame timings of the three phases, seconds.
#[derive(Debug, Clone, Copy, Default)]
pub struct Timings {
    pub preprocess_s: f64,
    pub inference_s: f64,
    pub postprocess_s: f64,
}

impl std::ops::AddAssign for Timings {
    fn add_assign(&mut self, t: Timings) {
        self.preprocess_s += t.preprocess_s;
        self.inference_s += t.inference_s;
        self.postprocess_s += t.postprocess_s;
    }
}

/// A loaded model with its config and reusable input buffer.
pub struct OnnxModel {
    session: Session,
    config: ModelConfig,
    pre: Option<Preprocessor>,
    input: Vec<f32>,
    /// The model's own shape of each configured output (-1 = dynamic), in
    /// the config's order: the stage sizes its output buffers from them.
    output_shapes: Vec<Vec<i64>>,
    /// The input and every configured output have a dynamic leading (batch)
    /// dimension: several frames can go through one `session.run`.
    batches: bool,
    /// The past positions for the next frame (`past_input`), taken by the
    /// run that uses them so no frame runs with another frame's.
    past: Option<Vec<f32>>,
}

fn float_tensor_shape<'a>(
    what: &'static str,
    name: &str,
    ty: &'a ValueType,
) -> Result<&'a [i64], LoadError> {
    match ty {
        ValueType::Tensor {
            ty: ort::value::TensorElementType::Float32,
            shape,
            ..
        } => Ok(shape),
        other => Err(LoadError::NotFloat {
            what,
            name: name.to_string(),
            ty: format!("{other:?}"),
        }),
    }
}

/// The float32 shape of the model's input or output `name` (`what`), from
/// the model's `(name, type)` list, or an error naming what it has.
fn named_tensor_shape<'a>(
    path: &str,
    what: &'static str,
    name: &str,
    mut tensors: impl Iterator<Item = (&'a str, &'a ValueType)> + Clone,
) -> Result<&'a [i64], LoadError> {
    let Some((found, ty)) = tensors.clone().find(|(n, _)| *n == name) else {
        return Err(LoadError::NoSuchTensor {
            path: path.to_string(),
            what,
            name: name.to_string(),
            available: tensors.by_ref().map(|(n, _)| n.to_string()).collect(),
        });
    };
    float_tensor_shape(what, found, ty)
}

/// The rank of an output of `kind` with its leading batch dimension.
fn batched_rank(kind: OutputKind) -> usize {
    match kind {
        OutputKind::FarFieldEnsemble => 5,
        OutputKind::TrajectoryLogLikelihood => 2,
        _ => 4,
    }
}

/// `true` if a model dimension (-1 = dynamic) accepts `want`.
fn dim_ok(model: i64, want: i64) -> bool {
    model < 0 || model == want
}

/// Checks an output's rank and channel count against its config.
fn check_output(spec: &OutputSpec, shape: &[i64]) -> Result<(), LoadError> {
    let mismatch = |config: String, hint: &str| LoadError::ShapeMismatch {
        what: "output",
        name: spec.name.clone(),
        model: shape.to_vec(),
        config,
        hint: hint.to_string(),
    };
    match spec.kind {
        OutputKind::FarFieldEnsemble => {
            let want = spec.ensemble_shape.unwrap_or_default().map(|d| d as i64);
            let core = match shape {
                [1, rest @ ..] if rest.len() == 4 => rest,
                s => s,
            };
            if core.len() != 4 || core.iter().zip(want).any(|(&m, w)| !dim_ok(m, w)) {
                return Err(mismatch(
                    format!("{want:?}"),
                    "ensemble_shape = [slices, radial_bins, members, classes]",
                ));
            }
        }
        OutputKind::TrajectoryLogLikelihood => {
            let k = spec.classes as i64;
            let ok = match shape {
                [n] => dim_ok(*n, k),
                [b, n] => dim_ok(*b, 1) && dim_ok(*n, k),
                _ => false,
            };
            if !ok {
                return Err(mismatch(
                    format!("[1, {k}]"),
                    "classes = the trajectory library size K",
                ));
            }
        }
        _ => {
            let c = spec.classes as i64;
            let ok = match (shape.len(), spec.layout) {
                (4, Layout::Nchw) => dim_ok(shape[0], 1) && dim_ok(shape[1], c),
                (4, Layout::Nhwc) => dim_ok(shape[0], 1) && dim_ok(shape[3], c),
                (3, _) => c == 1 && dim_ok(shape[0], 1),
                _ => false,
            };
            if !ok {
                let cfg = match spec.layout {
                    Layout::Nchw => format!("[1, {c}, H, W]"),
                    Layout::Nhwc => format!("[1, H, W, {c}]"),
                };
                return Err(mismatch(
                    cfg,
                    &format!("outputs.layout = {:?}, outputs.classes = {c}", spec.layout),
                ));
            }
        }
    }
    Ok(())
}

impl OnnxModel {
    /// Loads the model of `config`, checking it against the config.
    pub fn load(config: &ModelConfig) -> Result<Self, LoadError> {
        let path = config.model_path();
        if !path.exists() {
            return Err(LoadError::MissingModel(path.display().to_string()));
        }
        let env = runtime(None)?;
        let shown = path.display().to_string();
        let session_err = |detail: String| LoadError::Session {
            path: shown.clone(),
            detail,
        };
        let mut builder = Session::builder(env).map_err(|e| session_err(e.to_string()))?;
        if config.threads > 0 {
            builder = builder
                .with_intra_threads(config.threads)
                .map_err(|e| session_err(e.to_string()))?;
        }
        let providers = match config.execution_provider {
            ExecutionProvider::Cpu => vec![],
            ExecutionProvider::Cuda => vec![ort::ep::CUDA::default().build().error_on_failure()],
            ExecutionProvider::Tensorrt => vec![
                ort::ep::TensorRT::default().build().error_on_failure(),
                ort::ep::CUDA::default().build().error_on_failure(),
            ],
        };
        if !providers.is_empty() {
            builder =
                builder
                    .with_execution_providers(providers)
                    .map_err(|e| LoadError::Provider {
                        provider: config.execution_provider,
                        detail: e.to_string(),
                    })?;
        }
        let session = builder
            .commit_from_file(&path)
            .map_err(|e| session_err(e.to_string()))?;

        let inputs = || session.inputs().iter().map(|i| (i.name(), i.dtype()));
        let outputs = || session.outputs().iter().map(|o| (o.name(), o.dtype()));
        let model_shape = named_tensor_shape(&shown, "input", &config.input.name, inputs())?;
        let want = config.input_shape();
        if model_shape.len() != 4 || model_shape.iter().zip(want).any(|(&m, w)| !dim_ok(m, w)) {
            return Err(LoadError::ShapeMismatch {
                what: "input",
                name: config.input.name.clone(),
                model: model_shape.to_vec(),
                config: format!("{want:?}"),
                hint: format!(
                    "input.layout = {:?}, input.width = {}, input.height = {}",
                    config.input.layout, config.input.width, config.input.height
                ),
            });
        }
        if let Some(past) = &config.past_input {
            let shape = named_tensor_shape(&shown, "input", &past.name, inputs())?;
            let want = 2 * past.points as i64;
            let ok = match shape {
                [b, n] => dim_ok(*b, 1) && dim_ok(*n, want),
                _ => false,
            };
            if !ok {
                return Err(LoadError::ShapeMismatch {
                    what: "input",
                    name: past.name.clone(),
                    model: shape.to_vec(),
                    config: format!("[1, {want}]"),
                    hint: format!("past_input.points = {} (x, y each)", past.points),
                });
            }
        }
        let mut output_shapes = Vec::with_capacity(config.outputs.len());
        for spec in &config.outputs {
            let shape = named_tensor_shape(&shown, "output", &spec.name, outputs())?;
            check_output(spec, shape)?;
            output_shapes.push(shape.to_vec());
        }
        let len = want.iter().product::<i64>() as usize;
        // Batching needs the batch dimension open on both sides: a model
        // exported for one frame ([1, ...]) runs its frames one at a time.
        // An output has a batch dimension only at its kind's full rank (a
        // far-field ensemble may come without one).
        let batches = model_shape[0] < 0
            && config.past_input.is_none()
            && config
                .outputs
                .iter()
                .zip(&output_shapes)
                .all(|(spec, s)| s.len() == batched_rank(spec.kind) && s[0] < 0);
        Ok(Self {
            session,
            config: config.clone(),
            pre: None,
            input: vec![0.0; len],
            output_shapes,
            batches,
            past: None,
        })
    }

    /// The robot's past positions for the next frame run, as `past_input`
    /// describes them (`2 * points` values, x and y, oldest first).
    pub fn set_past(&mut self, values: &[f32]) -> Result<(), InferError> {
        let Some(spec) = &self.config.past_input else {
            return Err(InferError::Run(
                "this model has no past_input to give positions to".into(),
            ));
        };
        if values.len() != 2 * spec.points {
            return Err(InferError::Run(format!(
                "{} past values for input '{}', which takes {} ({} points)",
                values.len(),
                spec.name,
                2 * spec.points,
                spec.points
            )));
        }
        if let Some(bad) = values.iter().find(|v| !v.is_finite()) {
            return Err(InferError::Run(format!(
                "past position {bad} for input '{}'",
                spec.name
            )));
        }
        self.past = Some(values.to_vec());
        Ok(())
    }

    pub fn config(&self) -> &ModelConfig {
        &self.config
    }

    /// The model's shape of each configured output, as the model declares
    /// it (-1 for a dynamic dimension), in the order of `config().outputs`.
    pub fn output_shapes(&self) -> &[Vec<i64>] {
        &self.output_shapes
    }

    /// Whether frames can go through the model several at a time (its input
    /// and outputs have a dynamic batch dimension).
    pub fn batches(&self) -> bool {
        self.batches
    }

    /// Runs one frame and hands each configured output's spec, shape and values
    /// to `post`, read in place from ONNX Runtime's buffers.
    pub fn run<R>(
        &mut self,
        header: &ImageHeader,
        frame: &[u8],
        timings: &mut Timings,
        post: impl FnOnce(&[(&OutputSpec, Vec<usize>, &[f32])]) -> R,
    ) -> Result<R, InferError> {
        let mut post = Some(post);
        self.run_batch(&[(header, frame)], timings, |_, views| {
            (post.take().expect("one frame, one call"))(views)
        })
        .pop()
        .expect("one frame, one result")
    }

    /// Runs `frames` through one `session.run` where the model batches
    /// ([`Self::batches`]), else one at a time in this session, and hands
    /// each frame's outputs to `post` with the frame's index. A frame the
    /// pre-processing refuses gets its own error and leaves the batch; the
    /// rest still run. `timings` covers the whole batch.
    pub fn run_batch<R>(
        &mut self,
        frames: &[(&ImageHeader, &[u8])],
        timings: &mut Timings,
        mut post: impl FnMut(usize, &[(&OutputSpec, Vec<usize>, &[f32])]) -> R,
    ) -> Vec<Result<R, InferError>> {
        let group = if self.batches { frames.len().max(1) } else { 1 };
        let mut total = Timings::default();
        let mut results = Vec::with_capacity(frames.len());
        for chunk in frames.chunks(group) {
            total += self.run_group(chunk, &mut post, &mut results);
        }
        *timings = total;
        results
            .into_iter()
            .map(|r| r.expect("every frame has a result"))
            .collect()
    }

    /// One `session.run` over `frames`, their results appended to `results`
    /// (whose length is the first frame's index).
    fn run_group<R>(
        &mut self,
        frames: &[(&ImageHeader, &[u8])],
        post: &mut impl FnMut(usize, &[(&OutputSpec, Vec<usize>, &[f32])]) -> R,
        results: &mut Vec<Option<Result<R, InferError>>>,
    ) -> Timings {
        let t0 = Instant::now();
        let pre = self
            .pre
            .get_or_insert_with(|| Preprocessor::new(&self.config.input));
        let per_frame = pre.len();
        // The input buffer grows to the largest batch seen (one frame per
        // camera): bounded by the config, not by what arrives.
        if self.input.len() < frames.len() * per_frame {
            self.input.resize(frames.len() * per_frame, 0.0);
        }
        let first = results.len();
        let mut batch: Vec<usize> = Vec::with_capacity(frames.len());
        // One frame per run where there is a past input (it turns batching
        // off), and never with an earlier frame's positions: taken here,
        // whatever becomes of the frame.
        let past = self.past.take();
        if let Some(spec) = &self.config.past_input {
            if past.is_none() {
                for _ in frames {
                    results.push(Some(Err(InferError::NoPast(spec.name.clone()))));
                }
                return Timings::default();
            }
        }
        for (i, (header, frame)) in frames.iter().enumerate() {
            let slot = &mut self.input[batch.len() * per_frame..(batch.len() + 1) * per_frame];
            match pre.run(header, frame, slot) {
                Ok(()) => {
                    batch.push(first + i);
                    results.push(None);
                }
                Err(e) => results.push(Some(Err(e.into()))),
            }
        }
        let t1 = Instant::now();
        let mut t2 = t1;
        if !batch.is_empty() {
            if let Err(e) = self.run_session(&batch, past.as_deref(), post, results, &mut t2) {
                for &i in &batch {
                    results[i] = Some(Err(InferError::Run(e.clone())));
                }
            }
        }
        Timings {
            preprocess_s: (t1 - t0).as_secs_f64(),
            inference_s: (t2 - t1).as_secs_f64(),
            postprocess_s: t2.elapsed().as_secs_f64(),
        }
    }

    /// The `session.run` of a batch already in the input buffer; each
    /// output is split into its frames. `ran` is set when the model is done.
    fn run_session<R>(
        &mut self,
        batch: &[usize],
        past: Option<&[f32]>,
        post: &mut impl FnMut(usize, &[(&OutputSpec, Vec<usize>, &[f32])]) -> R,
        results: &mut [Option<Result<R, InferError>>],
        ran: &mut Instant,
    ) -> Result<(), String> {
        let n = batch.len();
        let mut shape = self.config.input_shape().map(|d| d as usize);
        shape[0] = n;
        let len = shape.iter().product::<usize>();
        let tensor =
            TensorRef::from_array_view((shape, &self.input[..len])).map_err(|e| e.to_string())?;
        let outputs = match (&self.config.past_input, past) {
            (Some(spec), Some(values)) => {
                let p = TensorRef::from_array_view(([1usize, values.len()], values))
                    .map_err(|e| e.to_string())?;
                self.session.run(ort::inputs![
                    self.config.input.name.as_str() => tensor,
                    spec.name.as_str() => p
                ])
            }
            _ => self
                .session
                .run(ort::inputs![self.config.input.name.as_str() => tensor]),
        }
        .map_err(|e| e.to_string())?;
        *ran = Instant::now();
        let mut whole = Vec::with_capacity(self.config.outputs.len());
        for spec in &self.config.outputs {
            let value = outputs
                .get(spec.name.as_str())
                .ok_or_else(|| format!("output '{}' missing from the result", spec.name))?;
            let (s, data) = value
                .try_extract_tensor::<f32>()
                .map_err(|e| format!("output '{}': {e}", spec.name))?;
            let mut s: Vec<usize> = s.iter().map(|&d| d.max(0) as usize).collect();
            if n > 1 {
                // A batched output answers one frame per input frame.
                if s.first() != Some(&n) || data.len() % n != 0 {
                    return Err(format!(
                        "output '{}' has shape {s:?} for a batch of {n} frames",
                        spec.name
                    ));
                }
                s[0] = 1;
            }
            whole.push((spec, s, data));
        }
        for (k, &i) in batch.iter().enumerate() {
            let views: Vec<(&OutputSpec, Vec<usize>, &[f32])> = whole
                .iter()
                .map(|(spec, s, data)| {
                    let per = data.len() / n;
                    (*spec, s.clone(), &data[k * per..(k + 1) * per])
                })
                .collect();
            results[i] = Some(Ok(post(i, &views)));
        }
        Ok(())
    }
}
