//! The inference stage as a library type ([`InferenceStage`]): the
//! perception of the papers farsight follows, one camera frame at a time.
//! Each frame (a depth image for the normals backend) goes through the
//! backend ([`Backend::run`], the same call `farsight infer` makes offline),
//! and what it produced goes out stamped with the frame's stamp and camera:
//!
//! - POVNav's navigability image (255 = navigable): a model's class map
//!   through the class table, a model's drivable mask, colour thresholds
//!   (hsv) or depth surface normals (normals); with a class map, the class
//!   ids and their confidence too;
//! - LRN's affordance heatmap;
//! - FITAM's far-field cost-class ensemble logits per image slice.
//!
//! A frame the backend cannot use (wrong size or encoding, non-finite model
//! output, no camera model yet for normals) is dropped and counted in the
//! stage's health, and nothing is published for it: a consumer never sees a
//! half-result. The class table file is polled for edits on the step, so an
//! operator's change takes effect without a restart.

use crate::class_table::ClassTableFile;
use crate::model_config::{InputSpec, ModelConfig, OutputKind, OutputSpec};
use crate::onnx::{OnnxModel, Timings};
use crate::stage::InferenceConfig;
use crate::{Backend, Perception};
use anyhow::Context;
use farsight_interfaces::message::{Image, Message, Tensor};
use farsight_interfaces::msg::{
    CameraInfo, HealthState, ImageHeader, PixelEncoding, Stamp, TensorHeader,
};
use farsight_interfaces::topics;
use farsight_stage::{HealthReport, Ports, Stage, StageEnv, StageKind, Step};
use std::time::Duration;

/// The inference stage: its backend, class table and ports.
pub struct InferenceStage {
    ports: Ports,
    /// Each camera's ports, in the config's order.
    cameras: Vec<CameraIo>,
    /// One backend for every camera: one ONNX Runtime session and thread
    /// pool, however many cameras.
    backend: Backend,
    table: Option<ClassTableFile>,
    timings: Timings,
    /// The newest camera model not yet handed to the normals backend: it
    /// may arrive on a step without a frame, and is used at the next frame.
    camera_info: Option<CameraInfo>,
    poll_ns: u64,
    last_poll_ns: Option<u64>,
    health_period_ns: u64,
    /// What to raise when a frame's result is larger than its output.
    size_hint: &'static str,
}

/// One camera's ports and, where the stage serves a `cameras` list, its
/// own health report.
struct CameraIo {
    port: PortIds,
    health: Option<CameraHealth>,
}

struct CameraHealth {
    port: usize,
    report: HealthReport,
    last_sent_ns: Option<u64>,
}

struct PortIds {
    frames: usize,
    camera_info: Option<usize>,
    classes: Option<usize>,
    confidence: Option<usize>,
    navigability: Option<usize>,
    heatmap: Option<usize>,
    far_field: Option<usize>,
}

/// What a backend can produce, and how large each output can be: an
/// output's shared memory is allocated at start, so its size must be known
/// before the first frame.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct OutputPlan {
    /// Pixels of the class id and confidence maps.
    classes_px: Option<usize>,
    navigability_px: Option<usize>,
    heatmap_px: Option<usize>,
    /// Values of the far-field ensemble tensor.
    far_field_len: Option<usize>,
}

impl OutputPlan {
    /// The hsv and normals backends: a navigability image the size of the
    /// frame, at most `max_frame_px` (the frame size is not known at start).
    fn frame(max_frame_px: u64) -> Self {
        Self {
            navigability_px: Some(max_frame_px as usize),
            ..Self::default()
        }
    }

    /// A model's outputs, by the same rules as the config's declared writes
    /// (`InferenceConfig::topics`): a class map gives navigability only
    /// through a class table. Sizes come from the model's output shapes
    /// (`shapes`, in the config's order); a dynamic height or width falls
    /// back to the model's input size.
    fn onnx(model: &ModelConfig, shapes: &[Vec<i64>], has_table: bool) -> Self {
        let grow = |slot: &mut Option<usize>, n: usize| *slot = Some(slot.unwrap_or(0).max(n));
        let mut plan = Self::default();
        for (i, spec) in model.outputs.iter().enumerate() {
            let px = || image_px(spec, shapes.get(i), &model.input);
            match spec.kind {
                OutputKind::ClassLogits | OutputKind::ClassProbabilities => {
                    grow(&mut plan.classes_px, px());
                    if has_table {
                        grow(&mut plan.navigability_px, px());
                    }
                }
                OutputKind::DrivableMask => grow(&mut plan.navigability_px, px()),
                OutputKind::AffordanceHeatmap => grow(&mut plan.heatmap_px, px()),
                // The output must have exactly this shape to be used.
                OutputKind::FarFieldEnsemble => grow(
                    &mut plan.far_field_len,
                    spec.ensemble_shape.unwrap_or_default().iter().product(),
                ),
                // Computed for HIP's planner, not published.
                OutputKind::TrajectoryLogLikelihood => {}
            }
        }
        plan
    }
}

/// Pixels of an image-like output of the model's `shape`; the input's when
/// the shape leaves height or width open (segmentation models answer at
/// their input's size).
fn image_px(spec: &OutputSpec, shape: Option<&Vec<i64>>, input: &InputSpec) -> usize {
    // An open leading (batch) dimension is one frame's worth.
    let fixed: Option<Vec<usize>> = shape.and_then(|s| {
        s.iter()
            .enumerate()
            .map(|(i, &d)| {
                if i == 0 && d < 0 {
                    Some(1)
                } else {
                    usize::try_from(d).ok()
                }
            })
            .collect()
    });
    fixed
        .and_then(|s| crate::postprocess::image_dims(spec, &s).ok())
        .map_or(input.width as usize * input.height as usize, |(h, w, _)| {
            h * w
        })
}

impl StageKind for InferenceStage {
    const KIND: &'static str = "inference";
    type Config = InferenceConfig;

    fn new(config: InferenceConfig, env: &StageEnv) -> anyhow::Result<Self> {
        let base = &env.config_dir;
        let (backend, model_table, plan, size_hint) = match config.backend.as_str() {
            "onnx" => {
                let model_config = ModelConfig::load(&base.join(&config.model_config))?;
                if let Some(past) = &model_config.past_input {
                    anyhow::bail!(
                        "{}: past_input {:?}: this stage has no pose history to feed it \
                         (a model of the robot's past positions runs in subgoal-selection, \
                         as HIP's hip_model)",
                        config.model_config,
                        past.name
                    );
                }
                // A model whose shapes do not match its config is refused
                // here, naming the tensor and both shapes.
                let model = OnnxModel::load(&model_config).context("loading the model")?;
                tracing::info!(model = %model_config.model_path().display(), "onnx backend");
                let has_table =
                    !config.class_table.is_empty() || model_config.class_table_path().is_some();
                let plan = OutputPlan::onnx(&model_config, model.output_shapes(), has_table);
                (
                    Backend::Onnx(Box::new(model)),
                    model_config.class_table_path(),
                    plan,
                    "the model's output shape",
                )
            }
            "hsv" => (
                Backend::Hsv(config.hsv.ranges.clone()),
                None,
                OutputPlan::frame(config.max_frame_px),
                "raise max_frame_px",
            ),
            _ => (
                Backend::Normals(config.normals, None, None),
                None,
                OutputPlan::frame(config.max_frame_px),
                "raise max_frame_px",
            ),
        };
        let table_path = if config.class_table.is_empty() {
            model_table
        } else {
            Some(base.join(&config.class_table))
        };
        let table = table_path
            .as_deref()
            .map(ClassTableFile::open)
            .transpose()?;
        let (ports, cameras) = declare_ports(&config, &env.instance, &plan);
        tracing::info!(
            backend = %config.backend,
            inputs = ?cameras.iter().map(|c| &ports.inputs[c.port.frames].topic).collect::<Vec<_>>(),
            batched = matches!(&backend, Backend::Onnx(m) if m.batches()),
            "inference config"
        );
        Ok(Self {
            ports,
            cameras,
            backend,
            table,
            timings: Timings::default(),
            camera_info: None,
            poll_ns: (config.class_table_poll_s * 1e9) as u64,
            last_poll_ns: None,
            health_period_ns: (1e9 / config.health_rate_hz) as u64,
            size_hint,
        })
    }
}

/// The stage's ports for `config` and what its backend produces: each
/// camera's inputs and outputs, and its health output for a `cameras` list.
fn declare_ports(
    config: &InferenceConfig,
    instance: &str,
    plan: &OutputPlan,
) -> (Ports, Vec<CameraIo>) {
    let mut ports = Ports {
        // Frames wake the step; the tick polls the class table and keeps
        // the health reports going while no frame comes.
        tick: Some(Duration::from_millis(200)),
        health_rate_hz: config.health_rate_hz,
        ..Ports::default()
    };
    let cameras = config
        .camera_names()
        .into_iter()
        .map(|c| {
            let health = config
                .camera_health_topic(instance, c)
                .map(|t| CameraHealth {
                    port: ports.output(t),
                    report: HealthReport::new(&format!("{instance}-{c}")),
                    last_sent_ns: None,
                });
            CameraIo {
                port: camera_ports(&mut ports, config, c, plan),
                health,
            }
        })
        .collect();
    (ports, cameras)
}

/// One camera's inputs and outputs.
fn camera_ports(
    ports: &mut Ports,
    config: &InferenceConfig,
    c: &str,
    plan: &OutputPlan,
) -> PortIds {
    // The normals backend reads depth and the camera model (its mount);
    // every other backend reads the camera frames.
    let normals = matches!(config.backend.as_str(), "normals");
    let frames = if normals {
        ports.waking_input(topics::depth(c).name())
    } else {
        ports.waking_input(topics::camera_image(c).name())
    };
    let camera_info = normals.then(|| ports.input(topics::camera_info(c).name()));
    // Image payloads are bytes: an f32 image is 4 bytes a pixel.
    let f32_bytes = core::mem::size_of::<f32>();
    PortIds {
        frames,
        camera_info,
        classes: plan
            .classes_px
            .map(|n| ports.slice_output(topics::class_map(c).name(), n)),
        confidence: plan
            .classes_px
            .map(|n| ports.slice_output(topics::class_confidence(c).name(), f32_bytes * n)),
        navigability: plan
            .navigability_px
            .map(|n| ports.slice_output(topics::navigability(c).name(), n)),
        heatmap: plan
            .heatmap_px
            .map(|n| ports.slice_output(topics::affordance_heatmap(c).name(), f32_bytes * n)),
        far_field: plan
            .far_field_len
            .map(|n| ports.slice_output(topics::far_field_logits(c).name(), f32_bytes * n)),
    }
}

impl Stage for InferenceStage {
    fn ports(&self) -> &Ports {
        &self.ports
    }

    fn step(&mut self, step: &mut Step<'_>) {
        // Nothing makes this stage degraded: a bad frame is a counted drop.
        step.health.set(HealthState::OK, "");
        if let Some(port) = self.cameras[0].port.camera_info {
            if let Some(info) = step.inbox.take::<CameraInfo>(port) {
                self.camera_info = Some(info);
            }
        }
        // Whichever wake it arrived on: an untaken frame is gone after the
        // step. Every camera's frame that is here goes in one batch.
        let mut frames: Vec<(usize, Image)> = Vec::new();
        for (k, cam) in self.cameras.iter_mut().enumerate() {
            if let Some(frame) = step.inbox.take::<Image>(cam.port.frames) {
                step.health.input();
                if let Some(h) = &mut cam.health {
                    h.report.set(HealthState::OK, "");
                    h.report.input();
                }
                frames.push((k, frame));
            }
        }
        if !frames.is_empty() {
            self.frames(&frames, step);
        }
        self.send_camera_health(step);
        self.poll_class_table(step.wall_ns);
    }
}

impl InferenceStage {
    /// Runs the frames of one step (`(camera index, frame)`) through the
    /// backend together and sends what each produced, or counts it dropped.
    fn frames(&mut self, frames: &[(usize, Image)], step: &mut Step<'_>) {
        if let (Backend::Normals(_, camera, _), Some(info)) =
            (&mut self.backend, self.camera_info.take())
        {
            match farsight_interfaces::camera::Camera::from_info(&info) {
                Ok(c) => *camera = Some(Box::new(c)),
                Err(e) => step.health.dropped(&format_args!("camera info: {e}")),
            }
        }
        let t = self.table.as_ref().map(|t| t.table());
        let inputs: Vec<(&ImageHeader, &[u8])> = frames
            .iter()
            .map(|(_, f)| (&f.header, f.data.as_slice()))
            .collect();
        let results = self.backend.run_batch(&inputs, t, &mut self.timings);
        // The latency runs to the end of the backend's work (its own
        // timings), as it did when the stage read the clock after it.
        let tm = &self.timings;
        let compute_ns = ((tm.preprocess_s + tm.inference_s + tm.postprocess_s) * 1e9) as u64;
        let done_ns = step.wall_ns.saturating_add(compute_ns);
        for ((k, frame), result) in frames.iter().zip(results) {
            let h = frame.header;
            let cam = &mut self.cameras[*k];
            let sent = match result {
                Ok(p) => Self::send(&self.ports, &cam.port, self.size_hint, &p, &h, step),
                Err(e) => {
                    step.health.dropped(&format_args!(
                        "{} frame {}: {e}",
                        self.ports.inputs[cam.port.frames].topic, h.stamp.frame_seq
                    ));
                    false
                }
            };
            if sent {
                step.health.output(h.stamp, done_ns);
            }
            if let Some(ch) = &mut cam.health {
                if sent {
                    ch.report.output(h.stamp, done_ns);
                } else {
                    ch.report.count_dropped();
                }
            }
        }
    }

    /// Sends one frame's result on its camera's outputs, all or nothing:
    /// a result larger than its output's memory drops the frame before any
    /// part of it goes out (counted and logged in the stage's health).
    fn send(
        ports: &Ports,
        port: &PortIds,
        size_hint: &str,
        p: &Perception,
        h: &ImageHeader,
        step: &mut Step<'_>,
    ) -> bool {
        let messages = Self::messages(port, p, h.stamp, h.camera_id);
        for (port, msg) in &messages {
            let out = &ports.outputs[*port];
            let bytes = payload_bytes(msg);
            if bytes > out.max_slice_bytes {
                step.health.dropped(&format_args!(
                    "publishing frame {}: {} needs {bytes} bytes, its output holds at most {} ({})",
                    h.stamp.frame_seq, out.topic, out.max_slice_bytes, size_hint
                ));
                return false;
            }
        }
        for (port, msg) in messages {
            step.out.send(port, msg);
        }
        true
    }

    /// Each camera's own health report, at the stage's health rate.
    fn send_camera_health(&mut self, step: &mut Step<'_>) {
        let now = step.wall_ns;
        for ch in self.cameras.iter_mut().filter_map(|c| c.health.as_mut()) {
            let due = ch
                .last_sent_ns
                .is_none_or(|t| now.saturating_sub(t) >= self.health_period_ns);
            if due {
                step.out.send(ch.port, ch.report.stamped(now));
                ch.last_sent_ns = Some(now);
            }
        }
    }

    /// The messages of one result, in the order they go out.
    fn messages(
        port: &PortIds,
        p: &Perception,
        stamp: Stamp,
        camera_id: u32,
    ) -> Vec<(usize, Message)> {
        let (w, h) = (p.width as u32, p.height as u32);
        let image = |enc, data: Vec<u8>| Image {
            header: ImageHeader::packed(stamp, camera_id, w, h, enc),
            data,
        };
        let mut out: Vec<(usize, Message)> = Vec::new();
        // Each output's port exists whenever the backend can produce it
        // (the plan follows the same rules as the backend).
        if let Some(c) = &p.classes {
            if let (Some(ids), Some(conf)) = (port.classes, port.confidence) {
                out.push((ids, image(PixelEncoding::MONO8, c.ids.clone()).into()));
                // An f32 image is 4 little-endian bytes a pixel.
                let bytes = bytemuck::cast_slice(&c.confidence).to_vec();
                out.push((conf, image(PixelEncoding::F32, bytes).into()));
            }
        }
        if let (Some(m), Some(port)) = (&p.navigability, port.navigability) {
            out.push((port, image(PixelEncoding::MONO8, m.clone()).into()));
        }
        if let (Some(hm), Some(port)) = (&p.heatmap, port.heatmap) {
            let bytes = bytemuck::cast_slice(hm).to_vec();
            out.push((port, image(PixelEncoding::F32, bytes).into()));
        }
        if let (Some((shape, data)), Some(port)) = (&p.far_field, port.far_field) {
            let dims = shape.map(|d| d as u32);
            let tensor = Tensor {
                header: TensorHeader::new(stamp, camera_id, &dims),
                data: data.clone(),
            };
            out.push((port, tensor.into()));
        }
        out
    }

    /// Reloads the class table file when it changed; a broken edit keeps
    /// the previous table.
    fn poll_class_table(&mut self, now_ns: u64) {
        let last = *self.last_poll_ns.get_or_insert(now_ns);
        if now_ns.saturating_sub(last) < self.poll_ns {
            return;
        }
        self.last_poll_ns = Some(now_ns);
        if let Some(t) = self.table.as_mut() {
            match t.poll() {
                Ok(true) => tracing::info!(reloads = t.reloads, "class table reloaded"),
                Ok(false) => {}
                Err(e) => {
                    tracing::error!("class table edit refused, keeping the previous table: {e}")
                }
            }
        }
    }
}

/// Bytes of a message's slice.
fn payload_bytes(msg: &Message) -> usize {
    match msg {
        Message::Image(m) => m.data.len(),
        Message::Tensor(m) => core::mem::size_of_val(m.data.as_slice()),
        _ => 0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use farsight_interfaces::camera::{Camera, CameraModel, Mount};
    use farsight_stage::runtime::{check_ports, Harness};
    use farsight_stage::{DeclaresTopics, Wake};
    use std::path::{Path, PathBuf};

    const HSV: &str = "backend = \"hsv\"\n[[hsv.ranges]]\nhue_deg = [100.0, 140.0]\nsaturation = [0.5, 1.0]\nvalue = [0.5, 1.0]\n";
    const IMAGE: &str = "camera/front/image";
    const NAV: &str = "perception/front/navigability";

    fn config(toml: &str) -> InferenceConfig {
        farsight_stage::parse_config(toml, "inference.toml").unwrap()
    }

    fn stage(toml: &str) -> Harness<InferenceStage> {
        let env = StageEnv {
            instance: "inference".into(),
            config_dir: ".".into(),
        };
        Harness::new(InferenceStage::new(config(toml), &env).unwrap())
    }

    fn stamp(seq: u64) -> Stamp {
        Stamp::new(seq, 1_000_000_000 * seq)
    }

    /// A `w` x 1 RGB8 frame: green (navigable for [`HSV`]) then red pixels.
    fn frame(seq: u64, green: usize, red: usize) -> Image {
        let w = (green + red) as u32;
        let mut data = Vec::new();
        (0..green).for_each(|_| data.extend([0, 255, 0]));
        (0..red).for_each(|_| data.extend([255, 0, 0]));
        Image {
            header: ImageHeader::packed(stamp(seq), 7, w, 1, PixelEncoding::RGB8),
            data,
        }
    }

    fn dropped(h: &Harness<InferenceStage>) -> u64 {
        h.health.report().dropped
    }

    #[test]
    fn a_good_frame_gives_its_navigability_carrying_its_stamp() {
        let mut h = stage(HSV);
        let wake = h.wake_on(IMAGE);
        h.put(IMAGE, frame(3, 2, 1));
        let out = h.step(wake, 5_000_000_000);
        assert_eq!(out.len(), 1, "{out:?}");
        let (topic, msg) = &out[0];
        assert_eq!(topic, NAV);
        let nav = Image::try_from(msg.clone()).unwrap();
        assert_eq!(nav.header.stamp, stamp(3), "the frame's stamp");
        assert_eq!(nav.header.camera_id, 7);
        assert_eq!(
            (nav.header.width, nav.header.height, nav.header.encoding),
            (3, 1, PixelEncoding::MONO8)
        );
        assert_eq!(nav.data, vec![255, 255, 0]);
        let r = h.health.report();
        assert_eq!((r.messages_in, r.messages_out, r.dropped), (1, 1, 0));
        assert_eq!(r.stamp.frame_seq, 3);
        assert_eq!(h.health.state(), HealthState::OK);
    }

    #[test]
    fn several_cameras_share_one_backend_each_with_its_outputs_and_health() {
        let toml = format!("cameras = [\"front\", \"rear\"]\n{HSV}");
        let mut h = stage(&toml);
        let io = config(&toml).topics("inference", Path::new(".")).unwrap();
        check_ports(&io, h.stage.ports()).unwrap();
        const REAR: &str = "camera/rear/image";
        let wake = h.wake_on(IMAGE);
        h.put(IMAGE, frame(3, 2, 1)).put(REAR, frame(4, 1, 2));
        let out = h.step(wake, 5_000_000_000);
        let topics: Vec<&str> = out.iter().map(|(t, _)| t.as_str()).collect();
        assert_eq!(
            topics,
            [
                NAV,
                "perception/rear/navigability",
                "health/inference-front",
                "health/inference-rear"
            ],
            "both frames in one step, then each camera's health"
        );
        let nav = |i: usize| Image::try_from(out[i].1.clone()).unwrap();
        assert_eq!(
            (nav(0).header.stamp, nav(0).data.clone()),
            (stamp(3), vec![255, 255, 0])
        );
        assert_eq!(
            (nav(1).header.stamp, nav(1).data.clone()),
            (stamp(4), vec![255, 0, 0])
        );
        let camera_health = |out: &[(String, Message)], topic: &str| {
            let (_, m) = out.iter().find(|(t, _)| t == topic).unwrap();
            match m {
                Message::Health(r) => *r,
                other => panic!("{topic}: {other:?}"),
            }
        };
        let front = camera_health(&out, "health/inference-front");
        assert_eq!(front.stage.as_str(), "inference-front");
        assert_eq!(
            (front.messages_in, front.messages_out, front.stamp.frame_seq),
            (1, 1, 3)
        );
        // A bad rear frame is the rear camera's drop, and the stage's.
        let mut short = frame(5, 2, 2);
        short.data.truncate(9);
        h.put(REAR, short);
        let out = h.step(h.wake_on(REAR), 5_500_000_000);
        assert!(
            out.is_empty(),
            "no output, and no health before its period: {out:?}"
        );
        let out = h.step(Wake::Tick, 6_000_000_000);
        let rear = camera_health(&out, "health/inference-rear");
        let front = camera_health(&out, "health/inference-front");
        assert_eq!(
            (rear.messages_in, rear.messages_out, rear.dropped),
            (2, 1, 1)
        );
        assert_eq!((front.messages_in, front.dropped), (1, 0));
        let r = h.health.report();
        assert_eq!((r.messages_in, r.messages_out, r.dropped), (3, 2, 1));
    }

    #[test]
    fn a_cameras_list_is_checked_by_name() {
        let err = |toml: &str| {
            farsight_stage::parse_config::<InferenceConfig>(toml, "i.toml")
                .unwrap_err()
                .to_string()
        };
        assert_eq!(
            err("camera = \"left\"\ncameras = [\"front\"]"),
            "config key `camera` = left: expected left out when `cameras` lists the cameras"
        );
        assert_eq!(
            err("cameras = [\"front\", \"rear\", \"front\"]"),
            "config key `cameras` = [\"front\", \"rear\", \"front\"]: expected each camera once"
        );
        assert!(err("cameras = [\"a b\"]").starts_with("config key `cameras[0]` = a b"));
        assert!(
            err("backend = \"normals\"\ncameras = [\"front\", \"rear\"]")
                .contains("run one instance per depth camera")
        );
    }

    #[test]
    fn a_frame_of_the_wrong_size_or_encoding_is_a_counted_drop_with_no_output() {
        let mut h = stage(HSV);
        let wake = h.wake_on(IMAGE);
        // Shorter than its header says.
        let mut short = frame(1, 2, 2);
        short.data.truncate(9);
        h.put(IMAGE, short);
        assert!(h.step(wake, 0).is_empty());
        assert_eq!(dropped(&h), 1);
        // Depth is not colour.
        let mut mono = frame(2, 4, 0);
        mono.header = ImageHeader::packed(stamp(2), 7, 4, 3, PixelEncoding::MONO8);
        h.put(IMAGE, mono);
        assert!(h.step(wake, 0).is_empty());
        assert_eq!(dropped(&h), 2);
        // The stage goes on: the next good frame gets its output.
        h.put(IMAGE, frame(3, 1, 1));
        assert_eq!(h.step(wake, 0).len(), 1);
        let r = h.health.report();
        assert_eq!((r.messages_in, r.messages_out, r.dropped), (3, 1, 2));
    }

    #[test]
    fn a_frame_larger_than_the_output_allocated_at_start_is_dropped_naming_the_key() {
        let mut h = stage(&format!("max_frame_px = 4\n{HSV}"));
        let nav = &h.stage.ports().outputs[0];
        assert_eq!((nav.topic.as_str(), nav.max_slice_bytes), (NAV, 4));
        let wake = h.wake_on(IMAGE);
        h.put(IMAGE, frame(1, 3, 2));
        assert!(h.step(wake, 0).is_empty());
        assert_eq!(dropped(&h), 1);
        h.put(IMAGE, frame(2, 2, 2));
        assert_eq!(h.step(wake, 0).len(), 1, "4 px fit");
    }

    #[test]
    fn a_frame_is_processed_on_whichever_wake_it_arrives() {
        // The runtime drains every input at a tick too, and clears what the
        // step did not take: a frame found at a tick is not lost.
        let mut h = stage(HSV);
        h.put(IMAGE, frame(1, 1, 0));
        assert_eq!(h.step(Wake::Tick, 0).len(), 1);
        assert!(h.step(Wake::Tick, 0).is_empty(), "nothing new");
    }

    #[test]
    fn normals_use_a_camera_model_that_came_before_the_frame_on_another_step() {
        let mut h = stage("backend = \"normals\"\n");
        let depth_topic = "camera/front/depth";
        let wake = h.wake_on(depth_topic);
        let (w, hh) = (16u32, 12u32);
        let depth = Image {
            header: ImageHeader::packed(stamp(4), 0, w, hh, PixelEncoding::MONO16),
            data: 2000u16
                .to_le_bytes()
                .repeat((w * hh) as usize)
                .into_iter()
                .collect(),
        };
        // No camera model yet: dropped, counted.
        h.put(depth_topic, depth.clone());
        assert!(h.step(wake, 0).is_empty());
        assert_eq!(dropped(&h), 1);
        // The model arrives alone (it does not wake the step): kept for the
        // next frame, not cleared with the step's inbox.
        let camera = Camera::new(
            0,
            "front",
            CameraModel::pinhole(w, hh, 10.0, 10.0, 8.0, 6.0),
            Mount::from_xyz_rpy_deg([0.0, 0.0, 1.0], [0.0, 10.0, 0.0]),
        );
        h.put("camera/front/info", camera.to_info(stamp(4)));
        assert!(h.step(Wake::Tick, 0).is_empty());
        h.put(depth_topic, depth);
        let out = h.step(wake, 0);
        assert_eq!(out.len(), 1, "{:?}", h.health.report());
        assert_eq!(out[0].0, NAV);
        assert_eq!(out[0].1.stamp(), stamp(4));
        assert_eq!(dropped(&h), 1);
    }

    fn repo() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
    }

    #[test]
    fn ports_are_what_the_config_declares_to_the_graph() {
        let dir = Path::new(".");
        for toml in [HSV, "backend = \"normals\"\n"] {
            let c = config(toml);
            let io = c.topics("inference", dir).unwrap();
            let h = stage(toml);
            check_ports(&io, h.stage.ports()).unwrap_or_else(|e| panic!("{toml}: {e}"));
        }
        // The onnx backend's ports, planned from each shipped model config
        // (loading the model itself needs ONNX Runtime: planned with no
        // shapes, so sizes fall back to the input's).
        for (model, table) in [
            ("deploy/models/twinlitenet.toml", ""),
            ("deploy/models/deeplabv3-voc.toml", ""),
            (
                "deploy/models/deeplabv3-voc.toml",
                "deploy/models/voc-classes.toml",
            ),
            ("deploy/models/sim-lrn/model.toml", ""),
            ("deploy/models/sim-fitam/model.toml", ""),
        ] {
            let toml = format!("model_config = {model:?}\nclass_table = {table:?}\n");
            let c = config(&toml);
            let io = c.topics("inference", &repo()).unwrap();
            let m = ModelConfig::load(&repo().join(model)).unwrap();
            let has_table = !table.is_empty() || m.class_table_path().is_some();
            let (ports, _) = declare_ports(&c, "inference", &OutputPlan::onnx(&m, &[], has_table));
            check_ports(&io, &ports).unwrap_or_else(|e| panic!("{model}: {e}"));
        }
    }

    #[test]
    fn a_model_of_the_robots_past_positions_is_refused_naming_its_input() {
        // HIP's learned density wants past positions this stage has no
        // poses for: refused at start, before ONNX Runtime is touched.
        let model = repo().join("deploy/models/sim-hip/model.toml");
        let env = StageEnv {
            instance: "inference".into(),
            config_dir: ".".into(),
        };
        let c = farsight_stage::parse_config::<InferenceConfig>(
            &format!("model_config = {:?}\n", model.display().to_string()),
            "inference.toml",
        );
        let e = match c {
            Ok(c) => InferenceStage::new(c, &env)
                .err()
                .expect("refused")
                .to_string(),
            Err(e) => e.to_string(),
        };
        assert!(e.contains("past_input") && e.contains("\"past\""), "{e}");
    }

    #[test]
    fn output_sizes_come_from_the_model_shapes_or_its_input() {
        let m = ModelConfig::load(&repo().join("deploy/models/twinlitenet.toml")).unwrap();
        // TwinLiteNet: 2-class logits at 640 x 360, with its class table.
        let fallback = OutputPlan::onnx(&m, &[], true);
        assert_eq!(fallback.classes_px, Some(640 * 360));
        assert_eq!(fallback.navigability_px, Some(640 * 360));
        let shapes = vec![vec![1, 2, 90, 160]];
        let exact = OutputPlan::onnx(&m, &shapes, false);
        assert_eq!(exact.classes_px, Some(90 * 160));
        assert_eq!(
            exact.navigability_px, None,
            "no class table: no navigability"
        );
        let batched = vec![vec![-1, 2, 90, 160]];
        assert_eq!(
            OutputPlan::onnx(&m, &batched, false).classes_px,
            Some(90 * 160),
            "an open batch dimension is one frame's worth"
        );
        let dynamic = vec![vec![1, 2, -1, -1]];
        assert_eq!(
            OutputPlan::onnx(&m, &dynamic, false).classes_px,
            Some(640 * 360)
        );
        let (ports, cams) = declare_ports(&config(""), "inference", &fallback);
        let port = &cams[0].port;
        let bytes = |p: Option<usize>| ports.outputs[p.unwrap()].max_slice_bytes;
        assert_eq!(bytes(port.classes), 640 * 360);
        assert_eq!(bytes(port.confidence), 4 * 640 * 360, "f32 a pixel");
        let fitam = ModelConfig::load(&repo().join("deploy/models/sim-fitam/model.toml")).unwrap();
        let want: usize = fitam
            .outputs
            .iter()
            .find_map(|o| o.ensemble_shape)
            .unwrap()
            .iter()
            .product();
        let plan = OutputPlan::onnx(&fitam, &[], false);
        assert_eq!(plan.far_field_len, Some(want));
        let (ports, cams) = declare_ports(&config(""), "inference", &plan);
        assert_eq!(
            ports.outputs[cams[0].port.far_field.unwrap()].max_slice_bytes,
            4 * want
        );
    }
}
