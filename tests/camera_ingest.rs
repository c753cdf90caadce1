//! camera-ingest as a real process: two cameras at once, each with its own
//! mount; broken files are counted and skipped while the stream goes on; a
//! missing V4L2 camera stops the stage at start-up with a message that says so.

use farsight_fuzz::seeds::Cdr;
use farsight_interfaces::camera::Camera;
use farsight_interfaces::msg::{ImageHeader, PixelEncoding, Stamp};
use farsight_interfaces::topics;
use farsight_tests::{repo_root, toml_string, Namespace};
use std::time::{Duration, Instant};

fn model(name: &str, w: u32, h: u32, yaw: f64) -> String {
    format!(
        "[cameras.model]\nname = \"{name}\"\nwidth = {w}\nheight = {h}\nfx = {f}\nfy = {f}\ncx = {cx}\ncy = {cy}\nrpy_deg = [0.0, 0.0, {yaw}]\n",
        f = w as f64 * 0.8,
        cx = w as f64 / 2.0,
        cy = h as f64 / 2.0
    )
}

#[test]
fn two_cameras_stream_and_broken_files_are_skipped() {
    let ns = Namespace::new("ingest2cam");
    // The rear camera's folder: good, truncated, wrong size, good (JPEG),
    // the bad corpus, good.
    let rear_dir = ns.root.join("rear");
    std::fs::create_dir_all(&rear_dir).unwrap();
    let h = ImageHeader::packed(Stamp::default(), 0, 64, 48, PixelEncoding::RGB8);
    let good = farsight_imaging::encode_png(&h, &vec![80u8; 64 * 48 * 3]).unwrap();
    std::fs::write(rear_dir.join("1000000000001.png"), &good).unwrap();
    std::fs::write(rear_dir.join("1000000000002.png"), &good[..good.len() / 2]).unwrap();
    let small = ImageHeader::packed(Stamp::default(), 0, 32, 48, PixelEncoding::RGB8);
    std::fs::write(
        rear_dir.join("1000000000003.png"),
        farsight_imaging::encode_png(&small, &vec![0u8; 32 * 48 * 3]).unwrap(),
    )
    .unwrap();
    let jpeg = farsight_imaging::encode_jpeg(&h, &vec![80u8; 64 * 48 * 3], 90).unwrap();
    std::fs::write(rear_dir.join("1000000000004.jpg"), &jpeg).unwrap();
    // Then the bad corpus: images declaring 100000x100000 and 16000x16000
    // (refused from the header, never allocated), empty, text, and JPEGs
    // cut short (which the decoder alone would grey-fill and return).
    let bad = repo_root().join("tests/fixtures/bad-images");
    for (k, name) in [
        "bomb-100000x100000.png",
        "large-16000x16000.png",
        "empty.png",
        "text.jpg",
    ]
    .iter()
    .enumerate()
    {
        std::fs::copy(
            bad.join(name),
            rear_dir.join(format!("100000000001{k}.png")),
        )
        .unwrap();
    }
    for (k, cut) in [jpeg.len() / 2, jpeg.len() - 2, 1000.min(jpeg.len() - 3)]
        .iter()
        .enumerate()
    {
        std::fs::write(rear_dir.join(format!("100000000002{k}.jpg")), &jpeg[..*cut]).unwrap();
    }
    std::fs::write(rear_dir.join("1000000000030.jpg"), &jpeg).unwrap();

    let orfd = repo_root().join("../shared/data/orfd/image_data");
    let cfg = ns.write(
        "camera-ingest.toml",
        &format!(
            "[[cameras]]\nfolder = {}\nrate_hz = 20.0\nloops = 1\n{}\n[[cameras]]\nfolder = \"rear\"\nrate_hz = 20.0\nloops = 1\n{}",
            toml_string(&orfd.display().to_string()),
            model("front", 1280, 720, 0.0),
            model("rear", 64, 48, 180.0)
        ),
    );
    let bus = ns.bus("ingest-test");
    let front = bus
        .slice_subscriber(&topics::camera_image("front"))
        .unwrap();
    let rear = bus.slice_subscriber(&topics::camera_image("rear")).unwrap();
    let rear_info = bus.subscriber(&topics::camera_info("rear")).unwrap();
    let health = bus.subscriber(&topics::health("camera-ingest")).unwrap();
    let mut stage = ns.start_stage("farsight-camera-ingest", "camera-ingest", &cfg);

    let (mut front_seqs, mut rear_caps) = (Vec::new(), Vec::new());
    let mut info = None;
    let mut last_health = None;
    let end = Instant::now() + Duration::from_secs(20);
    while Instant::now() < end
        && (front_seqs.len() < 6 || rear_caps.len() < 3 || last_health.is_none())
    {
        if let Some(f) = front.latest().unwrap() {
            f.header().validate(f.data().len()).unwrap();
            front_seqs.push(f.header().stamp.frame_seq);
        }
        if let Some(r) = rear.latest().unwrap() {
            assert_eq!((r.header().width, r.header().height), (64, 48));
            rear_caps.push(r.header().stamp.capture_time_ns);
        }
        if let Some(i) = rear_info.latest().unwrap() {
            info = Some(i);
        }
        if let Some(h) = health.latest().unwrap() {
            if h.state.name() == Some("stopping") {
                last_health = Some(h);
            }
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    assert_eq!(
        stage.wait_exit(Duration::from_secs(10)),
        Some(0),
        "{}",
        stage.stderr_so_far()
    );
    assert_eq!(
        front_seqs,
        vec![1, 2, 3, 4, 5, 6],
        "every ORFD frame, in order"
    );
    // The rear stream went on past the broken files: the JPEG after them arrived.
    assert_eq!(
        rear_caps,
        vec![
            1_000_000_000_001_000_000,
            1_000_000_000_004_000_000,
            1_000_000_000_030_000_000
        ],
        "{}",
        stage.stderr_so_far()
    );
    let h = last_health.expect("final health report");
    assert_eq!((h.messages_out, h.dropped), (9, 9), "{h:?}");
    let errors = stage.stderr_so_far();
    assert!(
        errors.contains("1000000000003.png: image is 32x48, the camera model says 64x48"),
        "{errors}"
    );
    for refused in [
        "1000000000010.png: a 100000x100000 image: larger than the 64x48 allowed",
        "1000000000011.png: a 16000x16000 image",
        "1000000000020.jpg: jpeg: truncated",
        "1000000000022.jpg: jpeg: truncated",
    ] {
        assert!(errors.contains(refused), "{refused}:\n{errors}");
    }
    // The rear camera's model travels with its frames: its centre looks backwards.
    let cam = Camera::from_info(&info.expect("rear camera info")).unwrap();
    let b = cam.pixel_bearing_rad(32.0, 24.0).unwrap();
    assert!((b.abs() - std::f64::consts::PI).abs() < 1e-9, "{b}");
}

/// The committed corpus (`tests/fixtures/bad-images`: 200 mutated PNGs and
/// JPEGs, the 100000x100000 bomb, a valid 16000x16000 header, empty and text
/// files), then one good frame, through camera-ingest in a memory cgroup as
/// tight as its unit's `MemoryMax`: nothing broken is published, every file
/// is dropped, counted and named, the good frame still arrives, the limit is
/// never hit and the stage ends normally (no abort).
#[test]
fn the_bad_image_corpus_publishes_nothing_within_the_units_memory_limit() {
    let ns = Namespace::new("ingestcorpus");
    let dir = ns.root.join("corpus");
    std::fs::create_dir_all(&dir).unwrap();
    let fixtures = repo_root().join("tests/fixtures/bad-images");
    let mut bad = Vec::new();
    for entry in std::fs::read_dir(fixtures.join("mutated")).unwrap() {
        bad.push(entry.unwrap().path());
    }
    assert_eq!(bad.len(), 200, "the mutated corpus");
    for name in [
        "bomb-100000x100000.png",
        "large-16000x16000.png",
        "empty.png",
        "text.jpg",
    ] {
        bad.push(fixtures.join(name));
    }
    for path in &bad {
        std::fs::copy(path, dir.join(path.file_name().unwrap())).unwrap();
    }
    // Sorted after every bad name: the stream must still work at the end.
    std::fs::copy(fixtures.join("good-32x24.png"), dir.join("zzz-good.png")).unwrap();

    let cfg = ns.write(
        "camera-ingest.toml",
        &format!(
            "[[cameras]]\nfolder = \"corpus\"\nrate_hz = 200.0\nloops = 1\n{}",
            model("front", 32, 24, 0.0)
        ),
    );
    let bus = ns.bus("ingest-corpus");
    let frames = bus
        .slice_subscriber(&topics::camera_image("front"))
        .unwrap();
    let health = bus.subscriber(&topics::health("camera-ingest")).unwrap();

    let limit = farsight_tests::unit_memory_max_bytes("camera-ingest");
    let cgroup = farsight_tests::MemoryCgroup::new("ingest-corpus", limit);
    let mut cmd = std::process::Command::new(farsight_tests::bin("farsight-camera-ingest"));
    cmd.args(["--config", cfg.to_str().unwrap()])
        .envs(ns.env())
        .env("RUST_LOG", "info");
    let mut stage = farsight_tests::Proc::spawn("farsight-camera-ingest", cgroup.wrap(&cmd));

    let (mut published, mut last) = (Vec::new(), None);
    let mut exit = None;
    let end = Instant::now() + Duration::from_secs(120);
    while Instant::now() < end && (exit.is_none() || last.is_none()) {
        if let Some(f) = frames.latest().unwrap() {
            published.push((f.header().width, f.header().height, f.data().to_vec()));
        }
        if let Some(h) = health.latest().unwrap() {
            if h.state.name() == Some("stopping") {
                last = Some(h);
            }
        }
        if exit.is_none() {
            exit = stage.wait_exit(Duration::from_millis(5));
        }
    }
    let errors = stage.stderr_so_far();
    assert_eq!(exit, Some(0), "no abort, a normal end:\n{errors}");
    let good =
        farsight_imaging::decode_png(&std::fs::read(fixtures.join("good-32x24.png")).unwrap())
            .unwrap()
            .1;
    assert_eq!(published.len(), 1, "only the good frame is published");
    assert_eq!(published[0], (32, 24, good));
    let h = last.expect("the final health report");
    assert_eq!((h.messages_out, h.dropped), (1, bad.len() as u64), "{h:?}");
    for path in &bad {
        let name = path.file_name().unwrap().to_str().unwrap();
        assert!(
            errors.contains(name),
            "{name} is not named in the log:\n{errors}"
        );
    }
    let peak = cgroup.peak_bytes();
    println!(
        "{} bad files: 0 published, {} dropped; peak memory {:.1} MiB of the unit's {} MiB",
        bad.len(),
        h.dropped,
        peak as f64 / 1048576.0,
        limit >> 20
    );
    assert_eq!(
        cgroup.limit_hits(),
        0,
        "the memory limit was hit (peak {peak} bytes)"
    );
}

#[test]
fn a_missing_v4l2_camera_stops_the_stage_with_a_clear_error() {
    let ns = Namespace::new("ingestv4l2");
    let cfg = ns.write(
        "camera-ingest.toml",
        &format!(
            "[[cameras]]\nsource = \"v4l2\"\ndevice = \"/dev/video-farsight-absent\"\n{}",
            model("front", 640, 480, 0.0)
        ),
    );
    let err = ns.start_must_fail("farsight-camera-ingest", &cfg);
    assert!(
        err.contains("camera front: V4L2 device /dev/video-farsight-absent does not exist: is the camera connected?"),
        "{err}"
    );
}

fn ros_image(sec: u32, w: u32, h: u32, step: u32, data: &[u8]) -> Vec<u8> {
    let mut c = Cdr::new();
    c.u32(sec)
        .u32(0)
        .string("front_optical")
        .u32(h)
        .u32(w)
        .string("rgb8");
    c.u8(0); // is_bigendian
    c.u32(step).bytes(data);
    c.finish()
}

fn ros_compressed(sec: u32, jpeg: &[u8]) -> Vec<u8> {
    let mut c = Cdr::new();
    c.u32(sec)
        .u32(250_000_000)
        .string("rear_optical")
        .string("jpeg")
        .bytes(jpeg);
    c.finish()
}

#[test]
fn a_ros2_bag_in_mcap_replays_into_the_graph() {
    let ns = Namespace::new("ingestmcap");
    let bag = ns.root.join("run.mcap");
    {
        let mut w = mcap::Writer::new(std::io::BufWriter::new(
            std::fs::File::create(&bag).unwrap(),
        ))
        .unwrap();
        let image_schema = w.add_schema("sensor_msgs/msg/Image", "ros2msg", b"std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\nuint32 step\nuint8[] data\n").unwrap();
        let compressed_schema = w
            .add_schema(
                "sensor_msgs/msg/CompressedImage",
                "ros2msg",
                b"std_msgs/Header header\nstring format\nuint8[] data\n",
            )
            .unwrap();
        let meta = Default::default();
        let front = w
            .add_channel(image_schema, "/front/image_raw", "cdr", &meta)
            .unwrap();
        let rear = w
            .add_channel(
                compressed_schema,
                "/rear/image_raw/compressed",
                "cdr",
                &meta,
            )
            .unwrap();
        let h = ImageHeader::packed(Stamp::default(), 0, 64, 48, PixelEncoding::RGB8);
        let jpeg = farsight_imaging::encode_jpeg(&h, &vec![120u8; 64 * 48 * 3], 90).unwrap();
        for k in 0..4u32 {
            let t = 1_000_000_000 + k as u64 * 50_000_000;
            let header = |channel_id| mcap::records::MessageHeader {
                channel_id,
                sequence: k,
                log_time: t,
                publish_time: t,
            };
            let pixels = vec![10 * k as u8 + 1; 64 * 48 * 3];
            // Message 2 claims a row stride that does not match its data: dropped.
            let step = if k == 2 { 64 * 3 + 1 } else { 64 * 3 };
            w.write_to_known_channel(&header(front), &ros_image(100 + k, 64, 48, step, &pixels))
                .unwrap();
            w.write_to_known_channel(&header(rear), &ros_compressed(200 + k, &jpeg))
                .unwrap();
        }
        w.finish().unwrap();
    }
    let cfg = ns.write(
        "camera-ingest.toml",
        &format!(
            "[[cameras]]\nsource = \"mcap\"\nfile = \"run.mcap\"\ntopic = \"/front/image_raw\"\nspeed = 2.0\n{}\n\
             [[cameras]]\nsource = \"mcap\"\nfile = \"run.mcap\"\ntopic = \"/rear/image_raw/compressed\"\n{}",
            model("front", 64, 48, 0.0),
            model("rear", 64, 48, 180.0)
        ),
    );
    let bus = ns.bus("ingest-mcap-test");
    let front = bus
        .slice_subscriber(&topics::camera_image("front"))
        .unwrap();
    let rear = bus.slice_subscriber(&topics::camera_image("rear")).unwrap();
    let mut stage = ns.start_stage("farsight-camera-ingest", "camera-ingest", &cfg);
    let (mut fronts, mut rears) = (Vec::new(), Vec::new());
    let end = Instant::now() + Duration::from_secs(15);
    while Instant::now() < end && (fronts.len() < 3 || rears.len() < 4) {
        if let Some(f) = front.latest().unwrap() {
            fronts.push((
                f.header().stamp.capture_time_ns,
                f.data()[0],
                f.header().encoding,
            ));
        }
        if let Some(r) = rear.latest().unwrap() {
            assert_eq!(r.header().encoding, PixelEncoding::RGB8);
            assert!(r.data().iter().all(|&v| v.abs_diff(120) < 6));
            rears.push(r.header().stamp.capture_time_ns);
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    assert_eq!(
        stage.wait_exit(Duration::from_secs(10)),
        Some(0),
        "{}",
        stage.stderr_so_far()
    );
    // The ROS header stamps become capture times; frame 2 (bad stride) is skipped.
    assert_eq!(
        fronts,
        vec![
            (100_000_000_000, 1, PixelEncoding::RGB8),
            (101_000_000_000, 11, PixelEncoding::RGB8),
            (103_000_000_000, 31, PixelEncoding::RGB8)
        ]
    );
    assert_eq!(
        rears,
        vec![
            200_250_000_000,
            201_250_000_000,
            202_250_000_000,
            203_250_000_000
        ]
    );
    let errors = stage.stderr_so_far();
    assert!(
        errors.contains("image data holds 9216 bytes, but height 48 x step 193 needs 9264"),
        "{errors}"
    );
}

#[test]
fn asking_for_a_topic_the_recording_lacks_names_the_ones_it_has() {
    let ns = Namespace::new("ingestmcap2");
    let bag = ns.root.join("empty.mcap");
    {
        let mut w = mcap::Writer::new(std::io::BufWriter::new(
            std::fs::File::create(&bag).unwrap(),
        ))
        .unwrap();
        let s = w
            .add_schema("sensor_msgs/msg/Image", "ros2msg", b"")
            .unwrap();
        let c = w
            .add_channel(s, "/left/image", "cdr", &Default::default())
            .unwrap();
        let hdr = mcap::records::MessageHeader {
            channel_id: c,
            sequence: 0,
            log_time: 1,
            publish_time: 1,
        };
        w.write_to_known_channel(&hdr, &ros_image(1, 2, 1, 6, &[0; 6]))
            .unwrap();
        w.finish().unwrap();
    }
    let cfg = ns.write(
        "camera-ingest.toml",
        &format!(
            "[[cameras]]\nsource = \"mcap\"\nfile = \"empty.mcap\"\ntopic = \"/right/image\"\n{}",
            model("front", 2, 1, 0.0)
        ),
    );
    let err = ns.start_must_fail("farsight-camera-ingest", &cfg);
    assert!(
        err.contains("no topic /right/image in")
            && err.contains("/left/image (cdr, sensor_msgs/msg/Image)"),
        "{err}"
    );
}
