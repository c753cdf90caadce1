//! The robot and the laptop as two hosts: network namespaces joined by a
//! veth pair, zenoh the only thing between them. The robot namespace runs
//! the graph (inference -> POVNav -> servo, driven by the replay fixture)
//! and the bridge with the shipped router config (deploy/zenoh); the laptop
//! namespace runs `farsight inspect`.

use farsight_interfaces::msg::{CommandReason, GoalKind};
use farsight_interfaces::topics;
use farsight_tests::netns::TwoHosts;
use farsight_tests::{free_port, repo_root, toml_string, Namespace, Proc};
use std::path::PathBuf;
use std::time::{Duration, Instant};

const STAGES: [&str; 3] = ["inference", "subgoal-selection", "velocity-servoing"];

fn fixture(name: &str) -> PathBuf {
    repo_root().join("tests/fixtures/sim-povnav").join(name)
}

/// The robot: the three stages and the command mux (a graph through
/// `farsight run`), the bridge behind the shipped router
/// config listening on the robot's address, and a replay of the fixture
/// at `speed` feeding them.
fn robot(ns: &Namespace, hosts: &TwoHosts, port: u16, speed: &str) -> Vec<Proc> {
    let r = Some(hosts.robot.as_str());
    let mut configs = Vec::new();
    for s in STAGES {
        let mut text = std::fs::read_to_string(fixture(&format!("{s}.toml"))).unwrap();
        if s == "velocity-servoing" {
            // Behind the command mux, as deployed.
            text = format!("command_topic = \"cmd/autonomy\"\n{text}");
        }
        configs.push((s, ns.write(&format!("{s}.toml"), &text)));
    }
    // The one writer of cmd/velocity: the operator's teleop over autonomy.
    configs.push(("command-mux", ns.write("command-mux.toml", "")));
    let nodes: Vec<(&str, &std::path::Path)> =
        configs.iter().map(|(s, c)| (*s, c.as_path())).collect();
    let mut procs = vec![ns.run_graph_in(
        r,
        &nodes,
        &[
            "camera/front/image",
            "camera/front/info",
            "state/pose",
            "nav/goal",
            "cmd/teleop",
        ],
        &["cmd/velocity"],
    )];
    let router = ns.shipped_router(&format!("tcp/{}:{port}", hosts.robot_ip));
    let mut bridge = format!(
        "robot = \"robot\"\n[zenoh]\nconfig_file = {}\n\
         [[export]]\ntopic = \"camera/front/image\"\ndownsample = 2\ncompression = \"jpeg\"\n\
         [[export]]\ntopic = \"perception/front/navigability\"\ndownsample = 2\ncompression = \"png\"\n\
         [[import]]\ntopic = \"nav/goal\"\n[[import]]\ntopic = \"cmd/teleop\"\n",
        toml_string(router.to_str().unwrap())
    );
    for t in [
        "camera/front/info",
        "nav/subgoal",
        "nav/path/visual",
        "health/inference",
        "health/subgoal-selection",
        "health/velocity-servoing",
    ] {
        bridge += &format!("[[export]]\ntopic = \"{t}\"\n");
    }
    procs.push(ns.start_bridge_in(r, &ns.write("bridge.toml", &bridge)));
    let recording = fixture("recording.mcap");
    procs.push(Proc::start_in(
        r,
        "farsight",
        &[
            "replay",
            recording.to_str().unwrap(),
            "--topics",
            "camera/front/image,camera/front/info,state/pose,nav/goal",
            "--speed",
            speed,
        ],
        ns,
        &[],
    ));
    procs
}

/// `farsight ARGS --user USER` in the laptop namespace.
fn laptop(
    ns: &Namespace,
    hosts: &TwoHosts,
    user: &str,
    password: &str,
    args: &[&str],
) -> (Option<i32>, String) {
    Proc::farsight_as(Some(&hosts.laptop), ns, user, password, args)
}

#[test]
fn a_laptop_on_another_host_sees_the_graph_and_commands_only_as_operator() {
    let ns = Namespace::new("netns");
    let hosts = TwoHosts::new("a");
    let port = free_port();
    let _robot = robot(&ns, &hosts, port, "1");
    let endpoint = format!("tcp/{}:{port}", hosts.robot_ip);
    std::thread::sleep(Duration::from_secs(1));
    let (code, view) = laptop(
        &ns,
        &hosts,
        "laptop",
        "laptop-secret",
        &[
            "inspect",
            "--connect",
            &endpoint,
            "--robot",
            "robot",
            "--seconds",
            "2.5",
        ],
    );
    assert_eq!(code, Some(0), "{view}");
    for s in STAGES {
        assert!(
            view.lines()
                .any(|l| l.trim_start().starts_with(s) && l.contains(" ok ")),
            "{s} alive:\n{view}"
        );
    }
    let line = view
        .lines()
        .find(|l| l.trim_start().starts_with("nav/subgoal"))
        .expect(&view);
    let rate: f64 = line.split_whitespace().nth(2).unwrap().parse().unwrap();
    assert!((7.0..13.0).contains(&rate), "{view}");
    let snap = ns.root.join("snap");
    let (code, out) = laptop(
        &ns,
        &hosts,
        "laptop",
        "laptop-secret",
        &[
            "inspect",
            "--connect",
            &endpoint,
            "--robot",
            "robot",
            "--seconds",
            "1.5",
            "snapshot",
            "--out",
            snap.to_str().unwrap(),
        ],
    );
    assert_eq!(code, Some(0), "{out}");
    assert!(snap.join("camera-front.png").exists(), "{out}");

    // Commands: the probe's GPS goals (the replay's goal is a local one)
    // and teleop velocity commands (the servo's are "tracking"). The
    // laptop's are refused by the robot's router; the operator's arrive in
    // the robot's shared memory.
    let bus = ns.bus("netns-test");
    let goals = bus.subscriber(&topics::goal()).unwrap();
    let cmds = bus.subscriber(&topics::velocity_command()).unwrap();
    let seen = |user: &str, password: &str| -> (bool, bool) {
        let mut p = Proc::start_in(
            Some(&hosts.laptop),
            "farsight",
            &[
                "probe",
                "net-publish-nav",
                "--velocity",
                "--connect",
                &endpoint,
                "--robot",
                "robot",
                "--duration-s",
                "1.5",
                "--user",
                user,
            ],
            &ns,
            &[("FARSIGHT_ZENOH_PASSWORD", password)],
        );
        let (mut goal, mut teleop) = (false, false);
        let end = Instant::now() + Duration::from_secs(20);
        let code = loop {
            if let Some(code) = p.wait_exit(Duration::from_millis(1)) {
                break code;
            }
            assert!(Instant::now() < end, "the probe hangs");
            goal |= goals
                .latest()
                .unwrap()
                .is_some_and(|g| g.kind == GoalKind::GPS);
            teleop |= cmds
                .latest()
                .unwrap()
                .is_some_and(|c| c.reason == CommandReason::TELEOP);
        };
        assert_eq!(code, 0, "{user}: {}", p.stderr_to_end());
        (goal, teleop)
    };
    assert_eq!(
        seen("laptop", "laptop-secret"),
        (false, false),
        "a laptop commanded the robot"
    );
    assert_eq!(
        seen("operator", "operator-secret"),
        (true, true),
        "the operator's commands"
    );
}

#[test]
fn cutting_the_link_leaves_the_robot_driving_and_the_laptop_view_comes_back() {
    let ns = Namespace::new("netcut");
    let hosts = TwoHosts::new("b");
    let port = free_port();
    // Half speed: 16 s of replay, enough for a cut and a reconnect.
    let _robot = robot(&ns, &hosts, port, "0.5");
    let endpoint = format!("tcp/{}:{port}", hosts.robot_ip);
    let bus = ns.bus("netcut-test");
    let cmds = bus.subscriber(&topics::velocity_command()).unwrap();
    let inspect = [
        "inspect",
        "--connect",
        &endpoint,
        "--robot",
        "robot",
        "--seconds",
        "1.5",
    ];
    std::thread::sleep(Duration::from_secs(1));
    let (code, view) = laptop(&ns, &hosts, "laptop", "laptop-secret", &inspect);
    assert_eq!(code, Some(0), "{view}");

    hosts.link(false);
    // With the link down the robot keeps navigating: commands keep coming
    // from frames the replay goes on feeding.
    let mut seqs = Vec::new();
    let end = Instant::now() + Duration::from_secs(2);
    while Instant::now() < end {
        if let Some(c) = cmds.latest().unwrap() {
            seqs.push(c.stamp.frame_seq);
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    seqs.dedup();
    assert!(
        seqs.len() >= 5,
        "the robot stalled without the laptop: {seqs:?}"
    );
    let (code, _) = laptop(&ns, &hosts, "laptop", "laptop-secret", &inspect);
    assert_ne!(code, Some(0), "the laptop heard the robot over a cut link");

    hosts.link(true);
    // The laptop's view comes back once the link does.
    let end = Instant::now() + Duration::from_secs(15);
    loop {
        let (code, view) = laptop(&ns, &hosts, "laptop", "laptop-secret", &inspect);
        if code == Some(0) && view.contains("nav/subgoal") {
            break;
        }
        assert!(Instant::now() < end, "the view did not come back:\n{view}");
    }
}
