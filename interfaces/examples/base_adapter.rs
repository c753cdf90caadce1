//! A reference base adapter: the loop a motor driver runs around
//! [`farsight_interfaces::base::CommandGate`]. It takes `cmd/velocity` from
//! the vehicle bus, and at the motor controller's rate sends the last command
//! while it is within its time-to-live, zero once it has expired, so the base
//! stops by itself when the command writer dies or freezes.
//!
//! Here the "motors" are a line on stdout per motor tick. Replace `send_to_motors`
//! with your platform's call (a CAN frame, a serial packet, a ROS 2 twist)
//! and keep the rest.
//!
//! ```sh
//! cargo run --release -p farsight-interfaces --example base_adapter -- 50 0.5
//! #                                      motor rate (Hz) ^   ^ max TTL (s)
//! ```

use farsight_interfaces::base::CommandGate;
use farsight_interfaces::topics;
use farsight_interfaces::transport::ipc::{self, Bus};
use std::ops::ControlFlow;
use std::time::{Duration, Instant};

fn send_to_motors(linear_mps: f64, angular_radps: f64) {
    println!("motors: v {linear_mps:+.3} m/s, w {angular_radps:+.3} rad/s");
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let rate_hz: f64 = args.next().map_or(Ok(50.0), |a| a.parse())?;
    let max_ttl_s: f64 = args.next().map_or(Ok(0.5), |a| a.parse())?;
    if !(rate_hz.is_finite() && rate_hz > 0.0) {
        return Err(format!("motor rate {rate_hz} Hz: expected a positive rate").into());
    }
    let bus = Bus::open("base-adapter")?;
    let commands = bus.subscriber(&topics::velocity_command())?;
    let mut gate = CommandGate::new(max_ttl_s);
    // The driver's own monotonic clock: never the graph's stamps.
    let t0 = Instant::now();
    ipc::wait_loop(
        &[commands.listener()],
        Some(Duration::from_secs_f64(1.0 / rate_hz)),
        |_wake| {
            let now_s = t0.elapsed().as_secs_f64();
            if let Ok(Some(cmd)) = commands.latest() {
                gate.receive(cmd, now_s);
            }
            // Every tick, changed or not: platforms with a heartbeat
            // timeout expect a steady stream.
            let (v, w) = gate.command(now_s);
            send_to_motors(v, w);
            ControlFlow::Continue(())
        },
    )?;
    send_to_motors(0.0, 0.0);
    Ok(())
}
