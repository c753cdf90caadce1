//! The command mux stage as a library type ([`MuxStage`]): the one writer
//! of `cmd/velocity`. Each configured input topic and `safety/estop` feed a
//! [`CommandMux`] (priorities, TTL caps counted from receipt, the latched
//! e-stop, the operator deadman: see the crate's documentation), and its
//! command goes out at `output_rate_hz` (the tick) and at once on every
//! message, so an e-stop or an operator's takeover reaches the base without
//! waiting for the tick. On a clean stop its last words are a stop.
//!
//! Receipt times are the step's `wall_ns`: the system clock in a process,
//! the simulated clock in the in-process executor, so the same rules run
//! in simulation. A clock that goes back makes no command live
//! ([`farsight_interfaces::base::CommandGate`]): it stops, never drives.

use crate::{CommandMux, MuxConfig, MuxState};
use farsight_interfaces::msg::{CommandReason, EStop, HealthState, Stamp, VelocityCommand};
use farsight_interfaces::topics::{self, Topic};
use farsight_stage::{Outbox, Ports, Stage, StageEnv, StageKind, Step};
use std::time::Duration;

/// The mux stage: the mux, its ports, and the source last reported.
pub struct MuxStage {
    mux: CommandMux,
    ports: Ports,
    /// The input port of each configured input, in the config's order (the
    /// mux's input index).
    inputs: Vec<usize>,
    estop: usize,
    command: usize,
    /// The state last reported: health and the log change only on a change.
    last_state: Option<MuxState>,
    /// The first step's wall time: the mux counts seconds from it, as it
    /// counted them from its start, so TTLs keep nanosecond resolution (an
    /// f64 of seconds since 1970 resolves only about 0.2 us).
    origin_ns: Option<u64>,
}

impl StageKind for MuxStage {
    const KIND: &'static str = "command-mux";
    type Config = MuxConfig;

    fn new(config: MuxConfig, _env: &StageEnv) -> anyhow::Result<Self> {
        let mut ports = Ports {
            tick: Some(Duration::from_secs_f64(1.0 / config.output_rate_hz)),
            health_rate_hz: config.health_rate_hz,
            ..Ports::default()
        };
        // Every input wakes the step: a command goes out at once on each.
        let inputs = config
            .inputs
            .iter()
            .map(|i| -> anyhow::Result<usize> {
                let topic = Topic::<VelocityCommand>::new(i.topic.as_str())?;
                Ok(ports.waking_input(topic.name()))
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        let estop = ports.waking_input(topics::estop().name());
        let command = ports.output(topics::velocity_command().name());
        Ok(Self {
            mux: CommandMux::new(config),
            ports,
            inputs,
            estop,
            command,
            last_state: None,
            origin_ns: None,
        })
    }
}

impl Stage for MuxStage {
    fn ports(&self) -> &Ports {
        &self.ports
    }

    fn step(&mut self, step: &mut Step<'_>) {
        let origin = *self.origin_ns.get_or_insert(step.wall_ns);
        // Signed: a clock that went back gives a negative time, which makes
        // no command live.
        let now_s = (i128::from(step.wall_ns) - i128::from(origin)) as f64 * 1e-9;
        // Commands first, then the e-stop: a press in the same step wins.
        for (k, &port) in self.inputs.iter().enumerate() {
            if let Some(cmd) = step.inbox.take::<VelocityCommand>(port) {
                step.health.input();
                self.mux.receive(k, cmd, now_s);
            }
        }
        if let Some(e) = step.inbox.take::<EStop>(self.estop) {
            self.mux.estop(&e, now_s);
        }
        let (cmd, state) = self.mux.command(now_s);
        if self.last_state.as_ref() != Some(&state) {
            match &state {
                MuxState::Input(name) => {
                    tracing::info!(input = %name, "command source");
                    step.health.set(HealthState::OK, "");
                }
                MuxState::EStopLatched => step.health.set(
                    HealthState::DEGRADED,
                    "e-stop latched: an operator clears it (safety/estop active = 2)",
                ),
                MuxState::NoInput => step
                    .health
                    .set(HealthState::DEGRADED, "no live command input"),
            }
            self.last_state = Some(state);
        }
        // Every step sends, tick or message: the base hears the mux at its
        // rate, and at once when anything changed.
        step.out.send(self.command, cmd);
        step.health.output(cmd.stamp, step.wall_ns);
    }

    fn stop(&mut self, out: &mut Outbox) {
        // Leave the robot stopped.
        out.send(
            self.command,
            VelocityCommand::stop(Stamp::default(), CommandReason::STALE_INPUT),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use farsight_interfaces::message::Message;
    use farsight_stage::runtime::{check_ports, Harness};
    use farsight_stage::{DeclaresTopics, Wake};

    const MS: u64 = 1_000_000;
    /// Wall times near a real epoch, as in a process.
    const T0: u64 = 1_700_000_000_000_000_000;
    const TELEOP: &str = "cmd/teleop";
    const AUTONOMY: &str = "cmd/autonomy";
    const ESTOP: &str = "safety/estop";

    fn stage(toml: &str) -> Harness<MuxStage> {
        let config: MuxConfig = farsight_stage::parse_config(toml, "command-mux.toml").unwrap();
        let env = StageEnv {
            instance: "command-mux".into(),
            config_dir: ".".into(),
        };
        Harness::new(MuxStage::new(config, &env).unwrap())
    }

    fn cmd(v: f32, reason: CommandReason, ttl_ms: u16) -> VelocityCommand {
        VelocityCommand {
            stamp: Stamp::new(9, 0),
            linear_mps: v,
            angular_radps: 0.0,
            reason,
            ttl_ms,
        }
    }

    fn estop(active: u8) -> EStop {
        EStop {
            active,
            ..Default::default()
        }
    }

    /// The one command a step sent.
    fn sent(out: Vec<(String, Message)>) -> VelocityCommand {
        assert_eq!(out.len(), 1, "{out:?}");
        let (topic, m) = out.into_iter().next().unwrap();
        assert_eq!(topic, "cmd/velocity");
        VelocityCommand::try_from(m).unwrap()
    }

    fn reason(h: &Harness<MuxStage>) -> String {
        h.health.report().reason.as_str().to_string()
    }

    #[test]
    fn the_live_input_of_highest_priority_wins_and_every_wake_sends() {
        let mut h = stage("");
        let (teleop, autonomy) = (h.wake_on(TELEOP), h.wake_on(AUTONOMY));
        h.put(AUTONOMY, cmd(0.8, CommandReason::TRACKING, 250));
        let c = sent(h.step(autonomy, T0));
        assert_eq!((c.linear_mps, c.reason), (0.8, CommandReason::TRACKING));
        assert_eq!(c.stamp, Stamp::new(9, 0), "the winner's stamp");
        assert_eq!(c.ttl_ms, 250);
        assert_eq!(h.health.state(), HealthState::OK);
        // The operator holds the robot still: a zero teleop command wins
        // over autonomy arriving in the same step.
        h.put(TELEOP, cmd(0.0, CommandReason::TELEOP, 300));
        h.put(AUTONOMY, cmd(0.8, CommandReason::TRACKING, 250));
        let c = sent(h.step(teleop, T0 + 50 * MS));
        assert_eq!((c.linear_mps, c.reason), (0.0, CommandReason::TELEOP));
        // A tick with nothing new still sends the winner, with what is left
        // of its life.
        let c = sent(h.step(Wake::Tick, T0 + 150 * MS));
        assert_eq!((c.reason, c.ttl_ms), (CommandReason::TELEOP, 200));
        assert_eq!(h.health.report().messages_in, 3);
        assert_eq!(h.health.report().messages_out, 3);
    }

    #[test]
    fn a_stale_source_stops_the_robot_and_the_next_in_line_takes_over() {
        let mut h = stage("");
        let teleop = h.wake_on(TELEOP);
        h.put(TELEOP, cmd(0.5, CommandReason::TELEOP, 60_000));
        h.put(AUTONOMY, cmd(0.3, CommandReason::TRACKING, 1000));
        assert_eq!(sent(h.step(teleop, T0)).reason, CommandReason::TELEOP);
        // Teleop asked for a minute; its input's cap is 0.5 s. Autonomy's
        // own command is capped at 0.5 s too, so both are gone by then.
        let c = sent(h.step(Wake::Tick, T0 + 499 * MS));
        assert_eq!(c.reason, CommandReason::TELEOP);
        let c = sent(h.step(Wake::Tick, T0 + 500 * MS));
        assert_eq!(
            (c.linear_mps, c.angular_radps, c.reason),
            (0.0, 0.0, CommandReason::STALE_INPUT)
        );
        assert_eq!(h.health.state(), HealthState::DEGRADED);
        assert_eq!(reason(&h), "no live command input");
        // Autonomy alone, live: it drives; teleop's silence hands it over.
        let autonomy = h.wake_on(AUTONOMY);
        h.put(AUTONOMY, cmd(0.3, CommandReason::TRACKING, 250));
        let c = sent(h.step(autonomy, T0 + 600 * MS));
        assert_eq!((c.linear_mps, c.reason), (0.3, CommandReason::TRACKING));
        assert_eq!(h.health.state(), HealthState::OK);
        // And stops once its own TTL has run out.
        let c = sent(h.step(Wake::Tick, T0 + 850 * MS));
        assert_eq!(c.reason, CommandReason::STALE_INPUT);
    }

    #[test]
    fn the_estop_stops_at_once_and_stays_latched_until_an_operator_clears_it() {
        let mut h = stage("");
        let wake = h.wake_on(ESTOP);
        h.put(AUTONOMY, cmd(1.0, CommandReason::TRACKING, 250));
        h.put(TELEOP, cmd(0.5, CommandReason::TELEOP, 250));
        h.put(ESTOP, estop(EStop::PRESSED));
        // Pressed in the same step as live commands: it wins, without
        // waiting for the tick.
        let c = sent(h.step(wake, T0));
        assert_eq!((c.linear_mps, c.reason), (0.0, CommandReason::ESTOP));
        assert_eq!(h.health.state(), HealthState::DEGRADED);
        assert!(reason(&h).starts_with("e-stop latched"), "{}", reason(&h));
        // Released is not cleared, whatever the inputs say.
        h.put(ESTOP, estop(EStop::RELEASED));
        h.put(TELEOP, cmd(0.5, CommandReason::TELEOP, 250));
        assert_eq!(
            sent(h.step(wake, T0 + 50 * MS)).reason,
            CommandReason::ESTOP
        );
        h.put(TELEOP, cmd(0.5, CommandReason::TELEOP, 250));
        assert_eq!(
            sent(h.step(h.wake_on(TELEOP), T0 + 60 * MS)).reason,
            CommandReason::ESTOP
        );
        // Cleared by the operator: the inputs count again.
        h.put(ESTOP, estop(EStop::CLEAR));
        let c = sent(h.step(wake, T0 + 100 * MS));
        assert_eq!((c.linear_mps, c.reason), (0.5, CommandReason::TELEOP));
        assert_eq!(h.health.state(), HealthState::OK);
    }

    #[test]
    fn with_a_deadman_teleop_stops_when_the_operator_heartbeat_does() {
        let mut h = stage("deadman_timeout_s = 0.5\non_operator_loss = \"continue\"\n");
        let wake = h.wake_on(TELEOP);
        h.put(ESTOP, estop(EStop::RELEASED));
        h.put(TELEOP, cmd(0.2, CommandReason::TELEOP, 2000));
        h.put(AUTONOMY, cmd(0.8, CommandReason::TRACKING, 2000));
        assert_eq!(sent(h.step(wake, T0)).reason, CommandReason::TELEOP);
        h.put(TELEOP, cmd(0.2, CommandReason::TELEOP, 2000));
        h.put(AUTONOMY, cmd(0.8, CommandReason::TRACKING, 2000));
        // No heartbeat for 0.5 s: teleop is dropped, autonomy continues.
        let c = sent(h.step(wake, T0 + 500 * MS));
        assert_eq!((c.linear_mps, c.reason), (0.8, CommandReason::TRACKING));
    }

    #[test]
    fn a_clean_stop_leaves_the_robot_stopped() {
        let mut h = stage("");
        let c = sent(h.stop());
        assert_eq!(
            (c.linear_mps, c.angular_radps, c.reason),
            (0.0, 0.0, CommandReason::STALE_INPUT)
        );
    }

    #[test]
    fn ports_are_what_the_config_declares_to_the_graph() {
        let two = "[[inputs]]\nname = \"a\"\ntopic = \"cmd/a\"\npriority = 1\nmax_ttl_s = 0.5\n\
                   [[inputs]]\nname = \"b\"\ntopic = \"cmd/b\"\npriority = 2\nmax_ttl_s = 0.5\n";
        for toml in ["", "deadman_timeout_s = 0.5\n", two] {
            let config: MuxConfig = farsight_stage::parse_config(toml, "m.toml").unwrap();
            let io = config.topics("command-mux", ".".as_ref()).unwrap();
            let h = stage(toml);
            check_ports(&io, h.stage.ports()).unwrap_or_else(|e| panic!("{toml}: {e}"));
            // Every input and the e-stop wake the step.
            assert!(h.stage.ports().inputs.iter().all(|p| p.wakes));
            assert_eq!(h.stage.ports().inputs.len(), config.inputs.len() + 1);
        }
        assert_eq!(
            stage("output_rate_hz = 50.0").stage.ports().tick,
            Some(Duration::from_millis(20))
        );
    }
}
