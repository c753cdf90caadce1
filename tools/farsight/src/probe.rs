//! Transport probes: publish test frames whose every byte is a function of the
//! sequence number, and receive them checking every byte and the order. Users run
//! them to check shared memory / zenoh on a new machine; the end-to-end tests run
//! them as separate processes.

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand};
use farsight_interfaces::clock::{Clock, WallClock};
use farsight_interfaces::msg::*;
use farsight_interfaces::topics;
use farsight_interfaces::transport::ipc::{self, Bus, Wake};
use farsight_interfaces::transport::net::NetBus;
use std::io::Write;
use std::ops::ControlFlow;
use std::time::{Duration, Instant};

#[derive(Subcommand)]
pub enum ProbeCommand {
    /// Publish RGB test frames on camera/<camera>/image over iceoryx2.
    Publish(PublishArgs),
    /// Receive test frames over iceoryx2 and check every byte and the order.
    Subscribe(SubscribeArgs),
    /// Receive test frames over zenoh (e.g. through the bridge) and check them.
    NetSubscribe(NetSubscribeArgs),
    /// Publish a pose and a goal over zenoh, repeatedly (for bridge imports).
    NetPublishNav(NetPublishNavArgs),
}

#[derive(Args)]
pub struct PublishArgs {
    #[arg(long, default_value = "probe")]
    camera: String,
    #[arg(long, default_value_t = 1440)]
    width: u32,
    #[arg(long, default_value_t = 1080)]
    height: u32,
    #[arg(long, default_value_t = 30.0)]
    rate_hz: f64,
    /// Stop after this many frames (default: run until SIGTERM).
    #[arg(long)]
    frames: Option<u64>,
    /// Sequence number of the first frame (a restarted publisher continues above the old one).
    #[arg(long, default_value_t = 1)]
    start_seq: u64,
}

#[derive(Args)]
pub struct SubscribeArgs {
    #[arg(long, default_value = "probe")]
    camera: String,
    /// Exit after this many frames.
    #[arg(long)]
    frames: Option<u64>,
    /// Exit after this long without frames (seconds).
    #[arg(long, default_value_t = 10.0)]
    idle_timeout_s: f64,
    /// Print a line per frame (`frame <seq>`), for tests that watch progress.
    #[arg(long)]
    each: bool,
}

#[derive(Args)]
pub struct NetSubscribeArgs {
    /// zenoh endpoint to connect to, e.g. tcp/127.0.0.1:7447.
    #[arg(long)]
    connect: String,
    #[arg(long, default_value = "robot")]
    robot: String,
    #[arg(long, default_value = "probe")]
    camera: String,
    #[arg(long, default_value_t = 5)]
    frames: u64,
    #[arg(long, default_value_t = 20.0)]
    timeout_s: f64,
}

#[derive(Args)]
pub struct NetPublishNavArgs {
    #[arg(long)]
    connect: String,
    #[command(flatten)]
    login: crate::Login,
    #[arg(long, default_value = "robot")]
    robot: String,
    #[arg(long, default_value_t = 10.0)]
    duration_s: f64,
    /// Also send a teleop velocity command (0.2 m/s ahead) on `cmd/teleop`
    /// each time: what an operator's joystick does (through the robot's
    /// command mux), and what a laptop must not be able to.
    #[arg(long)]
    velocity: bool,
}

/// The value of byte `i` of test frame `seq`: changes with both, so a torn or
/// stale frame shows up as a mismatch.
pub fn pattern_byte(seq: u64, i: usize) -> u8 {
    ((i % 251) as u8).wrapping_add((seq as u8).wrapping_mul(17))
}

/// Fills `buf` with the pattern of frame `seq`.
pub fn fill_pattern(seq: u64, buf: &mut [u8]) {
    for (i, b) in buf.iter_mut().enumerate() {
        *b = pattern_byte(seq, i);
    }
}

/// Index of the first byte of `buf` that is not frame `seq`'s pattern.
pub fn first_mismatch(seq: u64, buf: &[u8]) -> Option<usize> {
    buf.iter()
        .enumerate()
        .position(|(i, &b)| b != pattern_byte(seq, i))
}

pub fn run(cmd: ProbeCommand) -> Result<()> {
    match cmd {
        ProbeCommand::Publish(a) => publish(a),
        ProbeCommand::Subscribe(a) => subscribe(a),
        ProbeCommand::NetSubscribe(a) => net_subscribe(a),
        ProbeCommand::NetPublishNav(a) => net_publish_nav(a),
    }
}

fn publish(a: PublishArgs) -> Result<()> {
    if !(a.rate_hz > 0.0 && a.rate_hz.is_finite()) {
        bail!("--rate-hz {}: expected a positive rate", a.rate_hz);
    }
    let bus = Bus::open("probe-publisher")?;
    let len = a.width as usize * a.height as usize * 3;
    let frames = bus.slice_publisher(&topics::camera_image(&a.camera), len)?;
    let mut seq = a.start_seq;
    let mut sent = 0u64;
    let period = Duration::from_secs_f64(1.0 / a.rate_hz);
    println!(
        "publishing {}x{} rgb8 at {} Hz on {}",
        a.width,
        a.height,
        a.rate_hz,
        frames.topic()
    );
    let exit = ipc::wait_loop(&[], Some(period), |_| {
        let sent_frame = frames.publish_with(len, |px| {
            fill_pattern(seq, px);
            ImageHeader::packed(
                Stamp::new(seq, WallClock.now_ns()),
                0,
                a.width,
                a.height,
                PixelEncoding::RGB8,
            )
        });
        if let Err(e) = sent_frame {
            eprintln!("publish failed: {e}");
            return ControlFlow::Break(());
        }
        seq += 1;
        sent += 1;
        match a.frames {
            Some(n) if sent >= n => ControlFlow::Break(()),
            _ => ControlFlow::Continue(()),
        }
    })?;
    println!("sent {sent} frames ({exit:?})");
    Ok(())
}

fn subscribe(a: SubscribeArgs) -> Result<()> {
    let bus = Bus::open("probe-subscriber")?;
    let sub = bus.slice_subscriber(&topics::camera_image(&a.camera))?;
    let (mut received, mut corrupt, mut non_increasing) = (0u64, 0u64, 0u64);
    let mut last_seq: Option<u64> = None;
    let mut last_frame = Instant::now();
    let idle = Duration::from_secs_f64(a.idle_timeout_s);
    let mut timed_out = false;
    let mut failure: Option<String> = None;
    println!("subscribed to {}", sub.topic());
    std::io::stdout().flush().ok();
    ipc::wait_loop(
        &[sub.listener()],
        Some(Duration::from_millis(100)),
        |wake| {
            let frame = match sub.latest() {
                Ok(f) => f,
                Err(e) => {
                    failure = Some(e.to_string());
                    return ControlFlow::Break(());
                }
            };
            let Some(frame) = frame else {
                if wake == Wake::Tick && last_frame.elapsed() > idle {
                    timed_out = true;
                    return ControlFlow::Break(());
                }
                return ControlFlow::Continue(());
            };
            last_frame = Instant::now();
            received += 1;
            let h = *frame.header();
            if let Err(e) = h.validate(frame.data().len()) {
                corrupt += 1;
                eprintln!("frame {}: {e}", h.stamp.frame_seq);
            } else if let Some(i) = first_mismatch(h.stamp.frame_seq, frame.data()) {
                corrupt += 1;
                eprintln!(
                    "frame {}: byte {i} differs from the pattern",
                    h.stamp.frame_seq
                );
            }
            if let Some(last) = last_seq {
                if h.stamp.frame_seq <= last {
                    non_increasing += 1;
                    eprintln!(
                        "frame {} after {last}: sequence did not increase",
                        h.stamp.frame_seq
                    );
                }
            }
            last_seq = Some(h.stamp.frame_seq);
            if a.each {
                println!("frame {}", h.stamp.frame_seq);
                std::io::stdout().flush().ok();
            }
            if a.frames.is_some_and(|n| received >= n) {
                ControlFlow::Break(())
            } else {
                ControlFlow::Continue(())
            }
        },
    )?;
    let s = sub.skips();
    println!(
        "summary received={received} corrupt={corrupt} non_increasing={non_increasing} skipped={} timed_out={timed_out}",
        s.skipped
    );
    if let Some(f) = failure {
        bail!("receive failed: {f}");
    }
    if corrupt > 0 || non_increasing > 0 {
        bail!("{corrupt} corrupt and {non_increasing} out-of-order frames");
    }
    if let Some(n) = a.frames {
        if received < n {
            bail!(
                "received {received} of {n} frames before going idle for {}s",
                a.idle_timeout_s
            );
        }
    }
    Ok(())
}

fn net_bus(connect: &str, robot: &str) -> Result<NetBus> {
    let config = NetBus::config("peer", &[], &[connect.to_string()])?;
    NetBus::open(config, robot).context("opening zenoh session")
}

fn net_subscribe(a: NetSubscribeArgs) -> Result<()> {
    let bus = net_bus(&a.connect, &a.robot)?;
    let mut sub = bus.slice_subscriber(&topics::camera_image(&a.camera))?;
    let deadline = Instant::now() + Duration::from_secs_f64(a.timeout_s);
    let mut received = 0u64;
    while received < a.frames {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            bail!(
                "received {received} of {} frames over zenoh within {}s",
                a.frames,
                a.timeout_s
            );
        }
        let Some((h, data)) = sub.recv_timeout(left)? else {
            continue;
        };
        h.validate(data.len())
            .with_context(|| format!("frame {}", h.stamp.frame_seq))?;
        if let Some(i) = first_mismatch(h.stamp.frame_seq, &data) {
            bail!(
                "frame {}: byte {i} differs from the pattern",
                h.stamp.frame_seq
            );
        }
        received += 1;
        println!(
            "frame {} {}x{} intact",
            h.stamp.frame_seq, h.width, h.height
        );
    }
    println!("summary received={received} corrupt=0");
    Ok(())
}

fn net_publish_nav(a: NetPublishNavArgs) -> Result<()> {
    let config = a
        .login
        .client_config("client", std::slice::from_ref(&a.connect))?;
    let bus = NetBus::open(config, &a.robot).context("opening zenoh session")?;
    let mut pose_pub = bus.publisher(&topics::pose())?;
    let mut goal_pub = bus.publisher(&topics::goal())?;
    let mut cmd_pub = bus.publisher(&topics::command_input("teleop"))?;
    let end = Instant::now() + Duration::from_secs_f64(a.duration_s);
    let mut seq = 1;
    while Instant::now() < end {
        let stamp = Stamp::new(seq, WallClock.now_ns());
        pose_pub.publish(&Pose {
            stamp,
            position_m: [1.0, 2.0, 0.0],
            yaw_rad: 0.5,
            ..Default::default()
        })?;
        goal_pub.publish(&NavGoal {
            stamp,
            kind: GoalKind::GPS,
            latitude_deg: 40.4406,
            longitude_deg: -79.9959,
            tolerance_m: 2.0,
            ..Default::default()
        })?;
        if a.velocity {
            cmd_pub.publish(&VelocityCommand {
                stamp,
                linear_mps: 0.2,
                angular_radps: 0.0,
                reason: CommandReason::TELEOP,
                // Sent every 50 ms: obeyed for two periods, then the base stops.
                ttl_ms: 100,
            })?;
        }
        seq += 1;
        std::thread::sleep(Duration::from_millis(50));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pattern_differs_between_frames_and_detects_a_flipped_byte() {
        let mut a = vec![0u8; 1000];
        fill_pattern(5, &mut a);
        assert_eq!(first_mismatch(5, &a), None);
        assert_eq!(first_mismatch(6, &a), Some(0));
        a[777] ^= 1;
        assert_eq!(first_mismatch(5, &a), Some(777));
    }
}
