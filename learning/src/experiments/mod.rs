//! `scl eval EXPERIMENT --out DIR`: the paper's experiments, end to end.
//!
//! Each experiment trains the models it needs (or takes given files), evaluates them, and
//! writes CSV tables, PNG and SVG figures and `DIR/summary.md`. The shared parts live here:
//! the options every experiment takes ([`CommonArgs`]), the output directory and its model
//! cache ([`Run`]), data resolution, training jobs, and the progress bar.
//!
//! A run is resumable: trained models are cached under `DIR/models/` and reused when present
//! (after checking that they were trained with this run's settings: a mismatch is an error,
//! never a silent retrain or overwrite); the result files are rewritten from the cached
//! models on every run.
//!
//! Experiments: [`reversibility`] (proportionality and soft reversibility on the mock Gen3
//! lite), [`theorem`] (the soft-reversibility inequality, sampled), [`reconstruction`]
//! (validation loss of every kind on the three Gen3 lite tasks), [`greedy_user`] (the paper's
//! simulated greedy user on the 5-DOF planar reach, with the rank tests of [`stats`]).

pub mod figure;
pub mod greedy_user;
pub mod reconstruction;
pub mod reversibility;
pub mod stats;
pub mod theorem;

use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::sync::atomic::{AtomicBool, Ordering};

use rayon::prelude::*;

use crate::dataset::{self, Dataset};
use crate::eval::AnyModel;
use crate::tasks::Task;
use crate::train::{self, Progress, TrainConfig};
use mapper::model::{EncoderKind, ModelHeader, ModelKind};

use crate::ToolError;
use scl_signals as signals;

/// Why an experiment could not run.
#[derive(Debug, thiserror::Error)]
pub enum ExperimentError {
    /// The output directory is unusable.
    #[error("--out {path}: {reason}")]
    Out {
        /// The directory.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// A data set is unusable for the experiment.
    #[error("data {path}: {reason}")]
    Data {
        /// The data directory.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// A cached model file cannot be read.
    #[error(
        "cached model {path} is unusable ({reason}); remove it to retrain, or pick another --out"
    )]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// A cached model was trained with other settings than this run's.
    #[error(
        "cached model {path} has {what} {found}, but this run asks for {expected}; pick another --out, or remove the file to retrain it"
    )]
    Mismatch {
        /// The file.
        path: PathBuf,
        /// The setting.
        what: &'static str,
        /// The file's value.
        found: String,
        /// This run's value.
        expected: String,
    },
    /// A result file could not be written.
    #[error("cannot write {path}: {source}")]
    Write {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// Drawing a figure failed.
    #[error("cannot draw {path}: {reason}")]
    Plot {
        /// The figure.
        path: PathBuf,
        /// What failed.
        reason: String,
    },
    /// An option value is unusable.
    #[error("{option}: {reason}")]
    Option {
        /// The option.
        option: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// A given model file does not fit the experiment.
    #[error("{path}: {reason}")]
    Model {
        /// The model file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// Ctrl-C: the models finished so far are cached, the results were not written.
    #[error("interrupted; the models trained so far are kept, run the same command to resume")]
    Interrupted,
}

/// Options every experiment takes (`scl eval EXPERIMENT ...`).
#[derive(clap::Args, Debug, Clone)]
pub struct CommonArgs {
    /// Output directory: CSV tables, PNG / SVG figures, summary.md, and the model cache
    /// models/ (reused when present, so an interrupted run resumes).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Models per kind (the paper's 10): seeds 0..N, one model per seed (reconstruction: the
    /// best of N seeds).
    #[arg(long, default_value_t = 10)]
    pub seeds: usize,
    /// Epochs per seed (default: the paper's for the experiment).
    #[arg(long)]
    pub epochs: Option<usize>,
    /// Models trained at once, one thread each (0: one per CPU).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Data: a directory holding one data set per task (DIR/<task>/train, DIR/<task>/val), or,
    /// for a one-task experiment, one data set (DIR/train, DIR/val). Default: DIR/data under
    /// --out, where a missing task's demonstrations are generated (`scl demos --task T --seed
    /// 1`).
    #[arg(long, value_name = "DIR")]
    pub data: Option<PathBuf>,
    /// Evaluate these model files instead of training (their kind is read from the header).
    #[arg(long, value_name = "FILE", num_args = 1..)]
    pub models: Vec<PathBuf>,
    /// Hidden layer widths of the networks, comma-separated (the paper's 256,256).
    #[arg(long, default_value = "256,256")]
    pub hidden: String,
    /// The arm: a robot profile by the name `[graph] robot` takes. Its demonstrations are
    /// generated for the tasks (`scl demos --robot`) and its mock arm runs the rollouts.
    #[arg(long, value_name = "NAME", default_value = kinematics::RobotProfile::default_name(),
          value_parser = robot_profile)]
    pub robot: &'static kinematics::RobotProfile,
}

/// `--robot`: a robot profile by name; an unknown name is refused with the known ones.
pub fn robot_profile(name: &str) -> Result<&'static kinematics::RobotProfile, String> {
    kinematics::RobotProfile::by_name(name).map_err(|e| e.to_string())
}

/// One experiment's run: its output directory, settings and progress bar.
#[derive(Debug)]
pub struct Run {
    /// The experiment's name (`reversibility`, ...).
    pub name: &'static str,
    /// The output directory.
    pub out: PathBuf,
    /// Models per kind (seeds).
    pub seeds: usize,
    /// Epochs per seed.
    pub epochs: usize,
    /// Worker threads for training.
    pub threads: usize,
    /// Hidden widths.
    pub hidden: Vec<usize>,
    /// The `--data` directory, if given.
    pub data: Option<PathBuf>,
    /// The arm (`--robot`).
    pub robot: &'static kinematics::RobotProfile,
    /// The command line, for the summary and the model headers.
    pub command: String,
    bar: indicatif::ProgressBar,
}

impl Run {
    /// Checks the options and creates the output directory. `default_epochs` is the paper's
    /// for this experiment.
    pub fn new(
        name: &'static str,
        args: &CommonArgs,
        default_epochs: usize,
        command: &str,
    ) -> Result<Self, ExperimentError> {
        let out = args.out.clone();
        if out.exists() && !out.is_dir() {
            return Err(ExperimentError::Out {
                path: out,
                reason: "exists and is not a directory".into(),
            });
        }
        std::fs::create_dir_all(&out).map_err(|e| ExperimentError::Out {
            path: out.clone(),
            reason: format!("cannot create it: {e}"),
        })?;
        if args.seeds == 0 {
            return Err(ExperimentError::Option {
                option: "--seeds",
                reason: "must be at least 1".into(),
            });
        }
        let epochs = args.epochs.unwrap_or(default_epochs);
        if epochs == 0 {
            return Err(ExperimentError::Option {
                option: "--epochs",
                reason: "must be at least 1".into(),
            });
        }
        let hidden: Vec<usize> = crate::cli::parse_list(&args.hidden, "--hidden").map_err(|e| {
            ExperimentError::Option {
                option: "--hidden",
                reason: e.to_string(),
            }
        })?;
        if hidden.is_empty() || hidden.contains(&0) {
            return Err(ExperimentError::Option {
                option: "--hidden",
                reason: format!("`{}`: expected positive widths", args.hidden),
            });
        }
        let threads = match args.threads {
            0 => std::thread::available_parallelism().map_or(1, |n| n.get()),
            n => n,
        };
        let bar = if std::io::IsTerminal::is_terminal(&std::io::stderr()) {
            let bar = indicatif::ProgressBar::new(0);
            if let Ok(style) = indicatif::ProgressStyle::with_template(
                "{prefix} {elapsed_precise} [{bar:40}] {pos}/{len} eta {eta}  {msg}",
            ) {
                bar.set_style(style.progress_chars("=> "));
            }
            bar.set_prefix(name);
            bar
        } else {
            indicatif::ProgressBar::hidden()
        };
        Ok(Self {
            name,
            out,
            seeds: args.seeds,
            epochs,
            threads,
            hidden,
            data: args.data.clone(),
            robot: args.robot,
            command: command.to_owned(),
            bar,
        })
    }

    /// The pool of `threads` workers the run trains and evaluates on.
    pub fn pool(&self) -> Result<rayon::ThreadPool, ExperimentError> {
        let name = self.name;
        rayon::ThreadPoolBuilder::new()
            .num_threads(self.threads)
            .thread_name(move |i| format!("{name}-{i}"))
            .build()
            .map_err(|e| ExperimentError::Option {
                option: "--threads",
                reason: format!("cannot start {} threads: {e}", self.threads),
            })
    }

    /// A path under the output directory.
    pub fn path(&self, rel: &str) -> PathBuf {
        self.out.join(rel)
    }

    /// Adds `n` units of work to the progress bar.
    pub fn add_work(&self, n: u64) {
        self.bar.inc_length(n);
    }

    /// Marks `n` units of work done.
    pub fn done(&self, n: u64) {
        self.bar.inc(n);
    }

    /// Shows a message beside the bar.
    pub fn message(&self, msg: impl Into<std::borrow::Cow<'static, str>>) {
        self.bar.set_message(msg);
    }

    /// Ends the progress bar.
    pub fn finish(&self) {
        self.bar.finish_and_clear();
    }

    /// The data set of `task` (see [`CommonArgs::data`]): `--data DIR/<task>`, or `--data DIR`
    /// itself when it holds train/ and `single` (a one-task experiment), else
    /// `OUT/data/<task>`, generated when absent. The data must have a validation split.
    pub fn data(&self, task: Task, single: bool) -> Result<(PathBuf, Dataset), ToolError> {
        let dir = match &self.data {
            Some(d) => {
                let per_task = d.join(task.name());
                if per_task.is_dir() {
                    per_task
                } else if single && d.join("train").is_dir() {
                    d.clone()
                } else {
                    return Err(ExperimentError::Data {
                        path: d.clone(),
                        reason: format!(
                            "has no {}/ data set{}",
                            task.name(),
                            if single { " and no train/" } else { "" }
                        ),
                    }
                    .into());
                }
            }
            None => {
                let d = self.out.join("data").join(task.name());
                if !d.exists() {
                    let (n_train, n_val) = task.default_counts();
                    let robot = self.robot.name();
                    self.bar.suspend(|| {
                        tracing::info!(task = task.name(), robot, dir = %d.display(), "generating demonstrations (seed 1)");
                    });
                    let ds = crate::tasks::generate_for(task, self.robot, n_train, n_val, 1)?;
                    dataset::write_dir(&d, &ds)?;
                }
                d
            }
        };
        let ds = dataset::load_dir(&dir)?;
        if ds.val.is_empty() {
            return Err(ExperimentError::Data {
                path: dir,
                reason: "has no validation split (val/*.csv); the experiment evaluates on it"
                    .into(),
            }
            .into());
        }
        Ok((dir, ds))
    }

    /// The training configuration of a network variant with this run's epochs and hidden
    /// widths (seeds and base seed are set by the caller).
    pub fn config(&self, variant: Variant) -> Option<TrainConfig> {
        let base = |kind: ModelKind| -> TrainConfig {
            let b = if kind == ModelKind::Cae {
                TrainConfig::cae()
            } else {
                TrainConfig::default()
            };
            TrainConfig {
                hidden: self.hidden.clone(),
                epochs: self.epochs,
                threads: 1,
                ..b
            }
        };
        let li = |terms: &str| crate::train::li::parse_terms(terms).ok().flatten();
        Some(match variant {
            Variant::Pca => return None,
            Variant::Scl => base(ModelKind::Scl),
            Variant::SclNoGs => TrainConfig {
                gram_schmidt: false,
                ..base(ModelKind::Scl)
            },
            Variant::SclNoLipschitz => TrainConfig {
                lipschitz: None,
                ..base(ModelKind::Scl)
            },
            Variant::SclProjection => TrainConfig {
                encoder: EncoderKind::Projection,
                ..base(ModelKind::Scl)
            },
            Variant::Cae => base(ModelKind::Cae),
            Variant::CaeLiCons => TrainConfig {
                li: li("consistency"),
                ..base(ModelKind::Cae)
            },
            Variant::CaeLiProp => TrainConfig {
                li: li("proportionality"),
                ..base(ModelKind::Cae)
            },
            Variant::CaeLiRev => TrainConfig {
                li: li("reversibility"),
                ..base(ModelKind::Cae)
            },
            Variant::CaeLiConsProp => TrainConfig {
                li: li("consistency,proportionality"),
                ..base(ModelKind::Cae)
            },
            Variant::CaeLiConsRev => TrainConfig {
                li: li("consistency,reversibility"),
                ..base(ModelKind::Cae)
            },
            Variant::CaeLiPropRev => TrainConfig {
                li: li("proportionality,reversibility"),
                ..base(ModelKind::Cae)
            },
            Variant::CaeLiAll => TrainConfig {
                li: li("consistency,proportionality,reversibility"),
                ..base(ModelKind::Cae)
            },
        })
    }

    /// Makes sure every job's model file exists: checks the cached ones against their
    /// settings and trains the missing ones ([`Run::pool`]: `threads` at a time, each
    /// single-threaded, so results do not depend on the thread count or the schedule). Ctrl-C stops training; the finished
    /// models are kept.
    pub fn ensure_models(&self, jobs: &[Job]) -> Result<(), ToolError> {
        let mut missing = Vec::new();
        for job in jobs {
            if job.path.exists() {
                check_cached(job)?;
            } else {
                missing.push(job);
            }
        }
        let work: u64 = missing
            .iter()
            .map(|j| j.config.as_ref().map_or(1, |c| (c.seeds * c.epochs) as u64))
            .sum();
        self.add_work(work);
        if missing.is_empty() {
            return Ok(());
        }
        self.bar.suspend(|| {
            tracing::info!(
                experiment = self.name,
                models = missing.len(),
                cached = jobs.len() - missing.len(),
                "training"
            );
        });
        // The first error stops the other jobs (at their next epoch) and is returned.
        let cancel = AtomicBool::new(false);
        let first_error = OnceLock::new();
        self.pool()?.install(|| {
            missing.par_iter().for_each(|job| {
                if cancel.load(Ordering::Relaxed) {
                    return;
                }
                if let Err(e) = self.train_job(job, &cancel) {
                    cancel.store(true, Ordering::Relaxed);
                    let _ = first_error.set(e);
                }
            });
        });
        if let Some(e) = first_error.into_inner() {
            return Err(e);
        }
        if cancel.load(Ordering::Relaxed) {
            return Err(ExperimentError::Interrupted.into());
        }
        Ok(())
    }

    fn train_job(&self, job: &Job, cancel: &AtomicBool) -> Result<(), ToolError> {
        let Some(cfg) = &job.config else {
            crate::tools::train_pca(&crate::tools::TrainOptions {
                data: &job.data_dir,
                out: &job.path,
                latent_dim: 2,
                speed_scale: None,
                force: false,
                command: self.command.clone(),
                lerobot: Default::default(),
            })?;
            self.done(1);
            return Ok(());
        };
        let on_progress = |_: &Progress| {
            self.done(1);
            if signals::stop_requested() {
                cancel.store(true, Ordering::Relaxed);
            }
        };
        let outcome = train::train(cfg, &job.data, &self.command, &on_progress, cancel);
        if cancel.load(Ordering::Relaxed) {
            // A partly trained model is never cached (nor is an error reported that only
            // says the training was stopped).
            return Ok(());
        }
        let outcome = outcome?;
        let bytes = outcome.model.to_bytes()?;
        mapper::model::write_file(&job.path, &bytes, false)?;
        crate::cli::write_loss_log(&crate::cli::loss_log_path(&job.path), &outcome.runs)?;
        if job.loss_plot {
            crate::cli::plot_losses(
                &crate::cli::loss_plot_path(&job.path),
                &outcome.runs,
                outcome.best_index,
                cfg.kind,
            )?;
        }
        Ok(())
    }

    /// Writes a result file (results are rewritten on every run).
    pub fn write(&self, rel: &str, text: &str) -> Result<PathBuf, ExperimentError> {
        let path = self.out.join(rel);
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir).map_err(|source| ExperimentError::Write {
                path: dir.to_owned(),
                source,
            })?;
        }
        std::fs::write(&path, text).map_err(|source| ExperimentError::Write {
            path: path.clone(),
            source,
        })?;
        Ok(path)
    }

    /// The common head of every summary.md: experiment, command line, settings.
    pub fn summary_head(&self, title: &str, extra: &[(&str, String)]) -> String {
        let mut s = format!(
            "# {title}\n\nExperiment `{}`, written by `scl` {}.\n\nCommand:\n\n```\n{}\n```\n\nSettings:\n\n",
            self.name,
            env!("CARGO_PKG_VERSION"),
            self.command
        );
        s.push_str(&format!(
            "- models per kind (seeds): {}\n- epochs per seed: {}\n- hidden widths: {:?}\n",
            self.seeds, self.epochs, self.hidden
        ));
        for (k, v) in extra {
            s.push_str(&format!("- {k}: {v}\n"));
        }
        s.push('\n');
        s
    }
}

/// The model variants the experiments train, named as their cache files are.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Variant {
    /// PCA.
    Pca,
    /// SCL: Gram-Schmidt, L = 1, MLP encoder (the paper's).
    Scl,
    /// SCL without Gram-Schmidt (L = 1: the theorem applies).
    SclNoGs,
    /// SCL without the Lipschitz bound.
    SclNoLipschitz,
    /// SCL trained with the projection encoder `a = H'ᵀ qdot`.
    SclProjection,
    /// The conditional autoencoder.
    Cae,
    /// CAE with Li et al.'s consistency term (gamma = 2).
    CaeLiCons,
    /// CAE with Li et al.'s proportionality term (alpha sampled in [0.1, 1]).
    CaeLiProp,
    /// CAE with Li et al.'s reversibility term.
    CaeLiRev,
    /// CAE with Li et al.'s consistency and proportionality terms.
    CaeLiConsProp,
    /// CAE with Li et al.'s consistency and reversibility terms.
    CaeLiConsRev,
    /// CAE with Li et al.'s proportionality and reversibility terms.
    CaeLiPropRev,
    /// CAE with all three Li et al. terms.
    CaeLiAll,
}

impl Variant {
    /// The variants of the reconstruction table, in table order (the Li et al. grid's other
    /// points are in [`Variant::GREEDY`] only).
    pub const ALL: [Variant; 8] = [
        Variant::Pca,
        Variant::Scl,
        Variant::SclNoGs,
        Variant::SclNoLipschitz,
        Variant::SclProjection,
        Variant::Cae,
        Variant::CaeLiPropRev,
        Variant::CaeLiAll,
    ];

    /// The greedy-user experiment's groups: SCL with and without Gram-Schmidt, and CAE over
    /// every combination of the Li et al. terms (the paper's grid, plain CAE included).
    pub const GREEDY: [Variant; 10] = [
        Variant::Scl,
        Variant::SclNoGs,
        Variant::Cae,
        Variant::CaeLiCons,
        Variant::CaeLiProp,
        Variant::CaeLiRev,
        Variant::CaeLiConsProp,
        Variant::CaeLiConsRev,
        Variant::CaeLiPropRev,
        Variant::CaeLiAll,
    ];

    /// The variant called `name` (its cache name, [`Variant::name`]).
    pub fn from_name(name: &str) -> Option<Variant> {
        Self::ALL
            .into_iter()
            .chain(Self::GREEDY)
            .find(|v| v.name() == name)
    }

    /// The cache file name (without extension).
    pub fn name(self) -> &'static str {
        match self {
            Variant::Pca => "pca",
            Variant::Scl => "scl",
            Variant::SclNoGs => "scl-no-gs",
            Variant::SclNoLipschitz => "scl-no-lipschitz",
            Variant::SclProjection => "scl-projection",
            Variant::Cae => "cae",
            Variant::CaeLiCons => "cae-li-cons",
            Variant::CaeLiProp => "cae-li-prop",
            Variant::CaeLiRev => "cae-li-rev",
            Variant::CaeLiConsProp => "cae-li-cons-prop",
            Variant::CaeLiConsRev => "cae-li-cons-rev",
            Variant::CaeLiPropRev => "cae-li-prop-rev",
            Variant::CaeLiAll => "cae-li-all",
        }
    }

    /// The model kind.
    pub fn kind(self) -> ModelKind {
        match self {
            Variant::Pca => ModelKind::Pca,
            Variant::Scl | Variant::SclNoGs | Variant::SclNoLipschitz | Variant::SclProjection => {
                ModelKind::Scl
            }
            Variant::Cae
            | Variant::CaeLiCons
            | Variant::CaeLiProp
            | Variant::CaeLiRev
            | Variant::CaeLiConsProp
            | Variant::CaeLiConsRev
            | Variant::CaeLiPropRev
            | Variant::CaeLiAll => ModelKind::Cae,
        }
    }

    /// What the variant is, for tables.
    pub fn describe(self) -> &'static str {
        match self {
            Variant::Pca => "PCA",
            Variant::Scl => "SCL (Gram-Schmidt, L = 1)",
            Variant::SclNoGs => "SCL without Gram-Schmidt (L = 1)",
            Variant::SclNoLipschitz => "SCL without Lipschitz bound",
            Variant::SclProjection => "SCL, projection encoder",
            Variant::Cae => "CAE",
            Variant::CaeLiCons => "CAE + Li cons.",
            Variant::CaeLiProp => "CAE + Li prop.",
            Variant::CaeLiRev => "CAE + Li rev.",
            Variant::CaeLiConsProp => "CAE + Li cons. + prop.",
            Variant::CaeLiConsRev => "CAE + Li cons. + rev.",
            Variant::CaeLiPropRev => "CAE + Li prop. + rev.",
            Variant::CaeLiAll => "CAE + Li cons. + prop. + rev.",
        }
    }
}

/// One model file an experiment needs: where it is cached and how to train it.
#[derive(Debug, Clone)]
pub struct Job {
    /// The cache file.
    pub path: PathBuf,
    /// The variant.
    pub variant: Variant,
    /// Training configuration (seeds and base seed included); `None` for PCA.
    pub config: Option<TrainConfig>,
    /// The data set directory.
    pub data_dir: PathBuf,
    /// The data set.
    pub data: std::sync::Arc<Dataset>,
    /// Also draw the loss curves next to the model (as `scl train` does).
    pub loss_plot: bool,
}

/// Loads a model file, naming it in the error.
pub fn load_model(path: &Path) -> Result<AnyModel, ExperimentError> {
    AnyModel::load(path).map_err(|e| ExperimentError::Corrupt {
        path: path.to_owned(),
        reason: e.to_string(),
    })
}

/// Checks a cached model against the job's settings.
fn check_cached(job: &Job) -> Result<(), ExperimentError> {
    let m = load_model(&job.path)?;
    let h = m.header();
    let mismatch = |what: &'static str, found: String, expected: String| {
        Err(ExperimentError::Mismatch {
            path: job.path.clone(),
            what,
            found,
            expected,
        })
    };
    if h.kind != job.variant.kind() {
        return mismatch("kind", h.kind.to_string(), job.variant.kind().to_string());
    }
    if h.training.data_hash != job.data.hash {
        return mismatch(
            "training data hash",
            h.training.data_hash.clone(),
            format!("{} (of {})", job.data.hash, job.data_dir.display()),
        );
    }
    let Some(cfg) = &job.config else {
        return Ok(());
    };
    let expected = describe_config(cfg);
    let found = describe_header(h);
    if found != expected {
        return mismatch("settings", found, expected);
    }
    let settings = h.training.settings.as_ref();
    let (epochs, seeds) = settings.map_or((0, 0), |s| (s.epochs, s.seeds));
    if (epochs, seeds) != (cfg.epochs, cfg.seeds) {
        return mismatch(
            "epochs x seeds",
            format!("{epochs} x {seeds}"),
            format!("{} x {}", cfg.epochs, cfg.seeds),
        );
    }
    let seed = h.training.seed;
    if seed < cfg.base_seed || seed >= cfg.base_seed + cfg.seeds as u64 {
        return mismatch(
            "seed",
            seed.to_string(),
            format!("{}..{}", cfg.base_seed, cfg.base_seed + cfg.seeds as u64),
        );
    }
    Ok(())
}

/// The architecture settings of a configuration, in the words of [`describe_header`].
fn describe_config(cfg: &TrainConfig) -> String {
    settings_text(
        cfg.kind,
        &cfg.hidden,
        cfg.kind == ModelKind::Scl && cfg.gram_schmidt,
        cfg.lipschitz,
        cfg.encoder,
        cfg.li.as_ref(),
    )
}

/// The architecture settings recorded in a model header.
pub fn describe_header(h: &ModelHeader) -> String {
    match &h.network {
        None => "pca".into(),
        Some(n) => settings_text(
            h.kind,
            &n.hidden,
            h.kind == ModelKind::Scl && n.gram_schmidt,
            h.lipschitz_bound,
            n.encoder,
            n.li_losses.as_ref(),
        ),
    }
}

fn settings_text(
    kind: ModelKind,
    hidden: &[usize],
    gs: bool,
    lipschitz: Option<f64>,
    encoder: EncoderKind,
    li: Option<&mapper::model::LiLosses>,
) -> String {
    let mut parts = vec![
        kind.to_string(),
        format!(
            "hidden {}",
            hidden
                .iter()
                .map(usize::to_string)
                .collect::<Vec<_>>()
                .join("x")
        ),
    ];
    if kind == ModelKind::Scl {
        parts.push(if gs { "GS" } else { "no GS" }.into());
        parts.push(format!("encoder {encoder:?}").to_lowercase());
    }
    parts.push(lipschitz.map_or("no L".into(), |l| format!("L {l}")));
    if let Some(li) = li {
        let mut t = Vec::new();
        if li.consistency_gamma.is_some() {
            t.push("cons");
        }
        if li.proportionality_alpha.is_some() {
            t.push("prop");
        }
        if li.reversibility {
            t.push("rev");
        }
        parts.push(format!("Li {}", t.join("+")));
    }
    parts.join(", ")
}

/// Per-seed jobs of `variants`: `OUT/models/<task>/<variant>/seed-<k>.safetensors`, one model
/// per seed `k` in `0..seeds` (PCA is deterministic: its files are identical).
pub fn seed_jobs(
    run: &Run,
    task: Task,
    variants: &[Variant],
    data_dir: &Path,
    data: &std::sync::Arc<Dataset>,
) -> Vec<(Variant, usize, Job)> {
    let mut jobs = Vec::new();
    for &v in variants {
        for k in 0..run.seeds {
            let path = run
                .out
                .join("models")
                .join(task.name())
                .join(v.name())
                .join(format!("seed-{k}.safetensors"));
            let config = run.config(v).map(|c| TrainConfig {
                seeds: 1,
                base_seed: k as u64,
                ..c
            });
            jobs.push((
                v,
                k,
                Job {
                    path,
                    variant: v,
                    config,
                    data_dir: data_dir.to_owned(),
                    data: data.clone(),
                    loss_plot: false,
                },
            ));
        }
    }
    jobs
}

/// Reads given model files (`--models`), refusing any that fail to load.
pub fn given_models(paths: &[PathBuf]) -> Result<Vec<(PathBuf, AnyModel)>, ExperimentError> {
    paths
        .iter()
        .map(|p| load_model(p).map(|m| (p.clone(), m)))
        .collect()
}

/// A file name for tables: the path relative to `base` when inside it.
pub fn display_rel(path: &Path, base: &Path) -> String {
    path.strip_prefix(base)
        .unwrap_or(path)
        .display()
        .to_string()
}

/// A result table that could not be rendered, as a write error of its file.
pub fn write_error(path: &Path, e: csv::Error) -> ExperimentError {
    ExperimentError::Write {
        path: path.to_owned(),
        source: e.into(),
    }
}

#[cfg(test)]
mod tests;
