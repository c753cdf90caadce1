//! Two real processes exchange full-size camera frames over iceoryx2 shared
//! memory: every byte checked, order checked, and a crashed publisher replaced
//! without touching the subscriber.

use farsight_tests::{Namespace, Proc};
use std::time::{Duration, Instant};

#[test]
fn frames_1440x1080_at_30hz_arrive_intact_and_in_order() {
    let ns = Namespace::new("intact");
    let mut sub = Proc::start(
        "farsight",
        &[
            "probe",
            "subscribe",
            "--frames",
            "90",
            "--idle-timeout-s",
            "10",
        ],
        &ns,
    );
    sub.wait_line(Duration::from_secs(10), |l| l.starts_with("subscribed"))
        .expect("subscriber did not start");
    let mut publisher = Proc::start(
        "farsight",
        &[
            "probe",
            "publish",
            "--width",
            "1440",
            "--height",
            "1080",
            "--rate-hz",
            "30",
            "--frames",
            "150",
        ],
        &ns,
    );
    let (_, summary) = sub
        .wait_line(Duration::from_secs(30), |l| l.starts_with("summary"))
        .unwrap_or_else(|| panic!("no summary; stderr:\n{}", sub.stderr_so_far()));
    assert_eq!(
        sub.wait_exit(Duration::from_secs(5)),
        Some(0),
        "{summary}\n{}",
        sub.stderr_so_far()
    );
    assert!(
        summary.contains("received=90 corrupt=0 non_increasing=0"),
        "{summary}"
    );
    publisher.kill();
}

#[test]
fn subscriber_resumes_within_one_second_after_publisher_is_killed_and_restarted() {
    let ns = Namespace::new("restart");
    let sub = Proc::start(
        "farsight",
        &["probe", "subscribe", "--each", "--idle-timeout-s", "30"],
        &ns,
    );
    sub.wait_line(Duration::from_secs(10), |l| l.starts_with("subscribed"))
        .expect("subscriber did not start");
    let publish = |start_seq: &str| {
        Proc::start(
            "farsight",
            &[
                "probe",
                "publish",
                "--width",
                "1440",
                "--height",
                "1080",
                "--rate-hz",
                "30",
                "--start-seq",
                start_seq,
            ],
            &ns,
        )
    };
    let mut first = publish("1");
    // Mid-stream: at least 20 frames through.
    sub.wait_line(Duration::from_secs(15), |l| {
        l.strip_prefix("frame ")
            .and_then(|s| s.parse::<u64>().ok())
            .is_some_and(|s| s >= 20)
    })
    .unwrap_or_else(|| panic!("first publisher never got going; {}", sub.stderr_so_far()));
    first.kill(); // SIGKILL + reap: no clean-up runs in the publisher.

    let restarted_at = Instant::now();
    let _second = publish("1000000");
    let (t, line) = sub
        .wait_line(Duration::from_secs(10), |l| {
            l.strip_prefix("frame ")
                .and_then(|s| s.parse::<u64>().ok())
                .is_some_and(|s| s >= 1_000_000)
        })
        .unwrap_or_else(|| {
            panic!(
                "subscriber never saw the restarted publisher; {}",
                sub.stderr_so_far()
            )
        });
    let resumed = t.duration_since(restarted_at);
    eprintln!("resumed after {resumed:?} ({line})");
    assert!(
        resumed < Duration::from_secs(1),
        "resumed after {resumed:?}"
    );
    // The subscriber itself was never restarted and saw nothing corrupt.
    let errors = sub.stderr_so_far();
    assert!(
        !errors.contains("differs") && !errors.contains("did not increase"),
        "{errors}"
    );
}
