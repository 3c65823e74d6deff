//! Linux input devices through evdev: listing them (`scl joystick --list`), choosing one (by
//! path, by name, or the first joystick or gamepad that has the mapping's axes), and the
//! reading thread that hands its events to the joystick loop over a channel, reports an
//! unplugged device and reopens it when it comes back.

use std::os::fd::{AsFd, BorrowedFd};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use crossbeam_channel::Sender;

use super::Waker;
use super::mapping::{Code, Mapping};
use super::pad::{AxisInfo, RawEvent, Snapshot};

/// Where the device nodes live.
pub const INPUT_DIR: &str = "/dev/input";

/// What the reading thread hands to the loop.
#[derive(Debug, Clone, PartialEq)]
pub enum DeviceMsg {
    /// A device was opened; its state now.
    Connected(Snapshot),
    /// One event.
    Event(RawEvent),
    /// The open device failed (unplugged): why.
    Lost(String),
    /// No device could be opened: why (said once until one is found).
    Missing(String),
}

/// A device found in [`INPUT_DIR`].
#[derive(Debug, Clone, PartialEq)]
pub struct DeviceRow {
    /// Its node.
    pub path: PathBuf,
    /// Its name (empty if it has none).
    pub name: String,
    /// Number of absolute axes.
    pub axes: usize,
    /// Number of keys and buttons.
    pub keys: usize,
    /// Whether it looks like a joystick or gamepad (absolute X and Y axes and a joystick or
    /// gamepad button).
    pub joystick: bool,
}

/// Buttons of the kernel's joystick and gamepad ranges (`BTN_TRIGGER` .. `BTN_THUMBR` and
/// the unnamed ones up to 0x13f).
fn is_joystick_button(code: u16) -> bool {
    (0x120..=0x13f).contains(&code)
}

/// Whether a device with the absolute axes `abs` and the keys `keys` is a joystick or
/// gamepad with both `axes`: it has them and a button of the joystick or gamepad ranges.
fn is_joystick_with(abs: &[u16], keys: &[u16], axes: [u16; 2]) -> bool {
    axes.iter().all(|a| abs.contains(a)) && keys.iter().any(|k| is_joystick_button(*k))
}

/// Whether a device (its `name`, absolute axes `abs`, keys `keys`) is the one a selector
/// asks for: `want`, lower case, is part of its name (case-insensitive), or, when empty,
/// any joystick or gamepad with the mapping's two `axes`.
fn selects(want: &str, name: &str, abs: &[u16], keys: &[u16], axes: [u16; 2]) -> bool {
    if want.is_empty() {
        is_joystick_with(abs, keys, axes)
    } else {
        name.to_lowercase().contains(want)
    }
}

/// A device's absolute axes and keys, as codes.
fn codes(dev: &evdev::Device) -> (Vec<u16>, Vec<u16>) {
    let abs = dev
        .supported_absolute_axes()
        .map(|s| s.iter().map(|c| c.0).collect())
        .unwrap_or_default();
    let keys = dev
        .supported_keys()
        .map(|s| s.iter().map(|k| k.code()).collect())
        .unwrap_or_default();
    (abs, keys)
}

fn row_of(path: &Path, dev: &evdev::Device) -> DeviceRow {
    let (abs, keys) = codes(dev);
    DeviceRow {
        path: path.to_owned(),
        name: dev.name().unwrap_or_default().to_owned(),
        axes: abs.len(),
        keys: keys.len(),
        joystick: is_joystick_with(&abs, &keys, [0, 1]),
    }
}

/// The device nodes `eventN` in [`INPUT_DIR`], in number order.
fn nodes() -> Vec<PathBuf> {
    let Ok(rd) = std::fs::read_dir(INPUT_DIR) else {
        return Vec::new();
    };
    let mut v: Vec<(u32, PathBuf)> = rd
        .flatten()
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            let n = name.strip_prefix("event")?.parse().ok()?;
            Some((n, e.path()))
        })
        .collect();
    v.sort();
    v.into_iter().map(|(_, p)| p).collect()
}

/// Every input device that could be opened, and the nodes that could not (with the error).
pub fn list() -> (Vec<DeviceRow>, Vec<(PathBuf, std::io::Error)>) {
    let mut rows = Vec::new();
    let mut refused = Vec::new();
    for p in nodes() {
        match evdev::Device::open(&p) {
            Ok(d) => rows.push(row_of(&p, &d)),
            Err(e) => refused.push((p, e)),
        }
    }
    (rows, refused)
}

/// The text `scl joystick --list` prints.
pub fn render_list(rows: &[DeviceRow], refused: &[(PathBuf, std::io::Error)]) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    if rows.is_empty() && refused.is_empty() {
        let _ = writeln!(
            s,
            "no input devices in {INPUT_DIR} (none attached, or not visible here); the keyboard \
             source needs none: scl joystick --source keyboard"
        );
        return s;
    }
    let _ = writeln!(
        s,
        "{:<22} {:>5} {:>5}  {:<9} NAME",
        "DEVICE", "AXES", "KEYS", "KIND"
    );
    for r in rows {
        let _ = writeln!(
            s,
            "{:<22} {:>5} {:>5}  {:<9} {}",
            r.path.display(),
            r.axes,
            r.keys,
            if r.joystick { "joystick" } else { "-" },
            r.name
        );
    }
    if !refused.is_empty() {
        let denied = refused
            .iter()
            .filter(|(_, e)| e.kind() == std::io::ErrorKind::PermissionDenied)
            .count();
        let _ = writeln!(
            s,
            "{} more device(s) could not be opened{}",
            refused.len(),
            if denied > 0 {
                " (permission denied: add yourself to the `input` group, or use a udev rule)"
            } else {
                ""
            }
        );
    }
    s
}

/// Finds the device `selector` names: a path (starts with `/`), a name (case-insensitive
/// substring), or, when empty, the first joystick or gamepad with the mapping's two axes.
pub fn open(selector: &str, mapping: &Mapping) -> Result<(PathBuf, evdev::Device), String> {
    if selector.starts_with('/') {
        return evdev::Device::open(selector)
            .map(|d| (PathBuf::from(selector), d))
            .map_err(|e| format!("cannot open {selector}: {e}"));
    }
    let want = selector.to_lowercase();
    let axes = [mapping.axes[0].code, mapping.axes[1].code];
    let mut refused = 0;
    let mut seen = 0;
    for p in nodes() {
        seen += 1;
        let d = match evdev::Device::open(&p) {
            Ok(d) => d,
            Err(_) => {
                refused += 1;
                continue;
            }
        };
        let (abs, keys) = codes(&d);
        let ok = selects(&want, d.name().unwrap_or_default(), &abs, &keys, axes);
        if ok {
            return Ok((p, d));
        }
    }
    let what = if want.is_empty() {
        "no joystick or gamepad".to_owned()
    } else {
        format!("no device named like `{selector}`")
    };
    let hint = if refused > 0 {
        format!(
            " ({refused} of {seen} devices could not be opened: permission denied? see `scl joystick --list`)"
        )
    } else if seen == 0 {
        format!(" ({INPUT_DIR} has no devices)")
    } else {
        " (see `scl joystick --list`)".to_owned()
    };
    Err(format!("{what} found{hint}"))
}

/// The device's state now, for [`super::pad::Pad::connect`].
pub fn snapshot(path: &Path, dev: &evdev::Device) -> Snapshot {
    let axes = dev
        .get_absinfo()
        .map(|it| {
            it.map(|(c, info)| AxisInfo {
                code: c.0,
                min: info.minimum(),
                max: info.maximum(),
                value: info.value(),
            })
            .collect()
        })
        .unwrap_or_default();
    let keys = dev
        .supported_keys()
        .map(|s| s.iter().map(|k| k.code()).collect())
        .unwrap_or_default();
    let keys_down = dev
        .get_key_state()
        .map(|s| s.iter().map(|k| k.code()).collect())
        .unwrap_or_default();
    Snapshot {
        name: dev.name().unwrap_or_default().to_owned(),
        path: path.display().to_string(),
        axes,
        keys,
        keys_down,
    }
}

/// Waits up to `timeout` for `fd` to become readable (or report an error).
fn wait_readable(fd: BorrowedFd<'_>, timeout: Duration) -> bool {
    use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
    let timeout = PollTimeout::try_from(timeout).unwrap_or(PollTimeout::MAX);
    poll(&mut [PollFd::new(fd, PollFlags::POLLIN)], timeout).is_ok_and(|n| n > 0)
}

/// Starts the thread that reads the device `selector` names (see [`open`]) and hands its
/// events to the loop, waking it. When the device fails it says so and looks for it again
/// every `reconnect`; it ends when `stop` is set or the loop is gone.
pub fn spawn_reader(
    selector: String,
    mapping: Mapping,
    reconnect: Duration,
    tx: Sender<DeviceMsg>,
    waker: Arc<Waker>,
    stop: Arc<AtomicBool>,
) -> std::io::Result<std::thread::JoinHandle<()>> {
    std::thread::Builder::new()
        .name("evdev".into())
        .spawn(move || {
            let send = |m: DeviceMsg| {
                let ok = tx.send(m).is_ok();
                waker.notify();
                ok
            };
            let mut said_missing = false;
            while !stop.load(Ordering::Relaxed) {
                let (path, mut dev) = match open(&selector, &mapping) {
                    Ok(found) => found,
                    Err(reason) => {
                        if !said_missing && !send(DeviceMsg::Missing(reason)) {
                            return;
                        }
                        said_missing = true;
                        let t0 = Instant::now();
                        while t0.elapsed() < reconnect && !stop.load(Ordering::Relaxed) {
                            std::thread::sleep(Duration::from_millis(20));
                        }
                        continue;
                    }
                };
                said_missing = false;
                if let Err(e) = dev.set_nonblocking(true) {
                    tracing::warn!("{}: cannot set non-blocking reads: {e}", path.display());
                }
                if !send(DeviceMsg::Connected(snapshot(&path, &dev))) {
                    return;
                }
                loop {
                    if stop.load(Ordering::Relaxed) {
                        return;
                    }
                    if !wait_readable(dev.as_fd(), Duration::from_millis(100)) {
                        continue;
                    }
                    match dev.fetch_events() {
                        Ok(events) => {
                            for e in events {
                                let ev = RawEvent {
                                    kind: e.event_type().0,
                                    code: e.code(),
                                    value: e.value(),
                                };
                                if tx.send(DeviceMsg::Event(ev)).is_err() {
                                    return;
                                }
                            }
                            waker.notify();
                        }
                        Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {}
                        Err(e) => {
                            if !send(DeviceMsg::Lost(format!("{}: {e}", path.display()))) {
                                return;
                            }
                            break;
                        }
                    }
                }
            }
        })
}

/// The device inputs the mapping needs that a device lacks, as a readable list.
pub fn describe_missing(missing: &[(&'static str, Code)]) -> String {
    missing
        .iter()
        .map(|(role, c)| format!("{role} ({})", c.name()))
        .collect::<Vec<_>>()
        .join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(path: &str, name: &str, axes: usize, keys: usize, joystick: bool) -> DeviceRow {
        DeviceRow {
            path: PathBuf::from(path),
            name: name.into(),
            axes,
            keys,
            joystick,
        }
    }

    #[test]
    fn the_list_shows_each_device_and_why_others_are_missing() {
        let rows = [
            row(
                "/dev/input/event3",
                "AT Translated Set 2 keyboard",
                0,
                250,
                false,
            ),
            row("/dev/input/event17", "Microsoft X-Box 360 pad", 8, 15, true),
        ];
        let refused = [
            (
                PathBuf::from("/dev/input/event5"),
                std::io::Error::from(std::io::ErrorKind::PermissionDenied),
            ),
            (
                PathBuf::from("/dev/input/event6"),
                std::io::Error::from(std::io::ErrorKind::NotFound),
            ),
        ];
        let text = render_list(&rows, &refused);
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), 4, "{text}");
        let cols = |l: &str| l.split_whitespace().map(str::to_owned).collect::<Vec<_>>();
        assert_eq!(cols(lines[0]), ["DEVICE", "AXES", "KEYS", "KIND", "NAME"]);
        assert_eq!(
            cols(lines[1]),
            [
                "/dev/input/event3",
                "0",
                "250",
                "-",
                "AT",
                "Translated",
                "Set",
                "2",
                "keyboard"
            ]
        );
        assert_eq!(
            cols(lines[2]),
            [
                "/dev/input/event17",
                "8",
                "15",
                "joystick",
                "Microsoft",
                "X-Box",
                "360",
                "pad"
            ]
        );
        // The names line up under the header.
        let name_col = lines[0].find("NAME").unwrap();
        assert_eq!(&lines[1][name_col..], "AT Translated Set 2 keyboard");
        assert_eq!(&lines[2][name_col..], "Microsoft X-Box 360 pad");
        assert!(
            lines[3].starts_with("2 more device(s) could not be opened (permission denied"),
            "{text}"
        );
        // Refusals other than permissions give no hint about the input group.
        let text = render_list(&rows[..1], &refused[1..]);
        assert!(
            text.ends_with("1 more device(s) could not be opened\n"),
            "{text}"
        );
        // Nothing at all: a pointer to the keyboard source.
        let text = render_list(&[], &[]);
        assert!(
            text.starts_with("no input devices in /dev/input")
                && text.contains("--source keyboard"),
            "{text}"
        );
        assert!(!text.contains("DEVICE"));
    }

    #[test]
    fn a_selector_picks_by_name_or_the_first_joystick_with_the_axes() {
        let pad_abs = [0, 1, 2, 3, 4, 5];
        let pad_keys = [0x130, 0x131, 0x136];
        let kbd_keys = [1, 2, 30, 57];
        // By name: a case-insensitive part of it, whatever the device is.
        assert!(selects(
            "x-box",
            "Microsoft X-Box 360 pad",
            &pad_abs,
            &pad_keys,
            [0, 1]
        ));
        assert!(selects(
            "keyboard",
            "AT Translated Set 2 keyboard",
            &[],
            &kbd_keys,
            [0, 1]
        ));
        assert!(!selects(
            "logitech",
            "Microsoft X-Box 360 pad",
            &pad_abs,
            &pad_keys,
            [0, 1]
        ));
        assert!(!selects("pad", "", &pad_abs, &pad_keys, [0, 1]));
        // No selector: a joystick or gamepad button and both of the mapping's axes.
        assert!(selects(
            "",
            "Microsoft X-Box 360 pad",
            &pad_abs,
            &pad_keys,
            [0, 1]
        ));
        assert!(selects("", "pad", &pad_abs, &pad_keys, [3, 4]));
        assert!(
            !selects("", "pad", &[0, 1], &pad_keys, [3, 4]),
            "lacks the axes"
        );
        assert!(!selects("", "pad", &[0], &pad_keys, [0, 1]), "lacks y");
        // A touchpad has X and Y but no joystick button (BTN_TOUCH, BTN_LEFT).
        assert!(!selects("", "touchpad", &[0, 1], &[0x14a, 0x110], [0, 1]));
        // The ends of the joystick and gamepad button ranges.
        assert!(selects("", "stick", &[0, 1], &[0x120], [0, 1]));
        assert!(selects("", "stick", &[0, 1], &[0x13f], [0, 1]));
        assert!(!selects("", "stick", &[0, 1], &[0x11f, 0x140], [0, 1]));
    }
}
