//! `farsight-command-mux`: the one writer of `cmd/velocity` (see the
//! library's documentation). Wiring: each input topic and `safety/estop`
//! into [`CommandMux`], its command out at `output_rate_hz` and at once on
//! every input, a stop on the way out.

use anyhow::Result;
use farsight_command_mux::{CommandMux, MuxConfig, MuxState};
use farsight_interfaces::clock::{Clock, WallClock};
use farsight_interfaces::msg::{CommandReason, HealthState, Stamp, VelocityCommand};
use farsight_interfaces::topics::{self, Topic};
use farsight_interfaces::transport::ipc::{self, Bus};
use farsight_stage::{load_config, Health, StageArgs};
use std::ops::ControlFlow;
use std::time::{Duration, Instant};

const STAGE: &str = "command-mux";

fn main() {
    farsight_stage::run_main(STAGE, run);
}

fn run() -> Result<()> {
    let args = StageArgs::parse(STAGE)?;
    let instance = args.instance.as_str();
    farsight_stage::init_tracing(args.log_format);
    let config: MuxConfig = load_config(args.config.as_deref())?;
    let bus = Bus::open(instance)?;
    let inputs = config
        .inputs
        .iter()
        .map(|i| -> Result<_> {
            let topic = Topic::<VelocityCommand>::new(i.topic.as_str())?;
            Ok(bus.subscriber(&topic)?)
        })
        .collect::<Result<Vec<_>>>()?;
    let estops = bus.subscriber(&topics::estop())?;
    let out = bus.publisher(&topics::velocity_command())?;
    let mut health = Health::new(&bus, instance, config.health_rate_hz)?;
    let period = Duration::from_secs_f64(1.0 / config.output_rate_hz);
    let mut mux = CommandMux::new(config);
    farsight_stage::announce_ready(instance);

    // Receipt times on a monotonic clock: TTLs are counted from receipt.
    let start = Instant::now();
    let mut listeners: Vec<_> = inputs.iter().map(|s| s.listener()).collect();
    listeners.push(estops.listener());
    let mut last_state = None;
    ipc::wait_loop(&listeners, Some(period), |_wake| {
        let now_s = start.elapsed().as_secs_f64();
        for (k, input) in inputs.iter().enumerate() {
            match input.latest() {
                Ok(Some(cmd)) => {
                    health.input();
                    mux.receive(k, cmd, now_s);
                }
                Ok(None) => {}
                Err(e) => health.dropped(&e),
            }
        }
        if let Ok(Some(e)) = estops.latest() {
            mux.estop(&e, now_s);
        }
        let (cmd, state) = mux.command(now_s);
        if last_state.as_ref() != Some(&state) {
            match &state {
                MuxState::Input(name) => {
                    tracing::info!(input = %name, "command source");
                    health.set(HealthState::OK, "");
                }
                MuxState::EStopLatched => health.set(
                    HealthState::DEGRADED,
                    "e-stop latched: an operator clears it (safety/estop active = 2)",
                ),
                MuxState::NoInput => health.set(HealthState::DEGRADED, "no live command input"),
            }
            last_state = Some(state);
        }
        let now_ns = WallClock.now_ns();
        match out.publish(&cmd) {
            Ok(()) => health.output(cmd.stamp, now_ns),
            Err(e) => health.dropped(&e),
        }
        health.tick(now_ns);
        ControlFlow::Continue(())
    })?;
    // Leave the robot stopped.
    let _ = out.publish(&VelocityCommand::stop(
        Stamp::default(),
        CommandReason::STALE_INPUT,
    ));
    health.stopping(WallClock.now_ns());
    Ok(())
}
