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

use farsight_tests::{free_port, Namespace, Proc};
use serde_json::Value;
use std::collections::BTreeSet;
use std::path::Path;
use std::process::Command;
use std::time::Duration;

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
    let report = ns.root.join(format!("{}.json", script.replace('.', "-")));
    let _ = std::fs::remove_file(&report);
    let run = Command::new("node")
        .arg(Path::new("foxglove").join(script))
        .args(args)
        .arg("--report")
        .arg(&report)
        .output()
        .map_err(|e| format!("running node (Node.js is on every machine of this project): {e}"))?;
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
/// start with '/', up to a message path's first '.'.
fn layout_topics() -> BTreeSet<String> {
    fn take(s: &str, out: &mut BTreeSet<String>) {
        if let Some(rest) = s.strip_prefix('/') {
            let topic = rest.split('.').next().unwrap_or("");
            out.insert(format!("/{topic}"));
        }
    }
    fn walk(v: &Value, out: &mut BTreeSet<String>) {
        match v {
            Value::String(s) => take(s, out),
            Value::Array(a) => a.iter().for_each(|x| walk(x, out)),
            Value::Object(o) => {
                for (k, x) in o {
                    take(k, out);
                    walk(x, out);
                }
            }
            _ => {}
        }
    }
    let text = std::fs::read_to_string("../deploy/foxglove/farsight-layout.json").unwrap();
    let mut topics = BTreeSet::new();
    walk(&serde_json::from_str(&text).unwrap(), &mut topics);
    topics
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
    let missing: Vec<_> = layout_topics().difference(&advertised).cloned().collect();
    assert!(
        missing.is_empty(),
        "deploy/foxglove/farsight-layout.json names {missing:?}, never advertised (advertised: {advertised:?})"
    );
}

#[test]
fn the_demo_recording_holds_the_live_channels_and_the_official_mcap_reader_validates_them() {
    // The lock-step demo records every topic with `farsight record`, whose
    // Foxglove channels are on by default; the @mcap/core reader
    // (tests/foxglove/mcap.mjs) decodes and validates each one and checks
    // every frame id against /tf.
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
}
