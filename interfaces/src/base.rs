//! The robot base's side of `cmd/velocity`: obey a command for its
//! time-to-live, counted from when the base *received* it, then stop.
//!
//! A base (a motor driver, the simulator's robot) holds its last command
//! until told otherwise. If the graph's command writer dies or freezes
//! while the robot moves, nothing tells the base to stop, so each command
//! carries a time-to-live (`VelocityCommand::ttl_ms`). It is counted from
//! receipt on the base's own clock, because the base's clock is not
//! synchronised with the graph's. [`CommandGate`] is the one implementation
//! of that rule: the simulator drives its robot through it, and a driver for
//! a real base wraps it the same way (`examples/base_adapter.rs`).
//!
//! The contract for a base driver:
//! 1. Hand every received command to [`CommandGate::receive`] with the
//!    driver's monotonic time of receipt, in seconds.
//! 2. At the motor controller's rate, send [`CommandGate::command`] of the
//!    current time: the last command while it is within its TTL (capped by
//!    the driver's own `max_ttl_s`), zero velocity once it has expired.
//! 3. A command with a non-finite velocity is a stop, never obeyed.
//! 4. Configure the platform's own timeout too where it has one (a CAN
//!    heartbeat, a serial deadman): the gate runs in the driver process, and
//!    a dead driver is the platform's to catch.

use crate::msg::VelocityCommand;

/// Whether `cmd`, received at `received_s`, is still to be obeyed at `now_s`,
/// and with what `(linear_mps, angular_radps)`: the command's velocities
/// while `now_s - received_s` is below its TTL (at most `max_ttl_s`; a TTL
/// of 0 means `max_ttl_s`), `(0, 0)` after that or for a non-finite command.
pub fn obey_or_stop(
    cmd: &VelocityCommand,
    received_s: f64,
    now_s: f64,
    max_ttl_s: f64,
) -> (f64, f64) {
    match time_left_s(cmd, received_s, now_s, max_ttl_s) {
        Some(_) => (f64::from(cmd.linear_mps), f64::from(cmd.angular_radps)),
        None => (0.0, 0.0),
    }
}

/// How many seconds `cmd`, received at `received_s`, is still to be obeyed
/// at `now_s` (see [`obey_or_stop`]); `None` once expired or for a
/// non-finite command.
pub fn time_left_s(
    cmd: &VelocityCommand,
    received_s: f64,
    now_s: f64,
    max_ttl_s: f64,
) -> Option<f64> {
    let ttl_s = match cmd.ttl_ms {
        0 => max_ttl_s,
        ms => (f64::from(ms) * 1e-3).min(max_ttl_s),
    };
    let finite = cmd.linear_mps.is_finite() && cmd.angular_radps.is_finite();
    let age_s = now_s - received_s;
    // A clock that went backwards (age < 0) is not a licence to move.
    (finite && (0.0..ttl_s).contains(&age_s)).then_some(ttl_s - age_s)
}

/// The base's last command and when it arrived (see the module contract).
#[derive(Debug, Clone)]
pub struct CommandGate {
    max_ttl_s: f64,
    last: Option<(VelocityCommand, f64)>,
}

impl CommandGate {
    /// A gate that obeys no command longer than `max_ttl_s` after receipt
    /// (non-finite or negative values mean "never": every command is a stop).
    pub fn new(max_ttl_s: f64) -> Self {
        Self {
            max_ttl_s: if max_ttl_s.is_finite() {
                max_ttl_s.max(0.0)
            } else {
                0.0
            },
            last: None,
        }
    }

    /// Takes a command received at `now_s` (the base's monotonic seconds).
    pub fn receive(&mut self, cmd: VelocityCommand, now_s: f64) {
        self.last = Some((cmd, now_s));
    }

    /// What to send the motors at `now_s`.
    pub fn command(&self, now_s: f64) -> (f64, f64) {
        self.last.as_ref().map_or((0.0, 0.0), |(cmd, received_s)| {
            obey_or_stop(cmd, *received_s, now_s, self.max_ttl_s)
        })
    }

    /// The last command while it is to be obeyed at `now_s`, with the
    /// seconds it has left (a live zero counts: it is a command to stand).
    pub fn live(&self, now_s: f64) -> Option<(&VelocityCommand, f64)> {
        let (cmd, received_s) = self.last.as_ref()?;
        time_left_s(cmd, *received_s, now_s, self.max_ttl_s).map(|left| (cmd, left))
    }

    /// The last command received, if any.
    pub fn last(&self) -> Option<&VelocityCommand> {
        self.last.as_ref().map(|(c, _)| c)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msg::{CommandReason, Stamp};

    fn moving(ttl_ms: u16) -> VelocityCommand {
        VelocityCommand {
            stamp: Stamp::new(1, 0),
            linear_mps: 0.8,
            angular_radps: -0.2,
            reason: CommandReason::TRACKING,
            ttl_ms,
        }
    }

    #[test]
    fn a_command_is_obeyed_for_its_ttl_from_receipt_then_the_base_stops() {
        let mut gate = CommandGate::new(1.0);
        assert_eq!(gate.command(0.0), (0.0, 0.0), "nothing received: stopped");
        gate.receive(moving(250), 100.0);
        assert_eq!(gate.command(100.0), (f64::from(0.8f32), f64::from(-0.2f32)));
        assert!(gate.command(100.249).0 > 0.0);
        assert_eq!(gate.command(100.25), (0.0, 0.0), "expired at its TTL");
        assert_eq!(gate.command(107.0), (0.0, 0.0));
        // A newer command restarts the clock from its own receipt.
        gate.receive(moving(250), 107.0);
        assert!(gate.command(107.1).0 > 0.0);
    }

    #[test]
    fn the_bases_cap_bounds_every_ttl_and_stands_in_for_none() {
        // The command asks for 60 s; the base obeys at most 0.5 s.
        assert!(obey_or_stop(&moving(60_000), 0.0, 0.49, 0.5).0 > 0.0);
        assert_eq!(obey_or_stop(&moving(60_000), 0.0, 0.5, 0.5), (0.0, 0.0));
        // TTL 0: the cap applies.
        assert!(obey_or_stop(&moving(0), 0.0, 0.3, 0.5).0 > 0.0);
        assert_eq!(obey_or_stop(&moving(0), 0.0, 0.6, 0.5), (0.0, 0.0));
        // A gate with a non-finite or negative cap never moves.
        for cap in [f64::NAN, f64::INFINITY, -1.0] {
            let mut g = CommandGate::new(cap);
            g.receive(moving(250), 0.0);
            assert_eq!(g.command(0.0), (0.0, 0.0), "cap {cap}");
        }
    }

    #[test]
    fn non_finite_commands_and_clocks_that_go_back_stop_the_base() {
        let mut nan = moving(250);
        nan.linear_mps = f32::NAN;
        assert_eq!(obey_or_stop(&nan, 0.0, 0.0, 1.0), (0.0, 0.0));
        let mut inf = moving(250);
        inf.angular_radps = f32::INFINITY;
        assert_eq!(obey_or_stop(&inf, 0.0, 0.0, 1.0), (0.0, 0.0));
        // Received "in the future" of the clock read now: not obeyed.
        assert_eq!(obey_or_stop(&moving(250), 10.0, 9.9, 1.0), (0.0, 0.0));
    }
}
