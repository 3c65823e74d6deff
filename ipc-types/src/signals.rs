//! Shutdown on SIGINT / SIGTERM: handlers set a flag that every process loop polls. The
//! handlers are installed without `SA_RESTART`, so a blocking wait (the bridge's
//! `clock_nanosleep`) returns at once and the loop can stop the arm without waiting out a
//! period.

use std::sync::atomic::{AtomicBool, AtomicI32, Ordering};

static STOP: AtomicBool = AtomicBool::new(false);
static SIGNAL: AtomicI32 = AtomicI32::new(0);

extern "C" fn on_signal(sig: libc::c_int) {
    STOP.store(true, Ordering::SeqCst);
    SIGNAL.store(sig, Ordering::SeqCst);
}

/// Installs the SIGINT and SIGTERM handlers.
pub fn install() {
    for sig in [libc::SIGINT, libc::SIGTERM] {
        // SAFETY: the handler only stores to atomics (async-signal-safe); the sigaction struct
        // is zero-initialised and fully set before use.
        unsafe {
            let mut sa: libc::sigaction = std::mem::zeroed();
            sa.sa_sigaction = on_signal as *const () as usize;
            sa.sa_flags = 0;
            libc::sigemptyset(&mut sa.sa_mask);
            libc::sigaction(sig, &sa, std::ptr::null_mut());
        }
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
