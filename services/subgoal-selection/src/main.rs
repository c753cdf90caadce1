//! `farsight-subgoal-selection`: POVNav on the navigability image, the LRN
//! head on the angular bins, or D* Lite on the fused costmap, turned into a
//! [`Subgoal`] for the servo stage (with the path and the features that
//! explain it; D* Lite's world path goes out on `nav/path/planned` for the
//! servo's carrot tracking). Without a goal it publishes nothing, so the servo
//! stage goes stale and the robot stays put.

use anyhow::Result;
use farsight_costmap_fusion::hip::hip_scaled_costmap;
use farsight_inference::model_config::{ModelConfig, OutputKind};
use farsight_inference::onnx::OnnxModel;
use farsight_interfaces::camera::Camera;
use farsight_interfaces::clock::{Clock, WallClock};
use farsight_interfaces::fixed::FixedVec;
use farsight_interfaces::geo::GoalTracker;
use farsight_interfaces::msg::*;
use farsight_interfaces::topics;
use farsight_interfaces::transport::ipc::{self, Bus, Wake};
use farsight_stage::ClockSource;
use farsight_stage::{load_config, Health, Need, StageArgs, StageInputs};
use farsight_subgoal_selection::hip::{choose, LibraryFile, Trajectory};
use farsight_subgoal_selection::lrn_head::LrnHead;
use farsight_subgoal_selection::planner::WorldPlanner;
use farsight_subgoal_selection::povnav::{plan, safe_half_widths, Mode};
use farsight_subgoal_selection::stage::SubgoalStageConfig;
use std::ops::ControlFlow;
use std::time::Duration;

const STAGE: &str = "subgoal-selection";

fn main() {
    farsight_stage::run_main(STAGE, run);
}

/// Where a pixel's ray meets flat ground, in the robot frame (x ahead, y left).
fn ground_point(camera: &Camera, u: f64, v: f64) -> Option<(f64, f64)> {
    let r = camera.pixel_ray_robot(u, v);
    let h = camera.mount.height_m();
    (r.z < -1e-6 && h > 0.0).then(|| {
        let t = h / -r.z;
        (
            camera.mount.translation_m.x + t * r.x,
            camera.mount.translation_m.y + t * r.y,
        )
    })
}

fn run() -> Result<()> {
    let args = StageArgs::parse(STAGE)?;
    let instance = args.instance.as_str();
    farsight_stage::init_tracing(args.log_format);
    let config: SubgoalStageConfig = load_config(args.config.as_deref())?;
    if ["dstar_lite", "hip"].contains(&config.method.as_str()) {
        // A relative library path is relative to the config file, like a model's.
        return run_map_planner(&config, &args.config_dir(), instance);
    }
    let mut tracker =
        GoalTracker::anchored_at(config.anchor_latitude_deg, config.anchor_longitude_deg)?;
    let povnav = config.method == "povnav";
    let bus = Bus::open(instance)?;
    let nav = bus.slice_subscriber(&topics::navigability(&config.camera))?;
    let bins = bus.subscriber(&topics::angular_bins())?;
    let infos = bus.subscriber(&topics::camera_info(&config.camera))?;
    let poses = bus.subscriber(&topics::pose())?;
    let goals = bus.subscriber(&topics::goal())?;
    let subgoals = bus.publisher(&topics::subgoal())?;
    let visual_path = bus.publisher(&topics::path("visual"))?;
    let visual_path_robot = bus.publisher(&topics::path("visual_robot"))?;
    let mut health = Health::new(&bus, instance, config.health_rate_hz)?;
    farsight_stage::announce_ready(instance);

    let clock = WallClock;
    let mut camera: Option<Camera> = None;
    let mut half_widths: Option<((u32, u32), Vec<usize>)> = None;
    let mut head = LrnHead::default();
    let mut lrn_cfg = config.lrn;
    lrn_cfg.goal_heuristic |= config.method == "goal_heuristic";
    let input = if povnav {
        nav.listener()
    } else {
        bins.listener()
    };
    // The image or the bins, and the pose that places the goal: both
    // required, and a subgoal carries the older capture of the two.
    let mut inputs = StageInputs::new(config.input_deadline_s);
    let primary_in = inputs.add(
        &if povnav {
            topics::navigability(&config.camera).name().to_string()
        } else {
            topics::angular_bins().name().to_string()
        },
        Need::Required,
    );
    let pose_in = inputs.add(topics::pose().name(), Need::Required);
    // A stale required input: no subgoal (the servo's input then ages).
    let judge = |inputs: &StageInputs, health: &mut Health| -> Option<Stamp> {
        let freshness = inputs.check(inputs.now_ns(config.clock));
        if freshness.is_stale() {
            health.set(HealthState::DEGRADED, freshness.reason());
            return None;
        }
        inputs.output_stamp()
    };
    ipc::wait_loop(&[input], Some(Duration::from_millis(200)), |wake| {
        let now = clock.now_ns();
        if let Ok(Some(i)) = infos.latest() {
            match Camera::from_info(&i) {
                Ok(c) => camera = Some(c),
                Err(e) => health.dropped(&format_args!("camera info: {e}")),
            }
        }
        if let Ok(Some(p)) = poses.latest() {
            inputs.consumed(pose_in, p.stamp);
            tracker.set_pose(p);
        }
        if let Ok(Some(g)) = goals.latest() {
            tracker.set_goal(g);
        }
        health.tick(now);
        if wake == Wake::Tick {
            return ControlFlow::Continue(());
        }
        let target = tracker.goal_in_robot_frame();
        if povnav {
            let Ok(Some(frame)) = nav.latest() else {
                return ControlFlow::Continue(());
            };
            health.input();
            let h = *frame.header();
            inputs.consumed(primary_in, h.stamp);
            let Some((bearing, _)) = target else {
                health.set(
                    HealthState::DEGRADED,
                    "no goal (or pose) yet: no subgoal published",
                );
                return ControlFlow::Continue(());
            };
            let Some(cam) = &camera else {
                health.dropped(&"no camera model yet on camera/<name>/info");
                return ControlFlow::Continue(());
            };
            if let Err(e) = h.validate(frame.data().len()) {
                health.dropped(&e);
                return ControlFlow::Continue(());
            }
            if h.encoding != PixelEncoding::MONO8 {
                health.dropped(&format_args!(
                    "navigability must be mono8, got {}",
                    h.encoding
                ));
                return ControlFlow::Continue(());
            }
            let Some(stamp) = judge(&inputs, &mut health) else {
                return ControlFlow::Continue(());
            };
            let size = (h.width, h.height);
            if half_widths.as_ref().is_none_or(|(s, _)| *s != size) {
                let m = cam.model.scaled_to(h.width, h.height);
                let hw = safe_half_widths(
                    h.height as usize,
                    m.fx,
                    m.fy,
                    m.cy,
                    cam.mount.height_m(),
                    config.robot_width_m,
                    config.safety_margin_m,
                );
                half_widths = Some((size, hw));
            }
            let hw = &half_widths.as_ref().expect("just set").1;
            let p = plan(
                frame.data(),
                h.width as usize,
                h.height as usize,
                bearing,
                hw,
                &config.povnav,
            );
            let scaled = Camera {
                model: cam.model.scaled_to(h.width, h.height),
                ..cam.clone()
            };
            let (gx, gy) =
                ground_point(&scaled, p.hog_px.0, p.hog_px.1).unwrap_or((f64::NAN, f64::NAN));
            let mode = match p.mode {
                Mode::Safe => ServoMode::SAFE,
                Mode::Fallback => ServoMode::FALLBACK,
                Mode::Blocked => ServoMode::BLOCKED,
            };
            let subgoal = Subgoal {
                stamp,
                source: SubgoalSource::POVNAV,
                mode,
                heading_rad: p.alignment_rad as f32,
                x_m: gx as f32,
                y_m: gy as f32,
                image_u_px: p.hog_px.0 as f32,
                image_v_px: p.hog_px.1 as f32,
                proximity_lambda_px: p.proximity_px as f32,
                alignment_phi_rad: p.alignment_rad as f32,
            };
            let points: Vec<[f32; 2]> = p
                .path_px
                .iter()
                .map(|&(u, v)| [u as f32, v as f32])
                .collect();
            let path = Path {
                stamp,
                frame: PathFrame::IMAGE,
                camera_id: h.camera_id,
                points: FixedVec::from_slice(&points[..points.len().min(MAX_PATH_POINTS)])
                    .unwrap_or_default(),
            };
            // The same path on the ground, robot frame (metres): pixels at or
            // above the horizon line have no ground point and are left out.
            let ground: Vec<[f32; 2]> = p
                .path_px
                .iter()
                .filter_map(|&(u, v)| ground_point(&scaled, u, v))
                .filter(|&(x, y)| x.hypot(y) <= config.path_max_range_m)
                .map(|(x, y)| [x as f32, y as f32])
                .collect();
            let path_robot = Path {
                frame: PathFrame::ROBOT,
                points: FixedVec::from_slice(&ground[..ground.len().min(MAX_PATH_POINTS)])
                    .unwrap_or_default(),
                ..path
            };
            match subgoals
                .publish(&subgoal)
                .and_then(|()| visual_path.publish(&path))
                .and_then(|()| visual_path_robot.publish(&path_robot))
            {
                Ok(()) => {
                    health.set(HealthState::OK, "");
                    health.output(stamp, clock.now_ns());
                }
                Err(e) => health.dropped(&e),
            }
        } else {
            let Ok(Some(b)) = bins.latest() else {
                return ControlFlow::Continue(());
            };
            health.input();
            inputs.consumed(primary_in, b.stamp);
            let Some((bearing, distance)) = target else {
                health.set(
                    HealthState::DEGRADED,
                    "no goal (or pose) yet: no subgoal published",
                );
                return ControlFlow::Continue(());
            };
            let k = b.scores.len();
            let centers: Vec<f64> = (0..k)
                .map(|i| b.first_bin_start_rad as f64 + (i as f64 + 0.5) * b.bin_width_rad as f64)
                .collect();
            let scores: Vec<f64> = b.scores.as_slice().iter().map(|&s| s as f64).collect();
            let observed: Vec<bool> = (0..k)
                .map(|i| b.observed.as_slice().get(i).is_some_and(|&o| o == 1))
                .collect();
            if let Some(p) = tracker.pose() {
                head.set_robot_yaw(p.yaw_rad);
            }
            let Some(heading) =
                head.select(&lrn_cfg, &scores, &observed, &centers, bearing, distance)
            else {
                health.set(HealthState::DEGRADED, "no affordable observed bin");
                return ControlFlow::Continue(());
            };
            let Some(stamp) = judge(&inputs, &mut health) else {
                return ControlFlow::Continue(());
            };
            let d = config.subgoal_distance_m.min(distance);
            let subgoal = Subgoal {
                stamp,
                source: if lrn_cfg.goal_heuristic {
                    SubgoalSource::GOAL_HEURISTIC
                } else {
                    SubgoalSource::LRN
                },
                mode: ServoMode::SAFE,
                heading_rad: heading as f32,
                x_m: (d * heading.cos()) as f32,
                y_m: (d * heading.sin()) as f32,
                image_u_px: f32::NAN,
                image_v_px: f32::NAN,
                proximity_lambda_px: f32::NAN,
                alignment_phi_rad: f32::NAN,
            };
            match subgoals.publish(&subgoal) {
                Ok(()) => {
                    health.set(HealthState::OK, "");
                    health.output(stamp, clock.now_ns());
                }
                Err(e) => health.dropped(&e),
            }
        }
        ControlFlow::Continue(())
    })?;
    health.stopping(clock.now_ns());
    Ok(())
}

/// What plans on the costmap: D* Lite (a world-fixed grid per goal) or HIP
/// (the trajectory library over the latest HIP-scaled costmap).
enum MapPlanner {
    DStarLite(Option<WorldPlanner>),
    Hip {
        library: Vec<Trajectory>,
        /// The latest costmap's header and its HIP-scaled cells.
        costmap: Option<(CostmapHeader, Vec<f32>)>,
        /// The learned density model, and -log q per trajectory of the newest frame.
        model: Option<Box<OnnxModel>>,
        learned: Option<Vec<f64>>,
    },
}

/// Loads HIP's learned model; its trajectory output must score exactly the
/// library's trajectories.
fn load_hip_model(path: &std::path::Path, library_len: usize) -> Result<Box<OnnxModel>> {
    let cfg = ModelConfig::load(path)?;
    let Some(out) = cfg
        .outputs
        .iter()
        .find(|o| o.kind == OutputKind::TrajectoryLogLikelihood)
    else {
        anyhow::bail!(
            "{}: no output of kind \"trajectory_log_likelihood\" for HIP's learned cost",
            path.display()
        );
    };
    if out.classes != library_len {
        anyhow::bail!(
            "{}: output {:?} scores {} trajectories but the HIP library holds {library_len}",
            path.display(),
            out.name,
            out.classes
        );
    }
    Ok(Box::new(OnnxModel::load(&cfg)?))
}

impl MapPlanner {
    fn source(&self) -> SubgoalSource {
        match self {
            MapPlanner::DStarLite(_) => SubgoalSource::DSTAR_LITE,
            MapPlanner::Hip { .. } => SubgoalSource::HIP,
        }
    }
}

/// The costmap planners' loop: feed each costmap to the planner, replan from
/// the robot at most `replan_rate_hz` (and on every change for D* Lite),
/// publish the world path on `nav/path/planned` and a subgoal
/// `subgoal_distance_m` along it.
fn run_map_planner(
    config: &SubgoalStageConfig,
    base_dir: &std::path::Path,
    instance: &str,
) -> Result<()> {
    let mut planner = match config.method.as_str() {
        "hip" => {
            let file: LibraryFile =
                farsight_stage::load_config_file(&base_dir.join(&config.hip_library))?;
            tracing::info!(trajectories = file.trajectories.len(), "HIP library loaded");
            let library: Vec<Trajectory> = file.trajectories.into_iter().map(Trajectory).collect();
            let model = if config.hip_model.as_os_str().is_empty() {
                tracing::warn!("no hip_model: the learned term -log q is 0 for every trajectory");
                None
            } else {
                Some(load_hip_model(
                    &base_dir.join(&config.hip_model),
                    library.len(),
                )?)
            };
            MapPlanner::Hip {
                library,
                costmap: None,
                model,
                learned: None,
            }
        }
        _ => MapPlanner::DStarLite(None),
    };
    let mut tracker =
        GoalTracker::anchored_at(config.anchor_latitude_deg, config.anchor_longitude_deg)?;
    let bus = Bus::open(instance)?;
    let costmaps = bus.slice_subscriber(&topics::costmap(&config.costmap))?;
    let poses = bus.subscriber(&topics::pose())?;
    let goals = bus.subscriber(&topics::goal())?;
    let subgoals = bus.publisher(&topics::subgoal())?;
    let planned = bus.publisher(&topics::path("planned"))?;
    let mut health = Health::new(&bus, instance, config.health_rate_hz)?;
    farsight_stage::announce_ready(instance);

    let clock = WallClock;
    let mut pose: Option<Pose> = None;
    // The costmap and the pose are required; a plan (and every replan of
    // it) carries the older capture of the two. HIP's camera image is
    // optional: stale, the learned term is left out.
    let mut inputs = StageInputs::new(config.input_deadline_s);
    let costmap_in = inputs.add(topics::costmap(&config.costmap).name(), Need::Required);
    let pose_in = inputs.add(topics::pose().name(), Need::Required);
    let image_in = matches!(planner, MapPlanner::Hip { model: Some(_), .. })
        .then(|| inputs.add(topics::camera_image(&config.camera).name(), Need::Optional));
    let mut dirty = true;
    let period_ns = (1e9 / config.replan_rate_hz) as u64;
    let mut next_plan = 0u64;
    let images = bus.slice_subscriber(&topics::camera_image(&config.camera))?;
    ipc::wait_loop(
        &[costmaps.listener(), images.listener()],
        Some(Duration::from_millis(50)),
        |_| {
            let now = clock.now_ns();
            health.tick(now);
            let mut fresh_costmap = false;
            if let MapPlanner::Hip {
                model: Some(model),
                learned,
                ..
            } = &mut planner
            {
                // The learned term: -log q(tau | o) of each trajectory for the newest frame.
                if let Ok(Some(frame)) = images.latest() {
                    if let Some(id) = image_in {
                        inputs.consumed(id, frame.header().stamp);
                    }
                    let mut timings = Default::default();
                    let out = model.run(frame.header(), frame.data(), &mut timings, |outputs| {
                        farsight_inference::Perception::from_outputs(outputs, None)
                    });
                    match out {
                        Ok(Ok(p)) => {
                            *learned = p
                                .trajectory_log_q
                                .map(|q| q.iter().map(|&v| -(v as f64)).collect());
                            dirty = true;
                        }
                        Ok(Err(e)) => {
                            // Never score with an older frame's output.
                            *learned = None;
                            health.dropped(&format_args!("HIP model output: {e}"));
                        }
                        Err(e) => {
                            *learned = None;
                            health.dropped(&format_args!("HIP model: {e}"));
                        }
                    }
                }
            }
            if let Ok(Some(p)) = poses.latest() {
                inputs.consumed(pose_in, p.stamp);
                tracker.set_pose(p);
                pose = Some(p);
            }
            if let Ok(Some(g)) = goals.latest() {
                tracker.set_goal(g);
            }
            let (Some(p), Some((bearing, distance))) = (pose, tracker.goal_in_robot_frame()) else {
                health.set(
                    HealthState::DEGRADED,
                    "no goal (or pose) yet: nothing to plan",
                );
                return ControlFlow::Continue(());
            };
            let robot = [p.position_m[0], p.position_m[1]];
            let goal_robot = [distance * bearing.cos(), distance * bearing.sin()];
            let goal = p.to_world_frame(goal_robot);
            if let MapPlanner::DStarLite(pl) = &mut planner {
                let new_goal = pl.as_ref().is_none_or(|pl| {
                    let g = pl.goal_m();
                    (g[0] - goal[0]).hypot(g[1] - goal[1]) > config.planner.resolution_m
                });
                // A robot that left the grid (relocalised, carried, a
                // simulator started over) gets a grid around where it is.
                let left_grid = pl.as_ref().is_some_and(|pl| !pl.contains(robot));
                if new_goal || left_grid {
                    tracing::info!(
                        goal_x_m = goal[0],
                        goal_y_m = goal[1],
                        robot_x_m = robot[0],
                        robot_y_m = robot[1],
                        "{}: planning grid built",
                        if new_goal {
                            "new goal"
                        } else {
                            "the robot left the grid"
                        }
                    );
                    *pl = Some(WorldPlanner::new(robot, goal, &config.planner));
                    dirty = true;
                }
            }
            match costmaps.latest() {
                Ok(Some(c)) => {
                    health.input();
                    let h = *c.header();
                    if let Err(e) = h.validate(c.data().len()) {
                        health.dropped(&format_args!("costmap/{}: {e}", config.costmap));
                    } else {
                        inputs.consumed(costmap_in, h.stamp);
                        fresh_costmap = true;
                        match &mut planner {
                            MapPlanner::DStarLite(pl) => {
                                let pl = pl.as_mut().expect("built above");
                                dirty |= pl.apply_costmap(&h, c.data()) > 0;
                            }
                            MapPlanner::Hip { costmap, .. } => {
                                let costs: Vec<f32> =
                                    c.data().iter().map(|c| c.cost_s_per_m).collect();
                                *costmap = Some((h, hip_scaled_costmap(&costs, config.hip.alpha)));
                            }
                        }
                    }
                }
                Ok(None) => {}
                Err(e) => health.dropped(&e),
            }
            let due = match config.clock {
                // One plan per costmap message: each frame is planned on once.
                ClockSource::Stamps => fresh_costmap,
                ClockSource::Wall => dirty || now >= next_plan,
            };
            if !due {
                return ControlFlow::Continue(());
            }
            let input_now = inputs.now_ns(config.clock);
            let freshness = inputs.check(input_now);
            let stamp = match inputs.output_stamp() {
                Some(stamp) if !freshness.is_stale() => stamp,
                _ => {
                    // No plan from a map or pose the robot has left behind.
                    health.set(HealthState::DEGRADED, freshness.reason());
                    return ControlFlow::Continue(());
                }
            };
            let learned_fresh = image_in.is_some_and(|id| inputs.is_fresh(id, input_now));
            dirty = false;
            next_plan = now + period_ns;
            let source = planner.source();
            let path: Vec<[f64; 2]> = match &mut planner {
                MapPlanner::DStarLite(pl) => {
                    let pl = pl.as_mut().expect("built above");
                    match pl.plan(robot) {
                        Ok((path, cost_s)) => {
                            tracing::debug!(
                                cost_s,
                                cells = path.len(),
                                expanded = pl.expanded(),
                                "planned"
                            );
                            path
                        }
                        Err(e) => {
                            health.set(HealthState::DEGRADED, &e.to_string());
                            return ControlFlow::Continue(());
                        }
                    }
                }
                MapPlanner::Hip {
                    library,
                    costmap,
                    learned,
                    ..
                } => {
                    let Some((h, scaled)) = costmap else {
                        health.set(
                            HealthState::DEGRADED,
                            "no costmap yet: HIP has nothing to score",
                        );
                        return ControlFlow::Continue(());
                    };
                    // Off the map is unknown: the scaled value of the unknown cost
                    // would need the map's softmax sum, so count it as free (0)
                    // rather than invent one; the directive still pulls to the goal.
                    let at = |q: [f64; 2]| {
                        let w = p.to_world_frame(q);
                        match h.cell_index(w[0], w[1]).map(|k| scaled[k]) {
                            Some(v) if !v.is_nan() => v as f64,
                            _ => 0.0,
                        }
                    };
                    let learned = learned.as_deref().filter(|_| learned_fresh);
                    match choose(library, goal_robot, at, learned, &config.hip) {
                        Some(c) => {
                            tracing::debug!(?c, "HIP choice");
                            std::iter::once(robot)
                                .chain(library[c.index].0.iter().map(|&q| p.to_world_frame(q)))
                                .collect()
                        }
                        None => {
                            health.set(
                                HealthState::DEGRADED,
                                "every HIP trajectory crosses a lethal cell",
                            );
                            return ControlFlow::Continue(());
                        }
                    }
                }
            };
            let points: Vec<[f32; 2]> = path
                .iter()
                .take(MAX_PATH_POINTS)
                .map(|q| [q[0] as f32, q[1] as f32])
                .collect();
            let msg = Path {
                stamp,
                frame: PathFrame::WORLD,
                camera_id: 0,
                points: FixedVec::from_slice(&points).unwrap_or_default(),
            };
            // The subgoal: the first path point subgoal_distance_m away (or the end).
            let target = path
                .iter()
                .map(|&q| p.to_robot_frame(q))
                .find(|r| r[0].hypot(r[1]) >= config.subgoal_distance_m)
                .or_else(|| path.last().map(|&q| p.to_robot_frame(q)))
                .unwrap_or([0.0, 0.0]);
            let subgoal = Subgoal {
                stamp,
                source,
                mode: ServoMode::SAFE,
                heading_rad: target[1].atan2(target[0]) as f32,
                x_m: target[0] as f32,
                y_m: target[1] as f32,
                image_u_px: f32::NAN,
                image_v_px: f32::NAN,
                proximity_lambda_px: f32::NAN,
                alignment_phi_rad: f32::NAN,
            };
            match planned
                .publish(&msg)
                .and_then(|()| subgoals.publish(&subgoal))
            {
                Ok(()) => {
                    health.set(HealthState::OK, "");
                    health.output(stamp, now);
                }
                Err(e) => health.dropped(&e),
            }
            ControlFlow::Continue(())
        },
    )?;
    health.stopping(clock.now_ns());
    Ok(())
}
