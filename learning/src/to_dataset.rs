//! `scl dataset`: turns recordings into the training data format (`crate::dataset`: CSV
//! trajectories `t,q0..,c,qd0..,cd` in `train/` and `val/`), so a user records demonstrations
//! by teleoperating and trains on them.
//!
//! Only the recorded robot states are used. The tuple of tick `k` pairs the state at `k`
//! (`q`, gripper `c`) with the velocity the arm then executed, reported by state `k+1`
//! (`qdot_rad_s`), and the gripper rate `(c(k+1) - c(k)) / dt`: the operator's choice at that
//! state. A trajectory is a run of consecutive ticks; it ends where a state is missing, the
//! bridge missed a tick, stopped the arm (a controlled stop, a safety stop, shutdown) or the
//! joint count changes; rests of at least `--rest-s` are cut out; long runs are cut into
//! pieces of at most `--max-length-s`. Trajectories are spread evenly over train and val.

use std::path::{Path, PathBuf};

use crate::dataset::{Dataset, Trajectory};
use ipc_types::{RobotState, state_flags};

use crate::ToolError;
use crate::lerobot::run::RunSide;
use recording::{self, Event, Topic};

/// Joint-space speed (rad/s) and gripper rate (1/s) below which the arm counts as resting.
pub const REST_SPEED: f64 = 1e-3;

/// `scl dataset`'s arguments.
#[derive(Debug, Clone, clap::Args)]
pub struct DatasetArgs {
    /// Recordings to convert (from `scl record` or `scl up --record`; a recording cut by a
    /// crash is read up to its last complete chunk). With `--format lerobot` also
    /// demonstration sets (directories `scl demos` wrote), each trajectory an episode.
    #[arg(required = true, value_name = "FROM.mcap")]
    pub from: Vec<PathBuf>,
    /// Data set directory to write (gets train/ and val/); existing files are never
    /// overwritten.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Fraction of the trajectories that go to val/, spread evenly over the recording.
    #[arg(long, default_value_t = 0.25)]
    pub val_fraction: f64,
    /// Split trajectories where the arm rests at least this long (s) and leave the rest out;
    /// 0 keeps rests.
    #[arg(long, default_value_t = 1.0)]
    pub rest_s: f64,
    /// Cut trajectories longer than this (s) into equal pieces.
    #[arg(long, default_value_t = 20.0)]
    pub max_length_s: f64,
    /// Output format: `csv` (train/ and val/ trajectories for `scl train`) or `lerobot` (a
    /// LeRobot v3.0 dataset, one episode per recording, every tick a frame; docs/lerobot.md).
    #[arg(long, default_value = "csv", value_parser = ["csv", "lerobot"])]
    pub format: String,
    /// The task's text for `--format lerobot` (every episode's). Default: a study attempt's
    /// recording its study task's name and instructions, a demonstration set its task's,
    /// anything else `teleoperation`.
    #[arg(long)]
    pub task: Option<String>,
    /// The arm of the recordings for `--format lerobot`: a robot profile (names the joints,
    /// sets `robot_type` and fps).
    #[arg(long, value_name = "PROFILE", default_value_t = kinematics::RobotProfile::default_name().to_owned())]
    pub robot: String,
    /// What an episode of `--format lerobot` is for a recording: `recording` (one per
    /// recording, every tick a frame, nothing left out) or `trajectory` (one per trajectory
    /// as the CSV format cuts them with `--rest-s` and `--max-length-s`, the rests left
    /// out). A demonstration set's trajectories are episodes either way.
    #[arg(long, default_value = "recording", value_parser = ["recording", "trajectory"])]
    pub episodes: String,
}

/// How recordings are cut into trajectories.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Options {
    /// Fraction of trajectories for validation, in `[0, 1)`.
    pub val_fraction: f64,
    /// Shortest rest that splits a trajectory (s); 0 never splits at rests.
    pub rest_s: f64,
    /// Longest trajectory (s).
    pub max_length_s: f64,
}

impl Options {
    /// `scl dataset`'s defaults.
    pub const DEFAULT: Options = Options {
        val_fraction: 0.25,
        rest_s: 1.0,
        max_length_s: 20.0,
    };

    /// Checks the values, naming the flag of a bad one.
    pub fn validate(&self) -> Result<(), ToolError> {
        let bad = |flag: &str, v: f64, want: &str| {
            Err(ToolError::Graph(format!("{flag} {v}: must be {want}")))
        };
        if !(0.0..1.0).contains(&self.val_fraction) {
            return bad("--val-fraction", self.val_fraction, "in [0, 1)");
        }
        if !(self.rest_s.is_finite() && self.rest_s >= 0.0) {
            return bad("--rest-s", self.rest_s, "0 or more seconds");
        }
        if !(self.max_length_s.is_finite() && self.max_length_s > 0.0) {
            return bad(
                "--max-length-s",
                self.max_length_s,
                "a positive number of seconds",
            );
        }
        Ok(())
    }
}

/// What the cutting left out, in tuples.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LeftOut {
    /// Tuples in rests of at least `rest_s`.
    pub resting: usize,
    /// Tuples in fragments of a single tuple.
    pub fragments: usize,
}

/// One tuple before it goes into a trajectory.
#[derive(Debug, Clone)]
pub(crate) struct Tuple {
    /// The state's tick.
    pub(crate) tick: u64,
    /// The state's time stamp (ns).
    pub(crate) t_ns: u64,
    /// Joint angles (rad).
    pub(crate) q: Vec<f64>,
    /// Gripper state.
    pub(crate) c: f64,
    /// The velocity executed next (rad/s).
    pub(crate) qd: Vec<f64>,
    /// The gripper rate next (1/s).
    pub(crate) cd: f64,
}

impl Tuple {
    fn resting(&self) -> bool {
        self.qd.iter().map(|v| v * v).sum::<f64>().sqrt() < REST_SPEED && self.cd.abs() < REST_SPEED
    }
}

const NOT_A_DEMONSTRATION: u32 =
    state_flags::MISSED | state_flags::STOPPING | state_flags::SAFETY_STOP | state_flags::SHUTDOWN;

/// `states` sorted by tick, one per tick (any order in; duplicates dropped).
pub(crate) fn sorted_states(states: &[RobotState]) -> Vec<&RobotState> {
    let mut sorted: Vec<&RobotState> = states.iter().collect();
    // The bridge's shutdown state repeats its last tick: the running state comes first and
    // is the one kept.
    sorted.sort_by_key(|s| (s.tick, s.flags & state_flags::SHUTDOWN != 0));
    sorted.dedup_by_key(|s| s.tick);
    sorted
}

/// Whether state `a` with the motion reported by its successor `b` is a demonstration
/// tuple: consecutive ticks, neither a miss nor a stop nor shutdown, same arm, time moved.
pub(crate) fn is_demonstration(a: &RobotState, b: &RobotState) -> bool {
    b.tick == a.tick + 1
        && a.flags & state_flags::SHUTDOWN == 0
        && b.flags & NOT_A_DEMONSTRATION == 0
        && a.n_joints == b.n_joints
        && !a.q().is_empty()
        && b.t_ns > a.t_ns
}

/// The runs of valid consecutive tuples of `states` (any order; sorted by tick here).
fn runs(states: &[RobotState]) -> Vec<Vec<Tuple>> {
    let sorted = sorted_states(states);
    let mut out: Vec<Vec<Tuple>> = Vec::new();
    let mut cur: Vec<Tuple> = Vec::new();
    for w in sorted.windows(2) {
        let (a, b) = (w[0], w[1]);
        let dt_s = b.t_ns.saturating_sub(a.t_ns) as f64 / 1e9;
        if !is_demonstration(a, b) {
            if !cur.is_empty() {
                out.push(std::mem::take(&mut cur));
            }
            continue;
        }
        cur.push(Tuple {
            tick: a.tick,
            t_ns: a.t_ns,
            q: a.q().to_vec(),
            c: a.gripper,
            qd: b.qdot().to_vec(),
            cd: (b.gripper - a.gripper) / dt_s,
        });
    }
    if !cur.is_empty() {
        out.push(cur);
    }
    out
}

/// Cuts `run` at rests of at least `rest_s` (left out); returns the moving pieces.
fn cut_rests(run: Vec<Tuple>, rest_s: f64, left: &mut LeftOut) -> Vec<Vec<Tuple>> {
    if rest_s <= 0.0 {
        return vec![run];
    }
    let mut pieces = Vec::new();
    let mut cur: Vec<Tuple> = Vec::new();
    let mut rest: Vec<Tuple> = Vec::new();
    let mut close_rest = |cur: &mut Vec<Tuple>, rest: &mut Vec<Tuple>, next_t_ns: Option<u64>| {
        if rest.is_empty() {
            return;
        }
        let start = rest[0].t_ns;
        let end = next_t_ns.unwrap_or_else(|| {
            // A rest that ends the run lasts until one period after its last tuple.
            let n = rest.len() as u64;
            let last = rest[rest.len() - 1].t_ns;
            let period = if n > 1 { (last - start) / (n - 1) } else { 0 };
            last + period
        });
        if end.saturating_sub(start) as f64 / 1e9 >= rest_s {
            left.resting += rest.len();
            rest.clear();
            if !cur.is_empty() {
                pieces.push(std::mem::take(cur));
            }
        } else {
            cur.append(rest);
        }
    };
    for t in run {
        if t.resting() {
            rest.push(t);
        } else {
            close_rest(&mut cur, &mut rest, Some(t.t_ns));
            cur.push(t);
        }
    }
    close_rest(&mut cur, &mut rest, None);
    if !cur.is_empty() {
        pieces.push(cur);
    }
    pieces
}

/// Cuts `piece` into equal parts of at most `max_s`.
fn cut_length(piece: Vec<Tuple>, max_s: f64) -> Vec<Vec<Tuple>> {
    let (Some(first), Some(last)) = (piece.first(), piece.last()) else {
        return Vec::new();
    };
    let n = piece.len();
    // Duration including the last tuple's period.
    let span_s = (last.t_ns - first.t_ns) as f64 / 1e9 * n as f64 / (n.max(2) - 1) as f64;
    let parts = ((span_s / max_s).ceil() as usize).clamp(1, n);
    if parts == 1 {
        return vec![piece];
    }
    let mut out = Vec::with_capacity(parts);
    let mut it = piece.into_iter();
    for p in 0..parts {
        let take = (p + 1) * n / parts - p * n / parts;
        out.push(it.by_ref().take(take).collect());
    }
    out
}

/// The trajectories of one recording's robot states; `stem` names them
/// (`<stem>-<index>-tick<first tick>.csv`).
pub fn trajectories(states: &[RobotState], stem: &str, o: &Options) -> (Vec<Trajectory>, LeftOut) {
    cut(runs(states), stem, o)
}

/// Cuts runs of consecutive tuples into trajectories as [`trajectories`] does.
pub(crate) fn cut(runs: Vec<Vec<Tuple>>, stem: &str, o: &Options) -> (Vec<Trajectory>, LeftOut) {
    let (parts, left) = cut_with_starts(runs, stem, o);
    (parts.into_iter().map(|p| p.trajectory).collect(), left)
}

/// A trajectory [`cut`] made, with where it starts in its recording.
pub(crate) struct Part {
    /// The trajectory (its times from its first tuple).
    pub(crate) trajectory: Trajectory,
    /// Its first tuple's tick.
    pub(crate) first_tick: u64,
    /// Its first tuple's time stamp (ns).
    pub(crate) t0_ns: u64,
}

/// [`cut`], each trajectory with its first tick and time stamp.
pub(crate) fn cut_with_starts(
    runs: Vec<Vec<Tuple>>,
    stem: &str,
    o: &Options,
) -> (Vec<Part>, LeftOut) {
    let mut left = LeftOut::default();
    let mut out = Vec::new();
    for run in runs {
        for piece in cut_rests(run, o.rest_s, &mut left) {
            for part in cut_length(piece, o.max_length_s) {
                if part.len() < 2 {
                    left.fragments += part.len();
                    continue;
                }
                let (t0, first_tick) = (part[0].t_ns, part[0].tick);
                let mut traj = Trajectory {
                    name: format!("{stem}-{:03}-tick{}.csv", out.len(), part[0].tick),
                    ..Trajectory::default()
                };
                for t in part {
                    traj.t.push((t.t_ns - t0) as f64 / 1e9);
                    traj.q.push(t.q);
                    traj.c.push(t.c);
                    traj.qdot.push(t.qd);
                    traj.cdot.push(t.cd);
                }
                out.push(Part {
                    trajectory: traj,
                    first_tick,
                    t0_ns: t0,
                });
            }
        }
    }
    (out, left)
}

/// Spreads `trajs` over train and val: trajectory `i` goes to val when
/// `floor((i + 1) f) > floor(i f)`, so val gets `floor(n f)` of them, evenly spaced.
pub fn split(trajs: Vec<Trajectory>, val_fraction: f64) -> Dataset {
    let mut ds = Dataset::default();
    for (i, t) in trajs.into_iter().enumerate() {
        let to_val = ((i + 1) as f64 * val_fraction).floor() > (i as f64 * val_fraction).floor();
        if to_val {
            ds.val.push(t);
        } else {
            ds.train.push(t);
        }
    }
    ds
}

/// The robot states of recording `path`, and how far it could be read.
pub fn robot_states(path: &Path) -> Result<(Vec<RobotState>, recording::ReadSummary), ToolError> {
    read_states(path, |_| Ok(()))
}

/// [`robot_states`], giving every event to `other` as well, in the same pass.
fn read_states(
    path: &Path,
    mut other: impl FnMut(&Event<'_>) -> Result<(), recording::RecordError>,
) -> Result<(Vec<RobotState>, recording::ReadSummary), ToolError> {
    let mut states = Vec::new();
    let channel = Topic::RobotState.channel();
    let summary = recording::read_file(path, |ev| {
        if let Event::Message {
            channel: c,
            sequence,
            data,
            ..
        } = ev
            && c.topic == channel
        {
            states.push(recording::decode_robot_state(path, c, sequence, data)?);
            return Ok(());
        }
        other(&ev)
    })?;
    Ok((states, summary))
}

/// One recording's robot states, as both outputs of `scl dataset` read them.
struct RecordedStates {
    states: Vec<RobotState>,
    /// The file's name without its extension: the trajectories' or the episode's name.
    stem: String,
    /// Whether the file was read to its end (a cut one is read up to its last complete
    /// chunk, and said).
    complete: bool,
    /// The operator's side, the served model, the study task (gathered only for
    /// `--format lerobot`).
    side: RunSide,
}

impl RecordedStates {
    /// Reads recording `path`, with `side` also what else the LeRobot export takes from it,
    /// in the same pass; a cut file is said (and read as far as it goes), one without robot
    /// states is an error naming it.
    fn read(path: &Path, side: bool) -> Result<Self, ToolError> {
        let mut run = RunSide::default();
        let (states, summary) = if side {
            read_states(path, |ev| run.take(path, ev))?
        } else {
            robot_states(path)?
        };
        if !summary.complete {
            tracing::warn!(
                "{}: the recording is cut ({}); reading its {} readable messages (`scl record --recover` makes a finished copy)",
                path.display(),
                summary
                    .stopped
                    .as_ref()
                    .map_or_else(|| "no data-end record".to_owned(), ToString::to_string),
                summary.messages
            );
        }
        if states.is_empty() {
            return Err(ToolError::Graph(format!(
                "{}: no robot states in the recording (was /robot_state recorded?)",
                path.display()
            )));
        }
        let stem = path.file_stem().map_or_else(
            || "recording".to_owned(),
            |s| s.to_string_lossy().into_owned(),
        );
        Ok(Self {
            states,
            stem,
            complete: summary.complete,
            side: run,
        })
    }
}

/// What `scl dataset` did.
#[derive(Debug, Clone, PartialEq)]
pub struct ConvertReport {
    /// Files written.
    pub files: Vec<PathBuf>,
    /// Tuples in train/.
    pub n_train: usize,
    /// Tuples in val/.
    pub n_val: usize,
    /// Tuples left out.
    pub left_out: LeftOut,
    /// Recordings that were cut (read up to their last complete chunk).
    pub truncated: Vec<PathBuf>,
}

/// Converts recordings `from` into the data set directory `out`.
pub fn convert(from: &[PathBuf], out: &Path, o: &Options) -> Result<ConvertReport, ToolError> {
    o.validate()?;
    let mut all = Vec::new();
    let mut left = LeftOut::default();
    let mut truncated = Vec::new();
    for path in from {
        let r = RecordedStates::read(path, false)?;
        if !r.complete {
            truncated.push(path.clone());
        }
        let (trajs, l) = trajectories(&r.states, &r.stem, o);
        left.resting += l.resting;
        left.fragments += l.fragments;
        all.extend(trajs);
    }
    if all.is_empty() {
        return Err(ToolError::Graph(
            "the recordings hold no motion: every tuple was a rest, a stop or a fragment".into(),
        ));
    }
    let ds = split(all, o.val_fraction);
    if ds.val.is_empty() && o.val_fraction > 0.0 {
        tracing::warn!(
            "only {} trajectories: none for val/ (lower --max-length-s to cut more)",
            ds.train.len()
        );
    }
    let files = crate::dataset::write_dir(out, &ds)?;
    Ok(ConvertReport {
        files,
        n_train: ds.n_train(),
        n_val: ds.n_val(),
        left_out: left,
        truncated,
    })
}

/// The task text of an episode when `--task` is not given and neither a study attempt's
/// recording nor a demonstration set names one.
pub const DEFAULT_TASK: &str = "teleoperation";

/// `scl dataset --format lerobot`: each recording one episode, each trajectory of a
/// demonstration set (a directory `scl demos` wrote) one episode. `task` is every episode's
/// task text; without it a study attempt's recording gets its study task's (from its
/// `scl.trial` record, else its participant's `trials.csv`), a demonstration set its task's
/// ([`crate::lerobot::run::task_text`]), anything else [`DEFAULT_TASK`].
pub fn export_lerobot(
    from: &[PathBuf],
    out: &Path,
    robot: &str,
    task: Option<&str>,
) -> Result<crate::lerobot::export::ExportReport, ToolError> {
    export_lerobot_with(from, out, robot, task, Episodes::Recording)
}

/// What an episode of `scl dataset --format lerobot` is for a recording (`--episodes`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Episodes {
    /// One per recording, every recorded tick a frame, nothing left out (the default).
    Recording,
    /// One per trajectory as the CSV format cuts the recording ([`trajectories`] with these
    /// options: runs of demonstration tuples cut at rests and into pieces of at most the
    /// longest length), each frame a demonstration tuple; the rests and single-tuple
    /// fragments are left out, as there.
    Trajectory(Options),
}

/// [`export_lerobot`] with recordings cut into `episodes`.
pub fn export_lerobot_with(
    from: &[PathBuf],
    out: &Path,
    robot: &str,
    task: Option<&str>,
    episodes: Episodes,
) -> Result<crate::lerobot::export::ExportReport, ToolError> {
    use crate::lerobot::export::{Motion, Source};
    if let Episodes::Trajectory(o) = &episodes {
        o.validate()?;
    }
    let profile = kinematics::RobotProfile::by_name(robot)
        .map_err(|e| ToolError::Graph(format!("--robot: {e}")))?;
    let fps = profile.control_rate_hz().round() as u32;
    let mut sources = Vec::with_capacity(from.len());
    for path in from {
        if path.is_dir() {
            sources.extend(demonstration_sources(path, fps, task)?);
            continue;
        }
        let r = RecordedStates::read(path, true)?;
        let ticks: Vec<u64> = sorted_states(&r.states).iter().map(|s| s.tick).collect();
        let operator = ticks.iter().copied().zip(r.side.operator(&ticks)).collect();
        let task = match task {
            Some(t) => t.to_owned(),
            None => match r.side.study_task() {
                Some(t) => t,
                None => crate::lerobot::run::study_task_from_trials(path)?
                    .unwrap_or_else(|| DEFAULT_TASK.to_owned()),
            },
        };
        let model = r.side.served_model(&path.display().to_string());
        match episodes {
            Episodes::Recording => sources.push(Source {
                model,
                name: r.stem,
                task,
                motion: Motion::States(r.states),
                operator,
            }),
            Episodes::Trajectory(o) => {
                let flags: std::collections::BTreeMap<u64, u32> =
                    r.states.iter().map(|s| (s.tick, s.flags)).collect();
                let (parts, _) = cut_with_starts(runs(&r.states), &r.stem, &o);
                for p in parts {
                    let ticks = p.first_tick..p.first_tick + p.trajectory.len() as u64;
                    sources.push(Source {
                        model: model.clone(),
                        name: p.trajectory.name.trim_end_matches(".csv").to_owned(),
                        task: task.clone(),
                        operator: ticks
                            .clone()
                            .filter_map(|k| operator.get(&k).map(|o| (k, *o)))
                            .collect(),
                        motion: Motion::Tuples {
                            flags: ticks.map(|k| flags.get(&k).copied().unwrap_or(0)).collect(),
                            trajectory: p.trajectory,
                            first_tick: p.first_tick,
                            t0_ns: p.t0_ns,
                        },
                    });
                }
            }
        }
    }
    Ok(crate::lerobot::export::write(out, profile, fps, &sources)?)
}

/// The episodes of demonstration set `dir` (`scl demos` output: train/ then val/, one
/// episode per trajectory, named `<dir>/<split>/<file>`), their task text `task` or that of
/// the task its [`crate::demos::DEMOS_META`] file names. Refuses a trajectory whose time
/// steps are not the export's `fps`.
fn demonstration_sources(
    dir: &Path,
    fps: u32,
    task: Option<&str>,
) -> Result<Vec<crate::lerobot::export::Source>, ToolError> {
    use crate::lerobot::export::{Motion, Source};
    let ds = crate::dataset::load_dir(dir)?;
    let task = match task {
        Some(t) => t.to_owned(),
        None => crate::demos::DemosMeta::read(dir)?.map_or_else(
            || DEFAULT_TASK.to_owned(),
            |m| crate::lerobot::run::task_text(&m.task, &m.task),
        ),
    };
    let set = dir.file_name().map_or_else(
        || dir.display().to_string(),
        |s| s.to_string_lossy().into_owned(),
    );
    let period_s = 1.0 / f64::from(fps);
    let mut out = Vec::new();
    for (split, trajs) in [("train", ds.train), ("val", ds.val)] {
        for t in trajs {
            let name = format!("{set}/{split}/{}", t.name);
            if let Some(k) =
                t.t.windows(2)
                    .position(|w| ((w[1] - w[0]) - period_s).abs() > 1e-6)
            {
                return Err(ToolError::Graph(format!(
                    "{}: tuple {k} is followed {} s later, not at the robot profile's {fps} Hz ({period_s} s); LeRobot frames are evenly spaced",
                    dir.join(split).join(&t.name).display(),
                    t.t[k + 1] - t.t[k]
                )));
            }
            out.push(Source {
                name,
                task: task.clone(),
                motion: Motion::Tuples {
                    trajectory: t,
                    first_tick: 0,
                    t0_ns: 0,
                    flags: Vec::new(),
                },
                operator: std::collections::BTreeMap::new(),
                model: crate::lerobot::run::ServedModel::default(),
            });
        }
    }
    Ok(out)
}

/// `scl dataset`.
pub fn cli(args: &DatasetArgs) -> Result<std::process::ExitCode, ToolError> {
    if args.format == "lerobot" {
        let episodes = match args.episodes.as_str() {
            "trajectory" => Episodes::Trajectory(Options {
                val_fraction: Options::DEFAULT.val_fraction,
                rest_s: args.rest_s,
                max_length_s: args.max_length_s,
            }),
            _ => Episodes::Recording,
        };
        let r = export_lerobot_with(
            &args.from,
            &args.out,
            &args.robot,
            args.task.as_deref(),
            episodes,
        )?;
        eprintln!(
            "wrote a LeRobot v3.0 dataset of {} episodes, {} frames ({} flagged as no demonstration: missed, stopped, gaps, episode ends) to {}",
            r.episodes,
            r.frames,
            r.flagged,
            args.out.display()
        );
        return Ok(std::process::ExitCode::SUCCESS);
    }
    let o = Options {
        val_fraction: args.val_fraction,
        rest_s: args.rest_s,
        max_length_s: args.max_length_s,
    };
    let r = convert(&args.from, &args.out, &o)?;
    eprintln!(
        "wrote {} trajectories ({} train / {} validation tuples) from {} recording(s) to {}; left out {} resting and {} fragment tuples",
        r.files.len(),
        r.n_train,
        r.n_val,
        args.from.len(),
        args.out.display(),
        r.left_out.resting,
        r.left_out.fragments
    );
    Ok(std::process::ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;

    const DT_NS: u64 = 25_000_000;

    /// A state at `tick` moving joint 0 at `v` rad/s (the velocity that brought it there).
    fn st(tick: u64, q0: f64, v: f64) -> RobotState {
        let mut s = RobotState::at_rest(tick, 1_000_000_000 + tick * DT_NS, 2);
        s.applied_tick = tick.wrapping_sub(1);
        s.flags = state_flags::MOCK;
        s.q_rad[..2].copy_from_slice(&[q0, 0.5]);
        s.qdot_rad_s[0] = v;
        s.gripper = 0.01 * tick as f64;
        s
    }

    /// Ticks `from..to` moving at `v` from `q0`.
    fn moving(from: u64, to: u64, v: f64) -> Vec<RobotState> {
        (from..to)
            .map(|k| st(k, v * (k - from) as f64 * 0.025, v))
            .collect()
    }

    fn opts(rest_s: f64, max_length_s: f64) -> Options {
        Options {
            val_fraction: 0.25,
            rest_s,
            max_length_s,
        }
    }

    #[test]
    fn tuples_pair_a_state_with_the_velocity_that_followed() {
        let mut s = moving(0, 10, 0.2);
        s[5].qdot_rad_s[0] = 0.7; // the velocity executed from tick 4 to 5
        let (trajs, left) = trajectories(&s, "r", &opts(0.0, 100.0));
        assert_eq!(left, LeftOut::default());
        assert_eq!(trajs.len(), 1);
        let t = &trajs[0];
        assert_eq!(t.name, "r-000-tick0.csv");
        assert_eq!(t.len(), 9, "the last state has no successor");
        assert_eq!(t.qdot[4][0], 0.7);
        assert_eq!(t.q[4], s[4].q());
        assert!((t.t[3] - 0.075).abs() < 1e-12);
        assert!((t.cdot[0] - 0.4).abs() < 1e-9, "{}", t.cdot[0]);
    }

    #[test]
    fn gaps_stops_and_shutdown_end_a_trajectory() {
        let mut s = moving(0, 10, 0.2);
        s.extend(moving(12, 20, 0.2)); // ticks 10 and 11 lost
        s[15].flags |= state_flags::MISSED; // tick 17 reports a miss: tuple 16 is a stop
        s.last_mut().unwrap().flags |= state_flags::SHUTDOWN;
        // Out of order and with a duplicate, as two sources might give them.
        s.swap(0, 3);
        s.push(s[7]);
        let (trajs, left) = trajectories(&s, "r", &opts(0.0, 100.0));
        let ranges: Vec<(&str, usize)> = trajs.iter().map(|t| (t.name.as_str(), t.len())).collect();
        // 0..=8, then 12..=15 (16 -> 17 was a miss), then the lone tuple 17 (18 -> 19 is the
        // shutdown), left out as a fragment.
        assert_eq!(
            ranges,
            vec![("r-000-tick0.csv", 9), ("r-001-tick12.csv", 4)]
        );
        assert_eq!(left.fragments, 1);
    }

    #[test]
    fn long_rests_are_cut_out_and_short_ones_kept() {
        // 20 ticks moving, 60 at rest (1.5 s), 20 moving, 10 at rest (0.25 s), 20 moving.
        let mut s = moving(0, 20, 0.2);
        let q_end = s.last().unwrap().q_rad[0];
        s.extend((20..80).map(|k| RobotState {
            gripper: 0.0,
            ..st(k, q_end, 0.0)
        }));
        s.extend(moving(80, 100, 0.3));
        s.extend((100..110).map(|k| RobotState {
            gripper: 0.0,
            ..st(k, 0.0, 0.0)
        }));
        s.extend(moving(110, 131, 0.3));
        for x in &mut s {
            x.gripper = 0.0;
        }
        let (trajs, left) = trajectories(&s, "r", &opts(1.0, 100.0));
        assert_eq!(
            trajs.len(),
            2,
            "{:?}",
            trajs.iter().map(|t| &t.name).collect::<Vec<_>>()
        );
        assert_eq!(trajs[0].name, "r-000-tick0.csv");
        // Tuple 19 pairs state 19 with state 20's (zero) velocity: it rests; tuple 79 pairs
        // the resting state 79 with the motion that followed: it moves.
        assert_eq!(trajs[1].name, "r-001-tick79.csv");
        assert_eq!(trajs[0].len(), 19);
        assert_eq!(left.resting, 60);
        assert_eq!(trajs[1].len(), 51, "the short rest stays in");
        // Without rest splitting, one trajectory of every tuple.
        let (all, left) = trajectories(&s, "r", &opts(0.0, 100.0));
        assert_eq!(all.len(), 1);
        assert_eq!(all[0].len(), 130);
        assert_eq!(left.resting, 0);
    }

    #[test]
    fn long_runs_are_cut_into_equal_pieces() {
        let s = moving(0, 201, 0.1); // 200 tuples, 5 s
        let (trajs, _) = trajectories(&s, "r", &opts(0.0, 1.2));
        assert_eq!(trajs.len(), 5);
        assert!(trajs.iter().all(|t| t.len() == 40));
        assert_eq!(trajs[1].name, "r-001-tick40.csv");
        assert_eq!(trajs[1].t[0], 0.0, "each piece starts at t = 0");
    }

    #[test]
    fn val_gets_an_even_share() {
        let trajs: Vec<Trajectory> = (0..8)
            .map(|i| Trajectory {
                name: format!("{i}"),
                ..Trajectory::default()
            })
            .collect();
        let ds = split(trajs.clone(), 0.25);
        let names: Vec<&str> = ds.val.iter().map(|t| t.name.as_str()).collect();
        assert_eq!(names, vec!["3", "7"]);
        assert_eq!(ds.train.len(), 6);
        assert!(split(trajs.clone(), 0.0).val.is_empty());
        assert_eq!(split(trajs[..3].to_vec(), 0.25).val.len(), 0);
    }

    #[test]
    fn bad_options_name_the_flag() {
        let e = opts(1.0, 0.0).validate().unwrap_err().to_string();
        assert!(e.starts_with("--max-length-s 0"), "{e}");
        let e = Options {
            val_fraction: 1.0,
            ..opts(1.0, 1.0)
        }
        .validate()
        .unwrap_err()
        .to_string();
        assert!(e.starts_with("--val-fraction 1"), "{e}");
        assert!(opts(-1.0, 1.0).validate().is_err());
    }
}
