//! LeRobot datasets (the `lerobot` package's format, v3.0): recordings out as one
//! ([`export`], `scl dataset --format lerobot`), and one in as training data ([`import`],
//! `scl train --data DIR`). The layout and the meaning of each column are in
//! docs/lerobot.md.
//!
//! A v3.0 dataset is a directory: `meta/info.json` (format version, fps, robot type, the
//! features with dtype, shape and names, the file patterns), `meta/stats.json` (per feature
//! min, max, mean, std, count), `meta/tasks.parquet` (task text -> `task_index`),
//! `meta/episodes/chunk-000/file-000.parquet` (one row per episode: its tasks, length and
//! where its frames lie) and `data/chunk-NNN/file-NNN.parquet` (one row per frame).
//! Parquet is written and read with the `parquet` crate through Arrow arrays; no Python.

pub mod export;
pub mod import;
pub mod run;

use std::path::{Path, PathBuf};

/// The format version written and read.
pub const CODEBASE_VERSION: &str = "v3.0";
/// `meta/info.json`.
pub const INFO_PATH: &str = "meta/info.json";
/// `meta/stats.json`.
pub const STATS_PATH: &str = "meta/stats.json";
/// `meta/tasks.parquet`.
pub const TASKS_PATH: &str = "meta/tasks.parquet";
/// The one episodes-metadata file written.
pub const EPISODES_PATH: &str = "meta/episodes/chunk-000/file-000.parquet";
/// The one data file written.
pub const DATA_PATH: &str = "data/chunk-000/file-000.parquet";
/// The data file pattern info.json states.
pub const DATA_PATH_PATTERN: &str = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet";

/// The extra per-frame columns this stack writes (absent from other datasets).
pub mod column {
    /// The bridge's tick of the state (int64): gaps show ticks that were not recorded.
    pub const TICK: &str = "scl.tick";
    /// The state's time stamp, monotonic ns (int64).
    pub const T_NS: &str = "scl.t_ns";
    /// The state's `ipc_types::state_flags` bits (int64): MISSED, STOPPING, SAFETY_STOP...
    pub const STATE_FLAGS: &str = "scl.state_flags";
    /// 1 when the frame's state and action form a demonstration tuple as `scl dataset`
    /// takes them (int64 0/1): 0 marks a missed or stopped tick, a gap, the last frame.
    pub const DEMONSTRATION: &str = "scl.demonstration";
    /// The 2-D stick input the mapper used for the tick (float64 `x`, `y`:
    /// `MapperCommand::action`); 0, 0 when the tick has no recorded mapper command.
    pub const STICK: &str = "scl.stick";
    /// The map's mode (int64): the mapper's heartbeat's `NodeStatus::mode` latest at or
    /// before the tick (0 a map without modes, 1 + the mode's index otherwise); -1 when none
    /// was recorded.
    pub const MODE: &str = "scl.mode";
    /// Safety's `ipc_types::safe_flags` bits on the tick's executed command (int64); 0 when
    /// the tick has no recorded safe command.
    pub const SAFETY_FLAGS: &str = "scl.safety_flags";
    /// The joint-state feature.
    pub const STATE: &str = "observation.state";
    /// The action feature.
    pub const ACTION: &str = "action";
    /// The episodes-metadata column naming the recording an episode came from.
    pub const SOURCE: &str = "scl/source";
    /// The episodes-metadata column naming the kind of map the run served (`scl`, `pca`,
    /// `cae`, `modeswitch`, ...; empty when the recording does not say).
    pub const MAP_KIND: &str = "scl/map_kind";
    /// The episodes-metadata column with the SHA-256 (hex) of the served model's file as
    /// the recording embeds it (empty for a built-in map or a recording without one).
    pub const MODEL_SHA256: &str = "scl/model_sha256";
}

/// Why a LeRobot dataset could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum LeRobotError {
    /// A file or directory could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The path.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// A parquet file could not be written or read.
    #[error("{path}: {source}")]
    Parquet {
        /// The file.
        path: PathBuf,
        /// The parquet error.
        source: parquet::errors::ParquetError,
    },
    /// Arrow arrays could not be built.
    #[error("{path}: {source}")]
    Arrow {
        /// The file.
        path: PathBuf,
        /// The Arrow error.
        source: arrow_schema::ArrowError,
    },
    /// A JSON file is not valid JSON.
    #[error("{path}: {source}")]
    Json {
        /// The file.
        path: PathBuf,
        /// The parser's error.
        source: serde_json::Error,
    },
    /// The dataset is not what the format or this stack wants.
    #[error("{path}: {reason}")]
    Format {
        /// The file or directory.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// A CSV file (a study's `trials.csv`) does not read.
    #[error("{path}: {source}")]
    Csv {
        /// The file.
        path: PathBuf,
        /// The CSV reader's error.
        source: csv::Error,
    },
    /// Writing would replace existing files.
    #[error("{0} already exists and is not empty; choose another --out or remove it first")]
    Exists(PathBuf),
    /// A recording could not be read.
    #[error(transparent)]
    Record(#[from] recording::RecordError),
    /// The data set built could not be checked.
    #[error(transparent)]
    Dataset(#[from] crate::dataset::DatasetError),
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> LeRobotError + '_ {
    move |source| LeRobotError::Io {
        path: path.to_owned(),
        source,
    }
}

fn format_error(path: &Path, reason: impl Into<String>) -> LeRobotError {
    LeRobotError::Format {
        path: path.to_owned(),
        reason: reason.into(),
    }
}

/// Whether `dir` looks like a LeRobot dataset (has `meta/info.json`).
pub fn is_dataset(dir: &Path) -> bool {
    dir.join(INFO_PATH).is_file()
}

#[cfg(test)]
mod tests;
