//! The seed corpora: small valid samples of every input, made with the
//! project's own encoders and writers (`farsight-fuzz --write-seeds`
//! writes them to `tests/fixtures/fuzz/<target>/`). Files named `bad-*`
//! are known-bad inputs kept as seeds (the hand-made bad images); every
//! other seed must be accepted by its target.

use farsight_interfaces::camera::{Camera, CameraModel, Mount};
use farsight_interfaces::fixed::{FixedStr, FixedVec};
use farsight_interfaces::msg::*;
use farsight_interfaces::transport::wire;
use serde::Serialize;
use std::path::Path as FsPath;

/// A seed: its file name and bytes.
pub type Seed = (String, Vec<u8>);

fn stamp() -> Stamp {
    Stamp::new(42, 1_700_000_000_123_456_789)
}

/// A small test picture: a gradient with some structure, so the encoders
/// make real entropy-coded data.
fn pixels(w: usize, h: usize, channels: usize) -> Vec<u8> {
    let mut out = Vec::with_capacity(w * h * channels);
    for y in 0..h {
        for x in 0..w {
            for c in 0..channels {
                out.push(((x * 37 + y * 23 + c * 71) ^ (x * y)) as u8);
            }
        }
    }
    out
}

fn png_with(w: u32, h: u32, color: png::ColorType, data: &[u8], palette: Option<&[u8]>) -> Vec<u8> {
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, w, h);
        enc.set_color(color);
        enc.set_depth(png::BitDepth::Eight);
        if let Some(p) = palette {
            enc.set_palette(p.to_vec());
        }
        let mut wr = enc.write_header().expect("png header");
        wr.write_image_data(data).expect("png data");
    }
    out
}

fn packed(w: u32, h: u32, enc: PixelEncoding) -> ImageHeader {
    ImageHeader::packed(Stamp::default(), 0, w, h, enc)
}

/// PNGs (grey, RGB, 16-bit grey with the project's encoder; RGBA and
/// palette with the png crate) and JPEGs (RGB, grey, an odd size).
fn images() -> Vec<Seed> {
    let e = |h: &ImageHeader, d: &[u8]| farsight_imaging::encode_png(h, d).expect("png");
    let j = |h: &ImageHeader, d: &[u8], q| farsight_imaging::encode_jpeg(h, d, q).expect("jpeg");
    let mut out = vec![
        (
            "gray-8x6.png".into(),
            e(&packed(8, 6, PixelEncoding::MONO8), &pixels(8, 6, 1)),
        ),
        (
            "rgb-8x6.png".into(),
            e(&packed(8, 6, PixelEncoding::RGB8), &pixels(8, 6, 3)),
        ),
        (
            "mono16-8x6.png".into(),
            e(&packed(8, 6, PixelEncoding::MONO16), &pixels(8, 6, 2)),
        ),
        (
            "rgba-5x4.png".into(),
            png_with(5, 4, png::ColorType::Rgba, &pixels(5, 4, 4), None),
        ),
        (
            "palette-6x3.png".into(),
            png_with(
                6,
                3,
                png::ColorType::Indexed,
                &pixels(6, 3, 1).iter().map(|p| p % 4).collect::<Vec<_>>(),
                Some(&[0, 0, 0, 255, 0, 0, 0, 255, 0, 0, 0, 255]),
            ),
        ),
        (
            "rgb-16x16-q90.jpg".into(),
            j(&packed(16, 16, PixelEncoding::RGB8), &pixels(16, 16, 3), 90),
        ),
        (
            "gray-16x8-q75.jpg".into(),
            j(&packed(16, 8, PixelEncoding::MONO8), &pixels(16, 8, 1), 75),
        ),
        (
            "rgb-9x7-q50.jpg".into(),
            j(&packed(9, 7, PixelEncoding::RGB8), &pixels(9, 7, 3), 50),
        ),
    ];
    // The good images the bad-images corpus was made from, and the
    // hand-made bad images (refused from their headers).
    let bad = crate::workspace_root().join("tests/fixtures/bad-images");
    for name in ["good-32x24.png", "good-32x24.jpg"] {
        if let Ok(bytes) = std::fs::read(bad.join(name)) {
            out.push((name.to_string(), bytes));
        }
    }
    for name in [
        "bomb-100000x100000.png",
        "large-16000x16000.png",
        "empty.png",
        "text.jpg",
    ] {
        let bytes = std::fs::read(bad.join(name)).unwrap_or_default();
        out.push((format!("bad-{name}"), bytes));
    }
    out
}

/// CDR as rosbag2 writes it: little-endian, fields aligned to their size
/// from the end of the 4-byte encapsulation header (the fuzz seeds and
/// camera-ingest's tests build ROS 2 messages with it).
#[derive(Default)]
pub struct Cdr(Vec<u8>);

impl Cdr {
    pub fn new() -> Self {
        Self(Vec::new())
    }
    pub fn u32(&mut self, v: u32) -> &mut Self {
        while !self.0.len().is_multiple_of(4) {
            self.0.push(0);
        }
        self.0.extend(v.to_le_bytes());
        self
    }
    pub fn u8(&mut self, v: u8) -> &mut Self {
        self.0.push(v);
        self
    }
    pub fn string(&mut self, s: &str) -> &mut Self {
        self.u32(s.len() as u32 + 1);
        self.0.extend(s.as_bytes());
        self.0.push(0);
        self
    }
    pub fn bytes(&mut self, b: &[u8]) -> &mut Self {
        self.u32(b.len() as u32);
        self.0.extend(b);
        self
    }
    pub fn finish(&self) -> Vec<u8> {
        let mut out = vec![0, 1, 0, 0];
        out.extend(&self.0);
        out
    }
}

/// A CDR `sensor_msgs/msg/Image`.
pub fn ros_image(w: u32, h: u32, encoding: &str, step: u32, data: &[u8]) -> Vec<u8> {
    let mut c = Cdr::new();
    c.u32(1_700_000_000)
        .u32(250_000_000)
        .string("front_optical")
        .u32(h)
        .u32(w)
        .string(encoding)
        .u8(0)
        .u32(step)
        .bytes(data);
    c.finish()
}

/// A CDR `sensor_msgs/msg/CompressedImage`.
pub fn ros_compressed(format: &str, data: &[u8]) -> Vec<u8> {
    let mut c = Cdr::new();
    c.u32(1_700_000_001)
        .u32(0)
        .string("rear_optical")
        .string(format)
        .bytes(data);
    c.finish()
}

fn ros_cdr() -> Vec<Seed> {
    let img = |name: &str, w: u32, h: u32, enc: &str, bpp: u32, pad: u32| {
        let step = w * bpp + pad;
        (
            format!("image-{name}.cdr"),
            ros_image(w, h, enc, step, &pixels(step as usize, h as usize, 1)),
        )
    };
    let jpeg =
        farsight_imaging::encode_jpeg(&packed(8, 8, PixelEncoding::RGB8), &pixels(8, 8, 3), 80)
            .expect("jpeg");
    let png = farsight_imaging::encode_png(&packed(6, 4, PixelEncoding::MONO8), &pixels(6, 4, 1))
        .expect("png");
    vec![
        img("rgb8-4x3", 4, 3, "rgb8", 3, 0),
        img("bgr8-3x2-padded", 3, 2, "bgr8", 3, 3),
        img("rgba8-2x2", 2, 2, "rgba8", 4, 0),
        img("mono8-5x3", 5, 3, "mono8", 1, 0),
        img("mono16-4x2", 4, 2, "mono16", 2, 0),
        img("16uc1-3x3", 3, 3, "16UC1", 2, 2),
        img("yuyv-4x2", 4, 2, "yuv422_yuy2", 2, 0),
        ("compressed-jpeg.cdr".into(), ros_compressed("jpeg", &jpeg)),
        ("compressed-png.cdr".into(), ros_compressed("png", &png)),
    ]
}

fn ros_camera_info() -> Vec<Seed> {
    let plumb = "image_width: 640\nimage_height: 480\ncamera_name: front\ncamera_matrix:\n  rows: 3\n  cols: 3\n  data: [500.5, 0.0, 320.0, 0.0, 498.25, 240.0, 0.0, 0.0, 1.0]\ndistortion_model: plumb_bob\ndistortion_coefficients:\n  rows: 1\n  cols: 5\n  data: [-0.12, 0.034, 0.001, -0.002, 0.0]\nrectification_matrix:\n  rows: 3\n  cols: 3\n  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]\n";
    let fisheye = "image_width: 1280\nimage_height: 720\ncamera_matrix:\n  data: [400, 0, 640, 0, 400, 360, 0, 0, 1]\ndistortion_model: equidistant\ndistortion_coefficients:\n  data: [0.05, -0.01, 0.002, -0.0003]\n";
    let bare = "image_width: 320\nimage_height: 240\ncamera_matrix: {data: [250, 0, 160, 0, 250, 120, 0, 0, 1]}\n";
    vec![
        ("plumb-bob.yaml".into(), plumb.into()),
        ("equidistant.yaml".into(), fisheye.into()),
        ("no-distortion.yaml".into(), bare.into()),
    ]
}

/// One representative message of every topic kind, wire-encoded, with the
/// topic it goes on.
pub fn wire_messages() -> Vec<(&'static str, &'static str, Vec<u8>)> {
    let s = stamp();
    let fixed = |m: &dyn erased::Encode| m.encode();
    let rgb = ImageHeader::packed(s, 0, 4, 3, PixelEncoding::RGB8);
    let mono16 = ImageHeader {
        stride_bytes: 10,
        ..ImageHeader::packed(s, 1, 4, 2, PixelEncoding::MONO16)
    };
    let yuyv = ImageHeader::packed(s, 0, 4, 2, PixelEncoding::YUYV);
    let f32img = ImageHeader::packed(s, 0, 2, 2, PixelEncoding::F32);
    let png = farsight_imaging::encode_png(&packed(5, 3, PixelEncoding::RGB8), &pixels(5, 3, 3))
        .expect("png");
    let png_frame = ImageHeader {
        stride_bytes: 0,
        encoding: PixelEncoding::PNG,
        ..ImageHeader::packed(s, 0, 5, 3, PixelEncoding::RGB8)
    };
    let jpeg =
        farsight_imaging::encode_jpeg(&packed(8, 8, PixelEncoding::RGB8), &pixels(8, 8, 3), 85)
            .expect("jpeg");
    let jpeg_frame = ImageHeader {
        stride_bytes: 0,
        encoding: PixelEncoding::JPEG,
        ..ImageHeader::packed(s, 0, 8, 8, PixelEncoding::RGB8)
    };
    let slice = |h: &dyn erased::Encode, d: &[u8]| h.encode_slice(d);

    let cam = Camera::new(
        0,
        "front",
        CameraModel::pinhole(640, 480, 500.0, 500.0, 320.0, 240.0),
        Mount::from_xyz_rpy_deg([0.2, 0.0, 1.2], [0.0, 5.0, 0.0]),
    );
    let pinhole = cam.to_info(s);
    let fisheye = CameraInfo {
        lens: LensModel::FISHEYE,
        distortion: [0.05, -0.01, 0.002, -0.0003, 0.0],
        ..pinhole
    };
    let tensor = TensorHeader::new(s, 0, &[2, 3, 2, 3]);
    let tensor_data: Vec<f32> = (0..36).map(|k| k as f32 * 0.25 - 3.0).collect();
    let polar = PolarBinsHeader {
        stamp: s,
        heading_bins: 4,
        first_heading_start_rad: -std::f32::consts::PI,
        heading_width_rad: std::f32::consts::FRAC_PI_2,
        range_edges_m: FixedVec::from_slice(&[5.0, 10.0, 20.0, 40.0]).expect("edges"),
    };
    let polar_cells: Vec<PolarCell> = (0..12)
        .map(|k| {
            if k == 5 {
                PolarCell::NO_MEASUREMENT
            } else {
                PolarCell {
                    cost_s_per_m: 1.0 + k as f32,
                    variance: 0.5,
                    class_id: k % 3,
                    probability: 0.75,
                }
            }
        })
        .collect();
    let costmap = CostmapHeader {
        stamp: s,
        layer: CostmapLayer::FUSED,
        width: 3,
        height: 2,
        resolution_m: 0.5,
        x_min_m: -1.0,
        y_max_m: 2.0,
    };
    let cells: Vec<CostCell> = (0..6)
        .map(|k| CostCell {
            cost_s_per_m: if k == 4 {
                f32::INFINITY
            } else {
                k as f32 * 0.5
            },
            variance: 0.1,
        })
        .collect();
    let angular = AngularBins {
        stamp: s,
        first_bin_start_rad: -0.8,
        bin_width_rad: 0.2,
        scores: FixedVec::from_slice(&[0.1, 0.5, 0.9, 0.3, 0.0, 1.0, 0.2, 0.4]).expect("8"),
        observed: FixedVec::from_slice(&[1, 1, 1, 1, 0, 1, 1, 1]).expect("8"),
    };
    let subgoal = Subgoal {
        stamp: s,
        source: SubgoalSource::POVNAV,
        mode: ServoMode::SAFE,
        heading_rad: 0.2,
        x_m: 4.0,
        y_m: 0.8,
        image_u_px: 320.0,
        image_v_px: 400.0,
        proximity_lambda_px: 12.0,
        alignment_phi_rad: 0.1,
    };
    let path = Path {
        stamp: s,
        frame: PathFrame::WORLD,
        camera_id: 0,
        points: FixedVec::from_slice(&[[0.0, 0.0], [1.0, 0.5], [2.0, 1.5]]).expect("3"),
    };
    let gps_goal = NavGoal {
        stamp: s,
        kind: GoalKind::GPS,
        latitude_deg: 40.4416,
        longitude_deg: -79.9959,
        tolerance_m: 2.0,
        ..Default::default()
    };
    let local_goal = NavGoal {
        stamp: s,
        kind: GoalKind::LOCAL,
        x_m: 60.0,
        y_m: -4.0,
        tolerance_m: 1.5,
        ..Default::default()
    };
    let pose = Pose {
        stamp: s,
        position_m: [1.5, -2.0, 0.1],
        yaw_rad: 0.7,
        covariance: [0.01, 0.0, 0.0, 0.0, 0.01, 0.0, 0.0, 0.0, 0.002],
        linear_mps: 0.8,
        angular_radps: 0.1,
        gps: GpsFix {
            latitude_deg: 40.44,
            longitude_deg: -79.99,
            altitude_m: 280.0,
            valid: 1,
        },
    };
    let cmd = VelocityCommand {
        stamp: s,
        linear_mps: 0.6,
        angular_radps: -0.2,
        reason: CommandReason::TRACKING,
        ttl_ms: 300,
    };
    let estop = EStop {
        stamp: s,
        active: EStop::PRESSED,
        source: FixedStr::new("operator").expect("fits"),
    };
    let health = StageHealth {
        stamp: s,
        stage: FixedStr::new("velocity-servoing").expect("fits"),
        state: HealthState::DEGRADED,
        pid: 4242,
        messages_in: 100,
        messages_out: 98,
        dropped: 1,
        skipped: 1,
        last_latency_ms: 12.5,
        reason: FixedStr::new("stale subgoal").expect("fits"),
    };
    let f32px: Vec<u8> = [0.25f32, -1.0, 3.5, 0.0]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    vec![
        ("wire_image", "rgb8", slice(&rgb, &pixels(4, 3, 3))),
        (
            "wire_image",
            "mono16-stride",
            slice(&mono16, &pixels(10, 2, 1)),
        ),
        ("wire_image", "yuyv", slice(&yuyv, &pixels(8, 2, 1))),
        ("wire_image", "f32", slice(&f32img, &f32px)),
        ("wire_image", "png", slice(&png_frame, &png)),
        ("wire_image", "jpeg", slice(&jpeg_frame, &jpeg)),
        ("wire_camera_info", "pinhole", fixed(&pinhole)),
        ("wire_camera_info", "fisheye", fixed(&fisheye)),
        (
            "wire_tensor",
            "2x3x2x3",
            wire::encode_slice(&tensor, &tensor_data).expect("encodes"),
        ),
        ("wire_angular_bins", "8-bins", fixed(&angular)),
        (
            "wire_polar_bins",
            "4x3",
            wire::encode_slice(&polar, &polar_cells).expect("encodes"),
        ),
        (
            "wire_costmap",
            "3x2",
            wire::encode_slice(&costmap, &cells).expect("encodes"),
        ),
        ("wire_subgoal", "povnav", fixed(&subgoal)),
        ("wire_path", "world", fixed(&path)),
        ("wire_goal", "gps", fixed(&gps_goal)),
        ("wire_goal", "local", fixed(&local_goal)),
        ("wire_pose", "gps", fixed(&pose)),
        ("wire_velocity_command", "tracking", fixed(&cmd)),
        ("wire_estop", "pressed", fixed(&estop)),
        ("wire_health", "degraded", fixed(&health)),
    ]
}

/// Encoding through a trait object, so one list holds every message type.
mod erased {
    use super::*;
    pub trait Encode {
        fn encode(&self) -> Vec<u8>;
        fn encode_slice(&self, data: &[u8]) -> Vec<u8>;
    }
    impl<T: Serialize> Encode for T {
        fn encode(&self) -> Vec<u8> {
            wire::encode_message(self).expect("encodes")
        }
        fn encode_slice(&self, data: &[u8]) -> Vec<u8> {
            wire::encode_slice(self, data).expect("encodes")
        }
    }
}

/// The topic a wire seed's target names.
fn topic_of(target: &str) -> &'static str {
    crate::targets::KINDS
        .iter()
        .find(|(k, _)| crate::targets::wire_target(*k).0 == target)
        .map(|(_, t)| *t)
        .expect("a wire target")
}

fn temp_file(name: &str) -> std::path::PathBuf {
    std::env::temp_dir().join(format!("farsight-fuzz-seed-{}-{name}", std::process::id()))
}

/// A farsight recording holding every wire seed (uncompressed), one with
/// Foxglove channels (zstd), and a ROS 2 bag with both image messages.
fn mcaps() -> Vec<Seed> {
    use farsight_recording::write::RecordingWriter;
    let mut out = Vec::new();
    for (name, zstd, foxglove) in [
        ("farsight-all-kinds.mcap", false, false),
        ("farsight-foxglove-zstd.mcap", true, true),
    ] {
        let path = temp_file(name);
        let mut w = RecordingWriter::create_with(&path, foxglove, zstd).expect("create");
        for (k, (target, _, bytes)) in wire_messages().into_iter().enumerate() {
            if foxglove
                && !matches!(
                    target,
                    "wire_image" | "wire_pose" | "wire_costmap" | "wire_path"
                )
            {
                continue;
            }
            let t = 1_000_000_000 + k as u64 * 50_000_000;
            w.write(topic_of(target), Stamp::new(k as u64, t), t, &bytes)
                .expect("write");
        }
        w.finish().expect("finish");
        out.push((name.to_string(), std::fs::read(&path).expect("read back")));
        let _ = std::fs::remove_file(&path);
    }
    // A ROS 2 bag, uncompressed.
    let mut bag = Vec::new();
    {
        let mut w = mcap::WriteOptions::new()
            .profile("ros2")
            .compression(None)
            .create(std::io::Cursor::new(&mut bag))
            .expect("mcap writer");
        let image = w
            .add_schema(
                "sensor_msgs/msg/Image",
                "ros2msg",
                b"std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\nuint32 step\nuint8[] data\n",
            )
            .expect("schema");
        let compressed = w
            .add_schema(
                "sensor_msgs/msg/CompressedImage",
                "ros2msg",
                b"std_msgs/Header header\nstring format\nuint8[] data\n",
            )
            .expect("schema");
        let meta = Default::default();
        let front = w
            .add_channel(image, "/front/image_raw", "cdr", &meta)
            .expect("channel");
        let rear = w
            .add_channel(compressed, "/rear/image_raw/compressed", "cdr", &meta)
            .expect("channel");
        let cdr = ros_cdr();
        for k in 0..2u32 {
            let t = 1_000_000_000 + k as u64 * 100_000_000;
            let header = |channel_id| mcap::records::MessageHeader {
                channel_id,
                sequence: k,
                log_time: t,
                publish_time: t,
            };
            w.write_to_known_channel(&header(front), &cdr[k as usize].1)
                .expect("write");
            w.write_to_known_channel(&header(rear), &cdr[7].1)
                .expect("write");
        }
        w.finish().expect("finish");
    }
    out.push(("ros2-bag.mcap".into(), bag));
    out
}

fn toml_of<T: Serialize>(v: &T) -> Vec<u8> {
    toml::to_string(v).expect("defaults serialise").into_bytes()
}

/// A shipped file, by its path in the repository.
fn shipped(path: &str) -> Seed {
    let bytes =
        std::fs::read(crate::workspace_root().join(path)).unwrap_or_else(|e| panic!("{path}: {e}"));
    (path.replace('/', "_"), bytes)
}

fn stage_config<T: Serialize + Default>(stage: &str) -> Vec<Seed> {
    vec![
        ("defaults.toml".into(), toml_of(&T::default())),
        shipped(&format!("deploy/config/{stage}.toml")),
    ]
}

/// Every target's seeds, by target name.
pub fn all() -> Vec<(&'static str, Vec<Seed>)> {
    let mut out: Vec<(&'static str, Vec<Seed>)> = vec![
        ("image", images()),
        ("ros_cdr", ros_cdr()),
        ("ros_camera_info", ros_camera_info()),
        ("mcap", mcaps()),
    ];
    for (kind, _) in crate::targets::KINDS {
        let target = crate::targets::wire_target(kind).0;
        let seeds = wire_messages()
            .into_iter()
            .filter(|(t, _, _)| *t == target)
            .map(|(_, name, bytes)| (format!("{name}.wire"), bytes))
            .collect();
        out.push((target, seeds));
    }
    let hip = farsight_subgoal_selection::hip::LibraryFile {
        step_s: 0.5,
        trajectories: vec![
            vec![[0.5, 0.0], [1.0, 0.0], [1.5, 0.0]],
            vec![[0.5, 0.1], [1.0, 0.3], [1.4, 0.6]],
            vec![[0.5, -0.1], [1.0, -0.3], [1.4, -0.6]],
        ],
    };
    out.extend([
        (
            "config_camera_ingest",
            stage_config::<farsight_camera_ingest::IngestConfig>("camera-ingest"),
        ),
        (
            "config_inference",
            stage_config::<farsight_inference::stage::InferenceConfig>("inference"),
        ),
        (
            "config_model",
            vec![
                shipped("deploy/models/twinlitenet.toml"),
                shipped("deploy/models/deeplabv3-voc.toml"),
                shipped("deploy/models/sim-fitam/model.toml"),
                shipped("deploy/models/sim-lrn/model.toml"),
                shipped("deploy/models/sim-hip/model.toml"),
            ],
        ),
        (
            "config_class_table",
            vec![
                shipped("deploy/models/twinlitenet-classes.toml"),
                shipped("deploy/models/voc-classes.toml"),
            ],
        ),
        (
            "config_bin_projection",
            stage_config::<farsight_bin_projection::stage::BinProjectionConfig>("bin-projection"),
        ),
        (
            "config_costmap_fusion",
            stage_config::<farsight_costmap_fusion::stage::FusionStageConfig>("costmap-fusion"),
        ),
        (
            "config_subgoal_selection",
            stage_config::<farsight_subgoal_selection::stage::SubgoalStageConfig>(
                "subgoal-selection",
            ),
        ),
        (
            "config_hip_library",
            vec![("three.toml".into(), toml_of(&hip))],
        ),
        (
            "config_velocity_servoing",
            stage_config::<farsight_velocity_servoing::stage::ServoStageConfig>(
                "velocity-servoing",
            ),
        ),
        (
            "config_command_mux",
            stage_config::<farsight_command_mux::MuxConfig>("command-mux"),
        ),
        (
            "config_bridge",
            stage_config::<farsight_bridge::BridgeConfig>("bridge"),
        ),
    ]);
    out
}

/// Writes every target's seeds under `dir/<target>/`, replacing the files
/// there. Returns each target's seed count.
pub fn write(dir: &FsPath) -> Result<Vec<(&'static str, usize)>, String> {
    let mut counts = Vec::new();
    for (target, seeds) in all() {
        let d = dir.join(target);
        if d.exists() {
            for e in std::fs::read_dir(&d).map_err(|e| format!("{}: {e}", d.display()))? {
                let p = e.map_err(|e| e.to_string())?.path();
                if p.is_file() {
                    std::fs::remove_file(&p).map_err(|e| format!("{}: {e}", p.display()))?;
                }
            }
        }
        std::fs::create_dir_all(&d).map_err(|e| format!("{}: {e}", d.display()))?;
        for (name, bytes) in &seeds {
            let p = d.join(name);
            std::fs::write(&p, bytes).map_err(|e| format!("{}: {e}", p.display()))?;
        }
        counts.push((target, seeds.len()));
    }
    Ok(counts)
}
