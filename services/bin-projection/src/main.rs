//! `farsight-bin-projection`: LRN affordance heatmaps of every configured
//! camera -> one set of angular bins around the robot, published on
//! `bins/angular` each time a heatmap arrives.
//!
//! Config (`bin-projection.toml`, defaults shown):
//!
//! ```toml
//! cameras = ["front"]            # reads perception/<camera>/heatmap and camera/<camera>/info
//! health_rate_hz = 1.0
//! [bins]                         # see farsight_bin_projection::LrnBinsConfig (Spot preset)
//! bin_width_deg = 5.0
//! h_thresh = 0.7
//! threshold_on = "pixels"        # or "bins"
//! alpha = 0.1
//! ```

use anyhow::Result;
use farsight_bin_projection::{BinGeometry, CameraBins, LrnBins, LrnBinsConfig, Projection};
use farsight_interfaces::camera::Camera;
use farsight_interfaces::clock::{Clock, WallClock};
use farsight_interfaces::fixed::FixedVec;
use farsight_interfaces::msg::{AngularBins, HealthState, PixelEncoding, MAX_ANGULAR_BINS};
use farsight_interfaces::topics;
use farsight_interfaces::transport::ipc::{self, Bus, Wake};
use farsight_stage::{load_config, ConfigError, Health, StageArgs, Validate};
use serde::{Deserialize, Serialize};
use std::ops::ControlFlow;
use std::time::Duration;

const STAGE: &str = "bin-projection";

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct Config {
    cameras: Vec<String>,
    health_rate_hz: f64,
    bins: LrnBinsConfig,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            cameras: vec!["front".into()],
            health_rate_hz: 1.0,
            bins: LrnBinsConfig::default(),
        }
    }
}

impl Validate for Config {
    fn validate(&self) -> Result<(), ConfigError> {
        ConfigError::check(
            !self.cameras.is_empty(),
            "cameras",
            "[]",
            "at least one camera name",
        )?;
        for c in &self.cameras {
            farsight_interfaces::topics::validate_name(c)
                .map_err(|e| ConfigError::invalid("cameras", c, e.why))?;
        }
        ConfigError::check(
            self.health_rate_hz > 0.0,
            "health_rate_hz",
            self.health_rate_hz,
            "a positive rate in Hz",
        )?;
        self.bins.validate()
    }
}

fn main() {
    farsight_stage::run_main(STAGE, run);
}

fn run() -> Result<()> {
    let args = StageArgs::parse(STAGE)?;
    farsight_stage::init_tracing(args.log_format);
    let config: Config = load_config(args.config.as_deref())?;
    let geometry = BinGeometry::from_width_deg(config.bins.bin_width_deg);
    let bus = Bus::open(STAGE)?;
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
    let mut health = Health::new(&bus, STAGE, config.health_rate_hz)?;
    farsight_stage::announce_ready(STAGE);

    let n = config.cameras.len();
    let mut cameras: Vec<Option<Camera>> = vec![None; n];
    let mut maps: Vec<Option<CameraBins>> = vec![None; n];
    // Each camera's latest projection and when it arrived; a camera that stops
    // sending drops out after a second instead of holding its bins forever.
    let mut latest: Vec<Option<(u64, Projection)>> = vec![None; n];
    const CAMERA_TIMEOUT_NS: u64 = 1_000_000_000;
    let mut bins = LrnBins::new(geometry, config.bins);
    let clock = WallClock;
    let listeners: Vec<_> = heatmaps.iter().map(|h| h.listener()).collect();
    ipc::wait_loop(&listeners, Some(Duration::from_millis(200)), |wake| {
        let now = clock.now_ns();
        for (i, info) in infos.iter().enumerate() {
            if let Ok(Some(m)) = info.latest() {
                match Camera::from_info(&m) {
                    Ok(c) => {
                        if cameras[i].as_ref() != Some(&c) {
                            maps[i] = None;
                        }
                        cameras[i] = Some(c);
                    }
                    Err(e) => {
                        health.dropped(&format_args!("camera info {}: {e}", config.cameras[i]))
                    }
                }
            }
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
        latest[i] = Some((
            now,
            maps[i]
                .as_ref()
                .expect("just built")
                .project(values, config.bins.pixel_threshold()),
        ));
        let fresh: Vec<_> = latest
            .iter()
            .flatten()
            .filter(|(t, _)| now.saturating_sub(*t) <= CAMERA_TIMEOUT_NS)
            .map(|(_, p)| p.clone())
            .collect();
        let scores = bins.update(&fresh);
        let k = geometry.count.min(MAX_ANGULAR_BINS);
        let msg = AngularBins {
            stamp: h.stamp,
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
            Ok(()) => {
                health.set(HealthState::OK, "");
                health.output(h.stamp, clock.now_ns());
            }
            Err(e) => health.dropped(&e),
        }
        ControlFlow::Continue(())
    })?;
    health.stopping(clock.now_ns());
    Ok(())
}
