//! systemd's service notification for `scl up` under `Type=notify` with `WatchdogSec=`:
//! `READY=1` once the first tick has been executed, `WATCHDOG=1` every half watchdog period
//! while the bridge's heartbeat is fresh, `STOPPING=1` when the graph stops. A wedged graph
//! (the bridge stopped beating) is then restarted by systemd.
//!
//! The protocol is one datagram per message to the Unix socket named by `NOTIFY_SOCKET` (a
//! path, or an abstract name written with a leading `@`); the watchdog period comes from
//! `WATCHDOG_USEC`, for this process only when `WATCHDOG_PID` names it. Without
//! `NOTIFY_SOCKET` (a run by hand) nothing is sent. [`Watchdog`] is the pure decision; the
//! socket is [`Notifier`].

use std::os::unix::net::{SocketAddr, UnixDatagram};
use std::time::{Duration, Instant};

/// Why the notification socket could not be used.
#[derive(Debug, thiserror::Error)]
pub enum NotifyError {
    /// `NOTIFY_SOCKET` is set but unusable.
    #[error("NOTIFY_SOCKET `{socket}`: {reason}")]
    Socket {
        /// The variable's value.
        socket: String,
        /// What failed.
        reason: String,
    },
}

/// The datagram socket to systemd, or nothing when not run by systemd.
pub struct Notifier {
    socket: UnixDatagram,
    addr: SocketAddr,
    name: String,
}

impl Notifier {
    /// The notifier named by the environment: `None` without `NOTIFY_SOCKET`.
    pub fn from_env() -> Result<Option<Self>, NotifyError> {
        let Some(name) = std::env::var_os("NOTIFY_SOCKET") else {
            return Ok(None);
        };
        let name = name.to_string_lossy().into_owned();
        let err = |reason: String| NotifyError::Socket {
            socket: name.clone(),
            reason,
        };
        let addr = if let Some(abs) = name.strip_prefix('@') {
            use std::os::linux::net::SocketAddrExt;
            SocketAddr::from_abstract_name(abs.as_bytes()).map_err(|e| err(e.to_string()))?
        } else if name.starts_with('/') {
            SocketAddr::from_pathname(&name).map_err(|e| err(e.to_string()))?
        } else {
            return Err(err(
                "neither a path nor an abstract name (`@...`)".to_owned()
            ));
        };
        let socket = UnixDatagram::unbound().map_err(|e| err(e.to_string()))?;
        Ok(Some(Self { socket, addr, name }))
    }

    /// Sends one notification (`READY=1`, `WATCHDOG=1`, ...). A failure is logged, never
    /// fatal: the graph keeps the arm safe whether or not systemd hears it.
    pub fn send(&self, message: &str) {
        if let Err(e) = self.socket.send_to_addr(message.as_bytes(), &self.addr) {
            tracing::warn!("cannot notify systemd at {} ({message}): {e}", self.name);
        }
    }
}

/// The watchdog period for this process from `WATCHDOG_USEC` and `WATCHDOG_PID` (`None`:
/// no watchdog, or one meant for another process).
pub fn watchdog_from_env() -> Option<Duration> {
    let usec: u64 = std::env::var("WATCHDOG_USEC").ok()?.trim().parse().ok()?;
    if let Ok(pid) = std::env::var("WATCHDOG_PID")
        && pid.trim().parse::<u32>().ok() != Some(std::process::id())
    {
        return None;
    }
    (usec > 0).then(|| Duration::from_micros(usec))
}

/// What to tell systemd now.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Notice {
    /// `READY=1`: the first tick was executed.
    Ready,
    /// `WATCHDOG=1`: the bridge's heartbeat is fresh.
    Pet,
}

impl Notice {
    /// The datagram's text.
    pub fn message(self) -> &'static str {
        match self {
            Self::Ready => "READY=1",
            Self::Pet => "WATCHDOG=1",
        }
    }
}

/// The pure decision: ready once, then pets at half the watchdog period while the bridge's
/// last heartbeat is younger than `fresh_within`.
#[derive(Debug, Clone)]
pub struct Watchdog {
    every: Option<Duration>,
    fresh_within: Duration,
    ready: bool,
    last_pet: Option<Instant>,
}

impl Watchdog {
    /// `period`: the watchdog period (`None`: readiness only); `fresh_within`: how old the
    /// bridge's heartbeat may be for the graph to count as alive.
    pub fn new(period: Option<Duration>, fresh_within: Duration) -> Self {
        Self {
            every: period.map(|p| p / 2),
            fresh_within,
            ready: false,
            last_pet: None,
        }
    }

    /// What to send at `now`, given whether a tick has been executed and when the bridge
    /// last beat.
    pub fn poll(
        &mut self,
        now: Instant,
        ticked: bool,
        last_bridge_beat: Option<Instant>,
    ) -> Option<Notice> {
        if !ticked {
            return None;
        }
        if !self.ready {
            self.ready = true;
            self.last_pet = Some(now);
            return Some(Notice::Ready);
        }
        let every = self.every?;
        let fresh =
            last_bridge_beat.is_some_and(|t| now.saturating_duration_since(t) <= self.fresh_within);
        let due = self
            .last_pet
            .is_none_or(|t| now.saturating_duration_since(t) >= every);
        if fresh && due {
            self.last_pet = Some(now);
            return Some(Notice::Pet);
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: fn(u64) -> Duration = Duration::from_millis;

    #[test]
    fn ready_after_the_first_tick_then_pets_at_half_the_period_while_fresh() {
        let t0 = Instant::now();
        let mut w = Watchdog::new(Some(MS(2000)), MS(250));
        assert_eq!(w.poll(t0, false, Some(t0)), None, "no tick yet");
        assert_eq!(w.poll(t0 + MS(10), true, Some(t0)), Some(Notice::Ready));
        assert_eq!(w.poll(t0 + MS(500), true, Some(t0 + MS(490))), None);
        assert_eq!(
            w.poll(t0 + MS(1010), true, Some(t0 + MS(1000))),
            Some(Notice::Pet)
        );
        assert_eq!(w.poll(t0 + MS(1500), true, Some(t0 + MS(1490))), None);
        // The bridge stopped beating at 1.6 s: no pet at 2.01 s or after.
        let beat = Some(t0 + MS(1600));
        assert_eq!(w.poll(t0 + MS(2010), true, beat), None);
        assert_eq!(w.poll(t0 + MS(5000), true, beat), None);
        // It beats again: the next poll pets at once (the pet is overdue).
        assert_eq!(
            w.poll(t0 + MS(5100), true, Some(t0 + MS(5090))),
            Some(Notice::Pet)
        );
    }

    #[test]
    fn without_a_watchdog_only_ready_is_sent() {
        let t0 = Instant::now();
        let mut w = Watchdog::new(None, MS(250));
        assert_eq!(w.poll(t0, true, Some(t0)), Some(Notice::Ready));
        for k in 1..100 {
            assert_eq!(w.poll(t0 + MS(k * 100), true, Some(t0 + MS(k * 100))), None);
        }
    }

    #[test]
    fn messages_are_the_protocol_words() {
        assert_eq!(Notice::Ready.message(), "READY=1");
        assert_eq!(Notice::Pet.message(), "WATCHDOG=1");
    }
}
