//! `farsight-inference`: wires [`farsight_inference`] to the bus. Reads the
//! newest camera frame, runs the backend, publishes class ids + confidence,
//! navigability, heatmap or far-field tensors stamped with the frame's stamp.
//! A frame whose result is invalid (NaN output, bad frame) is dropped and
//! counted in the health message; nothing is published for it.

use anyhow::{Context, Result};
use farsight_inference::class_table::ClassTableFile;
use farsight_inference::model_config::ModelConfig;
use farsight_inference::onnx::{OnnxModel, Timings};
use farsight_inference::stage::InferenceConfig;
use farsight_inference::{Backend, Perception};
use farsight_interfaces::clock::{Clock, WallClock};
use farsight_interfaces::msg::{HealthState, ImageHeader, PixelEncoding, Stamp, TensorHeader};
use farsight_interfaces::topics;
use farsight_interfaces::transport::ipc::{self, Bus, SlicePublisher, Wake};
use farsight_stage::{load_config, Health, StageArgs};
use std::ops::ControlFlow;
use std::time::Duration;

const STAGE: &str = "inference";

fn main() {
    farsight_stage::run_main(STAGE, run);
}

/// Output publishers, created at the first result (when the output size is known).
struct Outputs {
    camera: String,
    classes: Option<SlicePublisher<ImageHeader, u8>>,
    confidence: Option<SlicePublisher<ImageHeader, u8>>,
    navigability: Option<SlicePublisher<ImageHeader, u8>>,
    heatmap: Option<SlicePublisher<ImageHeader, u8>>,
    far_field: Option<SlicePublisher<TensorHeader, f32>>,
}

impl Outputs {
    fn publish(&mut self, bus: &Bus, p: &Perception, stamp: Stamp, camera_id: u32) -> Result<()> {
        let (w, h) = (p.width as u32, p.height as u32);
        let n = p.width * p.height;
        let img = |enc| ImageHeader::packed(stamp, camera_id, w, h, enc);
        if let Some(c) = &p.classes {
            let ids = lazy(&mut self.classes, || {
                bus.slice_publisher(&topics::class_map(&self.camera), n)
            })?;
            ids.publish_copy(img(PixelEncoding::MONO8), &c.ids)?;
            let conf = lazy(&mut self.confidence, || {
                bus.slice_publisher(&topics::class_confidence(&self.camera), 4 * n)
            })?;
            // Image payloads are bytes: an f32 image is 4 little-endian bytes a pixel.
            conf.publish_copy(img(PixelEncoding::F32), bytemuck::cast_slice(&c.confidence))?;
        }
        if let Some(m) = &p.navigability {
            let nav = lazy(&mut self.navigability, || {
                bus.slice_publisher(&topics::navigability(&self.camera), n)
            })?;
            nav.publish_copy(img(PixelEncoding::MONO8), m)?;
        }
        if let Some(hm) = &p.heatmap {
            let pubr = lazy(&mut self.heatmap, || {
                bus.slice_publisher(&topics::affordance_heatmap(&self.camera), 4 * n)
            })?;
            pubr.publish_copy(img(PixelEncoding::F32), bytemuck::cast_slice(hm))?;
        }
        if let Some((shape, data)) = &p.far_field {
            let pubr = lazy(&mut self.far_field, || {
                bus.slice_publisher(&topics::far_field_logits(&self.camera), data.len())
            })?;
            let dims = shape.map(|d| d as u32);
            pubr.publish_copy(TensorHeader::new(stamp, camera_id, &dims), data)?;
        }
        Ok(())
    }
}

fn lazy<T, E: std::error::Error + Send + Sync + 'static>(
    slot: &mut Option<T>,
    make: impl FnOnce() -> Result<T, E>,
) -> Result<&mut T> {
    if slot.is_none() {
        *slot = Some(make()?);
    }
    Ok(slot.as_mut().expect("just set"))
}

fn run() -> Result<()> {
    let args = StageArgs::parse(STAGE)?;
    let instance = args.instance.as_str();
    farsight_stage::init_tracing(args.log_format);
    let config: InferenceConfig = load_config(args.config.as_deref())?;
    let base = args.config_dir();
    let (mut backend, model_table) = match config.backend.as_str() {
        "onnx" => {
            let model_config = ModelConfig::load(&base.join(&config.model_config))?;
            let model = OnnxModel::load(&model_config).context("loading the model")?;
            tracing::info!(model = %model_config.model_path().display(), "onnx backend");
            (
                Backend::Onnx(Box::new(model)),
                model_config.class_table_path(),
            )
        }
        "hsv" => (Backend::Hsv(config.hsv.ranges.clone()), None),
        _ => (Backend::Normals(config.normals, None, None), None),
    };
    let table_path = if config.class_table.is_empty() {
        model_table
    } else {
        Some(base.join(&config.class_table))
    };
    let mut table = table_path
        .as_deref()
        .map(ClassTableFile::open)
        .transpose()?;

    let bus = Bus::open(instance)?;
    // The normals backend reads depth (and the camera model for the mount);
    // every other backend reads the camera frames.
    let uses_depth = matches!(backend, Backend::Normals(..));
    let input_topic = if uses_depth {
        topics::depth(&config.camera)
    } else {
        topics::camera_image(&config.camera)
    };
    let frames = bus.slice_subscriber(&input_topic)?;
    let camera_info = bus.subscriber(&topics::camera_info(&config.camera))?;
    let mut outputs = Outputs {
        camera: config.camera.clone(),
        classes: None,
        confidence: None,
        navigability: None,
        heatmap: None,
        far_field: None,
    };
    let mut health = Health::new(&bus, instance, config.health_rate_hz)?;
    health.set(HealthState::OK, "");
    tracing::info!(backend = %config.backend, input = %input_topic.name(), "inference config");
    farsight_stage::announce_ready(instance);

    let clock = WallClock;
    let mut last_poll = clock.now_ns();
    let poll_ns = (config.class_table_poll_s * 1e9) as u64;
    let mut timings = Timings::default();
    ipc::wait_loop(
        &[frames.listener()],
        Some(Duration::from_millis(200)),
        |wake| {
            let now = clock.now_ns();
            if wake == Wake::Input(0) {
                match frames.latest() {
                    Err(e) => health.dropped(&e),
                    Ok(None) => {}
                    Ok(Some(frame)) => {
                        health.input();
                        let h = *frame.header();
                        if let (Backend::Normals(_, camera, _), Ok(Some(info))) =
                            (&mut backend, camera_info.latest())
                        {
                            match farsight_interfaces::camera::Camera::from_info(&info) {
                                Ok(c) => *camera = Some(Box::new(c)),
                                Err(e) => health.dropped(&format_args!("camera info: {e}")),
                            }
                        }
                        let t = table.as_ref().map(|t| t.table());
                        match backend.run(&h, frame.data(), t, &mut timings) {
                            Err(e) => {
                                health.dropped(&format_args!("frame {}: {e}", h.stamp.frame_seq))
                            }
                            Ok(p) => match outputs.publish(&bus, &p, h.stamp, h.camera_id) {
                                Ok(()) => health.output(h.stamp, clock.now_ns()),
                                Err(e) => health.dropped(&format_args!(
                                    "publishing frame {}: {e:#}",
                                    h.stamp.frame_seq
                                )),
                            },
                        }
                        health.set_skipped(frames.skips().skipped);
                    }
                }
            }
            if now.saturating_sub(last_poll) >= poll_ns {
                last_poll = now;
                if let Some(t) = table.as_mut() {
                    match t.poll() {
                        Ok(true) => tracing::info!(reloads = t.reloads, "class table reloaded"),
                        Ok(false) => {}
                        Err(e) => tracing::error!(
                            "class table edit refused, keeping the previous table: {e}"
                        ),
                    }
                }
            }
            health.tick(now);
            ControlFlow::Continue(())
        },
    )?;
    health.stopping(clock.now_ns());
    Ok(())
}
