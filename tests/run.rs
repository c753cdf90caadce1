//! `farsight run GRAPH` as a real process supervising real stages: every
//! node ready with its own health topic and log; a killed node restarted; a
//! frozen one killed by the watchdog and restarted; Ctrl-C stops them all;
//! a second supervisor of the same instances, or one under systemd, refused.
//! Paced on the supervisor's and the stages' own lines and reports, with
//! deadlines that only bound a hang.

use farsight_interfaces::topics;
use farsight_tests::{wait_health, Namespace, Proc};
use std::time::Duration;

const GRAPH: &str = r#"
[[node]]
name = "mux"
stage = "command-mux"
restart = "always"

[[node]]
name = "servo-a"
stage = "velocity-servoing"
[node.config]
command_topic = "cmd/autonomy"

[[node]]
name = "elsewhere"
stage = "velocity-servoing"
machine = "laptop"
[node.config]
command_topic = "cmd/laptop"

[[external]]
topic = "nav/subgoal"
from = "the test"
"#;

const LONG: Duration = Duration::from_secs(60);

fn alive(pid: u32) -> bool {
    // SAFETY: signal 0 only checks that the pid exists.
    unsafe { libc::kill(pid as libc::pid_t, 0) == 0 }
}

fn line(p: &Proc, what: &str) -> String {
    p.wait_line(LONG, |l| l.contains(what))
        .unwrap_or_else(|| panic!("no line with {what:?}:\n{}", p.stderr_so_far()))
        .1
}

#[test]
fn run_supervises_restarts_and_stops_a_graph() {
    let ns = Namespace::new("farsightrun");
    let graph = ns.write("graph.toml", GRAPH);
    let out = ns.root.join("run");
    let bus = ns.bus("run-test");
    let servo_health = bus.subscriber(&topics::health("servo-a")).unwrap();
    let mux_health = bus.subscriber(&topics::health("mux")).unwrap();
    let mut run = Proc::start(
        "farsight",
        &[
            "run",
            graph.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--watchdog-s",
            "3",
        ],
        &ns,
    );
    line(&run, "elsewhere: on laptop, not started here");
    line(&run, "mux: ready");
    let first = wait_health(&servo_health, LONG, "from servo-a", |_| true);
    wait_health(&mux_health, LONG, "from mux", |_| true);
    assert_eq!(first.stage.as_str(), "servo-a");
    for log in ["mux.log", "servo-a.log"] {
        let text = std::fs::read_to_string(out.join(log)).unwrap();
        let name = log.trim_end_matches(".log");
        assert!(text.contains(&format!("{name} ready")), "{log}: {text}");
    }
    assert!(
        !out.join("elsewhere.log").exists(),
        "a laptop node started here"
    );

    // Killed: restarted after its back-off, a new process.
    unsafe { libc::kill(first.pid as libc::pid_t, libc::SIGKILL) };
    line(
        &run,
        "servo-a: exited (signal: 9 (SIGKILL)); restart 1 in 0.5 s",
    );
    let second = wait_health(&servo_health, LONG, "from the restarted servo-a", |h| {
        h.pid != first.pid
    });

    // Frozen: its watchdog pings stop, the supervisor kills and restarts it.
    unsafe { libc::kill(second.pid as libc::pid_t, libc::SIGSTOP) };
    line(&run, "servo-a: no watchdog ping for");
    // (restart 2 in 1.0 s, or 1 in 0.5 s had it run 30 s since the last)
    line(&run, "servo-a: exited (signal: 9 (SIGKILL)); restart");
    let third = wait_health(&servo_health, LONG, "from servo-a after the freeze", |h| {
        h.pid != second.pid && h.pid != first.pid
    });
    assert!(!alive(second.pid), "the frozen process is gone");

    // A second supervisor of the same instances is refused.
    let mut twin = Proc::start(
        "farsight",
        &[
            "run",
            graph.to_str().unwrap(),
            "--out",
            ns.root.join("twin").to_str().unwrap(),
        ],
        &ns,
    );
    assert_eq!(twin.wait_exit(LONG), Some(1));
    let why = twin.stderr_so_far();
    assert!(why.contains("already runs here"), "{why}");

    // Ctrl-C: every node stops, then the supervisor.
    let mux_pid = wait_health(&mux_health, LONG, "from mux", |_| true).pid;
    unsafe { libc::kill(run.pid() as libc::pid_t, libc::SIGINT) };
    line(&run, "stopping 2 nodes");
    assert_eq!(run.wait_exit(LONG), Some(0), "{}", run.stderr_so_far());
    assert!(
        !alive(third.pid) && !alive(mux_pid),
        "a node outlived farsight run"
    );
}

#[test]
fn run_refuses_to_run_under_systemd() {
    let ns = Namespace::new("farsightrunsd");
    let graph = ns.write("graph.toml", GRAPH);
    let mut run = Proc::start_env(
        "farsight",
        &[
            "run",
            graph.to_str().unwrap(),
            "--out",
            ns.root.join("run").to_str().unwrap(),
        ],
        &ns,
        &[("INVOCATION_ID", "0123456789abcdef")],
    );
    assert_eq!(run.wait_exit(LONG), Some(1));
    assert!(
        run.stderr_so_far().contains("never both"),
        "{}",
        run.stderr_so_far()
    );
}

#[test]
fn the_orfd_graphs_recorder_node_records_every_frame_from_the_queues() {
    // `farsight demo --orfd` runs graphs/orfd.toml under `farsight run`:
    // the real ORFD frames at 10 Hz on the wall clock through TwinLiteNet
    // and POVNav, with the graph's recorder node reading each topic from
    // its queue (farsight run declares them to every node; the demo, which
    // publishes the pose and goal itself, feeds those queues too).
    let ns = Namespace::new("orfdrec");
    let out = ns.write("placeholder", "").with_file_name("orfd");
    let mut demo = Proc::start(
        "farsight",
        &["demo", "--orfd", "--out", out.to_str().unwrap()],
        &ns,
    );
    let code = demo.wait_exit(Duration::from_secs(180));
    assert_eq!(code, Some(0), "{}", demo.stderr_so_far());
    let run_log = std::fs::read_to_string(out.join("run.log")).unwrap();
    assert!(
        run_log.contains("queues: camera/front/image=16"),
        "{run_log}"
    );
    let info = farsight_recording::read::Recording::open(&out.join("recording.mcap"))
        .unwrap()
        .info()
        .unwrap();
    let count = |topic: &str| {
        info.topics
            .iter()
            .find(|t| t.topic == topic)
            .map_or(0, |t| t.count)
    };
    // Three passes over the six frames, each one recorded, and the goal
    // the demo published before the recorder started (the queue's history).
    assert_eq!(count("camera/front/image"), 18, "{info}");
    assert_eq!(count("camera/front/info"), 18, "{info}");
    assert_eq!(count("nav/goal"), 1, "{info}");
    // Inference skips frames that come while it is busy (latest-value, at
    // real time): what it did publish came through.
    assert!(count("perception/front/navigability") >= 12, "{info}");
    assert!(count("health/inference") > 0, "{info}");
}
