//! Reading a LeRobot v3.0 dataset as training data (`scl train --data DIR`).
//!
//! Joint positions and the gripper come from `observation.state`, its columns chosen by the
//! profile's joint names (`joint_1` or `joint_1.pos`; `--state-columns` names them
//! otherwise) and a column named `gripper` (or `gripper.pos`; 0 without one). Velocities
//! come from `action` when its columns are velocities (named `<joint>.vel`), else from the
//! states' differences at the dataset's fps. A dataset written by `scl dataset --format
//! lerobot` keeps its `scl.demonstration` flags and times, so it gives the same tuples as
//! `scl dataset` on the same recordings. Episodes are cut and split as `scl dataset` cuts
//! recordings.

use std::path::{Path, PathBuf};

use arrow_array::cast::AsArray;
use arrow_array::types::{Float32Type, Float64Type, Int64Type};
use arrow_array::{Array, RecordBatch};
use arrow_schema::DataType;
use kinematics::RobotProfile;
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
use serde_json::Value;

use super::{LeRobotError, column, format_error, io};
use crate::dataset::Dataset;
use crate::to_dataset::{self, Options, Tuple};

/// How to read a LeRobot dataset.
#[derive(Debug, Clone, Default)]
pub struct ImportOptions {
    /// The arm (a built-in profile name); `None`: the dataset's `robot_type` when it names a
    /// profile, else the default profile.
    pub robot: Option<String>,
    /// `observation.state`'s columns for the joints, base to tip, then optionally the
    /// gripper's; `None`: chosen by the profile's names.
    pub state_columns: Option<Vec<String>>,
}

/// Reads the LeRobot dataset `dir` into a training data set cut with `o` (as `scl dataset`
/// would). Returns the data set and the profile it is for.
pub fn load(
    dir: &Path,
    opts: &ImportOptions,
    o: &Options,
) -> Result<(Dataset, &'static RobotProfile), LeRobotError> {
    o.validate()
        .map_err(|e| format_error(dir, format!("cutting options: {e}")))?;
    let info_path = dir.join(super::INFO_PATH);
    let text = std::fs::read_to_string(&info_path).map_err(io(&info_path))?;
    let info: Value = serde_json::from_str(&text).map_err(|source| LeRobotError::Json {
        path: info_path.clone(),
        source,
    })?;
    let robot_type = info["robot_type"].as_str().unwrap_or("");
    let profile = pick_profile(&info_path, robot_type, opts.robot.as_deref())?;
    let fps = info["fps"]
        .as_f64()
        .filter(|f| *f > 0.0)
        .ok_or_else(|| format_error(&info_path, "no positive `fps`"))?;
    let names = feature_names(&info, column::STATE)
        .ok_or_else(|| format_error(&info_path, "no `observation.state` feature with names"))?;
    let pick = pick_columns(&info_path, &names, profile, opts.state_columns.as_deref())?;
    let action_cols =
        feature_names(&info, column::ACTION).and_then(|a| velocity_columns(&a, &names, &pick));
    let frames = read_frames(dir)?;
    let stem = dir.file_name().map_or_else(
        || "lerobot".to_owned(),
        |s| s.to_string_lossy().into_owned(),
    );
    let mut runs_by_episode: Vec<(String, Vec<Vec<Tuple>>)> = Vec::new();
    for ep in group_episodes(&frames) {
        let runs = episode_runs(ep, &pick, action_cols.as_ref(), fps);
        let source = frames
            .source(ep[0].episode)
            .unwrap_or_else(|| format!("{stem}-ep{}", ep[0].episode));
        runs_by_episode.push((source, runs));
    }
    let mut all = Vec::new();
    for (source, runs) in runs_by_episode {
        all.extend(to_dataset::cut(runs, &source, o).0);
    }
    let ds = to_dataset::split(all, o.val_fraction);
    let ds = crate::dataset::through_files(dir, ds.train, ds.val)?;
    Ok((ds, profile))
}

fn pick_profile(
    path: &Path,
    robot_type: &str,
    asked: Option<&str>,
) -> Result<&'static RobotProfile, LeRobotError> {
    let name = match asked {
        Some(n) => n,
        None if RobotProfile::names().any(|n| n == robot_type) => robot_type,
        None => RobotProfile::default_name(),
    };
    RobotProfile::by_name(name).map_err(|e| format_error(path, format!("--robot: {e}")))
}

fn feature_names(info: &Value, key: &str) -> Option<Vec<String>> {
    let names = &info["features"][key]["names"];
    let list = match names {
        Value::Array(a) => a,
        // Older writers nest the list: {"motors": [...]}.
        Value::Object(m) => m.values().next()?.as_array()?,
        _ => return None,
    };
    list.iter().map(|v| v.as_str().map(str::to_owned)).collect()
}

fn base(name: &str) -> &str {
    name.strip_suffix(".pos")
        .or_else(|| name.strip_suffix("_pos"))
        .unwrap_or(name)
}

/// The state columns of the joints and of the gripper.
#[derive(Debug, Clone)]
struct Pick {
    joints: Vec<usize>,
    gripper: Option<usize>,
}

fn pick_columns(
    path: &Path,
    names: &[String],
    profile: &RobotProfile,
    asked: Option<&[String]>,
) -> Result<Pick, LeRobotError> {
    let n = profile.n_joints();
    let find = |want: &str| names.iter().position(|c| c == want || base(c) == want);
    let mismatch = |what: String| {
        format_error(
            path,
            format!(
                "{what}: observation.state has {} columns [{}]; robot profile {} has {n} joints [{}] (choose the arm with --robot, or the columns with --state-columns)",
                names.len(),
                names.join(", "),
                profile.name(),
                profile.joint_names().join(", ")
            ),
        )
    };
    let (joint_names, gripper): (Vec<String>, Option<String>) = match asked {
        Some(cols) if cols.len() == n || cols.len() == n + 1 => {
            (cols[..n].to_vec(), cols.get(n).cloned())
        }
        Some(cols) => {
            return Err(mismatch(format!(
                "--state-columns names {} columns, not {n} or {}",
                cols.len(),
                n + 1
            )));
        }
        None => (profile.joint_names().to_vec(), Some("gripper".into())),
    };
    let mut joints = Vec::with_capacity(n);
    for j in &joint_names {
        joints.push(find(j).ok_or_else(|| mismatch(format!("no column `{j}`")))?);
    }
    let gripper = match (gripper, asked.is_some()) {
        (Some(g), true) => Some(find(&g).ok_or_else(|| mismatch(format!("no column `{g}`")))?),
        (Some(g), false) => find(&g),
        (None, _) => None,
    };
    Ok(Pick { joints, gripper })
}

/// The action columns that hold the picked joints' (and gripper's) velocities, when every
/// one is there as `<state column>.vel`.
fn velocity_columns(action: &[String], state: &[String], pick: &Pick) -> Option<Pick> {
    let vel = |i: usize| {
        let want = format!("{}.vel", base(&state[i]));
        action.iter().position(|a| *a == want)
    };
    let joints = pick
        .joints
        .iter()
        .map(|i| vel(*i))
        .collect::<Option<Vec<_>>>()?;
    let gripper = match pick.gripper {
        Some(g) => Some(vel(g)?),
        None => None,
    };
    Some(Pick { joints, gripper })
}

#[derive(Debug, Clone)]
struct Frame {
    episode: i64,
    frame_index: i64,
    timestamp: f64,
    state: Vec<f64>,
    action: Option<Vec<f64>>,
    tick: Option<i64>,
    t_ns: Option<i64>,
    demonstration: Option<bool>,
}

struct Frames {
    rows: Vec<Frame>,
    sources: Vec<(i64, String)>,
}

impl std::ops::Deref for Frames {
    type Target = [Frame];
    fn deref(&self) -> &[Frame] {
        &self.rows
    }
}

impl Frames {
    fn source(&self, episode: i64) -> Option<String> {
        self.sources
            .iter()
            .find(|(e, _)| *e == episode)
            .map(|(_, s)| s.clone())
    }
}

fn parquet_files(dir: &Path) -> Result<Vec<PathBuf>, LeRobotError> {
    let mut out = Vec::new();
    if !dir.is_dir() {
        return Ok(out);
    }
    for chunk in std::fs::read_dir(dir).map_err(io(dir))? {
        let chunk = chunk.map_err(io(dir))?.path();
        if chunk.is_dir() {
            for f in std::fs::read_dir(&chunk).map_err(io(&chunk))? {
                let f = f.map_err(io(&chunk))?.path();
                if f.extension().is_some_and(|e| e == "parquet") {
                    out.push(f);
                }
            }
        }
    }
    out.sort();
    Ok(out)
}

fn batches(path: &Path) -> Result<Vec<RecordBatch>, LeRobotError> {
    let pq = |source| LeRobotError::Parquet {
        path: path.to_owned(),
        source,
    };
    let file = std::fs::File::open(path).map_err(io(path))?;
    let reader = ParquetRecordBatchReaderBuilder::try_new(file)
        .map_err(pq)?
        .build()
        .map_err(pq)?;
    reader
        .map(|b| {
            b.map_err(|source| LeRobotError::Arrow {
                path: path.to_owned(),
                source,
            })
        })
        .collect()
}

/// A numeric column as f64 per row.
fn scalars(b: &RecordBatch, name: &str) -> Option<Vec<f64>> {
    let c = b.column_by_name(name)?;
    Some(match c.data_type() {
        DataType::Int64 => c
            .as_primitive::<Int64Type>()
            .values()
            .iter()
            .map(|v| *v as f64)
            .collect(),
        DataType::Float64 => c.as_primitive::<Float64Type>().values().to_vec(),
        DataType::Float32 => c
            .as_primitive::<Float32Type>()
            .values()
            .iter()
            .map(|v| f64::from(*v))
            .collect(),
        _ => return None,
    })
}

fn ints(b: &RecordBatch, name: &str) -> Option<Vec<i64>> {
    let c = b.column_by_name(name)?;
    (c.data_type() == &DataType::Int64).then(|| c.as_primitive::<Int64Type>().values().to_vec())
}

/// A vector column as rows of f64.
fn vectors(b: &RecordBatch, name: &str) -> Option<Vec<Vec<f64>>> {
    let c = b.column_by_name(name)?;
    let rows: Vec<std::sync::Arc<dyn Array>> = if let Some(l) = c.as_fixed_size_list_opt() {
        (0..l.len()).map(|i| l.value(i)).collect()
    } else if let Some(l) = c.as_list_opt::<i32>() {
        (0..l.len()).map(|i| l.value(i)).collect()
    } else {
        return None;
    };
    rows.iter()
        .map(|v| match v.data_type() {
            DataType::Float64 => Some(v.as_primitive::<Float64Type>().values().to_vec()),
            DataType::Float32 => Some(
                v.as_primitive::<Float32Type>()
                    .values()
                    .iter()
                    .map(|x| f64::from(*x))
                    .collect(),
            ),
            _ => None,
        })
        .collect()
}

fn read_frames(dir: &Path) -> Result<Frames, LeRobotError> {
    let data = dir.join("data");
    let files = parquet_files(&data)?;
    if files.is_empty() {
        return Err(format_error(&data, "no data/chunk-*/file-*.parquet"));
    }
    let mut rows = Vec::new();
    for f in &files {
        for b in batches(f)? {
            let need = |name: &str| format_error(f, format!("no numeric column `{name}`"));
            let state = vectors(&b, column::STATE).ok_or_else(|| need(column::STATE))?;
            let episode = ints(&b, "episode_index").ok_or_else(|| need("episode_index"))?;
            let frame_index = ints(&b, "frame_index").ok_or_else(|| need("frame_index"))?;
            let timestamp = scalars(&b, "timestamp").ok_or_else(|| need("timestamp"))?;
            let action = vectors(&b, column::ACTION);
            let tick = ints(&b, column::TICK);
            let t_ns = ints(&b, column::T_NS);
            let demo = ints(&b, column::DEMONSTRATION);
            for (i, s) in state.into_iter().enumerate() {
                rows.push(Frame {
                    episode: episode[i],
                    frame_index: frame_index[i],
                    timestamp: timestamp[i],
                    state: s,
                    action: action.as_ref().map(|a| a[i].clone()),
                    tick: tick.as_ref().map(|t| t[i]),
                    t_ns: t_ns.as_ref().map(|t| t[i]),
                    demonstration: demo.as_ref().map(|d| d[i] != 0),
                });
            }
        }
    }
    let mut sources = Vec::new();
    for f in parquet_files(&dir.join("meta/episodes"))? {
        for b in batches(&f)? {
            let (Some(e), Some(s)) = (
                ints(&b, "episode_index"),
                b.column_by_name(column::SOURCE)
                    .and_then(|c| c.as_string_opt::<i32>().cloned()),
            ) else {
                continue;
            };
            for (i, e) in e.iter().enumerate() {
                sources.push((*e, s.value(i).to_owned()));
            }
        }
    }
    Ok(Frames { rows, sources })
}

/// The frames of each episode, in order.
fn group_episodes(frames: &[Frame]) -> Vec<&[Frame]> {
    frames
        .chunk_by(|a, b| a.episode == b.episode && b.frame_index > a.frame_index)
        .collect()
}

/// The runs of demonstration tuples of one episode.
fn episode_runs(ep: &[Frame], pick: &Pick, vel: Option<&Pick>, fps: f64) -> Vec<Vec<Tuple>> {
    let q = |f: &Frame| pick.joints.iter().map(|j| f.state[*j]).collect::<Vec<_>>();
    let c = |f: &Frame| pick.gripper.map_or(0.0, |g| f.state[g]);
    let tick = |f: &Frame| f.tick.map_or(f.frame_index, |t| t) as u64;
    let t_ns = |f: &Frame| f.t_ns.map_or((f.timestamp * 1e9).round() as i64, |t| t) as u64;
    let mut runs = Vec::new();
    let mut cur: Vec<Tuple> = Vec::new();
    for (k, f) in ep.iter().enumerate() {
        let from_action = vel.zip(f.action.as_ref());
        let tuple = match (from_action, ep.get(k + 1)) {
            (Some((v, a)), _) => Some((
                v.joints.iter().map(|j| a[*j]).collect(),
                v.gripper.map_or(0.0, |g| a[g]),
            )),
            (None, Some(next)) => Some((
                q(next)
                    .iter()
                    .zip(q(f))
                    .map(|(b, a)| (b - a) * fps)
                    .collect(),
                (c(next) - c(f)) * fps,
            )),
            (None, None) => None,
        };
        let ok = tuple.is_some() && f.demonstration.unwrap_or(true);
        match tuple {
            Some((qd, cd)) if ok => cur.push(Tuple {
                tick: tick(f),
                t_ns: t_ns(f),
                q: q(f),
                c: c(f),
                qd,
                cd,
            }),
            _ => {
                if !cur.is_empty() {
                    runs.push(std::mem::take(&mut cur));
                }
            }
        }
    }
    if !cur.is_empty() {
        runs.push(cur);
    }
    runs
}

/// The training data at `path`: a LeRobot dataset (cut with `scl dataset`'s defaults), or
/// else a data set directory or file ([`crate::dataset::load`]).
pub fn load_training_data(path: &Path, opts: &ImportOptions) -> Result<Dataset, crate::ToolError> {
    if super::is_dataset(path) {
        let (ds, profile) = load(path, opts, &Options::DEFAULT)?;
        tracing::info!(
            robot = profile.name(),
            train = ds.n_train(),
            val = ds.n_val(),
            "read the LeRobot dataset {}",
            path.display()
        );
        Ok(ds)
    } else {
        Ok(crate::dataset::load(path)?)
    }
}
