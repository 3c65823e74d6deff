//! The offline commands: `scl demos`, `scl plot`, `scl train`, `scl import`, `scl eval`
//! (the `learning` crate's tools).

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Subcommand;
use learning::train::TrainConfig;
use mapper::model::ModelKind;
use scl::SclError;

/// `scl demos`'s options.
#[derive(clap::Args, Debug)]
pub(crate) struct DemosArgs {
    /// Task: `joint-reach` (joint-space reaches from home, the bundled model's data), the
    /// paper's Gen3 lite tasks `table-cleaning`, `pick-and-place`, `pouring`, or its 5-DOF
    /// `planar-reach`.
    #[arg(long, default_value = "joint-reach")]
    pub(crate) task: String,
    /// Output directory (gets train/ and val/); existing files are never overwritten.
    #[arg(long, value_name = "DIR")]
    pub(crate) out: PathBuf,
    /// Random seed.
    #[arg(long, default_value_t = 1)]
    pub(crate) seed: u64,
    /// Training trajectories (default: the task's; the paper's 3, 6, 8 for table-cleaning,
    /// pick-and-place, pouring; 40 for planar-reach; 6 for joint-reach).
    #[arg(long = "train")]
    pub(crate) n_train: Option<usize>,
    /// Validation trajectories (default: the task's; 2, or 10 for planar-reach).
    #[arg(long = "val")]
    pub(crate) n_val: Option<usize>,
    /// Also draw the TCP paths to this PNG (as `scl plot` does).
    #[arg(long, value_name = "FILE.png")]
    pub(crate) plot: Option<PathBuf>,
    /// The arm of the Cartesian tasks (table-cleaning, pick-and-place, pouring): a robot
    /// profile, by the name `[graph] robot` takes; the same scenes, started from its home.
    #[arg(long, value_name = "NAME", default_value = kinematics::RobotProfile::default_name(),
          value_parser = super::nodes::robot_profile)]
    pub(crate) robot: &'static kinematics::RobotProfile,
}

/// `scl plot`'s options.
#[derive(clap::Args, Debug)]
pub(crate) struct PlotArgs {
    /// Data set: a directory (train/*.csv, val/*.csv; *.json too) or one CSV / JSON file.
    #[arg(long, value_name = "DIR")]
    pub(crate) data: PathBuf,
    /// The PNG to write.
    #[arg(long, value_name = "FILE.png")]
    pub(crate) out: PathBuf,
    /// Figure title (default: the data's name and counts).
    #[arg(long)]
    pub(crate) title: Option<String>,
    /// TrueType font for the text (default: a common system font; none: no text).
    #[arg(long, value_name = "FILE.ttf")]
    pub(crate) font: Option<PathBuf>,
    /// Replace an existing PNG.
    #[arg(long)]
    pub(crate) force: bool,
}

/// `scl import`'s options.
#[derive(clap::Args, Debug)]
pub(crate) struct ImportArgs {
    /// The JSON weights of the decoder.
    #[arg(long, value_name = "FILE")]
    pub(crate) json: PathBuf,
    /// Model kind: `scl` (decoder outputs m*d, reshaped row-major) or `cae`.
    #[arg(long, default_value = "scl")]
    pub(crate) kind: String,
    /// Joints m.
    #[arg(long, default_value_t = 6)]
    pub(crate) joints: usize,
    /// Action dimension d.
    #[arg(long, default_value_t = 2)]
    pub(crate) latent_dim: usize,
    /// Speed scale s in rad/s the network's output is multiplied by.
    #[arg(long)]
    pub(crate) speed_scale: f64,
    /// Serve H without Gram-Schmidt (scl).
    #[arg(long)]
    pub(crate) no_gram_schmidt: bool,
    /// Input normalisation mean, comma-separated (default: none).
    #[arg(long, value_name = "LIST", requires = "input_std")]
    pub(crate) input_mean: Option<String>,
    /// Input normalisation scale, comma-separated.
    #[arg(long, value_name = "LIST", requires = "input_mean")]
    pub(crate) input_std: Option<String>,
    /// Model file to write.
    #[arg(long, value_name = "FILE")]
    pub(crate) out: PathBuf,
    /// Overwrite an existing model file.
    #[arg(long)]
    pub(crate) force: bool,
}

/// `scl eval EXPERIMENT --out DIR`: the paper's experiments (docs/experiments.md).
///
/// Every experiment shares the options of `learning::experiments::CommonArgs` (--out, --seeds,
/// --epochs, --threads, --data, --models, --hidden); each experiment flattens them into its
/// own arguments.
#[derive(Subcommand, Debug)]
pub(crate) enum EvalCmd {
    /// Proportionality and soft reversibility on the mock Gen3 lite (the paper's figure):
    /// a for 1 s, stop, -a for 1 s, 10 models per kind (SCL, CAE, PCA) x 10 start states.
    Reversibility(learning::experiments::reversibility::ReversibilityArgs),
    /// The soft-reversibility inequality over sampled states and actions, for SCL without
    /// Gram-Schmidt (the theorem: must always hold), with Gram-Schmidt, and CAE.
    /// `--models FILE...` checks given files (the former `scl eval reversibility --model`).
    Theorem(learning::experiments::theorem::TheoremArgs),
    /// Validation reconstruction loss of every kind on the three tasks of `--robot`'s arm (with
    /// `--models FILE... --data DIR`: of given files on one data set).
    Reconstruction(learning::experiments::reconstruction::ReconstructionArgs),
    /// The paper's simulated greedy user on the 5-DOF planar reach: SCL with and without
    /// Gram-Schmidt and CAE over the Li et al. loss grid (10 models each, 1000 epochs); the
    /// best of 4096 Gaussian actions per step, to the end state and back to the start of 100
    /// test trajectories; violin plots, Kruskal-Wallis and Dunn's test. Long at the paper's
    /// defaults (hours): resumable, and --seeds / --epochs / --test-trajectories give a quick
    /// look.
    GreedyUser(learning::experiments::greedy_user::GreedyUserArgs),
    /// Whether a map can do one of the paper's tasks before a person sits down: the expert
    /// operator's success rate from the study's start (`--operator expert`, `--seeds N`), or
    /// the share of the task's training demonstrations the follower tracks to the end
    /// through the map (`--operator follower`). In process, through the graph's safety
    /// filter (`--config`) and the mock arm; see docs/simulated-participants.md.
    Capability(scl_study::CapabilityArgs),
}

/// `scl train`: every option, with the paper's defaults.
#[derive(clap::Args, Debug)]
pub(crate) struct TrainArgs {
    /// Model kind: `pca`, `scl` or `cae`.
    #[arg(long, default_value = "pca")]
    pub(crate) kind: String,
    /// Data set directory (train/*.csv, val/*.csv), or a LeRobot v3.0 dataset directory
    /// (meta/info.json; see docs/lerobot.md).
    #[arg(long, value_name = "DIR")]
    pub(crate) data: PathBuf,
    /// A LeRobot dataset's arm: a robot profile (default: its `robot_type` when that names
    /// one, else the default profile). Its joints are looked up by name.
    #[arg(long, value_name = "PROFILE")]
    pub(crate) robot: Option<String>,
    /// A LeRobot dataset's `observation.state` columns for the arm's joints, base to tip,
    /// then optionally the gripper's, comma-separated (default: by the profile's joint names).
    #[arg(long, value_name = "NAMES", value_delimiter = ',')]
    pub(crate) state_columns: Option<Vec<String>>,
    /// Action dimension d.
    #[arg(long, default_value_t = 2)]
    pub(crate) latent_dim: usize,
    /// Speed scale s in rad/s (default: 95th percentile of the demonstrated speed).
    #[arg(long)]
    pub(crate) speed_scale: Option<f64>,
    /// Model file to write.
    #[arg(long, value_name = "FILE")]
    pub(crate) out: PathBuf,
    /// Overwrite an existing model file (and its loss log and picture).
    #[arg(long)]
    pub(crate) force: bool,
    /// Epochs per seed (scl, cae).
    #[arg(long, default_value_t = 200)]
    pub(crate) epochs: usize,
    /// Seeds to train; the best by validation loss is kept (scl, cae).
    #[arg(long, default_value_t = 10)]
    pub(crate) seeds: usize,
    /// Seed of the first run; run i uses seed + i.
    #[arg(long, default_value_t = 0)]
    pub(crate) seed: u64,
    /// Seeds trained at once, one thread each (0: one per CPU).
    #[arg(long, default_value_t = 0)]
    pub(crate) threads: usize,
    /// Mini-batch size.
    #[arg(long, default_value_t = 256)]
    pub(crate) batch: usize,
    /// Adam learning rate.
    #[arg(long, default_value_t = 1e-3)]
    pub(crate) lr: f64,
    /// Hidden layer widths, comma-separated.
    #[arg(long, default_value = "256,256")]
    pub(crate) hidden: String,
    /// Lipschitz bound L of the decoder w.r.t. the raw (q, c) (default 1 for scl, none for
    /// cae).
    #[arg(long, conflicts_with = "no_lipschitz")]
    pub(crate) lipschitz: Option<f64>,
    /// Train the SCL decoder without a Lipschitz bound.
    #[arg(long)]
    pub(crate) no_lipschitz: bool,
    /// Power iterations per optimiser step of the Lipschitz projection.
    #[arg(long, default_value_t = 1)]
    pub(crate) power_iterations: usize,
    /// Train and serve SCL without Gram-Schmidt.
    #[arg(long)]
    pub(crate) no_gram_schmidt: bool,
    /// Training encoder: `mlp` (the paper's) or `projection` (a = H'^T qdot, scl only).
    #[arg(long, default_value = "mlp")]
    pub(crate) encoder: String,
    /// Decoder input: `q-c` (joint angles and gripper) or `q`.
    #[arg(long, default_value = "q-c")]
    pub(crate) inputs: String,
    /// Li et al. loss terms for cae, comma-separated: consistency, proportionality,
    /// reversibility.
    #[arg(long, value_name = "TERMS")]
    pub(crate) li_losses: Option<String>,
    /// Weight of each Li term.
    #[arg(long, default_value_t = 1.0)]
    pub(crate) li_weight: f64,
    /// Temperature gamma of the consistency term.
    #[arg(long, default_value_t = learning::train::li::DEFAULT_GAMMA)]
    pub(crate) li_gamma: f64,
    /// Sampling range of alpha in the proportionality term, `lo,hi`.
    #[arg(long, default_value = "0.1,1.0")]
    pub(crate) li_alpha: String,
    /// Time step (s) of the reversibility term's transition.
    #[arg(long, default_value_t = learning::train::li::DEFAULT_STEP_S)]
    pub(crate) li_step: f64,
    /// After training, check the model on one of the paper's tasks (table-cleaning,
    /// pick-and-place, pouring), as `scl eval capability` does, on `--robot`'s arm (default
    /// the default profile) with the default graph: the share of the task's generated
    /// training demonstrations the follower tracks to their end through the model, then the
    /// expert's successes from the study's start. Default: the task `--data`'s directory is
    /// named after (`scl demos --task T --out data/T`); no check for other data. A check
    /// only: the model kept is the best seed by validation loss, as in the paper.
    #[arg(long, value_name = "TASK", conflicts_with = "no_check")]
    pub(crate) check_task: Option<String>,
    /// The expert's attempts in the check (0: the follower only).
    #[arg(long, default_value_t = 2)]
    pub(crate) check_seeds: u64,
    /// No check after training.
    #[arg(long)]
    pub(crate) no_check: bool,
}

impl TrainArgs {
    /// How to read `--data` when it is a LeRobot dataset.
    pub(crate) fn lerobot(&self) -> learning::lerobot::import::ImportOptions {
        learning::lerobot::import::ImportOptions {
            robot: self.robot.clone(),
            state_columns: self.state_columns.clone(),
        }
    }

    /// The training configuration of a network kind.
    pub(crate) fn config(&self, kind: ModelKind) -> Result<TrainConfig, SclError> {
        use learning::cli::{parse_encoder, parse_inputs, parse_list};
        let mut li = match &self.li_losses {
            Some(list) => learning::train::li::parse_terms(list).map_err(|reason| {
                learning::cli::LearningError::Option {
                    option: "--li-losses",
                    reason,
                }
            })?,
            None => None,
        };
        if let Some(li) = &mut li {
            li.weight = self.li_weight;
            li.step_s = self.li_step;
            if li.consistency_gamma.is_some() {
                li.consistency_gamma = Some(self.li_gamma);
            }
            if li.proportionality_alpha.is_some() {
                let r: Vec<f64> = parse_list(&self.li_alpha, "--li-alpha")?;
                let [lo, hi] = r[..] else {
                    return Err(learning::cli::LearningError::Option {
                        option: "--li-alpha",
                        reason: format!("`{}`: expected two numbers `lo,hi`", self.li_alpha),
                    }
                    .into());
                };
                li.proportionality_alpha = Some([lo, hi]);
            }
        }
        Ok(TrainConfig {
            kind,
            latent_dim: self.latent_dim,
            hidden: parse_list(&self.hidden, "--hidden")?,
            epochs: self.epochs,
            batch: self.batch,
            learning_rate: self.lr,
            seeds: self.seeds,
            base_seed: self.seed,
            threads: self.threads,
            // The paper bounds the SCL decoder with L = 1; a CAE is bounded only when asked.
            lipschitz: match kind {
                _ if self.no_lipschitz => None,
                ModelKind::Scl => Some(self.lipschitz.unwrap_or(1.0)),
                _ => self.lipschitz,
            },
            power_iterations: self.power_iterations,
            gram_schmidt: kind == ModelKind::Scl && !self.no_gram_schmidt,
            encoder: parse_encoder(&self.encoder)?,
            inputs: parse_inputs(&self.inputs)?,
            speed_scale: self.speed_scale,
            li,
        })
    }
}

/// `scl demos`.
pub(crate) fn demos(args: DemosArgs) -> Result<ExitCode, SclError> {
    let DemosArgs {
        task,
        out,
        seed,
        n_train,
        n_val,
        plot,
        robot,
    } = args;
    learning::tools::demos(&task, robot, &out, seed, (n_train, n_val), plot.as_deref())?;
    Ok(ExitCode::SUCCESS)
}

/// `scl plot`.
pub(crate) fn plot(args: PlotArgs) -> Result<ExitCode, SclError> {
    let PlotArgs {
        data,
        out,
        title,
        font,
        force,
    } = args;
    learning::tools::plot(&data, &out, title.as_deref(), font.as_deref(), force)?;
    Ok(ExitCode::SUCCESS)
}

/// `scl train`.
pub(crate) fn train(t: &TrainArgs) -> Result<ExitCode, SclError> {
    let command = std::env::args().collect::<Vec<_>>().join(" ");
    match t.kind.as_str() {
        "pca" => {
            learning::tools::train_pca(&learning::tools::TrainOptions {
                data: &t.data,
                out: &t.out,
                latent_dim: t.latent_dim,
                speed_scale: t.speed_scale,
                force: t.force,
                command,
                lerobot: t.lerobot(),
            })?;
        }
        "scl" | "cae" => {
            let kind = if t.kind == "scl" {
                ModelKind::Scl
            } else {
                ModelKind::Cae
            };
            let cfg = t.config(kind)?;
            learning::cli::train_network(&cfg, &t.data, &t.lerobot(), &t.out, t.force, &command)?;
        }
        other => {
            return Err(SclError::Other(format!(
                "--kind {other}: expected pca, scl or cae"
            )));
        }
    }
    if let Some(task) = t.check_task()? {
        check_trained(t, task)?;
    }
    Ok(ExitCode::SUCCESS)
}

impl TrainArgs {
    /// The task the trained model is checked on: `--check-task`, else the one `--data` is
    /// named after; none with `--no-check`.
    pub(crate) fn check_task(&self) -> Result<Option<learning::tasks::Task>, SclError> {
        use learning::tasks::Task;
        if self.no_check {
            return Ok(None);
        }
        if let Some(name) = &self.check_task {
            return match Task::from_name(name) {
                Ok(Task::PlanarReach) | Err(_) => Err(SclError::Other(format!(
                    "--check-task {name}: expected table-cleaning, pick-and-place or pouring"
                ))),
                Ok(task) => Ok(Some(task)),
            };
        }
        Ok(self
            .data
            .file_name()
            .and_then(|n| n.to_str())
            .and_then(|n| Task::from_name(n).ok())
            .filter(|t| *t != Task::PlanarReach))
    }
}

/// `scl train`'s check of the model it wrote on `task`: the follower along the task's
/// demonstrations, then the expert from the study's start.
fn check_trained(t: &TrainArgs, task: learning::tasks::Task) -> Result<(), SclError> {
    let robot = match &t.robot {
        Some(name) => kinematics::RobotProfile::by_name(name).map_err(SclError::Robot)?,
        None => kinematics::RobotProfile::default_robot(),
    };
    let graph = scl_config::GraphConfig::for_robot(robot);
    let model = t.out.display().to_string();
    let mut operators = vec![("follower", 1)];
    if t.check_seeds > 0 {
        operators.push(("expert", t.check_seeds));
    }
    for (operator, seeds) in operators {
        println!(
            "check on {} ({operator}; `scl eval capability {model} --task {} --operator {operator}`):",
            task.name(),
            task.name()
        );
        let args = scl_study::CapabilityArgs {
            model: model.clone(),
            task: task.name().to_owned(),
            operator: operator.to_owned(),
            seeds,
            study: None,
            jobs: None,
            json: false,
        };
        scl_study::capability(robot, &graph, &args)?;
    }
    Ok(())
}

/// `scl import`.
pub(crate) fn import(args: ImportArgs) -> Result<ExitCode, SclError> {
    let ImportArgs {
        json,
        kind,
        joints,
        latent_dim,
        speed_scale,
        no_gram_schmidt,
        input_mean,
        input_std,
        out,
        force,
    } = args;
    use learning::cli::parse_list;
    let kind = match kind.as_str() {
        "scl" => ModelKind::Scl,
        "cae" => ModelKind::Cae,
        other => {
            return Err(SclError::Other(format!(
                "--kind {other}: expected scl or cae"
            )));
        }
    };
    if !(speed_scale.is_finite() && speed_scale > 0.0) {
        return Err(SclError::Other(format!(
            "--speed-scale {speed_scale}: expected a positive number (rad/s)"
        )));
    }
    let normalisation = match (input_mean, input_std) {
        (Some(m), Some(s)) => Some((
            parse_list(&m, "--input-mean")?,
            parse_list(&s, "--input-std")?,
        )),
        _ => None,
    };
    let opts = learning::import::ImportOptions {
        kind,
        n_joints: joints,
        latent_dim,
        speed_scale,
        gram_schmidt: !no_gram_schmidt,
        normalisation,
        command: std::env::args().collect::<Vec<_>>().join(" "),
    };
    learning::cli::import_weights(&json, &opts, &out, force)?;
    Ok(ExitCode::SUCCESS)
}

/// `scl eval EXPERIMENT`: exit code 1 when the theorem's inequality failed.
pub(crate) fn eval(what: EvalCmd, cfg: &scl_config::GraphConfig) -> Result<ExitCode, SclError> {
    let period_s = cfg.period_s();
    let command = std::env::args().collect::<Vec<_>>().join(" ");
    use learning::experiments as ex;
    let (out, verdict) = match what {
        EvalCmd::Reversibility(args) => {
            let o = ex::reversibility::run(&args, period_s, &command)?;
            let failed: Vec<_> = o.checks.iter().filter(|c| !c.holds).collect();
            (
                o.out,
                if failed.is_empty() {
                    "the expected shape holds".to_owned()
                } else {
                    format!("{} expected-shape statement(s) do not hold", failed.len())
                },
            )
        }
        EvalCmd::Theorem(args) => {
            let o = ex::theorem::run(&args, period_s, &command)?;
            if !o.theorem_holds {
                eprintln!(
                    "scl eval theorem: the inequality FAILED where the theorem applies (a bug); see {}",
                    o.out.join("summary.md").display()
                );
                return Ok(ExitCode::from(1));
            }
            (
                o.out,
                "the inequality held wherever the theorem applies".to_owned(),
            )
        }
        EvalCmd::Reconstruction(args) => {
            let o = ex::reconstruction::run(&args, &command)?;
            (o.out, format!("{} models evaluated", o.entries.len()))
        }
        EvalCmd::Capability(args) => {
            scl_study::capability(cfg.graph.profile()?, cfg, &args)?;
            return Ok(ExitCode::SUCCESS);
        }
        EvalCmd::GreedyUser(args) => {
            let o = ex::greedy_user::run(&args, &command)?;
            let failed = o.checks.iter().filter(|c| !c.holds).count();
            (
                o.out,
                if failed == 0 {
                    "the paper's statements hold".to_owned()
                } else {
                    format!("{failed} of the paper's statement(s) do not hold")
                },
            )
        }
    };
    eprintln!("{verdict}; summary: {}", out.join("summary.md").display());
    Ok(ExitCode::SUCCESS)
}
