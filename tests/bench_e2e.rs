//! `farsight bench e2e` runs a chain's graph as real processes (the ORFD
//! POVNav graph; the simulator's FITAM graph) and times each frame from
//! ingest to every topic on its path: the table must hold every hop,
//! latencies that grow along the path, and each stage's memory. Paced by
//! the frames themselves (camera-ingest waits for each navigability image;
//! the simulator waits for each command), so a busy machine gives fewer
//! frames, not a failure; only the presence and order of figures are
//! checked.

use farsight_tests::{bin, repo_root};

/// Runs `farsight bench e2e` with a short warm-up and measurement, the
/// chain's own `args` before them; returns its stdout, once it succeeded.
fn bench_e2e(name: &str, args: &[&str], seconds: &str) -> String {
    let out_dir = std::env::temp_dir().join(format!("farsight-{name}-{}", std::process::id()));
    let out = std::process::Command::new(bin("farsight"))
        .current_dir(repo_root())
        .args(["bench", "e2e"])
        .args(args)
        .args([
            "--seconds",
            seconds,
            "--warm-up-s",
            "1",
            "--inference-runs",
            "2",
            "--out",
        ])
        .arg(&out_dir)
        .output()
        .expect("farsight bench e2e runs");
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stdout}\n{stderr}");
    let _ = std::fs::remove_dir_all(&out_dir);
    stdout
}

/// The cells of the report's table row that starts with `key`.
fn table_row<'a>(stdout: &'a str, key: &str) -> Vec<&'a str> {
    let row = stdout
        .lines()
        .find(|l| l.starts_with(&format!("| {key} |")))
        .unwrap_or_else(|| panic!("no row for {key}:\n{stdout}"));
    row.split('|').map(str::trim).collect()
}

#[test]
fn the_e2e_bench_times_every_hop_from_capture_to_command() {
    let stdout = bench_e2e("e2e", &[], "4");
    let median = |topic: &str| -> f64 {
        let cells = table_row(&stdout, topic);
        assert!(cells[3].parse::<usize>().unwrap() > 0, "{cells:?}");
        cells[4].parse().unwrap()
    };
    let path = [
        median("camera/front/image"),
        median("perception/front/navigability"),
        median("nav/subgoal"),
        median("cmd/velocity"),
    ];
    assert!(path.iter().all(|ms| *ms >= 0.0), "{path:?}\n{stdout}");
    // Each hop, over the frames seen at both its ends, takes time forward.
    // The rows above are over different frames (on a busy machine the
    // subgoal stage drops stale ones), so their medians need not rise
    // along the path; the FITAM chain below, lock-step, drops none.
    for hop in [
        "camera/front/image -> perception/front/navigability (inference)",
        "perception/front/navigability -> nav/subgoal (subgoal-selection)",
        "nav/subgoal -> cmd/velocity (velocity-servoing)",
    ] {
        let cells = table_row(&stdout, hop);
        assert!(cells[2].parse::<usize>().unwrap() > 0, "{cells:?}");
        let median: f64 = cells[3].parse().unwrap();
        assert!(median >= 0.0, "{cells:?}\n{stdout}");
    }
    assert!(stdout.contains("inference alone"), "{stdout}");
    assert!(stdout.contains("capture-to-command median"), "{stdout}");
    // graphs/orfd.toml's servo answers each subgoal at once (command_on_input).
    assert!(
        stdout.contains("velocity-servoing (a command on each new subgoal; its 20 Hz tick"),
        "{stdout}"
    );
    for stage in [
        "camera-ingest",
        "inference",
        "subgoal-selection",
        "velocity-servoing",
    ] {
        let row = stdout
            .lines()
            .find(|l| l.starts_with(&format!("| {stage} | ")) && l.matches('|').count() == 4)
            .unwrap_or_else(|| panic!("no memory row for {stage}:\n{stdout}"));
        let private: f64 = row.split('|').nth(2).unwrap().trim().parse().unwrap();
        assert!(private > 1.0, "{row}");
    }
}

/// `--chain fitam-sim`: graphs/sim/fitam.toml as processes in the
/// lock-step simulator, each frame timed from when the simulator published
/// it through far field, polar bins, the fused costmap and D* Lite's path to
/// the command. Lock-step, so a busy machine slows the simulated clock and
/// nothing is late; only the presence and order of figures are checked.
#[test]
fn the_e2e_bench_times_the_fitam_chain_in_the_simulator() {
    let stdout = bench_e2e("e2e-fitam", &["--chain", "fitam-sim"], "3");
    let path: Vec<f64> = [
        ("camera/front/image", "farsight-sim"),
        ("perception/front/far_field", "inference"),
        ("bins/polar", "bin-projection"),
        ("costmap/fused", "costmap-fusion"),
        ("nav/path/planned", "subgoal-selection"),
        ("cmd/velocity", "velocity-servoing"),
    ]
    .iter()
    .map(|(topic, stage)| {
        let cells = table_row(&stdout, &format!("{topic} | {stage}"));
        assert!(cells[3].parse::<usize>().unwrap() > 0, "{cells:?}");
        cells[4].parse().unwrap()
    })
    .collect();
    assert!(path.windows(2).all(|w| w[0] <= w[1]), "{path:?}\n{stdout}");
    assert!(path[5] > 0.0, "{stdout}");
    assert!(
        stdout.contains("event-driven: inference, bin-projection, costmap-fusion, subgoal-selection, velocity-servoing"),
        "{stdout}"
    );
    for stage in ["inference", "costmap-fusion", "subgoal-selection"] {
        assert!(
            stdout
                .lines()
                .any(|l| l.starts_with(&format!("| {stage} | ")) && l.matches('|').count() == 4),
            "no memory row for {stage}:\n{stdout}"
        );
    }
}
