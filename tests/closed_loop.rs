//! The simulator in the loop, through the demo command itself: `farsight
//! demo --method dstar-lite` starts costmap-fusion, D* Lite in
//! subgoal-selection and the servo tracking the planned path, each its own
//! process, with `farsight-sim run` as the robot on the lock-step clock.
//! Near-field sensing alone (the "no far-field" baseline) gets out of LRN's
//! bug trap, since D* Lite replans as the walls come into view. The default
//! demo adds the inference stage running the shipped FITAM model and bin
//! projection, so the fused map has a learned far field.
//!
//! Every stage of the demo runs on the stamps' clock (one output per input,
//! time from the capture times), so two runs of a seed drive the same track
//! bit for bit, with D* Lite as with POVNav (inference on the rendered RGB
//! -> subgoal-selection -> servo); and for each method, the navigation
//! benchmark's in-process trial of the same graph file drives the track
//! the processes drive.

use farsight_tests::{bin, Namespace, Proc};
use std::time::Duration;

fn field<'a>(summary: &'a str, key: &str) -> &'a str {
    summary
        .lines()
        .find_map(|l| l.strip_prefix(&format!("{key} = ")))
        .unwrap_or_else(|| panic!("no {key} in\n{summary}"))
}

#[test]
fn the_demo_escapes_the_bug_trap_with_dstar_lite_and_two_runs_drive_the_same_track() {
    assert!(bin("farsight-sim").exists(), "build the workspace first");
    let ns = Namespace::new("bugtrap");
    let dstar = ["--method", "dstar-lite"];
    let out = demo(&ns, "demo", &dstar);
    assert_same_track(&out, &demo(&ns, "again", &dstar));
    // The map shows the planner's decisions (orange plans), from the
    // recording of every topic the demo leaves beside it.
    let png = std::fs::read(out.join("bug-trap-map.png")).unwrap();
    let (_, rgb) = farsight_imaging::decode_png(&png).unwrap();
    let orange = rgb.chunks(3).filter(|p| *p == [255, 150, 0]).count();
    assert!(orange > 100, "{orange} plan pixels");
    let info = farsight_recording::read::Recording::open(&out.join("recording.mcap"))
        .unwrap()
        .info()
        .unwrap();
    let planned = info.topics.iter().find(|t| t.topic == "nav/path/planned");
    assert!(planned.is_some_and(|t| t.count > 100), "{info}");
    assert!(
        out.join("subgoal-selection.log").exists(),
        "stage logs are kept"
    );
    let summary = std::fs::read_to_string(out.join("summary.toml")).unwrap();
    eprintln!("{summary}");
    assert_eq!(field(&summary, "outcome"), "\"reached\"", "{summary}");
    assert_eq!(field(&summary, "collisions"), "0", "{summary}");
    assert_eq!(field(&summary, "late_commands"), "0", "{summary}");
    let distance: f64 = field(&summary, "distance_m").parse().unwrap();
    assert!(
        distance > 70.0,
        "it went round the trap, not through: {distance} m"
    );
}

#[test]
fn the_default_demo_runs_the_shipped_fitam_model_in_the_graph_and_leaves_the_trap() {
    let ns = Namespace::new("fitamdemo");
    let out = demo(&ns, "default", &[]);
    let summary = std::fs::read_to_string(out.join("summary.toml")).unwrap();
    eprintln!("{summary}");
    assert_eq!(field(&summary, "outcome"), "\"reached\"", "{summary}");
    assert_eq!(field(&summary, "collisions"), "0", "{summary}");
    assert_eq!(field(&summary, "late_commands"), "0", "{summary}");
    // The inference stage ran the shipped model, and its far field reached
    // the fused costmap through bin projection.
    let inference = std::fs::read_to_string(out.join("inference.toml")).unwrap();
    assert!(
        inference.contains("deploy/models/sim-fitam/model.toml"),
        "{inference}"
    );
    let info = farsight_recording::read::Recording::open(&out.join("recording.mcap"))
        .unwrap()
        .info()
        .unwrap();
    for topic in ["bins/polar", "costmap/fused", "nav/path/planned"] {
        let t = info.topics.iter().find(|t| t.topic == topic);
        assert!(t.is_some_and(|t| t.count > 100), "{topic}: {info}");
    }
    // The recorder is in the lock-step answer set: the simulator waits for
    // it before each next frame, so it lost no frame of the drive, and it
    // heard every instance's health from its first report.
    let frames = poses(&out.join("poses.csv")).lines().count() as u64 - 1;
    let count = |topic: &str| {
        info.topics
            .iter()
            .find(|t| t.topic == topic)
            .map_or(0, |t| t.count)
    };
    for topic in ["camera/front/image", "state/pose"] {
        assert_eq!(count(topic), frames, "{topic}: {info}");
    }
    assert!(count("cmd/velocity") >= frames, "{info}");
    for instance in [
        "inference",
        "bin-projection",
        "costmap-fusion",
        "subgoal-selection",
        "velocity-servoing",
    ] {
        assert!(
            count(&format!("health/{instance}")) > 0,
            "{instance}: {info}"
        );
    }
    let report = std::fs::read_to_string(out.join("recorder-report.txt")).unwrap();
    assert!(
        report.contains("health/inference") && report.contains("(not counted)"),
        "health gaps are not counted as losses:\n{report}"
    );
    for topic in ["camera/front/image", "state/pose", "cmd/velocity"] {
        let line = report.lines().find(|l| l.starts_with(topic));
        assert!(
            line.is_some_and(|l| l.ends_with("skipped 0")),
            "{topic}:\n{report}"
        );
    }
}

/// Runs `farsight demo` with `args` into a fresh folder; returns the folder.
/// Lock-step with a 60 s command timeout: these tests compare tracks, and
/// a run that drove a frame without its command could not match, so on a
/// machine loaded enough to starve a stage for the default 10 s the
/// simulator waits rather than drive on (summary.toml counts any late one;
/// a stage that died costs 60 s a frame, inside the demo's 240 s).
fn demo(ns: &Namespace, name: &str, args: &[&str]) -> std::path::PathBuf {
    let out = ns.write("placeholder", "").with_file_name(name);
    let mut all = vec![
        "demo",
        "--command-timeout-s",
        "60",
        "--out",
        out.to_str().unwrap(),
    ];
    all.extend_from_slice(args);
    let mut demo = Proc::start("farsight", &all, ns);
    let code = demo.wait_exit(Duration::from_secs(240));
    assert_eq!(code, Some(0), "farsight {all:?}:\n{}", demo.stderr_so_far());
    out
}

/// `farsight-sim run ARGS` at 160x90 (no graph: the test plays it), writing
/// into a fresh folder; returns the process and the folder.
fn small_sim(ns: &Namespace, args: &[&str]) -> (Proc, std::path::PathBuf) {
    let out = ns.write("placeholder", "").with_file_name("sim");
    let mut all = vec!["run", "--width", "160", "--height", "90"];
    all.extend_from_slice(args);
    all.extend_from_slice(&["--out", out.to_str().unwrap()]);
    (Proc::start("farsight-sim", &all, ns), out)
}

fn poses(path: &std::path::Path) -> String {
    std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

#[test]
fn povnav_on_the_rendered_rgb_crosses_the_bush_wall_and_two_runs_drive_the_same_track() {
    let ns = Namespace::new("povnavdet");
    let args = ["--method", "povnav", "--scenario", "bush-wall"];
    let (a, b) = (demo(&ns, "run-a", &args), demo(&ns, "run-b", &args));
    let summary = std::fs::read_to_string(a.join("summary.toml")).unwrap();
    eprintln!("{summary}");
    assert_eq!(field(&summary, "outcome"), "\"reached\"", "{summary}");
    assert_eq!(field(&summary, "late_commands"), "0", "{summary}");
    // The inference stage ran (no oracle): its log and config are there.
    assert!(a.join("inference.toml").exists());
    assert_same_track(&a, &b);
}

/// Two demo runs' `poses.csv` are the same, byte for byte.
fn assert_same_track(a: &std::path::Path, b: &std::path::Path) {
    let (ta, tb) = (poses(&a.join("poses.csv")), poses(&b.join("poses.csv")));
    assert!(
        ta.lines().count() > 500,
        "a whole drive: {} poses",
        ta.lines().count()
    );
    if ta != tb {
        let (i, (la, lb)) = ta
            .lines()
            .zip(tb.lines())
            .enumerate()
            .find(|(_, (x, y))| x != y)
            .expect("one is a prefix of the other");
        // A late command (the simulator waited out its timeout, and the
        // base coasted) is the usual way two runs part: say so.
        let summary = |d: &std::path::Path| {
            std::fs::read_to_string(d.join("summary.toml")).unwrap_or_default()
        };
        panic!(
            "the runs part at pose {i}: {la} vs {lb}\n{}:\n{}\n{}:\n{}",
            a.display(),
            summary(a),
            b.display(),
            summary(b)
        );
    }
}

/// The navigation benchmark's rows and the graph file each runs, as
/// `farsight bench nav --list` gives them.
fn bench_methods(ns: &Namespace) -> Vec<(String, String)> {
    let mut p = Proc::start("farsight", &["bench", "nav", "--list"], ns);
    assert_eq!(
        p.wait_exit(Duration::from_secs(30)),
        Some(0),
        "{}",
        p.stderr_so_far()
    );
    let rows: Vec<(String, String)> = std::iter::from_fn(|| {
        p.wait_line(Duration::from_millis(100), |_| true)
            .map(|(_, l)| l)
    })
    .map(|l| {
        let (m, g) = l.split_once('\t').unwrap_or_else(|| panic!("{l:?}"));
        (m.to_string(), g.to_string())
    })
    .collect();
    assert!(rows.len() >= 6, "{rows:?}");
    rows
}

#[test]
fn per_method_a_benchmark_trial_drives_the_track_its_graph_drives_as_processes_every_time() {
    // Short drives (20 s of simulated time) into the obstacle field: each
    // method's graph file twice as processes (`farsight demo --graph`,
    // through `farsight run`), and the benchmark's in-process trial of the
    // same file twice (one `farsight bench nav` per pass: trials side by
    // side, then one at a time, which must not change a track).
    let ns = Namespace::new("benchgraph");
    let (scenario, seconds) = ("obstacle-field-1", "20");
    let methods_and_graphs = bench_methods(&ns);
    let bench = |pass: &str, jobs: &str| {
        let traces = ns.write("placeholder", "").with_file_name(pass);
        let methods: Vec<&str> = methods_and_graphs.iter().map(|(m, _)| m.as_str()).collect();
        let methods = methods.join(",");
        let mut p = Proc::start(
            "farsight",
            &[
                "bench",
                "nav",
                "--trials",
                "1",
                "--methods",
                &methods,
                "--scenarios",
                scenario,
                "--max-time-s",
                seconds,
                "--trace",
                traces.to_str().unwrap(),
                "--out",
                traces.join("results.json").to_str().unwrap(),
                "--jobs",
                jobs,
            ],
            &ns,
        );
        assert_eq!(
            p.wait_exit(Duration::from_secs(240)),
            Some(0),
            "{}",
            p.stderr_so_far()
        );
        traces
    };
    let (first, second) = (bench("bench-a", "3"), bench("bench-b", "1"));
    // The results file: every trial's summary, in the table's order.
    let trials = |dir: &std::path::Path| {
        let text = std::fs::read_to_string(dir.join("results.json")).unwrap();
        serde_json::from_str::<serde_json::Value>(&text).unwrap()["trials"].clone()
    };
    let (a, b) = (trials(&first), trials(&second));
    assert_eq!(
        a.as_array().map(Vec::len),
        Some(methods_and_graphs.len()),
        "one trial per method: {a}"
    );
    assert_eq!(
        a, b,
        "the results of 3 trials side by side and of one at a time"
    );
    let mut parted = Vec::new();
    for (method, graph) in &methods_and_graphs {
        let graph = farsight_tests::repo_root().join(graph);
        let trace = format!("{scenario}-{method}-1.csv");
        let t = poses(&first.join(&trace));
        assert_eq!(
            t,
            poses(&second.join(&trace)),
            "{method}: two benchmark trials, 3 side by side and one at a time"
        );
        assert_eq!(
            t.lines().count(),
            201,
            "{method}: 20 s at 10 Hz and the header"
        );
        for run in ["a", "b"] {
            let out = demo(
                &ns,
                &format!("{method}-{run}"),
                &[
                    "--graph",
                    graph.to_str().unwrap(),
                    "--scenario",
                    scenario,
                    "--max-time-s",
                    seconds,
                ],
            );
            let g = poses(&out.join("poses.csv"));
            // A frame the graph did not answer within the simulator's
            // command timeout is driven without its command: lock-step
            // broke (a stage stalled or restarted), which the trial cannot
            // follow. Said as such, not only as a track that parts.
            let summary = std::fs::read_to_string(out.join("summary.toml")).unwrap();
            let late = field(&summary, "late_commands").to_string();
            if late != "0" {
                parted.push(format!(
                    "{method} run {run}: {late} late commands (lock-step broke)"
                ));
            }
            if let Some((i, (x, y))) = g
                .lines()
                .zip(t.lines())
                .enumerate()
                .find(|(_, (x, y))| x != y)
            {
                parted.push(format!(
                    "{method} run {run}: pose {i}: process {x} vs trial {y} ({late} late commands)"
                ));
            } else if g.lines().count() != t.lines().count() {
                parted.push(format!("{method} run {run}: lengths differ"));
            }
        }
        let last: Vec<f64> = t
            .lines()
            .last()
            .unwrap()
            .split(',')
            .map(|x| x.parse().unwrap())
            .collect();
        eprintln!("{method}: ends at {last:?}");
    }
    assert!(parted.is_empty(), "{parted:#?}");
}

#[test]
fn the_simulator_publishes_every_camera_it_is_asked_for_each_looking_its_own_way() {
    use farsight_interfaces::topics;
    use std::time::Instant;
    let ns = Namespace::new("simcams");
    let bus = ns.bus("simcams-test");
    let front = bus
        .slice_subscriber(&topics::camera_image("front"))
        .unwrap();
    let rear = bus.slice_subscriber(&topics::camera_image("rear")).unwrap();
    let rear_info = bus.subscriber(&topics::camera_info("rear")).unwrap();
    // No graph answers: each frame waits 50 ms for a command, then drives none.
    let (mut sim, _) = small_sim(
        &ns,
        &[
            "--scenario",
            "bug-trap",
            "--cameras",
            "front,rear",
            "--max-time-s",
            "1",
            "--command-timeout-s",
            "0.05",
        ],
    );
    let (mut f, mut r, mut info) = (None, None, None);
    let end = Instant::now() + Duration::from_secs(20);
    while Instant::now() < end && (f.is_none() || r.is_none() || info.is_none()) {
        if let Some(s) = front.latest().unwrap() {
            f = Some((*s.header(), s.data().to_vec()));
        }
        if let Some(s) = rear.latest().unwrap() {
            r = Some((*s.header(), s.data().to_vec()));
        }
        if let Some(i) = rear_info.latest().unwrap() {
            info = Some(i);
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    assert_eq!(
        sim.wait_exit(Duration::from_secs(20)),
        Some(0),
        "{}",
        sim.stderr_so_far()
    );
    let ((fh, fd), (rh, rd)) = (f.expect("a front frame"), r.expect("a rear frame"));
    assert_eq!((rh.width, rh.height, rh.camera_id), (160, 90, 3));
    assert_eq!(fh.camera_id, 0);
    // bug-trap: the wall is 35 m ahead, open grass behind; the views differ.
    assert_ne!(fd, rd);
    let cam = farsight_interfaces::camera::Camera::from_info(&info.expect("rear info")).unwrap();
    let bearing = cam.pixel_bearing_rad(cam.model.cx, cam.model.cy).unwrap();
    assert!(
        (bearing.abs() - std::f64::consts::PI).abs() < 1e-6,
        "{bearing}"
    );
}

/// The simulated robot is a base like a real one: it holds the last command
/// for that command's time-to-live from receipt, then stops, so a command
/// writer that dies stops the robot. Lock-step, so it is decided on the
/// simulated clock alone: the test answers only every 4th frame with a
/// 0.8 s time-to-live (8 frames), then falls silent like a killed servo.
#[test]
fn the_simulated_base_obeys_a_command_for_its_ttl_then_stops() {
    use farsight_interfaces::msg::{CommandReason, Stamp, VelocityCommand};
    use farsight_interfaces::topics;
    use std::time::Instant;
    let ns = Namespace::new("basettl");
    let bus = ns.bus("basettl-test");
    let pose_sub = bus.subscriber(&topics::pose()).unwrap();
    let commands = bus.publisher(&topics::velocity_command()).unwrap();
    // bush-wall: open ground for the first 40 m ahead of the start. Each
    // frame waits up to 0.5 s for the test's answer; the unanswered ones
    // cost that, hence a short run.
    let (mut sim, out) = small_sim(
        &ns,
        &[
            "--scenario",
            "bush-wall",
            "--max-time-s",
            "4",
            "--command-timeout-s",
            "0.5",
        ],
    );
    const LAST_ANSWERED: u64 = 21;
    let mut answered = Vec::new();
    let end = Instant::now() + Duration::from_secs(120);
    let code = loop {
        if let Some(code) = sim.wait_exit(Duration::ZERO) {
            break code;
        }
        assert!(Instant::now() < end, "{}", sim.stderr_so_far());
        if let Some(p) = pose_sub.latest().unwrap() {
            let k = p.stamp.frame_seq;
            if k % 4 == 1 && k <= LAST_ANSWERED {
                commands
                    .publish(&VelocityCommand {
                        stamp: Stamp::new(k, p.stamp.capture_time_ns),
                        linear_mps: 0.5,
                        angular_radps: 0.0,
                        reason: CommandReason::TELEOP,
                        ttl_ms: 800,
                    })
                    .unwrap();
                answered.push(k);
            }
        }
        std::thread::sleep(Duration::from_millis(1));
    };
    assert_eq!(code, 0, "{}", sim.stderr_so_far());
    assert_eq!(answered, vec![1, 5, 9, 13, 17, 21]);
    // x along the track, one row per frame (t = 0.1 s * frame).
    let xs: Vec<f64> = poses(&out.join("poses.csv"))
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(1).unwrap().parse().unwrap())
        .collect();
    assert!(xs.len() >= 40, "4 s at 10 Hz: {} poses", xs.len());
    // Every answer was taken in time: the premise of what follows.
    let summary = std::fs::read_to_string(out.join("summary.toml")).unwrap();
    assert_eq!(
        field(&summary, "late_commands"),
        (xs.len() - answered.len()).to_string(),
        "{summary}"
    );
    let at = |frame: u64| xs[frame as usize - 1];
    // Held between answers, the robot drove on at 0.5 m/s: about 0.9 m by
    // frame 21. Had the base stopped on every unanswered frame, it would
    // have crept (one frame of acceleration in four, about 0.1 m).
    let driven = at(LAST_ANSWERED) - at(1);
    assert!(driven > 0.6, "drove {driven:.2} m on held commands");
    // Silent after frame 21: 0.8 s more at 0.5 m/s and then braking, then
    // standing still for the rest of the run.
    let coasted = xs[xs.len() - 1] - at(LAST_ANSWERED);
    assert!(
        (0.25..0.6).contains(&coasted),
        "moved {coasted:.2} m after the last command"
    );
    let tail = &xs[33..];
    assert!(
        tail.iter().all(|&x| x == tail[0]),
        "stopped once the last command expired: {tail:?}"
    );
}
