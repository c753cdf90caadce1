//! systemd's service protocol (`sd_notify(3)`), the same for every stage:
//! `READY=1` once the stage is set up (after a model has loaded), `WATCHDOG=1`
//! from the stage's loop thread at half the unit's `WatchdogSec=`, and
//! `STOPPING=1` on shutdown. The pings come from [`crate::Health::tick`],
//! which every stage's loop calls on its tick even when no input arrives, so
//! an idle stage stays alive and a step that hangs stops the pings: systemd
//! then kills and restarts the unit. Without `NOTIFY_SOCKET` (not under
//! systemd) nothing is sent.

use sd_notify::NotifyState;
use std::time::{Duration, Instant};

/// Sends `WATCHDOG=1` at most once per half watchdog interval.
#[derive(Debug)]
pub struct Watchdog {
    ping_every: Option<Duration>,
    last_ping: Option<Instant>,
}

impl Watchdog {
    /// The interval systemd asked for (`WATCHDOG_USEC`, for this pid), if any.
    pub fn from_env() -> Self {
        Self {
            ping_every: sd_notify::watchdog_enabled().map(|d| d / 2),
            last_ping: None,
        }
    }

    /// Pings if half the watchdog interval has passed since the last ping.
    pub fn pet(&mut self) {
        let Some(every) = self.ping_every else {
            return;
        };
        if self.last_ping.is_some_and(|t| t.elapsed() < every) {
            return;
        }
        if let Err(e) = sd_notify::notify(&[NotifyState::Watchdog]) {
            tracing::warn!("watchdog ping failed: {e}");
        }
        self.last_ping = Some(Instant::now());
    }
}

/// `READY=1`: the stage is set up and running its loop.
pub fn notify_ready() {
    if let Err(e) = sd_notify::notify(&[NotifyState::Ready]) {
        tracing::warn!("readiness notification failed: {e}");
    }
}

/// `STOPPING=1`: the stage is shutting down on request.
pub fn notify_stopping() {
    let _ = sd_notify::notify(&[NotifyState::Stopping]);
}
