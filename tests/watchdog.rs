//! The systemd service protocol as a real stage speaks it. systemd cannot run
//! here, so the test plays it: it binds the `NOTIFY_SOCKET` datagram socket
//! itself and sets `WATCHDOG_USEC`, as systemd does for a unit with
//! `Type=notify` and `WatchdogSec=`. An idle stage says `READY=1` and keeps
//! pinging `WATCHDOG=1`; a stage whose step hangs (a test hook wedges it)
//! stops pinging while its process lives, which is what makes systemd kill
//! and restart it; SIGTERM says `STOPPING=1`.

use farsight_tests::{Namespace, Proc};
use std::os::unix::net::UnixDatagram;
use std::time::{Duration, Instant};

/// The socket systemd would own, and the stage's environment to reach it.
struct Manager {
    socket: UnixDatagram,
    path: String,
}

impl Manager {
    fn new(ns: &Namespace, name: &str) -> Self {
        let path = ns.root.join(name);
        let socket = UnixDatagram::bind(&path).expect("bind NOTIFY_SOCKET");
        Self {
            socket,
            path: path.to_str().unwrap().to_string(),
        }
    }

    /// Starts the servo (no inputs: idle) under this manager, with a 0.4 s
    /// watchdog (so a ping every 0.2 s) and `extra` environment.
    fn start_servo(&self, ns: &Namespace, extra: &[(&str, &str)]) -> Proc {
        let cfg = ns.write("velocity-servoing.toml", "");
        let mut env = vec![
            ("NOTIFY_SOCKET", self.path.as_str()),
            ("WATCHDOG_USEC", "400000"),
        ];
        env.extend_from_slice(extra);
        let p = Proc::start_env(
            "farsight-velocity-servoing",
            &["--config", cfg.to_str().unwrap()],
            ns,
            &env,
        );
        p.wait_line(Duration::from_secs(30), |l| l == "velocity-servoing ready")
            .unwrap_or_else(|| panic!("servo not ready:\n{}", p.stderr_so_far()));
        p
    }

    /// Datagrams received within `window`, one string each.
    fn receive_for(&self, window: Duration) -> Vec<String> {
        let end = Instant::now() + window;
        let mut got = Vec::new();
        let mut buf = [0u8; 512];
        loop {
            let left = end.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return got;
            }
            self.socket.set_read_timeout(Some(left)).unwrap();
            match self.socket.recv(&mut buf) {
                Ok(n) => got.push(String::from_utf8_lossy(&buf[..n]).into_owned()),
                Err(_) => return got,
            }
        }
    }

    /// Waits (generously) until `n` datagrams containing `what` have come.
    fn wait_for(&self, what: &str, n: usize) -> Vec<String> {
        let end = Instant::now() + Duration::from_secs(60);
        let mut got = Vec::new();
        while got.iter().filter(|m: &&String| m.contains(what)).count() < n {
            assert!(Instant::now() < end, "{n} x {what:?} never came: {got:?}");
            got.extend(self.receive_for(Duration::from_millis(100)));
        }
        got
    }
}

#[test]
fn an_idle_stage_says_ready_keeps_pinging_and_says_stopping() {
    let ns = Namespace::new("watchdogidle");
    let manager = Manager::new(&ns, "notify.sock");
    let mut servo = manager.start_servo(&ns, &[]);
    let got = manager.wait_for("WATCHDOG=1", 5);
    assert_eq!(
        got[0].trim(),
        "READY=1",
        "ready before the first ping: {got:?}"
    );
    assert_eq!(servo.terminate(Duration::from_secs(30)), Some(0));
    let rest = manager.receive_for(Duration::from_millis(200));
    assert!(
        rest.iter().any(|m| m.trim() == "STOPPING=1"),
        "no STOPPING=1 on SIGTERM: {rest:?}"
    );
}

#[test]
fn a_wedged_step_stops_the_pings_while_the_process_lives() {
    let ns = Namespace::new("watchdogwedge");
    let manager = Manager::new(&ns, "notify.sock");
    let mut servo = manager.start_servo(&ns, &[("FARSIGHT_TEST_WEDGE_AFTER_S", "1.0")]);
    manager.wait_for("WATCHDOG=1", 1);
    let end = Instant::now() + Duration::from_secs(60);
    while !servo.stderr_so_far().contains("step wedged") {
        assert!(
            Instant::now() < end,
            "never wedged:\n{}",
            servo.stderr_so_far()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    // Every ping sent before the wedge is in the socket by now.
    let before = manager.receive_for(Duration::from_millis(50));
    // Ten ping intervals of silence, with the process alive: systemd's
    // WatchdogSec would now kill and restart it.
    let after = manager.receive_for(Duration::from_secs(2));
    assert!(
        after.iter().all(|m| !m.contains("WATCHDOG=1")),
        "pings went on from a wedged loop: {after:?} (before: {before:?})"
    );
    assert_eq!(servo.wait_exit(Duration::ZERO), None, "the process lives");
}
