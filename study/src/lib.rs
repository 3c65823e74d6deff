//! User studies as the paper ran them (Section V: 13 participants, table cleaning and
//! pick-and-place with SCL, CAE and PCA, then pouring with SCL, CAE and mode switching;
//! practice, two attempts per model, single-blind, the order of the models counterbalanced).
//!
//! * [`plan`]: the study file and each participant's order (a balanced Latin square);
//! * [`data`]: `trials.csv` and `questionnaire.csv`, append-only, and where to resume;
//! * [`report`] and [`figures`]: the merged data's tables, rank tests and figures;
//! * [`simulate`]: simulated participants running the protocol on the mock arm, with the
//!   operators of [`operator`].
//!
//! The experimenter's screen that runs a study on the live graph is `scl-study`
//! (`scl study run`).

#![cfg_attr(test, allow(clippy::unwrap_used))]

pub mod capability;
pub mod data;
pub mod diagnose;
pub mod figures;
pub mod operator;
pub mod plan;
pub mod report;
pub mod setup;
pub mod simulate;

use std::path::PathBuf;

pub use plan::{Participant, Study};

/// What went wrong with a study's files, each naming the file (and key) at fault.
#[derive(Debug, thiserror::Error)]
pub enum StudyError {
    /// A file could not be read.
    #[error("{path}: {source}", path = path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// A file could not be written.
    #[error("cannot write {path}: {source}", path = path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The study file is not valid TOML or has an unknown key.
    #[error("{path}: {reason}", path = path.display())]
    Parse {
        /// The study file.
        path: PathBuf,
        /// The parser's message (it names the key and the line).
        reason: String,
    },
    /// A key of the study file has a value that cannot be used.
    #[error("{path}: `{key}`: {reason}", path = path.display())]
    Invalid {
        /// The study file.
        path: PathBuf,
        /// The key (`conditions[1].model`).
        key: String,
        /// Why.
        reason: String,
    },
    /// A participant id outside the plan.
    #[error("participant `{id}`: {reason}")]
    Participant {
        /// The id given.
        id: String,
        /// Why.
        reason: String,
    },
    /// A data file (`trials.csv`, `questionnaire.csv`) is unusable.
    #[error("{path}: {reason}", path = path.display())]
    Data {
        /// The file or directory.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// A simulated participant could not run.
    #[error(transparent)]
    Simulate(#[from] simulate::SimError),
    /// The report could not be made.
    #[error("report: {0}")]
    Report(String),
}
