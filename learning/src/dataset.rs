//! Demonstration data sets: trajectories of `(t, q, c, qdot, cdot)` tuples at 40 Hz.
//!
//! On disk a trajectory is one CSV file with the header `t,q0,…,q{m-1},c,qd0,…,qd{m-1},cd`
//! (seconds, rad, gripper state in `[0, 1]`, rad/s, 1/s). A data set is a directory with
//! `train/` and `val/` sub-directories of such files; a directory of CSV files without them is
//! all training data. Bad rows are reported by file and line.
//!
//! The same directories may also hold the SCL maps authors' JSON demonstrations (`*.json`):
//! a list of trajectories, each a list of samples `{"thetas": [...], "velocity": [...]}`
//! (joint angles in rad, joint velocities in rad/s, 40 Hz), with an optional `"gripper"`
//! state in `[0, 1]` (0 when absent); other keys are ignored. A JSON file gives one
//! trajectory per list entry, named `file.json#i`. Bad samples are reported by file,
//! trajectory and sample index; bad JSON by file, line and column. [`load`] takes a data set
//! directory or a single CSV or JSON file.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// One demonstration.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Trajectory {
    /// Where it came from (file name).
    pub name: String,
    /// Time of each tuple (s).
    pub t: Vec<f64>,
    /// Joint angles of each tuple (rad).
    pub q: Vec<Vec<f64>>,
    /// Gripper state of each tuple.
    pub c: Vec<f64>,
    /// Joint velocities of each tuple (rad/s).
    pub qdot: Vec<Vec<f64>>,
    /// Gripper rate of each tuple (1/s).
    pub cdot: Vec<f64>,
}

impl Trajectory {
    /// Number of tuples.
    pub fn len(&self) -> usize {
        self.t.len()
    }
    /// Whether it has no tuples.
    pub fn is_empty(&self) -> bool {
        self.t.is_empty()
    }
    /// Number of joints (0 if empty).
    pub fn n_joints(&self) -> usize {
        self.q.first().map_or(0, Vec::len)
    }
}

/// A training / validation split of trajectories.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Dataset {
    /// Training trajectories.
    pub train: Vec<Trajectory>,
    /// Validation trajectories.
    pub val: Vec<Trajectory>,
    /// FNV-1a 64 hash of every file's bytes in load order, hex: identifies the data a model
    /// was trained on.
    pub hash: String,
}

impl Dataset {
    /// Every training velocity row.
    pub fn train_qdot(&self) -> Vec<Vec<f64>> {
        self.train
            .iter()
            .flat_map(|t| t.qdot.iter().cloned())
            .collect()
    }
    /// Every validation velocity row.
    pub fn val_qdot(&self) -> Vec<Vec<f64>> {
        self.val
            .iter()
            .flat_map(|t| t.qdot.iter().cloned())
            .collect()
    }
    /// Tuples in the training split.
    pub fn n_train(&self) -> usize {
        self.train.iter().map(Trajectory::len).sum()
    }
    /// Tuples in the validation split.
    pub fn n_val(&self) -> usize {
        self.val.iter().map(Trajectory::len).sum()
    }
}

/// Why a data set could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// A file or directory could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The path.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The directory holds no trajectories.
    #[error(
        "{0}: no trajectories found (expected train/*.csv and val/*.csv, or *.csv; *.json also works)"
    )]
    Empty(PathBuf),
    /// The header line is wrong.
    #[error("{path}:1: bad header: {reason}")]
    Header {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// A data row is wrong.
    #[error("{path}:{line}: {reason}")]
    Row {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        reason: String,
    },
    /// Trajectories disagree on the joint count.
    #[error("{path}: has {found} joints, but earlier files have {expected}")]
    JointCount {
        /// The file.
        path: PathBuf,
        /// Its joint count.
        found: usize,
        /// The others'.
        expected: usize,
    },
    /// Writing would replace an existing file.
    #[error("{0} already exists; choose another --out or remove it first")]
    Exists(PathBuf),
    /// A JSON demonstration file is not valid JSON.
    #[error("{path}:{line}:{column}: not valid JSON: {reason}")]
    Json {
        /// The file.
        path: PathBuf,
        /// 1-based line.
        line: usize,
        /// 1-based column.
        column: usize,
        /// The parser's message.
        reason: String,
    },
    /// A JSON demonstration is not of the expected shape.
    #[error("{path}: {at}: {reason}")]
    JsonShape {
        /// The file.
        path: PathBuf,
        /// Where in the file: `top level`, `trajectory 2` or `trajectory 2, sample 17`
        /// (0-based indices).
        at: String,
        /// What is wrong.
        reason: String,
    },
}

/// The CSV header for `m` joints.
pub fn header(m: usize) -> String {
    let mut h = String::from("t");
    for i in 0..m {
        let _ = write!(h, ",q{i}");
    }
    h.push_str(",c");
    for i in 0..m {
        let _ = write!(h, ",qd{i}");
    }
    h.push_str(",cd");
    h
}

/// Parses one trajectory from CSV text; `path` names it in errors (with the line, from csv's
/// record position).
pub fn parse_csv(text: &str, path: &Path) -> Result<Trajectory, DatasetError> {
    let mut rdr = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        // Rows of another length are reported below, by line, with both counts.
        .flexible(true)
        .from_reader(text.as_bytes());
    let header_error = |reason: String| DatasetError::Header {
        path: path.to_owned(),
        reason,
    };
    let cols = rdr
        .headers()
        .map_err(|e| header_error(e.to_string()))?
        .clone();
    if cols.is_empty() {
        return Err(header_error("the file is empty".into()));
    }
    if cols.len() < 5 || !(cols.len() - 3).is_multiple_of(2) {
        return Err(header_error(format!(
            "{} columns; expected t,q0..,c,qd0..,cd",
            cols.len()
        )));
    }
    let m = (cols.len() - 3) / 2;
    let expected = header(m);
    let found = cols.iter().collect::<Vec<_>>().join(",");
    if found != expected {
        return Err(header_error(format!(
            "expected `{expected}`, found `{found}`"
        )));
    }
    let mut traj = Trajectory {
        name: path
            .file_name()
            .map_or_else(String::new, |n| n.to_string_lossy().into_owned()),
        ..Trajectory::default()
    };
    let mut record = csv::StringRecord::new();
    loop {
        let read = rdr.read_record(&mut record);
        let line = line_ending_at(text, rdr.position().byte());
        let bad = |reason: String| DatasetError::Row {
            path: path.to_owned(),
            line,
            reason,
        };
        if !read.map_err(|e| bad(e.to_string()))? {
            break;
        }
        // A line of blanks.
        if record.len() == 1 && record[0].is_empty() {
            continue;
        }
        if record.len() != cols.len() {
            return Err(bad(format!(
                "{} fields, expected {}",
                record.len(),
                cols.len()
            )));
        }
        let row: Vec<f64> = record.deserialize(None).map_err(|e| {
            let k = match e.kind() {
                csv::ErrorKind::Deserialize { err, .. } => err.field().map_or(0, |k| k as usize),
                _ => 0,
            };
            bad(format!(
                "column `{}` is `{}`, not a number",
                &cols[k],
                record.get(k).unwrap_or_default()
            ))
        })?;
        if let Some(k) = row.iter().position(|v| !v.is_finite()) {
            return Err(bad(format!("column `{}` is {}", &cols[k], row[k])));
        }
        if let Some(&last) = traj.t.last()
            && row[0] <= last
        {
            return Err(bad(format!(
                "time {} does not increase (previous {last})",
                row[0]
            )));
        }
        traj.t.push(row[0]);
        traj.q.push(row[1..=m].to_vec());
        traj.c.push(row[m + 1]);
        traj.qdot.push(row[m + 2..2 * m + 2].to_vec());
        traj.cdot.push(row[2 * m + 2]);
    }
    Ok(traj)
}

/// The line (1-based) of the one-line record of `text` that ends at byte `end` (the reader's
/// position after reading it). Not csv's own record position: measured with csv 1.4, that
/// leaves out the blank lines it skips (in `t,..\n\n0,..\n\n0.1,x,..` it puts the last record
/// on line 4, not 5) and comment lines altogether, and its byte offset is where the skipped
/// lines start; where a record ends is exact.
pub(crate) fn line_ending_at(text: &str, end: u64) -> usize {
    let upto = text.get(..end as usize).unwrap_or(text);
    1 + upto.trim_end_matches(['\r', '\n']).matches('\n').count()
}

/// Numbers with `D` decimals, the data sets' fixed format (`t` with 4, the rest with 6): a
/// file's bytes, and so the data set's hash, depend only on the values to that precision.
struct Decimals<'a, const D: usize>(&'a [f64]);

impl<const D: usize> serde::Serialize for Decimals<'_, D> {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_seq(self.0.iter().map(|v| format!("{v:.D$}")))
    }
}

/// One tuple as a CSV row, in the header's column order.
#[derive(serde::Serialize)]
struct Row<'a> {
    t: Decimals<'a, 4>,
    q: Decimals<'a, 6>,
    c: Decimals<'a, 6>,
    qd: Decimals<'a, 6>,
    cd: Decimals<'a, 6>,
}

/// Writes a trajectory as CSV (the header, then one row per tuple).
pub fn write_csv(w: impl std::io::Write, traj: &Trajectory) -> Result<(), csv::Error> {
    let mut w = csv::WriterBuilder::new().has_headers(false).from_writer(w);
    w.write_record(header(traj.n_joints()).split(','))?;
    for k in 0..traj.len() {
        w.serialize(Row {
            t: Decimals(std::slice::from_ref(&traj.t[k])),
            q: Decimals(&traj.q[k]),
            c: Decimals(std::slice::from_ref(&traj.c[k])),
            qd: Decimals(&traj.qdot[k]),
            cd: Decimals(std::slice::from_ref(&traj.cdot[k])),
        })?;
    }
    w.flush()?;
    Ok(())
}

/// Parses the authors' JSON demonstrations (see the module docs); `path` names the file in
/// errors and, with `#i`, each trajectory.
pub fn parse_json(text: &str, path: &Path) -> Result<Vec<Trajectory>, DatasetError> {
    let value: serde_json::Value = serde_json::from_str(text).map_err(|e| DatasetError::Json {
        path: path.to_owned(),
        line: e.line(),
        column: e.column(),
        reason: e.to_string(),
    })?;
    let shape = |at: String, reason: String| DatasetError::JsonShape {
        path: path.to_owned(),
        at,
        reason,
    };
    let serde_json::Value::Array(trajs) = value else {
        return Err(shape(
            "top level".into(),
            "expected a list of trajectories".into(),
        ));
    };
    let file = path
        .file_name()
        .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
    let numbers = |v: &serde_json::Value, key: &str, at: &dyn Fn() -> String| {
        let Some(list) = v.get(key) else {
            return Err(shape(at(), format!("no `{key}`")));
        };
        let Some(list) = list.as_array() else {
            return Err(shape(at(), format!("`{key}` is not a list of numbers")));
        };
        list.iter()
            .enumerate()
            .map(|(j, x)| match x.as_f64() {
                Some(f) if f.is_finite() => Ok(f),
                _ => Err(shape(
                    at(),
                    format!("`{key}`[{j}] is `{x}`, not a finite number"),
                )),
            })
            .collect::<Result<Vec<f64>, _>>()
    };
    let mut out = Vec::with_capacity(trajs.len());
    let mut m: Option<usize> = None;
    for (i, samples) in trajs.iter().enumerate() {
        let Some(samples) = samples.as_array() else {
            return Err(shape(
                format!("trajectory {i}"),
                "expected a list of samples".into(),
            ));
        };
        let mut traj = Trajectory {
            name: format!("{file}#{i}"),
            ..Trajectory::default()
        };
        for (k, sample) in samples.iter().enumerate() {
            let at = || format!("trajectory {i}, sample {k}");
            if !sample.is_object() {
                return Err(shape(
                    at(),
                    "expected an object with `thetas` and `velocity`".into(),
                ));
            }
            let q = numbers(sample, "thetas", &at)?;
            let qdot = numbers(sample, "velocity", &at)?;
            if q.is_empty() || q.len() != qdot.len() {
                return Err(shape(
                    at(),
                    format!(
                        "`thetas` has {} values and `velocity` {}; expected the same number, at least one",
                        q.len(),
                        qdot.len()
                    ),
                ));
            }
            match m {
                None => m = Some(q.len()),
                Some(expected) if expected != q.len() => {
                    return Err(shape(
                        at(),
                        format!("{} joints, but the samples before have {expected}", q.len()),
                    ));
                }
                Some(_) => {}
            }
            let c = match sample.get("gripper") {
                None | Some(serde_json::Value::Null) => 0.0,
                Some(g) => match g.as_f64() {
                    Some(c) if (0.0..=1.0).contains(&c) => c,
                    _ => {
                        return Err(shape(
                            at(),
                            format!("`gripper` is `{g}`, not a number in [0, 1]"),
                        ));
                    }
                },
            };
            traj.t.push(k as f64 * crate::demos::DT);
            traj.q.push(q);
            traj.c.push(c);
            traj.qdot.push(qdot);
            traj.cdot.push(0.0);
        }
        // The gripper rate: forward differences of the state (0 on the last sample).
        for k in 1..traj.len() {
            traj.cdot[k - 1] = (traj.c[k] - traj.c[k - 1]) / crate::demos::DT;
        }
        out.push(traj);
    }
    Ok(out)
}

fn data_files(dir: &Path) -> Result<Vec<PathBuf>, DatasetError> {
    let rd = std::fs::read_dir(dir).map_err(|source| DatasetError::Io {
        path: dir.to_owned(),
        source,
    })?;
    let mut files: Vec<PathBuf> = rd
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "csv" || e == "json"))
        .collect();
    files.sort();
    Ok(files)
}

fn is_json(path: &Path) -> bool {
    path.extension().is_some_and(|e| e == "json")
}

fn fnv1a(hash: &mut u64, bytes: &[u8]) {
    for b in bytes {
        *hash ^= u64::from(*b);
        *hash = hash.wrapping_mul(0x0000_0100_0000_01B3);
    }
}

/// Loads a data set directory (see the module docs).
pub fn load_dir(dir: &Path) -> Result<Dataset, DatasetError> {
    let (train_dir, val_dir) = (dir.join("train"), dir.join("val"));
    let (train_files, val_files) = if train_dir.is_dir() {
        let val = if val_dir.is_dir() {
            data_files(&val_dir)?
        } else {
            Vec::new()
        };
        (data_files(&train_dir)?, val)
    } else {
        (data_files(dir)?, Vec::new())
    };
    load_files(dir, &train_files, &val_files)
}

/// Loads a data set from a directory (see [`load_dir`]) or from one CSV or JSON file (all
/// of it training data).
pub fn load(path: &Path) -> Result<Dataset, DatasetError> {
    if path.is_file() {
        load_files(path, &[path.to_owned()], &[])
    } else {
        load_dir(path)
    }
}

fn load_files(
    dir: &Path,
    train_files: &[PathBuf],
    val_files: &[PathBuf],
) -> Result<Dataset, DatasetError> {
    if train_files.is_empty() {
        return Err(DatasetError::Empty(dir.to_owned()));
    }
    let mut hash = 0xcbf2_9ce4_8422_2325u64;
    let mut m: Option<usize> = None;
    let mut read = |files: &[PathBuf]| -> Result<Vec<Trajectory>, DatasetError> {
        let mut out = Vec::new();
        for f in files {
            let bytes = std::fs::read(f).map_err(|source| DatasetError::Io {
                path: f.clone(),
                source,
            })?;
            fnv1a(&mut hash, &bytes);
            let text = String::from_utf8_lossy(&bytes);
            let trajs = if is_json(f) {
                parse_json(&text, f)?
            } else {
                vec![parse_csv(&text, f)?]
            };
            for traj in trajs {
                let tm = traj.n_joints();
                if traj.is_empty() {
                    continue;
                }
                match m {
                    None => m = Some(tm),
                    Some(expected) if expected != tm => {
                        return Err(DatasetError::JointCount {
                            path: f.clone(),
                            found: tm,
                            expected,
                        });
                    }
                    Some(_) => {}
                }
                out.push(traj);
            }
        }
        Ok(out)
    };
    let train = read(train_files)?;
    let val = read(val_files)?;
    if train.is_empty() {
        return Err(DatasetError::Empty(dir.to_owned()));
    }
    Ok(Dataset {
        train,
        val,
        hash: format!("{hash:016x}"),
    })
}

/// The data set that [`load_dir`] would read back from a directory that [`write_dir`] wrote
/// with `train` and `val`: each split sorted by name, every value at the files' precision,
/// the same hash. Other sources (a LeRobot dataset) so train exactly as the same tuples
/// written by `scl dataset` do; `origin` names the source in errors.
pub fn through_files(
    origin: &Path,
    mut train: Vec<Trajectory>,
    mut val: Vec<Trajectory>,
) -> Result<Dataset, DatasetError> {
    let mut hash = 0xcbf2_9ce4_8422_2325u64;
    let mut m: Option<usize> = None;
    let mut read = |trajs: &mut Vec<Trajectory>| -> Result<Vec<Trajectory>, DatasetError> {
        trajs.sort_by(|a, b| a.name.cmp(&b.name));
        let mut out = Vec::with_capacity(trajs.len());
        for t in trajs.iter().filter(|t| !t.is_empty()) {
            let path = origin.join(&t.name);
            let mut bytes = Vec::new();
            write_csv(&mut bytes, t).map_err(|e| DatasetError::Row {
                path: path.clone(),
                line: 1,
                reason: e.to_string(),
            })?;
            fnv1a(&mut hash, &bytes);
            let back = parse_csv(&String::from_utf8_lossy(&bytes), &path)?;
            match m {
                None => m = Some(back.n_joints()),
                Some(expected) if expected != back.n_joints() => {
                    return Err(DatasetError::JointCount {
                        path,
                        found: back.n_joints(),
                        expected,
                    });
                }
                Some(_) => {}
            }
            out.push(back);
        }
        Ok(out)
    };
    let train = read(&mut train)?;
    let val = read(&mut val)?;
    if train.is_empty() {
        return Err(DatasetError::Empty(origin.to_owned()));
    }
    Ok(Dataset {
        train,
        val,
        hash: format!("{hash:016x}"),
    })
}

/// Writes a data set to `dir/train/*.csv` and `dir/val/*.csv`. Refuses to replace existing
/// files: nothing a user recorded is overwritten.
pub fn write_dir(dir: &Path, ds: &Dataset) -> Result<Vec<PathBuf>, DatasetError> {
    let mut written = Vec::new();
    let mut planned = Vec::new();
    for (split, trajs) in [("train", &ds.train), ("val", &ds.val)] {
        for t in trajs.iter() {
            let p = dir.join(split).join(&t.name);
            if p.exists() {
                return Err(DatasetError::Exists(p));
            }
            planned.push((p, t));
        }
    }
    for (p, t) in planned {
        if let Some(parent) = p.parent() {
            std::fs::create_dir_all(parent).map_err(|source| DatasetError::Io {
                path: parent.to_owned(),
                source,
            })?;
        }
        let io = |source| DatasetError::Io {
            path: p.clone(),
            source,
        };
        // `create_new`: a file that appeared since the check above is not replaced either.
        let file = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&p)
            .map_err(io)?;
        write_csv(std::io::BufWriter::new(file), t).map_err(|e| io(e.into()))?;
        written.push(p);
    }
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn traj(name: &str) -> Trajectory {
        Trajectory {
            name: name.into(),
            t: vec![0.0, 0.025],
            q: vec![vec![0.1, 0.2], vec![0.11, 0.21]],
            c: vec![0.0, 0.0],
            qdot: vec![vec![0.4, 0.4], vec![0.4, 0.4]],
            cdot: vec![0.0, 0.0],
        }
    }

    #[test]
    fn header_shape() {
        assert_eq!(header(2), "t,q0,q1,c,qd0,qd1,cd");
    }

    #[test]
    fn csv_round_trip() {
        let t = traj("a.csv");
        let mut bytes = Vec::new();
        write_csv(&mut bytes, &t).unwrap();
        // The fixed format: t with 4 decimals, the rest with 6.
        assert_eq!(
            String::from_utf8(bytes.clone()).unwrap(),
            "t,q0,q1,c,qd0,qd1,cd\n\
             0.0000,0.100000,0.200000,0.000000,0.400000,0.400000,0.000000\n\
             0.0250,0.110000,0.210000,0.000000,0.400000,0.400000,0.000000\n"
        );
        let back = parse_csv(std::str::from_utf8(&bytes).unwrap(), Path::new("a.csv")).unwrap();
        assert_eq!(back, t);
        // Blanks around fields and blank lines are fine; the line numbers count them.
        let e = parse_csv(
            "t, q0 ,c,qd0,cd\n\n 0,1,0,1,0\n\n0.1,x,0,1,0\n",
            Path::new("b.csv"),
        )
        .unwrap_err();
        assert_eq!(e.to_string(), "b.csv:5: column `q0` is `x`, not a number");
    }

    #[test]
    fn bad_rows_name_file_and_line() {
        let p = Path::new("d/x.csv");
        let e = parse_csv("t,q0,c,qd0,cd\n0,1,0,1,0\n0.1,abc,0,1,0\n", p).unwrap_err();
        assert_eq!(
            e.to_string(),
            "d/x.csv:3: column `q0` is `abc`, not a number"
        );
        let e = parse_csv("t,q0,c,qd0,cd\n0,1,0,1\n", p).unwrap_err();
        assert_eq!(e.to_string(), "d/x.csv:2: 4 fields, expected 5");
        let e = parse_csv("t,q0,c,qd0,cd\n0,NaN,0,1,0\n", p).unwrap_err();
        assert!(e.to_string().starts_with("d/x.csv:2: column `q0` is NaN"));
        let e = parse_csv("t,q0,c,qd0,cd\n0,1,0,1,0\n0,1,0,1,0\n", p).unwrap_err();
        assert!(e.to_string().contains("does not increase"));
        let e = parse_csv("time,a,b,c,d\n", p).unwrap_err();
        assert!(matches!(e, DatasetError::Header { .. }));
        let e = parse_csv("", p).unwrap_err();
        assert!(matches!(e, DatasetError::Header { .. }));
    }

    #[test]
    fn directory_round_trip_and_no_overwrite() {
        let dir = std::env::temp_dir().join(format!("scl-ds-test-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let ds = Dataset {
            train: vec![traj("a.csv"), traj("b.csv")],
            val: vec![traj("c.csv")],
            hash: String::new(),
        };
        write_dir(&dir, &ds).unwrap();
        let back = load_dir(&dir).unwrap();
        assert_eq!(back.train, ds.train);
        assert_eq!(back.val, ds.val);
        assert_eq!(back.n_train(), 4);
        assert_eq!(back.hash.len(), 16);
        assert!(matches!(write_dir(&dir, &ds), Err(DatasetError::Exists(_))));
        std::fs::remove_dir_all(&dir).unwrap();
        assert!(matches!(load_dir(&dir), Err(DatasetError::Io { .. })));
    }

    const TWO: &str = r#"[
      [ {"thetas": [0.1, 0.2], "velocity": [0.4, -0.4]},
        {"thetas": [0.11, 0.19], "velocity": [0.4, -0.4], "gripper": 0.5, "extra": "ignored"} ],
      [ {"thetas": [0.0, 0.0], "velocity": [0.0, 0.0], "gripper": null} ]
    ]"#;

    #[test]
    fn reads_the_authors_format() {
        let t = parse_json(TWO, Path::new("d/demo.json")).unwrap();
        assert_eq!(t.len(), 2);
        assert_eq!(t[0].name, "demo.json#0");
        assert_eq!(t[0].q, vec![vec![0.1, 0.2], vec![0.11, 0.19]]);
        assert_eq!(t[0].qdot[1], vec![0.4, -0.4]);
        assert_eq!(t[0].c, vec![0.0, 0.5]);
        assert_eq!(t[0].t, vec![0.0, crate::demos::DT]);
        assert!((t[0].cdot[0] - 0.5 / crate::demos::DT).abs() < 1e-9);
        assert_eq!(t[0].cdot[1], 0.0);
        assert_eq!(t[1].c, vec![0.0]);
        assert_eq!(t[1].n_joints(), 2);
    }

    #[test]
    fn errors_name_file_and_position() {
        let p = Path::new("d/demo.json");
        let e = |text: &str| parse_json(text, p).unwrap_err().to_string();
        assert!(
            e("[[{\"thetas\": [1,]}]]").starts_with("d/demo.json:1:"),
            "{}",
            e("[[{\"thetas\": [1,]}]]")
        );
        assert_eq!(
            e("{}"),
            "d/demo.json: top level: expected a list of trajectories"
        );
        assert_eq!(
            e("[[], 3]"),
            "d/demo.json: trajectory 1: expected a list of samples"
        );
        assert_eq!(
            e(r#"[[{"thetas": [1], "velocity": [0]}, {"thetas": [1]}]]"#),
            "d/demo.json: trajectory 0, sample 1: no `velocity`"
        );
        assert_eq!(
            e(r#"[[{"thetas": [1, "a"], "velocity": [0, 0]}]]"#),
            "d/demo.json: trajectory 0, sample 0: `thetas`[1] is `\"a\"`, not a finite number"
        );
        assert_eq!(
            e(r#"[[{"thetas": [1, 2], "velocity": [0]}]]"#),
            "d/demo.json: trajectory 0, sample 0: `thetas` has 2 values and `velocity` 1; expected the same number, at least one"
        );
        assert_eq!(
            e(r#"[[{"thetas": [1, 2], "velocity": [0, 0]}], [{"thetas": [1], "velocity": [0]}]]"#),
            "d/demo.json: trajectory 1, sample 0: 1 joints, but the samples before have 2"
        );
        assert_eq!(
            e(r#"[[{"thetas": [1], "velocity": [0], "gripper": 2}]]"#),
            "d/demo.json: trajectory 0, sample 0: `gripper` is `2`, not a number in [0, 1]"
        );
        assert_eq!(
            e(r#"[[3]]"#),
            "d/demo.json: trajectory 0, sample 0: expected an object with `thetas` and `velocity`"
        );
    }

    #[test]
    fn directories_and_single_files_load_json() {
        let dir = std::env::temp_dir().join(format!("scl-ds-json-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("train")).unwrap();
        std::fs::create_dir_all(dir.join("val")).unwrap();
        std::fs::write(dir.join("train/a.json"), TWO).unwrap();
        std::fs::write(
            dir.join("val/b.csv"),
            "t,q0,q1,c,qd0,qd1,cd\n0,0.1,0.2,0,0,0,0\n",
        )
        .unwrap();
        let ds = load(&dir).unwrap();
        assert_eq!(ds.train.len(), 2);
        assert_eq!(ds.n_train(), 3);
        assert_eq!(ds.val.len(), 1);
        let single = load(&dir.join("train/a.json")).unwrap();
        assert_eq!(single.train, ds.train);
        assert!(single.val.is_empty());
        assert_ne!(single.hash, ds.hash);
        // A JSON file whose joint count differs from the CSV's is refused by name.
        std::fs::write(
            dir.join("val/c.json"),
            r#"[[{"thetas": [1, 2, 3], "velocity": [0, 0, 0]}]]"#,
        )
        .unwrap();
        let e = load(&dir).unwrap_err().to_string();
        assert!(
            e.ends_with("c.json: has 3 joints, but earlier files have 2"),
            "{e}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
