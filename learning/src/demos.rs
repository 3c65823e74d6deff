//! Generated demonstrations.
//!
//! [`joint_reach`] makes a small data set that PCA fits almost exactly (the tests use such a
//! model for its known, state-independent directions): reaches from
//! the Gen3 lite's home pose to targets spread over two joint-space directions (a forward /
//! back reach of the shoulder, elbow and wrist, and a sideways turn of the base with the wrist
//! compensating) and back, with minimum-jerk speed profiles, varied durations and a little
//! velocity noise. The Cartesian tasks of the paper (table cleaning, pick and place, pouring,
//! the planar reach) are in [`crate::tasks`].

use kinematics::gen3_lite;

use crate::dataset::{Dataset, Trajectory};
use mapper::rng::Rng;

/// The file `scl demos` writes beside `train/` and `val/`: which task and arm the
/// demonstrations are of (JSON, [`DemosMeta`]), so that `scl dataset --format lerobot` names
/// their episodes' task.
pub const DEMOS_META: &str = "demos.json";

/// What [`DEMOS_META`] holds.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct DemosMeta {
    /// The task (`scl demos --task`: `pick-and-place`, `joint-reach`, ...).
    pub task: String,
    /// The arm's robot profile.
    pub robot: String,
    /// The random seed.
    pub seed: u64,
}

/// Why [`DEMOS_META`] could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum DemosMetaError {
    /// The file could not be read or written (writing refuses an existing file).
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: std::path::PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The file is not the JSON [`DemosMeta`] is.
    #[error("{path}: not a demonstration set's description: {source}")]
    Json {
        /// The file.
        path: std::path::PathBuf,
        /// The parser's error.
        source: serde_json::Error,
    },
}

impl DemosMeta {
    /// Reads `dir`'s [`DEMOS_META`]; `None` when it has none (a set made before, or by
    /// other means).
    pub fn read(dir: &std::path::Path) -> Result<Option<Self>, DemosMetaError> {
        let path = dir.join(DEMOS_META);
        let bytes = match std::fs::read(&path) {
            Ok(b) => b,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(source) => return Err(DemosMetaError::Io { path, source }),
        };
        serde_json::from_slice(&bytes)
            .map(Some)
            .map_err(|source| DemosMetaError::Json { path, source })
    }

    /// Writes it as `dir`'s [`DEMOS_META`], refusing to replace one.
    pub fn write(&self, dir: &std::path::Path) -> Result<std::path::PathBuf, DemosMetaError> {
        let path = dir.join(DEMOS_META);
        let text = serde_json::to_string_pretty(self).map_err(|source| DemosMetaError::Json {
            path: path.clone(),
            source,
        })?;
        let io = |source| DemosMetaError::Io {
            path: path.clone(),
            source,
        };
        std::fs::create_dir_all(dir).map_err(io)?;
        let mut f = std::fs::File::create_new(&path).map_err(io)?;
        std::io::Write::write_all(&mut f, text.as_bytes()).map_err(io)?;
        Ok(path)
    }
}

/// Control period of the demonstrations (s): the Gen3 lite's 40 Hz.
pub const DT: f64 = 1.0 / gen3_lite::CONTROL_RATE_HZ;

/// Forward / back reach direction (unnormalised joint-space offset at full extent).
pub const REACH_DIR: [f64; 6] = [0.0, 0.45, -0.55, 0.0, 0.35, 0.0];
/// Sideways turn direction.
pub const TURN_DIR: [f64; 6] = [0.9, 0.0, 0.0, 0.15, 0.0, -0.6];

/// Minimum-jerk position fraction and its time derivative at `tau` in `[0, 1]` for a move of
/// duration `dur` seconds.
fn min_jerk(tau: f64, dur: f64) -> (f64, f64) {
    let t2 = tau * tau;
    let s = t2 * tau * (10.0 - 15.0 * tau + 6.0 * t2);
    let ds = 30.0 * t2 * (1.0 - tau) * (1.0 - tau) / dur;
    (s, ds)
}

/// Appends a minimum-jerk move from `from` to `to` lasting `dur` seconds.
fn append_move(
    traj: &mut Trajectory,
    from: &[f64; 6],
    to: &[f64; 6],
    dur: f64,
    noise: f64,
    rng: &mut Rng,
) {
    let steps = (dur / DT).round() as usize;
    let t0 = traj.t.last().map_or(0.0, |t| t + DT);
    for k in 0..steps {
        let tau = k as f64 / steps as f64;
        let (s, ds) = min_jerk(tau, dur);
        traj.t.push(t0 + k as f64 * DT);
        traj.q
            .push((0..6).map(|j| from[j] + (to[j] - from[j]) * s).collect());
        traj.qdot.push(
            (0..6)
                .map(|j| (to[j] - from[j]) * ds + noise * rng.normal())
                .collect(),
        );
        traj.c.push(0.0);
        traj.cdot.push(0.0);
    }
}

/// The joint-space reaching set: `n_train` + `n_val` trajectories, each home -> target ->
/// home. Deterministic for a given seed.
pub fn joint_reach(n_train: usize, n_val: usize, seed: u64) -> Dataset {
    let mut rng = Rng::new(seed);
    let mut make = |i: usize, prefix: &str| {
        let mut traj = Trajectory {
            name: format!("{prefix}_{i:02}.csv"),
            ..Trajectory::default()
        };
        let home = gen3_lite::HOME;
        let (u, v) = (rng.range(-1.0, 1.0), rng.range(-1.0, 1.0));
        let mut target = home;
        for j in 0..6 {
            target[j] += u * REACH_DIR[j] + v * TURN_DIR[j] + 0.02 * rng.normal();
        }
        let out = rng.range(2.5, 4.5);
        let back = rng.range(2.5, 4.5);
        append_move(&mut traj, &home, &target, out, 0.005, &mut rng);
        append_move(&mut traj, &target, &home, back, 0.005, &mut rng);
        traj
    };
    let train = (0..n_train).map(|i| make(i, "train")).collect();
    let val = (0..n_val).map(|i| make(i, "val")).collect();
    Dataset {
        train,
        val,
        hash: String::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn deterministic_and_consistent() {
        let a = joint_reach(2, 1, 7);
        let b = joint_reach(2, 1, 7);
        assert_eq!(a, b);
        assert_ne!(a, joint_reach(2, 1, 8));
        let limits = gen3_lite::limits();
        for t in a.train.iter().chain(&a.val) {
            assert!(t.len() > 150);
            // Velocities integrate to the positions (up to the noise).
            let mut q = t.q[0].clone();
            for k in 0..t.len() - 1 {
                for j in 0..6 {
                    q[j] += t.qdot[k][j] * DT;
                }
            }
            let last = t.q.last().unwrap();
            for j in 0..6 {
                assert!(
                    (q[j] - last[j]).abs() < 0.05,
                    "joint {j}: {} vs {}",
                    q[j],
                    last[j]
                );
            }
            for row in &t.q {
                let mut r = row.clone();
                assert!(!limits.clamp_position(&mut r));
            }
        }
    }
}
