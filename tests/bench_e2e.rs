//! `farsight bench e2e` runs the ORFD POVNav graph as real processes and
//! times each frame from capture to every topic on its path: the table
//! must hold every hop, latencies that grow along the path, and each
//! stage's memory. Paced by the frames themselves (camera-ingest waits for
//! each navigability image), so a busy machine gives fewer frames, not a
//! failure; only the presence and order of figures are checked.

use farsight_tests::{bin, repo_root};

#[test]
fn the_e2e_bench_times_every_hop_from_capture_to_command() {
    let out_dir = std::env::temp_dir().join(format!("farsight-e2e-{}", std::process::id()));
    let out = std::process::Command::new(bin("farsight"))
        .current_dir(repo_root())
        .args([
            "bench",
            "e2e",
            "--seconds",
            "4",
            "--warm-up-s",
            "1",
            "--inference-runs",
            "2",
            "--out",
        ])
        .arg(&out_dir)
        .output()
        .expect("farsight bench e2e runs");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stdout}\n{stderr}");
    let median = |topic: &str| -> f64 {
        let row = stdout
            .lines()
            .find(|l| l.starts_with(&format!("| {topic} |")))
            .unwrap_or_else(|| panic!("no row for {topic}:\n{stdout}"));
        let cells: Vec<&str> = row.split('|').map(str::trim).collect();
        assert!(cells[3].parse::<usize>().unwrap() > 0, "{row}");
        cells[4].parse().unwrap()
    };
    let path = [
        median("camera/front/image"),
        median("perception/front/navigability"),
        median("nav/subgoal"),
        median("cmd/velocity"),
    ];
    assert!(path.windows(2).all(|w| w[0] <= w[1]), "{path:?}\n{stdout}");
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
    let _ = std::fs::remove_dir_all(&out_dir);
}
