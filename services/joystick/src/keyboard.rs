//! The keyboard source, for a person at a terminal with no joystick: arrow keys or WASD drive
//! the two axes with a ramp, space toggles the gripper, `m` (or Tab) switches the mode, Esc
//! latches the e-stop, `q` or Ctrl-C quits. A status line shows the input and the mapper's
//! mode.
//!
//! [`Keys`] is the pure part (key events and time in, [`Input`] out). Terminals report key
//! presses and the operating system's auto-repeat, but most do not report releases: a key
//! counts as held for [`KeyboardSettings::first_hold_s`] after its first press (longer than
//! the usual auto-repeat delay) and [`KeyboardSettings::repeat_hold_s`] after each repeat, so
//! it is released that long after the key is. Terminals that speak the kitty keyboard protocol
//! report releases too; once one is seen, holds end exactly at the release.
//!
//! [`Terminal`] puts the terminal in non-canonical, no-echo mode (output processing stays on,
//! so the other processes' log lines keep their shape) and, when the joystick process runs
//! under `scl up` in a background process group, borrows the terminal's foreground so it can
//! read keys; Ctrl-C or `q` then hands the terminal back and interrupts the process group it
//! was borrowed from (the supervisor, which stops the graph in order), as the terminal's own
//! Ctrl-C would have.

use std::io::{IsTerminal, Write};
use std::os::fd::AsFd;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use crossbeam_channel::Sender;
use ipc_types::buttons;
use nix::errno::Errno;
use nix::sys::signal::{self, SigHandler, Signal};
use nix::sys::termios::{self, LocalFlags, SetArg, SpecialCharacterIndices, Termios};
use nix::unistd::{Pid, getpgrp, tcgetpgrp, tcsetpgrp};

use super::{Input, JoystickError, Waker};

/// A key the source understands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Key {
    /// Left arrow or `a`: a0 negative.
    Left,
    /// Right arrow or `d`: a0 positive.
    Right,
    /// Up arrow or `w`: a1 positive.
    Up,
    /// Down arrow or `s`: a1 negative.
    Down,
    /// Space: toggle the gripper (close / open).
    Gripper,
    /// `m` or Tab: the mode button.
    Mode,
    /// Esc: e-stop.
    Estop,
    /// `q` or Ctrl-C: quit.
    Quit,
}

/// What happened to a key.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum KeyAction {
    /// Pressed (also the auto-repeat, on terminals that do not tell them apart).
    Press,
    /// Auto-repeat (kitty keyboard protocol).
    Repeat,
    /// Released (kitty keyboard protocol).
    Release,
}

/// Timing of the keyboard source.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KeyboardSettings {
    /// Time from rest to full deflection (s); a release returns to rest four times faster.
    pub ramp_s: f64,
    /// A key counts as held this long after its first press (s).
    pub first_hold_s: f64,
    /// ... and this long after each auto-repeat (s).
    pub repeat_hold_s: f64,
    /// Length of the mode and e-stop button pulses, and of the gap between two mode pulses
    /// (s); at least two ticks, so the mapper sees every press and every release.
    pub pulse_s: f64,
}

impl Default for KeyboardSettings {
    fn default() -> Self {
        Self {
            ramp_s: 0.5,
            first_hold_s: 0.6,
            repeat_hold_s: 0.15,
            pulse_s: 0.1,
        }
    }
}

const DIRS: [Key; 4] = [Key::Left, Key::Right, Key::Up, Key::Down];

/// The keyboard source's state.
#[derive(Debug, Clone)]
pub struct Keys {
    settings: KeyboardSettings,
    /// Per direction (Left, Right, Up, Down): held until this time (s).
    held_until: [f64; 4],
    /// The terminal reports releases (holds last until the release).
    releases: bool,
    axes: [f64; 2],
    last_t: Option<f64>,
    gripper_closed: bool,
    mode_queue: u32,
    mode_high_until: f64,
    mode_low_until: f64,
    estop_until: f64,
    quit: bool,
}

impl Keys {
    /// At rest, gripper open.
    pub fn new(settings: KeyboardSettings) -> Self {
        Self {
            settings,
            held_until: [f64::NEG_INFINITY; 4],
            releases: false,
            axes: [0.0; 2],
            last_t: None,
            gripper_closed: false,
            mode_queue: 0,
            mode_high_until: f64::NEG_INFINITY,
            mode_low_until: f64::NEG_INFINITY,
            estop_until: f64::NEG_INFINITY,
            quit: false,
        }
    }

    /// Takes a key event at time `t` (s, any fixed origin).
    pub fn key(&mut self, key: Key, action: KeyAction, t: f64) {
        if action == KeyAction::Release {
            self.releases = true;
        }
        if let Some(i) = DIRS.iter().position(|d| *d == key) {
            self.held_until[i] = match action {
                KeyAction::Release => f64::NEG_INFINITY,
                _ if self.releases => f64::INFINITY,
                KeyAction::Press if self.held_until[i] < t => t + self.settings.first_hold_s,
                _ => t + self.settings.repeat_hold_s,
            };
            return;
        }
        if action != KeyAction::Press {
            return;
        }
        match key {
            Key::Gripper => self.gripper_closed = !self.gripper_closed,
            Key::Mode => {
                self.mode_queue += 1;
                self.start_pulse(t);
            }
            Key::Estop => self.estop_until = t + self.settings.pulse_s.max(0.5),
            Key::Quit => self.quit = true,
            _ => {}
        }
    }

    /// Whether quit was asked for.
    pub fn quit_requested(&self) -> bool {
        self.quit
    }

    /// Whether the gripper is to be closed.
    pub fn gripper_closed(&self) -> bool {
        self.gripper_closed
    }

    fn start_pulse(&mut self, t: f64) {
        if self.mode_queue > 0 && t >= self.mode_low_until {
            self.mode_queue -= 1;
            self.mode_high_until = t + self.settings.pulse_s;
            self.mode_low_until = self.mode_high_until + self.settings.pulse_s;
        }
    }

    /// The input at time `t`, advancing the ramp; `gripper` is the arm's gripper state
    /// (0 open .. 1 closed) if known, so the gripper rate stops at the end of its travel.
    pub fn input(&mut self, t: f64, gripper: Option<f64>) -> Input {
        let until = self.held_until;
        let held = |i: usize| until[i] > t;
        let mut target = [
            f64::from(u8::from(held(1))) - f64::from(u8::from(held(0))),
            f64::from(u8::from(held(2))) - f64::from(u8::from(held(3))),
        ];
        let n = target[0].hypot(target[1]);
        if n > 1.0 {
            target.iter_mut().for_each(|v| *v /= n);
        }
        let dt = self.last_t.map_or(0.0, |l| (t - l).max(0.0));
        self.last_t = Some(t);
        let up = dt / self.settings.ramp_s;
        let down = 4.0 * up;
        for (v, goal) in self.axes.iter_mut().zip(target) {
            let rising =
                goal != 0.0 && goal.signum() == v.signum() && goal.abs() > v.abs() || *v == 0.0;
            let step = if rising { up } else { down };
            *v = if (goal - *v).abs() <= step {
                goal
            } else {
                *v + step * (goal - *v).signum()
            };
        }
        self.start_pulse(t);
        let moving = self.axes.iter().any(|v| *v != 0.0) || (0..4).any(held);
        let rate = match (self.gripper_closed, gripper) {
            (true, Some(c)) if c >= 0.98 => 0.0,
            (false, Some(c)) if c <= 0.02 => 0.0,
            (true, _) => 1.0,
            (false, _) => -1.0,
        };
        let mut bits = 0;
        if moving || rate != 0.0 {
            bits |= buttons::DEADMAN;
        }
        if self.gripper_closed {
            bits |= buttons::GRIPPER;
        }
        if t < self.mode_high_until {
            bits |= buttons::MODE;
        }
        if t < self.estop_until {
            bits |= buttons::ESTOP;
        }
        Input {
            axes: [self.axes[0] as f32, self.axes[1] as f32],
            gripper: rate as f32,
            buttons: bits,
        }
    }
}

/// The key a terminal event stands for.
pub fn key_of(ev: &crossterm::event::KeyEvent) -> Option<(Key, KeyAction)> {
    use crossterm::event::{KeyCode, KeyEventKind, KeyModifiers};
    let key = match ev.code {
        KeyCode::Left | KeyCode::Char('a' | 'A') => Key::Left,
        KeyCode::Right | KeyCode::Char('d' | 'D') => Key::Right,
        KeyCode::Up | KeyCode::Char('w' | 'W') => Key::Up,
        KeyCode::Down | KeyCode::Char('s' | 'S') => Key::Down,
        KeyCode::Char('c') if ev.modifiers.contains(KeyModifiers::CONTROL) => Key::Quit,
        KeyCode::Char(' ') => Key::Gripper,
        KeyCode::Char('m' | 'M') | KeyCode::Tab => Key::Mode,
        KeyCode::Esc => Key::Estop,
        KeyCode::Char('q' | 'Q') => Key::Quit,
        _ => return None,
    };
    let action = match ev.kind {
        KeyEventKind::Press => KeyAction::Press,
        KeyEventKind::Repeat => KeyAction::Repeat,
        KeyEventKind::Release => KeyAction::Release,
    };
    Some((key, action))
}

/// The terminal, set up for the keyboard source; restored when dropped.
pub struct Terminal {
    saved: Termios,
    /// The foreground process group the terminal was borrowed from (under `scl up`).
    borrowed_from: Option<Pid>,
    /// The kitty keyboard protocol was asked for (and must be popped).
    enhanced: bool,
    restored: bool,
}

impl std::fmt::Debug for Terminal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Terminal")
            .field("borrowed_from", &self.borrowed_from)
            .field("enhanced", &self.enhanced)
            .finish()
    }
}

impl Terminal {
    /// Takes the terminal on standard input: foreground (borrowed if another process group
    /// has it), no canonical line editing, no echo, no signal keys (Ctrl-C arrives as a key).
    pub fn take() -> Result<Self, JoystickError> {
        let stdin = std::io::stdin();
        if !stdin.is_terminal() {
            return Err(JoystickError::NoTerminal);
        }
        let fd = stdin.as_fd();
        let os = |what: &'static str| {
            move |e: Errno| JoystickError::Terminal {
                what,
                source: e.into(),
            }
        };
        // A process group borrowing the terminal must not be stopped by SIGTTOU / SIGTTIN
        // while it changes or reads it.
        for sig in [Signal::SIGTTOU, Signal::SIGTTIN] {
            // SAFETY: setting a disposition to "ignore" installs no handler code.
            let _ = unsafe { signal::signal(sig, SigHandler::SigIgn) };
        }
        let me = getpgrp();
        let mut borrowed_from = None;
        if let Ok(fg) = tcgetpgrp(fd)
            && fg.as_raw() > 0
            && fg != me
        {
            // SIGTTOU is ignored, so this takes effect from the background.
            tcsetpgrp(fd, me).map_err(os("take the terminal's foreground"))?;
            borrowed_from = Some(fg);
        }
        let saved = termios::tcgetattr(fd).map_err(os("read the terminal settings"))?;
        let mut t = saved.clone();
        t.local_flags &= !(LocalFlags::ICANON | LocalFlags::ECHO | LocalFlags::ISIG);
        t.control_chars[SpecialCharacterIndices::VMIN as usize] = 1;
        t.control_chars[SpecialCharacterIndices::VTIME as usize] = 0;
        termios::tcsetattr(fd, SetArg::TCSANOW, &t)
            .map_err(os("set the terminal to read single keys"))?;
        let mut term = Self {
            saved,
            borrowed_from,
            enhanced: false,
            restored: false,
        };
        // Ask for key releases (kitty keyboard protocol); terminals without it ignore this.
        if std::io::IsTerminal::is_terminal(&std::io::stderr()) {
            use crossterm::event::{KeyboardEnhancementFlags as F, PushKeyboardEnhancementFlags};
            let flags = F::DISAMBIGUATE_ESCAPE_CODES | F::REPORT_EVENT_TYPES;
            term.enhanced =
                crossterm::execute!(std::io::stderr(), PushKeyboardEnhancementFlags(flags)).is_ok();
        }
        Ok(term)
    }

    /// Whether the terminal was borrowed from another process group (`scl up`).
    pub fn borrowed(&self) -> bool {
        self.borrowed_from.is_some()
    }

    /// Restores the settings and gives the foreground back; with `interrupt`, then sends
    /// SIGINT to the process group it was borrowed from. Idempotent.
    pub fn restore(&mut self, interrupt: bool) {
        if self.restored {
            return;
        }
        self.restored = true;
        let stdin = std::io::stdin();
        let fd = stdin.as_fd();
        if self.enhanced {
            let _ = crossterm::execute!(
                std::io::stderr(),
                crossterm::event::PopKeyboardEnhancementFlags
            );
        }
        // Restoring the settings read in `take` on the same terminal; nothing to do on failure.
        let _ = termios::tcsetattr(fd, SetArg::TCSANOW, &self.saved);
        if let Some(pg) = self.borrowed_from {
            // Handing the foreground back (SIGTTOU is ignored) and signalling the group that
            // had it, as the terminal's Ctrl-C would have.
            let _ = tcsetpgrp(fd, pg);
            if interrupt {
                let _ = signal::killpg(pg, Signal::SIGINT);
            }
        }
        let _ = writeln!(std::io::stderr());
    }
}

impl Drop for Terminal {
    fn drop(&mut self) {
        self.restore(false);
    }
}

/// Starts the thread that reads keys from the terminal and hands them over, waking the loop.
/// It ends when `stop` is set or the terminal fails.
pub fn spawn_reader(
    tx: Sender<(Key, KeyAction)>,
    waker: Arc<Waker>,
    stop: Arc<AtomicBool>,
) -> std::io::Result<std::thread::JoinHandle<()>> {
    std::thread::Builder::new()
        .name("keyboard".into())
        .spawn(move || {
            use crossterm::event::{Event, poll, read};
            while !stop.load(Ordering::Relaxed) {
                match poll(Duration::from_millis(100)) {
                    Ok(false) => {}
                    Ok(true) => match read() {
                        Ok(Event::Key(k)) => {
                            if let Some(key) = key_of(&k) {
                                if tx.send(key).is_err() {
                                    return;
                                }
                                waker.notify();
                            }
                        }
                        Ok(_) => {}
                        Err(e) => {
                            tracing::warn!("the terminal failed: {e}; keyboard input stops");
                            return;
                        }
                    },
                    Err(e) => {
                        tracing::warn!("the terminal failed: {e}; keyboard input stops");
                        return;
                    }
                }
            }
        })
}

/// The mode the status line shows: that of the mapper safety forwards (`active_mapper`, 0
/// while safety's heartbeat is not seen), from `modes`, the newest `(mapper id, mode, mode
/// switches)` of each mapper's heartbeat ([`ipc_types::NodeStatus::mode`]: mode plus one, 0
/// for a map without modes). `?` while the active mapper's mode is unknown.
pub fn mode_text(active_mapper: u32, modes: &[(u32, u32, u32)]) -> String {
    match modes.iter().find(|m| m.0 == active_mapper) {
        None => "?".into(),
        Some((_, 0, _)) => "- (the map has no modes)".into(),
        Some((_, mode, switches)) => {
            let plural = if *switches == 1 { "switch" } else { "switches" };
            format!(
                "{} ({switches} {plural})",
                mapper::modeswitch::status_mode_name(*mode)
            )
        }
    }
}

/// The status line: the input, the gripper, the mapper's mode.
pub fn status_line(input: &Input, gripper_closed: bool, mode: &str) -> String {
    let b = input.buttons;
    let mut flags = String::new();
    for (bit, name) in [
        (buttons::DEADMAN, " deadman"),
        (buttons::MODE, " MODE"),
        (buttons::ESTOP, " E-STOP"),
    ] {
        if b & bit != 0 {
            flags.push_str(name);
        }
    }
    format!(
        "[keyboard] a = ({:+.2}, {:+.2})  gripper {}  mode {mode}{flags}   \
         arrows/WASD move, space gripper, m mode, Esc e-stop, q quit",
        input.axes[0],
        input.axes[1],
        if gripper_closed { "closing" } else { "opening" },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn s() -> KeyboardSettings {
        KeyboardSettings::default()
    }

    #[test]
    fn a_held_key_ramps_up_and_a_released_one_ramps_down_faster() {
        let mut k = Keys::new(s());
        assert_eq!(k.input(0.0, Some(0.0)).axes, [0.0, 0.0]);
        k.key(Key::Right, KeyAction::Press, 0.0);
        let a = k.input(0.1, Some(0.0));
        assert!((a.axes[0] - 0.2).abs() < 1e-6, "{a:?}");
        assert_eq!(a.buttons, buttons::DEADMAN);
        // Auto-repeat keeps it held; full deflection after the ramp time.
        let mut t = 0.1;
        while t < 1.0 {
            t += 0.025;
            if t > 0.5 {
                k.key(Key::Right, KeyAction::Press, t);
            }
            k.input(t, Some(0.0));
        }
        assert_eq!(k.input(t, Some(0.0)).axes, [1.0, 0.0]);
        // No repeats: released repeat_hold_s after the last, then down at 4x the rate.
        let t_rel = t + s().repeat_hold_s;
        assert_eq!(k.input(t_rel - 0.01, Some(0.0)).axes[0], 1.0);
        // 60 ms after the last update at 4 / 0.5 s: 1 - 0.48.
        let a = k.input(t_rel + 0.05, Some(0.0));
        assert!((a.axes[0] - 0.52).abs() < 0.02, "{a:?}");
        let a = k.input(t_rel + 0.2, Some(0.0));
        assert_eq!(a.axes, [0.0, 0.0]);
        assert_eq!(a.buttons, 0);
    }

    #[test]
    fn a_single_tap_holds_past_the_auto_repeat_delay() {
        let mut k = Keys::new(s());
        k.input(0.0, None);
        k.key(Key::Up, KeyAction::Press, 0.0);
        assert!(k.input(0.5, None).axes[1] > 0.9);
        assert!(k.input(0.59, None).axes[1] > 0.9);
        assert!(k.input(0.65, None).axes[1] < 0.9);
    }

    #[test]
    fn releases_end_holds_exactly_when_reported() {
        let mut k = Keys::new(s());
        k.input(0.0, None);
        k.key(Key::Down, KeyAction::Press, 0.0);
        k.key(Key::Down, KeyAction::Release, 0.05);
        // The first release switches to exact holds.
        k.key(Key::Left, KeyAction::Press, 0.1);
        let a = k.input(3.0, None);
        assert_eq!(a.axes, [-1.0, 0.0]);
        k.key(Key::Left, KeyAction::Release, 3.0);
        assert_eq!(k.input(3.2, None).axes, [0.0, 0.0]);
    }

    #[test]
    fn diagonals_stay_within_the_unit_circle() {
        let mut k = Keys::new(s());
        k.input(0.0, None);
        k.key(Key::Up, KeyAction::Release, 0.0);
        k.key(Key::Up, KeyAction::Press, 0.0);
        k.key(Key::Right, KeyAction::Press, 0.0);
        let a = k.input(2.0, None);
        let r = f64::from(a.axes[0]).hypot(f64::from(a.axes[1]));
        assert!((r - 1.0).abs() < 1e-6, "{a:?}");
        // Opposite keys cancel.
        k.key(Key::Left, KeyAction::Press, 2.0);
        let a = k.input(4.0, None);
        assert!(
            a.axes[0].abs() < 1e-6 && (a.axes[1] - 1.0).abs() < 1e-6,
            "{a:?}"
        );
    }

    #[test]
    fn mode_presses_become_separate_pulses() {
        let p = s().pulse_s;
        // Each pulse and each gap is at least two 40 Hz ticks long, so the mapper, reading
        // one sample a tick, sees every press and every release.
        assert!(p >= 2.0 * 0.025, "{p}");
        let mut k = Keys::new(s());
        k.input(0.0, None);
        // Three quick presses: three pulses with gaps, never one long one.
        k.key(Key::Mode, KeyAction::Press, 0.0);
        k.key(Key::Mode, KeyAction::Press, 0.01);
        k.key(Key::Mode, KeyAction::Press, 0.02);
        // Sampled every millisecond: the times the button goes up and down.
        let dt = 0.001;
        let (mut rises, mut falls) = (Vec::new(), Vec::new());
        let mut last = false;
        for i in 0..1000 {
            let t = f64::from(i) * dt;
            let on = k.input(t, None).buttons & buttons::MODE != 0;
            if on && !last {
                rises.push(t);
            }
            if !on && last {
                falls.push(t);
            }
            last = on;
        }
        assert_eq!(rises.len(), 3, "{rises:?}");
        assert_eq!(falls.len(), 3, "{falls:?}");
        for (i, (r, f)) in rises.iter().zip(&falls).enumerate() {
            assert!((f - r - p).abs() <= dt + 1e-9, "pulse {i}: {r}..{f}");
            if let Some(next) = rises.get(i + 1) {
                assert!((next - f - p).abs() <= dt + 1e-9, "gap {i}: {f}..{next}");
            }
        }
        // The queue is spent: no fourth pulse.
        assert!(falls[2] < 0.6, "{falls:?}");
        // And at 40 Hz, whatever the phase of the ticks, each pulse is seen on two ticks and
        // each gap too: three rising edges.
        for phase in [0.0, 0.007, 0.013, 0.024] {
            let mut k = Keys::new(s());
            k.input(0.0, None);
            for t in [0.0, 0.01, 0.02] {
                k.key(Key::Mode, KeyAction::Press, t);
            }
            let on: Vec<bool> = (0..40)
                .map(|i| k.input(phase + f64::from(i) * 0.025, None).buttons & buttons::MODE != 0)
                .collect();
            let edges = on.windows(2).filter(|w| w[1] && !w[0]).count() + usize::from(on[0]);
            assert_eq!(edges, 3, "phase {phase}: {on:?}");
        }
    }

    #[test]
    fn the_status_line_shows_the_active_mappers_mode() {
        // No heartbeat of safety or of the mapper yet.
        assert_eq!(mode_text(0, &[]), "?");
        assert_eq!(mode_text(1, &[]), "?");
        // Safety forwards mapper 1, a mode-switching map in z-yaw after two switches; mapper 2
        // (a swap in progress) is in roll-pitch.
        let modes = [(1, 2, 2), (2, 3, 5), (3, 0, 0)];
        assert_eq!(mode_text(1, &modes), "z-yaw (2 switches)");
        assert_eq!(mode_text(2, &modes), "roll-pitch (5 switches)");
        assert_eq!(mode_text(1, &[(1, 1, 1)]), "x-y (1 switch)");
        // A map without modes, a mapper not heard of.
        assert_eq!(mode_text(3, &modes), "- (the map has no modes)");
        assert_eq!(mode_text(4, &modes), "?");
        let line = status_line(&Input::NEUTRAL, false, &mode_text(2, &modes));
        assert!(line.contains("mode roll-pitch (5 switches)"), "{line}");
    }

    #[test]
    fn gripper_toggles_and_stops_at_the_end_of_travel() {
        let mut k = Keys::new(s());
        assert_eq!(k.input(0.0, Some(0.0)).gripper, 0.0);
        k.key(Key::Gripper, KeyAction::Press, 0.0);
        let i = k.input(0.1, Some(0.3));
        assert_eq!(i.gripper, 1.0);
        assert_eq!(i.buttons, buttons::DEADMAN | buttons::GRIPPER);
        assert_eq!(k.input(0.2, Some(0.99)).gripper, 0.0);
        k.key(Key::Gripper, KeyAction::Press, 0.3);
        assert_eq!(k.input(0.4, Some(0.99)).gripper, -1.0);
        // A repeat of the space bar does not toggle again.
        k.key(Key::Gripper, KeyAction::Repeat, 0.45);
        assert!(!k.gripper_closed());
    }

    #[test]
    fn escape_sends_an_estop_pulse_and_q_quits() {
        let mut k = Keys::new(s());
        k.key(Key::Estop, KeyAction::Press, 1.0);
        assert_ne!(k.input(1.1, None).buttons & buttons::ESTOP, 0);
        assert_eq!(k.input(2.0, None).buttons & buttons::ESTOP, 0);
        assert!(!k.quit_requested());
        k.key(Key::Quit, KeyAction::Press, 2.0);
        assert!(k.quit_requested());
    }

    #[test]
    fn terminal_keys_map() {
        use crossterm::event::{KeyCode, KeyEvent, KeyEventKind, KeyModifiers};
        let ev = |code, modifiers| KeyEvent::new(code, modifiers);
        assert_eq!(
            key_of(&ev(KeyCode::Char('w'), KeyModifiers::NONE)),
            Some((Key::Up, KeyAction::Press))
        );
        assert_eq!(
            key_of(&ev(KeyCode::Char('c'), KeyModifiers::CONTROL)).map(|k| k.0),
            Some(Key::Quit)
        );
        assert_eq!(
            key_of(&ev(KeyCode::Esc, KeyModifiers::NONE)).map(|k| k.0),
            Some(Key::Estop)
        );
        let mut rel = ev(KeyCode::Left, KeyModifiers::NONE);
        rel.kind = KeyEventKind::Release;
        assert_eq!(key_of(&rel), Some((Key::Left, KeyAction::Release)));
        assert_eq!(key_of(&ev(KeyCode::Char('x'), KeyModifiers::NONE)), None);
        let line = status_line(
            &Input {
                axes: [0.5, -0.25],
                gripper: 1.0,
                buttons: buttons::MODE,
            },
            true,
            "z-yaw (2 switches)",
        );
        assert!(line.contains("+0.50, -0.25") && line.contains("z-yaw") && line.contains("MODE"));
    }
}
