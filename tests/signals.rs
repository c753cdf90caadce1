//! Signals, as an operator and systemd send them, to every stage, the bridge
//! and the recorder as real processes: a freeze (SIGSTOP, then SIGCONT, as
//! a debugger or `kill -STOP` does) never ends one, and it goes on
//! publishing its health afterwards; SIGTERM (with the SIGCONT systemd sends
//! after it) and SIGINT end each cleanly (exit status 0).

use farsight_interfaces::msg::StageHealth;
use farsight_interfaces::topics;
use farsight_interfaces::transport::ipc::Subscriber;
use farsight_tests::{free_port, orfd_ingest_toml, Namespace, Proc};
use std::time::Duration;

/// A running process and, for stages, its health topic.
struct Running {
    proc: Proc,
    health: Option<Subscriber<StageHealth>>,
}

fn start_all(ns: &Namespace) -> Vec<Running> {
    let bus = ns.bus("signals-test");
    let mut all = Vec::new();
    let mut stage = |name: &str, toml: &str| {
        // Subscribe before the stage starts, so its reports are not missed.
        let health = bus.subscriber(&topics::health(name)).unwrap();
        let cfg = ns.write(&format!("{name}.toml"), toml);
        let proc = ns.start_stage(&format!("farsight-{name}"), name, &cfg);
        all.push(Running {
            proc,
            health: Some(health),
        });
    };
    stage(
        "camera-ingest",
        &orfd_ingest_toml("rate_hz = 2.0\nloops = 0"),
    );
    stage(
        "inference",
        "camera = \"front\"\nbackend = \"hsv\"\n[[hsv.ranges]]\nhue_deg = [25.0, 45.0]\nsaturation = [0.1, 0.45]\nvalue = [0.4, 0.8]\n",
    );
    stage("bin-projection", "cameras = [\"front\"]\n");
    stage("costmap-fusion", "");
    stage(
        "subgoal-selection",
        "method = \"povnav\"\ncamera = \"front\"\n",
    );
    stage("velocity-servoing", "");
    stage("command-mux", "");
    stage(
        "bridge",
        &format!(
            "robot = \"signals\"\n[zenoh]\nmode = \"peer\"\nlisten = [\"tcp/127.0.0.1:{}\"]\n[[export]]\ntopic = \"cmd/velocity\"\n",
            free_port()
        ),
    );
    let out = ns.root.join("signals.mcap");
    let rec = Proc::start(
        "farsight",
        &["record", "--topics", "**", "--out", out.to_str().unwrap()],
        ns,
    );
    rec.wait_line(Duration::from_secs(30), |l| l == "farsight-record ready")
        .unwrap_or_else(|| panic!("recorder not ready:\n{}", rec.stderr_so_far()));
    all.push(Running {
        proc: rec,
        health: None,
    });
    all
}

#[test]
fn a_frozen_stage_resumes_and_sigterm_or_sigint_ends_each_cleanly() {
    let ns = Namespace::new("signals");
    let mut all = start_all(&ns);
    for r in &all {
        r.proc.signal("STOP");
    }
    // Reports sent before the freeze are drained while nothing runs.
    std::thread::sleep(Duration::from_millis(500));
    for r in &all {
        if let Some(h) = &r.health {
            while h.latest().unwrap().is_some() {}
        }
    }
    for r in &all {
        r.proc.signal("CONT");
    }
    for r in all.iter_mut() {
        if let Some(h) = &r.health {
            let pid = r.proc.pid();
            let report = farsight_tests::wait_health(
                h,
                Duration::from_secs(30),
                &format!("from {} after the freeze", r.proc.name),
                |h| h.pid == pid,
            );
            assert_ne!(report.state.name(), Some("stopping"), "{report:?}");
        }
        assert_eq!(
            r.proc.wait_exit(Duration::ZERO),
            None,
            "{} exited after SIGSTOP/SIGCONT:\n{}",
            r.proc.name,
            r.proc.stderr_so_far()
        );
    }
    // Each ends cleanly on the way it is asked to stop:
    // - SIGTERM and at once SIGCONT, as `systemctl stop` sends them;
    // - SIGTERM to a frozen stage, then SIGCONT: both are pending when it
    //   runs again, and the kernel hands over SIGTERM first, so SIGCONT is
    //   the last signal iceoryx2 recorded (it kept only that one, and the
    //   stop was lost);
    // - SIGINT (Ctrl-C).
    for (i, r) in all.iter().enumerate() {
        let sequence: &[&str] = match i % 3 {
            0 => &["TERM", "CONT"],
            1 => &["STOP", "TERM", "CONT"],
            _ => &["INT"],
        };
        for s in sequence {
            r.proc.signal(s);
        }
    }
    for r in all.iter_mut() {
        assert_eq!(
            r.proc.wait_exit(Duration::from_secs(30)),
            Some(0),
            "{} after its stop signals:\n{}",
            r.proc.name,
            r.proc.stderr_so_far()
        );
    }
}
