//! Recorded input: a CSV file of the samples a joystick process published, and its replay
//! with the original timing.
//!
//! The format, one row per change of the input (a row holds until the next one):
//!
//! ```text
//! # comment lines start with '#'
//! t_s,a0,a1,gripper,buttons
//! 0.0,0.0,0.0,0.0,0
//! 1.25,0.8,0.0,0.0,1
//! 3.0,0.0,0.0,0.0,0
//! ```
//!
//! `t_s` is seconds since the first row (non-decreasing), `a0`, `a1` the axes and `gripper` the
//! gripper rate, each in `[-1, 1]`, `buttons` the [`ipc_types::buttons`] bits in decimal. Any
//! decimal notation reads; the recorder writes the shortest that reads back to the same value
//! (so a replay publishes exactly the recorded `f32`s). Read and written with `csv` through
//! [`Row`]; errors name the file and the line. The
//! last row ends the recording: after it a replay is neutral. `scl joystick --record-input FILE`
//! writes such a file (on a writer thread, so the loop never waits on the disk) from any source,
//! and `--source replay --replay FILE` plays one back.

use std::io::Write;
use std::path::{Path, PathBuf};

use crossbeam_channel::{Receiver, Sender};

use super::{Input, JoystickError};

/// The header row: [`Row`]'s field names.
pub const HEADER: &str = "t_s,a0,a1,gripper,buttons";

/// One row: read with `f64` axes (to check their range), written with the `f32` ones
/// published.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Row<A> {
    /// Seconds since the first row.
    pub t_s: f64,
    /// First axis.
    pub a0: A,
    /// Second axis.
    pub a1: A,
    /// Gripper rate.
    pub gripper: A,
    /// [`ipc_types::buttons`] bits.
    pub buttons: u32,
}

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
        let mut rdr = csv::ReaderBuilder::new()
            .comment(Some(b'#'))
            .trim(csv::Trim::All)
            // Rows of another length are reported below, by line.
            .flexible(true)
            .from_reader(text.as_bytes());
        let header = rdr.headers().map_err(|e| bad(0, e.to_string()))?.clone();
        if header.is_empty() {
            return Err(bad(0, "no rows".into()));
        }
        if header.iter().collect::<Vec<_>>().join(",") != HEADER {
            return Err(bad(
                line_ending_at(text, rdr.position().byte()),
                format!("the header must be `{HEADER}`"),
            ));
        }
        let mut rows: Vec<(f64, Input)> = Vec::new();
        let mut record = csv::StringRecord::new();
        loop {
            let read = rdr.read_record(&mut record);
            let line = line_ending_at(text, rdr.position().byte());
            if !read.map_err(|e| bad(line, e.to_string()))? {
                break;
            }
            // A line of blanks, or an indented comment.
            if record.len() == 1 && (record[0].is_empty() || record[0].starts_with('#')) {
                continue;
            }
            if record.len() != 5 {
                return Err(bad(
                    line,
                    format!("{} fields, expected 5 ({HEADER})", record.len()),
                ));
            }
            let not_a = |k: usize| {
                let (name, what) = match k {
                    4 => ("buttons", "a bit mask"),
                    k => (&header[k], "a number"),
                };
                bad(
                    line,
                    format!(
                        "{name} `{}` is not {what}",
                        record.get(k).unwrap_or_default()
                    ),
                )
            };
            let row: Row<f64> = record
                .deserialize(Some(&header))
                .map_err(|e| match e.kind() {
                    csv::ErrorKind::Deserialize { err, .. } => {
                        not_a(err.field().map_or(0, |k| k as usize))
                    }
                    _ => bad(line, e.to_string()),
                })?;
            let values = [row.t_s, row.a0, row.a1, row.gripper];
            if let Some(k) = values.iter().position(|v| !v.is_finite()) {
                return Err(not_a(k));
            }
            for (name, v) in [("a0", row.a0), ("a1", row.a1), ("gripper", row.gripper)] {
                if v.abs() > 1.0 {
                    return Err(bad(line, format!("{name} {v} is outside [-1, 1]")));
                }
            }
            let t = row.t_s;
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
                    axes: [row.a0 as f32, row.a1 as f32],
                    gripper: row.gripper as f32,
                    buttons: row.buttons,
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

/// The line (1-based) of the one-line record of `text` that ends at byte `end` (the reader's
/// position after reading it). Not csv's own record position, which leaves out the comment and
/// blank lines it skips (measured with csv 1.4; `learning::dataset` has the same helper).
fn line_ending_at(text: &str, end: u64) -> usize {
    let upto = text.get(..end as usize).unwrap_or(text);
    1 + upto.trim_end_matches(['\r', '\n']).matches('\n').count()
}

impl Row<f32> {
    /// The row of `input` at `t_s`.
    pub fn of(t_s: f64, input: &Input) -> Self {
        Self {
            t_s,
            a0: input.axes[0],
            a1: input.axes[1],
            gripper: input.gripper,
            buttons: input.buttons,
        }
    }
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

fn write_rows(mut file: std::fs::File, rx: &Receiver<(f64, Input)>) -> std::io::Result<usize> {
    writeln!(
        file,
        "# scl recorded joystick input: seconds since the first sample, axes, gripper rate, button bits"
    )?;
    // csv buffers the rows; the header is written even when no row follows.
    let mut w = csv::WriterBuilder::new()
        .has_headers(false)
        .from_writer(file);
    w.write_record(HEADER.split(','))?;
    let mut n = 0;
    for (t, input) in rx {
        w.serialize(Row::of(t, &input))?;
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
            (
                "# a\n\nt_s,a0,a1,gripper,buttons\n# b\n0,0,0,0,0\n\n  # c\n1,0,y,0,0\n",
                8,
                "a1 `y`",
            ),
            ("# a\nt_s,a0\n", 2, "header"),
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
        let text = std::fs::read_to_string(&p).unwrap();
        assert!(
            text.contains("\nt_s,a0,a1,gripper,buttons\n0.0,0.0,0.0,0.0,0\n0.2,0.25,-0.5,0.0,"),
            "{text}"
        );
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
