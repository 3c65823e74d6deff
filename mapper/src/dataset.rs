//! Demonstration data sets: trajectories of `(t, q, c, qdot, cdot)` tuples at 40 Hz.
//!
//! On disk a trajectory is one CSV file with the header `t,q0,…,q{m-1},c,qd0,…,qd{m-1},cd`
//! (seconds, rad, gripper state in `[0, 1]`, rad/s, 1/s). A data set is a directory with
//! `train/` and `val/` sub-directories of such files; a directory of CSV files without them is
//! all training data. Bad rows are reported by file and line.

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
    #[error("{0}: no trajectory CSV files found (expected train/*.csv and val/*.csv, or *.csv)")]
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

/// Parses one trajectory from CSV text; `path` names it in errors.
pub fn parse_csv(text: &str, path: &Path) -> Result<Trajectory, DatasetError> {
    let mut lines = text.lines();
    let head = lines.next().ok_or_else(|| DatasetError::Header {
        path: path.to_owned(),
        reason: "the file is empty".into(),
    })?;
    let cols: Vec<&str> = head.split(',').map(str::trim).collect();
    if cols.len() < 5 || !(cols.len() - 3).is_multiple_of(2) {
        return Err(DatasetError::Header {
            path: path.to_owned(),
            reason: format!("{} columns; expected t,q0..,c,qd0..,cd", cols.len()),
        });
    }
    let m = (cols.len() - 3) / 2;
    let expected = header(m);
    if cols.join(",") != expected {
        return Err(DatasetError::Header {
            path: path.to_owned(),
            reason: format!("expected `{expected}`, found `{head}`"),
        });
    }
    let mut traj = Trajectory {
        name: path
            .file_name()
            .map_or_else(String::new, |n| n.to_string_lossy().into_owned()),
        ..Trajectory::default()
    };
    let mut row = vec![0.0; cols.len()];
    for (i, line) in lines.enumerate() {
        let lineno = i + 2;
        if line.trim().is_empty() {
            continue;
        }
        let fields: Vec<&str> = line.split(',').collect();
        if fields.len() != cols.len() {
            return Err(DatasetError::Row {
                path: path.to_owned(),
                line: lineno,
                reason: format!("{} fields, expected {}", fields.len(), cols.len()),
            });
        }
        for (k, f) in fields.iter().enumerate() {
            let v: f64 = f.trim().parse().map_err(|_| DatasetError::Row {
                path: path.to_owned(),
                line: lineno,
                reason: format!("column `{}` is `{}`, not a number", cols[k], f.trim()),
            })?;
            if !v.is_finite() {
                return Err(DatasetError::Row {
                    path: path.to_owned(),
                    line: lineno,
                    reason: format!("column `{}` is {v}", cols[k]),
                });
            }
            row[k] = v;
        }
        if let Some(&last) = traj.t.last()
            && row[0] <= last
        {
            return Err(DatasetError::Row {
                path: path.to_owned(),
                line: lineno,
                reason: format!("time {} does not increase (previous {last})", row[0]),
            });
        }
        traj.t.push(row[0]);
        traj.q.push(row[1..=m].to_vec());
        traj.c.push(row[m + 1]);
        traj.qdot.push(row[m + 2..2 * m + 2].to_vec());
        traj.cdot.push(row[2 * m + 2]);
    }
    Ok(traj)
}

/// Renders a trajectory as CSV text.
pub fn to_csv(traj: &Trajectory) -> String {
    let m = traj.n_joints();
    let mut s = header(m);
    s.push('\n');
    for k in 0..traj.len() {
        let _ = write!(s, "{:.4}", traj.t[k]);
        for v in &traj.q[k] {
            let _ = write!(s, ",{v:.6}");
        }
        let _ = write!(s, ",{:.6}", traj.c[k]);
        for v in &traj.qdot[k] {
            let _ = write!(s, ",{v:.6}");
        }
        let _ = writeln!(s, ",{:.6}", traj.cdot[k]);
    }
    s
}

fn csv_files(dir: &Path) -> Result<Vec<PathBuf>, DatasetError> {
    let rd = std::fs::read_dir(dir).map_err(|source| DatasetError::Io {
        path: dir.to_owned(),
        source,
    })?;
    let mut files: Vec<PathBuf> = rd
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "csv"))
        .collect();
    files.sort();
    Ok(files)
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
            csv_files(&val_dir)?
        } else {
            Vec::new()
        };
        (csv_files(&train_dir)?, val)
    } else {
        (csv_files(dir)?, Vec::new())
    };
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
            let traj = parse_csv(&text, f)?;
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
        Ok(out)
    };
    let train = read(&train_files)?;
    let val = read(&val_files)?;
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
        std::fs::write(&p, to_csv(t)).map_err(|source| DatasetError::Io {
            path: p.clone(),
            source,
        })?;
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
        let back = parse_csv(&to_csv(&t), Path::new("a.csv")).unwrap();
        assert_eq!(back, t);
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
}
