//! `scl eval greedy-user`: the paper's simulated greedy user on the 5-DOF planar reach
//! (Section "Simulation Experiments for Human Prior Configuration", Figure "reaching
//! metrics").
//!
//! Models: SCL with and without Gram-Schmidt and the CAE over the grid of Li et al.'s loss
//! terms (every combination of consistency with `gamma = 2`, proportionality with `alpha`
//! sampled in `[0.1, 1]`, reversibility; plain CAE included), `--seeds` each (the paper's 10),
//! trained for `--epochs` (the paper's 1000) on the planar reaches (inverse-Jacobian control to
//! targets along one line, `crate::tasks`), each keeping the weights of its epoch with the
//! lowest validation loss. Test trajectories: `--test-trajectories` (the paper's 100) further
//! planar reaches, generated with `--seed`.
//!
//! For every model and test trajectory, the greedy user (`crate::greedy`: the best of
//! `--candidates` actions `a ~ N(0, I)` per step, clamped to `|a| <= 1` unless `--no-clip`, by
//! the distance of the next joint state to the goal) moves from the trajectory's start to its
//! end state, then back to the start, for `--horizon` times the demonstration's length per
//! leg. Reported: the joint-space distance to the end state after the first leg and to the
//! start after the second, as violin plots (log scale), and the rank tests the paper ran:
//! Kruskal-Wallis across the groups, then Dunn's test between pairs (Holm-adjusted). The
//! paper's comparison is SCL, SCL without Gram-Schmidt and "CAE": here the grid's CAE
//! configuration with the lowest mean validation loss; the tests across the whole grid are in
//! `stats.csv` too.
//!
//! Resumable twice over: the models are cached (`DIR/models/planar-reach/<variant>/seed-<k>`),
//! and so is each model's evaluation (`DIR/greedy/<variant>/seed-<k>.csv`, keyed by the
//! evaluation's settings and the model file's hash), so an interrupted run loses at most the
//! models being evaluated.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use rayon::prelude::*;

use crate::dataset::Trajectory;
use crate::eval::AnyModel;
use crate::greedy::{GreedyConfig, GreedyUser};
use crate::tasks::{self, Task};
use mapper::model::ModelKind;
use mapper::rng::Rng;

use super::figure::{self, COLOURS, Figure};
use super::reversibility::Check;
use super::stats::{self, RankTests};
use super::{CommonArgs, ExperimentError, Run, Variant};
use crate::ToolError;
use scl_signals as signals;

/// The paper's epochs for this experiment.
pub const DEFAULT_EPOCHS: usize = 1000;

/// The paper's groups ([`Variant::GREEDY`]), as `--variants` names them.
pub const DEFAULT_VARIANTS: &str = "scl,scl-no-gs,cae,cae-li-cons,cae-li-prop,cae-li-rev,cae-li-cons-prop,cae-li-cons-rev,cae-li-prop-rev,cae-li-all";

/// Errors below this are drawn at it on the log scale (rad).
const FLOOR: f64 = 1e-6;

/// `scl eval greedy-user` options.
#[derive(clap::Args, Debug, Clone)]
pub struct GreedyUserArgs {
    /// Shared experiment options (--data: a planar-reach data set, DIR/planar-reach or
    /// DIR/{train,val}).
    #[command(flatten)]
    pub common: CommonArgs,
    /// Test trajectories (the paper's 100): planar reaches generated with --seed, apart from
    /// the training data.
    #[arg(long, default_value_t = 100)]
    pub test_trajectories: usize,
    /// Candidate actions a ~ N(0, I) per step (the paper's 4096).
    #[arg(long, default_value_t = crate::greedy::PAPER_CANDIDATES)]
    pub candidates: usize,
    /// Steps per leg, as a multiple of the test demonstration's length in ticks.
    #[arg(long, default_value_t = 2.0)]
    pub horizon: f64,
    /// Use each Gaussian action as drawn (the paper's formula) instead of clamping it to
    /// |a| <= 1 as the mapper does with a joystick sample.
    #[arg(long)]
    pub no_clip: bool,
    /// Seed of the test trajectories and of the candidate actions (the same candidates for
    /// every model on a trajectory).
    #[arg(long, default_value_t = 2)]
    pub seed: u64,
    /// Groups to train and compare, comma-separated (default: the paper's grid). Ignored with
    /// --models, whose files are grouped by their settings.
    #[arg(long, default_value = DEFAULT_VARIANTS)]
    pub variants: String,
}

/// Which distance.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Metric {
    /// `|q_T − q_end|` after the leg from the start to the end state.
    Forward,
    /// `|q_0 − q_back|` after the leg back to the start.
    Return,
}

impl Metric {
    /// Name in tables.
    pub fn name(self) -> &'static str {
        match self {
            Metric::Forward => "to-end",
            Metric::Return => "back-to-start",
        }
    }
}

/// What one observation of a test is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Unit {
    /// A model's mean error over the test trajectories (the paper's "average errors ... for
    /// each of the 10 evaluations").
    Model,
    /// One test trajectory of one model.
    Trajectory,
}

impl Unit {
    /// Name in tables.
    pub fn name(self) -> &'static str {
        match self {
            Unit::Model => "model-mean",
            Unit::Trajectory => "trajectory",
        }
    }
}

/// One test trajectory's outcome for one model (a row of the evaluation cache, whose
/// header is the field names: `trajectory,steps,start_distance,forward_error,return_error`).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TrajResult {
    /// Index of the test trajectory.
    pub trajectory: usize,
    /// Steps per leg.
    pub steps: usize,
    /// `|q_0 − q_end|` (rad).
    pub start_distance: f64,
    /// Distance to the end state after the first leg (rad).
    #[serde(rename = "forward_error")]
    pub forward: f64,
    /// Distance to the start after the second leg (rad).
    #[serde(rename = "return_error")]
    pub back: f64,
}

impl TrajResult {
    fn get(&self, m: Metric) -> f64 {
        match m {
            Metric::Forward => self.forward,
            Metric::Return => self.back,
        }
    }
}

/// One model's results.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelResult {
    /// Seed / index within its group.
    pub index: usize,
    /// The model file.
    pub path: PathBuf,
    /// Its validation loss (reconstruction MSE at the kept epoch, (rad/s)²).
    pub val_loss: Option<f64>,
    /// One row per test trajectory.
    pub rows: Vec<TrajResult>,
}

impl ModelResult {
    /// Mean error over the test trajectories.
    pub fn mean(&self, m: Metric) -> f64 {
        self.rows.iter().map(|r| r.get(m)).sum::<f64>() / self.rows.len().max(1) as f64
    }
}

/// One group (variant) of models.
#[derive(Debug, Clone, PartialEq)]
pub struct Group {
    /// The variant's cache name (or, for given files, their settings).
    pub name: String,
    /// Short label for the figure.
    pub label: String,
    /// Model kind.
    pub kind: ModelKind,
    /// SCL with Gram-Schmidt.
    pub gram_schmidt: bool,
    /// Its models.
    pub models: Vec<ModelResult>,
}

impl Group {
    /// Every trajectory's error.
    pub fn errors(&self, m: Metric) -> Vec<f64> {
        self.models
            .iter()
            .flat_map(|x| x.rows.iter().map(move |r| r.get(m)))
            .collect()
    }

    /// Each model's mean error.
    pub fn model_means(&self, m: Metric) -> Vec<f64> {
        self.models.iter().map(|x| x.mean(m)).collect()
    }

    /// The observations of `unit`.
    pub fn sample(&self, m: Metric, unit: Unit) -> Vec<f64> {
        match unit {
            Unit::Model => self.model_means(m),
            Unit::Trajectory => self.errors(m),
        }
    }

    /// Median over every trajectory of every model.
    pub fn median(&self, m: Metric) -> f64 {
        stats::median(&self.errors(m))
    }

    /// Mean validation loss of its models (NaN when none is known).
    pub fn mean_val_loss(&self) -> f64 {
        let v: Vec<f64> = self.models.iter().filter_map(|m| m.val_loss).collect();
        if v.is_empty() {
            f64::NAN
        } else {
            v.iter().sum::<f64>() / v.len() as f64
        }
    }
}

/// The rank tests of one family of groups, one metric and one unit.
#[derive(Debug, Clone, PartialEq)]
pub struct Family {
    /// `paper` (SCL, SCL without Gram-Schmidt, the best CAE configuration) or `grid` (every
    /// group).
    pub name: &'static str,
    /// The distance tested.
    pub metric: Metric,
    /// What one observation is.
    pub unit: Unit,
    /// Indices into [`Outcome::groups`].
    pub groups: Vec<usize>,
    /// Kruskal-Wallis and Dunn (`None` when there was nothing to test).
    pub tests: Option<RankTests>,
}

/// What the experiment measured.
#[derive(Debug, Clone)]
pub struct Outcome {
    /// Every group, in the order of `--variants`.
    pub groups: Vec<Group>,
    /// The CAE group with the lowest mean validation loss.
    pub best_cae: Option<usize>,
    /// The rank tests.
    pub families: Vec<Family>,
    /// The paper's statements and whether the measurement bears them out.
    pub checks: Vec<Check>,
    /// The output directory.
    pub out: PathBuf,
}

impl Outcome {
    /// The group called `name`.
    pub fn group(&self, name: &str) -> Option<&Group> {
        self.groups.iter().find(|g| g.name == name)
    }

    /// The tests of a family, metric and unit.
    pub fn family(&self, name: &str, metric: Metric, unit: Unit) -> Option<&Family> {
        self.families
            .iter()
            .find(|f| f.name == name && f.metric == metric && f.unit == unit)
    }
}

/// A short label of a variant for the figure.
fn label(v: Variant) -> &'static str {
    match v {
        Variant::Scl => "SCL",
        Variant::SclNoGs => "SCL no GS",
        Variant::Cae => "CAE",
        Variant::CaeLiCons => "CAE C",
        Variant::CaeLiProp => "CAE P",
        Variant::CaeLiRev => "CAE R",
        Variant::CaeLiConsProp => "CAE CP",
        Variant::CaeLiConsRev => "CAE CR",
        Variant::CaeLiPropRev => "CAE PR",
        Variant::CaeLiAll => "CAE CPR",
        other => other.name(),
    }
}

/// One model to evaluate.
struct Entry {
    group: usize,
    index: usize,
    path: PathBuf,
    model: AnyModel,
    /// Where its evaluation is cached (trained models only).
    cache: Option<PathBuf>,
}

/// Runs the experiment; writes `errors.csv`, `models.csv`, `groups.csv`, `stats.csv`,
/// `greedy-user.png` / `.svg` and `summary.md` into `--out`.
pub fn run(args: &GreedyUserArgs, command: &str) -> Result<Outcome, ToolError> {
    let run = Run::new("greedy-user", &args.common, DEFAULT_EPOCHS, command)?;
    let task = Task::PlanarReach;
    check_options(args)?;
    let chain = kinematics::planar5::get();
    let m = chain.n_joints();
    let (data_dir, ds) = run.data(task, true)?;
    let ds = Arc::new(ds);
    let (mut groups, entries) = if args.common.models.is_empty() {
        trained_models(&run, args, &data_dir, &ds)?
    } else {
        given_models(args)?
    };
    for e in &entries {
        let h = e.model.header();
        if h.n_joints != m || h.latent_dim != 2 {
            return Err(ExperimentError::Model {
                path: e.path.clone(),
                reason: format!(
                    "drives {} joints from a {}-D action; the planar arm needs {m} from 2",
                    h.n_joints, h.latent_dim
                ),
            }
            .into());
        }
    }
    run.message("generating the test trajectories");
    let test = tasks::generate(task, 0, args.test_trajectories, args.seed)?.val;
    let legs = test
        .iter()
        .map(|t| leg(t, args.horizon))
        .collect::<Option<Vec<_>>>()
        .ok_or_else(|| ExperimentError::Data {
            path: PathBuf::from("<generated test trajectories>"),
            reason: "a test trajectory is empty".into(),
        })?;
    let cfg = GreedyConfig {
        candidates: args.candidates,
        dt_s: crate::demos::DT,
        clip: !args.no_clip,
        limits: Some((chain.lower().to_vec(), chain.upper().to_vec())),
    };
    let results = evaluate(&run, args, &cfg, &entries, &legs)?;
    for (e, rows) in entries.iter().zip(results) {
        groups[e.group].models.push(ModelResult {
            index: e.index,
            path: e.path.clone(),
            val_loss: e.model.header().training.validation_loss,
            rows,
        });
    }
    run.finish();
    let outcome = analyse(groups, run.out.clone());
    write_outputs(&run, args, &data_dir, &ds, &cfg, &legs, &outcome)?;
    Ok(outcome)
}

/// The options' checks: test trajectories and candidates at least 1, a positive horizon.
fn check_options(args: &GreedyUserArgs) -> Result<(), ToolError> {
    if args.test_trajectories == 0 {
        return Err(ExperimentError::Option {
            option: "--test-trajectories",
            reason: "must be at least 1".into(),
        }
        .into());
    }
    if args.candidates == 0 {
        return Err(ExperimentError::Option {
            option: "--candidates",
            reason: "must be at least 1".into(),
        }
        .into());
    }
    if !(args.horizon.is_finite() && args.horizon > 0.0) {
        return Err(ExperimentError::Option {
            option: "--horizon",
            reason: format!("{}: expected a positive number", args.horizon),
        }
        .into());
    }
    Ok(())
}

/// The groups of models and the models to evaluate.
type Models = (Vec<Group>, Vec<Entry>);

/// Without `--models`: the variants of `--variants` per seed, trained (or reused) on the
/// planar reach's data, one group per variant, their evaluations cached.
fn trained_models(
    run: &Run,
    args: &GreedyUserArgs,
    data_dir: &Path,
    ds: &Arc<crate::dataset::Dataset>,
) -> Result<Models, ToolError> {
    let task = Task::PlanarReach;
    let mut groups: Vec<Group> = Vec::new();
    let mut entries: Vec<Entry> = Vec::new();
    let variants = parse_variants(&args.variants)?;
    let jobs = super::seed_jobs(run, task, &variants, data_dir, ds);
    let plain: Vec<_> = jobs.iter().map(|(_, _, j)| j.clone()).collect();
    run.ensure_models(&plain)?;
    for v in &variants {
        groups.push(Group {
            name: v.name().to_owned(),
            label: label(*v).to_owned(),
            kind: v.kind(),
            gram_schmidt: *v == Variant::Scl,
            models: Vec::new(),
        });
    }
    for (v, k, job) in jobs {
        let group = variants.iter().position(|x| *x == v).unwrap_or_default();
        entries.push(Entry {
            group,
            index: k,
            model: super::load_model(&job.path)?,
            cache: Some(
                run.out
                    .join("greedy")
                    .join(v.name())
                    .join(format!("seed-{k}.csv")),
            ),
            path: job.path,
        });
    }
    Ok((groups, entries))
}

/// With `--models`: the given files, grouped by their settings.
fn given_models(args: &GreedyUserArgs) -> Result<Models, ToolError> {
    let mut groups: Vec<Group> = Vec::new();
    let mut entries: Vec<Entry> = Vec::new();
    for (path, model) in super::given_models(&args.common.models)? {
        let h = model.header();
        let settings = super::describe_header(h);
        let group = match groups.iter().position(|g| g.name == settings) {
            Some(g) => g,
            None => {
                groups.push(Group {
                    name: settings.clone(),
                    label: settings.split(", ").take(3).collect::<Vec<_>>().join(" "),
                    kind: h.kind,
                    gram_schmidt: h.kind == ModelKind::Scl
                        && h.network.as_ref().is_some_and(|n| n.gram_schmidt),
                    models: Vec::new(),
                });
                groups.len() - 1
            }
        };
        let index = entries.iter().filter(|e| e.group == group).count();
        entries.push(Entry {
            group,
            index,
            path,
            model,
            cache: None,
        });
    }
    Ok((groups, entries))
}

/// The variants named in `--variants`.
fn parse_variants(list: &str) -> Result<Vec<Variant>, ExperimentError> {
    let mut out = Vec::new();
    for name in list.split(',').map(str::trim).filter(|s| !s.is_empty()) {
        let v = Variant::from_name(name)
            .filter(|v| *v != Variant::Pca)
            .ok_or_else(|| ExperimentError::Option {
                option: "--variants",
                reason: format!(
                    "unknown group `{name}`; available: {}",
                    Variant::GREEDY.map(Variant::name).join(", ")
                ),
            })?;
        if !out.contains(&v) {
            out.push(v);
        }
    }
    if out.is_empty() {
        return Err(ExperimentError::Option {
            option: "--variants",
            reason: "no group given".into(),
        });
    }
    Ok(out)
}

/// A test trajectory as the greedy user's task: start, end state (the state after the last
/// tuple, `q_last + qdot_last · DT`), gripper, steps per leg.
#[derive(Debug, Clone, PartialEq)]
struct LegSpec {
    start: Vec<f64>,
    end: Vec<f64>,
    c: f64,
    steps: usize,
}

fn leg(t: &Trajectory, horizon: f64) -> Option<LegSpec> {
    let start = t.q.first()?.clone();
    let last = t.q.last()?;
    let qdot = t.qdot.last()?;
    let end = last
        .iter()
        .zip(qdot)
        .map(|(q, v)| q + v * crate::demos::DT)
        .collect();
    Some(LegSpec {
        start,
        end,
        c: t.c.first().copied().unwrap_or(0.0),
        steps: ((t.len() as f64 * horizon).ceil() as usize).max(1),
    })
}

/// The key a cached evaluation must carry to be reused.
fn cache_key(args: &GreedyUserArgs, cfg: &GreedyConfig, model_bytes: &[u8]) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in model_bytes {
        h ^= u64::from(*b);
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    format!(
        "# greedy-user v1 candidates={} horizon={} clip={} seed={} test_trajectories={} model_fnv1a={h:016x}",
        cfg.candidates, args.horizon, cfg.clip, args.seed, args.test_trajectories
    )
}

/// A cached evaluation: its key line, then the rows (CSV, header included), all `n` of them
/// in trajectory order; `None` when anything differs (the evaluation is then redone).
fn read_cache(path: &Path, key: &str, n: usize) -> Option<Vec<TrajResult>> {
    let text = std::fs::read_to_string(path).ok()?;
    let (first, table) = text.split_once('\n')?;
    if first != key {
        return None;
    }
    let rows: Vec<TrajResult> = csv::Reader::from_reader(table.as_bytes())
        .deserialize()
        .collect::<Result<_, _>>()
        .ok()?;
    (rows.len() == n && rows.iter().enumerate().all(|(i, r)| r.trajectory == i)).then_some(rows)
}

fn write_cache(path: &Path, key: &str, rows: &[TrajResult]) -> Result<(), ExperimentError> {
    let table = crate::table::to_csv(rows).map_err(|e| super::write_error(path, e))?;
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|source| ExperimentError::Write {
            path: dir.to_owned(),
            source,
        })?;
    }
    std::fs::write(path, format!("{key}\n{table}")).map_err(|source| ExperimentError::Write {
        path: path.to_owned(),
        source,
    })
}

/// Runs the greedy user for every model and test trajectory (cached evaluations are read
/// back), on `run.threads` threads. Returns each entry's rows; each row depends only on its
/// model and trajectory, never on the schedule.
fn evaluate(
    run: &Run,
    args: &GreedyUserArgs,
    cfg: &GreedyConfig,
    entries: &[Entry],
    legs: &[LegSpec],
) -> Result<Vec<Vec<TrajResult>>, ToolError> {
    let n = legs.len();
    let mut keys = Vec::with_capacity(entries.len());
    let mut done: Vec<Option<Vec<TrajResult>>> = Vec::with_capacity(entries.len());
    for e in entries {
        let bytes = std::fs::read(&e.path).map_err(|source| ExperimentError::Corrupt {
            path: e.path.clone(),
            reason: source.to_string(),
        })?;
        let key = cache_key(args, cfg, &bytes);
        done.push(e.cache.as_deref().and_then(|p| read_cache(p, &key, n)));
        keys.push(key);
    }
    let todo: Vec<usize> = (0..entries.len()).filter(|i| done[*i].is_none()).collect();
    run.add_work((todo.len() * n) as u64);
    if todo.is_empty() {
        return Ok(done.into_iter().map(Option::unwrap_or_default).collect());
    }
    run.message(format!(
        "greedy user: {} models x {n} trajectories ({} cached)",
        todo.len(),
        entries.len() - todo.len()
    ));
    tracing::debug!(
        models = todo.len(),
        cached = entries.len() - todo.len(),
        trajectories = n,
        "greedy user"
    );
    // One model's trajectories, evaluated in parallel and collected in trajectory order; its
    // evaluation is cached as soon as it is complete.
    let evaluate_entry = |e: usize| -> Result<Vec<TrajResult>, ToolError> {
        let entry = &entries[e];
        let rows = (0..n)
            .into_par_iter()
            .map(|t| {
                if signals::stop_requested() {
                    return Err(ExperimentError::Interrupted.into());
                }
                let spec = &legs[t];
                let mut user = GreedyUser::new(&entry.model, cfg.clone()).map_err(|err| {
                    ExperimentError::Model {
                        path: entry.path.clone(),
                        reason: err.to_string(),
                    }
                })?;
                // The same candidates for every model on a trajectory, whatever the schedule.
                let mut rng = Rng::new(
                    args.seed
                        .wrapping_mul(0x9E37_79B9_7F4A_7C15)
                        .wrapping_add(t as u64 + 1),
                );
                let r = user
                    .forward_back(
                        &spec.start,
                        &spec.end,
                        spec.c,
                        spec.steps,
                        spec.steps,
                        &mut rng,
                    )
                    .map_err(|err| ExperimentError::Model {
                        path: entry.path.clone(),
                        reason: err.to_string(),
                    })?;
                run.done(1);
                Ok(TrajResult {
                    trajectory: t,
                    steps: spec.steps,
                    start_distance: r.start_distance,
                    forward: r.forward.error,
                    back: r.back.error,
                })
            })
            .collect::<Result<Vec<_>, ToolError>>()?;
        if let Some(path) = &entry.cache {
            write_cache(path, &keys[e], &rows)?;
        }
        Ok(rows)
    };
    let fresh = run.pool()?.install(|| {
        todo.par_iter()
            .map(|&e| evaluate_entry(e))
            .collect::<Result<Vec<_>, ToolError>>()
    })?;
    let mut fresh = fresh.into_iter();
    Ok(done
        .into_iter()
        .map(|cached| cached.unwrap_or_else(|| fresh.next().unwrap_or_default()))
        .collect())
}

/// Picks the paper's groups, runs the tests and checks the paper's statements.
fn analyse(groups: Vec<Group>, out: PathBuf) -> Outcome {
    let best_by = |pred: &dyn Fn(&Group) -> bool| -> Option<usize> {
        groups
            .iter()
            .enumerate()
            .filter(|(_, g)| pred(g) && !g.models.is_empty())
            .min_by(|a, b| {
                let (x, y) = (a.1.mean_val_loss(), b.1.mean_val_loss());
                // Groups without a validation loss come last.
                x.is_nan().cmp(&y.is_nan()).then(x.total_cmp(&y))
            })
            .map(|(i, _)| i)
    };
    let scl = best_by(&|g| g.kind == ModelKind::Scl && g.gram_schmidt);
    let no_gs = best_by(&|g| g.kind == ModelKind::Scl && !g.gram_schmidt);
    let best_cae = best_by(&|g| g.kind == ModelKind::Cae);
    let paper: Vec<usize> = [scl, no_gs, best_cae].into_iter().flatten().collect();
    let all: Vec<usize> = (0..groups.len())
        .filter(|i| !groups[*i].models.is_empty())
        .collect();
    let mut families = Vec::new();
    for (name, members) in [("paper", &paper), ("grid", &all)] {
        for metric in [Metric::Return, Metric::Forward] {
            for unit in [Unit::Model, Unit::Trajectory] {
                let samples: Vec<Vec<f64>> = members
                    .iter()
                    .map(|g| groups[*g].sample(metric, unit))
                    .collect();
                let refs: Vec<&[f64]> = samples.iter().map(Vec::as_slice).collect();
                families.push(Family {
                    name,
                    metric,
                    unit,
                    groups: members.clone(),
                    tests: stats::rank_tests(&refs),
                });
            }
        }
    }
    let mut o = Outcome {
        groups,
        best_cae,
        families,
        checks: Vec::new(),
        out,
    };
    o.checks = checks(&o, scl, no_gs);
    o
}

fn checks(o: &Outcome, scl: Option<usize>, no_gs: Option<usize>) -> Vec<Check> {
    let mut out = Vec::new();
    let (Some(cae), true) = (o.best_cae, scl.is_some() || no_gs.is_some()) else {
        return out;
    };
    let scls: Vec<usize> = [scl, no_gs].into_iter().flatten().collect();
    let med = |g: usize, m: Metric| o.groups[g].median(m);
    let names = |gs: &[usize]| -> String {
        gs.iter()
            .map(|g| format!("{} {:.3e}", o.groups[*g].name, med(*g, Metric::Return)))
            .collect::<Vec<_>>()
            .join(", ")
    };
    out.push(Check {
        statement: format!(
            "SCL returns closer to the start than CAE (median back-to-start error over every trajectory, below the best CAE configuration's, {})",
            o.groups[cae].name
        ),
        holds: scls.iter().all(|s| med(*s, Metric::Return) < med(cae, Metric::Return)),
        detail: format!("medians (rad): {}, {}", names(&scls), names(&[cae])),
    });
    let caes: Vec<usize> = (0..o.groups.len())
        .filter(|g| o.groups[*g].kind == ModelKind::Cae && !o.groups[*g].models.is_empty())
        .collect();
    let best_cae_return = caes
        .iter()
        .copied()
        .min_by(|a, b| med(*a, Metric::Return).total_cmp(&med(*b, Metric::Return)));
    if let Some(bc) = best_cae_return {
        out.push(Check {
            statement: "even with the Li et al. terms, SCL returns closer than every CAE configuration (median back-to-start error)".into(),
            holds: scls.iter().all(|s| med(*s, Metric::Return) < med(bc, Metric::Return)),
            detail: format!(
                "SCL: {}; closest CAE configuration: {}",
                names(&scls),
                names(&[bc])
            ),
        });
    }
    for unit in [Unit::Model, Unit::Trajectory] {
        out.extend(significance_check(o, cae, &scls, unit));
    }
    let best_fwd = caes
        .iter()
        .copied()
        .min_by(|a, b| med(*a, Metric::Forward).total_cmp(&med(*b, Metric::Forward)));
    if let (Some(bf), Some(&s)) = (best_fwd, scls.first()) {
        let ratio = med(bf, Metric::Forward) / med(s, Metric::Forward);
        out.push(Check {
            statement: "some CAE configuration reaches the end state comparably to SCL (its median to-end error within a factor 2 of SCL's)".into(),
            holds: ratio <= 2.0,
            detail: format!(
                "{}: {:.3e} rad, {}: {:.3e} rad (ratio {ratio:.2})",
                o.groups[bf].name,
                med(bf, Metric::Forward),
                o.groups[s].name,
                med(s, Metric::Forward)
            ),
        });
    }
    out
}

/// The check of a significant difference between the best CAE configuration (`cae`) and
/// the SCL versions (`scls`) in the back-to-start error, one observation per `unit`; `None`
/// without those tests.
fn significance_check(o: &Outcome, cae: usize, scls: &[usize], unit: Unit) -> Option<Check> {
    let f = o.family("paper", Metric::Return, unit)?;
    let t = f.tests.as_ref()?;
    let pos = |g: usize| f.groups.iter().position(|x| *x == g);
    let pairs: Vec<&stats::DunnPair> = t
        .dunn
        .iter()
        .filter(|d| {
            let (a, b) = (f.groups[d.a], f.groups[d.b]);
            (a == cae && scls.contains(&b)) || (b == cae && scls.contains(&a))
        })
        .collect();
    let holds = t.kruskal.p < 0.05
        && pairs.len() == scls.len()
        && pairs.iter().all(|d| d.p_holm < 0.05)
        && pos(cae).is_some();
    Some(Check {
        statement: format!(
            "significant difference between CAE and both SCL versions in the back-to-start error (Kruskal-Wallis p < 0.05, then Dunn, Holm-adjusted p < 0.05; one observation per {})",
            if unit == Unit::Model {
                "model: its mean over the test trajectories"
            } else {
                "trajectory and model"
            }
        ),
        holds,
        detail: format!(
            "H = {:.3}, p = {:.3e}; {}",
            t.kruskal.h,
            t.kruskal.p,
            pairs
                .iter()
                .map(|d| format!(
                    "{} vs {}: z = {:.2}, p_holm = {:.3e}",
                    o.groups[f.groups[d.a]].name, o.groups[f.groups[d.b]].name, d.z, d.p_holm
                ))
                .collect::<Vec<_>>()
                .join("; ")
        ),
    })
}

/// A row of `errors.csv`: one test trajectory of one model.
#[derive(serde::Serialize)]
struct ErrorRow<'a> {
    group: &'a str,
    model: usize,
    file: String,
    trajectory: usize,
    steps: usize,
    #[serde(serialize_with = "crate::table::sci")]
    start_distance: f64,
    #[serde(serialize_with = "crate::table::sci")]
    forward_error: f64,
    #[serde(serialize_with = "crate::table::sci")]
    return_error: f64,
}

/// A row of `models.csv`: one model.
#[derive(serde::Serialize)]
struct ModelRow<'a> {
    group: &'a str,
    model: usize,
    file: String,
    #[serde(serialize_with = "crate::table::sci_opt")]
    val_loss: Option<f64>,
    #[serde(serialize_with = "crate::table::sci")]
    mean_forward_error: f64,
    #[serde(serialize_with = "crate::table::sci")]
    mean_return_error: f64,
    #[serde(serialize_with = "crate::table::sci")]
    median_forward_error: f64,
    #[serde(serialize_with = "crate::table::sci")]
    median_return_error: f64,
}

/// A row of `groups.csv`: one group, over every trajectory of its models.
#[derive(serde::Serialize)]
struct GroupRow<'a> {
    group: &'a str,
    label: &'a str,
    #[serde(serialize_with = "crate::table::display")]
    kind: ModelKind,
    models: usize,
    trajectories: usize,
    #[serde(serialize_with = "crate::table::sci")]
    mean_val_loss: f64,
    best_cae: bool,
    #[serde(serialize_with = "crate::table::sci")]
    median_forward_error: f64,
    #[serde(serialize_with = "crate::table::sci")]
    q25_forward_error: f64,
    #[serde(serialize_with = "crate::table::sci")]
    q75_forward_error: f64,
    #[serde(serialize_with = "crate::table::sci")]
    median_return_error: f64,
    #[serde(serialize_with = "crate::table::sci")]
    q25_return_error: f64,
    #[serde(serialize_with = "crate::table::sci")]
    q75_return_error: f64,
}

/// The header of `stats.csv` (written alone when nothing could be tested).
const STATS_HEADER: &str =
    "family,metric,unit,test,group_a,group_b,n,statistic,df,p,p_holm,p_bonferroni";

/// A row of `stats.csv`: a Kruskal-Wallis test (`n`, `df`) or a Dunn pair (`group_a`,
/// `group_b`, the adjusted p-values); `statistic` is H or z.
#[derive(serde::Serialize)]
struct StatsRow<'a> {
    family: &'a str,
    metric: &'a str,
    unit: &'a str,
    test: &'a str,
    group_a: Option<&'a str>,
    group_b: Option<&'a str>,
    n: Option<usize>,
    #[serde(serialize_with = "crate::table::sci")]
    statistic: f64,
    df: Option<usize>,
    #[serde(serialize_with = "crate::table::sci")]
    p: f64,
    #[serde(serialize_with = "crate::table::sci_opt")]
    p_holm: Option<f64>,
    #[serde(serialize_with = "crate::table::sci_opt")]
    p_bonferroni: Option<f64>,
}

#[allow(clippy::too_many_arguments)]
fn write_outputs(
    run: &Run,
    args: &GreedyUserArgs,
    data_dir: &Path,
    ds: &crate::dataset::Dataset,
    cfg: &GreedyConfig,
    legs: &[LegSpec],
    o: &Outcome,
) -> Result<(), ToolError> {
    let csv = |name: &str, text: Result<String, csv::Error>| -> Result<PathBuf, ExperimentError> {
        run.write(
            name,
            &text.map_err(|e| super::write_error(&run.path(name), e))?,
        )
    };
    let mut errors = Vec::new();
    let mut models = Vec::new();
    for g in &o.groups {
        for m in &g.models {
            let file = super::display_rel(&m.path, &run.out);
            for r in &m.rows {
                errors.push(ErrorRow {
                    group: &g.name,
                    model: m.index,
                    file: file.clone(),
                    trajectory: r.trajectory,
                    steps: r.steps,
                    start_distance: r.start_distance,
                    forward_error: r.forward,
                    return_error: r.back,
                });
            }
            let fw: Vec<f64> = m.rows.iter().map(|r| r.forward).collect();
            let bk: Vec<f64> = m.rows.iter().map(|r| r.back).collect();
            models.push(ModelRow {
                group: &g.name,
                model: m.index,
                file,
                val_loss: m.val_loss,
                mean_forward_error: m.mean(Metric::Forward),
                mean_return_error: m.mean(Metric::Return),
                median_forward_error: stats::median(&fw),
                median_return_error: stats::median(&bk),
            });
        }
    }
    csv("errors.csv", crate::table::to_csv(&errors))?;
    csv("models.csv", crate::table::to_csv(&models))?;
    let groups = o.groups.iter().enumerate().map(|(i, g)| {
        let f = g.errors(Metric::Forward);
        let b = g.errors(Metric::Return);
        GroupRow {
            group: &g.name,
            label: &g.label,
            kind: g.kind,
            models: g.models.len(),
            trajectories: f.len(),
            mean_val_loss: g.mean_val_loss(),
            best_cae: o.best_cae == Some(i),
            median_forward_error: stats::median(&f),
            q25_forward_error: stats::quantile(&f, 0.25),
            q75_forward_error: stats::quantile(&f, 0.75),
            median_return_error: stats::median(&b),
            q25_return_error: stats::quantile(&b, 0.25),
            q75_return_error: stats::quantile(&b, 0.75),
        }
    });
    csv("groups.csv", crate::table::to_csv(groups))?;
    let tests = stats_rows(o);
    csv(
        "stats.csv",
        crate::table::to_csv_or_header(STATS_HEADER, &tests),
    )?;
    figure::write(
        &Violins {
            groups: &o.groups,
            best_cae: o.best_cae,
        },
        &run.path("greedy-user"),
        (1400, 960),
    )?;
    let summary = summary(run, args, data_dir, ds, cfg, legs, o);
    run.write("summary.md", &summary)?;
    Ok(())
}

/// `stats.csv`'s rows: per family of tests, Kruskal-Wallis, then Dunn's pairs.
fn stats_rows(o: &Outcome) -> Vec<StatsRow<'_>> {
    let mut tests = Vec::new();
    for f in &o.families {
        let Some(t) = &f.tests else { continue };
        let row = |test, statistic, p| StatsRow {
            family: f.name,
            metric: f.metric.name(),
            unit: f.unit.name(),
            test,
            group_a: None,
            group_b: None,
            n: None,
            statistic,
            df: None,
            p,
            p_holm: None,
            p_bonferroni: None,
        };
        tests.push(StatsRow {
            n: Some(t.kruskal.n),
            df: Some(t.kruskal.df),
            ..row("kruskal-wallis", t.kruskal.h, t.kruskal.p)
        });
        for d in &t.dunn {
            tests.push(StatsRow {
                group_a: Some(&o.groups[f.groups[d.a]].name),
                group_b: Some(&o.groups[f.groups[d.b]].name),
                p_holm: Some(d.p_holm),
                p_bonferroni: Some(d.p_bonferroni),
                ..row("dunn", d.z, d.p)
            });
        }
    }
    tests
}

#[allow(clippy::too_many_arguments)]
fn summary(
    run: &Run,
    args: &GreedyUserArgs,
    data_dir: &Path,
    ds: &crate::dataset::Dataset,
    cfg: &GreedyConfig,
    legs: &[LegSpec],
    o: &Outcome,
) -> String {
    let steps: Vec<usize> = legs.iter().map(|l| l.steps).collect();
    let given = !args.common.models.is_empty();
    let mut s = run.summary_head(
        "The simulated greedy user on the 5-DOF planar reach",
        &[
            (
                "data (training)",
                format!(
                    "{} ({} train / {} val tuples, hash {})",
                    data_dir.display(),
                    ds.n_train(),
                    ds.n_val(),
                    ds.hash
                ),
            ),
            (
                "test trajectories",
                format!(
                    "{} planar reaches generated with seed {} (start {:?}, targets along the line x = {} m, y in [{}, {}] m)",
                    legs.len(),
                    args.seed,
                    tasks::PLANAR_START,
                    tasks::PLANAR_LINE_FROM[0],
                    tasks::PLANAR_LINE_FROM[1],
                    tasks::PLANAR_LINE_TO[1]
                ),
            ),
            (
                "greedy user",
                format!(
                    "best of {} actions a ~ N(0, I) per step{}, by |q* - (q + dt s map(q, a))| with dt = {} s and the model's speed scale s; joint limits [-2.6, 2.6] rad clamp the state",
                    cfg.candidates,
                    if cfg.clip {
                        ", each clamped to |a| <= 1 as the mapper clamps a joystick sample"
                    } else {
                        " (as drawn, not clamped)"
                    },
                    cfg.dt_s
                ),
            ),
            (
                "legs",
                format!(
                    "start -> end state, then back to the start, {} x the demonstration's length each ({} to {} steps)",
                    args.horizon,
                    steps.iter().min().copied().unwrap_or(0),
                    steps.iter().max().copied().unwrap_or(0)
                ),
            ),
            (
                "models",
                if given {
                    "given files, grouped by their settings".into()
                } else {
                    "trained per seed (DIR/models/planar-reach/<variant>/seed-<k>.safetensors), each keeping its epoch with the lowest validation loss; evaluations cached in DIR/greedy/<variant>/seed-<k>.csv".into()
                },
            ),
        ],
    );
    push_checks(&mut s, o);
    push_errors(&mut s, o);
    push_rank_tests(&mut s, o);
    s.push_str("\nz > 0: the first group ranks higher (larger errors). Files: `errors.csv` (every trajectory of every model), `models.csv` (per model, with its validation loss), `groups.csv`, `stats.csv` (Kruskal-Wallis and Dunn's pairs with Holm and Bonferroni adjustments, for the paper's three groups and for the whole grid, per model mean and per trajectory), `greedy-user.png` / `.svg` (violins of log10 error over every trajectory, Gaussian kernel density; black bar: median; dots: the models' means; the best CAE configuration by validation loss is marked *).\n");
    s
}

/// The summary's table of the paper's statements: each, whether it holds, the numbers.
fn push_checks(s: &mut String, o: &Outcome) {
    s.push_str("## The paper's statements\n\n| statement | holds | numbers |\n|---|---|---|\n");
    for c in &o.checks {
        let _ = writeln!(
            s,
            "| {} | {} | {} |",
            c.statement.replace('|', "\\|"),
            if c.holds { "yes" } else { "**no**" },
            c.detail.replace('|', "\\|")
        );
    }
}

/// The summary's error table: each group's median and quartiles, to the end and back.
fn push_errors(s: &mut String, o: &Outcome) {
    s.push_str("\n## Errors (rad; median [25 %, 75 %] over every test trajectory of every model)\n\n| group | models | mean val. MSE (rad/s)² | to the end state | back to the start |\n|---|---|---|---|---|\n");
    for (i, g) in o.groups.iter().enumerate() {
        let f = g.errors(Metric::Forward);
        let b = g.errors(Metric::Return);
        let _ = writeln!(
            s,
            "| {}{} | {} | {:.3e} | {:.3e} [{:.2e}, {:.2e}] | {:.3e} [{:.2e}, {:.2e}] |",
            g.name.replace('|', "\\|"),
            if o.best_cae == Some(i) {
                " (best CAE by val. loss)"
            } else {
                ""
            },
            g.models.len(),
            g.mean_val_loss(),
            stats::median(&f),
            stats::quantile(&f, 0.25),
            stats::quantile(&f, 0.75),
            stats::median(&b),
            stats::quantile(&b, 0.25),
            stats::quantile(&b, 0.75),
        );
    }
}

/// The summary's rank tests: Kruskal-Wallis and Dunn's pairs for the paper's three groups,
/// then Kruskal-Wallis across the whole grid.
fn push_rank_tests(s: &mut String, o: &Outcome) {
    s.push_str("\n## Rank tests: SCL, SCL without Gram-Schmidt, the best CAE configuration\n\n");
    for f in o.families.iter().filter(|f| f.name == "paper") {
        let _ = write!(
            s,
            "**{}, one observation per {}**: ",
            f.metric.name(),
            if f.unit == Unit::Model {
                "model (its mean error)"
            } else {
                "trajectory"
            }
        );
        match &f.tests {
            None => s.push_str("nothing to test.\n\n"),
            Some(t) => {
                let _ = writeln!(
                    s,
                    "Kruskal-Wallis H = {:.3} (df {}, n = {}), p = {:.3e}.\n\n| pair | z | p | p (Holm) |\n|---|---|---|---|",
                    t.kruskal.h, t.kruskal.df, t.kruskal.n, t.kruskal.p
                );
                for d in &t.dunn {
                    let _ = writeln!(
                        s,
                        "| {} vs {} | {:.3} | {:.3e} | {:.3e} |",
                        o.groups[f.groups[d.a]].name,
                        o.groups[f.groups[d.b]].name,
                        d.z,
                        d.p,
                        d.p_holm
                    );
                }
                s.push('\n');
            }
        }
    }
    s.push_str("Across the whole grid (every group; Dunn's pairs in `stats.csv`):\n\n| metric | unit | H | df | p |\n|---|---|---|---|---|\n");
    for f in o.families.iter().filter(|f| f.name == "grid") {
        if let Some(t) = &f.tests {
            let _ = writeln!(
                s,
                "| {} | {} | {:.3} | {} | {:.3e} |",
                f.metric.name(),
                f.unit.name(),
                t.kruskal.h,
                t.kruskal.df,
                t.kruskal.p
            );
        }
    }
}

/// Violin outlines: `(log10 error, half width in [0, 1])` from a Gaussian kernel density of
/// the log errors (Silverman's bandwidth), cut one bandwidth beyond the data.
fn violin(values: &[f64]) -> Vec<(f64, f64)> {
    let logs: Vec<f64> = values
        .iter()
        .filter(|v| v.is_finite())
        .map(|v| v.max(FLOOR).log10())
        .collect();
    let n = logs.len();
    if n == 0 {
        return Vec::new();
    }
    let mean = logs.iter().sum::<f64>() / n as f64;
    let sd = (logs.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n.max(2) as f64).sqrt();
    let iqr = stats::quantile(&logs, 0.75) - stats::quantile(&logs, 0.25);
    let spread = if iqr > 0.0 { sd.min(iqr / 1.34) } else { sd };
    let bw = (0.9 * spread * (n as f64).powf(-0.2)).max(0.02);
    let lo = logs.iter().copied().fold(f64::INFINITY, f64::min) - bw;
    let hi = logs.iter().copied().fold(f64::NEG_INFINITY, f64::max) + bw;
    let pts = 96;
    let mut out: Vec<(f64, f64)> = (0..=pts)
        .map(|i| {
            let y = lo + (hi - lo) * i as f64 / pts as f64;
            let d: f64 = logs
                .iter()
                .map(|v| (-0.5 * ((y - v) / bw).powi(2)).exp())
                .sum();
            (y, d)
        })
        .collect();
    let top = out.iter().map(|p| p.1).fold(0.0, f64::max);
    if top > 0.0 {
        out.iter_mut().for_each(|p| p.1 /= top);
    }
    out
}

struct Violins<'a> {
    groups: &'a [Group],
    best_cae: Option<usize>,
}

impl Violins<'_> {
    fn colour(&self, i: usize) -> plotters::style::RGBColor {
        let g = &self.groups[i];
        match (g.kind, g.gram_schmidt) {
            (ModelKind::Scl, true) => COLOURS[0],
            (ModelKind::Scl, false) => COLOURS[2],
            _ if self.best_cae == Some(i) => COLOURS[1],
            _ => COLOURS[3],
        }
    }
}

impl Figure for Violins<'_> {
    fn draw<DB: plotters::prelude::DrawingBackend>(
        &self,
        root: &plotters::prelude::DrawingArea<DB, plotters::coord::Shift>,
        text: bool,
    ) -> Result<(), String> {
        use plotters::prelude::*;
        let panels = root.split_evenly((2, 1));
        let n = self.groups.len().max(1);
        let names: Vec<String> = self
            .groups
            .iter()
            .enumerate()
            .map(|(i, g)| {
                if self.best_cae == Some(i) {
                    format!("{}*", g.label)
                } else {
                    g.label.clone()
                }
            })
            .collect();
        let sides = [
            (
                Metric::Forward,
                "distance to the end state |q_T - q_end| (rad), log scale",
            ),
            (
                Metric::Return,
                "distance back to the start |q_back - q_0| (rad), log scale",
            ),
        ];
        for (area, (metric, caption)) in panels.iter().zip(sides) {
            let all: Vec<f64> = self
                .groups
                .iter()
                .flat_map(|g| g.errors(metric))
                .filter(|v| v.is_finite())
                .map(|v| v.max(FLOOR))
                .collect();
            let lo = all.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = all.iter().copied().fold(0.0, f64::max);
            let (lo, hi) = if lo <= hi {
                (lo / 3.0, hi * 3.0)
            } else {
                (1e-4, 1.0)
            };
            let mut b = ChartBuilder::on(area);
            b.margin(14);
            if text {
                b.caption(caption, ("sans-serif", 18))
                    .x_label_area_size(34)
                    .y_label_area_size(64);
            }
            let mut chart = b
                .build_cartesian_2d(-0.5f64..n as f64 - 0.5, (lo..hi).log_scale())
                .map_err(figure::err)?;
            let labels = names.clone();
            let fmt = move |x: &f64| {
                let i = x.round();
                if (x - i).abs() < 1e-6 && i >= 0.0 {
                    labels.get(i as usize).cloned().unwrap_or_default()
                } else {
                    String::new()
                }
            };
            let mut mesh = chart.configure_mesh();
            mesh.disable_x_mesh();
            if text {
                mesh.x_labels(2 * n + 1)
                    .x_label_formatter(&fmt)
                    .y_desc("rad")
                    .label_style(("sans-serif", 14));
            } else {
                mesh.x_labels(0).y_labels(0);
            }
            mesh.draw().map_err(figure::err)?;
            for (i, g) in self.groups.iter().enumerate() {
                let colour = self.colour(i);
                let x = i as f64;
                let shape = violin(&g.errors(metric));
                if shape.is_empty() {
                    continue;
                }
                let mut outline: Vec<(f64, f64)> = shape
                    .iter()
                    .map(|(y, w)| (x + 0.42 * w, 10f64.powf(*y)))
                    .collect();
                outline.extend(
                    shape
                        .iter()
                        .rev()
                        .map(|(y, w)| (x - 0.42 * w, 10f64.powf(*y))),
                );
                chart
                    .draw_series(std::iter::once(Polygon::new(
                        outline.clone(),
                        colour.mix(0.45).filled(),
                    )))
                    .map_err(figure::err)?;
                outline.push(outline[0]);
                chart
                    .draw_series(std::iter::once(PathElement::new(
                        outline,
                        colour.stroke_width(1),
                    )))
                    .map_err(figure::err)?;
                let med = g.median(metric).max(FLOOR);
                chart
                    .draw_series(std::iter::once(PathElement::new(
                        vec![(x - 0.2, med), (x + 0.2, med)],
                        BLACK.stroke_width(3),
                    )))
                    .map_err(figure::err)?;
                chart
                    .draw_series(
                        g.model_means(metric)
                            .into_iter()
                            .filter(|v| v.is_finite())
                            .map(|v| Circle::new((x, v.max(FLOOR)), 3, BLACK.filled())),
                    )
                    .map_err(figure::err)?;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_groups_are_the_papers_grid() {
        assert_eq!(
            parse_variants(DEFAULT_VARIANTS).unwrap(),
            Variant::GREEDY.to_vec()
        );
        let e = parse_variants("scl,pca").unwrap_err().to_string();
        assert!(e.contains("unknown group `pca`"), "{e}");
        assert!(parse_variants(" , ").is_err());
    }

    #[test]
    fn violin_outline_peaks_at_one_and_spans_the_data() {
        let v = violin(&[0.01, 0.011, 0.012, 0.1]);
        let top = v.iter().map(|p| p.1).fold(0.0, f64::max);
        assert!((top - 1.0).abs() < 1e-12);
        assert!(v.first().unwrap().0 < -2.0 && v.last().unwrap().0 > -1.0);
        // The densest part is near 0.011.
        let peak = v.iter().max_by(|a, b| a.1.total_cmp(&b.1)).unwrap().0;
        assert!((peak - 0.011f64.log10()).abs() < 0.2, "{peak}");
        assert!(violin(&[]).is_empty());
        assert!(!violin(&[0.0, 0.0]).is_empty());
    }

    #[test]
    fn cached_evaluations_round_trip_and_need_their_key() {
        let dir = std::env::temp_dir().join(format!("scl-greedy-cache-{}", std::process::id()));
        let path = dir.join("g/seed-0.csv");
        let rows = vec![
            TrajResult {
                trajectory: 0,
                steps: 10,
                start_distance: 1.5,
                forward: 0.01,
                back: 1.0 / 3.0,
            },
            TrajResult {
                trajectory: 1,
                steps: 12,
                start_distance: 1.25,
                forward: 2e-7,
                back: 0.5,
            },
        ];
        write_cache(&path, "# k", &rows).unwrap();
        assert_eq!(read_cache(&path, "# k", 2).unwrap(), rows);
        assert!(read_cache(&path, "# other", 2).is_none());
        assert!(read_cache(&path, "# k", 3).is_none());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
