//! The bridge links the vehicle's iceoryx2 graph to zenoh: a frame published in
//! shared memory reaches a zenoh subscriber in another process intact, and a
//! pose and a goal published on zenoh arrive in iceoryx2.

use farsight_interfaces::msg::GoalKind;
use farsight_interfaces::topics;
use farsight_tests::{free_port, Namespace, Proc};
use std::time::{Duration, Instant};

fn start_bridge(ns: &Namespace, port: u16) -> Proc {
    let config = ns.root.join("bridge.toml");
    std::fs::write(
        &config,
        format!(
            r#"robot = "testbot"
[zenoh]
mode = "peer"
listen = ["tcp/127.0.0.1:{port}"]

[[export]]
topic = "camera/probe/image"

[[import]]
topic = "state/pose"

[[import]]
topic = "nav/goal"
"#
        ),
    )
    .unwrap();
    ns.start_bridge(&config)
}

#[test]
fn frame_crosses_the_bridge_to_a_zenoh_subscriber_intact() {
    let ns = Namespace::new("bridgeframe");
    let port = free_port();
    let _bridge = start_bridge(&ns, port);
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let mut laptop = Proc::start(
        "farsight",
        &[
            "probe",
            "net-subscribe",
            "--connect",
            &endpoint,
            "--robot",
            "testbot",
            "--frames",
            "5",
            "--timeout-s",
            "30",
        ],
        &ns,
    );
    let _camera = Proc::start(
        "farsight",
        &[
            "probe",
            "publish",
            "--width",
            "640",
            "--height",
            "480",
            "--rate-hz",
            "15",
        ],
        &ns,
    );
    let code = laptop.wait_exit(Duration::from_secs(40));
    let summary = laptop.wait_line(Duration::from_secs(1), |l| l.starts_with("summary"));
    assert_eq!(
        code,
        Some(0),
        "laptop side failed:\n{}",
        laptop.stderr_so_far()
    );
    assert_eq!(
        summary.map(|s| s.1).as_deref(),
        Some("summary received=5 corrupt=0")
    );
}

#[test]
fn pose_and_goal_published_on_zenoh_arrive_in_iceoryx2() {
    let ns = Namespace::new("bridgeimport");
    let port = free_port();
    let _bridge = start_bridge(&ns, port);
    let bus = ns.bus("bridge-test");
    let pose = bus.subscriber(&topics::pose()).unwrap();
    let goal = bus.subscriber(&topics::goal()).unwrap();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let _laptop = Proc::start(
        "farsight",
        &[
            "probe",
            "net-publish-nav",
            "--connect",
            &endpoint,
            "--robot",
            "testbot",
            "--duration-s",
            "20",
        ],
        &ns,
    );
    let end = Instant::now() + Duration::from_secs(20);
    let (mut got_pose, mut got_goal) = (None, None);
    while Instant::now() < end && (got_pose.is_none() || got_goal.is_none()) {
        if let Some(p) = pose.latest().unwrap() {
            got_pose = Some(p);
        }
        if let Some(g) = goal.latest().unwrap() {
            got_goal = Some(g);
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let p = got_pose.expect("no pose arrived in iceoryx2");
    assert_eq!(p.position_m, [1.0, 2.0, 0.0]);
    assert_eq!(p.yaw_rad, 0.5);
    let g = got_goal.expect("no goal arrived in iceoryx2");
    assert_eq!(g.kind, GoalKind::GPS);
    assert_eq!((g.latitude_deg, g.longitude_deg), (40.4406, -79.9959));
}
