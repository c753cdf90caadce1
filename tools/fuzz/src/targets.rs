//! The fuzz targets: each takes any bytes and runs what farsight does with
//! such an input, returning `Ok` for an input it accepts and `Err` (the
//! error's text) for one it refuses. A panic anywhere is a failure; so is
//! an accepted input that breaks its own invariants (the `assert!`s here
//! are those invariants, checked on every accepted input).

use farsight_camera_ingest::ros_cdr;
use farsight_imaging::ImageLimits;
use farsight_interfaces::camera::Camera;
use farsight_interfaces::geo::GoalTracker;
use farsight_interfaces::msg::*;
use farsight_interfaces::topics::TopicKind;
use farsight_interfaces::transport::{any::wire_stamp, wire};
use farsight_stage::Validate;
use serde::de::DeserializeOwned;
use serde::Serialize;
use std::fmt::Display;
use std::time::Duration;

/// What a target says of one input: accepted, or refused with why.
pub type Verdict = Result<(), String>;

fn text<E: Display>(e: E) -> String {
    e.to_string()
}

/// The image target's size limit: small, so a header that declares a big
/// image is refused quickly, and a small one decoded fully.
pub const IMAGE_LIMITS: ImageLimits = ImageLimits {
    max_width: 1024,
    max_height: 1024,
};

/// A decoded image must fit its own header; then what the stages do next
/// (colour conversion, downsampling) must work on it.
fn check_decoded(h: &ImageHeader, px: &[u8]) {
    h.validate(px.len()).unwrap_or_else(|e| {
        panic!("a decoder returned an image that does not fit its header: {e}")
    });
    if h.encoding == PixelEncoding::YUYV {
        let (rgb, d) = farsight_imaging::yuyv_to_rgb(h, px)
            .unwrap_or_else(|e| panic!("yuyv_to_rgb refused a valid YUYV image: {e}"));
        rgb.validate(d.len()).expect("yuyv_to_rgb's output fits");
    } else if h.encoding != PixelEncoding::F32 {
        let (small, d) = farsight_imaging::downsample(h, px, 2)
            .unwrap_or_else(|e| panic!("downsample refused a valid {} image: {e}", h.encoding));
        small.validate(d.len()).expect("downsample's output fits");
    }
}

/// The same PNG with every chunk's CRC made right, so mutations inside a
/// chunk reach the decoder instead of ending at the CRC check.
pub fn png_with_right_crcs(bytes: &[u8]) -> Vec<u8> {
    let mut out = bytes.to_vec();
    let mut pos = 8;
    while pos + 12 <= out.len() {
        let len = u32::from_be_bytes(out[pos..pos + 4].try_into().expect("4 bytes")) as usize;
        let Some(end) = (pos + 8).checked_add(len).filter(|e| e + 4 <= out.len()) else {
            break;
        };
        let crc = crc32fast::hash(&out[pos + 4..end]);
        out[end..end + 4].copy_from_slice(&crc.to_be_bytes());
        pos = end + 4;
    }
    out
}

/// PNG or JPEG bytes, as a folder source, a snapshot or a compressed frame
/// brings them (a PNG also with its CRCs made right).
pub fn image(bytes: &[u8]) -> Verdict {
    let verdict = decode_image(bytes);
    if bytes.starts_with(b"\x89PNG") {
        let fixed = png_with_right_crcs(bytes);
        if fixed != bytes {
            let again = decode_image(&fixed);
            if let (Err(a), Err(b)) = (&verdict, again) {
                return Err(format!("{a}; with right CRCs: {b}"));
            }
        }
    }
    verdict
}

fn decode_image(bytes: &[u8]) -> Verdict {
    let (h, px) = farsight_imaging::decode_image_within(bytes, IMAGE_LIMITS).map_err(text)?;
    assert!(
        h.width <= IMAGE_LIMITS.max_width && h.height <= IMAGE_LIMITS.max_height,
        "decoded a {}x{} image past the limits",
        h.width,
        h.height
    );
    check_decoded(&h, &px);
    Ok(())
}

/// A ROS 2 `sensor_msgs/msg/Image` or `CompressedImage` in CDR, as
/// camera-ingest's `mcap` source decodes it (both decoders on every input).
pub fn ros_cdr(bytes: &[u8]) -> Verdict {
    let raw = ros_cdr::decode_image(bytes).map_err(text);
    let compressed = ros_cdr::decode_compressed(bytes).map_err(|e| format!("{e:#}"));
    for (h, px) in raw.iter().chain(compressed.iter()) {
        check_decoded(h, px);
    }
    match (raw, compressed) {
        (Ok(_), _) | (_, Ok(_)) => Ok(()),
        (Err(a), Err(b)) => Err(format!("image: {a}; compressed: {b}")),
    }
}

/// A ROS `camera_info` YAML (`camera.calibration` in camera-ingest).
pub fn ros_camera_info(bytes: &[u8]) -> Verdict {
    let text = String::from_utf8_lossy(bytes);
    let model = farsight_interfaces::camera::parse_ros_camera_info(&text)?;
    let cam = Camera::new(
        0,
        "fuzz",
        model,
        farsight_interfaces::camera::Mount::from_xyz_rpy_deg([0.0, 0.0, 1.0], [0.0; 3]),
    );
    let (w, h) = (cam.model.width as f64, cam.model.height as f64);
    for (u, v) in [(0.0, 0.0), (w / 2.0, h / 2.0), (w, h)] {
        let _ = cam.pixel_bearing_rad(u, v);
        let ray = cam.model.unproject(u, v);
        let _ = cam.model.project(&ray);
    }
    let info = cam.to_info(Stamp::default());
    Camera::from_info(&info)
        .map_err(|e| format!("a parsed camera_info does not survive its own message: {e}"))?;
    Ok(())
}

/// Every topic kind, each with a topic name of that kind. The match in
/// [`wire_target`] is exhaustive: a new kind does not compile until it has
/// a target; list it here too.
pub const KINDS: [(TopicKind, &str); 13] = [
    (TopicKind::Image, "camera/front/image"),
    (TopicKind::CameraInfo, "camera/front/info"),
    (TopicKind::Tensor, "perception/front/far_field"),
    (TopicKind::AngularBins, "bins/angular"),
    (TopicKind::PolarBins, "bins/polar"),
    (TopicKind::Costmap, "costmap/fused"),
    (TopicKind::Subgoal, "nav/subgoal"),
    (TopicKind::Path, "nav/path/visual"),
    (TopicKind::Goal, "nav/goal"),
    (TopicKind::Pose, "state/pose"),
    (TopicKind::VelocityCommand, "cmd/vel"),
    (TopicKind::EStop, "safety/estop"),
    (TopicKind::Health, "health/fuzz"),
];

/// The target name and function of a topic kind's wire messages.
pub fn wire_target(kind: TopicKind) -> (&'static str, fn(&[u8]) -> Verdict) {
    match kind {
        TopicKind::Image => ("wire_image", wire_image),
        TopicKind::CameraInfo => ("wire_camera_info", wire_camera_info),
        TopicKind::Tensor => ("wire_tensor", wire_tensor),
        TopicKind::AngularBins => ("wire_angular_bins", wire_angular_bins),
        TopicKind::PolarBins => ("wire_polar_bins", wire_polar_bins),
        TopicKind::Costmap => ("wire_costmap", wire_costmap),
        TopicKind::Subgoal => ("wire_subgoal", wire_subgoal),
        TopicKind::Path => ("wire_path", wire_path),
        TopicKind::Goal => ("wire_goal", wire_goal),
        TopicKind::Pose => ("wire_pose", wire_pose),
        TopicKind::VelocityCommand => ("wire_velocity_command", wire_velocity_command),
        TopicKind::EStop => ("wire_estop", wire_estop),
        TopicKind::Health => ("wire_health", wire_health),
    }
}

fn topic_of(kind: TopicKind) -> &'static str {
    KINDS
        .iter()
        .find(|(k, _)| *k == kind)
        .map(|(_, t)| *t)
        .expect("every kind is in KINDS")
}

/// What every consumer of a wire message of `kind` runs first, whatever
/// the kind: the stamp read by the bridge and recorder, and the decoding
/// `farsight diff` does (which must agree with the typed decoding).
fn common(kind: TopicKind, bytes: &[u8], decoded: bool) {
    let topic = topic_of(kind);
    let stamp = wire_stamp(topic, bytes);
    let diff = farsight_recording::diff::decode(topic, bytes);
    if decoded {
        assert!(stamp.is_ok(), "wire_stamp refused a message that decodes");
        assert!(diff.is_ok(), "diff::decode refused a message that decodes");
    }
}

/// A fixed-size message: decoded, re-encoded and decoded again, which must
/// give the same bytes.
fn fixed<M: DeserializeOwned + Serialize>(kind: TopicKind, bytes: &[u8]) -> Result<M, String> {
    let m = wire::decode_message::<M>(bytes).map_err(text);
    common(kind, bytes, m.is_ok());
    let m = m?;
    let again = wire::encode_message(&m).expect("a decoded message encodes");
    let m2: M = wire::decode_message(&again).expect("a re-encoded message decodes");
    assert_eq!(
        wire::encode_message(&m2).expect("encodes"),
        again,
        "re-encoding is not stable"
    );
    Ok(m)
}

pub fn wire_image(bytes: &[u8]) -> Verdict {
    let parsed = wire::split_slice::<ImageHeader>(bytes).map_err(text);
    common(TopicKind::Image, bytes, parsed.is_ok());
    let (h, px) = parsed?;
    // What a stage does with a received frame: raw frames are checked
    // against their header, compressed ones decoded (as camera-ingest's
    // mcap source and the consumers of a bridged frame do).
    let (h, px) = farsight_imaging::decode_frame(h, px).map_err(text)?;
    check_decoded(&h, &px);
    Ok(())
}

pub fn wire_camera_info(bytes: &[u8]) -> Verdict {
    let info: CameraInfo = fixed(TopicKind::CameraInfo, bytes)?;
    // What bin-projection, subgoal-selection and costmap-fusion do with it.
    let cam = Camera::from_info(&info).map_err(text)?;
    let (w, h) = (info.width as f64, info.height as f64);
    for (u, v) in [(0.0, 0.0), (w / 2.0, h / 2.0), (w, h)] {
        let _ = cam.pixel_bearing_rad(u, v);
    }
    Ok(())
}

pub fn wire_tensor(bytes: &[u8]) -> Verdict {
    let parsed = wire::decode_slice::<TensorHeader, f32>(bytes).map_err(text);
    common(TopicKind::Tensor, bytes, parsed.is_ok());
    let (h, data) = parsed?;
    // bin-projection's check of a far-field tensor.
    let shape = h.shape();
    if shape.len() != 4 || h.element_count() != data.len() {
        return Err(format!(
            "tensor of shape {shape:?} with {} values",
            data.len()
        ));
    }
    Ok(())
}

pub fn wire_angular_bins(bytes: &[u8]) -> Verdict {
    let b: AngularBins = fixed(TopicKind::AngularBins, bytes)?;
    assert!(b.scores.len() <= MAX_ANGULAR_BINS && b.observed.len() <= MAX_ANGULAR_BINS);
    Ok(())
}

pub fn wire_polar_bins(bytes: &[u8]) -> Verdict {
    let parsed = wire::decode_slice::<PolarBinsHeader, PolarCell>(bytes).map_err(text);
    common(TopicKind::PolarBins, bytes, parsed.is_ok());
    let (h, cells) = parsed?;
    // costmap-fusion's check of received bins.
    let g = farsight_costmap_fusion::swath::PolarGeometry::from_header(&h)?;
    let want = g.heading_bins * g.radial_bins();
    if cells.len() != want {
        return Err(format!("{} cells, {want} wanted", cells.len()));
    }
    for bearing in [-4.0, -1.0, 0.0, 0.5, 3.2, 7.0] {
        if let Some(k) = g.heading_bin(bearing) {
            assert!(k < g.heading_bins);
        }
    }
    Ok(())
}

pub fn wire_costmap(bytes: &[u8]) -> Verdict {
    let parsed = wire::decode_slice::<CostmapHeader, CostCell>(bytes).map_err(text);
    common(TopicKind::Costmap, bytes, parsed.is_ok());
    let (h, cells) = parsed?;
    h.validate(cells.len())?;
    for k in [0, cells.len().saturating_sub(1)] {
        let [x, y] = h.cell_centre_m(k);
        if let Some(i) = h.cell_index(x, y) {
            assert!(i < cells.len(), "cell_index {i} past {} cells", cells.len());
        }
    }
    Ok(())
}

pub fn wire_subgoal(bytes: &[u8]) -> Verdict {
    let _: Subgoal = fixed(TopicKind::Subgoal, bytes)?;
    Ok(())
}

pub fn wire_path(bytes: &[u8]) -> Verdict {
    let p: Path = fixed(TopicKind::Path, bytes)?;
    assert!(p.points.len() <= MAX_PATH_POINTS);
    Ok(())
}

/// A pose with a valid GPS fix, for the goal and pose targets.
fn fixed_pose() -> Pose {
    Pose {
        position_m: [3.0, 4.0, 0.0],
        yaw_rad: 0.3,
        gps: GpsFix {
            latitude_deg: 40.44,
            longitude_deg: -79.99,
            altitude_m: 300.0,
            valid: 1,
        },
        ..Default::default()
    }
}

pub fn wire_goal(bytes: &[u8]) -> Verdict {
    let goal: NavGoal = fixed(TopicKind::Goal, bytes)?;
    // What subgoal-selection and velocity-servoing do with a goal.
    let mut t = GoalTracker::default();
    t.set_pose(fixed_pose());
    t.set_goal(goal);
    let _ = t.goal_in_robot_frame();
    Ok(())
}

pub fn wire_pose(bytes: &[u8]) -> Verdict {
    let pose: Pose = fixed(TopicKind::Pose, bytes)?;
    let mut t = GoalTracker::default();
    t.set_pose(fixed_pose());
    t.set_pose(pose);
    t.set_goal(NavGoal {
        kind: GoalKind::GPS,
        latitude_deg: 40.45,
        longitude_deg: -79.98,
        ..Default::default()
    });
    let _ = t.goal_in_robot_frame();
    let _ = pose.to_robot_frame(pose.to_world_frame([1.0, 2.0]));
    Ok(())
}

pub fn wire_velocity_command(bytes: &[u8]) -> Verdict {
    let _: VelocityCommand = fixed(TopicKind::VelocityCommand, bytes)?;
    Ok(())
}

pub fn wire_estop(bytes: &[u8]) -> Verdict {
    let e: EStop = fixed(TopicKind::EStop, bytes)?;
    let _ = e.source.as_str();
    Ok(())
}

pub fn wire_health(bytes: &[u8]) -> Verdict {
    let h: StageHealth = fixed(TopicKind::Health, bytes)?;
    let _ = (h.stage.as_str(), h.reason.as_str(), h.state.name());
    Ok(())
}

// ---------------------------------------------------------------- configs

/// TOML text parsed as a stage parses its file at start. An accepted
/// config must also be accepted again after a round trip through TOML.
fn config<T: DeserializeOwned + Serialize + Validate>(bytes: &[u8]) -> Result<T, String> {
    let text = String::from_utf8_lossy(bytes);
    let c: T = farsight_stage::parse_config(&text, "fuzz").map_err(text_of)?;
    let again =
        toml::to_string(&c).map_err(|e| format!("an accepted config does not serialise: {e}"));
    if let Ok(again) = again {
        if let Err(e) = farsight_stage::parse_config::<T>(&again, "fuzz round trip") {
            panic!("an accepted config is refused after a round trip through TOML: {e}\n{again}");
        }
    }
    Ok(c)
}

fn text_of(e: farsight_stage::ConfigError) -> String {
    e.to_string()
}

/// `1 / rate` as the period a stage waits (`Duration::from_secs_f64`
/// panics on a period it cannot hold).
fn period_of(rate_hz: f64) {
    let _ = Duration::from_secs_f64(1.0 / rate_hz);
}

pub fn config_camera_ingest(bytes: &[u8]) -> Verdict {
    let c: farsight_camera_ingest::IngestConfig = config(bytes)?;
    for (i, cam) in c.cameras.iter().enumerate() {
        cam.model
            .build(i as u32, std::path::Path::new("."))
            .map_err(text)?;
        period_of(cam.rate_hz);
        let _ = Duration::from_secs_f64(cam.pace_timeout_s);
    }
    Ok(())
}

pub fn config_inference(bytes: &[u8]) -> Verdict {
    let _: farsight_inference::stage::InferenceConfig = config(bytes)?;
    Ok(())
}

pub fn config_model(bytes: &[u8]) -> Verdict {
    let c: farsight_inference::model_config::ModelConfig = config(bytes)?;
    let _ = (c.input_shape(), c.model_path(), c.class_table_path());
    Ok(())
}

pub fn config_class_table(bytes: &[u8]) -> Verdict {
    let c: farsight_inference::class_table::ClassTableConfig = config(bytes)?;
    let t = farsight_inference::class_table::ClassTable::new(&c);
    let ids: Vec<u8> = (0..=255).collect();
    assert_eq!(t.navigability(&ids).len(), 256);
    Ok(())
}

pub fn config_bin_projection(bytes: &[u8]) -> Verdict {
    let c: farsight_bin_projection::stage::BinProjectionConfig = config(bytes)?;
    if c.method == "fitam" {
        let radial = c.fitam.range_edges_m.len() - 1;
        let _ = c.fitam.heading_bins * radial;
    } else {
        let g = farsight_bin_projection::BinGeometry::from_width_deg(c.bins.bin_width_deg);
        let _ = g;
    }
    Ok(())
}

pub fn config_costmap_fusion(bytes: &[u8]) -> Verdict {
    let _: farsight_costmap_fusion::stage::FusionStageConfig = config(bytes)?;
    Ok(())
}

pub fn config_subgoal_selection(bytes: &[u8]) -> Verdict {
    let c: farsight_subgoal_selection::stage::SubgoalStageConfig = config(bytes)?;
    GoalTracker::anchored_at(c.anchor_latitude_deg, c.anchor_longitude_deg).map_err(text)?;
    Ok(())
}

pub fn config_hip_library(bytes: &[u8]) -> Verdict {
    let _: farsight_subgoal_selection::hip::LibraryFile = config(bytes)?;
    Ok(())
}

pub fn config_velocity_servoing(bytes: &[u8]) -> Verdict {
    let c: farsight_velocity_servoing::stage::ServoStageConfig = config(bytes)?;
    GoalTracker::anchored_at(c.anchor_latitude_deg, c.anchor_longitude_deg).map_err(text)?;
    period_of(c.output_rate_hz);
    Ok(())
}

pub fn config_command_mux(bytes: &[u8]) -> Verdict {
    let c: farsight_command_mux::MuxConfig = config(bytes)?;
    period_of(c.output_rate_hz);
    let _ = farsight_command_mux::CommandMux::new(c);
    Ok(())
}

pub fn config_bridge(bytes: &[u8]) -> Verdict {
    let c: farsight_bridge::BridgeConfig = config(bytes)?;
    period_of(c.import_poll_hz);
    Ok(())
}

// ------------------------------------------------------------------- MCAP

/// The file the MCAP target writes each input to (the readers take paths):
/// one per thread, in memory (`/dev/shm`) where there is one: rewriting a
/// file on ext4 flushes it to disk at every close.
fn scratch_path() -> std::path::PathBuf {
    use std::sync::atomic::{AtomicU64, Ordering};
    static NEXT: AtomicU64 = AtomicU64::new(0);
    thread_local! {
        static PATH: std::path::PathBuf = [std::path::Path::new("/dev/shm")]
            .into_iter()
            .find(|d| d.is_dir())
            .map_or_else(std::env::temp_dir, std::path::Path::to_path_buf)
            .join(format!(
            "farsight-fuzz-{}-{}.mcap",
            std::process::id(),
            NEXT.fetch_add(1, Ordering::Relaxed)
        ));
    }
    PATH.with(|p| p.clone())
}

/// The same bytes with every CRC a reader checks set to 0 (MCAP's "not
/// computed"): chunk CRCs, the data section's and the summary's. Mutations
/// inside a chunk then reach the record parsing instead of ending at the
/// CRC check.
pub fn without_crcs(bytes: &[u8]) -> Vec<u8> {
    use mcap::records::op;
    let mut out = bytes.to_vec();
    let mut pos = mcap::MAGIC.len();
    while pos + 9 <= out.len() {
        let opcode = out[pos];
        let len = u64::from_le_bytes(out[pos + 1..pos + 9].try_into().expect("8 bytes"));
        let body = pos + 9;
        let Some(end) = usize::try_from(len).ok().and_then(|l| body.checked_add(l)) else {
            break;
        };
        if end > out.len() {
            break;
        }
        let crc_at = match opcode {
            op::CHUNK => Some(body + 24),
            op::DATA_END => Some(body),
            op::FOOTER => Some(body + 16),
            _ => None,
        };
        if let Some(at) = crc_at.filter(|at| at + 4 <= end) {
            out[at..at + 4].fill(0);
        }
        pos = end;
    }
    out
}

/// Reads the file at `path` as every reader of farsight does: `farsight
/// record --info` (the summary), replay (every message; farsight's own are
/// validated as their topic's kind) and camera-ingest's `mcap` source
/// (channels, then every frame of up to 8 of them, decoded).
fn read_mcap(path: &std::path::Path) -> Verdict {
    use farsight_recording::read::Recording;
    let rec = Recording::open(path).map_err(text)?;
    let info = rec.info().map_err(text)?;
    let _ = info.to_string();
    rec.for_each(|m| {
        if &*m.encoding == farsight_recording::MESSAGE_ENCODING {
            if let Some(kind) = farsight_interfaces::topics::kind_of(&m.topic) {
                let _ = (wire_target(kind).1)(&m.data);
            }
        }
        Ok(())
    })
    .map_err(text)?;
    let src = farsight_camera_ingest::mcap_source::McapFile::open(path)?;
    let contents = src.contents()?;
    for (topic, _, _) in contents.channels.iter().take(8) {
        src.for_each_frame(topic, |f| {
            if let Ok((h, px)) = &f.image {
                check_decoded(h, px);
            }
            true
        })?;
    }
    Ok(())
}

/// An MCAP file: read as it is, and again with its CRCs cleared.
pub fn mcap(bytes: &[u8]) -> Verdict {
    let path = scratch_path();
    let mut verdict = Ok(());
    for (k, input) in [bytes.to_vec(), without_crcs(bytes)].iter().enumerate() {
        if k == 1 && input == bytes {
            break;
        }
        std::fs::write(&path, input).map_err(|e| format!("{}: {e}", path.display()))?;
        let v = read_mcap(&path);
        if k == 0 {
            verdict = v;
        } else if let (Err(a), Err(b)) = (&verdict, v) {
            verdict = Err(format!("{a}; without CRCs: {b}"));
        }
    }
    let _ = std::fs::remove_file(&path);
    verdict
}
