//! `scl eval reversibility`: the paper's proportionality and soft-reversibility figure on the
//! mock Gen3 lite (or the mock arm of `--robot`, on that arm's demonstrations).
//!
//! For every model (10 per kind: SCL, CAE, PCA), start state (10, from the validation
//! demonstrations) and `alpha` on a grid in `[0, 1]`, with `theta` uniform: the mock arm
//! starts at the state, the served command `qdot = s · map(o, a)` with `a = alpha [cos theta,
//! sin theta]` runs for 1 s at the graph's rate (40 Hz), the arm stops, `−a` runs for 1 s.
//! Measured: `|q_fwd − q_0|` and `|q_rev − q_0|`. Expected (the paper): SCL and PCA forward
//! distances overlap, PCA returns exactly, SCL nearly, CAE does not.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::sync::Arc;

use crate::eval::{self, AnyModel};
use crate::rollout::{self, Plant};
use crate::tasks::Task;
use hw_bridge::mock::{MockArm, MockConfig};
use mapper::model::ModelKind;
use mapper::rng::Rng;

use super::figure::{self, COLOURS, Figure};
use super::{CommonArgs, ExperimentError, Run, Variant};
use crate::ToolError;

/// The paper's epochs for these models.
pub const DEFAULT_EPOCHS: usize = 200;

/// `scl eval reversibility` options.
#[derive(clap::Args, Debug, Clone)]
pub struct ReversibilityArgs {
    /// Shared experiment options.
    #[command(flatten)]
    pub common: CommonArgs,
    /// Task (table-cleaning, pick-and-place, pouring) whose validation demonstrations give the start states (and whose
    /// training demonstrations train the models).
    #[arg(long, default_value = "pick-and-place")]
    pub task: String,
    /// Start states per model (the paper's 10).
    #[arg(long, default_value_t = 10)]
    pub states: usize,
    /// Values of alpha, evenly spaced over [0, 1].
    #[arg(long, default_value_t = 11)]
    pub alphas: usize,
    /// Seed of the start states and action directions.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

/// One model of the experiment.
#[derive(Debug)]
pub struct ModelRef {
    /// Its group (`scl`, `cae`, `pca`).
    pub kind: ModelKind,
    /// Index within the group.
    pub index: usize,
    /// The file.
    pub path: PathBuf,
    /// The model.
    pub model: AnyModel,
}

/// Mean and standard deviation of both distances of one kind at one alpha.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Point {
    /// Alpha.
    pub alpha: f64,
    /// Runs.
    pub n: usize,
    /// Mean `|q_fwd − q_0|` (rad).
    pub forward_mean: f64,
    /// Its standard deviation.
    pub forward_std: f64,
    /// Mean `|q_rev − q_0|` (rad).
    pub reverse_mean: f64,
    /// Its standard deviation.
    pub reverse_std: f64,
    /// Largest `|q_rev − q_0|`.
    pub reverse_max: f64,
    /// Runs in which a joint reached its limit (the mock clamps the motion there).
    pub limited: usize,
    /// Largest `|q_rev − q_0|` over the runs that stayed inside the limits (0 if none did).
    pub reverse_max_inside: f64,
}

/// A row of `runs.csv`: one rollout.
#[derive(serde::Serialize)]
struct RunRow {
    #[serde(serialize_with = "crate::table::display")]
    kind: ModelKind,
    model: usize,
    file: String,
    state: usize,
    #[serde(serialize_with = "crate::table::display")]
    alpha: f64,
    #[serde(serialize_with = "crate::table::fixed::<9, _>")]
    theta: f64,
    #[serde(serialize_with = "crate::table::sci")]
    forward_rad: f64,
    #[serde(serialize_with = "crate::table::sci")]
    reverse_rad: f64,
    at_limit: bool,
}

/// A row of `curves.csv`: one point of the figure.
#[derive(serde::Serialize)]
struct CurveRow {
    #[serde(serialize_with = "crate::table::display")]
    kind: ModelKind,
    #[serde(serialize_with = "crate::table::display")]
    alpha: f64,
    n: usize,
    #[serde(serialize_with = "crate::table::sci")]
    forward_mean_rad: f64,
    #[serde(serialize_with = "crate::table::sci")]
    forward_std_rad: f64,
    #[serde(serialize_with = "crate::table::sci")]
    reverse_mean_rad: f64,
    #[serde(serialize_with = "crate::table::sci")]
    reverse_std_rad: f64,
    #[serde(serialize_with = "crate::table::sci")]
    reverse_max_rad: f64,
    at_limit_runs: usize,
    #[serde(serialize_with = "crate::table::sci")]
    reverse_max_inside_rad: f64,
}

/// One expected-shape statement and whether the measurement bears it out.
#[derive(Debug, Clone, PartialEq)]
pub struct Check {
    /// The statement.
    pub statement: String,
    /// Whether it holds.
    pub holds: bool,
    /// The numbers behind the verdict.
    pub detail: String,
}

/// What the experiment measured.
#[derive(Debug, Clone)]
pub struct Outcome {
    /// Curves per kind, in the order SCL, CAE, PCA (kinds without models are absent).
    pub curves: Vec<(ModelKind, Vec<Point>)>,
    /// The expected-shape verdicts.
    pub checks: Vec<Check>,
    /// The output directory.
    pub out: PathBuf,
}

impl Outcome {
    /// The curve of `kind`.
    pub fn curve(&self, kind: ModelKind) -> Option<&[Point]> {
        self.curves
            .iter()
            .find(|(k, _)| *k == kind)
            .map(|(_, c)| c.as_slice())
    }
}

/// The robot's mock arm as a rollout plant.
struct MockPlant {
    arm: MockArm,
    q: Vec<f64>,
    c: f64,
    limited: bool,
}

impl MockPlant {
    fn at(robot: &kinematics::RobotProfile, q0: &[f64], c0: f64) -> Result<Self, ToolError> {
        let mut arm = MockArm::for_robot(robot, MockConfig::for_robot(robot))
            .map_err(|e| ToolError::Graph(format!("mock arm: {e}")))?;
        arm.resume(q0, c0);
        let mut q = q0.to_vec();
        arm.limits().clamp_position(&mut q);
        Ok(Self {
            arm,
            q,
            c: c0.clamp(0.0, 1.0),
            limited: false,
        })
    }
}

impl Plant for MockPlant {
    fn q(&self) -> &[f64] {
        &self.q
    }
    fn gripper(&self) -> f64 {
        self.c
    }
    fn step(&mut self, qdot: &[f64], dt: f64) {
        self.arm.set_command(qdot, 0.0);
        let r = self.arm.step(dt);
        let n = self.q.len();
        self.q.copy_from_slice(&r.q_rad[..n]);
        self.c = r.gripper;
        self.limited = r.at_limit;
    }
    fn halt(&mut self) {
        self.arm.halt();
    }
    fn at_limit(&self) -> bool {
        self.limited
    }
}

const KINDS: [(ModelKind, Variant); 3] = [
    (ModelKind::Scl, Variant::Scl),
    (ModelKind::Cae, Variant::Cae),
    (ModelKind::Pca, Variant::Pca),
];

/// Runs the experiment: trains (or reuses) the models, rolls out every run on the mock arm,
/// writes `runs.csv`, `curves.csv`, `reversibility.png` / `.svg` and `summary.md` into
/// `--out`. `period_s` is the control period (the graph's 40 Hz).
pub fn run(args: &ReversibilityArgs, period_s: f64, command: &str) -> Result<Outcome, ToolError> {
    let run = Run::new("reversibility", &args.common, DEFAULT_EPOCHS, command)?;
    let task = Task::from_name(&args.task)?;
    check_options(args, task)?;
    let robot = run.robot;
    let (data_dir, ds) = run.data(task, true)?;
    let ds = Arc::new(ds);
    let models = if args.common.models.is_empty() {
        trained_models(&run, task, &data_dir, &ds)?
    } else {
        given_models(args)?
    };
    check_models(robot, &models)?;
    let mut rng = Rng::new(args.seed);
    let states = eval::states_from_data(&ds.val, args.states, &mut rng);
    let alphas = rollout::alpha_grid(args.alphas);
    let max_index = models.iter().map(|m| m.index + 1).max().unwrap_or(0);
    // One direction per (model index, state, alpha), the same for every kind.
    let thetas: Vec<f64> = (0..max_index * states.len() * alphas.len())
        .map(|_| rng.uniform() * std::f64::consts::TAU)
        .collect();
    let ticks = (1.0 / period_s).round().max(1.0) as usize;
    run.add_work((models.len() * states.len()) as u64);
    run.message("rollouts on the mock arm");
    let grid = Grid {
        states: &states,
        alphas: &alphas,
        thetas: &thetas,
        ticks,
        period_s,
    };
    let (csv_rows, samples) = rollouts(&run, &models, &grid)?;
    let curves = curves(&alphas, &samples);
    run.finish();
    let mut outcome = Outcome {
        curves,
        checks: Vec::new(),
        out: run.out.clone(),
    };
    outcome.checks = checks(&outcome);
    write_tables(&run, &csv_rows, &outcome)?;
    figure::write(
        &CurvesFigure {
            curves: &outcome.curves,
        },
        &run.path("reversibility"),
        (1200, 520),
    )?;
    let summary = summary(&run, args, &data_dir, &models, ticks, period_s, &outcome);
    run.write("summary.md", &summary)?;
    Ok(outcome)
}

/// The rollouts need the mock arm (not the planar task), a state and two alpha values.
fn check_options(args: &ReversibilityArgs, task: Task) -> Result<(), ToolError> {
    if task == Task::PlanarReach {
        return Err(ExperimentError::Option {
            option: "--task",
            reason: format!(
                "`{}` is the planar arm's; the rollouts run on the mock arm of --robot",
                args.task
            ),
        }
        .into());
    }
    if args.states == 0 || args.alphas < 2 {
        return Err(ExperimentError::Option {
            option: "--states / --alphas",
            reason: "need at least 1 state and 2 alpha values".into(),
        }
        .into());
    }
    Ok(())
}

/// Without `--models`: the SCL, CAE and PCA models per seed, trained (or reused) on the data.
fn trained_models(
    run: &Run,
    task: Task,
    data_dir: &std::path::Path,
    ds: &Arc<crate::dataset::Dataset>,
) -> Result<Vec<ModelRef>, ToolError> {
    let variants: Vec<Variant> = KINDS.iter().map(|(_, v)| *v).collect();
    let jobs = super::seed_jobs(run, task, &variants, data_dir, ds);
    let plain: Vec<_> = jobs.iter().map(|(_, _, j)| j.clone()).collect();
    run.ensure_models(&plain)?;
    let mut models = Vec::new();
    for (v, k, job) in jobs {
        models.push(ModelRef {
            kind: v.kind(),
            index: k,
            model: super::load_model(&job.path)?,
            path: job.path,
        });
    }
    Ok(models)
}

/// With `--models`: the given files, numbered per kind; a kind other than SCL, CAE or PCA
/// is an error.
fn given_models(args: &ReversibilityArgs) -> Result<Vec<ModelRef>, ToolError> {
    let mut count = [0usize; 3];
    let mut models = Vec::new();
    for (path, model) in super::given_models(&args.common.models)? {
        let kind = model.header().kind;
        let Some(g) = KINDS.iter().position(|(k, _)| *k == kind) else {
            return Err(ExperimentError::Model {
                path,
                reason: format!("a {kind} model; this experiment compares scl, cae and pca"),
            }
            .into());
        };
        models.push(ModelRef {
            kind,
            index: count[g],
            path,
            model,
        });
        count[g] += 1;
    }
    Ok(models)
}

/// Every model drives the mock arm's joints from a 2-D action.
fn check_models(robot: &kinematics::RobotProfile, models: &[ModelRef]) -> Result<(), ToolError> {
    for m in models {
        let h = m.model.header();
        if h.n_joints != robot.n_joints() || h.latent_dim != 2 {
            return Err(ExperimentError::Model {
                path: m.path.clone(),
                reason: format!(
                    "drives {} joints from a {}-D action; the mock {} needs {} from 2",
                    h.n_joints,
                    h.latent_dim,
                    robot.description(),
                    robot.n_joints()
                ),
            }
            .into());
        }
    }
    Ok(())
}

/// What every model is rolled out on: the start states, the alphas, one direction per
/// (model index, state, alpha), the ticks of a leg and the control period.
struct Grid<'a> {
    states: &'a eval::States,
    alphas: &'a [f64],
    thetas: &'a [f64],
    ticks: usize,
    period_s: f64,
}

/// (forward, reverse, at limit) samples of one kind at one alpha.
type Samples = (Vec<f64>, Vec<f64>, Vec<bool>);

/// Rolls every model out forward and back from every state at every alpha on the mock arm;
/// returns one row per rollout and the samples by (kind, alpha index).
fn rollouts(
    run: &Run,
    models: &[ModelRef],
    grid: &Grid<'_>,
) -> Result<(Vec<RunRow>, Vec<Vec<Samples>>), ToolError> {
    let (states, alphas) = (grid.states, grid.alphas);
    let mut csv_rows = Vec::new();
    let mut samples: Vec<Vec<Samples>> =
        vec![vec![(Vec::new(), Vec::new(), Vec::new()); alphas.len()]; KINDS.len()];
    for m in models {
        let g = KINDS
            .iter()
            .position(|(k, _)| *k == m.kind)
            .unwrap_or_default();
        let s = m.model.header().speed_scale_rad_s;
        let mut map = m.model.map();
        let file = super::display_rel(&m.path, &run.out);
        for (i, (q0, c0)) in states.iter().enumerate() {
            for (j, &alpha) in alphas.iter().enumerate() {
                let theta = grid.thetas[(m.index * states.len() + i) * alphas.len() + j];
                let mut plant = MockPlant::at(run.robot, q0, *c0)?;
                let r = rollout::forward_reverse(
                    map.as_mut(),
                    s,
                    &mut plant,
                    &rollout::action(alpha, theta),
                    grid.ticks,
                    grid.period_s,
                );
                samples[g][j].0.push(r.forward);
                samples[g][j].1.push(r.reverse);
                samples[g][j].2.push(r.limited);
                csv_rows.push(RunRow {
                    kind: m.kind,
                    model: m.index,
                    file: file.clone(),
                    state: i,
                    alpha,
                    theta,
                    forward_rad: r.forward,
                    reverse_rad: r.reverse,
                    at_limit: r.limited,
                });
            }
            run.done(1);
        }
    }
    Ok((csv_rows, samples))
}

/// One curve per kind with samples: the forward and reverse statistics at each alpha.
fn curves(alphas: &[f64], samples: &[Vec<Samples>]) -> Vec<(ModelKind, Vec<Point>)> {
    let mut curves = Vec::new();
    for (g, (kind, _)) in KINDS.iter().enumerate() {
        if samples[g][0].0.is_empty() {
            continue;
        }
        let pts = alphas
            .iter()
            .zip(&samples[g])
            .map(|(&alpha, (f, r, lim))| {
                let (fm, fs) = rollout::mean_std(f);
                let (rm, rs) = rollout::mean_std(r);
                Point {
                    alpha,
                    n: f.len(),
                    forward_mean: fm,
                    forward_std: fs,
                    reverse_mean: rm,
                    reverse_std: rs,
                    reverse_max: r.iter().copied().fold(0.0, f64::max),
                    limited: lim.iter().filter(|l| **l).count(),
                    reverse_max_inside: r
                        .iter()
                        .zip(lim)
                        .filter(|(_, l)| !**l)
                        .map(|(v, _)| *v)
                        .fold(0.0, f64::max),
                }
            })
            .collect();
        curves.push((*kind, pts));
    }
    curves
}

/// Writes `runs.csv` (one row per rollout) and `curves.csv` (one per kind and alpha).
fn write_tables(run: &Run, csv_rows: &[RunRow], outcome: &Outcome) -> Result<(), ToolError> {
    let runs_csv =
        crate::table::to_csv(csv_rows).map_err(|e| super::write_error(&run.path("runs.csv"), e))?;
    run.write("runs.csv", &runs_csv)?;
    let curves_csv = crate::table::to_csv(outcome.curves.iter().flat_map(|(kind, pts)| {
        pts.iter().map(|p| CurveRow {
            kind: *kind,
            alpha: p.alpha,
            n: p.n,
            forward_mean_rad: p.forward_mean,
            forward_std_rad: p.forward_std,
            reverse_mean_rad: p.reverse_mean,
            reverse_std_rad: p.reverse_std,
            reverse_max_rad: p.reverse_max,
            at_limit_runs: p.limited,
            reverse_max_inside_rad: p.reverse_max_inside,
        })
    }))
    .map_err(|e| super::write_error(&run.path("curves.csv"), e))?;
    run.write("curves.csv", &curves_csv)?;
    Ok(())
}

fn checks(o: &Outcome) -> Vec<Check> {
    let mut out = Vec::new();
    let moving =
        |c: &[Point]| -> Vec<Point> { c.iter().copied().filter(|p| p.alpha > 0.0).collect() };
    let scl = o.curve(ModelKind::Scl).map(moving);
    let pca = o.curve(ModelKind::Pca).map(moving);
    let cae = o.curve(ModelKind::Cae).map(moving);
    if let (Some(scl), Some(pca)) = (&scl, &pca) {
        let mut worst: f64 = 0.0;
        let mut holds = true;
        for (a, b) in scl.iter().zip(pca) {
            let gap = (a.forward_mean - b.forward_mean).abs();
            // PCA's models are identical and its speed state-independent, so its band is
            // nearly zero wide: overlap within the bands or within 5 % of PCA's mean.
            holds &= gap <= (0.5 * (a.forward_std + b.forward_std)).max(0.05 * b.forward_mean);
            worst = worst.max(gap / b.forward_mean.max(1e-12));
        }
        out.push(Check {
            statement: "SCL and PCA forward distances overlap (at every alpha > 0 the means differ by at most the half-std bands or 5 % of PCA's mean, whichever is larger)".into(),
            holds,
            detail: format!("largest gap between the means: {:.1} % of PCA's", 100.0 * worst),
        });
    }
    if let Some(pca) = &pca {
        let worst = pca.iter().map(|p| p.reverse_max_inside).fold(0.0, f64::max);
        let all = pca.iter().map(|p| p.reverse_max).fold(0.0, f64::max);
        let limited: usize = pca.iter().map(|p| p.limited).sum();
        let n: usize = pca.iter().map(|p| p.n).sum();
        out.push(Check {
            statement: "PCA returns exactly (|q_rev - q0| <= 1e-9 rad in every run that stayed inside the joint limits)".into(),
            holds: worst <= 1e-9 && limited < n,
            detail: format!(
                "largest |q_rev - q0| inside the limits: {worst:.3e} rad; {limited} of {n} runs (alpha > 0) touched a joint limit, where the mock clamps the motion (largest |q_rev - q0| over all runs: {all:.3e} rad)"
            ),
        });
    }
    if let Some(scl) = &scl {
        let worst = scl
            .iter()
            .map(|p| p.reverse_mean / p.forward_mean.max(1e-12))
            .fold(0.0, f64::max);
        out.push(Check {
            statement: "SCL nearly returns (mean |q_rev - q0| below 10 % of mean |q_fwd - q0| at every alpha > 0)".into(),
            holds: worst < 0.1,
            detail: format!("largest ratio of the means: {:.2} %", 100.0 * worst),
        });
    }
    if let (Some(cae), Some(scl)) = (&cae, &scl) {
        let last = cae.last().copied();
        let ratio = last.map_or(0.0, |p| p.reverse_mean / p.forward_mean.max(1e-12));
        let above = cae
            .iter()
            .zip(scl)
            .all(|(c, s)| c.reverse_mean > s.reverse_mean);
        out.push(Check {
            statement: "CAE does not return (mean |q_rev - q0| above SCL's at every alpha > 0, and at least 10 % of its forward distance at the largest alpha)".into(),
            holds: above && ratio >= 0.1,
            detail: format!(
                "at alpha = {}: CAE returns to {:.3} rad of the start after going {:.3} rad ({:.0} %); SCL to {:.4} rad",
                last.map_or(f64::NAN, |p| p.alpha),
                last.map_or(f64::NAN, |p| p.reverse_mean),
                last.map_or(f64::NAN, |p| p.forward_mean),
                100.0 * ratio,
                scl.last().map_or(f64::NAN, |p| p.reverse_mean)
            ),
        });
    }
    out
}

#[allow(clippy::too_many_arguments)]
fn summary(
    run: &Run,
    args: &ReversibilityArgs,
    data_dir: &std::path::Path,
    models: &[ModelRef],
    ticks: usize,
    period_s: f64,
    o: &Outcome,
) -> String {
    let given = !args.common.models.is_empty();
    let title = format!(
        "Proportionality and soft reversibility on the mock {}",
        run.robot.description()
    );
    let mut s = run.summary_head(
        &title,
        &[
            ("task (start states: its validation split)", args.task.clone()),
            ("data", data_dir.display().to_string()),
            ("start states per model", args.states.to_string()),
            (
                "alpha",
                format!("{} values evenly spaced over [0, 1]", args.alphas),
            ),
            ("theta", "uniform in [0, 2 pi), one per (model index, state, alpha), the same for every kind".into()),
            (
                "rollout",
                format!(
                    "served command qdot = s * map(q, c, a), |a| <= 1, on the mock arm (hw-bridge MockArm, clamps at the joint limits): a for {ticks} ticks of {:.0} ms, stop, -a for {ticks} ticks",
                    period_s * 1e3
                ),
            ),
            ("seed (states, directions)", args.seed.to_string()),
            (
                "models",
                if given {
                    format!("{} given files", models.len())
                } else {
                    "trained per seed (DIR/models/<task>/<kind>/seed-<k>.safetensors); PCA is deterministic, so its models are identical".into()
                },
            ),
        ],
    );
    s.push_str("## Expected shape\n\n| statement | holds | numbers |\n|---|---|---|\n");
    for c in &o.checks {
        let _ = writeln!(
            s,
            "| {} | {} | {} |",
            c.statement.replace('|', "\\|"),
            if c.holds { "yes" } else { "**no**" },
            c.detail.replace('|', "\\|")
        );
    }
    s.push_str("\n## Distances (mean ± std over models × states, rad)\n\n| alpha |");
    for (k, _) in &o.curves {
        let _ = write!(s, " {k} fwd | {k} rev |");
    }
    s.push_str("\n|---|");
    for _ in &o.curves {
        s.push_str("---|---|");
    }
    s.push('\n');
    let n_alpha = o.curves.first().map_or(0, |(_, c)| c.len());
    for j in 0..n_alpha {
        let _ = write!(s, "| {:.2} |", o.curves[0].1[j].alpha);
        for (_, c) in &o.curves {
            let p = c[j];
            let _ = write!(
                s,
                " {:.4} ± {:.4} | {:.2e} ± {:.1e} |",
                p.forward_mean, p.forward_std, p.reverse_mean, p.reverse_std
            );
        }
        s.push('\n');
    }
    s.push_str("\n## Models\n\n| file | kind | validation MSE (rad/s)² | speed scale (rad/s) |\n|---|---|---|---|\n");
    for m in models {
        let h = m.model.header();
        let _ = writeln!(
            s,
            "| {} | {} | {} | {:.3} |",
            super::display_rel(&m.path, &run.out),
            h.kind,
            h.training
                .validation_loss
                .map_or("-".into(), |v| format!("{v:.3e}")),
            h.speed_scale_rad_s
        );
    }
    s.push_str("\nFiles: `runs.csv` (every run), `curves.csv` (the figure's numbers), `reversibility.png` / `.svg` (left: |q_fwd - q0|, right: |q_rev - q0| against alpha; line: mean, band: ± half a standard deviation).\n");
    s
}

struct CurvesFigure<'a> {
    curves: &'a [(ModelKind, Vec<Point>)],
}

impl Figure for CurvesFigure<'_> {
    fn draw<DB: plotters::prelude::DrawingBackend>(
        &self,
        root: &plotters::prelude::DrawingArea<DB, plotters::coord::Shift>,
        text: bool,
    ) -> Result<(), String> {
        use plotters::prelude::*;
        let panels = root.split_evenly((1, 2));
        let fy = |p: &Point| (p.forward_mean, p.forward_std);
        let ry = |p: &Point| (p.reverse_mean, p.reverse_std);
        let ymax = |f: &dyn Fn(&Point) -> (f64, f64)| {
            self.curves
                .iter()
                .flat_map(|(_, c)| c.iter().map(|p| f(p).0 + 0.5 * f(p).1))
                .filter(|v| v.is_finite())
                .fold(1e-6, f64::max)
                * 1.08
        };
        type Pick<'f> = &'f dyn Fn(&Point) -> (f64, f64);
        let sides: [(Pick, &str); 2] = [
            (&fy, "|q_fwd - q0| (rad) after a for 1 s"),
            (&ry, "|q_rev - q0| (rad) after -a for 1 s"),
        ];
        for (area, (pick, label)) in panels.iter().zip(sides) {
            let top = ymax(pick);
            let mut b = ChartBuilder::on(area);
            b.margin(14);
            if text {
                b.caption(label, ("sans-serif", 18))
                    .x_label_area_size(36)
                    .y_label_area_size(56);
            }
            let mut chart = b
                .build_cartesian_2d(0f64..1f64, 0f64..top)
                .map_err(figure::err)?;
            let mut mesh = chart.configure_mesh();
            if text {
                mesh.x_desc("alpha = |a|").y_desc("rad");
            } else {
                mesh.x_labels(0).y_labels(0);
            }
            mesh.draw().map_err(figure::err)?;
            for (i, (kind, pts)) in self.curves.iter().enumerate() {
                let colour = COLOURS[i % COLOURS.len()];
                let mut band: Vec<(f64, f64)> = pts
                    .iter()
                    .map(|p| (p.alpha, pick(p).0 + 0.5 * pick(p).1))
                    .collect();
                band.extend(
                    pts.iter()
                        .rev()
                        .map(|p| (p.alpha, (pick(p).0 - 0.5 * pick(p).1).max(0.0))),
                );
                chart
                    .draw_series(std::iter::once(Polygon::new(band, colour.mix(0.18))))
                    .map_err(figure::err)?;
                let series = chart
                    .draw_series(LineSeries::new(
                        pts.iter().map(|p| (p.alpha, pick(p).0)),
                        colour.stroke_width(2),
                    ))
                    .map_err(figure::err)?;
                if text {
                    let name = kind.to_string().to_uppercase();
                    series.label(name).legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2))
                    });
                }
            }
            if text {
                chart
                    .configure_series_labels()
                    .position(SeriesLabelPosition::UpperLeft)
                    .background_style(WHITE.mix(0.8))
                    .border_style(BLACK)
                    .label_font(("sans-serif", 15))
                    .draw()
                    .map_err(figure::err)?;
            }
        }
        Ok(())
    }
}
