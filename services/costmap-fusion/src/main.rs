//! `farsight-costmap-fusion`: FITAM's fused costmap as a stage. Polar bins
//! (`bins/polar`) update the far-field Kalman layer at the pose they arrive
//! with; near-field sensing fixes cells: costmaps from other systems
//! (`costmap/<name>`), depth images and class maps of the configured cameras;
//! the window follows the pose. Frames are placed with the latest pose (no
//! pose interpolation by capture time yet). The fused map and its layers go out at a
//! fixed rate on `costmap/fused`, `costmap/far_field` and `costmap/near_field`,
//! stamped with the oldest of the newest pose and near-field captures
//! (farsight_stage::inputs): republishing never makes a map look younger.
//! A stale far field is left out of the fused map; a stale pose or near
//! field stops the maps.

use anyhow::Result;
use farsight_costmap_fusion::map::FusionMap;
use farsight_costmap_fusion::near_field::{class_map_cells, depth_cells, FixedCell};
use farsight_costmap_fusion::stage::FusionStageConfig;
use farsight_costmap_fusion::swath::PolarGeometry;
use farsight_inference::class_table::ClassTableFile;
use farsight_inference::normals::RayTable;
use farsight_interfaces::camera::Camera;
use farsight_interfaces::clock::{Clock, WallClock};
use farsight_interfaces::msg::{CameraInfo, ImageHeader, PixelEncoding};
use farsight_interfaces::msg::{CostmapLayer, HealthState, Pose, Stamp};
use farsight_interfaces::topics;
use farsight_interfaces::transport::ipc::{self, Bus, Wake};
use farsight_interfaces::transport::ipc::{SliceSubscriber, Subscriber};
use farsight_stage::{load_config, Freshness, Health, InputId, Need, StageArgs, StageInputs};
use std::ops::ControlFlow;
use std::time::Duration;

const STAGE: &str = "costmap-fusion";

fn main() {
    farsight_stage::run_main(STAGE, run);
}

fn run() -> Result<()> {
    let args = StageArgs::parse(STAGE)?;
    let instance = args.instance.as_str();
    farsight_stage::init_tracing(args.log_format);
    let config: FusionStageConfig = load_config(args.config.as_deref())?;
    let bus = Bus::open(instance)?;
    let poses = bus.subscriber(&topics::pose())?;
    let polar = bus.slice_subscriber(&topics::polar_bins())?;
    let locals = config
        .local_costmaps
        .iter()
        .map(|n| bus.slice_subscriber(&topics::costmap(n)))
        .collect::<Result<Vec<_>, _>>()?;
    let base_dir = args
        .config
        .as_deref()
        .and_then(std::path::Path::parent)
        .unwrap_or(std::path::Path::new("."))
        .to_path_buf();
    let nf = &config.near_field;
    let mut class_table = if nf.class_map_cameras.is_empty() {
        None
    } else {
        Some(ClassTableFile::open(&base_dir.join(&nf.class_table))?)
    };
    // Frame subscribers apart from the per-camera state: the wait loop
    // borrows their listeners while the state changes.
    let (mut sources, mut frames) = (Vec::new(), Vec::new());
    for (names, kind) in [
        (&nf.depth_cameras, Source::Depth),
        (&nf.class_map_cameras, Source::Classes),
    ] {
        for name in names {
            frames.push(bus.slice_subscriber(&match kind {
                Source::Depth => topics::depth(name),
                Source::Classes => topics::class_map(name),
            })?);
            sources.push(CameraSource {
                name: name.clone(),
                kind,
                info: bus.subscriber(&topics::camera_info(name))?,
                camera: None,
                rays: None,
            });
        }
    }
    let cells = config.width_cells * config.height_cells;
    let outputs = [
        (CostmapLayer::FUSED, "fused"),
        (CostmapLayer::FAR_FIELD, "far_field"),
        (CostmapLayer::LOCAL, "near_field"),
    ]
    .map(|(layer, name)| {
        bus.slice_publisher(&topics::costmap(name), cells)
            .map(|p| (layer, p))
    });
    let outputs = outputs.into_iter().collect::<Result<Vec<_>, _>>()?;
    let mut health = Health::new(&bus, instance, config.health_rate_hz)?;
    farsight_stage::announce_ready(instance);

    let clock = WallClock;
    let mut map = FusionMap::new(
        config.width_cells,
        config.height_cells,
        config.resolution_m,
        config.far_field,
    );
    let mut pose: Option<Pose> = None;
    // The pose and the near field are required (the near field is as fresh
    // as its freshest source); the far field is optional, left out of the
    // fused map when stale, unless it is the only map source.
    let mut inputs = StageInputs::new(config.input_deadline_s);
    let pose_in = inputs.add(topics::pose().name(), Need::Required);
    let near_in: Vec<InputId> = config
        .local_costmaps
        .iter()
        .map(|n| topics::costmap(n).name().to_string())
        .chain(sources.iter().map(|s| match s.kind {
            Source::Depth => topics::depth(&s.name).name().to_string(),
            Source::Classes => topics::class_map(&s.name).name().to_string(),
        }))
        .map(|n| inputs.add_to("near field", &n, Need::Required))
        .collect();
    let far_in = config.use_far_field.then(|| {
        let need = if near_in.is_empty() {
            Need::Required
        } else {
            Need::Optional
        };
        inputs.add(topics::polar_bins().name(), need)
    });
    let period_ns = (1e9 / config.publish_rate_hz) as u64;
    let mut next_publish = clock.now_ns();
    let stamped = config.clock == farsight_stage::ClockSource::Stamps;
    let mut listeners = vec![polar.listener()];
    listeners.extend(locals.iter().map(|l| l.listener()));
    listeners.extend(frames.iter().map(|f| f.listener()));
    ipc::wait_loop(&listeners, Some(Duration::from_millis(50)), |wake| {
        let now = clock.now_ns();
        let mut fresh = false;
        if let Ok(Some(p)) = poses.latest() {
            if p.position_m.iter().all(|v| v.is_finite()) && p.yaw_rad.is_finite() {
                map.recenter(p.position_m[0], p.position_m[1]);
                inputs.consumed(pose_in, p.stamp);
                pose = Some(p);
            } else {
                health.dropped(&format_args!("non-finite pose {:?}", p.position_m));
            }
        }
        match wake {
            Wake::Input(0) => match (polar.latest(), &pose) {
                (Ok(Some(s)), Some(p)) => {
                    health.input();
                    let h = *s.header();
                    let geometry = PolarGeometry::from_header(&h).and_then(|g| {
                        let want = g.heading_bins * g.radial_bins();
                        if s.data().len() == want {
                            Ok(g)
                        } else {
                            Err(format!(
                                "polar bins hold {} cells, {} heading x {} radial bins need {want}",
                                s.data().len(),
                                g.heading_bins,
                                g.radial_bins()
                            ))
                        }
                    });
                    match geometry {
                        Err(e) => health.dropped(&format_args!("bins/polar: {e}")),
                        Ok(_) if !config.use_far_field => {}
                        Ok(geometry) => {
                            let u = map.observe_far_field(
                                &geometry,
                                s.data(),
                                p.position_m[0],
                                p.position_m[1],
                                p.yaw_rad,
                            );
                            map.add_process_noise();
                            if let Some(far) = far_in {
                                inputs.consumed(far, h.stamp);
                            }
                            fresh = true;
                            tracing::debug!(?u, "far-field update");
                        }
                    }
                }
                (Ok(Some(_)), None) => health.dropped(&"polar bins before any pose"),
                (Err(e), _) => health.dropped(&e),
                _ => {}
            },
            Wake::Input(k) if k > locals.len() => {
                let s = k - 1 - locals.len();
                let src = &mut sources[s];
                if let Some(Err(e)) = class_table.as_mut().map(|t| t.poll()) {
                    health.dropped(&format_args!("class table edit not applied: {e}"));
                }
                match src.observe(&frames[s], pose.as_ref(), &config, class_table.as_ref()) {
                    Ok(Some((stamp, cells))) => {
                        health.input();
                        inputs.consumed(near_in[config.local_costmaps.len() + s], stamp);
                        for ((gx, gy), cost) in cells {
                            map.fix_local(gx, gy, cost);
                        }
                        fresh = true;
                    }
                    Ok(None) => {}
                    Err(e) => health.dropped(&format_args!("{}: {e}", src.name)),
                }
            }
            Wake::Input(k) => match locals[k - 1].latest() {
                Ok(Some(s)) => {
                    health.input();
                    let h = *s.header();
                    if let Err(e) = h.validate(s.data().len()) {
                        health.dropped(&format_args!(
                            "costmap/{}: {e}",
                            config.local_costmaps[k - 1]
                        ));
                    } else {
                        map.apply_local_costmap(&h, s.data());
                        inputs.consumed(near_in[k - 1], h.stamp);
                        fresh = true;
                    }
                }
                Ok(None) => {}
                Err(e) => health.dropped(&e),
            },
            Wake::Tick => {}
        }
        // On the stamps' clock every input message gets its maps, so each
        // frame's costmap is planned on exactly once.
        let due = if stamped { fresh } else { now >= next_publish };
        let input_now = inputs.now_ns(config.clock);
        let freshness = inputs.check(input_now);
        match (due, inputs.output_stamp()) {
            // A required input is stale: the maps would look as fresh as
            // the pose while showing the world as it was. Downstream stages
            // see the last maps age instead.
            _ if freshness.is_stale() => health.set(HealthState::DEGRADED, freshness.reason()),
            (true, Some(stamp)) => {
                next_publish = now + period_ns;
                let far_field = far_in.is_some_and(|far| inputs.is_fresh(far, input_now));
                for (layer, publisher) in &outputs {
                    let published = publisher
                        .publish_with(cells, |out| map.export_into(stamp, *layer, far_field, out));
                    if let Err(e) = published {
                        health.dropped(&e);
                    }
                }
                match &freshness {
                    Freshness::Fresh => health.set(HealthState::OK, ""),
                    other => health.set(HealthState::DEGRADED, other.reason()),
                }
                health.output(stamp, now);
            }
            _ => {}
        }
        health.tick(now);
        ControlFlow::Continue(())
    })?;
    health.stopping(clock.now_ns());
    Ok(())
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Source {
    Depth,
    Classes,
}

/// One camera feeding the near-field layer, with its model and ray table.
struct CameraSource {
    name: String,
    kind: Source,
    info: Subscriber<CameraInfo>,
    camera: Option<Camera>,
    rays: Option<RayTable>,
}

impl CameraSource {
    /// The newest frame as fixed cells; `Ok(None)` when there is none.
    fn observe(
        &mut self,
        frames: &SliceSubscriber<ImageHeader, u8>,
        pose: Option<&Pose>,
        config: &FusionStageConfig,
        classes: Option<&ClassTableFile>,
    ) -> Result<Option<(Stamp, Vec<FixedCell>)>, String> {
        if let Ok(Some(i)) = self.info.latest() {
            self.camera = Some(Camera::from_info(&i).map_err(|e| format!("camera info: {e}"))?);
        }
        let Some(frame) = frames.latest().map_err(|e| e.to_string())? else {
            return Ok(None);
        };
        let pose = pose.ok_or("a frame before any pose")?;
        let cam = self.camera.as_ref().ok_or("no camera model yet")?;
        let h = *frame.header();
        h.validate(frame.data().len()).map_err(|e| e.to_string())?;
        let (w, hh) = (h.width as usize, h.height as usize);
        if self.rays.as_ref().is_none_or(|t| !t.fits(cam, w, hh)) {
            self.rays = Some(RayTable::new(cam, w, hh));
        }
        let rays = self.rays.as_ref().expect("just built");
        let nf = &config.near_field;
        let res = config.resolution_m;
        Ok(Some((
            h.stamp,
            match self.kind {
                Source::Depth => {
                    let depth =
                        farsight_inference::depth_metres(&h, frame.data(), nf.depth_scale_m)
                            .map_err(|e| e.to_string())?;
                    depth_cells(&depth, rays, cam, pose, res, nf)
                }
                Source::Classes => {
                    if h.encoding != PixelEncoding::MONO8 {
                        return Err(format!("class map must be mono8, got {}", h.encoding));
                    }
                    let ids: Vec<u8> = frame
                        .data()
                        .chunks(h.stride_bytes as usize)
                        .take(hh)
                        .flat_map(|row| &row[..w])
                        .copied()
                        .collect();
                    let table = classes.ok_or("no class table")?.table();
                    class_map_cells(&ids, rays, cam, pose, res, nf, |c| table.cost_s_per_m(c))
                }
            },
        )))
    }
}
