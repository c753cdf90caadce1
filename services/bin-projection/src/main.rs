//! `farsight-bin-projection`: per-camera perception -> bins around the robot.
//! With `method = "lrn"`, LRN affordance heatmaps of every configured camera
//! become one set of angular bins on `bins/angular`; with `method = "fitam"`,
//! FITAM far-field ensemble outputs become polar cost bins on `bins/polar`.
//! Either is published each time an input arrives.
//!
//! Config: [`farsight_bin_projection::stage::BinProjectionConfig`].

use anyhow::Result;
use farsight_bin_projection::fitam;
use farsight_bin_projection::stage::BinProjectionConfig;
use farsight_bin_projection::{BinGeometry, CameraBins, LrnBins, Projection};
use farsight_interfaces::camera::Camera;
use farsight_interfaces::clock::{Clock, WallClock};
use farsight_interfaces::fixed::FixedVec;
use farsight_interfaces::msg::{
    AngularBins, HealthState, PixelEncoding, PolarBinsHeader, PolarCell, Stamp, MAX_ANGULAR_BINS,
};
use farsight_interfaces::topics;
use farsight_interfaces::transport::ipc::{self, Bus, Wake};
use farsight_stage::{load_config, Freshness, Health, InputId, Need, StageArgs, StageInputs};
use std::ops::ControlFlow;
use std::time::Duration;

const STAGE: &str = "bin-projection";

fn main() {
    farsight_stage::run_main(STAGE, run);
}

fn run() -> Result<()> {
    let args = StageArgs::parse(STAGE)?;
    let instance = args.instance.as_str();
    farsight_stage::init_tracing(args.log_format);
    let config: BinProjectionConfig = load_config(args.config.as_deref())?;
    if config.method == "fitam" {
        return run_fitam(&config, instance);
    }
    let geometry = BinGeometry::from_width_deg(config.bins.bin_width_deg);
    let bus = Bus::open(instance)?;
    let heatmaps = config
        .cameras
        .iter()
        .map(|c| bus.slice_subscriber(&topics::affordance_heatmap(c)))
        .collect::<Result<Vec<_>, _>>()?;
    let infos = config
        .cameras
        .iter()
        .map(|c| bus.subscriber(&topics::camera_info(c)))
        .collect::<Result<Vec<_>, _>>()?;
    let out = bus.publisher(&topics::angular_bins())?;
    let mut health = Health::new(&bus, instance, config.health_rate_hz)?;
    farsight_stage::announce_ready(instance);

    let n = config.cameras.len();
    let mut cameras: Vec<Option<Camera>> = vec![None; n];
    let mut maps: Vec<Option<CameraBins>> = vec![None; n];
    // Each camera's latest projection; a camera that stops sending drops out
    // instead of holding its bins forever.
    let mut latest: Vec<Option<Projection>> = vec![None; n];
    let (mut inputs, camera_in) = camera_inputs(&config);
    let mut bins = LrnBins::new(geometry, config.bins);
    let clock = WallClock;
    let listeners: Vec<_> = heatmaps.iter().map(|h| h.listener()).collect();
    ipc::wait_loop(&listeners, Some(Duration::from_millis(200)), |wake| {
        let now = clock.now_ns();
        for i in refresh_cameras(&infos, &mut cameras, &config.cameras, &mut health) {
            maps[i] = None;
        }
        health.tick(now);
        let Wake::Input(i) = wake else {
            return ControlFlow::Continue(());
        };
        let Ok(Some(s)) = heatmaps[i].latest() else {
            return ControlFlow::Continue(());
        };
        health.input();
        let h = *s.header();
        if let Err(e) = h.validate(s.data().len()) {
            health.dropped(&e);
            return ControlFlow::Continue(());
        }
        if h.encoding != PixelEncoding::F32 {
            health.dropped(&format_args!("heatmap must be f32, got {}", h.encoding));
            return ControlFlow::Continue(());
        }
        let Some(cam) = &cameras[i] else {
            health.dropped(&format_args!(
                "no camera model yet for {}",
                config.cameras[i]
            ));
            return ControlFlow::Continue(());
        };
        let (w, hh) = (h.width as usize, h.height as usize);
        if maps[i]
            .as_ref()
            .is_none_or(|m| (m.width, m.height) != (w, hh))
        {
            maps[i] = Some(CameraBins::new(cam, w, hh, &geometry));
        }
        // Read the heatmap in place; copy only if the payload is not f32-aligned.
        let copied: Vec<f32>;
        let values: &[f32] = match bytemuck::try_cast_slice(s.data()) {
            Ok(v) => v,
            Err(_) => {
                copied = s
                    .data()
                    .chunks_exact(4)
                    .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                    .collect();
                &copied
            }
        };
        latest[i] = Some(
            maps[i]
                .as_ref()
                .expect("just built")
                .project(values, config.bins.pixel_threshold()),
        );
        inputs.consumed(camera_in[i], h.stamp);
        let fresh: Vec<_> = fresh_cameras(&inputs, &camera_in, &latest, &mut health)
            .cloned()
            .collect();
        let stamp = inputs.output_stamp().unwrap_or(h.stamp);
        let scores = bins.update(&fresh);
        let k = geometry.count.min(MAX_ANGULAR_BINS);
        let msg = AngularBins {
            stamp,
            first_bin_start_rad: geometry.start_rad() as f32,
            bin_width_rad: geometry.width_rad() as f32,
            scores: FixedVec::from_slice(
                &scores.scores[..k]
                    .iter()
                    .map(|&v| v as f32)
                    .collect::<Vec<_>>(),
            )
            .unwrap_or_default(),
            observed: FixedVec::from_slice(
                &scores.observed[..k]
                    .iter()
                    .map(|&o| o as u8)
                    .collect::<Vec<_>>(),
            )
            .unwrap_or_default(),
        };
        match out.publish(&msg) {
            Ok(()) => health.output(stamp, clock.now_ns()),
            Err(e) => health.dropped(&e),
        }
        ControlFlow::Continue(())
    })?;
    health.stopping(clock.now_ns());
    Ok(())
}

/// The FITAM loop: each camera's latest ensemble output becomes polar cells
/// in the heading bins its slices look into; cameras merge by certainty.
fn run_fitam(config: &BinProjectionConfig, instance: &str) -> Result<()> {
    let cfg = &config.fitam;
    let bus = Bus::open(instance)?;
    let tensors = config
        .cameras
        .iter()
        .map(|c| bus.slice_subscriber(&topics::far_field_logits(c)))
        .collect::<Result<Vec<_>, _>>()?;
    let infos = config
        .cameras
        .iter()
        .map(|c| bus.subscriber(&topics::camera_info(c)))
        .collect::<Result<Vec<_>, _>>()?;
    let radial = cfg.range_edges_m.len() - 1;
    let out = bus.slice_publisher(&topics::polar_bins(), cfg.heading_bins * radial)?;
    let mut health = Health::new(&bus, instance, config.health_rate_hz)?;
    farsight_stage::announce_ready(instance);

    let n = config.cameras.len();
    let mut cameras: Vec<Option<Camera>> = vec![None; n];
    // Per camera: its slice -> heading bin table (for a slice count) and its
    // latest cells with their arrival time.
    let mut slice_bins: Vec<Option<(usize, Vec<Option<usize>>)>> = vec![None; n];
    let mut latest: Vec<Option<Vec<PolarCell>>> = vec![None; n];
    let (mut inputs, camera_in) = camera_inputs(config);
    let header = PolarBinsHeader {
        stamp: Stamp::default(),
        heading_bins: cfg.heading_bins as u32,
        first_heading_start_rad: -std::f32::consts::PI,
        heading_width_rad: std::f32::consts::TAU / cfg.heading_bins as f32,
        range_edges_m: FixedVec::from_slice(
            &cfg.range_edges_m
                .iter()
                .map(|&e| e as f32)
                .collect::<Vec<_>>(),
        )
        .unwrap_or_default(),
    };
    let clock = WallClock;
    let listeners: Vec<_> = tensors.iter().map(|t| t.listener()).collect();
    ipc::wait_loop(&listeners, Some(Duration::from_millis(200)), |wake| {
        let now = clock.now_ns();
        for i in refresh_cameras(&infos, &mut cameras, &config.cameras, &mut health) {
            slice_bins[i] = None;
        }
        health.tick(now);
        let Wake::Input(i) = wake else {
            return ControlFlow::Continue(());
        };
        let Ok(Some(s)) = tensors[i].latest() else {
            return ControlFlow::Continue(());
        };
        health.input();
        let h = *s.header();
        let shape = h.shape();
        if shape.len() != 4 || h.element_count() != s.data().len() {
            health.dropped(&format_args!(
                "far-field tensor of shape {shape:?} with {} values; want [slices, radial, members, classes]",
                s.data().len()
            ));
            return ControlFlow::Continue(());
        }
        let shape = [0, 1, 2, 3].map(|k| shape[k] as usize);
        let Some(cam) = &cameras[i] else {
            health.dropped(&format_args!(
                "no camera model yet for {}",
                config.cameras[i]
            ));
            return ControlFlow::Continue(());
        };
        if slice_bins[i].as_ref().is_none_or(|(k, _)| *k != shape[0]) {
            slice_bins[i] = Some((
                shape[0],
                fitam::slice_heading_bins(cam, shape[0], cfg.heading_bins),
            ));
        }
        let bins = &slice_bins[i].as_ref().expect("just built").1;
        match fitam::polar_observation(s.data(), shape, bins, cfg) {
            Ok(cells) => {
                latest[i] = Some(cells);
                inputs.consumed(camera_in[i], h.stamp);
            }
            Err(e) => {
                health.dropped(&format_args!("{}: {e}", config.cameras[i]));
                return ControlFlow::Continue(());
            }
        }
        let fresh: Vec<&[PolarCell]> = fresh_cameras(&inputs, &camera_in, &latest, &mut health)
            .map(Vec::as_slice)
            .collect();
        let merged = fitam::merge_cameras(&fresh);
        let stamp = inputs.output_stamp().unwrap_or(h.stamp);
        // (Functional update syntax here trips a rustc 1.95 MIR bug with the
        // const-generic FixedVec inside the header.)
        let mut stamped = header;
        stamped.stamp = stamp;
        match out.publish_copy(stamped, &merged) {
            Ok(()) => health.output(stamp, clock.now_ns()),
            Err(e) => health.dropped(&e),
        }
        ControlFlow::Continue(())
    })?;
    health.stopping(clock.now_ns());
    Ok(())
}

/// The cameras as one required group: the bins go on while any camera
/// sends, and carry the newest capture among them.
fn camera_inputs(config: &BinProjectionConfig) -> (StageInputs, Vec<InputId>) {
    let mut inputs = StageInputs::new(config.input_deadline_s);
    let ids = config
        .cameras
        .iter()
        .map(|c| inputs.add_to("cameras", c, Need::Required))
        .collect();
    (inputs, ids)
}

/// The cameras whose newest capture is within the deadline of the newest
/// of any camera (an event-driven stage: time is its inputs'), with the
/// stage's health saying which ones dropped out.
fn fresh_cameras<'a, T>(
    inputs: &'a StageInputs,
    ids: &'a [InputId],
    latest: &'a [Option<T>],
    health: &mut Health,
) -> impl Iterator<Item = &'a T> {
    let now = inputs.newest_capture_ns().unwrap_or(0);
    match inputs.check(now) {
        Freshness::Fresh => health.set(HealthState::OK, ""),
        other => health.set(HealthState::DEGRADED, other.reason()),
    }
    latest
        .iter()
        .zip(ids)
        .filter(move |(_, &id)| inputs.is_fresh(id, now))
        .filter_map(|(l, _)| l.as_ref())
}

/// Takes each camera's newest model; returns the cameras whose model changed
/// (their per-camera tables must be rebuilt). A bad camera info is dropped
/// and counted; the previous model stays.
fn refresh_cameras(
    infos: &[ipc::Subscriber<farsight_interfaces::msg::CameraInfo>],
    cameras: &mut [Option<Camera>],
    names: &[String],
    health: &mut Health,
) -> Vec<usize> {
    let mut changed = Vec::new();
    for (i, info) in infos.iter().enumerate() {
        if let Ok(Some(m)) = info.latest() {
            match Camera::from_info(&m) {
                Ok(c) => {
                    if cameras[i].as_ref() != Some(&c) {
                        changed.push(i);
                    }
                    cameras[i] = Some(c);
                }
                Err(e) => health.dropped(&format_args!("camera info {}: {e}", names[i])),
            }
        }
    }
    changed
}
