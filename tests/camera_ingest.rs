//! camera-ingest as a real process: two cameras at once, each with its own
//! mount; broken files are counted and skipped while the stream goes on; a
//! missing V4L2 camera stops the stage at start-up with a message that says so.

use farsight_interfaces::camera::Camera;
use farsight_interfaces::msg::{ImageHeader, PixelEncoding, Stamp};
use farsight_interfaces::topics;
use farsight_tests::{repo_root, Namespace, Proc};
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
    // The rear camera's folder: good, truncated, wrong size, good (JPEG).
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
    std::fs::write(
        rear_dir.join("1000000000004.jpg"),
        farsight_imaging::encode_jpeg(&h, &vec![80u8; 64 * 48 * 3], 90).unwrap(),
    )
    .unwrap();

    let orfd = repo_root().join("../shared/data/orfd/image_data");
    let cfg = ns.write(
        "camera-ingest.toml",
        &format!(
            "[[cameras]]\nfolder = {:?}\nrate_hz = 20.0\nloops = 1\n{}\n[[cameras]]\nfolder = \"rear\"\nrate_hz = 20.0\nloops = 1\n{}",
            orfd.display().to_string(),
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
        && (front_seqs.len() < 6 || rear_caps.len() < 2 || last_health.is_none())
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
        vec![1_000_000_000_001_000_000, 1_000_000_000_004_000_000],
        "{}",
        stage.stderr_so_far()
    );
    let h = last_health.expect("final health report");
    assert_eq!((h.messages_out, h.dropped), (8, 2), "{h:?}");
    let errors = stage.stderr_so_far();
    assert!(
        errors.contains("1000000000003.png: image is 32x48, the camera model says 64x48"),
        "{errors}"
    );
    // The rear camera's model travels with its frames: its centre looks backwards.
    let cam = Camera::from_info(&info.expect("rear camera info")).unwrap();
    let b = cam.pixel_bearing_rad(32.0, 24.0).unwrap();
    assert!((b.abs() - std::f64::consts::PI).abs() < 1e-9, "{b}");
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
    let mut p = Proc::start(
        "farsight-camera-ingest",
        &["--config", cfg.to_str().unwrap()],
        &ns,
    );
    assert_eq!(p.wait_exit(Duration::from_secs(10)), Some(1));
    let err = p.stderr_so_far();
    assert!(
        err.contains("camera front: V4L2 device /dev/video-farsight-absent does not exist: is the camera connected?"),
        "{err}"
    );
}
