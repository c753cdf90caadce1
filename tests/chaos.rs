//! Motion safety under faults (`farsight chaos`, tools/farsight/src/chaos.rs):
//! the simulator drives the FITAM graph in real time on the wall clock while
//! every stage is killed and restarted or frozen and continued, two rounds
//! in shuffled order. Bounded to about a minute; the 100-fault run is
//! `farsight chaos --faults 100` (README, "Tests"). Its invariants are
//! judged on capture times and on counts, not on the machine keeping up: a
//! busy machine makes the robot slower, not the run wrong.

use farsight_tests::{Namespace, Proc};
use std::time::Duration;

#[test]
fn killing_and_freezing_every_stage_never_moves_the_robot_on_stale_data() {
    let ns = Namespace::new("chaos");
    let out = ns.root.join("chaos");
    let mut p = Proc::start(
        "farsight",
        &[
            "chaos",
            "--faults",
            "12",
            "--gap-s",
            "2",
            "--out",
            out.to_str().unwrap(),
        ],
        &ns,
    );
    let code = p.wait_exit(Duration::from_secs(300));
    let stderr = p.stderr_to_end();
    let summary = std::fs::read_to_string(out.join("summary.toml"))
        .unwrap_or_else(|e| panic!("no summary ({e}):\n{stderr}"));
    eprintln!("{summary}");
    assert_eq!(code, Some(0), "{stderr}");
    let s: toml::Table = toml::from_str(&summary).unwrap();
    let int = |k: &str| s[k].as_integer().unwrap();
    assert_eq!(int("faults"), 12);
    assert_eq!(int("stale_moving_servo"), 0, "{stderr}");
    assert_eq!(int("stale_moving_mux"), 0, "{stderr}");
    assert_eq!(int("self_exits"), 0, "{stderr}");
    assert_eq!(int("moved_while_down"), 0, "{stderr}");
    assert!(int("moving_commands") > 100, "the robot was driven");
    assert!(
        s["distance_made_good_m"].as_float().unwrap() >= 5.0,
        "{summary}"
    );
    // Every stage was faulted, and its output came back each time.
    let stages = s["stages"].as_table().unwrap();
    assert_eq!(stages.len(), 6, "{summary}");
    for (name, st) in stages {
        let count = |k: &str| st[k].as_integer().unwrap();
        let resumed = |k: &str| st[k].as_array().unwrap().len() as i64;
        assert!(count("kills") + count("freezes") >= 2, "{name}: {summary}");
        assert_eq!(resumed("restart_s"), count("kills"), "{name}: {summary}");
        assert_eq!(resumed("continue_s"), count("freezes"), "{name}: {summary}");
    }
    // With the servo or the mux down, the robot stopped every time.
    let stops = s["stops_s"].as_array().unwrap();
    assert!(stops.len() >= 4, "{summary}");
    for t in stops {
        let t = t.as_float().unwrap();
        assert!((0.0..=3.0).contains(&t), "stopped after {t} s: {summary}");
    }
}
