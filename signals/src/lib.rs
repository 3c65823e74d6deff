//! Shutdown on SIGINT / SIGTERM: handlers set a flag that every process loop polls. The
//! handlers are installed without `SA_RESTART`, so a blocking wait (the bridge's
//! `clock_nanosleep`) returns at once and the loop can stop the arm without waiting out a
//! period.
#![cfg_attr(test, allow(clippy::unwrap_used))]

use std::sync::atomic::{AtomicBool, AtomicI32, Ordering};

use nix::sys::signal::{SaFlags, SigAction, SigHandler, SigSet, Signal, sigaction};

static STOP: AtomicBool = AtomicBool::new(false);
static SIGNAL: AtomicI32 = AtomicI32::new(0);

extern "C" fn on_signal(sig: std::ffi::c_int) {
    STOP.store(true, Ordering::SeqCst);
    SIGNAL.store(sig, Ordering::SeqCst);
}

/// Installs the SIGINT and SIGTERM handlers (no `SA_RESTART`: blocking calls return `EINTR`).
pub fn install() {
    let action = SigAction::new(
        SigHandler::Handler(on_signal),
        SaFlags::empty(),
        SigSet::empty(),
    );
    for sig in [Signal::SIGINT, Signal::SIGTERM] {
        // SAFETY: the handler only stores to atomics (async-signal-safe). Installing it for
        // these two signals is the only use; the previous handlers are not needed. Failure
        // (impossible for these valid signals) leaves the default handler, which also ends
        // the process.
        let _ = unsafe { sigaction(sig, &action) };
    }
}

/// Whether a shutdown was requested.
pub fn stop_requested() -> bool {
    STOP.load(Ordering::SeqCst)
}

/// Requests a shutdown from inside the process.
pub fn request_stop() {
    STOP.store(true, Ordering::SeqCst);
}

/// The signal that requested the shutdown (0 if none).
pub fn signal() -> i32 {
    SIGNAL.load(Ordering::SeqCst)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The handlers are installed without `SA_RESTART`, so a signal ends a blocking wait.
    #[test]
    fn handlers_do_not_restart_system_calls() {
        install();
        for sig in [Signal::SIGINT, Signal::SIGTERM] {
            let probe = SigAction::new(SigHandler::SigDfl, SaFlags::empty(), SigSet::empty());
            // SAFETY: reads the installed action by swapping in the default for a moment and
            // putting the installed one back; no signal is sent meanwhile.
            let installed = unsafe { sigaction(sig, &probe) }.unwrap();
            // SAFETY: as above.
            unsafe { sigaction(sig, &installed) }.unwrap();
            assert!(matches!(installed.handler(), SigHandler::Handler(_)));
            assert!(!installed.flags().contains(SaFlags::SA_RESTART));
        }
    }
}
