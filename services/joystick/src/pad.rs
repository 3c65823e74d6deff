//! From evdev events to the operator's input: the pure part of the device source.
//!
//! [`Pad`] keeps the raw values of the inputs a [`Mapping`] reads, takes events one by one
//! (applied a frame at a time, at each `SYN_REPORT`, as the kernel groups them), and shapes
//! them into an [`Input`]: axes normalised by the device's range, inverted, passed through a
//! radial deadzone (rescaled so the output starts from 0 at its edge), scaled and clamped
//! radially to `|a| <= 1`; the gripper rate from the close and open controls; the button bits.
//! Without a device the input is neutral and carries [`buttons::NO_DEVICE`].

use ipc_types::buttons;

use super::Input;
use super::mapping::{Code, Mapping};

/// Event type: synchronisation.
pub const EV_SYN: u16 = 0x00;
/// Event type: keys and buttons.
pub const EV_KEY: u16 = 0x01;
/// Event type: absolute axes.
pub const EV_ABS: u16 = 0x03;
/// `EV_SYN` code: end of a frame.
pub const SYN_REPORT: u16 = 0;
/// `EV_SYN` code: the kernel's buffer overran; events up to the next `SYN_REPORT` are lost.
pub const SYN_DROPPED: u16 = 3;

/// One evdev event, as numbers (`struct input_event` without its time).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RawEvent {
    /// Event type (`EV_KEY`, `EV_ABS`, `EV_SYN`, ...).
    pub kind: u16,
    /// Code within the type.
    pub code: u16,
    /// Value (axis position; 0 released, 1 pressed, 2 auto-repeat for keys).
    pub value: i32,
}

/// An absolute axis as the device reports it at connection.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AxisInfo {
    /// `ABS_*` code.
    pub code: u16,
    /// Smallest value.
    pub min: i32,
    /// Largest value.
    pub max: i32,
    /// Current value.
    pub value: i32,
}

/// What a device looks like when it is (re)connected: its axes and the keys held down.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Snapshot {
    /// The device's name.
    pub name: String,
    /// Its path (`/dev/input/eventN`).
    pub path: String,
    /// Every absolute axis it has.
    pub axes: Vec<AxisInfo>,
    /// Every key it has.
    pub keys: Vec<u16>,
    /// The keys held down now.
    pub keys_down: Vec<u16>,
}

/// The roles a mapping fills, in a fixed order.
const X: usize = 0;
const Y: usize = 1;
const CLOSE: usize = 2;
const OPEN: usize = 3;
const DEADMAN: usize = 4;
const MODE: usize = 5;
const ESTOP: usize = 6;
const N_SLOTS: usize = 7;

#[derive(Debug, Clone, Copy, PartialEq)]
struct Slot {
    code: Option<Code>,
    /// The axis's range (`None`: the device does not have it, or it is a key).
    range: Option<(i32, i32)>,
    /// Whether the connected device has this input.
    present: bool,
    value: i32,
    pending: Option<i32>,
}

/// The device source's state: the mapping and the mapped inputs' raw values.
#[derive(Debug, Clone)]
pub struct Pad {
    mapping: Mapping,
    slots: [Slot; N_SLOTS],
    connected: bool,
    /// After `SYN_DROPPED`: events are ignored up to the next `SYN_REPORT`.
    dropping: bool,
}

impl Pad {
    /// A pad for `mapping`, with no device yet.
    pub fn new(mapping: Mapping) -> Self {
        let code = |i: usize| match i {
            X => Some(Code::Abs(mapping.axes[0].code)),
            Y => Some(Code::Abs(mapping.axes[1].code)),
            CLOSE => mapping.gripper_close,
            OPEN => mapping.gripper_open,
            DEADMAN => mapping.deadman,
            MODE => mapping.mode,
            _ => mapping.estop,
        };
        let slots = std::array::from_fn(|i| Slot {
            code: code(i),
            range: None,
            present: false,
            value: 0,
            pending: None,
        });
        Self {
            mapping,
            slots,
            connected: false,
            dropping: false,
        }
    }

    /// The mapping.
    pub fn mapping(&self) -> &Mapping {
        &self.mapping
    }

    /// Whether a device is connected.
    pub fn connected(&self) -> bool {
        self.connected
    }

    /// A device was (re)connected: takes its ranges and current state. Returns the mapped
    /// inputs the device does not have (role, code), for a warning; they stay neutral.
    pub fn connect(&mut self, snap: &Snapshot) -> Vec<(&'static str, Code)> {
        const ROLES: [&str; N_SLOTS] = [
            "axis x",
            "axis y",
            "gripper close",
            "gripper open",
            "deadman",
            "mode",
            "e-stop",
        ];
        let mut missing = Vec::new();
        for (i, slot) in self.slots.iter_mut().enumerate() {
            slot.pending = None;
            slot.value = 0;
            slot.range = None;
            slot.present = false;
            match slot.code {
                None => {}
                Some(Code::Abs(c)) => {
                    if let Some(info) = snap.axes.iter().find(|a| a.code == c) {
                        let over = match i {
                            X => self.mapping.axes[0].range,
                            Y => self.mapping.axes[1].range,
                            _ => None,
                        };
                        slot.range = over.or((info.max > info.min).then_some((info.min, info.max)));
                        slot.present = slot.range.is_some();
                        slot.value = info.value;
                    }
                }
                Some(Code::Key(c)) => {
                    slot.present = snap.keys.contains(&c);
                    slot.value = i32::from(snap.keys_down.contains(&c));
                }
            }
            if let Some(code) = slot.code
                && !slot.present
            {
                missing.push((ROLES[i], code));
            }
        }
        self.connected = true;
        self.dropping = false;
        missing
    }

    /// The device is gone: the input turns neutral and flagged until it returns.
    pub fn disconnect(&mut self) {
        self.connected = false;
        for s in &mut self.slots {
            s.pending = None;
            s.value = 0;
        }
    }

    /// Takes one event; returns `true` when it completed a frame (`SYN_REPORT`), after which
    /// [`Pad::input`] reflects the frame.
    pub fn event(&mut self, ev: RawEvent) -> bool {
        match (ev.kind, ev.code) {
            (EV_SYN, SYN_REPORT) => {
                if self.dropping {
                    self.dropping = false;
                    for s in &mut self.slots {
                        s.pending = None;
                    }
                    return false;
                }
                for s in &mut self.slots {
                    if let Some(v) = s.pending.take() {
                        s.value = v;
                    }
                }
                true
            }
            (EV_SYN, SYN_DROPPED) => {
                self.dropping = true;
                false
            }
            _ if self.dropping => false,
            (kind, code) => {
                let want = match kind {
                    EV_ABS => Code::Abs(code),
                    EV_KEY => Code::Key(code),
                    _ => return false,
                };
                for s in &mut self.slots {
                    if s.code == Some(want) {
                        s.pending = Some(ev.value);
                    }
                }
                false
            }
        }
    }

    /// An axis input from -1 to 1 across its range, 0 at its integer centre, each half
    /// scaled on its own (so -32768..32767 is exactly 0 at 0 and ±1 at the ends); 0 if
    /// absent.
    fn bipolar(&self, i: usize) -> f64 {
        let s = &self.slots[i];
        match (s.present, s.range) {
            (true, Some((lo, hi))) => {
                let (lo, hi, v) = (i64::from(lo), i64::from(hi), i64::from(s.value));
                let c = (lo + hi) / 2;
                let t = if v >= c {
                    (v - c) as f64 / (hi - c).max(1) as f64
                } else {
                    (v - c) as f64 / (c - lo).max(1) as f64
                };
                t.clamp(-1.0, 1.0)
            }
            _ => 0.0,
        }
    }

    /// An input from 0 (released, or an axis at its minimum like a trigger at rest) to 1.
    fn unipolar(&self, i: usize) -> f64 {
        let s = &self.slots[i];
        if !s.present {
            return 0.0;
        }
        match (s.code, s.range) {
            (Some(Code::Key(_)), _) => f64::from(u8::from(s.value != 0)),
            (Some(Code::Abs(_)), Some((lo, hi))) => ((f64::from(s.value) - f64::from(lo))
                / (f64::from(hi) - f64::from(lo)))
            .clamp(0.0, 1.0),
            _ => 0.0,
        }
    }

    /// The shaped input of the last complete frame.
    pub fn input(&self) -> Input {
        if !self.connected {
            return Input {
                buttons: buttons::NO_DEVICE,
                ..Input::NEUTRAL
            };
        }
        let m = &self.mapping;
        let dz = m.deadzone;
        let mut a = [self.bipolar(X), self.bipolar(Y)];
        for (v, ax) in a.iter_mut().zip(&m.axes) {
            if ax.invert {
                *v = -*v;
            }
        }
        let a = shape_stick(a, dz, [m.axes[0].scale, m.axes[1].scale]);
        let trigger = |i: usize| {
            let u = self.unipolar(i);
            if u <= dz { 0.0 } else { (u - dz) / (1.0 - dz) }
        };
        let close = trigger(CLOSE);
        let open = trigger(OPEN);
        let mut bits = 0;
        for (slot, bit) in [
            (DEADMAN, buttons::DEADMAN),
            (MODE, buttons::MODE),
            (ESTOP, buttons::ESTOP),
        ] {
            if self.unipolar(slot) > 0.5 {
                bits |= bit;
            }
        }
        if close >= 0.5 {
            bits |= buttons::GRIPPER;
        }
        Input {
            axes: [a[0] as f32, a[1] as f32],
            gripper: (close - open).clamp(-1.0, 1.0) as f32,
            buttons: bits,
        }
    }
}

/// The stick's shaping: a radial deadzone `dz` (inside it 0; outside, the length is rescaled
/// so it grows from 0 at the deadzone's edge to 1 at full deflection, direction kept), then
/// the per-axis `scale`, then a radial clamp to `|a| <= 1`.
pub fn shape_stick(a: [f64; 2], dz: f64, scale: [f64; 2]) -> [f64; 2] {
    let r = a[0].hypot(a[1]);
    if r.is_nan() || r <= dz || !r.is_finite() {
        return [0.0, 0.0];
    }
    let k = (r.min(1.0) - dz) / (1.0 - dz) / r;
    let mut out = [a[0] * k * scale[0], a[1] * k * scale[1]];
    let n = out[0].hypot(out[1]);
    if n > 1.0 {
        out[0] /= n;
        out[1] /= n;
    }
    out
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// Parses one line of `evtest` output (`Event: time 1700000000.000100, type 3 (EV_ABS),
    /// code 0 (ABS_X), value 1200`, or the `-------------- SYN_REPORT ------------` lines);
    /// other lines give `None`. Returns the time (s) and the event.
    pub(crate) fn parse_evtest(line: &str) -> Option<(f64, RawEvent)> {
        let rest = line.trim().strip_prefix("Event: time ")?;
        let (time, rest) = rest.split_once(',')?;
        let t: f64 = time.trim().parse().ok()?;
        let num = |key: &str| -> Option<i64> {
            let i = rest.find(key)? + key.len();
            let s = rest[i..].trim_start();
            let end = s
                .find(|c: char| !(c.is_ascii_digit() || c == '-'))
                .unwrap_or(s.len());
            s[..end].parse().ok()
        };
        if rest.contains("SYN_REPORT") {
            return Some((
                t,
                RawEvent {
                    kind: EV_SYN,
                    code: SYN_REPORT,
                    value: 0,
                },
            ));
        }
        Some((
            t,
            RawEvent {
                kind: num("type ")? as u16,
                code: num("code ")? as u16,
                value: num("value ")? as i32,
            },
        ))
    }

    /// An Xbox pad as xpad reports it: sticks -32768..32767, triggers 0..1023.
    pub(crate) fn xbox_snapshot() -> Snapshot {
        let stick = |code: u16| AxisInfo {
            code,
            min: -32768,
            max: 32767,
            value: 0,
        };
        let trigger = |code: u16| AxisInfo {
            code,
            min: 0,
            max: 1023,
            value: 0,
        };
        Snapshot {
            name: "Microsoft X-Box 360 pad".into(),
            path: "/dev/input/event7".into(),
            axes: vec![
                stick(0),
                stick(1),
                trigger(2),
                stick(3),
                stick(4),
                trigger(5),
            ],
            keys: (0x130..=0x13e).collect(),
            keys_down: vec![],
        }
    }

    fn ev(kind: u16, code: u16, value: i32) -> RawEvent {
        RawEvent { kind, code, value }
    }

    fn syn() -> RawEvent {
        ev(EV_SYN, SYN_REPORT, 0)
    }

    #[test]
    fn stick_shaping() {
        // Inside the deadzone: nothing.
        assert_eq!(shape_stick([0.05, -0.05], 0.1, [1.0, 1.0]), [0.0, 0.0]);
        // At full deflection: 1, direction kept.
        let a = shape_stick([1.0, 0.0], 0.1, [1.0, 1.0]);
        assert!((a[0] - 1.0).abs() < 1e-12 && a[1] == 0.0);
        // Half-way out of the deadzone: half the output.
        let a = shape_stick([0.0, -0.55], 0.1, [1.0, 1.0]);
        assert!((a[1] + 0.5).abs() < 1e-12);
        // The corner of a square stick is clamped radially, direction kept.
        let a = shape_stick([1.0, 1.0], 0.1, [1.0, 1.0]);
        assert!((a[0].hypot(a[1]) - 1.0).abs() < 1e-12 && (a[0] - a[1]).abs() < 1e-12);
        // Scaling after the deadzone; a scale above 1 still ends at |a| <= 1.
        let a = shape_stick([1.0, 0.0], 0.1, [0.5, 1.0]);
        assert!((a[0] - 0.5).abs() < 1e-12);
        let a = shape_stick([0.8, 0.6], 0.0, [2.0, 2.0]);
        assert!((a[0].hypot(a[1]) - 1.0).abs() < 1e-12);
        assert_eq!(shape_stick([f64::NAN, 0.0], 0.1, [1.0, 1.0]), [0.0, 0.0]);
    }

    #[test]
    fn frames_apply_at_syn_report_and_shape_the_input() {
        let mut pad = Pad::new(Mapping::load("xbox").unwrap());
        assert_eq!(pad.input().buttons, buttons::NO_DEVICE);
        assert!(pad.connect(&xbox_snapshot()).is_empty());
        assert_eq!(pad.input(), Input::NEUTRAL);
        // Full right and full up (evdev y is negative up; the mapping inverts it).
        assert!(!pad.event(ev(EV_ABS, 0, 32767)));
        assert!(!pad.event(ev(EV_ABS, 1, -32768)));
        // Not applied before the frame ends.
        assert_eq!(pad.input(), Input::NEUTRAL);
        assert!(pad.event(syn()));
        let i = pad.input();
        let r = f64::from(i.axes[0]).hypot(f64::from(i.axes[1]));
        assert!(
            (r - 1.0).abs() < 1e-6 && i.axes[0] > 0.7 && i.axes[1] > 0.7,
            "{i:?}"
        );
        // Right trigger half-way: closing at (0.5 - 0.1) / 0.9; A held: mode.
        pad.event(ev(EV_ABS, 5, 512));
        pad.event(ev(EV_KEY, 0x130, 1));
        pad.event(syn());
        let i = pad.input();
        assert!((f64::from(i.gripper) - (512.0 / 1023.0 - 0.1) / 0.9).abs() < 1e-6);
        assert_eq!(i.buttons, buttons::MODE);
        // Pulled further: the gripper bit (closing at half rate or more).
        pad.event(ev(EV_ABS, 5, 700));
        pad.event(syn());
        assert_eq!(pad.input().buttons, buttons::MODE | buttons::GRIPPER);
        // Left trigger fully: opens against the right one; bumper: deadman; B: e-stop.
        pad.event(ev(EV_ABS, 2, 1023));
        pad.event(ev(EV_KEY, 0x130, 0));
        pad.event(ev(EV_KEY, 0x136, 1));
        pad.event(ev(EV_KEY, 0x131, 1));
        pad.event(syn());
        let i = pad.input();
        let close = (700.0 / 1023.0 - 0.1) / 0.9;
        assert!((f64::from(i.gripper) - (close - 1.0)).abs() < 1e-6, "{i:?}");
        assert_eq!(
            i.buttons,
            buttons::DEADMAN | buttons::ESTOP | buttons::GRIPPER
        );
        // Unmapped inputs change nothing.
        pad.event(ev(EV_ABS, 3, 30000));
        pad.event(ev(EV_KEY, 0x13c, 1));
        pad.event(syn());
        assert_eq!(pad.input(), i);
    }

    #[test]
    fn dropped_events_are_skipped_to_the_next_frame() {
        let mut pad = Pad::new(Mapping::load("xbox").unwrap());
        pad.connect(&xbox_snapshot());
        pad.event(ev(EV_ABS, 0, 20000));
        pad.event(ev(EV_SYN, SYN_DROPPED, 0));
        pad.event(ev(EV_ABS, 0, 32767));
        assert!(!pad.event(syn()));
        assert_eq!(pad.input(), Input::NEUTRAL);
        pad.event(ev(EV_ABS, 0, 32767));
        assert!(pad.event(syn()));
        assert!((pad.input().axes[0] - 1.0).abs() < 1e-6);
    }

    #[test]
    fn unplug_is_neutral_and_flagged_and_reconnect_reads_the_device_state() {
        let mut pad = Pad::new(Mapping::load("xbox").unwrap());
        pad.connect(&xbox_snapshot());
        pad.event(ev(EV_ABS, 0, 32767));
        pad.event(ev(EV_KEY, 0x136, 1));
        pad.event(syn());
        assert!(pad.input().axes[0] > 0.99);
        pad.disconnect();
        let i = pad.input();
        assert_eq!(i.axes, [0.0, 0.0]);
        assert_eq!((i.gripper, i.buttons), (0.0, buttons::NO_DEVICE));
        // Back with the stick held left and the bumper down: taken from the snapshot.
        let mut snap = xbox_snapshot();
        snap.axes[0].value = -32768;
        snap.keys_down = vec![0x136];
        pad.connect(&snap);
        let i = pad.input();
        assert!(i.axes[0] < -0.99 && i.buttons == buttons::DEADMAN, "{i:?}");
    }

    #[test]
    fn a_device_without_some_inputs_leaves_them_neutral() {
        let mut pad = Pad::new(Mapping::load("xbox").unwrap());
        let mut snap = xbox_snapshot();
        snap.axes.retain(|a| a.code != 5);
        snap.keys.retain(|k| *k != 0x131);
        let missing = pad.connect(&snap);
        let roles: Vec<_> = missing.iter().map(|(r, _)| *r).collect();
        assert_eq!(roles, ["gripper close", "e-stop"]);
        pad.event(ev(EV_ABS, 5, 1023));
        pad.event(syn());
        assert_eq!(pad.input().gripper, 0.0);
    }

    #[test]
    fn range_overrides_and_unipolar_axes() {
        let text = "deadzone = 0.0\n[axes]\nx = { code = \"ABS_X\", min = 0, max = 255 }\n\
                    y = { code = \"ABS_Y\", scale = 0.5 }\n[buttons]\ndeadman = \"ABS_Z\"";
        let mut pad = Pad::new(Mapping::parse(text, "t").unwrap());
        pad.connect(&xbox_snapshot());
        pad.event(ev(EV_ABS, 0, 255));
        pad.event(ev(EV_ABS, 1, 32767));
        pad.event(ev(EV_ABS, 2, 1000));
        pad.event(syn());
        let i = pad.input();
        // x at 255 of 0..255 is full right, y full: the corner, |a| = 1 at 45°, then y
        // scaled to a half.
        let half = std::f32::consts::FRAC_1_SQRT_2;
        assert!((i.axes[0] - half).abs() < 1e-5, "{i:?}");
        assert!((i.axes[1] - 0.5 * half).abs() < 1e-5, "{i:?}");
        // A trigger as a button: pressed past half-way.
        assert_eq!(i.buttons, buttons::DEADMAN);
    }

    /// A generic USB joystick as hid-generic reports it: X, Y 0..1023 centred, a throttle,
    /// the buttons `BTN_TRIGGER` .. `BTN_BASE6`.
    fn generic_snapshot() -> Snapshot {
        let axis = |code: u16, max: i32| AxisInfo {
            code,
            min: 0,
            max,
            value: max / 2,
        };
        Snapshot {
            name: "Logitech Extreme 3D".into(),
            path: "/dev/input/event9".into(),
            axes: vec![axis(0, 1023), axis(1, 1023), axis(5, 255), axis(6, 255)],
            keys: (0x120..=0x12b).collect(),
            keys_down: vec![],
        }
    }

    #[test]
    fn the_generic_mapping_reads_a_stick_and_its_buttons() {
        let (trigger, thumb, thumb2, top, top2) = (0x120, 0x121, 0x122, 0x123, 0x124);
        let mut pad = Pad::new(Mapping::load("generic").unwrap());
        assert!(pad.connect(&generic_snapshot()).is_empty());
        // At its centre (511 of 0..1023): neutral.
        assert_eq!(pad.input(), Input::NEUTRAL);
        // Pushed fully forward (y at its minimum; the mapping inverts it) with the deadman
        // (BTN_TOP2) held: a1 = +1, nothing on a0.
        pad.event(ev(EV_ABS, 1, 0));
        pad.event(ev(EV_KEY, top2, 1));
        assert!(pad.event(syn()));
        let i = pad.input();
        assert!(
            i.axes[0].abs() < 1e-6 && (i.axes[1] - 1.0).abs() < 1e-6,
            "{i:?}"
        );
        assert_eq!((i.gripper, i.buttons), (0.0, buttons::DEADMAN));
        // Right at three quarters: a0 = (0.5 - 0.1) / 0.9 of the length, direction kept,
        // and the trigger closes the gripper at full rate.
        pad.event(ev(EV_ABS, 0, 767));
        pad.event(ev(EV_ABS, 1, 512));
        pad.event(ev(EV_KEY, trigger, 1));
        pad.event(syn());
        let i = pad.input();
        let want = (f64::from(767 - 511) / 512.0 - 0.1) / 0.9;
        assert!((f64::from(i.axes[0]) - want).abs() < 1e-6, "{i:?}");
        assert!(i.axes[1].abs() < 0.01, "{i:?}");
        assert_eq!(i.gripper, 1.0);
        assert_eq!(i.buttons, buttons::DEADMAN | buttons::GRIPPER);
        // The thumb button opens against the trigger; BTN_THUMB2 is the mode button, BTN_TOP
        // the e-stop; the deadman released.
        pad.event(ev(EV_KEY, thumb, 1));
        pad.event(ev(EV_KEY, thumb2, 1));
        pad.event(ev(EV_KEY, top, 1));
        pad.event(ev(EV_KEY, top2, 0));
        pad.event(syn());
        let i = pad.input();
        assert_eq!(i.gripper, 0.0);
        assert_eq!(i.buttons, buttons::GRIPPER | buttons::MODE | buttons::ESTOP);
        // The throttle and the other buttons are not mapped: no change.
        pad.event(ev(EV_ABS, 6, 255));
        pad.event(ev(EV_KEY, 0x125, 1));
        pad.event(syn());
        assert_eq!(pad.input(), i);
        // Everything released, back at the centre: neutral.
        for k in [trigger, thumb, thumb2, top] {
            pad.event(ev(EV_KEY, k, 0));
        }
        pad.event(ev(EV_ABS, 0, 512));
        pad.event(syn());
        assert_eq!(pad.input(), Input::NEUTRAL);
    }

    #[test]
    fn evtest_lines_parse() {
        let (t, e) = parse_evtest(
            "Event: time 1700000000.000100, type 3 (EV_ABS), code 1 (ABS_Y), value -32768",
        )
        .unwrap();
        assert!((t - 1_700_000_000.000_1).abs() < 1e-6);
        assert_eq!(e, ev(EV_ABS, 1, -32768));
        let (_, e) =
            parse_evtest("Event: time 1700000000.000200, -------------- SYN_REPORT ------------")
                .unwrap();
        assert_eq!(e, syn());
        assert_eq!(parse_evtest("Input driver version is 1.0.1"), None);
    }
}
