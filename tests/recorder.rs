//! The recorder in a lock-step run (`farsight record --ack`): on
//! `health/<instance>` it reports the newest frame whose answer (the
//! velocity command) it has written, and a lock-step simulator
//! (`farsight-sim run --await-health`) sends the next frame only then. The
//! answer topic also carries stops that answer no frame (stamped frame 0:
//! the servo's, while its input is starved); one taken with the frame's
//! answer must not hide it, or the simulator waits for a report that never
//! comes.

use farsight_interfaces::msg::{CommandReason, Stamp, VelocityCommand};
use farsight_interfaces::topics;
use farsight_interfaces::transport::ipc::QUEUES_ENV;
use farsight_interfaces::transport::wire;
use farsight_tests::{wait_health, Namespace, Proc};
use std::time::Duration;

const WAIT: Duration = Duration::from_secs(30);

fn answer(frame_seq: u64) -> VelocityCommand {
    VelocityCommand {
        stamp: Stamp {
            frame_seq,
            capture_time_ns: frame_seq * 100_000_000,
        },
        linear_mps: 0.5,
        ..Default::default()
    }
}

fn starved_stop() -> VelocityCommand {
    VelocityCommand::stop(Stamp::default(), CommandReason::STALE_INPUT)
}

#[test]
fn a_stop_that_answers_no_frame_never_hides_or_takes_back_a_frames_answer() {
    let ns = Namespace::new("recorder-ack");
    let queues = "cmd/velocity=8";
    let bus = ns.bus_with_queues("test", Some(queues));
    let commands = bus.publisher(&topics::velocity_command()).unwrap();
    let health = bus.subscriber(&topics::health("recorder")).unwrap();
    let out = ns.root.join("ack.mcap");
    let mut rec = Proc::start_env(
        "farsight",
        &[
            "record",
            "--topics",
            "cmd/velocity",
            "--ack",
            "cmd/velocity",
            "--instance",
            "recorder",
            "--out",
            out.to_str().unwrap(),
        ],
        &ns,
        &[(QUEUES_ENV, queues)],
    );
    rec.wait_line(WAIT, |l| l == "farsight-record ready")
        .unwrap_or_else(|| panic!("recorder not ready:\n{}", rec.stderr_so_far()));
    wait_health(&health, WAIT, "from the recorder", |_| true);

    // Frame 1's answer and just after it a stop, taken in one pass: the
    // recorder is frozen while both are sent.
    rec.signal("STOP");
    commands.publish(&answer(1)).unwrap();
    commands.publish(&starved_stop()).unwrap();
    rec.signal("CONT");
    let h = wait_health(&health, WAIT, "with both messages taken", |h| {
        h.messages_in >= 2
    });
    assert_eq!(h.stamp.frame_seq, 1, "frame 1 acknowledged: {h:?}");

    // A stop alone afterwards is written, and the report stays at frame 1.
    commands.publish(&starved_stop()).unwrap();
    let h = wait_health(&health, WAIT, "with the stop taken", |h| h.messages_in >= 3);
    assert_eq!(h.stamp.frame_seq, 1, "not taken back to frame 0: {h:?}");

    // The next frame's answer alone is acknowledged as before.
    commands.publish(&answer(2)).unwrap();
    wait_health(&health, WAIT, "acknowledging frame 2", |h| {
        h.stamp.frame_seq == 2
    });

    // Every message went into the file.
    assert_eq!(rec.terminate(WAIT), Some(0), "{}", rec.stderr_to_end());
    let (messages, cut) = farsight_recording::read::Recording::open(&out)
        .unwrap()
        .messages()
        .unwrap();
    assert!(cut.is_none());
    let frames: Vec<u64> = messages
        .iter()
        .filter(|m| &*m.topic == "cmd/velocity")
        .map(|m| {
            wire::decode_message::<VelocityCommand>(&m.data)
                .unwrap()
                .stamp
                .frame_seq
        })
        .collect();
    assert_eq!(frames, [1, 0, 0, 2]);
}
