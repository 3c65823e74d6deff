//! Recorded input: a CSV file of the samples a joystick process published, and its replay
//! with the original timing.
//!
//! The format, one row per change of the input (a row holds until the next one):
//!
//! ```text
//! # comment lines start with '#'
//! t_s,a0,a1,gripper,buttons
//! 0.000000,0.000000,0.000000,0.000000,0
//! 1.250000,0.800000,0.000000,0.000000,1
//! 3.000000,0.000000,0.000000,0.000000,0
//! ```
//!
//! `t_s` is seconds since the first row (non-decreasing), `a0`, `a1` the axes and `gripper` the
//! gripper rate, each in `[-1, 1]`, `buttons` the [`ipc_types::buttons`] bits in decimal. The
//! last row ends the recording: after it a replay is neutral. `scl joystick --record-input FILE`
//! writes such a file (on a writer thread, so the loop never waits on the disk) from any source,
//! and `--source replay --replay FILE` plays one back.

use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use crossbeam_channel::{Receiver, Sender};

use super::{Input, JoystickError};

/// The header row.
pub const HEADER: &str = "t_s,a0,a1,gripper,buttons";

/// A recording in memory.
#[derive(Debug, Clone, PartialEq)]
pub struct Recording {
    /// Where it was read from.
    pub path: PathBuf,
    /// The rows: time (s) and input.
    pub rows: Vec<(f64, Input)>,
}

impl Recording {
    /// Reads and checks a recording.
    pub fn load(path: &Path) -> Result<Self, JoystickError> {
        let text = std::fs::read_to_string(path).map_err(|source| JoystickError::File {
            action: "cannot read the recorded input",
            path: path.to_owned(),
            source,
        })?;
        Self::parse(&text, path)
    }

    /// Parses a recording's text; `path` names it in errors.
    pub fn parse(text: &str, path: &Path) -> Result<Self, JoystickError> {
        let bad = |line: usize, reason: String| JoystickError::Replay {
            path: path.to_owned(),
            line,
            reason,
        };
        let mut rows = Vec::new();
        let mut header_seen = false;
        for (i, raw) in text.lines().enumerate() {
            let line = i + 1;
            let l = raw.trim();
            if l.is_empty() || l.starts_with('#') {
                continue;
            }
            if !header_seen {
                if l.replace(' ', "") != HEADER {
                    return Err(bad(line, format!("the header must be `{HEADER}`")));
                }
                header_seen = true;
                continue;
            }
            let fields: Vec<&str> = l.split(',').map(str::trim).collect();
            if fields.len() != 5 {
                return Err(bad(
                    line,
                    format!("{} fields, expected 5 ({HEADER})", fields.len()),
                ));
            }
            let mut v = [0.0f64; 4];
            for (k, name) in ["t_s", "a0", "a1", "gripper"].iter().enumerate() {
                v[k] = fields[k]
                    .parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| bad(line, format!("{name} `{}` is not a number", fields[k])))?;
                if k > 0 && v[k].abs() > 1.0 {
                    return Err(bad(line, format!("{name} {} is outside [-1, 1]", v[k])));
                }
            }
            let buttons: u32 = fields[4]
                .parse()
                .map_err(|_| bad(line, format!("buttons `{}` is not a bit mask", fields[4])))?;
            let t = v[0];
            if t < 0.0 {
                return Err(bad(line, format!("t_s {t} is negative")));
            }
            if let Some((last, _)) = rows.last()
                && t < *last
            {
                return Err(bad(
                    line,
                    format!("t_s {t} goes back in time (after {last})"),
                ));
            }
            rows.push((
                t,
                Input {
                    axes: [v[1] as f32, v[2] as f32],
                    gripper: v[3] as f32,
                    buttons,
                },
            ));
        }
        if rows.is_empty() {
            return Err(bad(0, "no rows".into()));
        }
        Ok(Self {
            path: path.to_owned(),
            rows,
        })
    }

    /// The input at `t_s` seconds into the replay: the newest row at or before it; neutral
    /// before the first row and from the last row on (the last row ends the recording).
    pub fn at(&self, t_s: f64) -> Input {
        let i = self.rows.partition_point(|(t, _)| *t <= t_s);
        if i == 0 || i == self.rows.len() {
            Input::NEUTRAL
        } else {
            self.rows[i - 1].1
        }
    }

    /// The time of the first row after `t_s`, if any (when the replay next changes).
    pub fn next_change(&self, t_s: f64) -> Option<f64> {
        let i = self.rows.partition_point(|(t, _)| *t <= t_s);
        self.rows.get(i).map(|(t, _)| *t)
    }

    /// Whether the replay has ended at `t_s`.
    pub fn finished(&self, t_s: f64) -> bool {
        self.rows.last().is_some_and(|(t, _)| t_s >= *t)
    }
}

/// One CSV row for `input` at `t_s`.
pub fn row(t_s: f64, input: &Input) -> String {
    format!(
        "{t_s:.6},{:.6},{:.6},{:.6},{}",
        input.axes[0], input.axes[1], input.gripper, input.buttons
    )
}

/// Writes the published input to a file on its own thread.
#[derive(Debug)]
pub struct InputRecorder {
    path: PathBuf,
    tx: Option<Sender<(f64, Input)>>,
    thread: Option<std::thread::JoinHandle<std::io::Result<usize>>>,
    last: Option<Input>,
}

impl InputRecorder {
    /// Creates `path` (refusing to replace an existing file: remove it or choose another
    /// name) and starts the writer.
    pub fn create(path: &Path) -> Result<Self, JoystickError> {
        let err = |source| JoystickError::File {
            action: "cannot create the input recording",
            path: path.to_owned(),
            source,
        };
        let file = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(path)
            .map_err(err)?;
        let (tx, rx) = crossbeam_channel::unbounded();
        let thread = std::thread::Builder::new()
            .name("input-recorder".into())
            .spawn(move || write_rows(file, &rx))
            .map_err(err)?;
        Ok(Self {
            path: path.to_owned(),
            tx: Some(tx),
            thread: Some(thread),
            last: None,
        })
    }

    /// Records `input` at `t_s` if it differs from the last recorded one.
    pub fn record(&mut self, t_s: f64, input: &Input) {
        if self.last.as_ref() == Some(input) {
            return;
        }
        self.last = Some(*input);
        if let Some(tx) = &self.tx {
            // The writer only stops on a write error, already logged.
            let _ = tx.send((t_s, *input));
        }
    }

    /// Writes the final row (the end of the recording at `t_s`), flushes and closes the file;
    /// returns the number of rows written.
    pub fn finish(mut self, t_s: f64) -> Result<usize, JoystickError> {
        if let Some(tx) = self.tx.take() {
            let last = self.last.unwrap_or(Input::NEUTRAL);
            let _ = tx.send((t_s, last));
        }
        let n = match self.thread.take().map(std::thread::JoinHandle::join) {
            Some(Ok(r)) => r.map_err(|source| JoystickError::File {
                action: "cannot write the input recording",
                path: self.path.clone(),
                source,
            })?,
            _ => 0,
        };
        Ok(n)
    }
}

fn write_rows(file: std::fs::File, rx: &Receiver<(f64, Input)>) -> std::io::Result<usize> {
    let mut w = BufWriter::new(file);
    writeln!(
        w,
        "# scl recorded joystick input: seconds since the first sample, axes, gripper rate, button bits"
    )?;
    writeln!(w, "{HEADER}")?;
    let mut n = 0;
    for (t, input) in rx {
        writeln!(w, "{}", row(t, &input))?;
        n += 1;
    }
    w.flush()?;
    Ok(n)
}

#[cfg(test)]
mod tests {
    use super::*;
    use ipc_types::buttons;

    fn input(a0: f32, a1: f32, b: u32) -> Input {
        Input {
            axes: [a0, a1],
            gripper: 0.0,
            buttons: b,
        }
    }

    #[test]
    fn replay_holds_each_row_until_the_next_and_ends_neutral() {
        let text = "# hand-written\nt_s,a0,a1,gripper,buttons\n0.5,0.8,0,0,0\n1.0,0,0,0,2\n\
                    1.1,0,-1,0.5,0\n2.0,0,0,0,0\n";
        let r = Recording::parse(text, Path::new("r.csv")).unwrap();
        assert_eq!(r.rows.len(), 4);
        assert_eq!(r.at(0.0), Input::NEUTRAL);
        assert_eq!(r.at(0.5), input(0.8, 0.0, 0));
        assert_eq!(r.at(0.99), input(0.8, 0.0, 0));
        assert_eq!(r.at(1.05).buttons, buttons::MODE);
        assert_eq!(r.at(1.5).gripper, 0.5);
        assert_eq!(r.at(2.0), Input::NEUTRAL);
        assert_eq!(r.at(100.0), Input::NEUTRAL);
        assert_eq!(r.next_change(0.0), Some(0.5));
        assert_eq!(r.next_change(1.0), Some(1.1));
        assert_eq!(r.next_change(2.0), None);
        assert!(!r.finished(1.99) && r.finished(2.0));
    }

    #[test]
    fn bad_files_name_the_file_and_line() {
        let cases = [
            ("a,b\n", 1, "header"),
            ("t_s,a0,a1,gripper,buttons\n0,0,0\n", 2, "3 fields"),
            ("t_s,a0,a1,gripper,buttons\n0,x,0,0,0\n", 2, "a0 `x`"),
            ("t_s,a0,a1,gripper,buttons\n0,2,0,0,0\n", 2, "outside"),
            (
                "t_s,a0,a1,gripper,buttons\n1,0,0,0,0\n0.5,0,0,0,0\n",
                3,
                "back in time",
            ),
            ("t_s,a0,a1,gripper,buttons\n0,0,0,0,-1\n", 2, "bit mask"),
            (
                "t_s,a0,a1,gripper,buttons\n0,nan,0,0,0\n",
                2,
                "not a number",
            ),
            ("# nothing\nt_s,a0,a1,gripper,buttons\n", 0, "no rows"),
        ];
        for (text, line, needle) in cases {
            let e = Recording::parse(text, Path::new("rec.csv")).unwrap_err();
            let msg = e.to_string();
            assert!(
                matches!(e, JoystickError::Replay { line: l, .. } if l == line),
                "{msg}"
            );
            assert!(msg.contains("rec.csv") && msg.contains(needle), "{msg}");
        }
    }

    #[test]
    fn a_recording_replays_what_was_recorded() {
        let dir = std::env::temp_dir().join(format!("scl-rec-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("in.csv");
        let mut rec = InputRecorder::create(&p).unwrap();
        let seq = [
            (0.0, input(0.0, 0.0, 0)),
            (0.1, input(0.0, 0.0, 0)), // unchanged: not written
            (0.2, input(0.25, -0.5, buttons::DEADMAN)),
            (0.7, input(0.0, 0.0, buttons::MODE)),
        ];
        for (t, i) in &seq {
            rec.record(*t, i);
        }
        assert_eq!(rec.finish(1.0).unwrap(), 4);
        // Refuses to overwrite.
        assert!(InputRecorder::create(&p).is_err());
        let r = Recording::load(&p).unwrap();
        assert_eq!(r.rows.len(), 4);
        assert_eq!(r.at(0.3), seq[2].1);
        assert_eq!(r.at(0.8), seq[3].1);
        assert!(r.finished(1.0));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
