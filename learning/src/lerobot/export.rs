//! Writing a LeRobot v3.0 dataset from robot states: one episode per source (a recording),
//! one frame per recorded tick, nothing dropped (see the module docs of [`super`]).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use arrow_array::builder::{ListBuilder, StringBuilder};
use arrow_array::{
    ArrayRef, FixedSizeListArray, Float32Array, Float64Array, Int64Array, RecordBatch, StringArray,
};
use arrow_schema::{DataType, Field, Schema};
use ipc_types::RobotState;
use kinematics::RobotProfile;
use parquet::arrow::ArrowWriter;
use serde_json::{Value, json};

use super::run::{OperatorTick, ServedModel};
use super::{LeRobotError, column, format_error, io};
use crate::dataset::Trajectory;
use crate::to_dataset;

/// One episode to write.
#[derive(Debug, Clone)]
pub struct Source {
    /// What it came from (a recording's file stem, a demonstration's file name); kept in
    /// the episodes metadata.
    pub name: String,
    /// The task's text.
    pub task: String,
    /// Its motion.
    pub motion: Motion,
    /// The operator's side by tick (a recording's; [`OperatorTick::FILL`] for a tick not
    /// in it).
    pub operator: BTreeMap<u64, OperatorTick>,
    /// The map the run served (empty for demonstrations).
    pub model: ServedModel,
}

/// The motion of an episode.
#[derive(Debug, Clone)]
pub enum Motion {
    /// Recorded robot states, any order (sorted by tick, one per tick, when written): one
    /// frame per state, the action the velocity the next state reports.
    States(Vec<RobotState>),
    /// Demonstration tuples (a trajectory of `scl demos`, or of a recording cut as `scl
    /// dataset` cuts them): one frame per tuple, each a demonstration, tuple `k` at tick
    /// `first_tick + k` and time `t0_ns` plus its time in the trajectory.
    Tuples {
        /// The tuples.
        trajectory: Trajectory,
        /// The first tuple's tick (0 for generated demonstrations).
        first_tick: u64,
        /// The first tuple's time stamp (ns; 0 for generated demonstrations).
        t0_ns: u64,
        /// Each tuple's state flags (a recording's; empty: 0 for every tuple).
        flags: Vec<u32>,
    },
}

/// One frame's values.
#[derive(Debug, Clone, PartialEq)]
struct Frame {
    tick: u64,
    t_ns: u64,
    flags: u32,
    /// Joint angles then the gripper.
    state: Vec<f64>,
    /// Executed joint velocities then the gripper rate; zero where nothing followed.
    action: Vec<f64>,
    demonstration: bool,
    operator: OperatorTick,
}

/// The frames of one source: every recorded tick (every tuple), each flagged.
fn frames(s: &Source, n: usize) -> Vec<Frame> {
    let operator = |tick: u64| s.operator.get(&tick).copied().unwrap_or(OperatorTick::FILL);
    match &s.motion {
        Motion::States(states) => state_frames(states, n, operator),
        Motion::Tuples {
            trajectory: t,
            first_tick,
            t0_ns,
            flags,
        } => (0..t.len())
            .map(|k| {
                let tick = first_tick + k as u64;
                let mut state = t.q[k].clone();
                state.push(t.c[k]);
                let mut action = t.qdot[k].clone();
                action.push(t.cdot[k]);
                Frame {
                    tick,
                    t_ns: t0_ns + (t.t[k] * 1e9).round() as u64,
                    flags: flags.get(k).copied().unwrap_or(0),
                    state,
                    action,
                    demonstration: true,
                    operator: operator(tick),
                }
            })
            .collect(),
    }
}

/// The frames of recorded states: every recorded tick, each flagged.
fn state_frames(
    states: &[RobotState],
    n: usize,
    operator: impl Fn(u64) -> OperatorTick,
) -> Vec<Frame> {
    let sorted = to_dataset::sorted_states(states);
    let mut out = Vec::with_capacity(sorted.len());
    for (i, a) in sorted.iter().enumerate() {
        let mut state = a.q().to_vec();
        state.push(a.gripper);
        let mut action = vec![0.0; n + 1];
        let mut demonstration = false;
        if let Some(b) = sorted.get(i + 1)
            && b.tick == a.tick + 1
            && b.n_joints == a.n_joints
            && b.t_ns > a.t_ns
        {
            let dt_s = (b.t_ns - a.t_ns) as f64 / 1e9;
            action[..n].copy_from_slice(b.qdot());
            action[n] = (b.gripper - a.gripper) / dt_s;
            demonstration = to_dataset::is_demonstration(a, b);
        }
        out.push(Frame {
            tick: a.tick,
            t_ns: a.t_ns,
            flags: a.flags,
            state,
            action,
            demonstration,
            operator: operator(a.tick),
        });
    }
    out
}

/// What [`write`] did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ExportReport {
    /// Episodes written.
    pub episodes: usize,
    /// Frames written.
    pub frames: usize,
    /// Frames flagged as no demonstration (missed, stopped, gap, last of an episode).
    pub flagged: usize,
    /// Files written.
    pub files: Vec<PathBuf>,
}

/// Writes `sources` as a LeRobot v3.0 dataset in `out` (which must not exist or be empty)
/// for `profile`'s arm at `fps`. Refuses a state whose joint count is not the profile's.
pub fn write(
    out: &Path,
    profile: &RobotProfile,
    fps: u32,
    sources: &[Source],
) -> Result<ExportReport, LeRobotError> {
    if out.exists() {
        let mut entries = std::fs::read_dir(out).map_err(io(out))?;
        if entries.next().is_some() {
            return Err(LeRobotError::Exists(out.to_owned()));
        }
    }
    let n = profile.n_joints();
    for s in sources {
        let bad = match &s.motion {
            Motion::States(states) => states
                .iter()
                .find(|st| st.q().len() != n)
                .map(|st| (format!("tick {}", st.tick), st.q().len())),
            Motion::Tuples { trajectory: t, .. } => {
                t.q.iter()
                    .enumerate()
                    .find(|(_, q)| q.len() != n)
                    .map(|(k, q)| (format!("tuple {k}"), q.len()))
            }
        };
        if let Some((at, joints)) = bad {
            return Err(format_error(
                Path::new(&s.name),
                format!(
                    "{at} has {joints} joints, but robot profile {} has {n} ({}); pass the arm's --robot",
                    profile.name(),
                    profile.joint_names().join(", ")
                ),
            ));
        }
    }
    let mut tasks: Vec<String> = Vec::new();
    let mut cols = Columns::default();
    let mut episodes = Vec::new();
    for (e, s) in sources.iter().enumerate() {
        let task_index = match tasks.iter().position(|t| *t == s.task) {
            Some(i) => i,
            None => {
                tasks.push(s.task.clone());
                tasks.len() - 1
            }
        };
        let fr = frames(s, n);
        let from = cols.index.len();
        for (k, f) in fr.iter().enumerate() {
            cols.push(f, k, e, task_index, fps);
        }
        episodes.push(EpisodeRow {
            name: s.name.clone(),
            task: s.task.clone(),
            model: s.model.clone(),
            from,
            to: cols.index.len(),
        });
    }
    let data_path = out.join(super::DATA_PATH);
    let episodes_path = out.join(super::EPISODES_PATH);
    let tasks_path = out.join(super::TASKS_PATH);
    let info_path = out.join(super::INFO_PATH);
    let stats_path = out.join(super::STATS_PATH);
    write_parquet(&data_path, cols.batch(n, &data_path)?)?;
    write_parquet(&episodes_path, episodes_batch(&episodes, &episodes_path)?)?;
    write_parquet(&tasks_path, tasks_batch(&tasks, &tasks_path)?)?;
    let mut names: Vec<String> = profile.joint_names().to_vec();
    names.push("gripper".into());
    let info = info_json(
        profile,
        fps,
        &names,
        episodes.len(),
        cols.index.len(),
        &tasks,
    );
    write_json(&info_path, &info)?;
    write_json(&stats_path, &cols.stats(n))?;
    let flagged = cols.demonstration.iter().filter(|d| **d == 0).count();
    Ok(ExportReport {
        episodes: episodes.len(),
        frames: cols.index.len(),
        flagged,
        files: vec![data_path, episodes_path, tasks_path, info_path, stats_path],
    })
}

struct EpisodeRow {
    name: String,
    task: String,
    model: ServedModel,
    from: usize,
    to: usize,
}

/// Every frame column, row by row.
#[derive(Default)]
struct Columns {
    state: Vec<f64>,
    action: Vec<f64>,
    timestamp: Vec<f32>,
    frame_index: Vec<i64>,
    episode_index: Vec<i64>,
    index: Vec<i64>,
    task_index: Vec<i64>,
    tick: Vec<i64>,
    t_ns: Vec<i64>,
    flags: Vec<i64>,
    demonstration: Vec<i64>,
    stick: Vec<f64>,
    mode: Vec<i64>,
    safety_flags: Vec<i64>,
}

impl Columns {
    fn push(&mut self, f: &Frame, k: usize, episode: usize, task: usize, fps: u32) {
        self.state.extend_from_slice(&f.state);
        self.action.extend_from_slice(&f.action);
        // LeRobot checks that time stamps step by 1/fps: they count frames, and the real
        // time and tick are in scl.t_ns and scl.tick.
        self.timestamp.push((k as f64 / f64::from(fps)) as f32);
        self.frame_index.push(k as i64);
        self.episode_index.push(episode as i64);
        self.index.push(self.index.len() as i64);
        self.task_index.push(task as i64);
        self.tick.push(i64::try_from(f.tick).unwrap_or(i64::MAX));
        self.t_ns.push(i64::try_from(f.t_ns).unwrap_or(i64::MAX));
        self.flags.push(i64::from(f.flags));
        self.demonstration.push(i64::from(f.demonstration));
        self.stick.extend_from_slice(&f.operator.stick);
        self.mode.push(f.operator.mode);
        self.safety_flags.push(f.operator.safety_flags);
    }

    fn scalars(&self) -> [(&'static str, Vec<f64>, &'static str); 11] {
        let f = |v: &[i64]| v.iter().map(|x| *x as f64).collect::<Vec<_>>();
        [
            (
                "timestamp",
                self.timestamp.iter().map(|x| f64::from(*x)).collect(),
                "float32",
            ),
            ("frame_index", f(&self.frame_index), "int64"),
            ("episode_index", f(&self.episode_index), "int64"),
            ("index", f(&self.index), "int64"),
            ("task_index", f(&self.task_index), "int64"),
            (column::TICK, f(&self.tick), "int64"),
            (column::T_NS, f(&self.t_ns), "int64"),
            (column::STATE_FLAGS, f(&self.flags), "int64"),
            (column::DEMONSTRATION, f(&self.demonstration), "int64"),
            (column::MODE, f(&self.mode), "int64"),
            (column::SAFETY_FLAGS, f(&self.safety_flags), "int64"),
        ]
    }

    fn batch(&self, n: usize, path: &Path) -> Result<RecordBatch, LeRobotError> {
        let arrow = |source| LeRobotError::Arrow {
            path: path.to_owned(),
            source,
        };
        let vector = |values: &[f64], dim: usize| -> Result<ArrayRef, LeRobotError> {
            let item = Arc::new(Field::new("item", DataType::Float64, true));
            let a = FixedSizeListArray::try_new(
                item,
                dim as i32,
                Arc::new(Float64Array::from(values.to_vec())),
                None,
            )
            .map_err(arrow)?;
            Ok(Arc::new(a))
        };
        let int = |v: &[i64]| -> ArrayRef { Arc::new(Int64Array::from(v.to_vec())) };
        let columns: Vec<(&str, ArrayRef)> = vec![
            (column::STATE, vector(&self.state, n + 1)?),
            (column::ACTION, vector(&self.action, n + 1)?),
            (
                "timestamp",
                Arc::new(Float32Array::from(self.timestamp.clone())),
            ),
            ("frame_index", int(&self.frame_index)),
            ("episode_index", int(&self.episode_index)),
            ("index", int(&self.index)),
            ("task_index", int(&self.task_index)),
            (column::TICK, int(&self.tick)),
            (column::T_NS, int(&self.t_ns)),
            (column::STATE_FLAGS, int(&self.flags)),
            (column::DEMONSTRATION, int(&self.demonstration)),
            (column::STICK, vector(&self.stick, 2)?),
            (column::MODE, int(&self.mode)),
            (column::SAFETY_FLAGS, int(&self.safety_flags)),
        ];
        batch(columns, BTreeMap::new(), path)
    }

    /// meta/stats.json: per feature and dimension min, max, mean, std, and the count.
    fn stats(&self, n: usize) -> Value {
        let mut out = serde_json::Map::new();
        out.insert(column::STATE.into(), vector_stats(&self.state, n + 1));
        out.insert(column::ACTION.into(), vector_stats(&self.action, n + 1));
        out.insert(column::STICK.into(), vector_stats(&self.stick, 2));
        for (name, values, _) in self.scalars() {
            out.insert(name.into(), vector_stats(&values, 1));
        }
        Value::Object(out)
    }
}

/// Stats of `values`, rows of `dim`.
fn vector_stats(values: &[f64], dim: usize) -> Value {
    let rows = values.len() / dim.max(1);
    let mut min = vec![f64::INFINITY; dim];
    let mut max = vec![f64::NEG_INFINITY; dim];
    let mut sum = vec![0.0; dim];
    for row in values.chunks_exact(dim) {
        for j in 0..dim {
            min[j] = min[j].min(row[j]);
            max[j] = max[j].max(row[j]);
            sum[j] += row[j];
        }
    }
    let mean: Vec<f64> = sum.iter().map(|s| s / rows.max(1) as f64).collect();
    let mut var = vec![0.0; dim];
    for row in values.chunks_exact(dim) {
        for j in 0..dim {
            var[j] += (row[j] - mean[j]).powi(2);
        }
    }
    let std: Vec<f64> = var
        .iter()
        .map(|v| (v / rows.max(1) as f64).sqrt())
        .collect();
    if rows == 0 {
        min.fill(0.0);
        max.fill(0.0);
    }
    json!({"min": min, "max": max, "mean": mean, "std": std, "count": [rows]})
}

fn episodes_batch(rows: &[EpisodeRow], path: &Path) -> Result<RecordBatch, LeRobotError> {
    let int = |f: &dyn Fn(usize, &EpisodeRow) -> i64| -> ArrayRef {
        Arc::new(Int64Array::from(
            rows.iter()
                .enumerate()
                .map(|(i, r)| f(i, r))
                .collect::<Vec<_>>(),
        ))
    };
    let mut tasks = ListBuilder::new(StringBuilder::new());
    for r in rows {
        tasks.values().append_value(&r.task);
        tasks.append(true);
    }
    let columns: Vec<(&str, ArrayRef)> = vec![
        ("episode_index", int(&|i, _| i as i64)),
        ("tasks", Arc::new(tasks.finish())),
        ("length", int(&|_, r| (r.to - r.from) as i64)),
        ("data/chunk_index", int(&|_, _| 0)),
        ("data/file_index", int(&|_, _| 0)),
        ("dataset_from_index", int(&|_, r| r.from as i64)),
        ("dataset_to_index", int(&|_, r| r.to as i64)),
        ("meta/episodes/chunk_index", int(&|_, _| 0)),
        ("meta/episodes/file_index", int(&|_, _| 0)),
        (
            column::SOURCE,
            Arc::new(StringArray::from(
                rows.iter().map(|r| r.name.clone()).collect::<Vec<_>>(),
            )),
        ),
        (
            column::MAP_KIND,
            Arc::new(StringArray::from(
                rows.iter()
                    .map(|r| r.model.kind.clone())
                    .collect::<Vec<_>>(),
            )),
        ),
        (
            column::MODEL_SHA256,
            Arc::new(StringArray::from(
                rows.iter()
                    .map(|r| r.model.sha256.clone())
                    .collect::<Vec<_>>(),
            )),
        ),
    ];
    batch(columns, BTreeMap::new(), path)
}

/// meta/tasks.parquet as pandas writes a frame indexed by the task text, so that LeRobot's
/// `pd.read_parquet` gets the text as the index.
fn tasks_batch(tasks: &[String], path: &Path) -> Result<RecordBatch, LeRobotError> {
    let pandas = json!({
        "index_columns": ["__index_level_0__"],
        "column_indexes": [],
        "columns": [
            {"name": "task_index", "field_name": "task_index", "pandas_type": "int64",
             "numpy_type": "int64", "metadata": null},
            {"name": null, "field_name": "__index_level_0__", "pandas_type": "unicode",
             "numpy_type": "object", "metadata": null}
        ],
        "creator": {"library": "scl", "version": env!("CARGO_PKG_VERSION")},
        "pandas_version": "2.0.0"
    });
    let columns: Vec<(&str, ArrayRef)> = vec![
        (
            "task_index",
            Arc::new(Int64Array::from(
                (0..tasks.len() as i64).collect::<Vec<_>>(),
            )),
        ),
        (
            "__index_level_0__",
            Arc::new(StringArray::from(tasks.to_vec())),
        ),
    ];
    let meta = BTreeMap::from([("pandas".to_owned(), pandas.to_string())]);
    batch(columns, meta, path)
}

fn batch(
    columns: Vec<(&str, ArrayRef)>,
    metadata: BTreeMap<String, String>,
    path: &Path,
) -> Result<RecordBatch, LeRobotError> {
    let fields: Vec<Field> = columns
        .iter()
        .map(|(name, a)| Field::new(*name, a.data_type().clone(), true))
        .collect();
    let schema = Schema::new(fields).with_metadata(
        metadata
            .into_iter()
            .collect::<std::collections::HashMap<String, String>>(),
    );
    RecordBatch::try_new(
        Arc::new(schema),
        columns.into_iter().map(|(_, a)| a).collect(),
    )
    .map_err(|source| LeRobotError::Arrow {
        path: path.to_owned(),
        source,
    })
}

fn write_parquet(path: &Path, batch: RecordBatch) -> Result<(), LeRobotError> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(io(dir))?;
    }
    let pq = |source| LeRobotError::Parquet {
        path: path.to_owned(),
        source,
    };
    let file = std::fs::File::create_new(path).map_err(io(path))?;
    let mut w = ArrowWriter::try_new(file, batch.schema(), None).map_err(pq)?;
    w.write(&batch).map_err(pq)?;
    w.close().map_err(pq)?;
    Ok(())
}

fn write_json(path: &Path, v: &Value) -> Result<(), LeRobotError> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(io(dir))?;
    }
    let text = serde_json::to_string_pretty(v).map_err(|source| LeRobotError::Json {
        path: path.to_owned(),
        source,
    })?;
    std::fs::File::create_new(path)
        .and_then(|mut f| std::io::Write::write_all(&mut f, text.as_bytes()))
        .map_err(io(path))
}

fn info_json(
    profile: &RobotProfile,
    fps: u32,
    names: &[String],
    episodes: usize,
    frames: usize,
    tasks: &[String],
) -> Value {
    let vel: Vec<String> = names.iter().map(|n| format!("{n}.vel")).collect();
    let scalar = |dtype: &str| json!({"dtype": dtype, "shape": [1], "names": null});
    json!({
        "codebase_version": super::CODEBASE_VERSION,
        "robot_type": profile.name(),
        "total_episodes": episodes,
        "total_frames": frames,
        "total_tasks": tasks.len(),
        "chunks_size": 1000,
        "data_files_size_in_mb": 100,
        "video_files_size_in_mb": 200,
        "fps": fps,
        "splits": {"train": format!("0:{episodes}")},
        "data_path": super::DATA_PATH_PATTERN,
        "video_path": null,
        "features": {
            column::STATE: {"dtype": "float64", "shape": [names.len()], "names": names},
            column::ACTION: {"dtype": "float64", "shape": [vel.len()], "names": vel},
            "timestamp": scalar("float32"),
            "frame_index": scalar("int64"),
            "episode_index": scalar("int64"),
            "index": scalar("int64"),
            "task_index": scalar("int64"),
            column::TICK: scalar("int64"),
            column::T_NS: scalar("int64"),
            column::STATE_FLAGS: scalar("int64"),
            column::DEMONSTRATION: scalar("int64"),
            column::STICK: {"dtype": "float64", "shape": [2], "names": ["x", "y"]},
            column::MODE: scalar("int64"),
            column::SAFETY_FLAGS: scalar("int64"),
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use ipc_types::state_flags;

    #[test]
    fn every_tick_is_a_frame_and_misses_are_flagged() {
        let mut s: Vec<RobotState> = (0..6)
            .map(|k| {
                let mut st = RobotState::at_rest(k, 1_000 + k * 25_000_000, 2);
                st.qdot_rad_s[0] = 0.1 * k as f64;
                st
            })
            .collect();
        s[3].flags |= state_flags::MISSED;
        s.remove(5); // tick 5 not recorded: tick 4 has no successor
        let f = state_frames(&s, 2, |_| OperatorTick::FILL);
        assert_eq!(f.len(), 5);
        let demo: Vec<bool> = f.iter().map(|f| f.demonstration).collect();
        assert_eq!(demo, [true, true, false, true, false]);
        assert_eq!(f[1].action[0], 0.2, "the velocity the next state reports");
        assert_eq!(f[2].action[0], 0.30000000000000004, "kept, though flagged");
        assert_eq!(f[4].action, vec![0.0; 3]);
    }
}
