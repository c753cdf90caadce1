//! `farsight-camera-ingest`: wires [`farsight_camera_ingest`] to the bus.

use anyhow::{bail, Context, Result};
use farsight_camera_ingest::{capture_time_from_name, list_images, read_frame, IngestConfig};
use farsight_interfaces::clock::{Clock, WallClock};
use farsight_interfaces::msg::{HealthState, Stamp};
use farsight_interfaces::topics;
use farsight_interfaces::transport::ipc::{self, Bus};
use farsight_stage::{load_config, Health, StageArgs};
use std::ops::ControlFlow;
use std::time::Duration;

const STAGE: &str = "camera-ingest";

fn main() {
    if let Err(e) = run() {
        tracing::error!("{e:#}");
        eprintln!("farsight-{STAGE}: {e:#}");
        std::process::exit(1);
    }
}

fn run() -> Result<()> {
    let args = StageArgs::parse(STAGE)?;
    farsight_stage::init_tracing(args.log_format);
    let config: IngestConfig = load_config(args.config.as_deref())?;
    let base = args.config_dir();
    let camera = config.camera.build(0, &base)?;
    let folder = base.join(&config.folder);
    let files =
        list_images(&folder).with_context(|| format!("reading folder {}", folder.display()))?;
    if files.is_empty() {
        bail!("folder {} holds no PNG images", folder.display());
    }
    let (w, h) = (camera.model.width, camera.model.height);
    let bus = Bus::open(STAGE)?;
    let frames = bus.slice_publisher(
        &topics::camera_image(&camera.name),
        w as usize * h as usize * 3,
    )?;
    let info = bus.publisher(&topics::camera_info(&camera.name))?;
    let mut health = Health::new(&bus, STAGE, config.health_rate_hz)?;
    health.set(HealthState::OK, "");
    tracing::info!(folder = %folder.display(), frames = files.len(), camera = %camera.name, "camera-ingest config");
    farsight_stage::announce_ready(STAGE);

    let clock = WallClock;
    let (mut index, mut pass, mut seq) = (0usize, 0u32, 0u64);
    // When looping, keep decoded frames after the first pass (within a budget):
    // replaying a short folder at full speed should cost a copy, not a decode.
    let frame_bytes = w as usize * h as usize * 3;
    let cache_budget = 512 << 20;
    let mut cache: Vec<Option<(farsight_interfaces::msg::ImageHeader, Vec<u8>)>> =
        if config.loops != 1 && files.len() * frame_bytes <= cache_budget {
            vec![None; files.len()]
        } else {
            vec![]
        };
    let period = Duration::from_secs_f64(1.0 / config.rate_hz);
    ipc::wait_loop(&[], Some(period), |_| {
        let now = clock.now_ns();
        if index == files.len() {
            index = 0;
            pass += 1;
            if config.loops != 0 && pass >= config.loops {
                tracing::info!(published = seq, "all frames published");
                return ControlFlow::Break(());
            }
        }
        let path = &files[index];
        let cached = cache.get(index).cloned().flatten();
        index += 1;
        health.input();
        let read = match cached {
            Some(frame) => Ok(frame),
            None => read_frame(path, w, h).inspect(|frame| {
                if let Some(slot) = cache.get_mut(index - 1) {
                    *slot = Some(frame.clone());
                }
            }),
        };
        match read {
            Err(e) => health.dropped(&e),
            Ok((header, data)) => {
                seq += 1;
                let capture = capture_time_from_name(path).unwrap_or(now);
                let stamp = Stamp::new(seq, capture);
                let sent = frames.publish_with(data.len(), |px| {
                    px.copy_from_slice(&data);
                    farsight_interfaces::msg::ImageHeader {
                        stamp,
                        camera_id: camera.id,
                        ..header
                    }
                });
                match sent.and_then(|()| info.publish(&camera.to_info(stamp))) {
                    Ok(()) => health.output(stamp, now),
                    Err(e) => health.dropped(&e),
                }
            }
        }
        health.tick(now);
        ControlFlow::Continue(())
    })?;
    health.stopping(clock.now_ns());
    Ok(())
}
