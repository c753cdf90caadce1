//! farsight's topics as Foxglove messages: what the live server sends and
//! what a recording's Foxglove channels hold, made in one place.
//!
//! Frames follow ROS (REP-103, REP-105): `map` is farsight's local ENU
//! world frame, `odom` coincides with it (farsight's pose is already
//! drift-corrected), `base_link` is the robot (x ahead, y left, z up) and
//! `camera_<name>_optical_frame` each camera (z forward, x right, y down).
//! `/tf` carries map -> odom -> base_link from every pose, and base_link ->
//! each camera from its `camera/<name>/info` mount.
//!
//! Images are JPEG, downscaled by a whole factor to at most
//! `image_max_width_px`, and `/camera/<name>/calibration` describes the
//! image as sent (intrinsics scaled with it), so the 3-D panel projects
//! costmap and paths into it. POVNav's visual path (pixels) is shown twice:
//! on the image (`/camera/<name>/annotations`) and on the ground
//! (`/nav/path/visual`, projected through the camera model onto flat
//! ground, as POVNav section 4.6 does for its safe path).
//!
//! Every message is logged at its capture time, one clock for every topic;
//! health reports (stamped with the stage's last output) are logged at the
//! newest capture time seen, so they line up with the data they describe.

use crate::throttle::{Rate, Throttle};
use farsight_imaging as imaging;
use farsight_interfaces::camera::Camera;
use farsight_interfaces::message::{Costmap, Image, Message};
use farsight_interfaces::msg::*;
use foxglove::bytes::Bytes;
use foxglove::messages as fm;
use foxglove::{Encode, Schema};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Costs at or above this (lethal cells are infinite) are drawn at it:
/// Foxglove's colour map needs finite values. farsight's own costmap
/// channels keep the exact costs.
pub const DISPLAY_COST_CAP_S_PER_M: f32 = 20.0;

/// What the view sends and how often (`[foxglove]` in a config file).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ViewConfig {
    /// Images wider than this are downscaled by a whole factor to fit.
    pub image_max_width_px: u32,
    /// JPEG quality of the images sent (1..=100).
    pub jpeg_quality: u8,
    /// Rate limits per Foxglove topic on capture time; the first matching
    /// rule wins, unmatched topics are not limited.
    pub rate: Vec<Rate>,
}

impl Default for ViewConfig {
    /// Sized for a 10 Mbit/s link (1.25 MB/s): cameras, overlays and LRN
    /// bins at 5 Hz and 640 px, costmaps and the goal at 1 Hz, health at
    /// 2 Hz, pose, transforms, paths and commands at 10 Hz.
    fn default() -> Self {
        Self {
            image_max_width_px: 640,
            jpeg_quality: 75,
            rate: vec![
                Rate::new("/camera/*/image", 5.0),
                Rate::new("/camera/*/annotations", 5.0),
                Rate::new("/camera/*/calibration", 1.0),
                Rate::new("/perception/**", 5.0),
                Rate::new("/costmap/*", 1.0),
                Rate::new("/nav/goal", 1.0),
                Rate::new("/bins/*", 5.0),
                Rate::new("/health/*", 2.0),
                Rate::new("/**", 10.0),
            ],
        }
    }
}

impl ViewConfig {
    pub fn validate(&self) -> Result<(), String> {
        if self.image_max_width_px < 16 {
            return Err(format!(
                "image_max_width_px = {}: must be at least 16",
                self.image_max_width_px
            ));
        }
        if !(1..=100).contains(&self.jpeg_quality) {
            return Err(format!(
                "jpeg_quality = {}: must be 1..=100",
                self.jpeg_quality
            ));
        }
        self.rate.iter().try_for_each(Rate::validate)
    }
}

/// A JSON message on a channel whose JSON schema farsight defines (no
/// Foxglove schema fits commands, e-stop and health).
#[derive(Debug, Clone, PartialEq)]
pub struct JsonMessage {
    pub schema_name: &'static str,
    pub schema: &'static str,
    pub value: serde_json::Value,
}

/// One Foxglove message.
#[derive(Debug, Clone, PartialEq)]
pub enum FoxMessage {
    CompressedImage(fm::CompressedImage),
    CameraCalibration(fm::CameraCalibration),
    ImageAnnotations(fm::ImageAnnotations),
    FrameTransforms(fm::FrameTransforms),
    Grid(fm::Grid),
    PoseInFrame(fm::PoseInFrame),
    PosesInFrame(fm::PosesInFrame),
    SceneUpdate(fm::SceneUpdate),
    Json(JsonMessage),
}

macro_rules! each_encoded {
    ($self:ident, $m:ident => $e:expr, $json:ident => $j:expr) => {
        match $self {
            FoxMessage::CompressedImage($m) => $e,
            FoxMessage::CameraCalibration($m) => $e,
            FoxMessage::ImageAnnotations($m) => $e,
            FoxMessage::FrameTransforms($m) => $e,
            FoxMessage::Grid($m) => $e,
            FoxMessage::PoseInFrame($m) => $e,
            FoxMessage::PosesInFrame($m) => $e,
            FoxMessage::SceneUpdate($m) => $e,
            FoxMessage::Json($json) => $j,
        }
    };
}

fn encoded<T: Encode>(m: &T) -> Vec<u8> {
    let mut buf = Vec::with_capacity(m.encoded_len().unwrap_or(256));
    // A Vec grows as needed: encoding into it cannot run out of room.
    m.encode(&mut buf)
        .unwrap_or_else(|e| unreachable!("protobuf encoding into a Vec: {e}"));
    buf
}

fn schema_of<T: Encode>(_: &T) -> (Schema, String) {
    (
        T::get_schema().expect("Foxglove's message types have schemas"),
        T::get_message_encoding(),
    )
}

impl FoxMessage {
    /// The channel's schema and message encoding (`protobuf` or `json`).
    pub fn schema(&self) -> (Schema, String) {
        each_encoded!(self, m => schema_of(m), j => (
            Schema::new(j.schema_name, "jsonschema", j.schema.as_bytes().to_vec()),
            "json".to_string(),
        ))
    }

    /// The message's bytes in its encoding.
    pub fn encode(&self) -> Vec<u8> {
        each_encoded!(self, m => encoded(m), j => serde_json::to_vec(&j.value)
            .unwrap_or_else(|e| unreachable!("a JSON value serialises: {e}")))
    }
}

/// One message for a Foxglove topic, logged at `log_time_ns`.
#[derive(Debug, Clone, PartialEq)]
pub struct Out {
    pub topic: String,
    pub log_time_ns: u64,
    pub message: FoxMessage,
}

/// What the view knows of one camera.
#[derive(Debug, Clone, Default)]
struct CameraState {
    camera: Option<Camera>,
    /// The newest frame as sent (RGB8, downscaled), for the overlays.
    frame: Option<(ImageHeader, Vec<u8>)>,
    /// Size of the frames the camera publishes (may be smaller than the
    /// camera model's when the bridge downsampled them).
    input_size_px: Option<(u32, u32)>,
    /// The newest visual path and subgoal, in the camera model's pixels.
    path_px: Vec<[f32; 2]>,
    subgoal_px: Option<[f32; 2]>,
}

/// Converts farsight messages to Foxglove messages, throttled per topic.
#[derive(Debug)]
pub struct View {
    config: ViewConfig,
    throttle: Throttle,
    cameras: BTreeMap<String, CameraState>,
    newest_ns: u64,
    /// The newest goal (x, y in map), sent again with the pose: a goal is
    /// published once, and an app that connects later must still see it.
    goal_m: Option<(f64, f64)>,
    dropped: BTreeMap<String, u64>,
}

/// Names one camera's optical frame.
pub fn optical_frame(camera: &str) -> String {
    format!("camera_{camera}_optical_frame")
}

fn stamp(ns: u64) -> Option<fm::Timestamp> {
    let sec = u32::try_from(ns / 1_000_000_000).unwrap_or(u32::MAX);
    Some(fm::Timestamp::new(sec, (ns % 1_000_000_000) as u32))
}

fn vec3(x: f64, y: f64, z: f64) -> Option<fm::Vector3> {
    Some(fm::Vector3 { x, y, z })
}

fn yaw_quat(yaw_rad: f64) -> Option<fm::Quaternion> {
    Some(fm::Quaternion {
        x: 0.0,
        y: 0.0,
        z: (yaw_rad / 2.0).sin(),
        w: (yaw_rad / 2.0).cos(),
    })
}

fn planar_pose(x_m: f64, y_m: f64, yaw_rad: f64) -> fm::Pose {
    fm::Pose {
        position: vec3(x_m, y_m, 0.0),
        orientation: yaw_quat(yaw_rad),
    }
}

fn color(r: f64, g: f64, b: f64, a: f64) -> Option<fm::Color> {
    Some(fm::Color { r, g, b, a })
}

fn json(schema_name: &'static str, schema: &'static str, value: serde_json::Value) -> FoxMessage {
    FoxMessage::Json(JsonMessage {
        schema_name,
        schema,
        value,
    })
}

impl View {
    pub fn new(config: ViewConfig) -> Result<Self, String> {
        config.validate()?;
        Ok(Self {
            throttle: Throttle::new(config.rate.clone()),
            config,
            cameras: BTreeMap::new(),
            newest_ns: 0,
            goal_m: None,
            dropped: BTreeMap::new(),
        })
    }

    /// Messages that could not be shown, per farsight topic (a corrupt
    /// frame, a camera model that does not validate).
    pub fn dropped(&self) -> &BTreeMap<String, u64> {
        &self.dropped
    }

    fn drop_message(&mut self, topic: &str, why: impl std::fmt::Display) {
        let n = self.dropped.entry(topic.to_string()).or_default();
        *n += 1;
        // Logged on the first and then every hundredth: a broken camera at
        // 30 Hz must not flood the log.
        if *n % 100 == 1 {
            tracing::warn!(topic, dropped = *n, "not shown in Foxglove: {why}");
        }
    }

    fn admit(&mut self, topic: &str, t_ns: u64) -> bool {
        self.throttle.admit(topic, t_ns)
    }

    /// The Foxglove messages for one farsight message of `topic`.
    // One arm per farsight topic; the throttle stays inside its arm rather
    // than in a guard, where a refused message would fall through to `_`.
    #[allow(clippy::collapsible_match)]
    pub fn on_message(&mut self, topic: &str, msg: &Message) -> Vec<Out> {
        let t_ns = msg.stamp().capture_time_ns;
        if !matches!(msg, Message::Health(_)) {
            self.newest_ns = self.newest_ns.max(t_ns);
        }
        let parts: Vec<&str> = topic.split('/').collect();
        let mut out = Vec::new();
        fn emit(out: &mut Vec<Out>, topic: String, log_time_ns: u64, message: FoxMessage) {
            out.push(Out {
                topic,
                log_time_ns,
                message,
            })
        }
        match (parts.as_slice(), msg) {
            (["camera", name, "image"], Message::Image(img)) => {
                let fox = format!("/camera/{name}/image");
                if self.admit(&fox, t_ns) {
                    match self.camera_image(name, img) {
                        Ok(m) => emit(&mut out, fox, t_ns, m),
                        Err(e) => self.drop_message(topic, e),
                    }
                }
            }
            (["camera", name, "info"], Message::CameraInfo(info)) => {
                match Camera::from_info(info) {
                    Ok(c) => {
                        self.cameras.entry(name.to_string()).or_default().camera = Some(c);
                        let fox = format!("/camera/{name}/calibration");
                        if let Some(m) = self.calibration(name, t_ns) {
                            if self.admit(&fox, t_ns) {
                                emit(&mut out, fox, t_ns, m);
                            }
                        }
                    }
                    Err(e) => self.drop_message(topic, e),
                }
            }
            (
                ["perception", name, layer @ ("navigability" | "classes" | "heatmap")],
                Message::Image(img),
            ) => {
                let fox = format!("/perception/{name}/{layer}");
                if self.cameras.get(*name).is_some_and(|c| c.frame.is_some())
                    && self.admit(&fox, t_ns)
                {
                    match self.overlay(name, layer, img) {
                        Ok(m) => emit(&mut out, fox, t_ns, m),
                        Err(e) => self.drop_message(topic, e),
                    }
                }
            }
            (["bins", "angular"], Message::AngularBins(b)) => {
                if self.admit("/bins/angular", t_ns) {
                    emit(
                        &mut out,
                        "/bins/angular".into(),
                        t_ns,
                        angular_bins_scene(b),
                    );
                }
            }
            (["costmap", layer], Message::Costmap(c)) => {
                let fox = format!("/costmap/{layer}");
                if self.admit(&fox, t_ns) {
                    match costmap_grid(c) {
                        Ok(m) => emit(&mut out, fox, t_ns, m),
                        Err(e) => self.drop_message(topic, e),
                    }
                }
            }
            (["nav", "subgoal", ..], Message::Subgoal(s)) => {
                let fox = format!("/{topic}");
                if s.x_m.is_finite() && s.y_m.is_finite() && self.admit(&fox, t_ns) {
                    let m = fm::PoseInFrame {
                        timestamp: stamp(t_ns),
                        frame_id: "base_link".into(),
                        pose: Some(planar_pose(
                            s.x_m as f64,
                            s.y_m as f64,
                            s.heading_rad as f64,
                        )),
                    };
                    emit(&mut out, fox, t_ns, FoxMessage::PoseInFrame(m));
                }
                if parts.len() == 2 && s.image_u_px.is_finite() && s.image_v_px.is_finite() {
                    // A subgoal names no camera: it is the visual path's.
                    if let Some(name) = self.image_camera(None) {
                        let c = self.cameras.entry(name.clone()).or_default();
                        c.subgoal_px = Some([s.image_u_px, s.image_v_px]);
                        if let Some(o) = self.annotations(&name, t_ns) {
                            out.push(o);
                        }
                    }
                }
            }
            (["nav", "path", kind], Message::Path(p)) => {
                let fox = format!("/nav/path/{kind}");
                match p.frame {
                    PathFrame::WORLD | PathFrame::ROBOT => {
                        if self.admit(&fox, t_ns) {
                            let frame = if p.frame == PathFrame::WORLD {
                                "map"
                            } else {
                                "base_link"
                            };
                            let poses = p
                                .points
                                .as_slice()
                                .iter()
                                .filter(|q| q[0].is_finite() && q[1].is_finite())
                                .map(|q| planar_pose(q[0] as f64, q[1] as f64, 0.0))
                                .collect();
                            emit(&mut out, fox, t_ns, poses_in_frame(t_ns, frame, poses));
                        }
                    }
                    PathFrame::IMAGE => match self.image_camera(Some(p.camera_id)) {
                        Some(name) => {
                            let pixels: Vec<[f32; 2]> = p
                                .points
                                .as_slice()
                                .iter()
                                .copied()
                                .filter(|q| q[0].is_finite() && q[1].is_finite())
                                .collect();
                            let c = self.cameras.entry(name.clone()).or_default();
                            c.path_px = pixels;
                            let camera = c.camera.clone();
                            if let Some(camera) = camera {
                                if self.admit(&fox, t_ns) {
                                    let poses = ground_path(&camera, &self.cameras[&name].path_px);
                                    emit(
                                        &mut out,
                                        fox,
                                        t_ns,
                                        poses_in_frame(t_ns, "base_link", poses),
                                    );
                                }
                            }
                            if let Some(o) = self.annotations(&name, t_ns) {
                                out.push(o);
                            }
                        }
                        None => self.drop_message(
                            topic,
                            format!(
                                "no camera/<name>/info with camera id {} seen yet",
                                p.camera_id
                            ),
                        ),
                    },
                    other => self.drop_message(topic, format!("unknown path frame {other}")),
                }
            }
            (["nav", "goal"], Message::Goal(g)) => {
                if g.x_m.is_finite() && g.y_m.is_finite() {
                    self.goal_m = Some((g.x_m, g.y_m));
                    out.extend(self.goal(t_ns));
                } else {
                    self.drop_message(topic, "the goal is not finite");
                }
            }
            (["state", "pose"], Message::Pose(p)) => {
                let [x, y, z] = p.position_m;
                if [x, y, z, p.yaw_rad].iter().all(|v| v.is_finite()) {
                    if self.admit("/state/pose", t_ns) {
                        let m = fm::PoseInFrame {
                            timestamp: stamp(t_ns),
                            frame_id: "map".into(),
                            pose: Some(fm::Pose {
                                position: vec3(x, y, z),
                                orientation: yaw_quat(p.yaw_rad),
                            }),
                        };
                        emit(
                            &mut out,
                            "/state/pose".into(),
                            t_ns,
                            FoxMessage::PoseInFrame(m),
                        );
                    }
                    if self.admit("/tf", t_ns) {
                        emit(&mut out, "/tf".into(), t_ns, self.transforms(p, t_ns));
                    }
                    out.extend(self.goal(t_ns));
                } else {
                    self.drop_message(topic, "a position or yaw is not finite");
                }
            }
            (["cmd", _], Message::VelocityCommand(c)) => {
                let fox = format!("/{topic}");
                if self.admit(&fox, t_ns) {
                    emit(&mut out, fox, t_ns, command_json(c));
                }
            }
            (["safety", "estop"], Message::EStop(e)) => {
                if self.admit("/safety/estop", t_ns) {
                    emit(&mut out, "/safety/estop".into(), t_ns, estop_json(e));
                }
            }
            (["health", _], Message::Health(h)) => {
                let fox = format!("/{topic}");
                let at = if self.newest_ns > 0 {
                    self.newest_ns
                } else {
                    t_ns
                };
                if self.admit(&fox, at) {
                    emit(&mut out, fox, at, health_json(h));
                }
            }
            _ => {}
        }
        out
    }

    /// The camera a pixel path belongs to: by id, or the only camera.
    fn image_camera(&self, id: Option<u32>) -> Option<String> {
        let with_id = |c: &CameraState| match (id, &c.camera) {
            (Some(id), Some(cam)) => cam.id == id,
            (None, Some(_)) => true,
            (_, None) => false,
        };
        let mut known = self.cameras.iter().filter(|(_, c)| with_id(c));
        let first = known.next().map(|(n, _)| n.clone());
        match id {
            Some(_) => first,
            // Without an id only an unambiguous camera will do.
            None => first.filter(|_| known.next().is_none()),
        }
    }

    fn camera_image(&mut self, name: &str, img: &Image) -> Result<FoxMessage, String> {
        let (h, pixels) =
            imaging::decode_frame(img.header, &img.data).map_err(|e| e.to_string())?;
        let rgb = imaging::to_rgb8(&h, &pixels).map_err(|e| e.to_string())?;
        let rgb_header =
            ImageHeader::packed(h.stamp, h.camera_id, h.width, h.height, PixelEncoding::RGB8);
        let factor = h.width.div_ceil(self.config.image_max_width_px).max(1);
        let (small_h, small) =
            imaging::downsample(&rgb_header, &rgb, factor).map_err(|e| e.to_string())?;
        let jpeg = imaging::encode_jpeg(&small_h, &small, self.config.jpeg_quality)
            .map_err(|e| e.to_string())?;
        let c = self.cameras.entry(name.to_string()).or_default();
        c.input_size_px = Some((h.width, h.height));
        c.frame = Some((small_h, small));
        Ok(FoxMessage::CompressedImage(fm::CompressedImage {
            timestamp: stamp(h.stamp.capture_time_ns),
            frame_id: optical_frame(name),
            data: Bytes::from(jpeg),
            format: "jpeg".into(),
        }))
    }

    /// Pixel scale from the camera model's image to the image as sent.
    fn sent_scale(&self, name: &str) -> Option<(f64, f64)> {
        let c = self.cameras.get(name)?;
        let camera = c.camera.as_ref()?;
        let (h, _) = c.frame.as_ref()?;
        Some((
            h.width as f64 / camera.model.width as f64,
            h.height as f64 / camera.model.height as f64,
        ))
    }

    fn calibration(&self, name: &str, t_ns: u64) -> Option<FoxMessage> {
        let c = self.cameras.get(name)?;
        let camera = c.camera.as_ref()?;
        let (h, _) = c.frame.as_ref()?;
        let (sx, sy) = self.sent_scale(name)?;
        let m = &camera.model;
        // Decimation keeps pixel i*f as pixel i: pixel coordinates (centres
        // at integers, as ROS and Foxglove count them) scale by 1/f.
        let (fx, fy, cx, cy) = (m.fx * sx, m.fy * sy, m.cx * sx, m.cy * sy);
        let (distortion_model, d) = match m.lens {
            farsight_interfaces::camera::Lens::PlumbBob { k1, k2, p1, p2, k3 } => {
                ("plumb_bob", vec![k1, k2, p1, p2, k3])
            }
            farsight_interfaces::camera::Lens::KannalaBrandt { k1, k2, k3, k4 } => {
                ("kannala_brandt", vec![k1, k2, k3, k4])
            }
        };
        Some(FoxMessage::CameraCalibration(fm::CameraCalibration {
            timestamp: stamp(t_ns),
            frame_id: optical_frame(name),
            width: h.width,
            height: h.height,
            distortion_model: distortion_model.into(),
            d,
            k: vec![fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
            r: vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            p: vec![fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
        }))
    }

    fn overlay(&self, name: &str, layer: &str, img: &Image) -> Result<FoxMessage, String> {
        let (fh, frame) = self.cameras[name]
            .frame
            .as_ref()
            .ok_or("no camera frame yet")?;
        let (mh, mask) = imaging::decode_frame(img.header, &img.data).map_err(|e| e.to_string())?;
        mh.validate(mask.len()).map_err(|e| e.to_string())?;
        let (mw, mht) = (mh.width as usize, mh.height as usize);
        let stride = mh.stride_bytes as usize;
        let value_at = |i: usize| -> f32 {
            let (x, y) = (i % mw, i / mw);
            match mh.encoding {
                PixelEncoding::F32 => {
                    let o = y * stride + x * 4;
                    f32::from_le_bytes([mask[o], mask[o + 1], mask[o + 2], mask[o + 3]])
                }
                _ => mask[y * stride + x] as f32,
            }
        };
        if !matches!(mh.encoding, PixelEncoding::MONO8 | PixelEncoding::F32) {
            return Err(format!(
                "{layer} is {}, expected mono8 or 32FC1",
                mh.encoding
            ));
        }
        let (w, h) = (fh.width as usize, fh.height as usize);
        let blended = match layer {
            "navigability" => imaging::overlay(frame, w, h, mw, mht, 0.45, |i| {
                Some(if value_at(i) > 127.0 {
                    [0, 220, 0]
                } else {
                    [230, 0, 0]
                })
            }),
            "classes" => imaging::overlay(frame, w, h, mw, mht, 0.5, |i| {
                Some(imaging::class_color(value_at(i) as u8))
            }),
            _ => imaging::overlay(frame, w, h, mw, mht, 0.6, |i| {
                let v = value_at(i);
                let v = if mh.encoding == PixelEncoding::F32 {
                    v
                } else {
                    v / 255.0
                };
                v.is_finite()
                    .then(|| [(v.clamp(0.0, 1.0) * 255.0) as u8, 0, 0])
            }),
        };
        let jpeg = imaging::encode_jpeg(fh, &blended, self.config.jpeg_quality)
            .map_err(|e| e.to_string())?;
        Ok(FoxMessage::CompressedImage(fm::CompressedImage {
            timestamp: stamp(img.header.stamp.capture_time_ns),
            frame_id: optical_frame(name),
            data: Bytes::from(jpeg),
            format: "jpeg".into(),
        }))
    }

    /// The newest goal as `/nav/goal`, if its throttle admits one at `t_ns`.
    fn goal(&mut self, t_ns: u64) -> Option<Out> {
        let (x_m, y_m) = self.goal_m?;
        if !self.admit("/nav/goal", t_ns) {
            return None;
        }
        Some(Out {
            topic: "/nav/goal".into(),
            log_time_ns: t_ns,
            message: FoxMessage::PoseInFrame(fm::PoseInFrame {
                timestamp: stamp(t_ns),
                frame_id: "map".into(),
                pose: Some(planar_pose(x_m, y_m, 0.0)),
            }),
        })
    }

    /// The visual path and subgoal drawn on the image as sent.
    fn annotations(&mut self, name: &str, t_ns: u64) -> Option<Out> {
        let (sx, sy) = self.sent_scale(name)?;
        let fox = format!("/camera/{name}/annotations");
        if !self.admit(&fox, t_ns) {
            return None;
        }
        let c = &self.cameras[name];
        let px = |q: [f32; 2]| fm::Point2 {
            x: q[0] as f64 * sx,
            y: q[1] as f64 * sy,
        };
        let mut points = Vec::new();
        if c.path_px.len() >= 2 {
            points.push(fm::PointsAnnotation {
                timestamp: stamp(t_ns),
                r#type: fm::points_annotation::Type::LineStrip as i32,
                points: c.path_px.iter().copied().map(px).collect(),
                outline_color: color(1.0, 0.6, 0.0, 1.0),
                // A line strip is not filled; the schema still wants a colour.
                fill_color: color(0.0, 0.0, 0.0, 0.0),
                thickness: 3.0,
                ..Default::default()
            });
        }
        if let Some(s) = c.subgoal_px {
            points.push(fm::PointsAnnotation {
                timestamp: stamp(t_ns),
                r#type: fm::points_annotation::Type::Points as i32,
                points: vec![px(s)],
                outline_color: color(1.0, 0.0, 0.0, 1.0),
                fill_color: color(1.0, 0.0, 0.0, 1.0),
                thickness: 12.0,
                ..Default::default()
            });
        }
        Some(Out {
            topic: fox,
            log_time_ns: t_ns,
            message: FoxMessage::ImageAnnotations(fm::ImageAnnotations {
                timestamp: stamp(t_ns),
                points,
                ..Default::default()
            }),
        })
    }

    fn transforms(&self, p: &Pose, t_ns: u64) -> FoxMessage {
        let tf = |parent: &str, child: String, t: [f64; 3], q: [f64; 4]| fm::FrameTransform {
            timestamp: stamp(t_ns),
            parent_frame_id: parent.into(),
            child_frame_id: child,
            translation: vec3(t[0], t[1], t[2]),
            rotation: Some(fm::Quaternion {
                x: q[0],
                y: q[1],
                z: q[2],
                w: q[3],
            }),
        };
        let yaw = p.yaw_rad;
        let mut transforms = vec![
            tf("map", "odom".into(), [0.0; 3], [0.0, 0.0, 0.0, 1.0]),
            tf(
                "odom",
                "base_link".into(),
                p.position_m,
                [0.0, 0.0, (yaw / 2.0).sin(), (yaw / 2.0).cos()],
            ),
        ];
        for (name, c) in &self.cameras {
            if let Some(camera) = &c.camera {
                let q = camera.mount.robot_from_optical.quaternion();
                transforms.push(tf(
                    "base_link",
                    optical_frame(name),
                    camera.mount.translation_m.into(),
                    [q.i, q.j, q.k, q.w],
                ));
            }
        }
        FoxMessage::FrameTransforms(fm::FrameTransforms { transforms })
    }
}

/// Where each pixel of a path meets flat ground, in `base_link`; pixels at
/// or above the horizon have no ground point and are left out.
fn ground_path(camera: &Camera, pixels: &[[f32; 2]]) -> Vec<fm::Pose> {
    pixels
        .iter()
        .filter_map(|q| camera.ground_point_m(q[0] as f64, q[1] as f64))
        .map(|(x, y)| planar_pose(x, y, 0.0))
        .collect()
}

fn poses_in_frame(t_ns: u64, frame: &str, poses: Vec<fm::Pose>) -> FoxMessage {
    FoxMessage::PosesInFrame(fm::PosesInFrame {
        timestamp: stamp(t_ns),
        frame_id: frame.into(),
        poses,
    })
}

/// A costmap as a `Grid` in `map`. Foxglove grids grow from their origin
/// along +x and +y, so row 0 is the southmost row, where farsight's row 0
/// is the northmost: rows are written in reverse.
pub fn costmap_grid(c: &Costmap) -> Result<FoxMessage, String> {
    let h = &c.header;
    h.validate(c.data.len())?;
    let w = h.width as usize;
    let res = h.resolution_m as f64;
    let mut data = Vec::with_capacity(c.data.len() * 4);
    for row in c.data.chunks(w.max(1)).rev() {
        for cell in row {
            let cost = if cell.cost_s_per_m.is_nan() {
                f32::NAN
            } else {
                cell.cost_s_per_m.min(DISPLAY_COST_CAP_S_PER_M)
            };
            data.extend_from_slice(&cost.to_le_bytes());
        }
    }
    let rows = h.height as f64;
    Ok(FoxMessage::Grid(fm::Grid {
        timestamp: stamp(h.stamp.capture_time_ns),
        frame_id: "map".into(),
        pose: Some(planar_pose(
            h.x_min_m - 0.5 * res,
            h.y_max_m - (rows - 0.5) * res,
            0.0,
        )),
        column_count: h.width,
        cell_size: Some(fm::Vector2 { x: res, y: res }),
        row_stride: h.width * 4,
        cell_stride: 4,
        fields: vec![fm::PackedElementField {
            name: "cost_s_per_m".into(),
            offset: 0,
            r#type: fm::packed_element_field::NumericType::Float32 as i32,
        }],
        data: Bytes::from(data),
    }))
}

/// LRN's angular bins as wedges around the robot: length and colour by
/// score (red 0 to green 1), unobserved bins short and grey.
pub fn angular_bins_scene(b: &AngularBins) -> FoxMessage {
    let t_ns = b.stamp.capture_time_ns;
    let mut points = Vec::new();
    let mut colors = Vec::new();
    let scores = b.scores.as_slice();
    let observed = b.observed.as_slice();
    for (i, &score) in scores.iter().enumerate() {
        let a0 = b.first_bin_start_rad as f64 + i as f64 * b.bin_width_rad as f64;
        let a1 = a0 + b.bin_width_rad as f64;
        let seen = observed.get(i).is_some_and(|&o| o != 0) && score.is_finite();
        let s = if seen {
            score.clamp(0.0, 1.0) as f64
        } else {
            0.0
        };
        let r = if seen { 1.0 + 4.0 * s } else { 0.5 };
        let c = if seen {
            fm::Color {
                r: 1.0 - s,
                g: s,
                b: 0.0,
                a: 0.8,
            }
        } else {
            fm::Color {
                r: 0.5,
                g: 0.5,
                b: 0.5,
                a: 0.5,
            }
        };
        // The polar histogram's outline, one strip: each bin's arc at its
        // radius, joined by the radial steps between bins (two points a
        // bin, a third of drawing each bin as a closed wedge).
        points.extend([bin_point(a0, r), bin_point(a1, r)]);
        colors.extend([c, c]);
    }
    let grey = fm::Color {
        r: 0.5,
        g: 0.5,
        b: 0.5,
        a: 0.5,
    };
    if !points.is_empty() {
        points.insert(0, bin_point(0.0, 0.0));
        colors.insert(0, grey);
        points.push(bin_point(0.0, 0.0));
        colors.push(grey);
    }
    FoxMessage::SceneUpdate(fm::SceneUpdate {
        deletions: vec![],
        entities: vec![fm::SceneEntity {
            timestamp: stamp(t_ns),
            frame_id: "base_link".into(),
            id: "angular_bins".into(),
            // Shown until the next update replaces it.
            lifetime: Some(fm::Duration::new(0, 0)),
            frame_locked: true,
            lines: vec![fm::LinePrimitive {
                r#type: fm::line_primitive::Type::LineStrip as i32,
                pose: Some(planar_pose(0.0, 0.0, 0.0)),
                thickness: 0.04,
                scale_invariant: false,
                points,
                color: Some(grey),
                colors,
                ..Default::default()
            }],
            ..Default::default()
        }],
    })
}

/// A point of the bins' drawing in base_link: bearing `a` rad, `r` m out.
fn bin_point(a: f64, r: f64) -> fm::Point3 {
    fm::Point3 {
        x: r * a.cos(),
        y: r * a.sin(),
        z: 0.05,
    }
}

fn time_json(ns: u64) -> serde_json::Value {
    serde_json::json!({ "sec": ns / 1_000_000_000, "nsec": ns % 1_000_000_000 })
}

macro_rules! json_schema {
    ($title:literal, { $($field:literal : $ty:literal),* $(,)? }) => {
        concat!(
            r#"{"title":""#, $title, r#"","type":"object","properties":{"timestamp":"#,
            // The shared time object: seconds and nanoseconds, as Foxglove's.
            r#"{"type":"object","properties":{"sec":{"type":"integer","minimum":0},"nsec":{"type":"integer","minimum":0,"maximum":999999999}},"required":["sec","nsec"]}"#,
            $(",\"", $field, "\":{\"type\":\"", $ty, "\"}"),*,
            r#"},"required":["timestamp""#, $(",\"", $field, "\""),*, "]}"
        )
    };
}

/// The JSON schema of `/cmd/*`.
pub const COMMAND_SCHEMA: &str = json_schema!("farsight.VelocityCommand", {
    "frame_seq": "integer", "linear_mps": "number", "angular_radps": "number",
    "reason": "string", "ttl_ms": "integer",
});
/// The JSON schema of `/safety/estop`.
pub const ESTOP_SCHEMA: &str = json_schema!("farsight.EStop", {
    "active": "boolean", "source": "string",
});
/// The JSON schema of `/health/*`.
pub const HEALTH_SCHEMA: &str = json_schema!("farsight.StageHealth", {
    "stage": "string", "state": "string", "pid": "integer", "messages_in": "integer",
    "messages_out": "integer", "dropped": "integer", "skipped": "integer",
    "last_latency_ms": "number", "reason": "string", "frame_seq": "integer",
});

fn command_json(c: &VelocityCommand) -> FoxMessage {
    json(
        "farsight.VelocityCommand",
        COMMAND_SCHEMA,
        serde_json::json!({
            "timestamp": time_json(c.stamp.capture_time_ns),
            "frame_seq": c.stamp.frame_seq,
            "linear_mps": finite_or_zero(c.linear_mps),
            "angular_radps": finite_or_zero(c.angular_radps),
            "reason": c.reason.to_string(),
            "ttl_ms": c.ttl_ms,
        }),
    )
}

fn estop_json(e: &EStop) -> FoxMessage {
    json(
        "farsight.EStop",
        ESTOP_SCHEMA,
        serde_json::json!({
            "timestamp": time_json(e.stamp.capture_time_ns),
            "active": e.active != 0,
            "source": e.source.as_str(),
        }),
    )
}

fn health_json(h: &StageHealth) -> FoxMessage {
    json(
        "farsight.StageHealth",
        HEALTH_SCHEMA,
        serde_json::json!({
            "timestamp": time_json(h.stamp.capture_time_ns),
            "stage": h.stage.as_str(),
            "state": h.state.to_string(),
            "pid": h.pid,
            "messages_in": h.messages_in,
            "messages_out": h.messages_out,
            "dropped": h.dropped,
            "skipped": h.skipped,
            "last_latency_ms": finite_or_zero(h.last_latency_ms),
            "reason": h.reason.as_str(),
            "frame_seq": h.stamp.frame_seq,
        }),
    )
}

/// JSON has no NaN: a command or latency that is not a number is written
/// as 0 (farsight's own channels keep the value).
fn finite_or_zero(v: f32) -> f64 {
    if v.is_finite() {
        v as f64
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use farsight_interfaces::camera::{CameraModel, Mount};

    fn front_camera() -> Camera {
        Camera::new(
            4,
            "front",
            CameraModel::pinhole(1280, 720, 800.0, 800.0, 640.0, 360.0),
            Mount::from_xyz_rpy_deg([0.5, 0.0, 1.2], [0.0, 10.0, 0.0]),
        )
    }

    fn frame(camera: &Camera, t_ns: u64) -> Message {
        let (w, h) = (camera.model.width, camera.model.height);
        Message::Image(Image {
            header: ImageHeader::packed(Stamp::new(1, t_ns), camera.id, w, h, PixelEncoding::RGB8),
            data: vec![90; (w * h * 3) as usize],
        })
    }

    #[test]
    fn a_frame_goes_out_downscaled_with_a_calibration_and_transforms_for_it() {
        let camera = front_camera();
        let mut view = View::new(ViewConfig::default()).unwrap();
        let info = Message::CameraInfo(camera.to_info(Stamp::new(1, 1_000)));
        assert!(
            view.on_message("camera/front/info", &info).is_empty(),
            "no frame yet: nothing to calibrate"
        );
        let out = view.on_message("camera/front/image", &frame(&camera, 1_000));
        let FoxMessage::CompressedImage(img) = &out[0].message else {
            panic!("{out:?}")
        };
        assert_eq!(
            (out[0].topic.as_str(), img.frame_id.as_str()),
            ("/camera/front/image", "camera_front_optical_frame")
        );
        let (h, _) = imaging::decode_jpeg(&img.data).unwrap();
        assert_eq!((h.width, h.height), (640, 360), "1280 px halved to fit 640");

        let out = view.on_message("camera/front/info", &info);
        let FoxMessage::CameraCalibration(c) = &out[0].message else {
            panic!("{out:?}")
        };
        assert_eq!((c.width, c.height), (640, 360));
        assert_eq!(
            c.k,
            vec![400.0, 0.0, 320.0, 0.0, 400.0, 180.0, 0.0, 0.0, 1.0]
        );

        let pose = Pose {
            stamp: Stamp::new(1, 1_000),
            position_m: [3.0, 4.0, 0.0],
            yaw_rad: 1.0,
            ..Default::default()
        };
        let out = view.on_message("state/pose", &Message::Pose(pose));
        let tf = out
            .iter()
            .find_map(|o| match &o.message {
                FoxMessage::FrameTransforms(t) => Some(t),
                _ => None,
            })
            .expect("transforms with the pose");
        let cam = tf
            .transforms
            .iter()
            .find(|t| t.child_frame_id == "camera_front_optical_frame")
            .unwrap();
        assert_eq!(cam.parent_frame_id, "base_link");
        let q = camera.mount.robot_from_optical.quaternion();
        let r = cam.rotation.unwrap();
        assert_eq!([r.x, r.y, r.z, r.w], [q.i, q.j, q.k, q.w]);
        let base = tf
            .transforms
            .iter()
            .find(|t| t.child_frame_id == "base_link")
            .unwrap();
        assert_eq!(base.translation.unwrap().x, 3.0);

        let bad = Pose {
            position_m: [f64::NAN, 0.0, 0.0],
            ..pose
        };
        assert!(view
            .on_message("state/pose", &Message::Pose(bad))
            .is_empty());
        assert_eq!(
            view.dropped().get("state/pose"),
            Some(&1),
            "a NaN pose is counted, not shown"
        );
    }

    #[test]
    fn a_goal_published_once_is_sent_again_with_the_pose_for_apps_that_connect_later() {
        let mut view = View::new(ViewConfig::default()).unwrap();
        let goal = NavGoal {
            stamp: Stamp::new(1, 1_000_000_000),
            x_m: 80.0,
            y_m: 50.0,
            ..Default::default()
        };
        let out = view.on_message("nav/goal", &Message::Goal(goal));
        assert_eq!(out.len(), 1, "{out:?}");
        let goals_with_pose = |view: &mut View, t_s: f64| {
            let pose = Pose {
                stamp: Stamp::new(1, (t_s * 1e9) as u64),
                ..Default::default()
            };
            view.on_message("state/pose", &Message::Pose(pose))
                .into_iter()
                .filter(|o| o.topic == "/nav/goal")
                .count()
        };
        // Pose at 10 Hz for 3 s: the goal again at its 1 Hz.
        let again: usize = (11..=40)
            .map(|i| goals_with_pose(&mut view, i as f64 / 10.0))
            .sum();
        assert_eq!(again, 3);
        let nan = NavGoal {
            x_m: f64::NAN,
            ..goal
        };
        assert!(view.on_message("nav/goal", &Message::Goal(nan)).is_empty());
        assert_eq!(view.dropped().get("nav/goal"), Some(&1));
    }

    #[test]
    fn costmap_rows_are_flipped_to_grow_north_and_lethal_cells_are_capped() {
        let h = CostmapHeader {
            width: 2,
            height: 2,
            resolution_m: 1.0,
            x_min_m: 10.0,
            y_max_m: 20.0,
            ..Default::default()
        };
        let cell = |c| CostCell {
            cost_s_per_m: c,
            variance: 0.0,
        };
        let c = Costmap {
            header: h,
            data: vec![cell(1.0), cell(2.0), cell(f32::INFINITY), cell(4.0)],
        };
        let FoxMessage::Grid(g) = costmap_grid(&c).unwrap() else {
            panic!()
        };
        let first = f32::from_le_bytes(g.data[0..4].try_into().unwrap());
        assert_eq!(
            first, DISPLAY_COST_CAP_S_PER_M,
            "the southern row (farsight row 1) comes first"
        );
        let p = g.pose.unwrap().position.unwrap();
        assert_eq!((p.x, p.y), (9.5, 18.5));
        let short = Costmap {
            header: h,
            data: vec![cell(1.0)],
        };
        assert!(costmap_grid(&short).unwrap_err().contains("2x2"));
    }

    /// A tree the simulator's renderer drew, projected through what the
    /// view publishes (`/tf`: map -> odom -> base_link -> the optical frame,
    /// and `/camera/front/calibration` for the image as sent), lands within
    /// 2 px of the tree's pixels in that image. A box's silhouette is
    /// bounded by its corners: the leftmost and rightmost tree columns are
    /// the corners' extreme azimuths, its lowest row the nearest corner on
    /// the ground.
    #[test]
    fn a_tree_the_renderer_drew_projects_through_the_transforms_and_calibration_onto_it() {
        use farsight_sim::render::{Frame, Renderer};
        use farsight_sim::world::{class, Cover, Obstacle, World};
        use nalgebra::{Quaternion, UnitQuaternion, Vector3};
        // A level pinhole camera, 1280 px sent at 640, offset on the robot
        // and turned a little, so every transform in the chain matters.
        let camera = Camera::new(
            4,
            "front",
            CameraModel::pinhole(1280, 720, 700.0, 700.0, 640.0, 360.0),
            Mount::from_xyz_rpy_deg([0.6, 0.3, 1.1], [0.0, 0.0, -8.0]),
        );
        let pose_xy_yaw = [13.0, 9.0, 0.4];
        let mut world = World::new(60, 60, Cover::Grass);
        let tree = (30_i64, 17_i64);
        world.set_obstacle(tree.0, tree.1, Obstacle::Tree);
        let mut frame = Frame::default();
        Renderer::new(&camera, 100.0).render(&world, pose_xy_yaw, &mut frame);
        // Where the renderer put the tree, in the image as sent (1280 -> 640:
        // pixel 2i goes out as pixel i).
        let (mut u_lo, mut u_hi, mut v_hi) = (usize::MAX, 0, 0);
        for v in 0..frame.height {
            for u in 0..frame.width {
                if frame.class_ids[v * frame.width + u] == class::TREE {
                    (u_lo, u_hi, v_hi) = (u_lo.min(u), u_hi.max(u), v_hi.max(v));
                }
            }
        }
        assert!(
            u_hi > u_lo + 20,
            "the tree is in view: columns {u_lo}..{u_hi}"
        );
        let drawn = [u_lo as f64 / 2.0, u_hi as f64 / 2.0, v_hi as f64 / 2.0];

        let mut view = View::new(ViewConfig::default()).unwrap();
        let t_ns = 5_000_000_000;
        let rgb = Message::Image(Image {
            header: ImageHeader::packed(
                Stamp::new(1, t_ns),
                camera.id,
                1280,
                720,
                PixelEncoding::RGB8,
            ),
            data: frame.rgb.clone(),
        });
        view.on_message(
            "camera/front/info",
            &Message::CameraInfo(camera.to_info(Stamp::new(1, t_ns))),
        );
        view.on_message("camera/front/image", &rgb);
        let calibration = view
            .on_message(
                "camera/front/info",
                &Message::CameraInfo(camera.to_info(Stamp::new(1, t_ns))),
            )
            .into_iter()
            .find_map(|o| match o.message {
                FoxMessage::CameraCalibration(c) => Some(c),
                _ => None,
            })
            .expect("calibration");
        let pose = Pose {
            stamp: Stamp::new(1, t_ns),
            position_m: [pose_xy_yaw[0], pose_xy_yaw[1], 0.0],
            yaw_rad: pose_xy_yaw[2],
            ..Default::default()
        };
        let transforms = view
            .on_message("state/pose", &Message::Pose(pose))
            .into_iter()
            .find_map(|o| match o.message {
                FoxMessage::FrameTransforms(t) => Some(t.transforms),
                _ => None,
            })
            .expect("transforms");
        // A point in `child` from one in `parent`, by the published
        // transform (the child frame's pose in its parent, as ROS's tf).
        let into_child = |parent: &str, child: &str, p: Vector3<f64>| {
            let t = transforms
                .iter()
                .find(|t| t.parent_frame_id == parent && t.child_frame_id == child)
                .unwrap_or_else(|| panic!("no transform {parent} -> {child}"));
            let (tr, r) = (t.translation.unwrap(), t.rotation.unwrap());
            let q = UnitQuaternion::from_quaternion(Quaternion::new(r.w, r.x, r.y, r.z));
            q.inverse() * (p - Vector3::new(tr.x, tr.y, tr.z))
        };
        let k = &calibration.k;
        assert_eq!(calibration.frame_id, "camera_front_optical_frame");
        assert_eq!((calibration.width, calibration.height), (640, 360));
        let pixel = |x_m: f64, y_m: f64| {
            let odom = into_child("map", "odom", Vector3::new(x_m, y_m, 0.0));
            let base = into_child("odom", "base_link", odom);
            let c = into_child("base_link", &calibration.frame_id, base);
            assert!(c.z > 0.0, "z forward: the tree is in front");
            [k[0] * c.x / c.z + k[2], k[4] * c.y / c.z + k[5]]
        };
        // The cell's ground corners (cells are centred on whole metres).
        let corners: Vec<[f64; 2]> = [(-0.5, -0.5), (-0.5, 0.5), (0.5, -0.5), (0.5, 0.5)]
            .iter()
            .map(|(dx, dy)| pixel(tree.0 as f64 + dx, tree.1 as f64 + dy))
            .collect();
        let projected = [
            corners.iter().map(|p| p[0]).fold(f64::INFINITY, f64::min),
            corners
                .iter()
                .map(|p| p[0])
                .fold(f64::NEG_INFINITY, f64::max),
            corners
                .iter()
                .map(|p| p[1])
                .fold(f64::NEG_INFINITY, f64::max),
        ];
        for (what, (d, p)) in ["left edge", "right edge", "foot"]
            .iter()
            .zip(drawn.iter().zip(projected))
        {
            assert!(
                (d - p).abs() <= 2.0,
                "{what}: drawn at {d} px, projects to {p:.2} px (all: drawn {drawn:?}, projected {projected:?})"
            );
        }
    }
}
