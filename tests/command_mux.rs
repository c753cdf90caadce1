//! `farsight-command-mux` as a process on real iceoryx2 topics: the
//! operator's teleop outranks autonomy while live, each input's TTL cap
//! holds, the e-stop latches until an operator clears it, and the deadman
//! drops teleop when the operator's heartbeat stops. Paced on answers: each
//! step feeds its inputs until the output says what it should, so a busy
//! machine is slower, never wrong.

use farsight_interfaces::msg::{CommandReason, EStop, VelocityCommand};
use farsight_interfaces::topics;
use farsight_tests::{stamp_now, Namespace};
use std::time::{Duration, Instant};

fn command(v: f32, reason: CommandReason, ttl_ms: u16) -> VelocityCommand {
    VelocityCommand {
        stamp: stamp_now(1),
        linear_mps: v,
        angular_radps: 0.0,
        reason,
        ttl_ms,
    }
}

#[test]
fn teleop_outranks_autonomy_the_estop_latches_and_the_deadman_drops_teleop() {
    let ns = Namespace::new("mux");
    let bus = ns.bus("mux-test");
    let cfg = ns.write(
        "command-mux.toml",
        "deadman_timeout_s = 0.5\non_operator_loss = \"continue\"\n",
    );
    let out = bus.subscriber(&topics::velocity_command()).unwrap();
    let teleop = bus.publisher(&topics::command_input("teleop")).unwrap();
    let autonomy = bus.publisher(&topics::command_input("autonomy")).unwrap();
    let estop = bus.publisher(&topics::estop()).unwrap();
    let mux = ns.start_stage("farsight-command-mux", "command-mux", &cfg);

    // What each step feeds: the operator's heartbeat (an e-stop state),
    // teleop and autonomy commands, each optional.
    struct Feed {
        heartbeat: Option<u8>,
        teleop: Option<VelocityCommand>,
        autonomy: Option<VelocityCommand>,
    }
    let step = |what: &str, feed: &Feed, want: &dyn Fn(&VelocityCommand) -> bool| {
        let end = Instant::now() + Duration::from_secs(20);
        let mut last = None;
        while Instant::now() < end {
            if let Some(active) = feed.heartbeat {
                estop
                    .publish(&EStop {
                        stamp: stamp_now(1),
                        active,
                        ..Default::default()
                    })
                    .unwrap();
            }
            if let Some(c) = feed.teleop {
                teleop.publish(&c).unwrap();
            }
            if let Some(c) = feed.autonomy {
                autonomy.publish(&c).unwrap();
            }
            std::thread::sleep(Duration::from_millis(20));
            if let Some(c) = out.latest().unwrap() {
                if want(&c) {
                    return c;
                }
                last = Some(c);
            }
        }
        panic!(
            "{what}: last cmd/velocity {last:?}\n{}",
            mux.stderr_so_far()
        );
    };
    let drive = command(0.8, CommandReason::TRACKING, 250);
    let joystick = command(0.2, CommandReason::TELEOP, 300);
    let is = |v: f32, reason: CommandReason| {
        move |c: &VelocityCommand| c.linear_mps == v && c.reason == reason
    };

    // Autonomy alone drives (the operator link is up).
    let both_up = Feed {
        heartbeat: Some(EStop::RELEASED),
        teleop: None,
        autonomy: Some(drive),
    };
    let c = step(
        "autonomy drives",
        &both_up,
        &is(0.8, CommandReason::TRACKING),
    );
    assert!(
        c.ttl_ms > 0 && c.ttl_ms <= 250,
        "what is left of 250 ms: {c:?}"
    );
    // The operator takes over, and holding still (zero) still wins.
    let teleop_feed = |t: VelocityCommand| Feed {
        teleop: Some(t),
        ..both_up
    };
    step(
        "teleop wins",
        &teleop_feed(joystick),
        &is(0.2, CommandReason::TELEOP),
    );
    step(
        "a zero from the operator wins",
        &teleop_feed(command(0.0, CommandReason::TELEOP, 300)),
        &is(0.0, CommandReason::TELEOP),
    );
    // Teleop asks for a minute; its input's cap is 0.5 s: once it stops
    // sending, autonomy is back.
    teleop
        .publish(&command(0.2, CommandReason::TELEOP, 60_000))
        .unwrap();
    let handed_back = Instant::now();
    step(
        "autonomy back after teleop's cap",
        &both_up,
        &is(0.8, CommandReason::TRACKING),
    );
    assert!(handed_back.elapsed() >= Duration::from_millis(450));

    // The e-stop latches: releasing does not clear it, only an operator does.
    step(
        "e-stop",
        &Feed {
            heartbeat: Some(EStop::PRESSED),
            ..teleop_feed(joystick)
        },
        &is(0.0, CommandReason::ESTOP),
    );
    let released = Instant::now();
    while released.elapsed() < Duration::from_millis(500) {
        let c = step(
            "still latched",
            &teleop_feed(joystick),
            &|c: &VelocityCommand| c.reason == CommandReason::ESTOP,
        );
        assert_eq!(c.linear_mps, 0.0);
    }
    step(
        "cleared by the operator",
        &Feed {
            heartbeat: Some(EStop::CLEAR),
            ..teleop_feed(joystick)
        },
        &is(0.2, CommandReason::TELEOP),
    );

    // The operator link is lost (no heartbeat) while teleop commands still
    // come: teleop is dropped, autonomy goes on (on_operator_loss = continue).
    step(
        "teleop dropped with the link",
        &Feed {
            heartbeat: None,
            ..teleop_feed(joystick)
        },
        &is(0.8, CommandReason::TRACKING),
    );
    // Nothing live: zero, stale.
    step(
        "nothing live",
        &Feed {
            heartbeat: None,
            teleop: None,
            autonomy: None,
        },
        &is(0.0, CommandReason::STALE_INPUT),
    );
}

#[test]
fn a_mux_that_is_told_to_stop_leaves_the_robot_stopped_and_bad_configs_are_named() {
    let ns = Namespace::new("muxstop");
    let bus = ns.bus("mux-stop-test");
    let out = bus.subscriber(&topics::velocity_command()).unwrap();
    let autonomy = bus.publisher(&topics::command_input("autonomy")).unwrap();
    let mut mux = ns.start_stage(
        "farsight-command-mux",
        "command-mux",
        &ns.write("command-mux.toml", ""),
    );
    let end = Instant::now() + Duration::from_secs(20);
    loop {
        autonomy
            .publish(&command(0.5, CommandReason::TRACKING, 250))
            .unwrap();
        std::thread::sleep(Duration::from_millis(20));
        if out.latest().unwrap().is_some_and(|c| c.linear_mps == 0.5) {
            break;
        }
        assert!(Instant::now() < end, "{}", mux.stderr_so_far());
    }
    assert_eq!(mux.terminate(Duration::from_secs(10)), Some(0));
    let mut last = None;
    while let Some(c) = out.latest().unwrap() {
        last = Some(c);
    }
    let last = last.expect("a last command");
    assert_eq!((last.linear_mps, last.angular_radps), (0.0, 0.0));

    let bad = ns.write(
        "bad.toml",
        "[[inputs]]\nname = \"x\"\ntopic = \"cmd/velocity\"\npriority = 1\nmax_ttl_s = 0.5\n",
    );
    let err = ns.start_must_fail("farsight-command-mux", &bad);
    assert!(
        err.contains("inputs[0].topic") && err.contains("cmd/velocity"),
        "{err}"
    );
}
