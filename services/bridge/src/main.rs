//! `farsight-bridge`: wires [`farsight_bridge`] to the transports. See the
//! library docs for the config file.
//!
//! `farsight-bridge [--config bridge.toml] --print-router-config` prints the
//! robot's zenoh router config for that bridge config (its ACL generated
//! from the import list, [`farsight_bridge::acl`]) and exits.

use anyhow::{Context, Result};
use farsight_bridge::{BridgeConfig, Export, Import};
use farsight_interfaces::clock::{Clock, WallClock};
use farsight_interfaces::msg::HealthState;
use farsight_interfaces::transport::ipc::{self, Bus, LoopExit, Wake};
use farsight_interfaces::transport::net::NetBus;
use farsight_stage::{load_config, Health, StageArgs};
use std::ops::ControlFlow;
use std::time::Duration;
use zenoh::Wait;

const STAGE: &str = "bridge";

fn main() {
    farsight_stage::run_main(STAGE, run);
}

fn run() -> Result<()> {
    let mut argv: Vec<String> = std::env::args().skip(1).collect();
    let print_router = argv.iter().any(|a| a == "--print-router-config");
    argv.retain(|a| a != "--print-router-config");
    let args = StageArgs::parse_from(STAGE, argv)?;
    let instance = args.instance.as_str();
    if print_router {
        let config: BridgeConfig = load_config(args.config.as_deref())?;
        print!("{}", farsight_bridge::acl::router_config(&config));
        return Ok(());
    }
    farsight_stage::init_tracing(args.log_format);
    let config: BridgeConfig = load_config(args.config.as_deref())?;
    let zenoh_config = config.zenoh.to_zenoh(&args.config_dir())?;
    if let Some(why) = farsight_bridge::acl::mismatch(&zenoh_config, &config) {
        tracing::warn!(file = %config.zenoh.config_file, "zenoh config: {why}");
    }
    let bus = Bus::open(instance)?;
    let net = NetBus::open(zenoh_config, &config.robot).context("opening the zenoh session")?;
    // A laptop lists live stages with a liveliness query on farsight/<robot>/alive/**.
    let _alive = net
        .session()
        .liveliness()
        .declare_token(net.key(&format!("alive/{instance}")))
        .wait()
        .map_err(|e| anyhow::anyhow!("declaring liveliness: {e}"))?;
    let exports = config
        .export
        .iter()
        .cloned()
        .map(|c| Export::open(&bus, &net, c))
        .collect::<Result<Vec<_>, _>>()?;
    let mut imports = config
        .import
        .iter()
        .map(|c| Import::open(&bus, &net, c))
        .collect::<Result<Vec<_>, _>>()?;
    let mut health = Health::new(&bus, instance, config.health_rate_hz)?;
    health.set(HealthState::OK, "");
    let clock = WallClock;
    tracing::info!(
        robot = %config.robot,
        exports = ?exports.iter().map(Export::topic).collect::<Vec<_>>(),
        imports = ?imports.iter().map(Import::topic).collect::<Vec<_>>(),
        "bridge config"
    );
    farsight_stage::announce_ready(instance);

    let listeners: Vec<_> = exports.iter().map(Export::listener).collect();
    let tick = Duration::from_secs_f64(1.0 / config.import_poll_hz);
    let mut last_cleanup = clock.now_ns();
    let exit = ipc::wait_loop(&listeners, Some(tick), |wake| {
        let now = clock.now_ns();
        match wake {
            Wake::Input(i) => {
                health.input();
                match exports[i].pump(now) {
                    Ok(true) => health.output(Default::default(), now),
                    Ok(false) => {}
                    Err(e) => health.dropped(&format_args!("export {}: {e:#}", exports[i].topic())),
                }
            }
            Wake::Tick => {
                for im in imports.iter_mut() {
                    match im.pump() {
                        Ok(true) => health.output(Default::default(), now),
                        Ok(false) => {}
                        Err(e) => health.dropped(&format_args!("import {}: {e}", im.topic())),
                    }
                }
                if now.saturating_sub(last_cleanup) > 5_000_000_000 {
                    bus.cleanup_dead_nodes();
                    last_cleanup = now;
                }
            }
        }
        health.tick(now);
        ControlFlow::Continue(())
    })?;
    if exit == LoopExit::Terminated {
        tracing::info!("SIGTERM: shutting down");
    }
    health.stopping(clock.now_ns());
    Ok(())
}
