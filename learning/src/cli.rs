//! The learning tools: `scl train --kind scl|cae` (with a progress bar, a per-epoch loss log
//! and a loss-curve picture next to the model), `scl import` (weights trained elsewhere) and
//! `scl eval reconstruction | reversibility`.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::sync::atomic::{AtomicBool, Ordering};

use crate::dataset;
use crate::eval::{self, AnyModel};
use crate::import::{self, ImportOptions};
use crate::train::{self, Progress, SeedRun, TrainConfig, TrainOutcome};
use mapper::model::{self, EncoderKind, ModelKind, ObsInputs};
use mapper::rng::Rng;

use crate::ToolError;
use scl_signals as signals;

/// Why writing a training artefact failed.
#[derive(Debug, thiserror::Error)]
pub enum LearningError {
    /// A file could not be written.
    #[error("cannot write {path}: {source}")]
    Write {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// A companion file exists and overwriting was not asked for.
    #[error("{0} already exists; pass --force to overwrite it")]
    Exists(PathBuf),
    /// Drawing the loss curves failed.
    #[error("cannot draw {path}: {reason}")]
    Plot {
        /// The picture.
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
}

/// The per-epoch loss log written next to a model: `<model stem>.loss.csv`.
pub fn loss_log_path(model: &Path) -> PathBuf {
    model.with_extension("loss.csv")
}

/// The loss-curve picture written next to a model: `<model stem>.loss.png`.
pub fn loss_plot_path(model: &Path) -> PathBuf {
    model.with_extension("loss.png")
}

/// Parses a comma-separated list of numbers for `option`.
pub fn parse_list<T: std::str::FromStr>(
    text: &str,
    option: &'static str,
) -> Result<Vec<T>, LearningError> {
    text.split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse().map_err(|_| LearningError::Option {
                option,
                reason: format!("`{s}` is not a number"),
            })
        })
        .collect()
}

/// Parses `--inputs`: `q-c` (joint angles and gripper) or `q`.
pub fn parse_inputs(text: &str) -> Result<ObsInputs, LearningError> {
    match text {
        "q-c" | "qc" => Ok(ObsInputs::JointsAndGripper),
        "q" => Ok(ObsInputs::Joints),
        other => Err(LearningError::Option {
            option: "--inputs",
            reason: format!("`{other}`; expected `q-c` or `q`"),
        }),
    }
}

/// Parses `--encoder`: `mlp` or `projection`.
pub fn parse_encoder(text: &str) -> Result<EncoderKind, LearningError> {
    match text {
        "mlp" => Ok(EncoderKind::Mlp),
        "projection" => Ok(EncoderKind::Projection),
        other => Err(LearningError::Option {
            option: "--encoder",
            reason: format!("`{other}`; expected `mlp` or `projection`"),
        }),
    }
}

/// Trains a network model and writes it with its loss log and picture. Refuses to replace
/// any of the three files unless `force` (checked before training starts).
pub fn train_network(
    cfg: &TrainConfig,
    data: &Path,
    data_opts: &crate::lerobot::import::ImportOptions,
    out: &Path,
    force: bool,
    command: &str,
) -> Result<TrainOutcome, ToolError> {
    let log_path = loss_log_path(out);
    let plot_path = loss_plot_path(out);
    if !force {
        if out.exists() {
            return Err(mapper::ModelError::Exists(out.to_owned()).into());
        }
        for p in [&log_path, &plot_path] {
            if p.exists() {
                return Err(LearningError::Exists(p.clone()).into());
            }
        }
    }
    let ds = crate::lerobot::import::load_training_data(data, data_opts)?;
    tracing::info!(
        kind = %cfg.kind,
        train = ds.n_train(),
        val = ds.n_val(),
        seeds = cfg.seeds,
        epochs = cfg.epochs,
        "training"
    );
    let total = (cfg.seeds * cfg.epochs) as u64;
    let bar = indicatif::ProgressBar::new(total);
    if let Ok(style) = indicatif::ProgressStyle::with_template(
        "{elapsed_precise} [{bar:40}] {pos}/{len} seed-epochs  eta {eta}  {msg}",
    ) {
        bar.set_style(style.progress_chars("=> "));
    }
    let cancel = AtomicBool::new(false);
    let best = std::sync::Mutex::new(f64::INFINITY);
    let on_progress = |p: &Progress| {
        let Progress::Epoch { val_loss, .. } = p;
        bar.inc(1);
        if let Some(v) = val_loss
            && let Ok(mut b) = best.lock()
            && *v < *b
        {
            *b = *v;
            bar.set_message(format!("best val {v:.3e} (rad/s)²"));
        }
        if signals::stop_requested() {
            cancel.store(true, Ordering::Relaxed);
        }
    };
    let outcome = train::train(cfg, &ds, command, &on_progress, &cancel)?;
    bar.finish();
    if cancel.load(Ordering::Relaxed) {
        eprintln!("interrupted: keeping the best weights trained so far");
    }
    let bytes = outcome.model.to_bytes()?;
    model::write_file(out, &bytes, force)?;
    // Read it back through the same checks the mapper applies.
    model::LoadedModel::load(&out.display().to_string())?;
    write_loss_log(&log_path, &outcome.runs)?;
    plot_losses(&plot_path, &outcome.runs, outcome.best_index, cfg.kind)?;
    let best_run = &outcome.runs[outcome.best_index];
    eprintln!(
        "{} d={} on {} tuples: {} seeds in {:.1} s; best seed {} (epoch {}), validation MSE {}{} -> {}",
        cfg.kind,
        cfg.latent_dim,
        ds.n_train(),
        outcome.runs.len(),
        outcome.train_seconds,
        best_run.seed,
        best_run.best_epoch,
        outcome
            .validation_loss
            .map_or("n/a (no val/)".into(), |l| format!("{l:.3e} (rad/s)²")),
        outcome
            .model
            .header()
            .lipschitz_bound
            .map_or(String::new(), |l| format!("; Lipschitz bound {l}")),
        out.display()
    );
    eprintln!(
        "loss log {}, curves {}",
        log_path.display(),
        plot_path.display()
    );
    Ok(outcome)
}

/// One row of the loss log.
#[derive(serde::Serialize)]
struct LossRow {
    seed: u64,
    epoch: usize,
    #[serde(serialize_with = "crate::table::sci")]
    train_loss: f64,
    #[serde(serialize_with = "crate::table::sci_opt")]
    val_loss: Option<f64>,
}

/// Writes `seed,epoch,train_loss,val_loss` rows ((rad/s)²; empty `val_loss` without a
/// validation split).
pub fn write_loss_log(path: &Path, runs: &[SeedRun]) -> Result<(), LearningError> {
    let rows = runs.iter().flat_map(|r| {
        r.history.iter().map(|e| LossRow {
            seed: r.seed,
            epoch: e.epoch,
            train_loss: e.train_loss,
            val_loss: e.val_loss,
        })
    });
    let err = |source| LearningError::Write {
        path: path.to_owned(),
        source,
    };
    let text = crate::table::to_csv_or_header("seed,epoch,train_loss,val_loss", rows)
        .map_err(|e| err(e.into()))?;
    std::fs::write(path, text).map_err(err)
}

/// Registers a system sans-serif font with the plotting library, once; `false` when none of
/// the usual font files exists (the picture is then drawn without text).
fn font_available() -> bool {
    static FONT: OnceLock<bool> = OnceLock::new();
    *FONT.get_or_init(|| {
        const CANDIDATES: [&str; 4] = [
            "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
            "/usr/share/fonts/TTF/DejaVuSans.ttf",
            "/usr/share/fonts/dejavu/DejaVuSans.ttf",
            "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
        ];
        for c in CANDIDATES {
            if let Ok(bytes) = std::fs::read(c) {
                // The plotting library keeps fonts for the life of the process.
                let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
                if plotters::style::register_font(
                    "sans-serif",
                    plotters::style::FontStyle::Normal,
                    bytes,
                )
                .is_ok()
                {
                    return true;
                }
            }
        }
        false
    })
}

/// Draws the loss curves as a PNG: every seed's validation loss (thin grey), the kept seed's
/// training (blue) and validation (red) loss, log scale. Axis labels when a system font is
/// found.
pub fn plot_losses(
    path: &Path,
    runs: &[SeedRun],
    best: usize,
    kind: ModelKind,
) -> Result<(), LearningError> {
    use plotters::prelude::*;
    let (w, h) = (900u32, 560u32);
    let mut buf = vec![0u8; (w * h * 3) as usize];
    let perr = |e: &dyn std::fmt::Display| LearningError::Plot {
        path: path.to_owned(),
        reason: e.to_string(),
    };
    let text = font_available();
    let epochs = runs
        .iter()
        .map(|r| r.history.len())
        .max()
        .unwrap_or(1)
        .max(2);
    let values = runs
        .iter()
        .flat_map(|r| {
            r.history
                .iter()
                .flat_map(|e| [Some(e.train_loss), e.val_loss])
        })
        .flatten()
        .filter(|v| v.is_finite() && *v > 0.0);
    let (lo, hi) = values.fold((f64::INFINITY, 0.0f64), |(lo, hi), v| {
        (lo.min(v), hi.max(v))
    });
    let (lo, hi) = if lo < hi {
        (lo * 0.8, hi * 1.25)
    } else {
        (1e-6, 1.0)
    };
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| perr(&e))?;
        let mut builder = ChartBuilder::on(&root);
        builder.margin(16);
        if text {
            builder
                .caption(
                    format!("{kind}: loss per epoch (grey: validation of every seed; red / blue: kept seed's validation / training)"),
                    ("sans-serif", 15),
                )
                .x_label_area_size(40)
                .y_label_area_size(80);
        }
        let mut chart = builder
            .build_cartesian_2d(1f64..epochs as f64, (lo..hi).log_scale())
            .map_err(|e| perr(&e))?;
        let mut mesh = chart.configure_mesh();
        let integer = |x: &f64| format!("{x:.0}");
        if text {
            mesh.x_desc("epoch")
                .y_desc("MSE (rad/s)²")
                .x_label_formatter(&integer);
        } else {
            mesh.x_labels(0).y_labels(0);
        }
        mesh.draw().map_err(|e| perr(&e))?;
        let grey = RGBColor(190, 190, 190);
        for r in runs {
            let pts = r
                .history
                .iter()
                .filter_map(|e| e.val_loss.map(|v| (e.epoch as f64, v)));
            chart
                .draw_series(LineSeries::new(pts, grey.stroke_width(1)))
                .map_err(|e| perr(&e))?;
        }
        if let Some(r) = runs.get(best) {
            let train = r.history.iter().map(|e| (e.epoch as f64, e.train_loss));
            chart
                .draw_series(LineSeries::new(train, BLUE.stroke_width(2)))
                .map_err(|e| perr(&e))?;
            let val = r
                .history
                .iter()
                .filter_map(|e| e.val_loss.map(|v| (e.epoch as f64, v)));
            chart
                .draw_series(LineSeries::new(val, RED.stroke_width(2)))
                .map_err(|e| perr(&e))?;
        }
        root.present().map_err(|e| perr(&e))?;
    }
    let file = std::fs::File::create(path).map_err(|source| LearningError::Write {
        path: path.to_owned(),
        source,
    })?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), w, h);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut writer = enc.write_header().map_err(|e| perr(&e))?;
    writer.write_image_data(&buf).map_err(|e| perr(&e))?;
    writer.finish().map_err(|e| perr(&e))
}

/// `scl import`: builds a model file from the authors' JSON weights.
pub fn import_weights(
    json: &Path,
    opts: &ImportOptions,
    out: &Path,
    force: bool,
) -> Result<(), ToolError> {
    if out.exists() && !force {
        return Err(mapper::ModelError::Exists(out.to_owned()).into());
    }
    let model = import::import_file(json, opts)?;
    let bytes = model.to_bytes()?;
    model::write_file(out, &bytes, force)?;
    model::LoadedModel::load(&out.display().to_string())?;
    eprintln!(
        "imported {} ({} joints, d={}, hidden {:?}, Lipschitz bound of the decoder {:.3}) -> {}",
        json.display(),
        opts.n_joints,
        opts.latent_dim,
        model.info().hidden,
        model.header().lipschitz_bound.unwrap_or(f64::NAN),
        out.display()
    );
    Ok(())
}

/// `scl eval reconstruction`: the validation reconstruction MSE of each model on `data`'s
/// validation split (or its training split when it has none), as a Markdown table.
pub fn eval_reconstruction(data: &Path, models: &[PathBuf]) -> Result<String, ToolError> {
    let ds = dataset::load_dir(data)?;
    let (split, trajs) = if ds.val.is_empty() {
        ("train", &ds.train)
    } else {
        ("val", &ds.val)
    };
    let n: usize = trajs.iter().map(|t| t.len()).sum();
    let mut s = format!(
        "Reconstruction MSE of qdot on {} ({split} split, {n} tuples, data hash {}):\n\n",
        data.display(),
        ds.hash
    );
    s.push_str(
        "| model | kind | d | settings | MSE (rad/s)² | trained on |\n|---|---|---|---|---|---|\n",
    );
    for p in models {
        let m = AnyModel::load(p)?;
        let mse = eval::reconstruction_mse(&m, p, trajs)?;
        let h = m.header();
        let settings = match &h.network {
            None => "-".to_owned(),
            Some(net) => {
                let mut parts = vec![format!("hidden {:?}", net.hidden)];
                if h.kind == ModelKind::Scl {
                    parts.push(if net.gram_schmidt {
                        "GS".into()
                    } else {
                        "no GS".into()
                    });
                }
                parts.push(format!("encoder {:?}", net.encoder).to_lowercase());
                if let Some(l) = h.lipschitz_bound {
                    parts.push(format!("L {l:.3}"));
                }
                if let Some(li) = &net.li_losses {
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
                    parts.push(format!("Li: {}", t.join("+")));
                }
                if let Some(st) = &h.training.settings {
                    parts.push(format!("{} ep x {} seeds", st.epochs, st.seeds));
                }
                parts.join(", ")
            }
        };
        let same = if h.training.data_hash == ds.hash {
            "this data".to_owned()
        } else if h.training.data_hash.is_empty() {
            "unknown".to_owned()
        } else {
            format!("other ({})", h.training.data_hash)
        };
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {:.4e} | {} |",
            p.file_name().map_or_else(
                || p.display().to_string(),
                |f| f.to_string_lossy().into_owned()
            ),
            h.kind,
            h.latent_dim,
            settings,
            mse,
            same
        );
    }
    Ok(s)
}

/// `scl eval reversibility`: the soft-reversibility experiments (see `crate::eval`) on a
/// model, at states from `data` (when given) and uniform in the joint limits, with the
/// transition of one control period `Δ = period_s` and the paper's literal `T` (`Δ·s = 1`).
pub fn eval_reversibility(
    model: &Path,
    data: Option<&Path>,
    samples: usize,
    seed: u64,
    period_s: f64,
) -> Result<String, ToolError> {
    let m = AnyModel::load(model)?;
    let h = m.header().clone();
    let mut rng = Rng::new(seed);
    let mut sets: Vec<(&str, eval::States)> = Vec::new();
    if let Some(dir) = data {
        let ds = dataset::load_dir(dir)?;
        let trajs: Vec<_> = ds.train.iter().chain(&ds.val).cloned().collect();
        sets.push((
            "data states",
            eval::states_from_data(&trajs, samples, &mut rng),
        ));
    }
    let (lo, hi): (Vec<f64>, Vec<f64>) = if h.n_joints == kinematics::gen3_lite::N_JOINTS {
        let l = kinematics::gen3_lite::limits();
        (l.lower_rad, l.upper_rad)
    } else {
        (
            vec![-std::f64::consts::PI; h.n_joints],
            vec![std::f64::consts::PI; h.n_joints],
        )
    };
    sets.push((
        "uniform in limits",
        eval::states_uniform(&lo, &hi, samples, &mut rng),
    ));
    let s = h.speed_scale_rad_s;
    let ticks = (1.0 / period_s).round().max(1.0) as usize;
    let mut out = format!(
        "Soft reversibility of {} ({}, d={}, Gram-Schmidt {}, Lipschitz bound {}), |a| uniform in [0, 1), seed {seed}:\n\n",
        model.display(),
        h.kind,
        h.latent_dim,
        h.network.as_ref().is_some_and(|n| n.gram_schmidt),
        h.lipschitz_bound
            .map_or("none".into(), |l| format!("{l:.3}")),
    );
    out.push_str("| states | transition | n | one step: held | mean ratio | worst ratio | a then -a for 1 s: held | mean ratio | worst ratio |\n|---|---|---|---|---|---|---|---|---|\n");
    for (name, states) in &sets {
        for (label, step, reps) in [
            (format!("q + {period_s} s * s * map"), period_s * s, ticks),
            ("q + map (paper's T)".to_owned(), 1.0, ticks),
        ] {
            let mut map = m.map();
            let r = eval::reversibility(map.as_mut(), states, step, reps, 1.0, &mut rng);
            let _ = writeln!(
                out,
                "| {name} | {label} | {} | {:.2} % | {:.3} | {:.3} | {:.2} % | {:.3} | {:.3} |",
                r.one_step.total,
                100.0 * r.one_step.value(),
                r.one_step.mean_ratio,
                r.one_step.worst_ratio,
                100.0 * r.repeated.value(),
                r.repeated.mean_ratio,
                r.repeated.worst_ratio,
            );
        }
    }
    out.push_str("\nratio = |q_back - q_0| / |q_forward - q_0|; held = ratio < 1. Trials whose forward action did not move the arm are not counted.\n");
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp_dir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("scl-learning-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        d
    }

    #[test]
    fn train_writes_model_log_and_picture_and_refuses_to_overwrite() {
        let dir = temp_dir("train");
        let data = dir.join("data");
        dataset::write_dir(&data, &crate::demos::joint_reach(2, 1, 3)).unwrap();
        let out = dir.join("m.safetensors");
        let cfg = TrainConfig {
            hidden: vec![8, 8],
            epochs: 3,
            seeds: 2,
            ..TrainConfig::default()
        };
        let outcome = train_network(
            &cfg,
            &data,
            &Default::default(),
            &out,
            false,
            "scl train test",
        )
        .unwrap();
        let model = model::LoadedModel::load(out.to_str().unwrap()).unwrap();
        assert_eq!(model.header.kind, ModelKind::Scl);
        assert_eq!(model.header.training.command, "scl train test");
        let log = std::fs::read_to_string(loss_log_path(&out)).unwrap();
        let lines: Vec<&str> = log.lines().collect();
        assert_eq!(lines[0], "seed,epoch,train_loss,val_loss");
        assert_eq!(lines.len(), 1 + 2 * 3);
        assert!(lines[1].starts_with("0,1,"));
        let png = std::fs::read(loss_plot_path(&out)).unwrap();
        assert_eq!(&png[1..4], b"PNG");
        assert_eq!(outcome.runs.len(), 2);
        // Every file is protected without --force, and replaced with it.
        let e = train_network(&cfg, &data, &Default::default(), &out, false, "t").unwrap_err();
        assert!(e.to_string().contains("--force"), "{e}");
        std::fs::remove_file(&out).unwrap();
        let e = train_network(&cfg, &data, &Default::default(), &out, false, "t").unwrap_err();
        assert!(e.to_string().contains("loss.csv"), "{e}");
        train_network(&cfg, &data, &Default::default(), &out, true, "t").unwrap();
        // The table and the reversibility report run on the result.
        let table = eval_reconstruction(&data, std::slice::from_ref(&out)).unwrap();
        assert!(table.contains("| m.safetensors | scl | 2 |"), "{table}");
        assert!(table.contains("this data"), "{table}");
        let rev = eval_reversibility(&out, Some(&data), 20, 1, 0.025).unwrap();
        assert!(
            rev.contains("data states") && rev.contains("uniform in limits"),
            "{rev}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn option_parsers_name_the_option() {
        assert_eq!(
            parse_list::<usize>("256, 128", "--hidden").unwrap(),
            vec![256, 128]
        );
        let e = parse_list::<usize>("256,x", "--hidden")
            .unwrap_err()
            .to_string();
        assert!(e.contains("--hidden") && e.contains("`x`"), "{e}");
        assert_eq!(parse_inputs("q").unwrap(), ObsInputs::Joints);
        assert!(
            parse_inputs("qq")
                .unwrap_err()
                .to_string()
                .contains("--inputs")
        );
        assert_eq!(
            parse_encoder("projection").unwrap(),
            EncoderKind::Projection
        );
        assert!(
            parse_encoder("x")
                .unwrap_err()
                .to_string()
                .contains("--encoder")
        );
    }
}
