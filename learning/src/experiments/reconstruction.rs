//! `scl eval reconstruction`: the validation reconstruction loss of every kind and variant on
//! the three Gen3 lite tasks (what `scripts/learning-table.sh` does for one data set).
//!
//! Models are cached as `DIR/models/<task>/<variant>.safetensors`, each the best of `--seeds`
//! seeds as `scl train` writes it (with its loss log and curves), so files trained by
//! `scripts/learning-table.sh` into that layout are reused.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::sync::Arc;

use crate::dataset;
use crate::eval;
use crate::tasks::Task;
use crate::train::TrainConfig;

use super::figure::{self, COLOURS, Figure};
use super::{CommonArgs, ExperimentError, Job, Run, Variant};
use crate::ToolError;

/// The paper's epochs.
pub const DEFAULT_EPOCHS: usize = 200;

/// The paper's three Gen3 lite tasks.
pub const DEFAULT_TASKS: &str = "table-cleaning,pick-and-place,pouring";

/// `scl eval reconstruction` options.
#[derive(clap::Args, Debug, Clone)]
pub struct ReconstructionArgs {
    /// Shared experiment options. With --models, --data names the one data set to evaluate
    /// them on.
    #[command(flatten)]
    pub common: CommonArgs,
    /// Tasks, comma-separated.
    #[arg(long, default_value = DEFAULT_TASKS)]
    pub tasks: String,
}

/// One cell of the table.
#[derive(Debug, Clone, PartialEq)]
pub struct Entry {
    /// The task (or data set name).
    pub task: String,
    /// The variant (or file stem).
    pub variant: String,
    /// The model's settings as its header records them.
    pub settings: String,
    /// Validation reconstruction MSE of qdot ((rad/s)²).
    pub val_mse: f64,
    /// The model file.
    pub path: PathBuf,
}

/// What the experiment measured.
#[derive(Debug, Clone)]
pub struct Outcome {
    /// Every (task, variant).
    pub entries: Vec<Entry>,
    /// The output directory.
    pub out: PathBuf,
}

/// Runs the experiment; writes `reconstruction.csv`, `reconstruction.md`,
/// `reconstruction.png` / `.svg` and `summary.md`.
pub fn run(args: &ReconstructionArgs, command: &str) -> Result<Outcome, ToolError> {
    let run = Run::new("reconstruction", &args.common, DEFAULT_EPOCHS, command)?;
    let (entries, data_lines) = if args.common.models.is_empty() {
        trained_entries(args, &run)?
    } else {
        given_entries(args)?
    };
    run.finish();
    #[derive(serde::Serialize)]
    struct CsvRow<'a> {
        task: &'a str,
        variant: &'a str,
        settings: &'a str,
        #[serde(serialize_with = "crate::table::sci")]
        val_mse: f64,
    }
    let csv = crate::table::to_csv(entries.iter().map(|e| CsvRow {
        task: &e.task,
        variant: &e.variant,
        settings: &e.settings,
        val_mse: e.val_mse,
    }))
    .map_err(|e| super::write_error(&run.path("reconstruction.csv"), e))?;
    let table = markdown(&entries);
    run.write("reconstruction.csv", &csv)?;
    run.write("reconstruction.md", &table)?;
    figure::write(
        &Bars { entries: &entries },
        &run.path("reconstruction"),
        (1100, 560),
    )?;
    let title = format!(
        "Validation reconstruction loss on the {}'s tasks",
        args.common.robot.description()
    );
    let mut s = run.summary_head(
        &title,
        &[
            (
                "models",
                if args.common.models.is_empty() {
                    "each the best of --seeds seeds (seeds 0..N) by validation loss, cached as DIR/models/<task>/<variant>.safetensors (the settings of scripts/learning-table.sh)".into()
                } else {
                    format!("{} given files", entries.len())
                },
            ),
            ("data", data_lines.join("; ")),
        ],
    );
    s.push_str("## Validation MSE of qdot, (rad/s)²\n\n");
    s.push_str(&table);
    s.push_str("\nFiles: `reconstruction.csv` (with each model's settings), `reconstruction.png` / `.svg` (bar chart, log scale).\n");
    run.write("summary.md", &s)?;
    print!("{table}");
    Ok(Outcome {
        entries,
        out: run.out.clone(),
    })
}

/// The entries (one per model) and the data sets' descriptions.
type Entries = (Vec<Entry>, Vec<String>);

/// Without `--models`: every variant trained (or reused) on each task of `--tasks`, the best
/// of the seeds, evaluated on the task's validation split.
fn trained_entries(args: &ReconstructionArgs, run: &Run) -> Result<Entries, ToolError> {
    let mut entries = Vec::new();
    let mut data_lines = Vec::new();
    let tasks: Vec<Task> = args
        .tasks
        .split(',')
        .map(str::trim)
        .filter(|t| !t.is_empty())
        .map(Task::from_name)
        .collect::<Result<_, _>>()?;
    if tasks.is_empty() {
        return Err(ExperimentError::Option {
            option: "--tasks",
            reason: "no task given".into(),
        }
        .into());
    }
    let mut jobs = Vec::new();
    let mut sets = Vec::new();
    for &task in &tasks {
        let (dir, ds) = run.data(task, tasks.len() == 1)?;
        let ds = Arc::new(ds);
        data_lines.push(format!(
            "{}: {} ({} train / {} val tuples, hash {})",
            task.name(),
            dir.display(),
            ds.n_train(),
            ds.n_val(),
            ds.hash
        ));
        for v in Variant::ALL {
            jobs.push(Job {
                path: run
                    .out
                    .join("models")
                    .join(task.name())
                    .join(format!("{}.safetensors", v.name())),
                variant: v,
                config: run.config(v).map(|c| TrainConfig {
                    seeds: run.seeds,
                    base_seed: 0,
                    ..c
                }),
                data_dir: dir.clone(),
                data: ds.clone(),
                loss_plot: true,
            });
        }
        sets.push((task, ds));
    }
    run.ensure_models(&jobs)?;
    for job in &jobs {
        let m = super::load_model(&job.path)?;
        let mse = eval::reconstruction_mse(&m, &job.path, &job.data.val)?;
        let task = sets
            .iter()
            .find(|(_, d)| Arc::ptr_eq(d, &job.data))
            .map_or("?", |(t, _)| t.name());
        entries.push(Entry {
            task: task.to_owned(),
            variant: job.variant.name().to_owned(),
            settings: super::describe_header(m.header()),
            val_mse: mse,
            path: job.path.clone(),
        });
    }
    Ok((entries, data_lines))
}

/// With `--models`: the given files, evaluated on the validation split of `--data`.
fn given_entries(args: &ReconstructionArgs) -> Result<Entries, ToolError> {
    let mut entries = Vec::new();
    let mut data_lines = Vec::new();
    let Some(dir) = &args.common.data else {
        return Err(ExperimentError::Option {
            option: "--models",
            reason: "needs --data DIR, the data set to evaluate them on".into(),
        }
        .into());
    };
    let ds = dataset::load_dir(dir)?;
    if ds.val.is_empty() {
        return Err(ExperimentError::Data {
            path: dir.clone(),
            reason: "has no validation split (val/*.csv)".into(),
        }
        .into());
    }
    let name = dir.file_name().map_or_else(
        || dir.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    );
    data_lines.push(format!(
        "{name}: {} ({} train / {} val tuples, hash {})",
        dir.display(),
        ds.n_train(),
        ds.n_val(),
        ds.hash
    ));
    for (path, m) in super::given_models(&args.common.models)? {
        let mse = eval::reconstruction_mse(&m, &path, &ds.val)?;
        entries.push(Entry {
            task: name.clone(),
            variant: path
                .file_stem()
                .map_or_else(String::new, |s| s.to_string_lossy().into_owned()),
            settings: super::describe_header(m.header()),
            val_mse: mse,
            path,
        });
    }
    Ok((entries, data_lines))
}

fn columns(entries: &[Entry]) -> (Vec<String>, Vec<String>) {
    let mut tasks: Vec<String> = Vec::new();
    let mut variants: Vec<String> = Vec::new();
    for e in entries {
        if !tasks.contains(&e.task) {
            tasks.push(e.task.clone());
        }
        if !variants.contains(&e.variant) {
            variants.push(e.variant.clone());
        }
    }
    (tasks, variants)
}

fn markdown(entries: &[Entry]) -> String {
    let (tasks, variants) = columns(entries);
    let mut s = String::from("| variant |");
    for t in &tasks {
        let _ = write!(s, " {t} |");
    }
    s.push_str("\n|---|");
    for _ in &tasks {
        s.push_str("---|");
    }
    s.push('\n');
    for v in &variants {
        let _ = write!(s, "| {v} |");
        for t in &tasks {
            match entries.iter().find(|e| &e.task == t && &e.variant == v) {
                Some(e) => {
                    let _ = write!(s, " {:.3e} |", e.val_mse);
                }
                None => s.push_str(" - |"),
            }
        }
        s.push('\n');
    }
    s
}

struct Bars<'a> {
    entries: &'a [Entry],
}

impl Figure for Bars<'_> {
    fn draw<DB: plotters::prelude::DrawingBackend>(
        &self,
        root: &plotters::prelude::DrawingArea<DB, plotters::coord::Shift>,
        text: bool,
    ) -> Result<(), String> {
        use plotters::prelude::*;
        let (tasks, variants) = columns(self.entries);
        let values = self
            .entries
            .iter()
            .map(|e| e.val_mse)
            .filter(|v| v.is_finite() && *v > 0.0);
        let (lo, hi) = values.fold((f64::INFINITY, 0.0f64), |(l, h), v| (l.min(v), h.max(v)));
        let (lo, hi) = if lo <= hi {
            (lo / 2.0, hi * 2.0)
        } else {
            (1e-6, 1.0)
        };
        let n = tasks.len().max(1) as f64;
        let mut b = ChartBuilder::on(root);
        b.margin(16);
        if text {
            b.caption(
                "validation reconstruction MSE of qdot, (rad/s)², log scale",
                ("sans-serif", 18),
            )
            .x_label_area_size(36)
            .y_label_area_size(72);
        }
        let mut chart = b
            .build_cartesian_2d(-0.5f64..n - 0.5, (lo..hi).log_scale())
            .map_err(figure::err)?;
        let names = tasks.clone();
        let label = move |x: &f64| {
            let i = x.round();
            if (x - i).abs() < 1e-6 && i >= 0.0 {
                names.get(i as usize).cloned().unwrap_or_default()
            } else {
                String::new()
            }
        };
        let mut mesh = chart.configure_mesh();
        mesh.disable_x_mesh();
        if text {
            mesh.x_labels(tasks.len() * 2 + 1)
                .x_label_formatter(&label)
                .y_desc("(rad/s)²");
        } else {
            mesh.x_labels(0).y_labels(0);
        }
        mesh.draw().map_err(figure::err)?;
        let width = 0.8 / variants.len().max(1) as f64;
        for (vi, v) in variants.iter().enumerate() {
            let colour = COLOURS[vi % COLOURS.len()];
            let bars: Vec<_> = tasks
                .iter()
                .enumerate()
                .filter_map(|(ti, t)| {
                    let e = self
                        .entries
                        .iter()
                        .find(|e| &e.task == t && &e.variant == v)?;
                    let x0 = ti as f64 - 0.4 + vi as f64 * width;
                    (e.val_mse.is_finite() && e.val_mse > 0.0).then(|| {
                        Rectangle::new([(x0, lo), (x0 + width * 0.9, e.val_mse)], colour.filled())
                    })
                })
                .collect();
            let series = chart.draw_series(bars).map_err(figure::err)?;
            if text {
                series.label(v.clone()).legend(move |(x, y)| {
                    Rectangle::new([(x, y - 5), (x + 12, y + 5)], colour.filled())
                });
            }
        }
        if text {
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::UpperRight)
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .label_font(("sans-serif", 14))
                .draw()
                .map_err(figure::err)?;
        }
        Ok(())
    }
}
