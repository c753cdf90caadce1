//! The subgoal-selection stage as a library type ([`SubgoalStage`]): where
//! the robot should head next, as a [`Subgoal`] for the servo stage, from
//! one of five methods (`method` in the config):
//!
//! - `povnav`: POVNav (sections 4.3-4.7) on the navigability image: the
//!   horizon optic goal and the visual path, with the proximity and
//!   alignment features the servo's control law takes, and the path in the
//!   image (`nav/path/visual`) and on the ground (`nav/path/visual_robot`).
//! - `lrn` and `goal_heuristic`: LRN's goal-conditioned head (Algorithm 1)
//!   on the angular bins; the heading becomes a subgoal
//!   `subgoal_distance_m` out (the goal heuristic is the same head with
//!   uniform scores).
//! - `dstar_lite`: FITAM's sense-plan-act loop (section IV-E): D* Lite on the
//!   fused costmap in a world-fixed grid, repaired incrementally per map.
//! - `hip`: HIP's trajectory library scored by eq. (1) (sections II-III) on
//!   the HIP-scaled costmap, with the learned term -log q from a model on
//!   the camera image when one is configured.
//!
//! The costmap planners publish their world path on `nav/path/planned`
//! (the servo's carrot tracking) and a subgoal `subgoal_distance_m` along
//! it. A costmap they cannot plan on (D* Lite finds no path, every HIP
//! trajectory crosses a lethal cell) is answered with an empty path, on
//! which the servo stops: a lock-step simulator gets its answer, and the
//! robot stops now rather than when its last command expires. LRN's head
//! answers fresh bins with no affordable observed bin (`no_hotspot =
//! "stop"`) the same way, with a `BLOCKED` subgoal, and a planner it
//! guides answers that frame with an empty path. Without a
//! goal no method publishes anything: the servo's input then ages and the
//! robot stays put.
//!
//! Every output carries the older capture of its required inputs (the
//! image, bins or costmap; and the pose), and a stale required input gives
//! no output, so a dead stage upstream stops the robot through the servo's
//! deadline. With `clock = "stamps"` (lock-step simulation, replays) ages
//! are judged on the inputs' capture times, and the costmap planners plan
//! once per costmap, so a run is the same on any machine.

use crate::hip::{choose, lethal_clearance_m, required_clearance_m, LibraryFile, Trajectory};
use crate::lrn_head::{LrnHead, LrnHeadConfig};
use crate::planner::WorldPlanner;
use crate::povnav::{plan, safe_half_widths, Mode, PovnavComponents};
use crate::stage::SubgoalStageConfig;
use farsight_costmap_fusion::hip::hip_scaled_costmap;
use farsight_inference::model_config::{ModelConfig, OutputKind};
use farsight_inference::onnx::OnnxModel;
use farsight_interfaces::camera::Camera;
use farsight_interfaces::fixed::FixedVec;
use farsight_interfaces::geo::GoalTracker;
use farsight_interfaces::message::{Costmap, Image};
use farsight_interfaces::msg::{
    AngularBins, CameraInfo, CostmapHeader, HealthState, NavGoal, Path, PathFrame, PixelEncoding,
    Pose, ServoMode, Stamp, Subgoal, SubgoalSource, MAX_PATH_POINTS,
};
use farsight_interfaces::topics;
use farsight_stage::inputs::InputId;
use farsight_stage::{
    ClockSource, HealthReport, Need, Ports, Stage, StageEnv, StageInputs, StageKind, Step,
};
use std::time::Duration;

/// The subgoal stage: one instance, its state between steps.
pub struct SubgoalStage {
    ports: Ports,
    cx: Context,
    method: Method,
}

/// What every method shares: the config, the common ports, the goal and
/// the freshness of the required inputs.
struct Context {
    config: SubgoalStageConfig,
    port: PortIds,
    tracker: GoalTracker,
    inputs: StageInputs,
    primary_in: InputId,
    pose_in: InputId,
    /// With a `guide`: its input and its latest subgoal, this instance's goal.
    guide_in: Option<InputId>,
    guide: Option<Subgoal>,
    /// The latest poses, oldest first: a guide's subgoal is in the robot
    /// frame of the frame it was made from, so it is placed with the pose
    /// of that frame's capture, not the newest one.
    poses: std::collections::VecDeque<Pose>,
}

/// Poses kept for [`Context::pose_at`]: a few seconds at a localisation
/// stack's 10-50 Hz.
const POSE_HISTORY: usize = 128;

/// Whether a frame can be planned on: with a guide, only together with the
/// guide's subgoal of the same frame (an exact-time join on the frame
/// number, so a lock-step run plans each frame on the same pair whichever
/// chain answered first).
#[derive(Debug, Clone, Copy, PartialEq)]
enum Join {
    Ready,
    /// The guide has not answered this frame yet: keep it.
    Wait,
    /// The guide answered a later frame: this one will never pair.
    Missed,
}

/// The ports every method has.
struct PortIds {
    /// The navigability image, the angular bins or the costmap: wakes the step.
    primary: usize,
    pose: usize,
    /// `nav/goal`, or the guide's subgoal topic (which also wakes the step).
    goal: usize,
    subgoal: usize,
}

/// The ports only some methods have.
enum MethodPorts {
    Povnav {
        camera_info: usize,
        visual_path: usize,
        visual_path_robot: usize,
    },
    Heading,
    Map {
        planned: usize,
        /// HIP with a learned model: the camera image it runs on.
        image: Option<usize>,
    },
}

enum Method {
    Povnav(Box<Povnav>),
    Heading(Heading),
    Map(Box<MapPlan>),
}

fn is_map_method(method: &str) -> bool {
    ["dstar_lite", "hip"].contains(&method)
}

fn has_hip_model(config: &SubgoalStageConfig) -> bool {
    config.method == "hip" && !config.hip_model.as_os_str().is_empty()
}

/// The ports of a config's method (no files read, so tests can check any
/// config's ports against what it declares to the graph).
fn declare_ports(config: &SubgoalStageConfig) -> (Ports, PortIds, MethodPorts) {
    let map = is_map_method(&config.method);
    let mut ports = Ports {
        // The image-space methods answer their input; the tick only keeps
        // the health report going. The costmap planners also replan on it
        // (at most `replan_rate_hz`, on the wall clock).
        tick: Some(Duration::from_millis(if map { 50 } else { 200 })),
        health_rate_hz: config.health_rate_hz,
        ..Ports::default()
    };
    let primary = match config.method.as_str() {
        "povnav" => topics::navigability(&config.camera).name().to_string(),
        "dstar_lite" | "hip" => topics::costmap(&config.costmap).name().to_string(),
        _ => topics::angular_bins().name().to_string(),
    };
    let primary = ports.waking_input(primary);
    let image = has_hip_model(config)
        .then(|| ports.waking_input(topics::camera_image(&config.camera).name()));
    let camera_info = (config.method == "povnav")
        .then(|| ports.input(topics::camera_info(&config.camera).name()));
    let pose = ports.input(topics::pose().name());
    let goal = match config.guide.as_str() {
        "" => ports.input(topics::goal().name()),
        guide => ports.waking_input(guide),
    };
    // Output order is send order: the planned path goes before the subgoal
    // made from it, the visual paths after the subgoal.
    let planned = map.then(|| ports.output(topics::path("planned").name()));
    let subgoal = ports.output(config.subgoal_topic.as_str());
    let method = match (camera_info, planned) {
        (Some(camera_info), _) => MethodPorts::Povnav {
            camera_info,
            visual_path: ports.output(topics::path("visual").name()),
            visual_path_robot: ports.output(topics::path("visual_robot").name()),
        },
        (None, Some(planned)) => MethodPorts::Map { planned, image },
        (None, None) => MethodPorts::Heading,
    };
    let ids = PortIds {
        primary,
        pose,
        goal,
        subgoal,
    };
    (ports, ids, method)
}

impl StageKind for SubgoalStage {
    const KIND: &'static str = "subgoal-selection";
    type Config = SubgoalStageConfig;

    fn new(config: SubgoalStageConfig, env: &StageEnv) -> anyhow::Result<Self> {
        let (ports, port, method_ports) = declare_ports(&config);
        // The primary input (the image, bins or costmap) and the pose that
        // places the goal are both required; the primary is declared first,
        // so an output carries its frame number (what a lock-step player
        // waits for) and the older capture time of the two.
        let mut inputs = StageInputs::new(config.input_deadline_s);
        let primary_in = inputs.add(&ports.inputs[port.primary].topic, Need::Required);
        let pose_in = inputs.add(topics::pose().name(), Need::Required);
        // A guide that stops answering stops this instance like a stale
        // pose does: no subgoal towards a heading the robot has left behind.
        let guide_in =
            (!config.guide.is_empty()).then(|| inputs.add(&config.guide, Need::Required));
        let method = match method_ports {
            MethodPorts::Povnav {
                camera_info,
                visual_path,
                visual_path_robot,
            } => Method::Povnav(Box::new(Povnav {
                camera_info,
                visual_path,
                visual_path_robot,
                camera: None,
                half_widths: None,
                vmpp: None,
                pending: None,
            })),
            MethodPorts::Heading => {
                let mut lrn = config.lrn;
                lrn.goal_heuristic |= config.method == "goal_heuristic";
                Method::Heading(Heading {
                    head: LrnHead::default(),
                    lrn,
                })
            }
            MethodPorts::Map { planned, image } => {
                // HIP's camera image is optional: stale, the learned term
                // is left out of the score.
                let image = image.map(|port| {
                    let id =
                        inputs.add(topics::camera_image(&config.camera).name(), Need::Optional);
                    (port, id)
                });
                Method::Map(Box::new(MapPlan {
                    planner: MapPlanner::load(&config, &env.config_dir)?,
                    planned,
                    image,
                    image_seq: None,
                    pending: None,
                    dirty: true,
                    period_ns: (1e9 / config.replan_rate_hz) as u64,
                    next_plan: 0,
                    requested_goal_m: None,
                }))
            }
        };
        let tracker =
            GoalTracker::anchored_at(config.anchor_latitude_deg, config.anchor_longitude_deg)?;
        Ok(Self {
            ports,
            cx: Context {
                config,
                port,
                tracker,
                inputs,
                primary_in,
                pose_in,
                guide_in,
                guide: None,
                poses: Default::default(),
            },
            method,
        })
    }
}

impl Stage for SubgoalStage {
    fn ports(&self) -> &Ports {
        &self.ports
    }

    fn step(&mut self, step: &mut Step<'_>) {
        // The health report stays on the wall clock (`step.now_ns` as the
        // runner set it) with either `clock`: only the inputs' ages are
        // judged on the stamps, so on the stamps' clock, where time stands
        // still without inputs, the report still goes out at its rate.
        match &mut self.method {
            Method::Povnav(m) => m.step(&mut self.cx, step),
            Method::Heading(m) => m.step(&mut self.cx, step),
            Method::Map(m) => m.step(&mut self.cx, step),
        }
    }
}

const NO_GOAL: &str = "no goal (or pose) yet: no subgoal published";

impl Context {
    /// Takes this step's pose and goal in.
    fn receive(&mut self, step: &mut Step<'_>) {
        if let Some(p) = step.inbox.take::<Pose>(self.port.pose) {
            self.inputs.consumed(self.pose_in, p.stamp);
            self.tracker.set_pose(p);
            if self.poses.len() == POSE_HISTORY {
                self.poses.pop_front();
            }
            self.poses.push_back(p);
        }
        match self.guide_in {
            Some(id) => {
                if let Some(g) = step.inbox.take::<Subgoal>(self.port.goal) {
                    self.inputs.consumed(id, g.stamp);
                    self.guide = Some(g);
                }
            }
            None => {
                if let Some(g) = step.inbox.take::<NavGoal>(self.port.goal) {
                    self.tracker.set_goal(g);
                }
            }
        }
    }

    /// The pose at capture time `t_ns`: the newest one captured at or
    /// before it, or the oldest kept when none is that old.
    fn pose_at(&self, t_ns: u64) -> Option<Pose> {
        self.poses
            .iter()
            .rev()
            .find(|p| p.stamp.capture_time_ns <= t_ns)
            .or(self.poses.front())
            .copied()
    }

    /// Whether frame `frame_seq` can be planned on now (see [`Join`]).
    fn join(&self, frame_seq: u64) -> Join {
        match (self.guide_in, &self.guide) {
            (None, _) => Join::Ready,
            (Some(_), None) => Join::Wait,
            (Some(_), Some(g)) => match g.stamp.frame_seq.cmp(&frame_seq) {
                std::cmp::Ordering::Equal => Join::Ready,
                std::cmp::Ordering::Less => Join::Wait,
                std::cmp::Ordering::Greater => Join::Missed,
            },
        }
    }

    /// Whether `pending`, the input `what` of frame `seq`, can be planned
    /// on now; one that can never pair is dropped (counted, logged).
    fn joined<T>(
        &self,
        pending: &mut Option<T>,
        seq: u64,
        what: &str,
        health: &mut HealthReport,
    ) -> bool {
        match self.join(seq) {
            Join::Ready => true,
            Join::Wait => false,
            Join::Missed => {
                *pending = None;
                health.dropped(&format_args!(
                    "{what} of frame {seq}: the guide answered a later frame, never this one"
                ));
                false
            }
        }
    }

    /// The goal's bearing and distance in the robot frame: `nav/goal`
    /// through the pose, or the guide's subgoal (already in the robot
    /// frame of its frame; `frame_seq` given, only that frame's).
    fn goal_in_robot_frame(&self, frame_seq: Option<u64>) -> Option<(f64, f64)> {
        if self.guide_in.is_none() {
            return self.tracker.goal_in_robot_frame();
        }
        let g = self
            .guide
            .filter(|g| frame_seq.is_none_or(|k| g.stamp.frame_seq == k))?;
        let (x, y) = (g.x_m as f64, g.y_m as f64);
        (x.is_finite() && y.is_finite()).then(|| (y.atan2(x), x.hypot(y)))
    }

    /// The stamp an output made now carries; `None` (and the stage
    /// degraded, naming the input) when a required input is stale: no
    /// subgoal, so the servo's input ages.
    fn judge(&self, wall_ns: u64, health: &mut HealthReport) -> Option<Stamp> {
        let freshness = self
            .inputs
            .check(self.inputs.now_at(self.config.clock, wall_ns));
        if freshness.is_stale() {
            health.set(HealthState::DEGRADED, freshness.reason());
            return None;
        }
        self.inputs.output_stamp()
    }
}

/// POVNav's state: the camera model, and the safe half-widths of the
/// footprint per image row (recomputed only when the image size changes).
struct Povnav {
    camera_info: usize,
    visual_path: usize,
    visual_path_robot: usize,
    camera: Option<Camera>,
    half_widths: Option<((u32, u32), Vec<usize>)>,
    /// VMPP's primitives and their arcs in the image (`povnav.components =
    /// "vmpp"`), per image size.
    vmpp: Option<VmppArcs>,
    /// A frame waiting for its guide's subgoal.
    pending: Option<Image>,
}

/// The pixel where the ground point (x ahead, y left, metres, robot frame)
/// appears in `camera`'s image; `None` behind it.
fn ground_pixel(camera: &Camera, x_m: f64, y_m: f64) -> Option<(f64, f64)> {
    let rel = nalgebra::Vector3::new(x_m, y_m, 0.0) - camera.mount.translation_m;
    let optical = camera
        .mount
        .robot_from_optical
        .inverse_transform_vector(&rel);
    camera.model.project(&optical).map(|p| (p.x, p.y))
}

/// VMPP's motion primitives and each arc point's pixel, for one image size.
struct VmppArcs {
    size: (u32, u32),
    primitives: Vec<crate::vmpp::Primitive>,
    pixels: Vec<Vec<Option<(f64, f64)>>>,
}

impl Povnav {
    fn step(&mut self, cx: &mut Context, step: &mut Step<'_>) {
        if let Some(i) = step.inbox.take::<CameraInfo>(self.camera_info) {
            match Camera::from_info(&i) {
                Ok(c) => {
                    // Tables made for another model are stale.
                    if self.camera.as_ref() != Some(&c) {
                        self.half_widths = None;
                        self.vmpp = None;
                    }
                    self.camera = Some(c);
                }
                Err(e) => step.health.dropped(&format_args!("camera info: {e}")),
            }
        }
        cx.receive(step);
        // A frame is planned on in the step it arrives in (the runner drops
        // what a step leaves), or with a guide in the step its guide's
        // subgoal arrives in.
        if let Some(frame) = step.inbox.take::<Image>(cx.port.primary) {
            step.health.input();
            cx.inputs.consumed(cx.primary_in, frame.header.stamp);
            if let Some(old) = self.pending.replace(frame) {
                if cx.guide_in.is_some() {
                    step.health.dropped(&format_args!(
                        "frame {}: no guide subgoal for it before the next frame",
                        old.header.stamp.frame_seq
                    ));
                }
            }
        }
        let Some(seq) = self.pending.as_ref().map(|f| f.header.stamp.frame_seq) else {
            return;
        };
        if !cx.joined(&mut self.pending, seq, "navigability", step.health) {
            return;
        }
        let frame = self.pending.take().expect("checked above");
        let h = frame.header;
        let Some((bearing, _)) = cx.goal_in_robot_frame(Some(seq)) else {
            step.health.set(HealthState::DEGRADED, NO_GOAL);
            return;
        };
        let Some(cam) = &self.camera else {
            step.health
                .dropped(&"no camera model yet on camera/<name>/info");
            return;
        };
        if let Err(e) = h.validate(frame.data.len()) {
            step.health.dropped(&e);
            return;
        }
        if h.encoding != PixelEncoding::MONO8 {
            step.health.dropped(&format_args!(
                "navigability must be mono8, got {}",
                h.encoding
            ));
            return;
        }
        let Some(stamp) = cx.judge(step.wall_ns, step.health) else {
            return;
        };
        let config = &cx.config;
        // The model is calibrated at the camera's resolution; the
        // navigability image may be smaller (the network's input size).
        let scaled = Camera {
            model: cam.model.scaled_to(h.width, h.height),
            ..cam.clone()
        };
        let size = (h.width, h.height);
        if self.half_widths.as_ref().is_none_or(|(s, _)| *s != size) {
            let m = &scaled.model;
            let hw = safe_half_widths(
                h.height as usize,
                m.fx,
                m.fy,
                m.cy,
                cam.mount.height_m(),
                config.robot_width_m,
                config.safety_margin_m,
            );
            self.half_widths = Some((size, hw));
        }
        let hw = &self.half_widths.as_ref().expect("just set").1;
        let p = if config.povnav.components == PovnavComponents::Vmpp {
            if self.vmpp.as_ref().is_none_or(|a| a.size != size) {
                let primitives = crate::vmpp::primitives(&config.povnav.vmpp);
                let pixels = primitives
                    .iter()
                    .map(|p| {
                        p.ground_m
                            .iter()
                            .map(|&(x, y)| ground_pixel(&scaled, x, y))
                            .collect()
                    })
                    .collect();
                self.vmpp = Some(VmppArcs {
                    size,
                    primitives,
                    pixels,
                });
            }
            let arcs = self.vmpp.as_ref().expect("just set");
            crate::vmpp::plan(
                &frame.data,
                h.width as usize,
                h.height as usize,
                bearing,
                hw,
                &arcs.primitives,
                &arcs.pixels,
                &config.povnav,
            )
        } else {
            plan(
                &frame.data,
                h.width as usize,
                h.height as usize,
                bearing,
                hw,
                &config.povnav,
            )
        };
        let (gx, gy) = scaled
            .ground_point_m(p.hog_px.0, p.hog_px.1)
            .unwrap_or((f64::NAN, f64::NAN));
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
        // above the horizon line have no ground point and are left out, and
        // far points (ill-conditioned near the horizon) too.
        let ground: Vec<[f32; 2]> = p
            .path_px
            .iter()
            .filter_map(|&(u, v)| scaled.ground_point_m(u, v))
            .filter(|&(x, y)| x.hypot(y) <= config.path_max_range_m)
            .map(|(x, y)| [x as f32, y as f32])
            .collect();
        let path_robot = Path {
            frame: PathFrame::ROBOT,
            points: FixedVec::from_slice(&ground[..ground.len().min(MAX_PATH_POINTS)])
                .unwrap_or_default(),
            ..path
        };
        step.out.send(cx.port.subgoal, subgoal);
        step.out.send(self.visual_path, path);
        step.out.send(self.visual_path_robot, path_robot);
        step.health.set(HealthState::OK, "");
        step.health.output(stamp, step.wall_ns);
    }
}

/// LRN's head (or the goal heuristic's): the previous choice, kept in the
/// world frame across steps.
struct Heading {
    head: LrnHead,
    lrn: LrnHeadConfig,
}

impl Heading {
    fn step(&mut self, cx: &mut Context, step: &mut Step<'_>) {
        cx.receive(step);
        let Some(b) = step.inbox.take::<AngularBins>(cx.port.primary) else {
            return;
        };
        step.health.input();
        cx.inputs.consumed(cx.primary_in, b.stamp);
        let Some((bearing, distance)) = cx.goal_in_robot_frame(None) else {
            step.health.set(HealthState::DEGRADED, NO_GOAL);
            return;
        };
        let k = b.scores.len();
        let centers: Vec<f64> = (0..k)
            .map(|i| b.first_bin_start_rad as f64 + (i as f64 + 0.5) * b.bin_width_rad as f64)
            .collect();
        let scores: Vec<f64> = b.scores.as_slice().iter().map(|&s| s as f64).collect();
        // An unobserved bin is unknown, not zero: it cannot be chosen.
        let observed: Vec<bool> = (0..k)
            .map(|i| b.observed.as_slice().get(i).is_some_and(|&o| o == 1))
            .collect();
        if let Some(p) = cx.tracker.pose() {
            self.head.set_robot_yaw(p.yaw_rad);
        }
        let choice = self
            .head
            .select(&self.lrn, &scores, &observed, &centers, bearing, distance);
        let Some(stamp) = cx.judge(step.wall_ns, step.health) else {
            return;
        };
        let source = if self.lrn.goal_heuristic {
            SubgoalSource::GOAL_HEURISTIC
        } else {
            SubgoalSource::LRN
        };
        let Some(heading) = choice else {
            // Fresh bins with nothing affordable are a decision, and the
            // frame is answered with it: a blocked subgoal the servo stops
            // on. Unanswered, a lock-step simulator would wait out its
            // command timeout and, in one process, the base would coast on
            // the last command. No heading and no point: nothing that
            // reads it (a servo, a guided planner) can steer by it.
            let blocked = Subgoal {
                stamp,
                source,
                mode: ServoMode::BLOCKED,
                heading_rad: f32::NAN,
                x_m: f32::NAN,
                y_m: f32::NAN,
                image_u_px: f32::NAN,
                image_v_px: f32::NAN,
                proximity_lambda_px: f32::NAN,
                alignment_phi_rad: f32::NAN,
            };
            step.out.send(cx.port.subgoal, blocked);
            step.health
                .set(HealthState::DEGRADED, "no affordable observed bin");
            step.health.output(stamp, step.wall_ns);
            return;
        };
        let d = cx.config.subgoal_distance_m.min(distance);
        let subgoal = Subgoal {
            stamp,
            source,
            mode: ServoMode::SAFE,
            heading_rad: heading as f32,
            x_m: (d * heading.cos()) as f32,
            y_m: (d * heading.sin()) as f32,
            image_u_px: f32::NAN,
            image_v_px: f32::NAN,
            proximity_lambda_px: f32::NAN,
            alignment_phi_rad: f32::NAN,
        };
        step.out.send(cx.port.subgoal, subgoal);
        if self.head.fell_back() {
            step.health.set(
                HealthState::DEGRADED,
                "no affordable observed bin: heading for the goal",
            );
        } else {
            step.health.set(HealthState::OK, "");
        }
        step.health.output(stamp, step.wall_ns);
    }
}

/// What plans on the costmap: D* Lite (a world-fixed grid per goal) or HIP
/// (the trajectory library over the latest HIP-scaled costmap).
enum MapPlanner {
    DStarLite(Option<Box<WorldPlanner>>),
    Hip {
        library: Vec<Trajectory>,
        /// The latest costmap's header and its HIP-scaled cells.
        costmap: Option<(CostmapHeader, Vec<f32>)>,
        /// The learned density model, and -log q per trajectory of the newest frame.
        model: Option<Box<OnnxModel>>,
        learned: Option<Vec<f64>>,
    },
}

impl MapPlanner {
    /// The config's planner; HIP's library and model paths are relative to
    /// the config file's folder, like a model's.
    fn load(config: &SubgoalStageConfig, base_dir: &std::path::Path) -> anyhow::Result<Self> {
        if config.method != "hip" {
            return Ok(MapPlanner::DStarLite(None));
        }
        let file: LibraryFile =
            farsight_stage::load_config_file(&base_dir.join(&config.hip_library))?;
        tracing::info!(trajectories = file.trajectories.len(), "HIP library loaded");
        let library: Vec<Trajectory> = file.trajectories.into_iter().map(Trajectory).collect();
        let model = if has_hip_model(config) {
            Some(load_hip_model(
                &base_dir.join(&config.hip_model),
                library.len(),
            )?)
        } else {
            tracing::warn!("no hip_model: the learned term -log q is 0 for every trajectory");
            None
        };
        Ok(MapPlanner::Hip {
            library,
            costmap: None,
            model,
            learned: None,
        })
    }

    fn source(&self) -> SubgoalSource {
        match self {
            MapPlanner::DStarLite(_) => SubgoalSource::DSTAR_LITE,
            MapPlanner::Hip { .. } => SubgoalSource::HIP,
        }
    }
}

/// Loads HIP's learned model; its trajectory output must score exactly the
/// library's trajectories.
fn load_hip_model(path: &std::path::Path, library_len: usize) -> anyhow::Result<Box<OnnxModel>> {
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

/// The costmap planners' state: feed each costmap to the planner, replan
/// from the robot at most `replan_rate_hz` (and on every change for D*
/// Lite; once per costmap on the stamps' clock), publish the world path and
/// a subgoal `subgoal_distance_m` along it.
struct MapPlan {
    planner: MapPlanner,
    planned: usize,
    /// HIP with a model: the camera image's port and its (optional) input.
    image: Option<(usize, InputId)>,
    /// The frame of the newest camera image the model has run on.
    image_seq: Option<u64>,
    /// A costmap that came before there was a pose and a goal: it waits for
    /// them, the newest replacing it, as it used to wait in its subscriber.
    pending: Option<Costmap>,
    /// Something changed since the last plan (a costmap's cells, the grid,
    /// the learned term): replan now rather than at the next period.
    dirty: bool,
    period_ns: u64,
    next_plan: u64,
    /// The goal the D* Lite grid was built for, before any pull-back from
    /// a blocked cell: a guide's goal is judged new against this, so a
    /// pulled-back goal is not rebuilt (twice) every frame.
    requested_goal_m: Option<[f64; 2]>,
}

impl MapPlan {
    fn step(&mut self, cx: &mut Context, step: &mut Step<'_>) {
        let now = step.wall_ns;
        let mut fresh_costmap = false;
        // This step's pose first: HIP's past input is read at the frame's
        // capture time, which may be the pose's.
        cx.receive(step);
        if let (
            MapPlanner::Hip {
                model: Some(model),
                learned,
                ..
            },
            Some((port, image_in)),
        ) = (&mut self.planner, self.image)
        {
            // The learned term: -log q(tau | o) of each trajectory for the newest frame.
            if let Some(frame) = step.inbox.take::<Image>(port) {
                cx.inputs.consumed(image_in, frame.header.stamp);
                self.image_seq = Some(frame.header.stamp.frame_seq);
                // A model of the robot's past positions gets them at the
                // frame's capture time; without a pose yet the frame is
                // not run and no older term is kept.
                let past = model.config().past_input.clone().map(|spec| {
                    let pose_at = |t| {
                        cx.pose_at(t)
                            .map(|p| [p.position_m[0], p.position_m[1], p.yaw_rad])
                    };
                    let t_ns = frame.header.stamp.capture_time_ns;
                    crate::hip::past_positions(pose_at, t_ns, spec.points, spec.step_s)
                        .ok_or_else(|| "no pose yet for the past positions".to_string())
                        .and_then(|past| model.set_past(&past).map_err(|e| e.to_string()))
                });
                let out = match past {
                    Some(Err(e)) => Err(farsight_inference::onnx::InferError::Run(e)),
                    _ => {
                        let mut timings = Default::default();
                        model.run(&frame.header, &frame.data, &mut timings, |outputs| {
                            farsight_inference::Perception::from_outputs(outputs, None)
                        })
                    }
                };
                match out {
                    Ok(Ok(p)) => {
                        *learned = p
                            .trajectory_log_q
                            .map(|q| q.iter().map(|&v| -(v as f64)).collect());
                        self.dirty = true;
                    }
                    Ok(Err(e)) => {
                        // Never score with an older frame's output.
                        *learned = None;
                        step.health.dropped(&format_args!("HIP model output: {e}"));
                    }
                    Err(e) => {
                        *learned = None;
                        step.health.dropped(&format_args!("HIP model: {e}"));
                    }
                }
            }
        }
        if let Some(c) = step.inbox.take::<Costmap>(cx.port.primary) {
            self.pending = Some(c);
        }
        let config = &cx.config;
        // On the stamps' clock the planner moves only with a costmap (one
        // plan per frame). A step without one (a tick, between a frame's
        // pose and its costmap) would place the goal with the newer pose
        // and the older guide, and rebuild the grid for that mix: a track
        // that depends on when the tick fell.
        if config.clock == ClockSource::Stamps && self.pending.is_none() {
            return;
        }
        // With a guide on the stamps' clock, a costmap waits for the
        // guide's subgoal of its frame; on the wall clock the newest guide
        // subgoal is the goal of the next plan.
        let join_seq = match (cx.guide_in, config.clock) {
            (Some(_), ClockSource::Stamps) => {
                self.pending.as_ref().map(|c| c.header.stamp.frame_seq)
            }
            _ => None,
        };
        if let Some(k) = join_seq {
            if !cx.joined(&mut self.pending, k, "costmap", step.health) {
                return;
            }
        }
        // HIP's learned term on the stamps' clock: a costmap waits for the
        // camera image of its frame. Stages as processes get the two in
        // either order, in one process together; without the wait the
        // first frame was planned with no term in one and with it in the
        // other, and the tracks parted.
        if let (Some(_), ClockSource::Stamps, Some(c)) = (self.image, config.clock, &self.pending) {
            if self.image_seq.is_none_or(|s| s < c.header.stamp.frame_seq) {
                return;
            }
        }
        // A guide that found nothing affordable on this frame (LRN's head,
        // `no_hotspot = "stop"`) gives no goal to plan toward: the frame is
        // answered as one with no way on, with an empty path.
        if cx.guide_in.is_some()
            && cx.guide.is_some_and(|g| {
                g.mode == ServoMode::BLOCKED && join_seq.is_none_or(|k| g.stamp.frame_seq == k)
            })
        {
            self.answer_a_blocked_guide(cx, step, fresh_costmap);
            return;
        }
        let (Some(&p), Some((bearing, distance))) =
            (cx.tracker.pose(), cx.goal_in_robot_frame(join_seq))
        else {
            step.health.set(
                HealthState::DEGRADED,
                "no goal (or pose) yet: nothing to plan",
            );
            return;
        };
        let robot = [p.position_m[0], p.position_m[1]];
        let goal_robot = [distance * bearing.cos(), distance * bearing.sin()];
        // A guide's subgoal goes where its frame's robot was looking.
        let frame_pose = match (cx.guide_in, cx.guide) {
            (Some(_), Some(g)) => cx.pose_at(g.stamp.capture_time_ns).unwrap_or(p),
            _ => p,
        };
        let goal = frame_pose.to_world_frame(goal_robot);
        if let MapPlanner::DStarLite(pl) = &mut self.planner {
            let requested = self.requested_goal_m;
            let new_goal = pl.as_ref().is_none_or(|pl| {
                let g = requested.unwrap_or(pl.goal_m());
                (g[0] - goal[0]).hypot(g[1] - goal[1]) > config.planner.resolution_m
            });
            // A robot that left the grid (relocalised, carried, a
            // simulator started over) gets a grid around where it is.
            let left_grid = pl.as_ref().is_some_and(|pl| !pl.contains(robot));
            // A goal that moved on the grid keeps the grid (and what it
            // remembers); the search starts over.
            let retargeted =
                new_goal && !left_grid && pl.as_mut().is_some_and(|pl| pl.retarget(robot, goal));
            if retargeted {
                self.requested_goal_m = Some(goal);
                self.dirty = true;
            } else if new_goal || left_grid {
                let why = if new_goal {
                    "new goal"
                } else {
                    "the robot left the grid"
                };
                // A guide moves the goal every frame: its grids are not news.
                if cx.guide_in.is_none() {
                    tracing::info!(
                        goal_x_m = goal[0],
                        goal_y_m = goal[1],
                        robot_x_m = robot[0],
                        robot_y_m = robot[1],
                        "{why}: planning grid built"
                    );
                }
                *pl = Some(Box::new(WorldPlanner::new(robot, goal, &config.planner)));
                self.requested_goal_m = Some(goal);
                self.dirty = true;
            }
        }
        if let Some(c) = self.pending.take() {
            step.health.input();
            let h = c.header;
            if let Err(e) = h.validate(c.data.len()) {
                step.health
                    .dropped(&format_args!("costmap/{}: {e}", config.costmap));
            } else {
                cx.inputs.consumed(cx.primary_in, h.stamp);
                fresh_costmap = true;
                match &mut self.planner {
                    MapPlanner::DStarLite(pl) => {
                        let planner = pl.as_mut().expect("built above");
                        self.dirty |= planner.apply_costmap(&h, &c.data) > 0;
                        // A guide's subgoal is a direction and a distance:
                        // inside an obstacle, head for the free ground
                        // before it, or nearest it (WorldPlanner::
                        // goal_pulled_back_from_blocked).
                        let pulled_back = cx
                            .guide_in
                            .and_then(|_| planner.goal_pulled_back_from_blocked(robot));
                        if let Some(g) = pulled_back {
                            let mut planner = WorldPlanner::new(robot, g, &config.planner);
                            planner.apply_costmap(&h, &c.data);
                            *pl = Some(Box::new(planner));
                            self.dirty = true;
                        }
                    }
                    MapPlanner::Hip { costmap, .. } => {
                        let costs: Vec<f32> = c.data.iter().map(|c| c.cost_s_per_m).collect();
                        *costmap = Some((h, hip_scaled_costmap(&costs, config.hip.alpha)));
                    }
                }
            }
        }
        let due = match config.clock {
            // One plan per costmap message: each frame is planned on once.
            ClockSource::Stamps => fresh_costmap,
            ClockSource::Wall => self.dirty || now >= self.next_plan,
        };
        if !due {
            return;
        }
        let input_now = cx.inputs.now_at(config.clock, now);
        let freshness = cx.inputs.check(input_now);
        let stamp = match cx.inputs.output_stamp() {
            Some(stamp) if !freshness.is_stale() => stamp,
            _ => {
                // No plan from a map or pose the robot has left behind.
                step.health.set(HealthState::DEGRADED, freshness.reason());
                return;
            }
        };
        let learned_fresh = self
            .image
            .is_some_and(|(_, id)| cx.inputs.is_fresh(id, input_now));
        self.dirty = false;
        self.next_plan = now + self.period_ns;
        let source = self.planner.source();
        let planned: Result<Vec<[f64; 2]>, String> = match &mut self.planner {
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
                        Ok(path)
                    }
                    Err(e) => Err(e.to_string()),
                }
            }
            MapPlanner::Hip {
                library,
                costmap,
                learned,
                ..
            } => {
                let learned = learned.as_deref().filter(|_| learned_fresh);
                let frame = HipFrame {
                    pose: &p,
                    goal_robot,
                };
                hip_path(library, costmap.as_ref(), learned, config, frame)
            }
        };
        let path = match planned {
            Ok(path) => path,
            Err(why) => {
                self.answer_with_a_stop(step, stamp, &why);
                return;
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
        step.out.send(self.planned, msg);
        step.out.send(cx.port.subgoal, subgoal);
        step.health.set(HealthState::OK, "");
        step.health.output(stamp, now);
    }

    /// Answers the frame with an empty path, on which the servo stops, and
    /// says why. Unanswered, a lock-step simulator would wait out its
    /// command timeout and, in one process, the base would coast on the
    /// last command; neither is a decision this stage made.
    fn answer_with_a_stop(&self, step: &mut Step<'_>, stamp: Stamp, why: &str) {
        let empty = Path {
            stamp,
            frame: PathFrame::WORLD,
            camera_id: 0,
            points: FixedVec::default(),
        };
        step.out.send(self.planned, empty);
        step.health.set(HealthState::DEGRADED, why);
        step.health.output(stamp, step.wall_ns);
    }

    /// A blocked guide's frame: its costmap is taken (and counted) but not
    /// planned on, and the frame, when due, gets a stop. The map is not
    /// added to the planner's memory: the robot stops, so the next frame's
    /// map covers the same ground.
    fn answer_a_blocked_guide(&mut self, cx: &mut Context, step: &mut Step<'_>, mut fresh: bool) {
        let now = step.wall_ns;
        if let Some(c) = self.pending.take() {
            step.health.input();
            match c.header.validate(c.data.len()) {
                Ok(()) => {
                    cx.inputs.consumed(cx.primary_in, c.header.stamp);
                    fresh = true;
                }
                Err(e) => step
                    .health
                    .dropped(&format_args!("costmap/{}: {e}", cx.config.costmap)),
            }
        }
        let due = match cx.config.clock {
            ClockSource::Stamps => fresh,
            ClockSource::Wall => self.dirty || fresh || now >= self.next_plan,
        };
        if !due {
            return;
        }
        let freshness = cx.inputs.check(cx.inputs.now_at(cx.config.clock, now));
        let stamp = match cx.inputs.output_stamp() {
            Some(stamp) if !freshness.is_stale() => stamp,
            _ => {
                step.health.set(HealthState::DEGRADED, freshness.reason());
                return;
            }
        };
        self.dirty = false;
        self.next_plan = now + self.period_ns;
        self.answer_with_a_stop(
            step,
            stamp,
            "the guide's subgoal is blocked: nothing to plan toward",
        );
    }
}

/// The robot's pose and the goal in its frame, for [`hip_path`].
struct HipFrame<'a> {
    pose: &'a Pose,
    goal_robot: [f64; 2],
}

/// HIP's choice for one frame (eq. (1) over the library) as a world path
/// from the robot, or why there is none.
fn hip_path(
    library: &[Trajectory],
    costmap: Option<&(CostmapHeader, Vec<f32>)>,
    learned: Option<&[f64]>,
    config: &SubgoalStageConfig,
    frame: HipFrame<'_>,
) -> Result<Vec<[f64; 2]>, String> {
    let Some((h, scaled)) = costmap else {
        return Err("no costmap yet: HIP has nothing to score".to_string());
    };
    let learner_only = config.hip.learner_only();
    if learner_only && learned.is_none() {
        // The Learner alone sees nothing but the camera: without a fresh
        // frame's term it would drive on the directive blind.
        return Err(
            "HIP's Learner alone (phi = 0) has no fresh learned term: nothing to plan".to_string(),
        );
    }
    let p = frame.pose;
    let robot = [p.position_m[0], p.position_m[1]];
    let radius_m = config.hip.robot_radius_m;
    let clearance_m = required_clearance_m(h, scaled, robot, radius_m);
    // Off the map is unknown: the scaled value of the unknown cost would
    // need the map's softmax sum, so count it as free (0) rather than
    // invent one; the directive still pulls to the goal.
    let at = |q: [f64; 2]| {
        if learner_only {
            return 0.0;
        }
        let w = p.to_world_frame(q);
        if lethal_clearance_m(h, scaled, w, radius_m) < clearance_m {
            return f64::INFINITY;
        }
        match h.cell_index(w[0], w[1]).map(|k| scaled[k]) {
            Some(v) if !v.is_nan() => v as f64,
            _ => 0.0,
        }
    };
    let c = choose(library, frame.goal_robot, at, learned, &config.hip)
        .ok_or("every HIP trajectory crosses a lethal cell")?;
    tracing::debug!(?c, "HIP choice");
    Ok(std::iter::once(robot)
        .chain(library[c.index].0.iter().map(|&q| p.to_world_frame(q)))
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use farsight_interfaces::camera::{CameraModel, Mount};
    use farsight_interfaces::message::Message;
    use farsight_interfaces::msg::{CostCell, CostmapLayer, GoalKind, ImageHeader};
    use farsight_stage::runtime::Harness;
    use farsight_stage::Wake;
    use std::path::PathBuf;

    #[test]
    fn a_ground_point_projects_back_to_the_pixel_it_came_from() {
        let cam = Camera::new(
            0,
            "front",
            CameraModel::pinhole(64, 48, 40.0, 40.0, 31.5, 23.5),
            Mount::from_xyz_rpy_deg([0.2, 0.1, 1.0], [0.0, 15.0, 10.0]),
        );
        for (u, v) in [(10.0, 40.0), (31.5, 30.0), (60.0, 47.0)] {
            let (x, y) = cam.ground_point_m(u, v).unwrap();
            let (pu, pv) = ground_pixel(&cam, x, y).unwrap();
            assert!(
                (pu - u).abs() < 1e-6 && (pv - v).abs() < 1e-6,
                "({u}, {v}) -> ({pu}, {pv})"
            );
        }
        assert_eq!(ground_pixel(&cam, -5.0, 0.0), None, "behind the camera");
    }

    const S: u64 = 1_000_000_000;
    const MS: u64 = 1_000_000;

    /// One method under test: its config (and the folder its paths resolve
    /// against), its primary input, and what a plan sends.
    struct Case {
        name: &'static str,
        toml: String,
        dir: PathBuf,
        primary: &'static str,
        source: SubgoalSource,
        outputs: &'static [&'static str],
        no_goal: &'static str,
    }

    impl Case {
        fn stage(&self) -> Harness<SubgoalStage> {
            Harness::new(
                SubgoalStage::new(self.config(), &env(&self.dir))
                    .unwrap_or_else(|e| panic!("{}: {e:#}", self.name)),
            )
        }

        fn config(&self) -> SubgoalStageConfig {
            farsight_stage::parse_config(&self.toml, "test").unwrap()
        }

        /// The primary input captured at `stamp`, and for POVNav the camera
        /// model it needs.
        fn put_primary(&self, h: &mut Harness<SubgoalStage>, stamp: Stamp) {
            let msg: Message = match self.primary {
                "perception/front/navigability" => {
                    h.put("camera/front/info", camera().to_info(stamp));
                    navigability(stamp).into()
                }
                "bins/angular" => bins(stamp).into(),
                _ => costmap(stamp).into(),
            };
            h.put(self.primary, msg);
        }
    }

    fn env(dir: &std::path::Path) -> StageEnv {
        StageEnv {
            instance: "subgoal-selection".into(),
            config_dir: dir.to_path_buf(),
        }
    }

    /// A folder of its own per call (tests run in parallel) holding a HIP
    /// library: straight ahead (it ends in the goal region of a goal
    /// ahead), left and right.
    fn hip_dir() -> PathBuf {
        use std::sync::atomic::{AtomicUsize, Ordering};
        static N: AtomicUsize = AtomicUsize::new(0);
        let dir = std::env::temp_dir().join(format!(
            "farsight-subgoal-stage-{}-{}",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        ));
        std::fs::create_dir_all(&dir).unwrap();
        let line = |dx: f64, dy: f64| {
            (1..=10)
                .map(|i| format!("[{}, {}]", dx * i as f64, dy * i as f64))
                .collect::<Vec<_>>()
                .join(", ")
        };
        std::fs::write(
            dir.join("hip-library.toml"),
            format!(
                "step_s = 0.2\ntrajectories = [[{}], [{}], [{}]]\n",
                line(0.4, 0.0),
                line(0.3, 0.25),
                line(0.3, -0.25)
            ),
        )
        .unwrap();
        dir
    }

    /// Every method, on the stamps' clock unless `extra` says otherwise.
    fn cases(extra: &str) -> Vec<Case> {
        const VISUAL: &str = "no goal (or pose) yet: no subgoal published";
        const MAP: &str = "no goal (or pose) yet: nothing to plan";
        let clock = if extra.contains("clock") {
            extra.to_string()
        } else {
            format!("clock = \"stamps\"\n{extra}")
        };
        let case = |name: &'static str,
                    method: &str,
                    primary: &'static str,
                    source: SubgoalSource,
                    outputs: &'static [&'static str],
                    no_goal: &'static str| Case {
            name,
            toml: format!("method = \"{method}\"\n{clock}"),
            dir: ".".into(),
            primary,
            source,
            outputs,
            no_goal,
        };
        vec![
            case(
                "povnav",
                "povnav",
                "perception/front/navigability",
                SubgoalSource::POVNAV,
                &["nav/subgoal", "nav/path/visual", "nav/path/visual_robot"],
                VISUAL,
            ),
            case(
                "lrn",
                "lrn",
                "bins/angular",
                SubgoalSource::LRN,
                &["nav/subgoal"],
                VISUAL,
            ),
            case(
                "goal_heuristic",
                "goal_heuristic",
                "bins/angular",
                SubgoalSource::GOAL_HEURISTIC,
                &["nav/subgoal"],
                VISUAL,
            ),
            Case {
                toml: format!(
                    "method = \"dstar_lite\"\nsubgoal_distance_m = 5.0\n{clock}\n[planner]\nmargin_m = 15.0\n"
                ),
                ..case(
                    "dstar_lite",
                    "",
                    "costmap/fused",
                    SubgoalSource::DSTAR_LITE,
                    &["nav/path/planned", "nav/subgoal"],
                    MAP,
                )
            },
            Case {
                toml: format!("method = \"hip\"\nhip_library = \"hip-library.toml\"\n{clock}"),
                dir: hip_dir(),
                ..case(
                    "hip",
                    "",
                    "costmap/fused",
                    SubgoalSource::HIP,
                    &["nav/path/planned", "nav/subgoal"],
                    MAP,
                )
            },
        ]
    }

    fn at(seq: u64, t_ns: u64) -> Stamp {
        Stamp::new(seq, t_ns)
    }

    /// The robot at the origin facing east (+x).
    fn pose(stamp: Stamp) -> Pose {
        Pose {
            stamp,
            ..Default::default()
        }
    }

    /// A goal 20 m straight ahead.
    fn goal() -> NavGoal {
        NavGoal {
            kind: GoalKind::LOCAL,
            x_m: 20.0,
            tolerance_m: 1.0,
            ..Default::default()
        }
    }

    /// A level camera 1 m up, looking ahead, 80x60.
    fn camera() -> Camera {
        Camera::new(
            0,
            "front",
            CameraModel::pinhole(80, 60, 40.0, 40.0, 39.5, 29.5),
            Mount::from_xyz_rpy_deg([0.0, 0.0, 1.0], [0.0; 3]),
        )
    }

    /// Navigable ground from row 35 down (below the horizon line).
    fn navigability(stamp: Stamp) -> Image {
        let (w, h) = (80, 60);
        Image {
            header: ImageHeader::packed(stamp, 0, w, h, PixelEncoding::MONO8),
            data: (0..w * h)
                .map(|i| if i / w >= 35 { 255 } else { 0 })
                .collect(),
        }
    }

    /// Eight observed bins over the front half, all equally good.
    fn bins(stamp: Stamp) -> AngularBins {
        let k = 8;
        AngularBins {
            stamp,
            first_bin_start_rad: -std::f32::consts::FRAC_PI_2,
            bin_width_rad: std::f32::consts::PI / k as f32,
            scores: FixedVec::from_slice(&vec![1.0; k]).unwrap(),
            observed: FixedVec::from_slice(&vec![1; k]).unwrap(),
        }
    }

    /// Free ground 11 m x 11 m around the robot.
    fn costmap(stamp: Stamp) -> Costmap {
        Costmap {
            header: CostmapHeader {
                stamp,
                layer: CostmapLayer::FUSED,
                width: 11,
                height: 11,
                resolution_m: 1.0,
                x_min_m: -5.0,
                y_max_m: 5.0,
            },
            data: vec![
                CostCell {
                    cost_s_per_m: 0.5,
                    variance: 0.0,
                };
                11 * 11
            ],
        }
    }

    fn subgoals(out: &[(String, Message)]) -> Vec<Subgoal> {
        out.iter()
            .filter(|(t, _)| t == "nav/subgoal")
            .map(|(_, m)| Subgoal::try_from(m.clone()).unwrap())
            .collect()
    }

    fn topics_of(out: &[(String, Message)]) -> Vec<&str> {
        out.iter().map(|(t, _)| t.as_str()).collect()
    }

    #[test]
    fn without_a_goal_no_method_publishes_and_each_says_why() {
        for c in cases("") {
            let mut h = c.stage();
            h.put("state/pose", pose(at(90, 10 * S)));
            c.put_primary(&mut h, at(7, 10 * S));
            let out = h.step(h.wake_on(c.primary), 10 * S);
            assert!(out.is_empty(), "{}: {:?}", c.name, topics_of(&out));
            assert_eq!(h.health.state(), HealthState::DEGRADED, "{}", c.name);
            assert_eq!(h.health.report().reason.as_str(), c.no_goal, "{}", c.name);
            assert_eq!(h.health.report().messages_out, 0, "{}", c.name);
        }
    }

    #[test]
    fn on_stamps_a_stale_pose_or_primary_input_gives_no_output_and_names_it() {
        for c in cases("") {
            for (stale, pose_t, primary_t) in
                [("state/pose", 10 * S, 12 * S), (c.primary, 12 * S, 10 * S)]
            {
                let mut h = c.stage();
                h.put("state/pose", pose(at(90, pose_t)));
                h.put("nav/goal", goal());
                c.put_primary(&mut h, at(7, primary_t));
                // The wall clock is far off: only the stamps count.
                let out = h.step(h.wake_on(c.primary), 1000 * S);
                assert!(
                    out.is_empty(),
                    "{} ({stale}): {:?}",
                    c.name,
                    topics_of(&out)
                );
                assert_eq!(h.health.state(), HealthState::DEGRADED, "{}", c.name);
                let reason = h.health.report().reason.as_str();
                assert!(
                    reason.starts_with(&format!("{stale} is 2.00 s old")),
                    "{}: {reason}",
                    c.name
                );
            }
        }
    }

    #[test]
    fn a_fresh_input_pose_and_goal_give_one_subgoal_carrying_the_older_capture() {
        for c in cases("") {
            let mut h = c.stage();
            h.put("state/pose", pose(at(90, 10 * S)));
            h.put("nav/goal", goal());
            c.put_primary(&mut h, at(7, 10 * S + 300 * MS));
            let out = h.step(h.wake_on(c.primary), 1000 * S);
            assert_eq!(topics_of(&out), c.outputs, "{}", c.name);
            let s = subgoals(&out);
            assert_eq!(s.len(), 1, "{}", c.name);
            // The primary input's frame number, the pose's (older) capture.
            assert_eq!(s[0].stamp, at(7, 10 * S), "{}", c.name);
            assert_eq!(s[0].source, c.source, "{}", c.name);
            assert!(
                s[0].x_m > 0.0 && s[0].y_m.abs() < s[0].x_m,
                "{}: toward the goal ahead, not {s:?}",
                c.name
            );
            for (topic, m) in &out {
                assert_eq!(m.stamp(), at(7, 10 * S), "{}: {topic}", c.name);
            }
            assert_eq!(h.health.state(), HealthState::OK, "{}", c.name);
            assert_eq!(h.health.report().messages_out, 1, "{}", c.name);
            // Nothing new: nothing sent (one output per input on the stamps).
            let out = h.step(Wake::Tick, 1001 * S);
            assert!(out.is_empty(), "{}: {:?}", c.name, topics_of(&out));
        }
    }

    #[test]
    fn a_map_planner_walled_in_answers_its_frame_with_an_empty_path_the_servo_stops_on() {
        // A lethal ring 2 m round the robot: no path, no admissible HIP
        // trajectory. Unanswered, a lock-step simulator would wait out its
        // command timeout and a base coast on the last command.
        let walled = |stamp: Stamp| {
            let mut map = costmap(stamp);
            for (k, cell) in map.data.iter_mut().enumerate() {
                let (i, j) = ((k / 11) as i64 - 5, (k % 11) as i64 - 5);
                if i.abs().max(j.abs()) == 2 {
                    cell.cost_s_per_m = f32::INFINITY;
                }
            }
            map
        };
        let planners = cases("");
        let planners: Vec<_> = planners
            .iter()
            .filter(|c| c.outputs.contains(&"nav/path/planned"))
            .collect();
        assert_eq!(planners.len(), 2, "D* Lite and HIP");
        for c in planners {
            let mut h = c.stage();
            h.put("state/pose", pose(at(7, 10 * S)));
            h.put("nav/goal", goal());
            h.put(c.primary, walled(at(7, 10 * S)));
            let out = h.step(h.wake_on(c.primary), 10 * S);
            assert_eq!(topics_of(&out), ["nav/path/planned"], "{}", c.name);
            let path = Path::try_from(out[0].1.clone()).unwrap();
            assert!(path.points.is_empty(), "{}: {path:?}", c.name);
            assert_eq!(path.stamp, at(7, 10 * S), "{}", c.name);
            assert_eq!(h.health.state(), HealthState::DEGRADED, "{}", c.name);
            let why = h.health.report().reason.as_str().to_string();
            assert!(
                why.contains("no path") || why.contains("lethal"),
                "{}: {why}",
                c.name
            );
            // The walls gone, the next frame is planned as usual.
            h.put("state/pose", pose(at(8, 10 * S + S / 10)));
            c.put_primary(&mut h, at(8, 10 * S + S / 10));
            let out = h.step(h.wake_on(c.primary), 11 * S);
            assert_eq!(topics_of(&out), c.outputs, "{}", c.name);
            let path = Path::try_from(out[0].1.clone()).unwrap();
            assert!(path.points.len() > 1, "{}: {path:?}", c.name);
        }
    }

    #[test]
    fn lrn_with_no_scored_bin_stops_or_heads_for_the_goal_as_configured_never_on_stale_bins() {
        let lrn = |extra: &str| cases(extra).into_iter().find(|c| c.name == "lrn").unwrap();
        // Every bin observed, none scored; the goal 20 m ahead, 20 m left.
        let cold = |stamp: Stamp| {
            let mut b = bins(stamp);
            b.scores = FixedVec::from_slice(&[0.0; 8]).unwrap();
            b
        };
        let left_goal = NavGoal {
            y_m: 20.0,
            ..goal()
        };
        let run = |c: &Case, bins_t: u64| {
            let mut h = c.stage();
            h.put("state/pose", pose(at(90, 10 * S)));
            h.put("nav/goal", left_goal);
            h.put("bins/angular", cold(at(7, bins_t)));
            let out = h.step(h.wake_on("bins/angular"), 1000 * S);
            let reason = h.health.report().reason.as_str().to_string();
            (subgoals(&out), h.health.state(), reason)
        };
        let (sent, state, reason) = run(&lrn(""), 10 * S);
        // The default answers the frame with a stop: a blocked subgoal
        // with its stamp and nothing to steer by.
        assert_eq!(sent.len(), 1, "{sent:?}");
        assert_eq!(sent[0].mode, ServoMode::BLOCKED);
        assert_eq!(sent[0].stamp.capture_time_ns, 10 * S);
        assert!(sent[0].heading_rad.is_nan() && sent[0].x_m.is_nan() && sent[0].y_m.is_nan());
        assert_eq!(state, HealthState::DEGRADED);
        assert_eq!(reason, "no affordable observed bin");
        let to_goal = lrn("[lrn]\nno_hotspot = \"goal\"");
        let (sent, state, reason) = run(&to_goal, 10 * S);
        assert_eq!(sent.len(), 1, "{sent:?}");
        assert!(
            (sent[0].heading_rad - std::f32::consts::FRAC_PI_4).abs() < 1e-6,
            "toward the goal: {sent:?}"
        );
        assert_eq!(state, HealthState::DEGRADED);
        assert_eq!(reason, "no affordable observed bin: heading for the goal");
        // Bins 2 s older than the pose: nothing, stop or fallback, and
        // the reason is the stale input.
        for c in [lrn(""), to_goal] {
            let (sent, state, reason) = run(&c, 8 * S);
            assert!(sent.is_empty(), "stale bins: {sent:?}");
            assert_eq!(state, HealthState::DEGRADED);
            assert!(reason.starts_with("bins/angular is 2.00 s old"), "{reason}");
        }
    }

    /// A guide's subgoal of frame `seq`: 10 m ahead and 10 m left.
    fn guide(seq: u64) -> Subgoal {
        Subgoal {
            stamp: at(seq, 10 * S),
            source: SubgoalSource::LRN,
            heading_rad: std::f32::consts::FRAC_PI_4,
            x_m: 10.0,
            y_m: 10.0,
            ..Default::default()
        }
    }

    #[test]
    fn with_a_guide_each_frame_is_planned_with_the_guides_subgoal_of_that_frame() {
        const GUIDE: &str = "nav/subgoal/lrn";
        let guided: Vec<Case> = cases(&format!("guide = \"{GUIDE}\""))
            .into_iter()
            .filter(|c| !c.primary.starts_with("bins"))
            .collect();
        assert_eq!(guided.len(), 3);
        for c in guided {
            let mut h = c.stage();
            // No nav/goal: the guide's subgoal is this instance's goal
            // (the harness refuses a topic the stage does not read).
            h.put("state/pose", pose(at(90, 10 * S)));
            c.put_primary(&mut h, at(7, 10 * S));
            let out = h.step(h.wake_on(c.primary), 10 * S);
            assert!(out.is_empty(), "{}: frame 7 waits for its guide", c.name);
            // An older frame's guide is not this frame's.
            h.put(GUIDE, guide(6));
            let out = h.step(h.wake_on(GUIDE), 10 * S);
            assert!(out.is_empty(), "{}: {:?}", c.name, topics_of(&out));
            h.put(GUIDE, guide(7));
            let out = h.step(h.wake_on(GUIDE), 10 * S);
            assert_eq!(topics_of(&out), c.outputs, "{}", c.name);
            let s = subgoals(&out);
            assert_eq!(s[0].stamp.frame_seq, 7, "{}", c.name);
            assert!(
                s[0].y_m > 0.5 && s[0].x_m > 0.0,
                "{}: toward the guide's subgoal, ahead and left: {s:?}",
                c.name
            );
            assert_eq!(h.health.report().dropped, 0, "{}", c.name);
            // A frame whose guide answered a later frame never pairs: it is
            // dropped, counted, and nothing goes out.
            c.put_primary(&mut h, at(8, 10 * S));
            h.put(GUIDE, guide(9));
            let out = h.step(h.wake_on(c.primary), 10 * S);
            assert!(out.is_empty(), "{}: {:?}", c.name, topics_of(&out));
            assert_eq!(h.health.report().dropped, 1, "{}", c.name);
        }
    }

    #[test]
    fn a_guided_planner_answers_a_blocked_guides_frame_with_an_empty_path() {
        // LRN's head with nothing affordable sends a BLOCKED subgoal with
        // no point: the planner has no goal for that frame, and stops the
        // robot on it rather than leave it unanswered.
        const GUIDE: &str = "nav/subgoal/lrn";
        let planners: Vec<Case> = cases(&format!("guide = \"{GUIDE}\""))
            .into_iter()
            .filter(|c| c.outputs.contains(&"nav/path/planned"))
            .collect();
        assert_eq!(planners.len(), 2, "D* Lite and HIP");
        let blocked = |stamp: Stamp| Subgoal {
            stamp,
            mode: ServoMode::BLOCKED,
            heading_rad: f32::NAN,
            x_m: f32::NAN,
            y_m: f32::NAN,
            ..guide(stamp.frame_seq)
        };
        for c in planners {
            let mut h = c.stage();
            h.put("state/pose", pose(at(7, 10 * S)));
            h.put(GUIDE, blocked(at(7, 10 * S)));
            c.put_primary(&mut h, at(7, 10 * S));
            let out = h.step(h.wake_on(c.primary), 10 * S);
            assert_eq!(topics_of(&out), ["nav/path/planned"], "{}", c.name);
            let path = Path::try_from(out[0].1.clone()).unwrap();
            assert!(path.points.is_empty(), "{}: {path:?}", c.name);
            assert_eq!(path.stamp.frame_seq, 7, "{}", c.name);
            assert_eq!(h.health.state(), HealthState::DEGRADED, "{}", c.name);
            let why = h.health.report().reason.as_str().to_string();
            assert!(why.contains("blocked"), "{}: {why}", c.name);
            assert_eq!(h.health.report().dropped, 0, "{}", c.name);
            // Blocked on frame 8 too, but its costmap 2 s old: no answer
            // from a stale map, and the reason says so.
            h.put("state/pose", pose(at(8, 12 * S)));
            h.put(GUIDE, blocked(at(8, 12 * S)));
            c.put_primary(&mut h, at(8, 10 * S));
            let out = h.step(h.wake_on(c.primary), 12 * S);
            assert!(out.is_empty(), "{}: {:?}", c.name, topics_of(&out));
            let why = h.health.report().reason.as_str().to_string();
            assert!(why.contains(" is 2.00 s old"), "{}: {why}", c.name);
            // The guide finds a way again on frame 9: planned as usual.
            h.put("state/pose", pose(at(9, 12 * S + S / 10)));
            let found = Subgoal {
                stamp: at(9, 12 * S + S / 10),
                ..guide(9)
            };
            h.put(GUIDE, found);
            c.put_primary(&mut h, at(9, 12 * S + S / 10));
            let out = h.step(h.wake_on(c.primary), 12 * S);
            assert_eq!(topics_of(&out), c.outputs, "{}", c.name);
            let path = Path::try_from(out[0].1.clone()).unwrap();
            assert!(path.points.len() > 1, "{}: {path:?}", c.name);
        }
    }

    #[test]
    fn on_stamps_a_guided_planner_moves_only_with_a_costmap() {
        const GUIDE: &str = "nav/subgoal/lrn";
        let c = cases(&format!("guide = \"{GUIDE}\""))
            .into_iter()
            .find(|c| c.name == "dstar_lite")
            .unwrap();
        let mut h = c.stage();
        h.put("state/pose", pose(at(7, 10 * S)));
        h.put(GUIDE, guide(7));
        c.put_primary(&mut h, at(7, 10 * S));
        let out = h.step(h.wake_on(c.primary), 10 * S);
        assert_eq!(topics_of(&out), c.outputs);
        let grid_goal = |h: &Harness<SubgoalStage>| match &h.stage.method {
            Method::Map(m) => match &m.planner {
                MapPlanner::DStarLite(Some(pl)) => pl.goal_m(),
                _ => panic!("no planning grid"),
            },
            _ => unreachable!(),
        };
        let goal_7 = grid_goal(&h);
        // Frame 8's pose (5 m on) reaches the stage on a tick, before frame
        // 8's costmap and guide: guide 7 must not be placed with it.
        h.put(
            "state/pose",
            Pose {
                position_m: [5.0, 0.0, 0.0],
                ..pose(at(8, 10 * S + S / 10))
            },
        );
        assert!(h.step(Wake::Tick, 10 * S + S / 20).is_empty());
        assert_eq!(grid_goal(&h), goal_7, "the grid is frame 7's");
    }

    #[test]
    fn on_the_wall_clock_a_guides_subgoal_is_placed_with_its_frames_pose() {
        const GUIDE: &str = "nav/subgoal/lrn";
        let c = cases(&format!("guide = \"{GUIDE}\"\nclock = \"wall\""))
            .into_iter()
            .find(|c| c.name == "dstar_lite")
            .unwrap();
        let mut h = c.stage();
        // The guide's frame was captured at 10 s, the robot at the origin
        // facing east; by the time its subgoal (10 m ahead, 10 m left)
        // arrives the robot has turned north and moved 2 m.
        h.put("state/pose", pose(at(1, 10 * S)));
        h.step(Wake::Tick, 10 * S);
        h.put(
            "state/pose",
            Pose {
                position_m: [2.0, 0.0, 0.0],
                yaw_rad: std::f64::consts::FRAC_PI_2,
                ..pose(at(2, 10 * S + S / 5))
            },
        );
        h.put(GUIDE, guide(1));
        c.put_primary(&mut h, at(2, 10 * S + S / 5));
        let out = h.step(h.wake_on(c.primary), 10 * S + S / 5);
        assert_eq!(topics_of(&out), c.outputs);
        let Method::Map(m) = &h.stage.method else {
            unreachable!()
        };
        let MapPlanner::DStarLite(Some(pl)) = &m.planner else {
            panic!("no planning grid")
        };
        let g = pl.goal_m();
        assert!(
            (g[0] - 10.0).abs() < 1e-9 && (g[1] - 10.0).abs() < 1e-9,
            "placed with the pose at 10 s: {g:?}"
        );
    }

    #[test]
    fn hips_learner_alone_needs_a_model() {
        let lib = "method = \"hip\"\nhip_library = \"l.toml\"\n";
        let e = farsight_stage::parse_config::<SubgoalStageConfig>(
            &format!("{lib}[hip]\nphi = 0.0\n"),
            "test",
        )
        .expect_err("phi = 0 without a model plans on nothing")
        .to_string();
        assert!(e.contains("hip.phi") && e.contains("hip_model"), "{e}");
        for ok in [
            format!("{lib}hip_model = \"m.toml\"\n[hip]\nphi = 0.0\n"),
            format!("{lib}[hip]\nphi = 0.5\n"),
        ] {
            farsight_stage::parse_config::<SubgoalStageConfig>(&ok, "test").expect(&ok);
        }
    }

    #[test]
    fn a_guide_must_be_a_named_subgoal_topic_for_a_method_that_follows_one() {
        let refused = |toml: &str| {
            farsight_stage::parse_config::<SubgoalStageConfig>(toml, "test")
                .expect_err(toml)
                .to_string()
        };
        let e = refused("method = \"lrn\"\nguide = \"nav/subgoal/x\"");
        assert!(e.contains("guide") && e.contains("nav/subgoal/x"), "{e}");
        let e = refused("guide = \"nav/goal\"");
        assert!(e.contains("guide") && e.contains("nav/goal"), "{e}");
        let e = refused("guide = \"nav/subgoal\"");
        assert!(e.contains("other than subgoal_topic"), "{e}");
        let e = refused("subgoal_topic = \"nav/path/visual\"");
        assert!(
            e.contains("subgoal_topic") && e.contains("nav/path/visual"),
            "{e}"
        );
        // The graph sees the guide in place of nav/goal, and the named output.
        let c: SubgoalStageConfig = farsight_stage::parse_config(
            "method = \"lrn\"\nsubgoal_topic = \"nav/subgoal/lrn\"",
            "test",
        )
        .unwrap();
        let io =
            farsight_stage::DeclaresTopics::topics(&c, "lrn", std::path::Path::new(".")).unwrap();
        assert!(io.writes.iter().any(|t| t == "nav/subgoal/lrn"), "{io:?}");
        let c: SubgoalStageConfig =
            farsight_stage::parse_config("guide = \"nav/subgoal/lrn\"", "test").unwrap();
        let io = farsight_stage::DeclaresTopics::topics(&c, "povnav", std::path::Path::new("."))
            .unwrap();
        assert!(
            io.reads.iter().any(|r| r.topic == "nav/subgoal/lrn"),
            "{io:?}"
        );
        assert!(!io.reads.iter().any(|r| r.topic == "nav/goal"), "{io:?}");
    }

    #[test]
    fn an_input_drained_on_a_tick_is_answered_in_that_step() {
        // The runner drains every input at every wake and drops what the
        // step leaves: an input the tick drained must not be lost.
        for c in cases("") {
            let mut h = c.stage();
            h.put("state/pose", pose(at(90, 10 * S)));
            h.put("nav/goal", goal());
            c.put_primary(&mut h, at(7, 10 * S));
            let out = h.step(Wake::Tick, 10 * S);
            assert_eq!(subgoals(&out).len(), 1, "{}", c.name);
        }
    }

    #[test]
    fn a_costmap_before_the_goal_is_planned_on_when_the_goal_comes() {
        // As it waited in its subscriber: the plan needs no second map.
        for c in cases("")
            .into_iter()
            .filter(|c| c.primary == "costmap/fused")
        {
            let mut h = c.stage();
            h.put("state/pose", pose(at(90, 10 * S)));
            c.put_primary(&mut h, at(7, 10 * S));
            assert!(h.step(h.wake_on(c.primary), 10 * S).is_empty());
            h.put("nav/goal", goal());
            let out = h.step(Wake::Tick, 10 * S + 50 * MS);
            let s = subgoals(&out);
            assert_eq!(s.len(), 1, "{}", c.name);
            assert_eq!(s[0].stamp, at(7, 10 * S), "{}", c.name);
            assert_eq!(h.health.report().messages_in, 1, "{}", c.name);
        }
    }

    #[test]
    fn on_the_wall_clock_the_map_planners_replan_at_their_rate_keeping_the_stamp() {
        for c in cases("clock = \"wall\"\nreplan_rate_hz = 2.0")
            .into_iter()
            .filter(|c| c.primary == "costmap/fused")
        {
            let mut h = c.stage();
            h.put("state/pose", pose(at(90, 10 * S)));
            h.put("nav/goal", goal());
            c.put_primary(&mut h, at(7, 10 * S));
            let out = h.step(h.wake_on(c.primary), 10 * S);
            assert_eq!(subgoals(&out).len(), 1, "{}", c.name);
            // Not due yet: the next plan is half a second after this one.
            assert!(
                h.step(Wake::Tick, 10 * S + 100 * MS).is_empty(),
                "{}",
                c.name
            );
            let out = h.step(Wake::Tick, 10 * S + 600 * MS);
            let s = subgoals(&out);
            assert_eq!(s.len(), 1, "{}: replanned on the tick", c.name);
            assert_eq!(s[0].stamp, at(7, 10 * S), "{}: the map's age shows", c.name);
            // Past the deadline on the wall clock: no plan, the stale input named.
            assert!(
                h.step(Wake::Tick, 11 * S + 200 * MS).is_empty(),
                "{}",
                c.name
            );
            assert_eq!(h.health.state(), HealthState::DEGRADED, "{}", c.name);
            assert!(h.health.report().reason.as_str().contains("costmap/fused"));
        }
    }

    #[test]
    fn povnav_without_a_camera_model_drops_the_frame() {
        let c = cases("").remove(0);
        assert_eq!(c.name, "povnav");
        let mut h = c.stage();
        h.put("state/pose", pose(at(90, 10 * S)));
        h.put("nav/goal", goal());
        h.put("perception/front/navigability", navigability(at(7, 10 * S)));
        assert!(h.step(h.wake_on(c.primary), 10 * S).is_empty());
        assert_eq!(h.health.report().dropped, 1);
        assert_eq!(h.health.report().messages_in, 1);
    }

    #[test]
    fn ports_are_what_the_config_declares_to_the_graph() {
        use farsight_stage::DeclaresTopics;
        for c in cases("") {
            let h = c.stage();
            let io = c
                .config()
                .topics("subgoal-selection", std::path::Path::new("."))
                .unwrap();
            farsight_stage::runtime::check_ports(&io, h.stage.ports())
                .unwrap_or_else(|e| panic!("{}: {e}", c.name));
            assert_eq!(h.stage.ports().inputs[0].topic, c.primary, "{}", c.name);
            assert!(h.stage.ports().inputs[0].wakes, "{}", c.name);
        }
        // HIP with a learned model also reads (and wakes on) the camera
        // image; its ports need no model file to be declared.
        let config: SubgoalStageConfig = farsight_stage::parse_config(
            "method = \"hip\"\nhip_library = \"l.toml\"\nhip_model = \"m.toml\"\ncamera = \"rear\"\n",
            "test",
        )
        .unwrap();
        let io = config
            .topics("subgoal-selection", std::path::Path::new("."))
            .unwrap();
        let (ports, _, _) = declare_ports(&config);
        farsight_stage::runtime::check_ports(&io, &ports).unwrap();
        let image = ports
            .input_index("camera/rear/image")
            .expect("an image input");
        assert!(ports.inputs[image].wakes);
    }
}
