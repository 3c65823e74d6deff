//! A participant's data: `trials.csv` (one row per attempt), `questionnaire.csv` (one row
//! per answer), written append-only, a row at a time and synced, so a crash loses at most the
//! attempt under way, and read back to resume at the first unfinished attempt.

use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::StudyError;

/// The trials file's name in a participant's directory.
pub const TRIALS: &str = "trials.csv";
/// The questionnaire file's name in a participant's directory.
pub const QUESTIONNAIRE: &str = "questionnaire.csv";
/// The copy of the study file in a participant's directory.
pub const STUDY_COPY: &str = "study.toml";

/// How an attempt ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Outcome {
    /// The experimenter pressed the success key.
    Success,
    /// The experimenter pressed the failure key.
    Failure,
    /// The time limit ran out.
    Timeout,
}

impl Outcome {
    /// Its name in the files.
    pub fn name(self) -> &'static str {
        match self {
            Self::Success => "success",
            Self::Failure => "failure",
            Self::Timeout => "timeout",
        }
    }
}

/// One attempt: a row of `trials.csv`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrialRow {
    /// The study's name.
    pub study: String,
    /// `P03`.
    pub participant: String,
    /// The task.
    pub task: String,
    /// The condition's blind label.
    pub label: String,
    /// The condition's name (never shown during the study).
    pub condition: String,
    /// The model the condition served.
    pub model: String,
    /// The condition's position in the participant's order, from 1.
    pub position: u32,
    /// The attempt, from 1.
    pub attempt: u32,
    /// The experimenter repeated this attempt: the row is kept, the repetition follows.
    pub repeated: bool,
    /// How it ended.
    pub outcome: Outcome,
    /// The task's completion (%, 100 for a success; entered by the experimenter otherwise).
    pub completion_pct: f64,
    /// Time from start to the end (s), pauses excluded.
    pub duration_s: f64,
    /// Mode-switch presses during the attempt (maps with modes).
    pub mode_switches: u32,
    /// E-stops during the attempt.
    pub estops: u32,
    /// The attempt's recording, relative to the participant's directory.
    pub recording: String,
    /// When it started (Unix time, s).
    pub started_unix_s: f64,
}

/// One answer: a row of `questionnaire.csv`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AnswerRow {
    /// The study's name.
    pub study: String,
    /// `P03`.
    pub participant: String,
    /// The task.
    pub task: String,
    /// The condition's blind label.
    pub label: String,
    /// The condition's name.
    pub condition: String,
    /// `likert` or `tlx`.
    pub kind: String,
    /// The item's text or the subscale's name.
    pub item: String,
    /// The answer.
    pub value: u32,
}

/// Reads every row of a CSV file of `T`; an absent file has none.
pub fn read_rows<T: for<'de> Deserialize<'de>>(path: &Path) -> Result<Vec<T>, StudyError> {
    if !path.exists() {
        return Ok(Vec::new());
    }
    let mut r = csv::Reader::from_path(path).map_err(|e| StudyError::Data {
        path: path.to_owned(),
        reason: e.to_string(),
    })?;
    r.deserialize()
        .enumerate()
        .map(|(i, row)| {
            row.map_err(|e| StudyError::Data {
                path: path.to_owned(),
                reason: format!("row {}: {e}", i + 1),
            })
        })
        .collect()
}

/// An append-only CSV file: the header once when the file is new, then one synced row per
/// call. Existing rows are never rewritten.
pub struct Appender {
    path: PathBuf,
    file: File,
    header: bool,
}

impl Appender {
    /// Opens `path` for appending (creating it).
    pub fn open(path: &Path) -> Result<Self, StudyError> {
        let header = !path.exists() || std::fs::metadata(path).is_ok_and(|m| m.len() == 0);
        let file = OpenOptions::new()
            .create(true)
            .append(true)
            .open(path)
            .map_err(|source| StudyError::Write {
                path: path.to_owned(),
                source,
            })?;
        Ok(Self {
            path: path.to_owned(),
            file,
            header,
        })
    }

    /// Appends `row` and syncs the file.
    pub fn push<T: Serialize>(&mut self, row: &T) -> Result<(), StudyError> {
        self.push_all(std::slice::from_ref(row))
    }

    /// Appends `rows` in one write (a questionnaire is saved whole or not at all) and syncs.
    pub fn push_all<T: Serialize>(&mut self, rows: &[T]) -> Result<(), StudyError> {
        let mut w = csv::WriterBuilder::new()
            .has_headers(self.header)
            .from_writer(Vec::new());
        for row in rows {
            w.serialize(row).map_err(|e| StudyError::Data {
                path: self.path.clone(),
                reason: e.to_string(),
            })?;
        }
        let bytes = w.into_inner().map_err(|e| StudyError::Data {
            path: self.path.clone(),
            reason: e.to_string(),
        })?;
        let werr = |source| StudyError::Write {
            path: self.path.clone(),
            source,
        };
        self.file.write_all(&bytes).map_err(werr)?;
        self.file.sync_data().map_err(werr)?;
        self.header = false;
        Ok(())
    }
}

/// What a participant has done so far, from their files.
#[derive(Debug, Clone, Default)]
pub struct Progress {
    /// Every trial row, in order.
    pub trials: Vec<TrialRow>,
    /// Every answer row, in order.
    pub answers: Vec<AnswerRow>,
}

impl Progress {
    /// Reads the files in `dir` (none yet: nothing done); refuses data of another participant.
    pub fn load(dir: &Path, participant: &str) -> Result<Self, StudyError> {
        let trials: Vec<TrialRow> = read_rows(&dir.join(TRIALS))?;
        let answers: Vec<AnswerRow> = read_rows(&dir.join(QUESTIONNAIRE))?;
        let other = trials
            .iter()
            .map(|t| &t.participant)
            .chain(answers.iter().map(|a| &a.participant))
            .find(|p| p.as_str() != participant);
        if let Some(p) = other {
            return Err(StudyError::Data {
                path: dir.to_owned(),
                reason: format!(
                    "holds data of participant {p}, not {participant}: give each participant \
                     a directory of their own"
                ),
            });
        }
        Ok(Self { trials, answers })
    }

    /// Whether attempt `attempt` of `label` on `task` is finished (a row that was not
    /// repeated).
    pub fn attempt_done(&self, task: &str, label: &str, attempt: u32) -> bool {
        self.trials
            .iter()
            .any(|t| t.task == task && t.label == label && t.attempt == attempt && !t.repeated)
    }

    /// Whether the questionnaire of `label` on `task` was answered.
    pub fn answered(&self, task: &str, label: &str) -> bool {
        self.answers
            .iter()
            .any(|a| a.task == task && a.label == label)
    }
}

/// A file name in `dir` that does not exist yet: `stem.ext`, else `stem-2.ext`, `stem-3.ext`,
/// ... (an attempt cut by a crash keeps its recording; the next try gets a new one).
pub fn fresh_name(dir: &Path, stem: &str, ext: &str) -> PathBuf {
    let first = dir.join(format!("{stem}.{ext}"));
    if !first.exists() {
        return first;
    }
    (2..)
        .map(|i| dir.join(format!("{stem}-{i}.{ext}")))
        .find(|p| !p.exists())
        .unwrap_or(first)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    pub(crate) fn row(task: &str, label: &str, attempt: u32, repeated: bool) -> TrialRow {
        TrialRow {
            study: "s".into(),
            participant: "P01".into(),
            task: task.into(),
            label: label.into(),
            condition: "SCL".into(),
            model: "bundled".into(),
            position: 1,
            attempt,
            repeated,
            outcome: Outcome::Success,
            completion_pct: 100.0,
            duration_s: 12.5,
            mode_switches: 0,
            estops: 0,
            recording: "r.mcap".into(),
            started_unix_s: 1.0,
        }
    }

    #[test]
    fn rows_append_read_back_and_say_what_is_done() {
        let dir = std::env::temp_dir().join(format!("scl-study-data-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let mut a = Appender::open(&dir.join(TRIALS)).unwrap();
        a.push(&row("reach", "A", 1, true)).unwrap();
        a.push(&row("reach", "A", 1, false)).unwrap();
        drop(a);
        // A second writer (a resumed run) appends without a second header.
        let mut a = Appender::open(&dir.join(TRIALS)).unwrap();
        a.push(&row("reach", "A", 2, true)).unwrap();
        let p = Progress::load(&dir, "P01").unwrap();
        assert_eq!(p.trials.len(), 3);
        assert!(p.attempt_done("reach", "A", 1));
        assert!(!p.attempt_done("reach", "A", 2), "only repeated so far");
        assert!(!p.attempt_done("reach", "B", 1));
        let e = Progress::load(&dir, "P02").unwrap_err().to_string();
        assert!(e.contains("P01") && e.contains("P02"), "{e}");
        std::fs::write(dir.join("r.mcap"), b"x").unwrap();
        assert_eq!(fresh_name(&dir, "r", "mcap"), dir.join("r-2.mcap"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
