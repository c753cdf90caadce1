//! Real frames through the real perception stages: camera-ingest plays the ORFD
//! off-road frames into shared memory, the inference stage runs TwinLiteNet on
//! them, and the navigability images it publishes mark the road ahead drivable
//! and the sky not. Each pair runs as a graph through `farsight run`, which
//! starts the camera once inference is ready.

use farsight_interfaces::msg::PixelEncoding;
use farsight_interfaces::topics;
use farsight_tests::{
    navigable_fraction, orfd_ingest_toml, repo_root, toml_string, wait_health, Namespace,
    ORFD_ROAD_AHEAD, ORFD_SKY,
};
use std::time::{Duration, Instant};

/// camera-ingest keys for lock-step on the inference stage's answers: each
/// frame waits (up to a minute) for the mask of the one before.
const PACED: &str = "rate_hz = 100.0\nloops = 1\npace_by = \"perception/front/navigability\"\npace_timeout_s = 60.0";

#[test]
fn twinlitenet_stage_marks_the_orfd_road_navigable() {
    let ns = Namespace::new("perception");
    let root = repo_root();
    let inference_cfg = ns.write(
        "inference.toml",
        &format!(
            "camera = \"front\"\nmodel_config = {}\n",
            toml_string(
                &root
                    .join("deploy/models/twinlitenet.toml")
                    .display()
                    .to_string()
            )
        ),
    );
    // Lock-step on the stage's answers: every frame is processed however
    // slow the machine, so the counts below are exact.
    let ingest_cfg = ns.write("camera-ingest.toml", &orfd_ingest_toml(PACED));
    let bus = ns.bus("perception-test");
    let nav = bus
        .slice_subscriber(&topics::navigability("front"))
        .unwrap();
    let health = bus.subscriber(&topics::health("inference")).unwrap();
    let _graph = ns.run_graph(
        &[
            ("inference", &inference_cfg),
            ("camera-ingest", &ingest_cfg),
        ],
        &[],
        &["perception/front/navigability"],
    );

    let mut seen = Vec::new();
    let end = Instant::now() + Duration::from_secs(120);
    while seen.last() != Some(&6) && Instant::now() < end {
        if let Some(s) = nav.latest().unwrap() {
            let h = *s.header();
            assert_eq!(h.encoding, PixelEncoding::MONO8);
            h.validate(s.data().len()).unwrap();
            let (w, hgt) = (h.width as usize, h.height as usize);
            let (road_x, road_y) = ORFD_ROAD_AHEAD;
            let (sky_x, sky_y) = ORFD_SKY;
            let road = navigable_fraction(s.data(), w, hgt, road_x, road_y);
            let sky = navigable_fraction(s.data(), w, hgt, sky_x, sky_y);
            assert!(
                road > 0.8 && sky < 0.02,
                "frame {}: road {road:.2}, sky {sky:.2}",
                h.stamp.frame_seq
            );
            // The mask carries the stamp of the camera frame it came from.
            assert!((1..=6).contains(&h.stamp.frame_seq));
            assert!(h.stamp.capture_time_ns / 1_000_000 >= 1_623_721_491_895);
            seen.push(h.stamp.frame_seq);
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(seen.last(), Some(&6), "the last frame's mask: {seen:?}");
    assert!(seen.windows(2).all(|w| w[0] < w[1]), "{seen:?}");
    // Every frame became a mask: none dropped, none skipped.
    let h = wait_health(&health, Duration::from_secs(30), "with 6 masks out", |h| {
        h.messages_out >= 6
    });
    assert_eq!((h.messages_out, h.dropped, h.skipped), (6, 0, 0), "{h:?}");
}

#[test]
fn farsight_infer_writes_masks_and_overlays_a_person_can_check() {
    let ns = Namespace::new("infercli");
    let root = repo_root();
    let out = ns.root.join("infer");
    let frames = root.join("../shared/data/orfd/image_data");
    let first = std::fs::read_dir(&frames)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .min()
        .unwrap();
    // One good image, one truncated copy: the broken one is reported and skipped.
    let broken = ns.root.join("broken.png");
    let bytes = std::fs::read(&first).unwrap();
    std::fs::write(&broken, &bytes[..bytes.len() / 3]).unwrap();
    let mut p = farsight_tests::Proc::start(
        "farsight",
        &[
            "infer",
            "--model-config",
            root.join("deploy/models/twinlitenet.toml")
                .to_str()
                .unwrap(),
            first.to_str().unwrap(),
            broken.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ],
        &ns,
    );
    assert_eq!(
        p.wait_exit(Duration::from_secs(60)),
        Some(0),
        "{}",
        p.stderr_so_far()
    );
    assert!(
        p.stderr_so_far().contains("broken.png: skipped"),
        "{}",
        p.stderr_so_far()
    );
    let stem = first.file_stem().unwrap().to_str().unwrap();
    let (h, mask) = farsight_imaging::decode_png(
        &std::fs::read(out.join(format!("{stem}.navigability.png"))).unwrap(),
    )
    .unwrap();
    assert_eq!(
        (h.width, h.height, h.encoding),
        (640, 360, PixelEncoding::MONO8)
    );
    assert!(mask.iter().all(|&v| v == 0 || v == 255));
    let (oh, _) = farsight_imaging::decode_png(
        &std::fs::read(out.join(format!("{stem}.overlay.png"))).unwrap(),
    )
    .unwrap();
    assert_eq!(
        (oh.width, oh.height),
        (1280, 720),
        "the overlay is at frame resolution"
    );
    assert!(out.join(format!("{stem}.classes.png")).exists());
}

/// Runs `farsight infer` with `args`; its exit code and stderr.
fn farsight_infer(ns: &Namespace, args: &[&str]) -> (Option<i32>, String) {
    let mut p = farsight_tests::Proc::start("farsight", &[&["infer"], args].concat(), ns);
    let code = p.wait_exit(Duration::from_secs(60));
    (code, p.stderr_so_far())
}

fn png(path: &std::path::Path) -> (farsight_interfaces::msg::ImageHeader, Vec<u8>) {
    farsight_imaging::decode_png(&std::fs::read(path).unwrap()).unwrap()
}

/// The learned models' outputs drawn over real frames (what the README's
/// pictures are made with): FITAM's far field as bands across the top,
/// HIP's ranking of its library in the lower right corner (and as CSV),
/// the frame untouched elsewhere; every overlay on one contact sheet.
#[test]
fn farsight_infer_draws_the_learned_models_and_a_contact_sheet() {
    let ns = Namespace::new("inferdraw");
    let root = repo_root();
    let orfd = root.join("../shared/data/orfd/image_data/1623721491895.png");
    let wvn = root.join("../shared/data/wvn/mountain_bike_trail_raw.png");
    let s = |p: &std::path::Path| p.to_str().unwrap().to_string();
    let (frame_h, frame) = png(&orfd);
    assert_eq!((frame_h.width, frame_h.height), (1280, 720));
    let model = |m: &str| s(&root.join("deploy/models").join(m).join("model.toml"));

    let out = ns.root.join("fitam");
    let sheet = ns.root.join("fitam-sheet.png");
    let (code, err) = farsight_infer(
        &ns,
        &[
            "--model-config",
            &model("sim-fitam"),
            &s(&orfd),
            &s(&wvn),
            "--out",
            &s(&out),
            "--sheet",
            &s(&sheet),
            "--sheet-columns",
            "2",
            "--sheet-width",
            "200",
        ],
    );
    assert_eq!(code, Some(0), "{err}");
    let (oh, overlay) = png(&out.join("1623721491895.overlay.png"));
    assert_eq!((oh.width, oh.height), (1280, 720));
    // Three radial bands of 1/16 of the height each, the frame below them.
    let row = |img: &[u8], y: usize| img[y * 1280 * 3..(y + 1) * 1280 * 3].to_vec();
    assert_ne!(row(&overlay, 10), row(&frame, 10));
    assert_ne!(row(&overlay, 130), row(&frame, 130));
    assert_eq!(overlay[140 * 1280 * 3..], frame[140 * 1280 * 3..]);
    // Two cells 200 wide, as tall as the first frame's aspect makes them.
    let (sh, _) = png(&sheet);
    assert_eq!((sh.width, sh.height), (400, 113));

    // HIP needs the library it ranks, and names the flag that gives it.
    let out = ns.root.join("hip");
    let (code, err) = farsight_infer(
        &ns,
        &[
            "--model-config",
            &model("sim-hip"),
            &s(&orfd),
            "--out",
            &s(&out),
        ],
    );
    assert_eq!(code, Some(1));
    assert!(err.contains("--hip-library"), "{err}");
    let library = s(&root.join("deploy/models/sim-hip/hip-library.toml"));
    let hip = |library: &str, frame: &std::path::Path| {
        farsight_infer(
            &ns,
            &[
                "--model-config",
                &model("sim-hip"),
                "--hip-library",
                library,
                &s(frame),
                "--out",
                &s(&out),
            ],
        )
    };
    let (code, err) = hip(&library, &orfd);
    assert_eq!(code, Some(0), "{err}");
    let csv = std::fs::read_to_string(out.join("1623721491895.log_q.csv")).unwrap();
    let log_q: Vec<f64> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(1).unwrap().parse().unwrap())
        .collect();
    assert_eq!(log_q.len(), 200);
    assert!(log_q.iter().all(|q| q.is_finite()), "{csv}");
    // A library the model was not exported with is refused, naming it;
    // a frame too small for the inset is drawn as it is.
    let short = ns.write(
        "short-library.toml",
        &format!(
            "step_s = 0.2\ntrajectories = [[{}]]\n",
            ["[0.1, 0.0]"; 10].join(", ")
        ),
    );
    let (code, err) = hip(&s(&short), &orfd);
    assert_eq!(code, Some(1));
    assert!(
        err.contains("short-library.toml: 1 trajectories, but the model scores 200"),
        "{err}"
    );
    let tiny = ns.root.join("tiny.png");
    let tiny_frame: Vec<u8> = (0..24 * 20 * 3).map(|i| (i * 7 % 251) as u8).collect();
    let header = farsight_interfaces::msg::ImageHeader::packed(
        farsight_interfaces::msg::Stamp::default(),
        0,
        24,
        20,
        PixelEncoding::RGB8,
    );
    std::fs::write(
        &tiny,
        farsight_imaging::encode_png(&header, &tiny_frame).unwrap(),
    )
    .unwrap();
    let (code, err) = hip(&library, &tiny);
    assert_eq!(code, Some(0), "{err}");
    assert_eq!(png(&out.join("tiny.overlay.png")).1, tiny_frame);
    let (_, overlay) = png(&out.join("1623721491895.overlay.png"));
    let px = |img: &[u8], x: usize, y: usize| img[(y * 1280 + x) * 3..][..3].to_vec();
    // The inset (the lower right 360x360) is drawn; the rest is the frame.
    assert_ne!(px(&overlay, 1279, 719), px(&frame, 1279, 719));
    assert_eq!(overlay[..360 * 1280 * 3], frame[..360 * 1280 * 3]);
    assert_eq!(px(&overlay, 100, 700), px(&frame, 100, 700));
}

#[test]
fn depth_normals_stage_marks_the_orfd_road_navigable() {
    let ns = Namespace::new("normalsstage");
    let data = repo_root().join("../shared/data/orfd");
    let ingest_cfg = ns.write(
        "camera-ingest.toml",
        &(orfd_ingest_toml(&format!(
            "{PACED}\ndepth_folder = {}",
            toml_string(&data.join("dense_depth").display().to_string())
        )) + "xyz_m = [0.0, 0.0, 1.5]\nrpy_deg = [0.0, 6.7, 0.0]\n"),
    );
    let inference_cfg = ns.write(
        "inference.toml",
        "camera = \"front\"\nbackend = \"normals\"\n",
    );
    let bus = ns.bus("normals-test");
    let nav = bus
        .slice_subscriber(&topics::navigability("front"))
        .unwrap();
    let health = bus.subscriber(&topics::health("inference")).unwrap();
    let run = ns.run_graph(
        &[
            ("inference", &inference_cfg),
            ("camera-ingest", &ingest_cfg),
        ],
        &[],
        &["perception/front/navigability"],
    );
    let mut seqs = Vec::new();
    let end = Instant::now() + Duration::from_secs(120);
    while seqs.last() != Some(&6) && Instant::now() < end {
        if let Some(s) = nav.latest().unwrap() {
            let h = *s.header();
            let (w, hh) = (h.width as usize, h.height as usize);
            assert_eq!((w, hh), (1280, 720));
            let road = navigable_fraction(s.data(), w, hh, ORFD_ROAD_AHEAD.0, ORFD_ROAD_AHEAD.1);
            assert!(
                road > 0.8,
                "frame {}: road ahead {road:.2} navigable",
                h.stamp.frame_seq
            );
            assert!(
                s.data()[..w * 80].iter().all(|&v| v == 0),
                "the sky (no depth) is never navigable"
            );
            seqs.push(h.stamp.frame_seq);
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    assert!(
        run.wait_line(Duration::from_secs(30), |l| l
            .starts_with("camera-ingest: exited (exit status: 0)"))
            .is_some(),
        "{}",
        ns.node_log("camera-ingest")
    );
    assert!(
        seqs.last() == Some(&6) && seqs.windows(2).all(|w| w[0] < w[1]),
        "{seqs:?}"
    );
    // The camera model is published before the first depth frame, so even
    // that one is processed: all six frames became masks.
    let h = wait_health(&health, Duration::from_secs(30), "with 6 masks out", |h| {
        h.messages_out >= 6
    });
    assert_eq!((h.messages_out, h.dropped, h.skipped), (6, 0, 0), "{h:?}");
}

/// camera-ingest on the ORFD frames (looping) and an inference stage with
/// `inference_toml`, through `farsight run`; returns it.
fn orfd_graph(ns: &Namespace, inference_toml: &str, loops: u32) -> farsight_tests::Proc {
    let ingest_cfg = ns.write(
        "camera-ingest.toml",
        &orfd_ingest_toml(&format!("rate_hz = 4.0\nloops = {loops}")),
    );
    let inference_cfg = ns.write("inference.toml", inference_toml);
    ns.run_graph(
        &[
            ("inference", &inference_cfg),
            ("camera-ingest", &ingest_cfg),
        ],
        &[],
        &["perception/front/navigability"],
    )
}

#[test]
fn deeplabv3_stage_publishes_21_class_maps_with_confidence() {
    let ns = Namespace::new("deeplabstage");
    let bus = ns.bus("deeplab-test");
    let classes = bus.slice_subscriber(&topics::class_map("front")).unwrap();
    let confidence = bus
        .slice_subscriber(&topics::class_confidence("front"))
        .unwrap();
    let cfg = format!(
        "camera = \"front\"\nmodel_config = {}\n",
        toml_string(
            &repo_root()
                .join("deploy/models/deeplabv3-voc.toml")
                .display()
                .to_string()
        )
    );
    let _graph = orfd_graph(&ns, &cfg, 1);
    let end = Instant::now() + Duration::from_secs(30);
    let (mut got_classes, mut got_conf) = (None, None);
    while (got_classes.is_none() || got_conf.is_none()) && Instant::now() < end {
        if let Some(c) = classes.latest().unwrap() {
            let h = *c.header();
            assert_eq!(
                (h.width, h.height, h.encoding),
                (257, 257, PixelEncoding::MONO8)
            );
            assert!(c.data().iter().all(|&id| id < 21));
            got_classes = Some(h.stamp.frame_seq);
        }
        if let Some(c) = confidence.latest().unwrap() {
            let h = *c.header();
            assert_eq!(h.encoding, PixelEncoding::F32);
            let p: Vec<f32> = c
                .data()
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
                .collect();
            assert_eq!(p.len(), 257 * 257);
            assert!(
                p.iter().all(|&v| v > 0.0 && v <= 1.0),
                "softmax confidence is a probability"
            );
            got_conf = Some(h.stamp.frame_seq);
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    assert!(
        got_classes.is_some() && got_conf.is_some(),
        "{got_classes:?} {got_conf:?}"
    );
}

#[test]
fn non_finite_model_output_is_dropped_and_counted_never_published() {
    let ns = Namespace::new("nanstage");
    // A model config whose input scale overflows f32: the real network then
    // produces inf/NaN for every frame.
    let base = std::fs::read_to_string(repo_root().join("deploy/models/twinlitenet.toml")).unwrap();
    let models = repo_root().join("deploy/models");
    let broken = base
        .replace("scale = 0.00392156862745098", "scale = 1e38")
        .replace(
            "model = \"../../../shared/",
            &format!("model = \"{}/../../../shared/", models.display()),
        )
        .replace(
            "class_table = \"",
            &format!("class_table = \"{}/", models.display()),
        );
    let model_cfg = ns.write("overflow.toml", &broken);
    let bus = ns.bus("nan-test");
    let nav = bus
        .slice_subscriber(&topics::navigability("front"))
        .unwrap();
    let health = bus.subscriber(&topics::health("inference")).unwrap();
    // The frames loop until three have been dropped, however many a slow
    // machine skips on the way.
    let run = orfd_graph(
        &ns,
        &format!(
            "camera = \"front\"\nmodel_config = {}\n",
            toml_string(&model_cfg.display().to_string())
        ),
        0,
    );
    let pid = run.child_instance_pid("inference");
    let end = Instant::now() + Duration::from_secs(120);
    let mut last = None;
    while Instant::now() < end {
        assert!(
            nav.latest().unwrap().is_none(),
            "a frame with non-finite output was published"
        );
        if let Some(h) = health.latest().unwrap() {
            if h.dropped >= 3 {
                last = Some(h);
                break;
            }
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let h = last.expect("the stage reports dropped frames in its health");
    assert_eq!(h.messages_out, 0);
    let log = ns.node_log("inference");
    assert!(log.contains("non-finite values"), "{log}");
    assert!(pid.is_some());
    assert_eq!(
        run.child_instance_pid("inference"),
        pid,
        "the stage keeps running, never restarted"
    );
}

#[test]
fn class_table_edits_take_effect_without_a_restart() {
    let ns = Namespace::new("classtable");
    let table = ns.write(
        "classes.toml",
        "[[class]]\nid = 1\nname = \"drivable\"\nnavigable = true\ncost_s_per_m = 0.25\n",
    );
    let cfg = format!(
        "camera = \"front\"\nmodel_config = {}\nclass_table = {}\nclass_table_poll_s = 0.2\n",
        toml_string(
            &repo_root()
                .join("deploy/models/twinlitenet.toml")
                .display()
                .to_string()
        ),
        toml_string(&table.display().to_string())
    );
    let bus = ns.bus("classtable-test");
    let nav = bus
        .slice_subscriber(&topics::navigability("front"))
        .unwrap();
    let _graph = orfd_graph(&ns, &cfg, 0);
    let navigable = |timeout: u64, want_any: bool| {
        let end = Instant::now() + Duration::from_secs(timeout);
        while Instant::now() < end {
            if let Some(s) = nav.latest().unwrap() {
                if s.data().contains(&255) == want_any {
                    return true;
                }
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        false
    };
    assert!(
        navigable(60, true),
        "the road is navigable with the first table"
    );
    // The operator decides nothing is drivable: the running stage follows.
    std::fs::write(
        &table,
        "[[class]]\nid = 1\nname = \"drivable\"\nnavigable = false\n",
    )
    .unwrap();
    let later = std::time::SystemTime::now() + Duration::from_secs(1);
    std::fs::File::options()
        .write(true)
        .open(&table)
        .unwrap()
        .set_modified(later)
        .unwrap();
    assert!(navigable(60, false), "after the edit nothing is navigable");
    let log = ns.node_log("inference");
    assert!(log.contains("class table reloaded"), "{log}");
}

#[test]
fn paced_by_its_consumer_camera_ingest_loses_no_frame() {
    let ns = Namespace::new("paced");
    // 100 Hz asked for, twice through the folder.
    let ingest_cfg = ns.write(
        "camera-ingest.toml",
        &orfd_ingest_toml(&PACED.replace("loops = 1", "loops = 2")),
    );
    let inference_cfg = ns.write(
        "inference.toml",
        &format!(
            "camera = \"front\"\nmodel_config = {}\n",
            toml_string(
                &repo_root()
                    .join("deploy/models/twinlitenet.toml")
                    .display()
                    .to_string()
            )
        ),
    );
    let bus = ns.bus("paced-test");
    let nav = bus
        .slice_subscriber(&topics::navigability("front"))
        .unwrap();
    let health = bus.subscriber(&topics::health("inference")).unwrap();
    // Through farsight run, which starts the camera (a source) once
    // inference is ready: the first frame is not lost to a reader that
    // had not subscribed yet.
    let run = ns.run_graph(
        &[
            ("inference", &inference_cfg),
            ("camera-ingest", &ingest_cfg),
        ],
        &[],
        &["perception/front/navigability"],
    );
    let mut seqs = Vec::new();
    let end = Instant::now() + Duration::from_secs(120);
    while seqs.last() != Some(&12) && Instant::now() < end {
        if let Some(s) = nav.latest().unwrap() {
            seqs.push(s.header().stamp.frame_seq);
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    assert!(
        seqs.last() == Some(&12) && seqs.windows(2).all(|w| w[0] < w[1]),
        "{seqs:?}"
    );
    assert!(
        run.wait_line(Duration::from_secs(30), |l| l
            .starts_with("camera-ingest: exited (exit status: 0)"))
            .is_some(),
        "camera-ingest did not finish"
    );
    let log = ns.node_log("camera-ingest");
    assert!(!log.contains("did not take frame"), "{log}");
    // Every frame waited for the stage: all 12 became masks, none skipped.
    let h = wait_health(&health, Duration::from_secs(30), "with 12 masks out", |h| {
        h.messages_out >= 12
    });
    assert_eq!((h.messages_out, h.dropped, h.skipped), (12, 0, 0), "{h:?}");
}

/// `farsight bench inference --cameras 2`: one inference process serving
/// both cameras (the batched LRN fixture, one ONNX Runtime session) against a
/// process per camera, each camera's frames counted from its own health
/// topic. The window waits for every camera's results (counts, not the
/// clock), so a busy machine gives lower rates, not a failure: only that
/// both layouts served both cameras is checked.
#[test]
fn bench_inference_compares_one_session_for_two_cameras_with_two_processes() {
    let out = std::process::Command::new(farsight_tests::bin("farsight"))
        .current_dir(repo_root())
        .args([
            "bench",
            "inference",
            "--model-config",
            "tests/fixtures/models/lrn-batch/model.toml",
            "--runs",
            "1",
            "--stage-seconds",
            "1",
            "--cameras",
            "2",
        ])
        .output()
        .expect("farsight bench inference runs");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stdout}\n{stderr}");
    for layout in [
        "| one process, one session (batched) |",
        "| 2 processes, a session each |",
    ] {
        let row = stdout
            .lines()
            .find(|l| l.starts_with(layout))
            .unwrap_or_else(|| panic!("no row {layout}:\n{stdout}"));
        let cells: Vec<&str> = row.split('|').map(str::trim).collect();
        let per_camera: Vec<f64> = cells[3].split(" / ").map(|f| f.parse().unwrap()).collect();
        assert_eq!(per_camera.len(), 2, "{row}");
        assert!(
            per_camera.iter().all(|&f| f > 0.0),
            "every camera served: {row}"
        );
        let total: f64 = cells[2].parse().unwrap();
        assert!(
            (total - per_camera.iter().sum::<f64>()).abs() < 0.2,
            "{row}"
        );
    }
    assert!(stdout.contains("one process / 2 processes:"), "{stdout}");
}
