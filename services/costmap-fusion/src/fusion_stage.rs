//! The costmap-fusion stage as a library type ([`FusionStage`]): FITAM's
//! fused map (section IV-D). Polar bins (`bins/polar`) update the far-field
//! Kalman layer ([`crate::kalman`]) at the pose they arrive with; near-field
//! sensing fixes cells: costmaps from other systems (`costmap/<name>`), and
//! depth images and class maps of the configured cameras
//! ([`crate::near_field`]); the window follows the pose. Frames are placed
//! with the latest pose (no pose interpolation by capture time yet).
//!
//! The fused map and its layers go out on `costmap/fused`,
//! `costmap/far_field` and `costmap/near_field`, stamped with the oldest of
//! the newest pose and near-field captures (farsight_stage::inputs):
//! republishing never makes a map look younger. A stale far field is left out
//! of the fused map (FITAM with no far field); a stale pose or near field
//! stops the maps, so downstream stages see the last ones age.
//!
//! On the wall clock the maps go out at `publish_rate_hz`; with
//! `clock = "stamps"` (lock-step simulation, replays) every input message
//! that changed the map gets one set of maps, so each frame's costmap is
//! planned on exactly once, on any machine.

use crate::map::FusionMap;
use crate::near_field::{class_map_cells, depth_cells, FixedCell};
use crate::stage::FusionStageConfig;
use crate::swath::PolarGeometry;
use farsight_inference::class_table::ClassTableFile;
use farsight_inference::normals::RayTable;
use farsight_interfaces::camera::Camera;
use farsight_interfaces::message::{Costmap, Image, Message, PolarBins};
use farsight_interfaces::msg::{CostCell, CostmapLayer, HealthState, PixelEncoding, Pose};
use farsight_interfaces::topics;
use farsight_stage::CameraModels;
use farsight_stage::{
    ClockSource, Freshness, Inbox, InputId, Need, Ports, Stage, StageEnv, StageInputs, StageKind,
    Step,
};
use std::time::Duration;

/// The costmap-fusion stage: one instance, its state between steps.
pub struct FusionStage {
    config: FusionStageConfig,
    ports: Ports,
    port: PortIds,
    cameras: CameraModels,
    sources: Vec<CameraSource>,
    class_table: Option<ClassTableFile>,
    map: FusionMap,
    pose: Option<Pose>,
    inputs: StageInputs,
    pose_in: InputId,
    /// The near-field inputs: the local costmaps, then the camera sources.
    near_in: Vec<InputId>,
    far_in: Option<InputId>,
    period_ns: u64,
    /// When the next maps are due on the wall clock; `None`: at once.
    next_publish_ns: Option<u64>,
    /// Answering the far field: per near-field input port, the message
    /// that came in a step without a far field (a tick), held for the
    /// frame's far field (see `step`).
    held: Vec<(usize, Option<Message>)>,
}

struct PortIds {
    pose: usize,
    polar: usize,
    locals: Vec<usize>,
    /// One per camera source, as [`FusionStage::sources`].
    frames: Vec<usize>,
    layers: [(CostmapLayer, usize); 3],
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Source {
    Depth,
    Classes,
}

/// One camera feeding the near-field layer, with its ray table.
struct CameraSource {
    name: String,
    kind: Source,
    /// Its model in [`FusionStage::cameras`].
    camera: usize,
    rays: Option<RayTable>,
}

impl StageKind for FusionStage {
    const KIND: &'static str = "costmap-fusion";
    type Config = FusionStageConfig;

    fn new(config: FusionStageConfig, env: &StageEnv) -> anyhow::Result<Self> {
        let nf = &config.near_field;
        let class_table = if nf.class_map_cameras.is_empty() {
            None
        } else {
            Some(ClassTableFile::open(&env.config_dir.join(&nf.class_table))?)
        };
        let mut ports = Ports {
            // On the wall clock the maps go out on time even when inputs
            // are slow; the tick is how the step notices they are due.
            tick: Some(Duration::from_millis(50)),
            health_rate_hz: config.health_rate_hz,
            ..Ports::default()
        };
        let pose = ports.input(topics::pose().name());
        // Read even with `use_far_field = false`: bins are still checked
        // and counted, only kept out of the map (the "no far field" baseline).
        let polar = ports.waking_input(topics::polar_bins().name());
        // Answering the far field, a near field waits in the inbox for it.
        let locals: Vec<usize> = config
            .local_costmaps
            .iter()
            .map(|n| {
                let t = topics::costmap(n).name().to_string();
                if config.answer_far_field {
                    ports.input(t)
                } else {
                    ports.waking_input(t)
                }
            })
            .collect();
        let kinds = [
            (&nf.depth_cameras, Source::Depth),
            (&nf.class_map_cameras, Source::Classes),
        ];
        let cameras =
            CameraModels::declare(&mut ports, kinds.iter().flat_map(|(names, _)| names.iter()));
        let mut sources = Vec::new();
        let mut frames = Vec::new();
        for (names, kind) in kinds {
            for name in names {
                frames.push(ports.waking_input(source_topic(kind, name)));
                sources.push(CameraSource {
                    name: name.clone(),
                    kind,
                    camera: cameras.index(name).expect("declared above"),
                    rays: None,
                });
            }
        }
        // Each layer's shared memory is sized up front: the whole window.
        let cells = config.width_cells * config.height_cells;
        let max_bytes = cells * std::mem::size_of::<CostCell>();
        let layers = [
            (CostmapLayer::FUSED, "fused"),
            (CostmapLayer::FAR_FIELD, "far_field"),
            (CostmapLayer::LOCAL, "near_field"),
        ]
        .map(|(layer, name)| {
            (
                layer,
                ports.slice_output(topics::costmap(name).name(), max_bytes),
            )
        });
        // The pose and the near field are required (the near field is as
        // fresh as its freshest source); the far field is optional, left out
        // of the fused map when stale, unless it is the only map source.
        let mut inputs = StageInputs::new(config.input_deadline_s);
        let pose_in = inputs.add(topics::pose().name(), Need::Required);
        let near_in: Vec<InputId> = config
            .local_costmaps
            .iter()
            .map(|n| topics::costmap(n).name().to_string())
            .chain(sources.iter().map(|s| source_topic(s.kind, &s.name)))
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
        // The near-field inputs' ports (local costmaps, then depth and
        // class frames), each with the message held for the far field.
        let held = locals.iter().chain(&frames).map(|&p| (p, None)).collect();
        Ok(Self {
            map: FusionMap::new(
                config.width_cells,
                config.height_cells,
                config.resolution_m,
                config.far_field,
            ),
            period_ns: (1e9 / config.publish_rate_hz) as u64,
            config,
            ports,
            port: PortIds {
                pose,
                polar,
                locals,
                frames,
                layers,
            },
            cameras,
            sources,
            class_table,
            pose: None,
            inputs,
            pose_in,
            near_in,
            far_in,
            next_publish_ns: None,
            held,
        })
    }
}

fn source_topic(kind: Source, camera: &str) -> String {
    match kind {
        Source::Depth => topics::depth(camera).name().to_string(),
        Source::Classes => topics::class_map(camera).name().to_string(),
    }
}

impl Stage for FusionStage {
    fn ports(&self) -> &Ports {
        &self.ports
    }

    fn step(&mut self, step: &mut Step<'_>) {
        // The pose first: every map update this step is placed with it.
        self.take_pose(step);
        let health = &mut *step.health;
        self.cameras.refresh(step.inbox, |name, e| {
            health.dropped(&format_args!("{name}: camera info: {e}"))
        });
        // Answering the far field, the near field goes into the map after
        // the frame's far field, as in the in-process executor (which never
        // ticks): one that a process's tick took in is held until then
        // (the newest per input), not applied first.
        let holding = self.config.answer_far_field;
        if holding {
            self.hold_near_field(step.inbox);
        }
        // Every input that arrived is used, whichever one woke the step.
        let far = self.take_polar(step);
        if holding {
            if !far {
                self.publish(step, false);
                return;
            }
            self.release_near_field(step.inbox);
        }
        let local = self.take_locals(step);
        let frames = self.take_frames(step);
        // Answering the far field: a near field that came in on a tick (a
        // process's wait loop takes every input it finds) is in the map, and
        // goes out with the frame's far field.
        let answer = if self.config.answer_far_field {
            far
        } else {
            far || local || frames
        };
        self.publish(step, answer);
        // Health is judged on the wall clock (step.now_ns stays wall_ns),
        // on either clock: with no inputs, the stamps' time stands still,
        // and a report must still go out.
    }
}

impl FusionStage {
    /// Moves this step's near-field messages from the inbox to `held`.
    fn hold_near_field(&mut self, inbox: &mut Inbox) {
        for (port, slot) in &mut self.held {
            if let Some(m) = inbox.take_any(*port) {
                *slot = Some(m);
            }
        }
    }

    /// Puts the held near-field messages back in the inbox for this step.
    fn release_near_field(&mut self, inbox: &mut Inbox) {
        for (port, slot) in &mut self.held {
            if let Some(m) = slot.take() {
                inbox.put(*port, m);
            }
        }
    }

    fn take_pose(&mut self, step: &mut Step<'_>) {
        let Some(p) = step.inbox.take::<Pose>(self.port.pose) else {
            return;
        };
        if p.position_m.iter().all(|v| v.is_finite()) && p.yaw_rad.is_finite() {
            self.map.recenter(p.position_m[0], p.position_m[1]);
            self.inputs.consumed(self.pose_in, p.stamp);
            self.pose = Some(p);
        } else {
            step.health
                .dropped(&format_args!("non-finite pose {:?}", p.position_m));
        }
    }

    /// Polar bins into the far-field layer; `true` if the map changed.
    fn take_polar(&mut self, step: &mut Step<'_>) -> bool {
        let Some(bins) = step.inbox.take::<PolarBins>(self.port.polar) else {
            return false;
        };
        let Some(p) = self.pose else {
            // Bins are relative to the robot: without a pose they have no place.
            step.health.dropped(&"polar bins before any pose");
            return false;
        };
        step.health.input();
        let h = bins.header;
        let geometry = PolarGeometry::from_header(&h).and_then(|g| {
            let want = g.heading_bins * g.radial_bins();
            if bins.data.len() == want {
                Ok(g)
            } else {
                Err(format!(
                    "polar bins hold {} cells, {} heading x {} radial bins need {want}",
                    bins.data.len(),
                    g.heading_bins,
                    g.radial_bins()
                ))
            }
        });
        match geometry {
            Err(e) => {
                step.health.dropped(&format_args!("bins/polar: {e}"));
                false
            }
            Ok(_) if !self.config.use_far_field => false,
            Ok(geometry) => {
                let u = self.map.observe_far_field(
                    &geometry,
                    &bins.data,
                    p.position_m[0],
                    p.position_m[1],
                    p.yaw_rad,
                );
                self.map.add_process_noise();
                if let Some(far) = self.far_in {
                    self.inputs.consumed(far, h.stamp);
                }
                tracing::debug!(?u, "far-field update");
                true
            }
        }
    }

    /// Other systems' costmaps into the near-field layer; `true` if the map
    /// changed.
    fn take_locals(&mut self, step: &mut Step<'_>) -> bool {
        let mut changed = false;
        for (k, &port) in self.port.locals.iter().enumerate() {
            let Some(m) = step.inbox.take::<Costmap>(port) else {
                continue;
            };
            step.health.input();
            if let Err(e) = m.header.validate(m.data.len()) {
                let name = &self.config.local_costmaps[k];
                step.health.dropped(&format_args!("costmap/{name}: {e}"));
                continue;
            }
            self.map.apply_local_costmap(&m.header, &m.data);
            self.inputs.consumed(self.near_in[k], m.header.stamp);
            changed = true;
        }
        changed
    }

    /// Depth images and class maps into the near-field layer; `true` if the
    /// map changed.
    fn take_frames(&mut self, step: &mut Step<'_>) -> bool {
        let mut changed = false;
        for (s, &port) in self.port.frames.iter().enumerate() {
            let Some(frame) = step.inbox.take::<Image>(port) else {
                continue;
            };
            // A class table edited while the stage runs applies from the
            // next frame; a broken edit keeps the previous table.
            if let Some(Err(e)) = self.class_table.as_mut().map(|t| t.poll()) {
                step.health
                    .dropped(&format_args!("class table edit not applied: {e}"));
            }
            let src = &mut self.sources[s];
            let observed = src.observe(
                &frame,
                self.pose.as_ref(),
                self.cameras.get(src.camera),
                &self.config,
                self.class_table.as_ref(),
            );
            match observed {
                Ok(cells) => {
                    step.health.input();
                    let near = self.near_in[self.config.local_costmaps.len() + s];
                    self.inputs.consumed(near, frame.header.stamp);
                    for ((gx, gy), cost) in cells {
                        self.map.fix_local(gx, gy, cost);
                    }
                    changed = true;
                }
                Err(e) => step.health.dropped(&format_args!("{}: {e}", src.name)),
            }
        }
        changed
    }

    /// Sends the maps when due and every required input is fresh, and says
    /// why not in health otherwise.
    fn publish(&mut self, step: &mut Step<'_>, map_changed: bool) {
        let now = step.wall_ns;
        let due = match self.config.clock {
            ClockSource::Stamps => map_changed,
            ClockSource::Wall => self.next_publish_ns.is_none_or(|t| now >= t),
        };
        let input_now = self.inputs.now_at(self.config.clock, step.wall_ns);
        let freshness = self.inputs.check(input_now);
        match (due, self.inputs.output_stamp()) {
            // A required input is stale: the maps would look as fresh as
            // the pose while showing the world as it was. Downstream stages
            // see the last maps age instead.
            _ if freshness.is_stale() => {
                step.health.set(HealthState::DEGRADED, freshness.reason());
            }
            (true, Some(stamp)) => {
                self.next_publish_ns = Some(now + self.period_ns);
                let far_field = self
                    .far_in
                    .is_some_and(|far| self.inputs.is_fresh(far, input_now));
                for (layer, port) in self.port.layers {
                    let (header, data) = self.map.export(stamp, layer, far_field);
                    step.out.send(port, Costmap { header, data });
                    if layer == CostmapLayer::FUSED {
                        // The planner waits on the fused map alone: it goes
                        // out before the two layers are built.
                        step.out.flush();
                    }
                }
                match &freshness {
                    Freshness::Fresh => step.health.set(HealthState::OK, ""),
                    other => step.health.set(HealthState::DEGRADED, other.reason()),
                }
                step.health.output(stamp, now);
            }
            _ => {}
        }
    }
}

impl CameraSource {
    /// A frame as fixed cells, or why it cannot be used.
    fn observe(
        &mut self,
        frame: &Image,
        pose: Option<&Pose>,
        camera: Option<&Camera>,
        config: &FusionStageConfig,
        classes: Option<&ClassTableFile>,
    ) -> Result<Vec<FixedCell>, String> {
        let pose = pose.ok_or("a frame before any pose")?;
        let cam = camera.ok_or("no camera model yet")?;
        let h = frame.header;
        h.validate(frame.data.len()).map_err(|e| e.to_string())?;
        let (w, hh) = (h.width as usize, h.height as usize);
        let rays = match &mut self.rays {
            Some(t) if t.fits(cam, w, hh) => t,
            slot => slot.insert(RayTable::new(cam, w, hh)),
        };
        let nf = &config.near_field;
        let res = config.resolution_m;
        Ok(match self.kind {
            Source::Depth => {
                let depth = farsight_inference::depth_metres(&h, &frame.data, nf.depth_scale_m)
                    .map_err(|e| e.to_string())?;
                depth_cells(&depth, rays, cam, pose, res, nf)
            }
            Source::Classes => {
                if h.encoding != PixelEncoding::MONO8 {
                    return Err(format!("class map must be mono8, got {}", h.encoding));
                }
                let ids: Vec<u8> = frame
                    .data
                    .chunks(h.stride_bytes as usize)
                    .take(hh)
                    .flat_map(|row| &row[..w])
                    .copied()
                    .collect();
                let table = classes.ok_or("no class table")?.table();
                class_map_cells(&ids, rays, cam, pose, res, nf, |c| table.cost_s_per_m(c))
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use farsight_interfaces::camera::{CameraModel, Mount};
    use farsight_interfaces::fixed::FixedVec;
    use farsight_interfaces::message::Message;
    use farsight_interfaces::msg::{CostmapHeader, ImageHeader, PolarBinsHeader, PolarCell, Stamp};
    use farsight_stage::runtime::Harness;
    use farsight_stage::Wake;

    const S: u64 = 1_000_000_000;

    fn stage_in(toml: &str, dir: &std::path::Path) -> Harness<FusionStage> {
        let config: FusionStageConfig = farsight_stage::parse_config(toml, "test").unwrap();
        let env = StageEnv {
            instance: "fusion".into(),
            config_dir: dir.into(),
        };
        Harness::new(FusionStage::new(config, &env).unwrap())
    }

    fn stage(toml: &str) -> Harness<FusionStage> {
        stage_in(toml, std::path::Path::new("."))
    }

    fn pose(seq: u64, t_ns: u64) -> Pose {
        Pose {
            stamp: Stamp::new(seq, t_ns),
            ..Default::default()
        }
    }

    /// A 21x21 near-field map around the origin, 0.5 s/m, lethal at (5, 0).
    fn local(seq: u64, t_ns: u64) -> Costmap {
        let (half, side) = (10i64, 21i64);
        let header = CostmapHeader {
            stamp: Stamp::new(seq, t_ns),
            layer: CostmapLayer::LOCAL,
            width: side as u32,
            height: side as u32,
            resolution_m: 1.0,
            x_min_m: -half as f64,
            y_max_m: half as f64,
        };
        let data = (0..side * side)
            .map(|k| CostCell {
                cost_s_per_m: if (-half + k % side, half - k / side) == (5, 0) {
                    f32::INFINITY
                } else {
                    0.5
                },
                variance: 0.0,
            })
            .collect();
        Costmap { header, data }
    }

    /// 32 heading x 3 radial bins out to 100 m, every one certain of class 2.
    fn polar(seq: u64, t_ns: u64) -> PolarBins {
        PolarBins {
            header: PolarBinsHeader {
                stamp: Stamp::new(seq, t_ns),
                heading_bins: 32,
                first_heading_start_rad: -std::f32::consts::PI,
                heading_width_rad: std::f32::consts::TAU / 32.0,
                range_edges_m: FixedVec::from_slice(&[25.0, 50.0, 75.0, 100.0]).unwrap(),
            },
            data: vec![
                PolarCell {
                    cost_s_per_m: 1.0 / 4.25,
                    variance: 0.01,
                    class_id: 2,
                    probability: 0.99,
                };
                96
            ],
        }
    }

    /// The maps sent, by layer topic, in order.
    fn maps(out: Vec<(String, Message)>) -> Vec<(String, Costmap)> {
        out.into_iter()
            .map(|(topic, m)| (topic, Costmap::try_from(m).unwrap()))
            .collect()
    }

    fn cost_at(m: &Costmap, x_m: f64, y_m: f64) -> f32 {
        m.data[m.header.cell_index(x_m, y_m).unwrap()].cost_s_per_m
    }

    #[test]
    fn a_fresh_pose_and_near_field_give_the_three_maps_stamped_with_the_oldest_capture() {
        let mut h = stage("width_cells = 41\nheight_cells = 41\n");
        let wake = h.wake_on("costmap/local");
        h.put("state/pose", pose(90, 10 * S));
        h.put("costmap/local", local(3, 10 * S - S / 5));
        let out = maps(h.step(wake, 10 * S));
        let topics: Vec<&str> = out.iter().map(|(t, _)| t.as_str()).collect();
        assert_eq!(
            topics,
            ["costmap/fused", "costmap/far_field", "costmap/near_field"]
        );
        // The planner's input goes out before the layers nobody waits on
        // are built.
        assert_eq!(h.flushed_mid_step, ["costmap/fused"]);
        // The oldest required capture (the near field's); the frame number
        // of the first declared input (the pose).
        for (_, m) in &out {
            assert_eq!(m.header.stamp, Stamp::new(90, 10 * S - S / 5));
            assert_eq!(m.data.len(), 41 * 41);
        }
        assert!(
            cost_at(&out[0].1, 5.0, 0.0).is_infinite(),
            "the wall is fused"
        );
        assert_eq!(out[2].1.header.layer, CostmapLayer::LOCAL);
        // The far field never came: it is optional, so the maps go out,
        // degraded, naming it.
        assert_eq!(h.health.state(), HealthState::DEGRADED);
        assert_eq!(h.health.report().reason.as_str(), "no bins/polar yet");
        assert_eq!(h.health.report().messages_out, 1);
    }

    #[test]
    fn a_stale_near_field_stops_the_maps_naming_it() {
        let mut h = stage("width_cells = 41\nheight_cells = 41\nuse_far_field = false\n");
        let wake = h.wake_on("costmap/local");
        h.put("state/pose", pose(1, 10 * S));
        h.put("costmap/local", local(1, 10 * S));
        assert_eq!(maps(h.step(wake, 10 * S)).len(), 3);
        assert_eq!(h.health.state(), HealthState::OK);
        // Poses go on; the near field's source died. Past the 1 s deadline
        // on the wall clock: no maps.
        h.put("state/pose", pose(2, 11 * S + S / 2));
        assert!(h.step(Wake::Tick, 11 * S + S / 2).is_empty());
        assert_eq!(h.health.state(), HealthState::DEGRADED);
        assert_eq!(
            h.health.report().reason.as_str(),
            "near field is 1.50 s old (deadline 1 s)"
        );
        // A stale pose stops them too.
        h.put("costmap/local", local(3, 20 * S));
        assert!(h.step(wake, 20 * S).is_empty());
        assert!(h
            .health
            .report()
            .reason
            .as_str()
            .starts_with("state/pose is 8.50 s old"));
    }

    #[test]
    fn answering_the_far_field_publishes_once_a_frame_with_both_fields_in() {
        let mut h = stage(
            "width_cells = 121\nheight_cells = 121\nclock = \"stamps\"\nanswer_far_field = true\n",
        );
        assert!(
            !h.stage.ports().inputs[h.stage.ports().input_index("costmap/local").unwrap()].wakes,
            "the near field waits for the far field"
        );
        // The near field alone (a tick that found it): held, no maps out.
        h.put("state/pose", pose(1, 10 * S));
        h.put("costmap/local", local(1, 10 * S));
        assert!(h.step(Wake::Tick, 10 * S).is_empty());
        // The frame's far field: one set of maps, with the wall of the
        // near field and the far field's free ground 40 m ahead.
        let wake = h.wake_on("bins/polar");
        h.put("bins/polar", polar(1, 10 * S));
        let out = maps(h.step(wake, 10 * S));
        assert_eq!(out.len(), 3);
        assert!(cost_at(&out[0].1, 5.0, 0.0).is_infinite(), "the wall");
        assert!(cost_at(&out[0].1, 40.0, 0.0) < 0.5, "the far field");
        // Refused where it cannot hold: no far field, or the wall clock.
        for bad in [
            "answer_far_field = true\nuse_far_field = false\nclock = \"stamps\"\n",
            "answer_far_field = true\n",
        ] {
            let e = farsight_stage::parse_config::<FusionStageConfig>(bad, "test")
                .unwrap_err()
                .to_string();
            assert!(e.contains("answer_far_field"), "{e}");
        }
    }

    #[test]
    fn answering_the_far_field_a_near_field_taken_on_a_tick_waits_for_it() {
        // A near field 61 x 61 m, overlapping the far field's first ring
        // (25-50 m): applied before the far field, it would leave those
        // cells out of the far-field layer. The process's tick must give
        // the maps the in-process executor gives (both in one step).
        let config =
            "width_cells = 121\nheight_cells = 121\nclock = \"stamps\"\nanswer_far_field = true\n";
        let big_local = || {
            let mut m = local(1, 10 * S);
            let side = 61usize;
            m.header.width = side as u32;
            m.header.height = side as u32;
            m.header.x_min_m = -30.0;
            m.header.y_max_m = 30.0;
            m.data = vec![m.data[0]; side * side];
            m
        };
        let run = |tick_first: bool| {
            let mut h = stage(config);
            h.put("state/pose", pose(1, 10 * S));
            h.put("costmap/local", big_local());
            if tick_first {
                assert!(h.step(Wake::Tick, 10 * S).is_empty());
            }
            let wake = h.wake_on("bins/polar");
            h.put("bins/polar", polar(1, 10 * S));
            maps(h.step(wake, 10 * S))
        };
        let (one_step, tick_first) = (run(false), run(true));
        assert_eq!(one_step.len(), 3);
        // Bit for bit (unobserved cells are NaN).
        let bits = |m: &Costmap| -> Vec<(u32, u32)> {
            m.data
                .iter()
                .map(|c| (c.cost_s_per_m.to_bits(), c.variance.to_bits()))
                .collect()
        };
        for ((topic, a), (_, b)) in one_step.iter().zip(&tick_first) {
            let differ = bits(a).iter().zip(bits(b)).filter(|(x, y)| *x != y).count();
            assert_eq!(differ, 0, "{topic}: cells that differ");
        }
    }

    #[test]
    fn a_stale_far_field_is_left_out_of_the_fused_map() {
        let mut h = stage("width_cells = 121\nheight_cells = 121\n");
        let wake = h.wake_on("bins/polar");
        h.put("state/pose", pose(1, 10 * S));
        h.put("costmap/local", local(1, 10 * S));
        h.put("bins/polar", polar(1, 10 * S));
        let out = maps(h.step(wake, 10 * S));
        let known = cost_at(&out[0].1, 40.0, 0.0);
        assert!(known < 0.5, "the far field 40 m ahead: {known}");
        assert_eq!(h.health.state(), HealthState::OK);
        // 1.5 s on, with a fresh pose and near field but no new bins.
        h.put("state/pose", pose(2, 11 * S + S / 2));
        h.put("costmap/local", local(2, 11 * S + S / 2));
        let out = maps(h.step(h.wake_on("costmap/local"), 11 * S + S / 2));
        assert_eq!(cost_at(&out[0].1, 40.0, 0.0), 1.0, "unknown cost");
        assert!(cost_at(&out[1].1, 40.0, 0.0) < 0.5, "the layer keeps it");
        assert_eq!(h.health.state(), HealthState::DEGRADED);
        assert_eq!(
            h.health.report().reason.as_str(),
            "bins/polar is 1.50 s old (deadline 1 s)"
        );
    }

    #[test]
    fn on_the_wall_clock_maps_go_out_at_the_publish_rate() {
        let mut h = stage("width_cells = 41\nheight_cells = 41\npublish_rate_hz = 2.0\n");
        let wake = h.wake_on("costmap/local");
        let feed = |h: &mut Harness<FusionStage>, seq: u64, t: u64| {
            h.put("state/pose", pose(seq, t));
            h.put("costmap/local", local(seq, t));
            maps(h.step(wake, t)).len()
        };
        assert_eq!(feed(&mut h, 1, 10 * S), 3);
        assert_eq!(feed(&mut h, 2, 10 * S + S / 10), 0, "not due for 0.5 s");
        assert_eq!(feed(&mut h, 3, 10 * S + S / 2), 3);
        // A tick with nothing new republishes once due, keeping the stamp.
        let out = maps(h.step(Wake::Tick, 11 * S));
        assert_eq!(out.len(), 3);
        assert_eq!(out[0].1.header.stamp.frame_seq, 3);
    }

    #[test]
    fn on_the_stamps_clock_each_input_that_changed_the_map_gets_one_set() {
        let mut h = stage("width_cells = 41\nheight_cells = 41\nclock = \"stamps\"\n");
        let wake = h.wake_on("costmap/local");
        h.put("state/pose", pose(1, 10 * S));
        h.put("costmap/local", local(1, 10 * S));
        // The wall time is far from the stamps: it is not the stage's clock.
        assert_eq!(maps(h.step(wake, 500 * S)).len(), 3);
        assert!(h.step(Wake::Tick, 501 * S).is_empty(), "nothing new");
        h.put("costmap/local", local(2, 10 * S + S / 10));
        let out = maps(h.step(wake, 501 * S));
        assert_eq!(out.len(), 3);
        assert_eq!(out[0].1.header.stamp, Stamp::new(1, 10 * S));
        // A pose alone changes no map.
        h.put("state/pose", pose(2, 10 * S + S / 5));
        assert!(h.step(Wake::Tick, 502 * S).is_empty());
    }

    #[test]
    fn malformed_inputs_are_counted_drops_and_the_stage_goes_on() {
        let mut h = stage("width_cells = 41\nheight_cells = 41\nclock = \"stamps\"\n");
        let polar_wake = h.wake_on("bins/polar");
        let local_wake = h.wake_on("costmap/local");
        // Bins before any pose.
        h.put("bins/polar", polar(1, 10 * S));
        assert!(h.step(polar_wake, 0).is_empty());
        // A non-finite pose.
        let mut bad = pose(1, 10 * S);
        bad.position_m[0] = f64::NAN;
        h.put("state/pose", bad);
        assert!(h.step(Wake::Tick, 0).is_empty());
        assert_eq!(h.health.report().dropped, 2);
        // A costmap that promises more cells than it holds; one with a NaN
        // origin; bins with a billion-metre range edge; bins with too few
        // cells.
        h.put("state/pose", pose(2, 10 * S));
        let mut short = local(1, 10 * S);
        short.data.truncate(100);
        h.put("costmap/local", short);
        assert!(h.step(local_wake, 0).is_empty());
        let mut nan = local(2, 10 * S);
        nan.header.x_min_m = f64::NAN;
        h.put("costmap/local", nan);
        assert!(h.step(local_wake, 0).is_empty());
        let mut absurd = polar(2, 10 * S);
        absurd.header.range_edges_m = FixedVec::from_slice(&[25.0, 50.0, 75.0, 1e9]).unwrap();
        h.put("bins/polar", absurd);
        assert!(h.step(polar_wake, 0).is_empty());
        let mut few = polar(3, 10 * S);
        few.data.truncate(95);
        h.put("bins/polar", few);
        assert!(h.step(polar_wake, 0).is_empty());
        assert_eq!(h.health.report().dropped, 6);
        assert_eq!(h.health.report().messages_in, 4);
        // A valid map is fused as usual.
        h.put("costmap/local", local(3, 10 * S));
        let out = maps(h.step(local_wake, 0));
        assert!(cost_at(&out[0].1, 5.0, 0.0).is_infinite());
    }

    /// A camera 1 m up looking ahead and 30 degrees down, 32x24 pixels.
    fn camera() -> Camera {
        Camera::new(
            0,
            "front",
            CameraModel::pinhole(32, 24, 16.0, 16.0, 15.5, 11.5),
            Mount::from_xyz_rpy_deg([0.0, 0.0, 1.0], [0.0, 30.0, 0.0]),
        )
    }

    fn depth(seq: u64, t_ns: u64) -> Image {
        let values = vec![3.0f32; 32 * 24];
        Image {
            header: ImageHeader::packed(Stamp::new(seq, t_ns), 0, 32, 24, PixelEncoding::F32),
            data: bytemuck_bytes(&values),
        }
    }

    fn bytemuck_bytes(v: &[f32]) -> Vec<u8> {
        v.iter().flat_map(|f| f.to_le_bytes()).collect()
    }

    #[test]
    fn a_depth_frame_needs_a_pose_and_a_camera_model() {
        let mut h = stage(
            "width_cells = 41\nheight_cells = 41\nlocal_costmaps = []\nuse_far_field = false\n\
             [near_field]\ndepth_cameras = [\"front\"]\n",
        );
        let wake = h.wake_on("camera/front/depth");
        h.put("camera/front/depth", depth(1, 10 * S));
        assert!(h.step(wake, 10 * S).is_empty());
        h.put("state/pose", pose(1, 10 * S));
        h.put("camera/front/depth", depth(2, 10 * S));
        assert!(h.step(wake, 10 * S).is_empty());
        assert_eq!(h.health.report().dropped, 2, "no pose, then no model");
        // A broken model is a drop too, and still no model.
        let mut broken = camera().to_info(Stamp::default());
        broken.lens = farsight_interfaces::msg::LensModel(7);
        h.put("camera/front/info", broken);
        h.put("camera/front/depth", depth(3, 10 * S));
        assert!(h.step(wake, 10 * S).is_empty());
        assert_eq!(h.health.report().dropped, 4);
        assert_eq!(h.health.report().messages_in, 0);
        h.put("camera/front/info", camera().to_info(Stamp::default()));
        h.put("camera/front/depth", depth(4, 10 * S + S / 10));
        let out = maps(h.step(wake, 10 * S + S / 10));
        assert_eq!(out.len(), 3);
        assert_eq!(out[0].1.header.stamp, Stamp::new(1, 10 * S));
        assert_eq!(h.health.report().messages_in, 1);
        assert_eq!(h.health.state(), HealthState::OK);
    }

    #[test]
    fn ports_are_what_the_config_declares_to_the_graph() {
        use farsight_stage::DeclaresTopics;
        let dir =
            std::env::temp_dir().join(format!("farsight-fusion-ports-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(
            dir.join("classes.toml"),
            "[[class]]\nid = 1\nnavigable = true\ncost_s_per_m = 0.25\n",
        )
        .unwrap();
        for toml in [
            "",
            "local_costmaps = []",
            "use_far_field = false",
            "local_costmaps = [\"lidar\", \"radar\"]\n[near_field]\ndepth_cameras = [\"front\"]\n\
             class_map_cameras = [\"front\", \"rear\"]\nclass_table = \"classes.toml\"",
        ] {
            let h = stage_in(toml, &dir);
            let config: FusionStageConfig = farsight_stage::parse_config(toml, "test").unwrap();
            let io = config.topics("fusion", &dir).unwrap();
            farsight_stage::runtime::check_ports(&io, h.stage.ports()).unwrap();
            for o in &h.stage.ports().outputs {
                assert_eq!(
                    o.max_slice_bytes,
                    201 * 201 * std::mem::size_of::<CostCell>()
                );
            }
        }
        // One info input per camera, however many sources it feeds.
        let h = stage_in(
            "[near_field]\ndepth_cameras = [\"front\"]\nclass_map_cameras = [\"front\"]\n\
             class_table = \"classes.toml\"",
            &dir,
        );
        let infos = h.stage.ports().inputs.iter();
        assert_eq!(infos.filter(|p| p.topic == "camera/front/info").count(), 1);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
