//! `scl eval theorem`: the soft-reversibility inequality `|T(T(q, a), −a) − q| < |T(q, a) − q|`
//! (paper, Theorem 1; see [`crate::eval`]) over many sampled states and actions `|a| < 1`.
//!
//! For Lipschitz-bounded SCL without Gram-Schmidt the theorem applies and the inequality must
//! hold in every trial (a failure is a bug); for SCL with Gram-Schmidt and for CAE the
//! fraction of trials where it holds is measured. Two transitions: one control period,
//! `T(q, a) = q + Δ·s·map(q, a)`, and the paper's literal `T(q, a) = q + map(q, a)`.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::sync::Arc;

use crate::dataset;
use crate::eval::{self, AnyModel, Fraction};
use crate::tasks::Task;
use mapper::model::ModelKind;
use mapper::rng::Rng;

use super::{CommonArgs, ExperimentError, Run, Variant};
use crate::ToolError;

/// The paper's epochs for these models.
pub const DEFAULT_EPOCHS: usize = 200;

/// `scl eval theorem` options.
#[derive(clap::Args, Debug, Clone)]
pub struct TheoremArgs {
    /// Shared experiment options.
    #[command(flatten)]
    pub common: CommonArgs,
    /// Task whose demonstrations (on `--robot`'s arm) train the models and give the data
    /// states.
    #[arg(long, default_value = "pick-and-place")]
    pub task: String,
    /// States per set (from the data; uniform within the joint limits), one random action
    /// each.
    #[arg(long, default_value_t = 2000)]
    pub samples: usize,
    /// Seed of the states and actions (every model sees the same ones).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

/// The measured fraction of one group of models on one state set and transition.
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    /// Group: a variant name, or a file name for given models.
    pub group: String,
    /// The models' kind.
    pub kind: ModelKind,
    /// Whether the theorem's hypotheses hold for every model of the group.
    pub theorem_applies: bool,
    /// `data` or `uniform`.
    pub states: &'static str,
    /// `period` (`Δ·s`) or `paper` (`1`).
    pub transition: &'static str,
    /// Models in the group.
    pub models: usize,
    /// Trials summed over the models (`mean_ratio` averaged over models, `worst_ratio` the
    /// largest).
    pub fraction: Fraction,
    /// The smallest per-model fraction.
    pub min_model_fraction: f64,
}

/// A row of `models.csv`: one model on one state set and transition.
#[derive(serde::Serialize)]
struct ModelRow {
    group: String,
    file: String,
    #[serde(serialize_with = "crate::table::display")]
    kind: ModelKind,
    gram_schmidt: bool,
    #[serde(serialize_with = "crate::table::display_opt")]
    lipschitz_bound: Option<f64>,
    #[serde(serialize_with = "crate::table::display")]
    speed_scale: f64,
    states: &'static str,
    transition: &'static str,
    #[serde(serialize_with = "crate::table::display")]
    step: f64,
    theorem_applies: bool,
    trials: usize,
    held: usize,
    no_motion: usize,
    #[serde(serialize_with = "crate::table::display")]
    fraction: f64,
    #[serde(serialize_with = "crate::table::sci")]
    mean_ratio: f64,
    #[serde(serialize_with = "crate::table::sci")]
    worst_ratio: f64,
}

/// A row of `theorem.csv`: one group ([`Row`]).
#[derive(serde::Serialize)]
struct GroupRow<'a> {
    group: &'a str,
    #[serde(serialize_with = "crate::table::display")]
    kind: ModelKind,
    theorem_applies: bool,
    states: &'a str,
    transition: &'a str,
    models: usize,
    trials: usize,
    held: usize,
    no_motion: usize,
    #[serde(serialize_with = "crate::table::display")]
    fraction: f64,
    #[serde(serialize_with = "crate::table::display")]
    min_model_fraction: f64,
    #[serde(serialize_with = "crate::table::sci")]
    mean_ratio: f64,
    #[serde(serialize_with = "crate::table::sci")]
    worst_ratio: f64,
}

/// What the experiment measured.
#[derive(Debug, Clone)]
pub struct Outcome {
    /// One row per group, state set and transition.
    pub rows: Vec<Row>,
    /// Whether the inequality held in every trial where the theorem applies.
    pub theorem_holds: bool,
    /// The output directory.
    pub out: PathBuf,
}

struct Member {
    group: String,
    path: PathBuf,
    model: AnyModel,
}

/// Runs the experiment; writes `models.csv`, `theorem.csv`, `theorem.md` and `summary.md`.
pub fn run(args: &TheoremArgs, period_s: f64, command: &str) -> Result<Outcome, ToolError> {
    let run = Run::new("theorem", &args.common, DEFAULT_EPOCHS, command)?;
    if args.samples == 0 {
        return Err(ExperimentError::Option {
            option: "--samples",
            reason: "must be at least 1".into(),
        }
        .into());
    }
    let (members, trajs, data_note) = if args.common.models.is_empty() {
        trained_members(args, &run)?
    } else {
        given_members(args)?
    };
    let n_joints = common_joint_count(&members)?;
    let sets = state_sets(args, &trajs, n_joints);
    run.add_work((members.len() * sets.len() * 2) as u64);
    run.message("checking the inequality");
    let (model_rows, groups) = measure(args, period_s, &run, &members, &sets);
    run.finish();
    let rows = group_rows(groups);
    let theorem_holds = rows
        .iter()
        .filter(|r| r.theorem_applies)
        .all(|r| r.fraction.held == r.fraction.total);
    if !theorem_holds {
        tracing::error!(
            "the soft-reversibility inequality failed where the theorem applies: this is a bug"
        );
    }
    let table = write_tables(&run, &model_rows, &rows)?;
    let mut s = summary_head(args, period_s, &run, members.len(), &data_note, n_joints);
    push_verdict(&mut s, &rows, theorem_holds);
    s.push_str("## Fractions\n\n");
    s.push_str(&table);
    s.push_str("\nFiles: `theorem.csv` / `theorem.md` (per group), `models.csv` (per model).\n");
    run.write("summary.md", &s)?;
    Ok(Outcome {
        rows,
        theorem_holds,
        out: run.out.clone(),
    })
}

/// The models to check, the trajectories whose states they see and the data's name (empty
/// without data).
type Members = (Vec<Member>, Vec<dataset::Trajectory>, String);

/// Without `--models`: trains (or reuses) the variants on `--task`'s data per seed, whose
/// train and val trajectories give the data states.
fn trained_members(args: &TheoremArgs, run: &Run) -> Result<Members, ToolError> {
    let task = Task::from_name(&args.task)?;
    let (data_dir, ds) = run.data(task, true)?;
    let data_note = data_dir.display().to_string();
    let ds = Arc::new(ds);
    let variants = [Variant::SclNoGs, Variant::Scl, Variant::Cae];
    let jobs = super::seed_jobs(run, task, &variants, &data_dir, &ds);
    let plain: Vec<_> = jobs.iter().map(|(_, _, j)| j.clone()).collect();
    run.ensure_models(&plain)?;
    let mut members = Vec::new();
    for (v, _, job) in jobs {
        members.push(Member {
            group: v.name().to_owned(),
            model: super::load_model(&job.path)?,
            path: job.path,
        });
    }
    let trajs: Vec<_> = ds.train.iter().chain(&ds.val).cloned().collect();
    Ok((members, trajs, data_note))
}

/// With `--models`: the given files, each its own group; data states only when `--data`
/// names a data set.
fn given_members(args: &TheoremArgs) -> Result<Members, ToolError> {
    let mut data_note = String::new();
    let mut members = Vec::new();
    for (path, model) in super::given_models(&args.common.models)? {
        members.push(Member {
            group: path.file_name().map_or_else(
                || path.display().to_string(),
                |f| f.to_string_lossy().into_owned(),
            ),
            path,
            model,
        });
    }
    // Data states only when --data names a data set.
    let trajs = match &args.common.data {
        Some(d) => {
            data_note = d.display().to_string();
            let ds = dataset::load_dir(d)?;
            ds.train.iter().chain(&ds.val).cloned().collect()
        }
        None => Vec::new(),
    };
    Ok((members, trajs, data_note))
}

/// The joint count every model drives (that of the first); an error names a model that
/// drives another.
fn common_joint_count(members: &[Member]) -> Result<usize, ToolError> {
    let n_joints = members.first().map_or(0, |m| m.model.header().n_joints);
    if let Some(m) = members
        .iter()
        .find(|m| m.model.header().n_joints != n_joints)
    {
        return Err(ExperimentError::Model {
            path: m.path.clone(),
            reason: format!(
                "drives {} joints, the first model {n_joints}",
                m.model.header().n_joints
            ),
        }
        .into());
    }
    Ok(n_joints)
}

/// The state sets: drawn from the data (if any), and uniform within the joint limits.
fn state_sets(
    args: &TheoremArgs,
    trajs: &[dataset::Trajectory],
    n_joints: usize,
) -> Vec<(&'static str, eval::States)> {
    let mut rng = Rng::new(args.seed);
    let mut sets: Vec<(&'static str, eval::States)> = Vec::new();
    if !trajs.is_empty() {
        sets.push((
            "data",
            eval::states_from_data(trajs, args.samples, &mut rng),
        ));
    }
    // The arm's own limits (`--robot`; its continuous joints as its profile bounds them for
    // safety's margins); models of another joint count (given with --models) get a turn
    // either way of zero.
    let robot = args.common.robot;
    let (lo, hi) = if n_joints == robot.n_joints() {
        let l = robot.limits();
        (l.lower_rad.clone(), l.upper_rad.clone())
    } else {
        (
            vec![-std::f64::consts::PI; n_joints],
            vec![std::f64::consts::PI; n_joints],
        )
    };
    sets.push((
        "uniform",
        eval::states_uniform(&lo, &hi, args.samples, &mut rng),
    ));
    sets
}

/// The models' kind, whether the theorem applies to every one, and their fractions.
type Acc = (ModelKind, bool, Vec<Fraction>);

/// The per-group accumulators, by (group, state set, transition), in first-seen order.
type Groups = Vec<(String, &'static str, &'static str, Acc)>;

/// Checks the inequality for every model on every state set and both transitions; returns
/// one row per model, set and transition, and the groups' accumulators.
fn measure(
    args: &TheoremArgs,
    period_s: f64,
    run: &Run,
    members: &[Member],
    sets: &[(&'static str, eval::States)],
) -> (Vec<ModelRow>, Groups) {
    let mut model_rows = Vec::new();
    let mut groups: Groups = Vec::new();
    for m in members {
        let h = m.model.header();
        let gs = h.network.as_ref().is_some_and(|n| n.gram_schmidt);
        let s = h.speed_scale_rad_s;
        for (si, (set, states)) in sets.iter().enumerate() {
            for (ti, (transition, step)) in [("period", period_s * s), ("paper", 1.0)]
                .into_iter()
                .enumerate()
            {
                // Every model sees the same actions on the same states.
                let mut arng = Rng::new(
                    args.seed
                        .wrapping_mul(0x9E37_79B9_7F4A_7C15)
                        .wrapping_add((si * 2 + ti) as u64 + 1),
                );
                let mut map = m.model.map();
                let r = eval::reversibility(map.as_mut(), states, step, 1, 1.0, &mut arng);
                let f = r.one_step;
                let applies = h.kind == ModelKind::Scl
                    && !gs
                    && h.lipschitz_bound.is_some_and(|l| step * l <= 1.0);
                model_rows.push(ModelRow {
                    group: m.group.clone(),
                    file: super::display_rel(&m.path, &run.out),
                    kind: h.kind,
                    gram_schmidt: gs,
                    lipschitz_bound: h.lipschitz_bound,
                    speed_scale: s,
                    states: set,
                    transition,
                    step,
                    theorem_applies: applies,
                    trials: f.total,
                    held: f.held,
                    no_motion: f.no_motion,
                    fraction: f.value(),
                    mean_ratio: f.mean_ratio,
                    worst_ratio: f.worst_ratio,
                });
                match groups
                    .iter_mut()
                    .find(|(g, st, tr, _)| *g == m.group && st == set && *tr == transition)
                {
                    Some((_, _, _, acc)) => {
                        acc.1 &= applies;
                        acc.2.push(f);
                    }
                    None => {
                        groups.push((m.group.clone(), set, transition, (h.kind, applies, vec![f])))
                    }
                }
                run.done(1);
            }
        }
    }
    (model_rows, groups)
}

/// One [`Row`] per group: its models' trials summed.
fn group_rows(groups: Groups) -> Vec<Row> {
    groups
        .into_iter()
        .map(|(group, states, transition, (kind, applies, fs))| {
            let mut total = Fraction::default();
            for f in &fs {
                total.held += f.held;
                total.total += f.total;
                total.no_motion += f.no_motion;
                total.worst_ratio = total.worst_ratio.max(f.worst_ratio);
                total.mean_ratio += f.mean_ratio / fs.len() as f64;
            }
            Row {
                group,
                kind,
                theorem_applies: applies,
                states,
                transition,
                models: fs.len(),
                min_model_fraction: fs.iter().map(Fraction::value).fold(1.0, f64::min),
                fraction: total,
            }
        })
        .collect()
}

/// Writes `models.csv`, `theorem.csv` and `theorem.md`; returns the markdown table.
fn write_tables(run: &Run, model_rows: &[ModelRow], rows: &[Row]) -> Result<String, ToolError> {
    let models_csv = crate::table::to_csv(model_rows)
        .map_err(|e| super::write_error(&run.path("models.csv"), e))?;
    let csv = crate::table::to_csv(rows.iter().map(|r| GroupRow {
        group: &r.group,
        kind: r.kind,
        theorem_applies: r.theorem_applies,
        states: r.states,
        transition: r.transition,
        models: r.models,
        trials: r.fraction.total,
        held: r.fraction.held,
        no_motion: r.fraction.no_motion,
        fraction: r.fraction.value(),
        min_model_fraction: r.min_model_fraction,
        mean_ratio: r.fraction.mean_ratio,
        worst_ratio: r.fraction.worst_ratio,
    }))
    .map_err(|e| super::write_error(&run.path("theorem.csv"), e))?;
    let table = markdown(rows);
    run.write("models.csv", &models_csv)?;
    run.write("theorem.csv", &csv)?;
    run.write("theorem.md", &table)?;
    Ok(table)
}

/// The summary's title and settings: the models, the states, the actions, the transitions.
fn summary_head(
    args: &TheoremArgs,
    period_s: f64,
    run: &Run,
    n_members: usize,
    data_note: &str,
    n_joints: usize,
) -> String {
    let robot = args.common.robot;
    run.summary_head(
        "The soft-reversibility inequality, sampled",
        &[
            (
                "models",
                if args.common.models.is_empty() {
                    format!(
                        "scl-no-gs, scl, cae trained on {} per seed (DIR/models/<task>/<variant>/seed-<k>.safetensors)",
                        args.task
                    )
                } else {
                    format!("{n_members} given files")
                },
            ),
            (
                "data states",
                if data_note.is_empty() {
                    "none (no --data)".into()
                } else {
                    format!("{} drawn from {data_note} (train and val)", args.samples)
                },
            ),
            (
                "uniform states",
                if n_joints == robot.n_joints() {
                    format!(
                        "{} uniform within the {}'s joint limits, gripper uniform in [0, 1]",
                        args.samples,
                        robot.description()
                    )
                } else {
                    format!(
                        "{} uniform in [-pi, pi] per joint ({n_joints} joints, not the {}'s \
                         {}), gripper uniform in [0, 1]",
                        args.samples,
                        robot.description(),
                        robot.n_joints()
                    )
                },
            ),
            (
                "actions",
                "one per state, uniform direction, |a| uniform in [0, 1)".into(),
            ),
            (
                "transitions",
                format!(
                    "period: T(q, a) = q + {period_s} s * s * map(q, a); paper: T(q, a) = q + map(q, a)"
                ),
            ),
            ("seed", args.seed.to_string()),
        ],
    )
}

/// The summary's verdict: whether the inequality held wherever the theorem applies.
fn push_verdict(s: &mut String, rows: &[Row], theorem_holds: bool) {
    s.push_str("## Verdict\n\n");
    if rows.iter().any(|r| r.theorem_applies) {
        let n: usize = rows
            .iter()
            .filter(|r| r.theorem_applies)
            .map(|r| r.fraction.total)
            .sum();
        if theorem_holds {
            let _ = writeln!(
                s,
                "The inequality held in all {n} trials where the theorem applies (SCL without Gram-Schmidt, Lipschitz bound L with step * L <= 1), as it must.\n"
            );
        } else {
            let _ = writeln!(
                s,
                "**The inequality FAILED in some of the {n} trials where the theorem applies: this is a bug.**\n"
            );
        }
    } else {
        s.push_str("No model satisfies the theorem's hypotheses; only measured fractions.\n\n");
    }
}

fn markdown(rows: &[Row]) -> String {
    let mut s = String::from(
        "| models | theorem applies | states | transition | held | fraction | lowest model | mean ratio | worst ratio |\n|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        let f = &r.fraction;
        let _ = writeln!(
            s,
            "| {} ({} × {}) | {} | {} | {} | {} / {} | {:.2} % | {:.2} % | {:.3} | {:.3} |",
            r.group,
            r.models,
            r.kind,
            if r.theorem_applies { "yes" } else { "no" },
            r.states,
            r.transition,
            f.held,
            f.total,
            100.0 * f.value(),
            100.0 * r.min_model_fraction,
            f.mean_ratio,
            f.worst_ratio
        );
    }
    s.push_str("\nratio = |T(T(q, a), -a) - q| / |T(q, a) - q|; held = ratio < 1. Trials where the forward step did not move are not counted.\n");
    s
}
