//! `farsight foxglove` live, against an independent client: the demo runs a
//! simulated graph on the wall clock with its Foxglove server, and the
//! official npm `@foxglove/ws-protocol` client (`tests/foxglove/client.mjs`,
//! installed pinned by `cargo xtask test`) subscribes to every channel the
//! server advertises, decodes each message with the schema the channel
//! advertised and validates it against the official `@foxglove/schemas`
//! JSON schemas. Issue 19's "what must be shown": the client's per-channel
//! table (messages, schema-valid, rate) and the bytes per second the
//! laptop receives with the default throttles, printed by each run.
//!
//! Paced on counts: the client stops once each required topic has brought
//! its messages, whatever the machine's speed; the demo is stopped after.

use farsight_tests::{free_port, toml_string, Namespace, Proc};
use serde_json::Value;
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// Messages of each required topic the client waits for.
const MESSAGES: u64 = 3;

/// Runs `farsight demo --method METHOD --realtime --foxglove-port P` and the
/// client against it until each of `require` has [`MESSAGES`] messages;
/// returns the client's report (see `tests/foxglove/client.mjs`).
fn live_demo(ns: &Namespace, method: &str, require: &[&str]) -> Value {
    assert!(
        Path::new("foxglove/node_modules/@foxglove/ws-protocol").exists(),
        "the Node.js test client is not installed: run `cargo xtask setup` (npm ci in tests/foxglove)"
    );
    let port = free_port();
    let out = ns.root.join(method);
    let mut demo = Proc::start(
        "farsight",
        &[
            "demo",
            "--method",
            method,
            "--realtime",
            "--max-time-s",
            "600",
            "--foxglove-port",
            &port.to_string(),
            "--out",
            out.to_str().unwrap(),
        ],
        ns,
    );
    let url = demo
        .wait_line(Duration::from_secs(180), |l| {
            l.starts_with("foxglove: ws://")
        })
        .unwrap_or_else(|| panic!("{method}: no foxglove server\n{}", demo.stderr_so_far()));
    assert!(
        url.1.contains(&format!("ws://127.0.0.1:{port} ")),
        "{}",
        url.1
    );
    let url = format!("ws://127.0.0.1:{port}");
    let (messages, timeout) = (MESSAGES.to_string(), "300");
    let report = node_script(
        ns,
        &format!("{method}: the Foxglove client"),
        "client.mjs",
        &[
            &url,
            "--until-messages",
            &messages,
            "--require",
            &require.join(","),
            "--timeout-s",
            timeout,
        ],
    )
    .unwrap_or_else(|why| {
        panic!(
            "{method}: the client did not get {MESSAGES} messages of each of {require:?}: {why}\ndemo:\n{}",
            demo.stderr_so_far()
        )
    });
    demo.kill();
    report
}

/// Runs `node tests/foxglove/SCRIPT ARGS --report FILE` and prints its
/// table under `what`; its report, or why it failed (exit status, output).
fn node_script(ns: &Namespace, what: &str, script: &str, args: &[&str]) -> Result<Value, String> {
    run_script(
        "node",
        "Node.js is on every machine of this project",
        ns,
        what,
        script,
        args,
    )
}

/// `PROGRAM tests/foxglove/SCRIPT ARGS --report FILE` (`missing` says how to
/// get PROGRAM), its table printed under `what`: its report, or why it
/// failed (exit status, output).
fn run_script(
    program: &str,
    missing: &str,
    ns: &Namespace,
    what: &str,
    script: &str,
    args: &[&str],
) -> Result<Value, String> {
    let report = ns.root.join(format!("{}.json", script.replace('.', "-")));
    let _ = std::fs::remove_file(&report);
    let run = Command::new(program)
        .arg(Path::new("foxglove").join(script))
        .args(args)
        .arg("--report")
        .arg(&report)
        .output()
        .map_err(|e| format!("running {program} ({missing}): {e}"))?;
    let table = String::from_utf8_lossy(&run.stdout);
    eprintln!("{what}:\n{table}");
    if !run.status.success() {
        return Err(format!(
            "{} ({}):\n{table}\n{}",
            script,
            run.status,
            String::from_utf8_lossy(&run.stderr)
        ));
    }
    let text =
        std::fs::read_to_string(&report).map_err(|e| format!("{}: {e}", report.display()))?;
    serde_json::from_str(&text).map_err(|e| format!("{}: {e}", report.display()))
}

/// Every channel's messages decoded and schema-valid, and the server
/// offers nothing to publish (read-only on the robot).
fn assert_valid(method: &str, report: &Value) {
    let caps = report["capabilities"].as_array().unwrap();
    assert!(
        !caps.iter().any(|c| c == "clientPublish"),
        "{method}: the robot's server must be read-only: {caps:?}"
    );
    for (topic, ch) in report["channels"].as_object().unwrap() {
        assert_eq!(
            ch["messages"], ch["valid"],
            "{method} {topic}: {}",
            ch["first_error"]
        );
        assert!(ch["first_error"].is_null(), "{method} {topic}: {ch}");
    }
}

/// Every topic the shipped layout names: strings (keys or values) that
/// start with '/', up to a message path's first '.'; apart, the topics its
/// panels publish on (Teleop's `topic`, Publish's `topicName`, the 3-D
/// panel's publish tools).
fn layout_topics() -> (BTreeSet<String>, BTreeSet<String>) {
    const PUBLISHED: [&str; 5] = [
        "topic",
        "topicName",
        "poseTopic",
        "pointTopic",
        "poseEstimateTopic",
    ];
    fn take(s: &str, out: &mut BTreeSet<String>) {
        if let Some(rest) = s.strip_prefix('/') {
            let topic = rest.split('.').next().unwrap_or("");
            out.insert(format!("/{topic}"));
        }
    }
    fn walk(v: &Value, shown: &mut BTreeSet<String>, published: &mut BTreeSet<String>) {
        match v {
            Value::String(s) => take(s, shown),
            Value::Array(a) => a.iter().for_each(|x| walk(x, shown, published)),
            Value::Object(o) => {
                for (k, x) in o {
                    take(k, shown);
                    match x {
                        Value::String(s) if PUBLISHED.contains(&k.as_str()) => take(s, published),
                        _ => walk(x, shown, published),
                    }
                }
            }
            _ => {}
        }
    }
    let text = std::fs::read_to_string("../deploy/foxglove/farsight-layout.json").unwrap();
    let (mut shown, mut published) = (BTreeSet::new(), BTreeSet::new());
    walk(
        &serde_json::from_str(&text).unwrap(),
        &mut shown,
        &mut published,
    );
    (shown, published)
}

#[test]
fn the_official_client_validates_every_live_channel_and_the_layout_finds_its_topics() {
    let ns = Namespace::new("foxlive");
    // POVNav: the camera with its overlay and the visual path on the
    // ground; LRN bins + D* Lite: the bins, the costmap and the planned path.
    let povnav = live_demo(
        &ns,
        "povnav",
        &[
            "/camera/front/image",
            "/camera/front/calibration",
            "/camera/front/annotations",
            "/perception/front/navigability",
            "/nav/path/visual",
            "/nav/subgoal",
            "/nav/goal",
            "/state/pose",
            "/tf",
            "/cmd/velocity",
            "/health/velocity-servoing",
        ],
    );
    assert_valid("povnav", &povnav);
    let lrn_dstar = live_demo(
        &ns,
        "lrn-dstar",
        &[
            "/camera/front/image",
            "/perception/front/heatmap",
            "/bins/angular",
            "/costmap/fused",
            "/nav/path/planned",
            "/state/pose",
            "/cmd/velocity",
        ],
    );
    assert_valid("lrn-dstar", &lrn_dstar);

    // The camera fits a 10 Mbit/s link: JPEG, downscaled, at least 320 px.
    let image = &povnav["channels"]["/camera/front/image"];
    assert_eq!(image["schema"], "foxglove.CompressedImage", "{image}");
    assert_eq!(image["last"]["format"], "jpeg", "{image}");
    let calibration = &povnav["channels"]["/camera/front/calibration"]["last"];
    let width = calibration["width"].as_u64().unwrap();
    assert!((320..=640).contains(&width), "{calibration}");
    assert_eq!(
        calibration["frame_id"], image["last"]["frame_id"],
        "the image and its calibration share the optical frame"
    );
    // The visual path lies on the ground in base_link, in metres, not pixels.
    let path = &povnav["channels"]["/nav/path/visual"]["last"];
    assert_eq!(path["frame_id"], "base_link", "{path}");
    for pose in path["poses"].as_array().unwrap() {
        let p = &pose["position"];
        let (x, y, z) = (
            p["x"].as_f64().unwrap(),
            p["y"].as_f64().unwrap(),
            p["z"].as_f64().unwrap(),
        );
        assert!(x > 0.0 && x < 60.0 && y.abs() < 60.0 && z == 0.0, "{path}");
    }
    for (method, report) in [("povnav", &povnav), ("lrn-dstar", &lrn_dstar)] {
        let rate = report["bytes_per_s"].as_f64().unwrap();
        eprintln!(
            "{method}: the laptop receives {:.1} kB/s with the default throttles",
            rate / 1e3
        );
        assert!(rate < 1.25e6, "{method}: {rate} B/s does not fit 10 Mbit/s");
    }

    // The shipped layout names only topics these graphs advertise.
    let advertised: BTreeSet<String> = [&povnav, &lrn_dstar]
        .iter()
        .flat_map(|r| r["channels"].as_object().unwrap().keys().cloned())
        .collect();
    let (shown, published) = layout_topics();
    let missing: Vec<_> = shown.difference(&advertised).cloned().collect();
    assert!(
        missing.is_empty(),
        "deploy/foxglove/farsight-layout.json names {missing:?}, never advertised (advertised: {advertised:?})"
    );
    // What its panels publish, the laptop's server takes from the operator.
    let accepted: BTreeSet<String> = farsight_foxglove::operator::ACCEPTED_TOPICS
        .iter()
        .map(|t| t.to_string())
        .collect();
    assert_eq!(
        published, accepted,
        "the layout's publishing panels and the operator's topics"
    );
}

#[test]
fn the_demo_recording_holds_the_live_channels_and_the_official_mcap_reader_validates_them() {
    // The lock-step demo records every topic with `farsight record`, whose
    // Foxglove channels are on by default. Two independent readers decode
    // and validate each one against the official Foxglove schemas and check
    // every frame id against /tf: the @mcap/core reader
    // (tests/foxglove/mcap.mjs) and the Python `mcap` package's
    // (tests/foxglove/mcap_check.py); both pass and count the same.
    let ns = Namespace::new("foxrec");
    let out = ns.root.join("demo");
    let mut demo = Proc::start(
        "farsight",
        &[
            "demo",
            "--method",
            "povnav",
            "--max-time-s",
            "10",
            "--out",
            out.to_str().unwrap(),
        ],
        &ns,
    );
    assert_eq!(
        demo.wait_exit(Duration::from_secs(240)),
        Some(0),
        "{}",
        demo.stderr_so_far()
    );
    let recording = out.join("recording.mcap");
    let report = node_script(
        &ns,
        "the demo's recording, read by @mcap/core",
        "mcap.mjs",
        &[recording.to_str().unwrap()],
    )
    .unwrap_or_else(|why| panic!("{why}"));
    let python = python_script(
        &ns,
        "the demo's recording, read by the Python mcap package",
        "mcap_check.py",
        &[recording.to_str().unwrap()],
    )
    .unwrap_or_else(|why| panic!("{why}"));
    assert_same_reading(&report, &python);
    assert!(
        report["farsight_messages"].as_u64().unwrap() > 100,
        "the lossless copy stays"
    );
    let channels = report["channels"].as_object().unwrap();
    for topic in [
        "/camera/front/image",
        "/camera/front/calibration",
        "/perception/front/navigability",
        "/nav/path/visual",
        "/state/pose",
        "/tf",
        "/cmd/velocity",
        "/health/velocity-servoing",
    ] {
        let n = channels
            .get(topic)
            .map_or(0, |c| c["messages"].as_u64().unwrap());
        assert!(n > 0, "{topic}: {n} messages (the table above)");
    }
    // The same images the live server sends: JPEG, at most 640 px wide.
    let image = &channels["/camera/front/image"]["last"];
    assert_eq!(image["format"], "jpeg", "{image}");
    assert_eq!(
        channels["/camera/front/calibration"]["last"]["width"], 640,
        "{}",
        channels["/camera/front/calibration"]
    );
    let frames: Vec<&str> = report["frames_used"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f.as_str().unwrap())
        .collect();
    assert!(frames.contains(&"camera_front_optical_frame"), "{frames:?}");

    // Both readers refuse a copy with one image that breaks its schema
    // (an empty message: no timestamp) and no /tf.
    let spoiled = ns.root.join("spoiled.mcap");
    spoiled_copy(&recording, &spoiled);
    let spoiled = spoiled.to_str().unwrap();
    let node = node_script(&ns, "the spoiled copy, @mcap/core", "mcap.mjs", &[spoiled]);
    let python = python_script(&ns, "the spoiled copy, Python", "mcap_check.py", &[spoiled]);
    for (reader, result) in [("@mcap/core", node), ("python", python)] {
        let why = result.expect_err(&format!("{reader} passed the spoiled copy"));
        assert!(
            why.contains("without a transform: base_link, camera_front_optical_frame, map"),
            "{reader}: {why}"
        );
        let image = why
            .lines()
            .skip_while(|l| !l.starts_with("/camera/front/image "))
            .nth(1)
            .unwrap_or_default();
        assert!(image.contains("first error: "), "{reader}: {why}");
    }
}

/// Copies the recording at `from` to `to` without its /tf messages and with
/// the first /camera/front/image message emptied (protobuf decodes it as
/// all defaults: no timestamp, which the schema requires).
fn spoiled_copy(from: &Path, to: &Path) {
    let bytes = std::fs::read(from).unwrap();
    let mut w =
        mcap::Writer::new(std::io::BufWriter::new(std::fs::File::create(to).unwrap())).unwrap();
    let mut emptied = false;
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let mut m = m.unwrap();
        match m.channel.topic.as_str() {
            "/tf" => continue,
            "/camera/front/image" if !emptied => {
                m.data = Vec::new().into();
                emptied = true;
            }
            _ => {}
        }
        w.write(&m).unwrap();
    }
    w.finish().unwrap();
}

/// The Python reader's interpreter: the virtual environment `cargo xtask
/// setup` makes from the pinned `tests/foxglove/requirements.txt`.
const PYTHON: &str = "foxglove/.venv/bin/python";

/// Runs `tests/foxglove/.venv/bin/python tests/foxglove/SCRIPT ARGS --report
/// FILE` and prints its table under `what`; its report, or why it failed
/// (not installed, exit status, output).
fn python_script(ns: &Namespace, what: &str, script: &str, args: &[&str]) -> Result<Value, String> {
    const INSTALL: &str = "a virtual environment from tests/foxglove/requirements.txt: \
                           run `cargo xtask setup`";
    if !Path::new(PYTHON).exists() {
        return Err(format!(
            "the Python test reader is not installed (no tests/{PYTHON}): {INSTALL}"
        ));
    }
    run_script(PYTHON, INSTALL, ns, what, script, args)
}

/// The two readers of one recording agree: the same Foxglove channels with
/// the same schema, message, valid and byte counts, the same count of
/// farsight's own messages and the same frame ids, each with a transform.
fn assert_same_reading(node: &Value, python: &Value) {
    assert_eq!(python["complete"], true, "{}", python["read_error"]);
    assert_eq!(
        node["farsight_messages"], python["farsight_messages"],
        "farsight's own messages"
    );
    let (a, b) = (
        node["channels"].as_object().unwrap(),
        python["channels"].as_object().unwrap(),
    );
    let topics = |m: &serde_json::Map<String, Value>| m.keys().cloned().collect::<Vec<_>>();
    assert_eq!(topics(a), topics(b), "the Foxglove channels");
    for (topic, n) in a {
        let p = &b[topic];
        for key in ["schema", "encoding", "messages", "valid", "bytes"] {
            assert_eq!(n[key], p[key], "{topic} {key}: @mcap/core {n}\npython {p}");
        }
        assert_eq!(p["messages"], p["valid"], "{topic}: {}", p["first_error"]);
    }
    assert_eq!(node["frames_used"], python["frames_used"], "frame ids used");
    assert_eq!(
        python["frames_without_transform"],
        Value::Array(vec![]),
        "frame ids without a transform"
    );
}

#[test]
fn the_orfd_replay_watched_from_a_laptop_is_schema_valid_and_fits_the_link() {
    // `farsight demo --orfd` (the six real ORFD frames, camera-ingest ->
    // TwinLiteNet -> POVNav -> servo) with its Foxglove server on the
    // laptop's path: `farsight foxglove --connect` reading the graph's
    // bridge over zenoh. Played in a loop (`--loops 0`) until the official
    // client has its messages, then stopped with SIGTERM, as Ctrl-C does.
    assert!(
        Path::new("foxglove/node_modules/@foxglove/ws-protocol").exists(),
        "the Node.js test client is not installed: run `cargo xtask setup` (npm ci in tests/foxglove)"
    );
    let ns = Namespace::new("foxorfd");
    let port = free_port();
    let out = ns.root.join("orfd");
    let mut demo = Proc::start(
        "farsight",
        &[
            "demo",
            "--orfd",
            "--loops",
            "0",
            "--foxglove-port",
            &port.to_string(),
            "--out",
            out.to_str().unwrap(),
        ],
        &ns,
    );
    let line = demo
        .wait_line(Duration::from_secs(240), |l| {
            l.starts_with("foxglove: ws://")
        })
        .unwrap_or_else(|| panic!("orfd: no foxglove server\n{}", demo.stderr_so_far()));
    assert!(
        line.1.contains(&format!("ws://127.0.0.1:{port} ")),
        "{}",
        line.1
    );
    let url = format!("ws://127.0.0.1:{port}");
    let require = [
        "/camera/front/image",
        "/camera/front/calibration",
        "/perception/front/navigability",
        "/cmd/velocity",
        "/health/camera-ingest",
    ];
    let messages = MESSAGES.to_string();
    let report = node_script(
        &ns,
        "orfd: the Foxglove client on the laptop's server",
        "client.mjs",
        &[
            &url,
            "--until-messages",
            &messages,
            "--require",
            &require.join(","),
            "--timeout-s",
            "300",
        ],
    )
    .unwrap_or_else(|why| {
        panic!(
            "orfd: the client did not get {MESSAGES} messages of each of {require:?}: {why}\ndemo:\n{}\n{}",
            demo.stderr_so_far(),
            stage_logs(&out)
        )
    });
    assert_eq!(
        demo.terminate(Duration::from_secs(60)),
        Some(0),
        "the demo stops cleanly on SIGTERM\n{}",
        demo.stderr_so_far()
    );
    let summary = std::fs::read_to_string(out.join("summary.txt")).unwrap();
    eprintln!("orfd: the demo's summary:\n{summary}");
    assert!(summary.contains("stopped by a signal"), "{summary}");
    assert!(
        std::fs::read_to_string(out.join("foxglove-report.txt"))
            .unwrap()
            .contains("/camera/front/image"),
        "the laptop server's closing report"
    );

    // Every channel decoded and schema-valid. (The laptop's server may
    // offer clientPublish: it takes the operator's commands to the robot.)
    for (topic, ch) in report["channels"].as_object().unwrap() {
        assert_eq!(
            ch["messages"], ch["valid"],
            "orfd {topic}: {}",
            ch["first_error"]
        );
        assert!(ch["first_error"].is_null(), "orfd {topic}: {ch}");
    }
    let image = &report["channels"]["/camera/front/image"];
    assert_eq!(image["schema"], "foxglove.CompressedImage", "{image}");
    assert_eq!(image["last"]["format"], "jpeg", "{image}");
    let rate = report["bytes_per_s"].as_f64().unwrap();
    eprintln!(
        "orfd: the laptop receives {:.1} kB/s with the default throttles",
        rate / 1e3
    );
    assert!(rate < 1.25e6, "orfd: {rate} B/s does not fit 10 Mbit/s");
}

/// `node tests/foxglove/publish.mjs URL ARGS --report F`, started and left
/// running (the caller stops it once the robot has seen enough).
fn start_publisher(ns: &Namespace, name: &str, url: &str, args: &[&str]) -> (Child, PathBuf) {
    let report = ns.root.join(format!("publish-{name}.json"));
    let child = Command::new("node")
        .arg(Path::new("foxglove").join("publish.mjs"))
        .arg(url)
        .args(args)
        .args(["--timeout-s", "300", "--report"])
        .arg(&report)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("running node (Node.js is on every machine of this project)");
    (child, report)
}

/// Stops a publisher (SIGTERM: it writes its report) and returns the report.
fn stop_publisher((child, report): (Child, PathBuf)) -> Value {
    // SAFETY: kill(2) on our own child's pid.
    unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
    let out = child.wait_with_output().unwrap();
    let text = std::fs::read_to_string(&report).unwrap_or_else(|e| {
        panic!(
            "{}: {e}\n{}{}",
            report.display(),
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        )
    });
    serde_json::from_str(&text).unwrap()
}

/// Polls `what` until it holds (the robot's answer), up to 120 s.
fn until<T>(what: &str, mut f: impl FnMut() -> Option<T>) -> T {
    let end = Instant::now() + Duration::from_secs(120);
    loop {
        if let Some(v) = f() {
            return v;
        }
        assert!(Instant::now() < end, "{what}: not seen in 120 s");
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// `farsight foxglove` on a laptop, reading the robot's bridge through the
/// shipped router (laptops read, only the operator commands), logged in as
/// `user`; once it said it is ready, with `mode` in its ready line.
/// The last lines of each stage's log in a `farsight run` output folder,
/// for a failure message: which stage stalled or refused what.
fn stage_logs(out: &Path) -> String {
    let mut logs: Vec<_> = std::fs::read_dir(out)
        .map(|d| d.flatten().map(|e| e.path()).collect())
        .unwrap_or_default();
    logs.retain(|p| p.extension().is_some_and(|e| e == "log"));
    logs.sort();
    let mut text = String::new();
    for p in logs {
        let body = std::fs::read_to_string(&p).unwrap_or_default();
        let lines: Vec<&str> = body.lines().collect();
        let tail = lines[lines.len().saturating_sub(40)..].join("\n");
        text += &format!("--- {} (last 40 lines)\n{tail}\n", p.display());
    }
    text
}

fn laptop_server(ns: &Namespace, endpoint: &str, user: &str, mode: &str) -> (Proc, String) {
    let port = free_port().to_string();
    let password = format!("{user}-secret");
    let args = [
        "foxglove",
        "--connect",
        endpoint,
        "--robot",
        "robot",
        "--port",
        &port,
        "--user",
        user,
    ];
    let p = Proc::start_env(
        "farsight",
        &args,
        ns,
        &[("FARSIGHT_ZENOH_PASSWORD", password.as_str())],
    );
    let ready = p
        .wait_line(Duration::from_secs(60), |l| {
            l.starts_with("farsight-foxglove ready")
        })
        .unwrap_or_else(|| panic!("{user}: no server\n{}", p.stderr_so_far()));
    assert!(ready.1.contains(mode), "{user}: {}", ready.1);
    (p, format!("ws://127.0.0.1:{port}"))
}

#[test]
fn the_apps_goal_teleop_and_estop_reach_the_robot_only_from_the_operator() {
    use farsight_interfaces::msg::CommandReason;
    use farsight_interfaces::topics;
    assert!(
        Path::new("foxglove/node_modules/@foxglove/ws-protocol").exists(),
        "the Node.js test client is not installed: run `cargo xtask setup` (npm ci in tests/foxglove)"
    );
    let ns = Namespace::new("foxop");
    let port = free_port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    // The robot: the bridge behind the shipped router, importing the
    // operator's keys, and the command mux (teleop over autonomy).
    let router = ns.shipped_router(&endpoint);
    let bridge = ns.write(
        "bridge.toml",
        &format!(
            "robot = \"robot\"\n[zenoh]\nconfig_file = {}\n\
             [[export]]\ntopic = \"health/command-mux\"\n\
             [[import]]\ntopic = \"nav/goal\"\n[[import]]\ntopic = \"safety/estop\"\n\
             [[import]]\ntopic = \"cmd/teleop\"\n",
            toml_string(router.to_str().unwrap())
        ),
    );
    let _bridge = ns.start_bridge(&bridge);
    let _mux = ns.start_stage(
        "farsight-command-mux",
        "command-mux",
        &ns.write("command-mux.toml", ""),
    );
    let bus = ns.bus("foxop-test");
    let goals = bus.subscriber(&topics::goal()).unwrap();
    let commands = bus.subscriber(&topics::velocity_command()).unwrap();
    let goal = |x: f64| {
        format!(
            r#"{{"header":{{"stamp":{{"sec":0,"nsec":0}},"frame_id":"map"}},"pose":{{"position":{{"x":{x},"y":-3,"z":0}},"orientation":{{"x":0,"y":0,"z":0,"w":1}}}}}}"#
        )
    };
    let twist = r#"{"linear":{"x":0.4,"y":0,"z":0},"angular":{"x":0,"y":0,"z":-0.25}}"#;
    let goal_11 = goal(11.0);
    let goal_22 = goal(22.5);

    // A laptop login: the app may publish (the server offers it, so the
    // app's tools work), but each topic is refused with a status the app
    // shows, and nothing is put on zenoh.
    let (mut server, url) = laptop_server(&ns, &endpoint, "laptop", "commands refused");
    let (code, report) = {
        let out = Command::new("node")
            .arg(Path::new("foxglove").join("publish.mjs"))
            .arg(&url)
            .args([
                "--publish",
                "/nav/goal",
                "geometry_msgs/PoseStamped",
                &goal_11,
            ])
            .args(["--publish", "/cmd/teleop", "geometry_msgs/Twist", twist])
            .args([
                "--publish",
                "/safety/estop",
                "farsight/EStop",
                r#"{"active":"pressed"}"#,
            ])
            .args(["--until-statuses", "3", "--timeout-s", "120"])
            .output()
            .unwrap();
        (
            out.status.code(),
            String::from_utf8_lossy(&out.stdout).to_string(),
        )
    };
    assert_eq!(
        code,
        Some(0),
        "the laptop's refusals:\n{report}\n{}",
        server.stderr_so_far()
    );
    for topic in ["/nav/goal", "/cmd/teleop", "/safety/estop"] {
        assert!(
            report.contains(&format!(
                "farsight refused {topic}: zenoh user \"laptop\" may not command"
            )),
            "{topic}: {report}"
        );
    }
    assert_eq!(server.terminate(Duration::from_secs(20)), Some(0));
    let closing: Vec<String> = std::iter::from_fn(|| {
        server
            .wait_line(Duration::from_millis(100), |_| true)
            .map(|(_, l)| l)
    })
    .collect();
    for topic in ["/nav/goal", "/cmd/teleop", "/safety/estop"] {
        assert!(
            closing
                .iter()
                .any(|l| l.starts_with(topic) && l.contains(" 0 from the app sent to the robot")),
            "{topic}: {closing:?}"
        );
    }
    assert!(goals.latest().unwrap().is_none(), "a laptop's goal arrived");

    // The operator: the goal reaches the planner's topic, teleop wins the mux.
    let (_server, url) = laptop_server(
        &ns,
        &endpoint,
        "operator",
        "operator: goals, e-stop, teleop",
    );
    let driving = start_publisher(
        &ns,
        "drive",
        &url,
        &[
            "--publish",
            "/nav/goal",
            "geometry_msgs/PoseStamped",
            &goal_22,
            "--publish",
            "/cmd/teleop",
            "geometry_msgs/Twist",
            twist,
        ],
    );
    let g = until("the operator's goal on nav/goal", || {
        goals.latest().unwrap()
    });
    assert_eq!((g.x_m, g.y_m), (22.5, -3.0), "{g:?}");
    let c = until("the operator's teleop on cmd/velocity", || {
        commands
            .latest()
            .unwrap()
            .filter(|c| c.reason == CommandReason::TELEOP)
    });
    assert_eq!((c.linear_mps, c.angular_radps), (0.4, -0.25), "{c:?}");
    let report = stop_publisher(driving);
    assert!(
        report["statuses"].as_array().unwrap().is_empty(),
        "the operator's messages were refused: {report}"
    );
    assert!(report["capabilities"]
        .as_array()
        .unwrap()
        .iter()
        .any(|c| c == "clientPublish"));

    // The app's e-stop latches the mux while teleop keeps coming; the
    // operator's clear lets teleop through again.
    let pressed = start_publisher(
        &ns,
        "estop",
        &url,
        &[
            "--publish",
            "/safety/estop",
            "farsight/EStop",
            r#"{"active":"pressed"}"#,
            "--publish",
            "/cmd/teleop",
            "geometry_msgs/Twist",
            twist,
        ],
    );
    let c = until("the app's e-stop on cmd/velocity", || {
        commands
            .latest()
            .unwrap()
            .filter(|c| c.reason == CommandReason::ESTOP)
    });
    assert_eq!((c.linear_mps, c.angular_radps), (0.0, 0.0), "{c:?}");
    stop_publisher(pressed);
    let cleared = start_publisher(
        &ns,
        "clear",
        &url,
        &[
            "--publish",
            "/safety/estop",
            "farsight/EStop",
            r#"{"active":"clear"}"#,
            "--publish",
            "/cmd/teleop",
            "geometry_msgs/Twist",
            twist,
        ],
    );
    until("teleop after the operator's clear", || {
        commands
            .latest()
            .unwrap()
            .filter(|c| c.reason == CommandReason::TELEOP)
    });
    stop_publisher(cleared);
}
