//! # farsight-command-mux
//!
//! The one writer of the robot's command topic `cmd/velocity`, as Nav2's
//! `twist_mux` with its collision monitor's gate in front of the base:
//!
//! - **inputs with priorities**: each input is a topic of velocity commands
//!   (`cmd/teleop` from the operator through the bridge, `cmd/autonomy` from
//!   the servo); the live input of highest priority wins, even when it says
//!   stop (an operator holding the robot still overrides autonomy);
//! - **a TTL cap per input**: an input's command is live for its own
//!   `ttl_ms` from *receipt*, at most the input's `max_ttl_s`
//!   ([`farsight_interfaces::base::CommandGate`], the rule bases obey), so
//!   a teleop link that hangs cannot hold a command for longer;
//! - **a latched e-stop**: an [`EStop`] with `active = 1` on `safety/estop`
//!   stops the output until an operator sends `active = 2` (clear);
//!   releasing the button (`active = 0`) does not clear it;
//! - **an optional deadman**: with `deadman_timeout_s > 0` the operator link
//!   is alive while e-stop messages keep arriving (the operator's e-stop
//!   tool sends its state as a heartbeat); lost, operator inputs stop at
//!   once and autonomy goes on or stops as `on_operator_loss` says.
//!
//! The output carries the winning command's stamp and reason and, as its
//! time-to-live, what is left of the winner's life, so a dead mux stops the
//! base as a dead servo would. Without a live input it is a zero command
//! with reason `stale_input`.
//!
//! Config (`command-mux.toml`, defaults shown):
//!
//! ```toml
//! output_rate_hz = 20.0          # cmd/velocity at this rate, and on every input
//! health_rate_hz = 1.0
//! deadman_timeout_s = 0.0        # 0: no deadman; else the operator link is lost after
//!                                # this long without a message on safety/estop
//! on_operator_loss = "stop"      # autonomy with the link lost: "stop" or "continue"
//!
//! [[inputs]]                     # the default inputs:
//! name = "teleop"
//! topic = "cmd/teleop"
//! priority = 100                 # higher wins
//! max_ttl_s = 0.5                # a command is live at most this long after receipt
//! operator = true                # stops at once when the operator link is lost
//!
//! [[inputs]]
//! name = "autonomy"
//! topic = "cmd/autonomy"         # the servo's command_topic
//! priority = 10
//! max_ttl_s = 0.5
//! operator = false
//! ```

pub mod mux_stage;

use farsight_interfaces::base::CommandGate;
use farsight_interfaces::msg::{CommandReason, EStop, VelocityCommand};
use farsight_interfaces::topics;
use farsight_stage::ranges::RATE_HZ;
use farsight_stage::{ConfigError, Io, Need, Range, Ranges, Validate};
use serde::{Deserialize, Serialize};

/// What autonomy does when the operator link is lost.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum OnOperatorLoss {
    /// Autonomy stops too: nobody is watching.
    #[default]
    Stop,
    /// Autonomy goes on; only operator inputs stop.
    Continue,
}

/// One input of the mux.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MuxInputConfig {
    pub name: String,
    /// A velocity command topic, `cmd/<name>`.
    pub topic: String,
    pub priority: u8,
    pub max_ttl_s: f64,
    /// Driven by the operator through the link the deadman watches.
    #[serde(default)]
    pub operator: bool,
}

/// The stage's config.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MuxConfig {
    pub output_rate_hz: f64,
    pub health_rate_hz: f64,
    pub deadman_timeout_s: f64,
    pub on_operator_loss: OnOperatorLoss,
    pub inputs: Vec<MuxInputConfig>,
}

impl Default for MuxConfig {
    fn default() -> Self {
        Self {
            output_rate_hz: 20.0,
            health_rate_hz: 1.0,
            deadman_timeout_s: 0.0,
            on_operator_loss: OnOperatorLoss::Stop,
            inputs: vec![
                MuxInputConfig {
                    name: "teleop".into(),
                    topic: "cmd/teleop".into(),
                    priority: 100,
                    max_ttl_s: 0.5,
                    operator: true,
                },
                MuxInputConfig {
                    name: "autonomy".into(),
                    topic: "cmd/autonomy".into(),
                    priority: 10,
                    max_ttl_s: 0.5,
                    operator: false,
                },
            ],
        }
    }
}

impl farsight_stage::DeclaresTopics for MuxConfig {
    fn topics(&self, instance: &str, _: &std::path::Path) -> Result<Io, String> {
        let mut io = Io::for_instance(instance);
        for input in &self.inputs {
            io.read(input.topic.clone(), Need::Optional);
        }
        // With a deadman, no e-stop heartbeat means no motion.
        let estop = if self.deadman_timeout_s > 0.0 {
            Need::Required
        } else {
            Need::Optional
        };
        io.read(topics::estop().name(), estop)
            .write(topics::velocity_command().name());
        Ok(io)
    }
}

impl Validate for MuxConfig {
    fn ranges(&self, r: &mut Ranges) {
        r.key("output_rate_hz", self.output_rate_hz, RATE_HZ)
            .key("health_rate_hz", self.health_rate_hz, RATE_HZ)
            // 0: no deadman.
            .key(
                "deadman_timeout_s",
                self.deadman_timeout_s,
                Range::between(0.0, 60.0).unit("s"),
            );
        for (i, input) in self.inputs.iter().enumerate() {
            r.key(
                &format!("inputs[{i}].priority"),
                input.priority,
                Range::between(0.0, 255.0),
            )
            .key(
                &format!("inputs[{i}].max_ttl_s"),
                input.max_ttl_s,
                Range::above_to(0.0, 60.0).unit("s"),
            );
        }
    }

    fn check_rules(&self) -> Result<(), ConfigError> {
        ConfigError::check(
            !self.inputs.is_empty(),
            "inputs",
            "[]",
            "at least one [[inputs]] table",
        )?;
        let mut names = std::collections::HashSet::new();
        let mut topics_seen = std::collections::HashSet::new();
        for (i, input) in self.inputs.iter().enumerate() {
            let key = |k: &str| format!("inputs[{i}].{k}");
            ConfigError::check(
                !input.name.is_empty() && names.insert(input.name.as_str()),
                &key("name"),
                &input.name,
                "a name used once",
            )?;
            ConfigError::check(
                matches!(
                    topics::kind_of(&input.topic),
                    Some(topics::TopicKind::VelocityCommand)
                ) && input.topic != topics::velocity_command().name()
                    && topics_seen.insert(input.topic.as_str()),
                &key("topic"),
                &input.topic,
                "a command topic cmd/<name> other than cmd/velocity (the mux's output), used once",
            )?;
        }
        Ok(())
    }
}

/// Why the mux sends what it sends.
#[derive(Debug, Clone, PartialEq)]
pub enum MuxState {
    /// Input `name` wins.
    Input(String),
    /// The e-stop is latched.
    EStopLatched,
    /// No input is live.
    NoInput,
}

/// The mux: the inputs' last commands, the e-stop latch and the operator
/// link. Times are the mux's monotonic seconds of receipt.
#[derive(Debug, Clone)]
pub struct CommandMux {
    config: MuxConfig,
    gates: Vec<CommandGate>,
    estop_latched: bool,
    operator_heard_s: Option<f64>,
}

impl CommandMux {
    pub fn new(config: MuxConfig) -> Self {
        let gates = config
            .inputs
            .iter()
            .map(|i| CommandGate::new(i.max_ttl_s))
            .collect();
        Self {
            config,
            gates,
            estop_latched: false,
            operator_heard_s: None,
        }
    }

    pub fn config(&self) -> &MuxConfig {
        &self.config
    }

    /// Takes input `index`'s command, received at `now_s`.
    pub fn receive(&mut self, index: usize, cmd: VelocityCommand, now_s: f64) {
        self.gates[index].receive(cmd, now_s);
    }

    /// Takes an e-stop message received at `now_s`: pressed latches, clear
    /// (from an operator) unlatches, and any message is the operator's
    /// heartbeat.
    pub fn estop(&mut self, msg: &EStop, now_s: f64) {
        match msg.active {
            EStop::PRESSED => self.estop_latched = true,
            EStop::CLEAR => self.estop_latched = false,
            _ => {}
        }
        self.operator_heard_s = Some(now_s);
    }

    pub fn estop_latched(&self) -> bool {
        self.estop_latched
    }

    /// `false` once the deadman has gone `deadman_timeout_s` without hearing
    /// the operator (never heard counts as lost); always `true` without a
    /// deadman.
    pub fn operator_link_alive(&self, now_s: f64) -> bool {
        self.config.deadman_timeout_s == 0.0
            || self
                .operator_heard_s
                .is_some_and(|t| (0.0..self.config.deadman_timeout_s).contains(&(now_s - t)))
    }

    /// The command for `cmd/velocity` at `now_s`, and why.
    pub fn command(&self, now_s: f64) -> (VelocityCommand, MuxState) {
        if self.estop_latched {
            let stop = VelocityCommand::stop(Default::default(), CommandReason::ESTOP);
            return (stop, MuxState::EStopLatched);
        }
        let link = self.operator_link_alive(now_s);
        let allowed = |input: &MuxInputConfig| {
            link || (!input.operator && self.config.on_operator_loss == OnOperatorLoss::Continue)
        };
        let winner = self
            .config
            .inputs
            .iter()
            .zip(&self.gates)
            .filter(|(input, _)| allowed(input))
            .filter_map(|(input, gate)| gate.live(now_s).map(|l| (input, l)))
            .max_by_key(|(input, _)| input.priority);
        match winner {
            Some((input, (cmd, ttl_left_s))) => {
                let out = VelocityCommand {
                    // What is left of the winner's life: a dead mux stops
                    // the base no later than the winner itself would have.
                    ttl_ms: (ttl_left_s * 1e3).round().clamp(1.0, f64::from(u16::MAX)) as u16,
                    ..*cmd
                };
                (out, MuxState::Input(input.name.clone()))
            }
            None => (
                VelocityCommand::stop(Default::default(), CommandReason::STALE_INPUT),
                MuxState::NoInput,
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use farsight_interfaces::msg::Stamp;

    fn cmd(v: f32, reason: CommandReason, ttl_ms: u16) -> VelocityCommand {
        VelocityCommand {
            stamp: Stamp::new(3, 0),
            linear_mps: v,
            angular_radps: 0.0,
            reason,
            ttl_ms,
        }
    }

    const TELEOP: usize = 0;
    const AUTONOMY: usize = 1;

    #[test]
    fn teleop_outranks_autonomy_while_live_even_when_it_says_stop() {
        let mut mux = CommandMux::new(MuxConfig::default());
        assert_eq!(mux.command(0.0).1, MuxState::NoInput);
        assert_eq!(mux.command(0.0).0.linear_mps, 0.0);
        mux.receive(AUTONOMY, cmd(1.0, CommandReason::TRACKING, 250), 10.0);
        let (out, state) = mux.command(10.1);
        assert_eq!(state, MuxState::Input("autonomy".into()));
        assert_eq!((out.linear_mps, out.reason), (1.0, CommandReason::TRACKING));
        assert_eq!(out.stamp, Stamp::new(3, 0), "the winner's stamp");
        assert_eq!(out.ttl_ms, 150, "what is left of the winner's 250 ms");
        // The operator holds the robot still: a zero teleop command wins.
        mux.receive(TELEOP, cmd(0.0, CommandReason::TELEOP, 300), 10.1);
        mux.receive(AUTONOMY, cmd(1.0, CommandReason::TRACKING, 250), 10.15);
        let (out, state) = mux.command(10.2);
        assert_eq!(state, MuxState::Input("teleop".into()));
        assert_eq!((out.linear_mps, out.reason), (0.0, CommandReason::TELEOP));
        // Teleop expires (its own 300 ms): autonomy again.
        mux.receive(AUTONOMY, cmd(0.7, CommandReason::TRACKING, 250), 10.35);
        let (out, state) = mux.command(10.4);
        assert_eq!(state, MuxState::Input("autonomy".into()));
        assert_eq!(out.linear_mps, 0.7);
        // Everything expires: zero, stale.
        let (out, state) = mux.command(11.0);
        assert_eq!(state, MuxState::NoInput);
        assert_eq!(
            (out.linear_mps, out.reason),
            (0.0, CommandReason::STALE_INPUT)
        );
    }

    #[test]
    fn each_input_is_capped_at_its_own_max_ttl_and_non_finite_is_never_live() {
        let mut mux = CommandMux::new(MuxConfig::default());
        // A teleop command asking for 60 s lives 0.5 s (the input's cap).
        mux.receive(TELEOP, cmd(0.5, CommandReason::TELEOP, 60_000), 0.0);
        assert_eq!(mux.command(0.49).0.linear_mps, 0.5);
        assert_eq!(mux.command(0.49).0.ttl_ms, 10);
        assert_eq!(mux.command(0.5).1, MuxState::NoInput);
        // TTL 0 means the cap.
        mux.receive(TELEOP, cmd(0.5, CommandReason::TELEOP, 0), 1.0);
        assert_eq!(mux.command(1.4).0.linear_mps, 0.5);
        // A NaN command is nobody's: the lower priority wins.
        mux.receive(AUTONOMY, cmd(0.3, CommandReason::TRACKING, 250), 2.0);
        mux.receive(TELEOP, cmd(f32::NAN, CommandReason::TELEOP, 250), 2.0);
        assert_eq!(mux.command(2.1).1, MuxState::Input("autonomy".into()));
        // A clock that went back is not a licence to move.
        assert_eq!(mux.command(1.9).1, MuxState::NoInput);
    }

    #[test]
    fn the_estop_latches_until_an_operator_clears_it() {
        let mut mux = CommandMux::new(MuxConfig::default());
        let estop = |active| EStop {
            active,
            ..Default::default()
        };
        mux.receive(AUTONOMY, cmd(1.0, CommandReason::TRACKING, 250), 0.0);
        mux.estop(&estop(EStop::PRESSED), 0.05);
        let (out, state) = mux.command(0.1);
        assert_eq!(state, MuxState::EStopLatched);
        assert_eq!((out.linear_mps, out.reason), (0.0, CommandReason::ESTOP));
        // Released: still latched, whatever the inputs say.
        mux.estop(&estop(EStop::RELEASED), 0.2);
        mux.receive(TELEOP, cmd(0.5, CommandReason::TELEOP, 250), 0.2);
        mux.receive(AUTONOMY, cmd(1.0, CommandReason::TRACKING, 250), 0.2);
        assert_eq!(mux.command(0.3).1, MuxState::EStopLatched);
        // Cleared by the operator: the inputs count again.
        mux.estop(&estop(EStop::CLEAR), 0.3);
        assert!(!mux.estop_latched());
        assert_eq!(mux.command(0.35).1, MuxState::Input("teleop".into()));
    }

    #[test]
    fn with_the_operator_link_lost_teleop_stops_at_once_and_autonomy_as_configured() {
        for (loss, autonomy_drives) in [
            (OnOperatorLoss::Stop, false),
            (OnOperatorLoss::Continue, true),
        ] {
            let mut mux = CommandMux::new(MuxConfig {
                deadman_timeout_s: 0.5,
                on_operator_loss: loss,
                ..Default::default()
            });
            let heartbeat = EStop::default();
            assert!(!mux.operator_link_alive(0.0), "never heard: lost");
            mux.estop(&heartbeat, 0.0);
            // Teleop asks for 0.5 s; the link is lost at 0.5 s.
            mux.receive(TELEOP, cmd(0.8, CommandReason::TELEOP, 500), 0.3);
            mux.receive(AUTONOMY, cmd(0.4, CommandReason::TRACKING, 500), 0.3);
            assert_eq!(mux.command(0.45).1, MuxState::Input("teleop".into()));
            // The link is lost at 0.5 s, before teleop's TTL runs out at 0.8 s.
            let (out, state) = mux.command(0.55);
            assert_ne!(state, MuxState::Input("teleop".into()), "{loss:?}");
            assert_eq!(
                out.linear_mps,
                if autonomy_drives { 0.4 } else { 0.0 },
                "{loss:?}"
            );
            // Heard again: teleop wins again.
            mux.estop(&heartbeat, 0.6);
            assert_eq!(mux.command(0.65).1, MuxState::Input("teleop".into()));
        }
    }

    #[test]
    fn bad_configs_are_refused_naming_the_key() {
        let parse = |text: &str| {
            farsight_stage::parse_config::<MuxConfig>(text, "command-mux.toml")
                .map_err(|e| e.to_string())
        };
        assert_eq!(parse("").unwrap(), MuxConfig::default());
        let input = |topic: &str, ttl: f64| {
            format!(
                "[[inputs]]\nname = \"a\"\ntopic = \"{topic}\"\npriority = 1\nmax_ttl_s = {ttl}\n"
            )
        };
        let e = parse(&input("cmd/velocity", 0.5)).unwrap_err();
        assert!(
            e.contains("inputs[0].topic") && e.contains("cmd/velocity"),
            "{e}"
        );
        let e = parse(&input("nav/goal", 0.5)).unwrap_err();
        assert!(e.contains("inputs[0].topic"), "{e}");
        let e = parse(&input("cmd/teleop", f64::INFINITY)).unwrap_err();
        assert!(e.contains("inputs[0].max_ttl_s"), "{e}");
        let e = parse(&format!("{}{}", input("cmd/a", 0.5), input("cmd/b", 0.5))).unwrap_err();
        assert!(e.contains("inputs[1].name"), "{e}");
        let e = parse("deadman_timeout_s = -1.0\n").unwrap_err();
        assert!(e.contains("deadman_timeout_s"), "{e}");
        let e = parse("on_operator_loss = \"maybe\"\n").unwrap_err();
        assert!(e.contains("on_operator_loss"), "{e}");
    }
}
