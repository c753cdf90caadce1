//! The image-space navigation chain on real data: TwinLiteNet's navigability
//! mask of the ORFD dirt road -> POVNav subgoal -> servo command.

use farsight_inference::class_table::ClassTableFile;
use farsight_inference::model_config::ModelConfig;
use farsight_inference::onnx::{OnnxModel, Timings};
use farsight_inference::Backend;
use farsight_subgoal_selection::povnav::{plan, safe_half_widths, Mode, PovnavConfig};
use farsight_tests::repo_root;
use farsight_velocity_servoing::{povnav_command, ServoConfig};

#[test]
fn orfd_road_goal_ahead_drives_forward_and_a_side_goal_turns_toward_it() {
    let config = ModelConfig::load(&repo_root().join("deploy/models/twinlitenet.toml")).unwrap();
    let table = ClassTableFile::open(&config.class_table_path().unwrap()).unwrap();
    let mut backend = Backend::Onnx(Box::new(OnnxModel::load(&config).unwrap()));
    let files = farsight_tests::orfd_files("image_data");
    // The ORFD camera (calib/cam_K) at the 640x360 model resolution, ~1.5 m up;
    // a 1 m wide robot with a 0.2 m margin.
    let half_widths = safe_half_widths(
        360,
        1487.75 / 2.0,
        1471.06 / 2.0,
        376.48 / 2.0,
        1.5,
        1.0,
        0.2,
    );
    let (pcfg, scfg) = (PovnavConfig::default(), ServoConfig::default());
    for f in &files {
        let (h, frame) = farsight_imaging::decode_png(&std::fs::read(f).unwrap()).unwrap();
        let p = backend
            .run(&h, &frame, Some(table.table()), &mut Timings::default())
            .unwrap();
        let nav = p.navigability.unwrap();
        let ahead = plan(&nav, p.width, p.height, 0.0, &half_widths, &pcfg);
        let (v, w) = povnav_command(ahead.proximity_px, ahead.alignment_rad, &scfg);
        eprintln!(
            "{}: ahead hog {:?} lambda {:.0} phi {:.2} mode {:?} -> v {v:.2} w {w:.2}",
            f.file_name().unwrap().to_string_lossy(),
            ahead.hog_px,
            ahead.proximity_px,
            ahead.alignment_rad,
            ahead.mode
        );
        assert_eq!(ahead.mode, Mode::Safe);
        assert!(v > 0.2, "drives forward along the road: v {v}");
        assert!(w.abs() < 0.5, "small turn rate with the goal ahead: {w}");
        for (deg, side) in [(60.0f64, 1.0), (-60.0, -1.0)] {
            let p = plan(
                &nav,
                p.width,
                p.height,
                deg.to_radians(),
                &half_widths,
                &pcfg,
            );
            let (_, w) = povnav_command(p.proximity_px, p.alignment_rad, &scfg);
            eprintln!(
                "  goal {deg}: hog {:?} phi {:.2} -> w {w:.2}",
                p.hog_px, p.alignment_rad
            );
            assert!(
                w * side > 0.1,
                "goal {deg} deg: turns toward its side (w {w})"
            );
        }
    }
}

/// The whole image-space graph as real processes: camera-ingest -> inference
/// (TwinLiteNet) -> subgoal-selection (POVNav) -> velocity-servoing.
mod graph {
    use farsight_interfaces::msg::*;
    use farsight_interfaces::topics;
    use farsight_tests::{repo_root, toml_string, Namespace, Proc};
    use std::time::{Duration, Instant};

    fn inference(ns: &Namespace) -> Proc {
        let cfg = ns.write(
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
        ns.start_stage("farsight-inference", "inference", &cfg)
    }

    // The one chain started stage by stage, not through `farsight run`: it
    // keeps inference down for a second to measure the stop, longer than
    // farsight run's 0.5 s restart back-off would (tests/replay.rs kills
    // stages under farsight run's supervision).
    #[test]
    fn killing_inference_stops_the_robot_within_the_deadline_and_restarting_resumes() {
        let ns = Namespace::new("killinfer");
        let bus = ns.bus("kill-test");
        let pose = bus.publisher(&topics::pose()).unwrap();
        let goal = bus.publisher(&topics::goal()).unwrap();
        let cmds = bus.subscriber(&topics::velocity_command()).unwrap();
        let servo_health = bus
            .subscriber(&topics::health("velocity-servoing"))
            .unwrap();
        let publish_nav_inputs = || {
            pose.publish(&farsight_tests::pose_now()).unwrap();
            goal.publish(&NavGoal {
                kind: GoalKind::LOCAL,
                x_m: 200.0,
                tolerance_m: 2.0,
                ..Default::default()
            })
            .unwrap();
        };
        publish_nav_inputs();
        let ingest_cfg = ns.write(
            "camera-ingest.toml",
            &format!(
                "[[cameras]]\nfolder = {}\nrate_hz = 8.0\nloops = 0\ncapture_time = \"publish\"\n[cameras.model]\nname = \"front\"\nwidth = 1280\nheight = 720\nfx = 1487.75\nfy = 1471.06\ncx = 625.01\ncy = 376.48\nxyz_m = [0.0, 0.0, 1.5]\n",
                toml_string(&repo_root().join("../shared/data/orfd/image_data").display().to_string())
            ),
        );
        // Staleness is judged on capture time: the deadline covers the
        // pipeline's latency too. TwinLiteNet on a busy 2-core CI machine
        // (two busy loops and other test binaries beside it) gave
        // subgoals 1.6-2.8 s old, so a 1 s deadline never let it drive.
        let deadline_s = 4.0;
        let servo_cfg = ns.write(
            "velocity-servoing.toml",
            &format!("output_rate_hz = 20.0\nsubgoal_deadline_s = {deadline_s}\n"),
        );
        let subgoal_cfg = ns.write(
            "subgoal-selection.toml",
            &format!("method = \"povnav\"\ncamera = \"front\"\nrobot_width_m = 1.0\ninput_deadline_s = {deadline_s}\n"),
        );
        let servo = ns.start_stage(
            "farsight-velocity-servoing",
            "velocity-servoing",
            &servo_cfg,
        );
        let subgoal = ns.start_stage(
            "farsight-subgoal-selection",
            "subgoal-selection",
            &subgoal_cfg,
        );
        let mut infer = inference(&ns);
        let _ingest = ns.start_stage("farsight-camera-ingest", "camera-ingest", &ingest_cfg);

        let next_cmd = |timeout: Duration,
                        pred: &dyn Fn(&VelocityCommand) -> bool|
         -> Option<(Instant, VelocityCommand)> {
            let end = Instant::now() + timeout;
            while Instant::now() < end {
                // Like a localisation stack and an operator tool would: pose as a
                // stream, the goal once but handed to stages that join later.
                pose.publish(&farsight_tests::pose_now()).unwrap();
                goal.deliver_history().unwrap();
                if let Some(c) = cmds.latest().unwrap() {
                    if pred(&c) {
                        return Some((Instant::now(), c));
                    }
                }
                std::thread::sleep(Duration::from_millis(2));
            }
            None
        };
        let driving =
            |c: &VelocityCommand| c.reason == CommandReason::TRACKING && c.linear_mps > 0.05;
        let robot_path = bus.subscriber(&topics::path("visual_robot")).unwrap();
        let (_, c) = next_cmd(Duration::from_secs(30), &driving).unwrap_or_else(|| {
            panic!(
                "the graph never drove forward; last command {:?}\nsubgoal-selection:\n{}\nservo:\n{}",
                cmds.latest(),
                subgoal.stderr_so_far(),
                servo.stderr_so_far()
            )
        });
        assert!(c.angular_radps.abs() < 1.0, "{c:?}");
        // The visual path on the ground: from beside the robot to a point ahead.
        let path = robot_path
            .latest()
            .unwrap()
            .expect("the visual path in robot coordinates");
        assert_eq!(path.frame, PathFrame::ROBOT);
        let pts = path.points.as_slice();
        assert!(pts.len() >= 2, "{pts:?}");
        assert!(
            pts.iter().all(|p| p[0] > 0.0 && p[0].hypot(p[1]) <= 50.0),
            "ahead of the camera, within the 50 m default range: {pts:?}"
        );
        assert!(
            pts.last().unwrap()[0] > pts[0][0] + 1.0,
            "leading away from the robot: {pts:?}"
        );

        infer.kill(); // SIGKILL + reap
        let killed = Instant::now();
        let (t, c) = next_cmd(Duration::from_secs_f64(deadline_s + 5.0), &|c| {
            c.reason == CommandReason::STALE_INPUT
        })
        .expect("the servo notices");
        assert_eq!((c.linear_mps, c.angular_radps), (0.0, 0.0));
        // The last subgoal was derived from a frame taken before the kill: the
        // stop comes within the deadline plus one frame of pipeline and one tick.
        let after = t.duration_since(killed).as_secs_f64();
        eprintln!(
            "servo output zero {after:.3} s after inference was killed (deadline {deadline_s} s)"
        );
        assert!(
            after < deadline_s + 0.4,
            "stopped {after:.2} s after the kill"
        );
        // While inference is down, nothing but zero goes out.
        let end = Instant::now() + Duration::from_secs(1);
        while Instant::now() < end {
            if let Some(c) = cmds.latest().unwrap() {
                assert_eq!(
                    (c.linear_mps, c.angular_radps, c.reason),
                    (0.0, 0.0, CommandReason::STALE_INPUT)
                );
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        let h = servo_health.latest().unwrap().expect("servo health");
        assert_eq!(h.state, HealthState::DEGRADED);
        assert!(
            h.reason.as_str().starts_with("nav/subgoal is"),
            "{:?}",
            h.reason
        );

        let _infer2 = inference(&ns);
        publish_nav_inputs();
        next_cmd(Duration::from_secs(30), &driving).expect("driving again once inference is back");
    }
}

/// bin-projection as a process. No LRN heatmap model exists yet (issue 9
/// trains one), so the test process plays the inference stage and publishes
/// constructed heatmaps for a front and a rear camera.
mod bins {
    use farsight_interfaces::camera::{Camera, CameraModel, Mount};
    use farsight_interfaces::msg::*;
    use farsight_interfaces::topics;
    use farsight_tests::Namespace;
    use std::time::{Duration, Instant};

    #[test]
    fn front_and_rear_heatmaps_become_angular_bins() {
        let ns = Namespace::new("binstage");
        let bus = ns.bus("bins-test");
        let (w, h) = (64usize, 32usize);
        // f = 32 px on a 64 px wide image: +-45 degrees each way.
        let model = CameraModel::pinhole(w as u32, h as u32, 32.0, 32.0, 31.5, 15.5);
        let front = Camera::new(
            0,
            "front",
            model,
            Mount::from_xyz_rpy_deg([0.0; 3], [0.0; 3]),
        );
        let rear = Camera::new(
            1,
            "rear",
            model,
            Mount::from_xyz_rpy_deg([0.0; 3], [0.0, 0.0, 180.0]),
        );
        let cfg = ns.write(
            "bin-projection.toml",
            "cameras = [\"front\", \"rear\"]\n[bins]\nbin_width_deg = 10.0\nh_thresh = 0.5\nalpha = 1.0\n",
        );
        let out = bus.subscriber(&topics::angular_bins()).unwrap();
        let stage = ns.start_stage("farsight-bin-projection", "bin-projection", &cfg);
        let infos = [&front, &rear].map(|c| bus.publisher(&topics::camera_info(&c.name)).unwrap());
        let heats = [&front, &rear].map(|c| {
            bus.slice_publisher(&topics::affordance_heatmap(&c.name), w * h * 4)
                .unwrap()
        });
        // Capture times are 0.1 s per sequence number.
        let stamp = |seq: u64| Stamp::new(seq, seq * 100_000_000);
        let publish = |k: usize, cam: &Camera, heat: &dyn Fn(usize) -> f32, seq: u64| {
            infos[k].publish(&cam.to_info(stamp(seq))).unwrap();
            let values: Vec<f32> = (0..w * h).map(|i| heat(i % w)).collect();
            let header =
                ImageHeader::packed(stamp(seq), cam.id, w as u32, h as u32, PixelEncoding::F32);
            heats[k]
                .publish_copy(header, bytemuck::cast_slice(&values))
                .unwrap();
        };
        // Front: hot in the right quarter of the image (robot's right, about -20..-45 deg).
        publish(0, &front, &|u| if u >= 48 { 1.0 } else { 0.2 }, 1);
        std::thread::sleep(Duration::from_millis(100));
        // Rear: hot everywhere it looks.
        publish(1, &rear, &|_| 1.0, 2);
        let bins_of = |seq: u64| {
            let end = Instant::now() + Duration::from_secs(10);
            while Instant::now() < end {
                if let Some(b) = out.latest().unwrap() {
                    if b.stamp.frame_seq == seq {
                        return b;
                    }
                }
                std::thread::sleep(Duration::from_millis(10));
            }
            panic!("no bins of frame {seq}:\n{}", stage.stderr_so_far());
        };
        let b = bins_of(2);
        let g = farsight_bin_projection_geometry(b.bin_width_rad as f64);
        let bin = |deg: f64| g(deg.to_radians());
        assert_eq!(b.scores.len(), 36);
        let s = b.scores.as_slice();
        let o = b.observed.as_slice();
        // Front right (-30 deg) scores, front left (+30) was below h_thresh.
        assert!(s[bin(-30.0)] > 0.0 && s[bin(30.0)] == 0.0, "{s:?}");
        // Straight behind scores (rear camera); the sides at +-90 deg nobody sees.
        assert!(s[bin(179.0)] > 0.0);
        assert_eq!(
            (o[bin(90.0)], o[bin(-90.0)]),
            (0, 0),
            "unobserved, not zero"
        );
        assert_eq!(o[bin(0.0)], 1);
        let total: f32 = s.iter().sum();
        assert!((total - 1.0).abs() < 1e-4, "normalised: {total}");

        // The rear camera dies; the front one goes on. Within the 1 s input
        // deadline (capture time) its bins stay; past it they drop out and
        // the stage says so, but the bins keep coming: degraded, not stopped.
        let health = bus.subscriber(&topics::health("bin-projection")).unwrap();
        let front_only = |u: usize| if u >= 48 { 1.0 } else { 0.2 };
        for seq in 3..=12 {
            publish(0, &front, &front_only, seq);
            let b = bins_of(seq);
            assert_eq!(b.observed.as_slice()[bin(179.0)], 1, "frame {seq}");
        }
        for seq in 13..=16 {
            publish(0, &front, &front_only, seq);
            let b = bins_of(seq);
            let o = b.observed.as_slice();
            assert_eq!((o[bin(179.0)], o[bin(0.0)]), (0, 1), "frame {seq}");
        }
        let h = farsight_tests::wait_health(&health, Duration::from_secs(5), "degraded", |h| {
            h.state == HealthState::DEGRADED
        });
        assert!(
            h.reason.as_str().starts_with("rear is 1.")
                && h.reason.as_str().ends_with("s old (deadline 1 s)"),
            "{:?}",
            h.reason
        );
        // It comes back: seen behind again.
        publish(1, &rear, &|_| 1.0, 17);
        assert_eq!(bins_of(17).observed.as_slice()[bin(179.0)], 1);
    }

    /// Bin index of a bearing for bins of `width` radians starting at -pi.
    fn farsight_bin_projection_geometry(width: f64) -> impl Fn(f64) -> usize {
        move |a: f64| {
            (((a + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI)) / width) as usize
        }
    }
}

/// velocity-servoing as a process tracking a planner's path by carrot: the
/// test plays the planner (a world-frame path) and localisation (the pose).
mod path_tracking {
    use farsight_interfaces::fixed::FixedVec;
    use farsight_interfaces::msg::*;
    use farsight_interfaces::topics;
    use farsight_tests::Namespace;
    use std::time::{Duration, Instant};

    #[test]
    fn servo_follows_a_world_frame_path_and_stops_when_it_goes_stale() {
        let ns = Namespace::new("pathtrack");
        let bus = ns.bus("path-test");
        let cfg = ns.write(
            "velocity-servoing.toml",
            "track = \"path\"\nsubgoal_deadline_s = 0.3\n[servo]\nlookahead_m = 2.0\n",
        );
        let cmds = bus.subscriber(&topics::velocity_command()).unwrap();
        let health = bus
            .subscriber(&topics::health("velocity-servoing"))
            .unwrap();
        let stage = ns.start_stage("farsight-velocity-servoing", "velocity-servoing", &cfg);
        let paths = bus.publisher(&topics::path("planned")).unwrap();
        let poses = bus.publisher(&topics::pose()).unwrap();
        // Robot at (10, 0) facing north; the path runs north then bends west
        // (the robot's left): (10,0) -> (10,1) -> (7,1).
        let pose = Pose {
            position_m: [10.0, 0.0, 0.0],
            yaw_rad: std::f64::consts::FRAC_PI_2,
            ..Default::default()
        };
        let path = Path {
            stamp: Stamp::new(7, 0),
            frame: PathFrame::WORLD,
            camera_id: 0,
            points: FixedVec::from_slice(&[[10.0, 0.0], [10.0, 1.0], [7.0, 1.0]]).unwrap(),
        };
        // `feed`: how old the published path's capture is (the pose is
        // always fresh), or None to stop publishing both.
        let wait_for = |what: &str, pred: &dyn Fn(&VelocityCommand) -> bool, feed: Option<u64>| {
            let end = Instant::now() + Duration::from_secs(10);
            while Instant::now() < end {
                if let Some(age_ns) = feed {
                    let now = farsight_tests::stamp_now(7);
                    poses.publish(&Pose { stamp: now, ..pose }).unwrap();
                    let captured = Stamp::new(7, now.capture_time_ns - age_ns);
                    // (Not `Path { stamp, ..path }`: that trips a rustc MIR
                    // bug with the const-generic FixedVec inside.)
                    let mut p = path;
                    p.stamp = captured;
                    paths.publish(&p).unwrap();
                }
                if let Some(c) = cmds.latest().unwrap() {
                    if pred(&c) {
                        return c;
                    }
                }
                std::thread::sleep(Duration::from_millis(10));
            }
            panic!(
                "no command {what}; last {:?}\n{}",
                cmds.latest(),
                stage.stderr_so_far()
            );
        };
        // The carrot is on the westward leg, ahead-left: drive and turn left.
        let tracking = |c: &VelocityCommand| {
            c.reason == CommandReason::TRACKING && c.linear_mps > 0.05 && c.angular_radps > 0.3
        };
        let c = wait_for("turning left along the path", &tracking, Some(0));
        assert_eq!(
            c.stamp.frame_seq, 7,
            "the command names the path it came from"
        );
        // A planner replanning on a map whose source died: the path keeps
        // arriving, but from a capture older than the deadline. Zero.
        let stale = |c: &VelocityCommand| c.reason == CommandReason::STALE_INPUT;
        let c = wait_for(
            "stopping on a path from old data",
            &stale,
            Some(400_000_000),
        );
        assert_eq!((c.linear_mps, c.angular_radps), (0.0, 0.0));
        let named = |_: &VelocityCommand| {
            health.latest().unwrap().is_some_and(|h| {
                h.state == HealthState::DEGRADED
                    && h.reason.as_str().starts_with("nav/path/planned is 0.4")
            })
        };
        wait_for("health naming the old path", &named, Some(400_000_000));
        wait_for("tracking again on fresh data", &tracking, Some(0));
        // The planner stops: zero within the deadline, and health says why.
        let c = wait_for("stopping on a stale path", &stale, None);
        assert_eq!((c.linear_mps, c.angular_radps), (0.0, 0.0));
    }
}
