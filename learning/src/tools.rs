//! The offline tools: `scl demos` (generate demonstrations), `scl train` (fit a model) and
//! `scl plot` (draw demonstrations' TCP paths).

use std::path::Path;

use crate::dataset;
use crate::pca;
use crate::tasks::Task;
use mapper::model::{self, FORMAT, ModelHeader, ModelKind, PCA_VERSION, TrainingInfo};

use crate::ToolError;
use crate::plot;

/// Task names `scl demos --task` accepts.
pub const DEMO_TASKS: &str = "joint-reach, table-cleaning, pick-and-place, pouring, planar-reach";

/// Generates the demonstrations of `task` into `out` (refusing to overwrite any file) and,
/// with `plot`, draws their TCP paths to that PNG (refused up front if it exists).
/// Trajectory counts default to the task's (the paper's for its tasks; 6 / 2 for
/// joint-reach). The Cartesian tasks are made on `robot`'s arm; joint-reach and planar-reach
/// have their own arms (the Gen3 lite, the planar 5-DOF arm), and refuse another `robot`.
/// Returns the data set written.
pub fn demos(
    task: &str,
    robot: &'static kinematics::RobotProfile,
    out: &Path,
    seed: u64,
    (n_train, n_val): (Option<usize>, Option<usize>),
    plot: Option<&Path>,
) -> Result<dataset::Dataset, ToolError> {
    if let Some(png) = plot
        && png.exists()
    {
        return Err(plot::PlotError::Exists(png.to_owned()).into());
    }
    let own_arm = |task: &'static str| {
        if robot.name() == kinematics::RobotProfile::default_name() {
            Ok(())
        } else {
            Err(crate::tasks::TaskError::Robot {
                task,
                robot: robot.name().to_owned(),
                reason: "it has its own arm; leave --robot out",
            })
        }
    };
    let ds = if task == "joint-reach" {
        own_arm("joint-reach")?;
        crate::demos::joint_reach(n_train.unwrap_or(6), n_val.unwrap_or(2), seed)
    } else {
        let t = Task::from_name(task)?;
        if t == Task::PlanarReach {
            own_arm(t.name())?;
        }
        let (dt, dv) = t.default_counts();
        crate::tasks::generate_for(t, robot, n_train.unwrap_or(dt), n_val.unwrap_or(dv), seed)?
    };
    let meta = crate::demos::DemosMeta {
        task: task.to_owned(),
        robot: robot.name().to_owned(),
        seed,
    };
    let meta_path = out.join(crate::demos::DEMOS_META);
    if meta_path.exists() {
        return Err(dataset::DatasetError::Exists(meta_path).into());
    }
    let files = dataset::write_dir(out, &ds)?;
    meta.write(out)?;
    eprintln!(
        "wrote {} trajectories ({} train / {} validation tuples) to {}",
        files.len(),
        ds.n_train(),
        ds.n_val(),
        out.display()
    );
    if let Some(png) = plot {
        plot_dataset(&ds, task, png, None, None, false)?;
    }
    Ok(ds)
}

/// Draws the TCP paths of the data set at `data` (a directory or a CSV / JSON file) to the
/// PNG `out`. `title` defaults to the data's name and counts; `font` to a system font.
pub fn plot(
    data: &Path,
    out: &Path,
    title: Option<&str>,
    font: Option<&Path>,
    force: bool,
) -> Result<(), ToolError> {
    let ds = dataset::load(data)?;
    let name = data.file_name().map_or_else(
        || data.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    );
    plot_dataset(&ds, &name, out, title, font, force)
}

/// Draws an already loaded data set (see [`plot`]).
pub fn plot_dataset(
    ds: &dataset::Dataset,
    name: &str,
    out: &Path,
    title: Option<&str>,
    font: Option<&Path>,
    force: bool,
) -> Result<(), ToolError> {
    if out.exists() && !force {
        return Err(plot::PlotError::Exists(out.to_owned()).into());
    }
    let text = plot::load_font(font)?.is_some();
    if !text {
        tracing::warn!(
            "no font found (tried {}); drawing without text, pass --font FILE.ttf for labels",
            plot::FONT_CANDIDATES.join(", ")
        );
    }
    let title = title.map_or_else(|| plot::title_for(name, ds), str::to_owned);
    let rgb = plot::render(ds, &title, text)?;
    plot::write_png(out, &rgb, force)?;
    eprintln!(
        "drew {} trajectories to {}",
        ds.train.len() + ds.val.len(),
        out.display()
    );
    Ok(())
}

/// What `scl train` fits.
#[derive(Debug, Clone)]
pub struct TrainOptions<'a> {
    /// The data set directory.
    pub data: &'a Path,
    /// The model file to write.
    pub out: &'a Path,
    /// Action dimension d.
    pub latent_dim: usize,
    /// Speed scale (rad/s); from the data when `None`.
    pub speed_scale: Option<f64>,
    /// Replace an existing model file.
    pub force: bool,
    /// The command line, recorded in the header.
    pub command: String,
    /// How to read `data` when it is a LeRobot dataset.
    pub lerobot: crate::lerobot::import::ImportOptions,
}

/// Fits PCA on a data set and writes the model file. Returns the header written.
pub fn train_pca(o: &TrainOptions<'_>) -> Result<ModelHeader, ToolError> {
    if o.out.exists() && !o.force {
        return Err(mapper::ModelError::Exists(o.out.to_owned()).into());
    }
    let ds = crate::lerobot::import::load_training_data(o.data, &o.lerobot)?;
    let train = ds.train_qdot();
    let m = train.first().map_or(0, Vec::len);
    let map = pca::fit(&train, o.latent_dim)?;
    let val = ds.val_qdot();
    let validation_loss = (!val.is_empty()).then(|| pca::reconstruction_mse(&map, &val));
    // Default speed scale: the 95th percentile of the demonstrated joint speed (norm), so a
    // full deflection moves about as fast as the demonstrator did.
    let speed = match o.speed_scale {
        Some(s) => s,
        None => {
            let mut norms: Vec<f64> = train
                .iter()
                .map(|r| r.iter().map(|v| v * v).sum::<f64>().sqrt())
                .collect();
            norms.sort_by(f64::total_cmp);
            norms[((norms.len() as f64 * 0.95) as usize).min(norms.len() - 1)]
        }
    };
    if !(speed.is_finite() && speed > 0.0) {
        return Err(ToolError::Graph(format!(
            "speed scale {speed} is not a positive number (are the demonstrations standing still?)"
        )));
    }
    let names: Vec<String> = if m == kinematics::gen3_lite::N_JOINTS {
        kinematics::gen3_lite::JOINT_NAMES
            .iter()
            .map(|s| (*s).to_owned())
            .collect()
    } else {
        (0..m).map(|i| format!("joint_{}", i + 1)).collect()
    };
    let header = ModelHeader {
        format: FORMAT.into(),
        version: PCA_VERSION,
        kind: ModelKind::Pca,
        n_joints: m,
        latent_dim: o.latent_dim,
        joint_names: names,
        speed_scale_rad_s: speed,
        lipschitz_bound: None,
        network: None,
        training: TrainingInfo {
            data_hash: ds.hash.clone(),
            n_train: ds.n_train(),
            n_val: ds.n_val(),
            validation_loss,
            seed: 0,
            command: o.command.clone(),
            settings: None,
        },
    };
    let bytes = model::to_bytes(
        &header,
        &[(
            mapper::pca::BASIS_TENSOR,
            vec![m, o.latent_dim],
            map.basis_row_major_f32(),
        )],
    )?;
    model::write_file(o.out, &bytes, o.force)?;
    // Read it back through the same checks the mapper applies.
    model::LoadedModel::load(&o.out.display().to_string())?;
    eprintln!(
        "PCA d={} on {} tuples: validation MSE {} ; speed scale {:.3} rad/s -> {}",
        o.latent_dim,
        ds.n_train(),
        validation_loss.map_or("n/a (no val/)".into(), |l| format!("{l:.3e} (rad/s)²")),
        speed,
        o.out.display()
    );
    Ok(header)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lite() -> &'static kinematics::RobotProfile {
        kinematics::RobotProfile::default_robot()
    }

    fn tmp(name: &str) -> std::path::PathBuf {
        let d = std::env::temp_dir().join(format!("scl-tools-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        d
    }

    #[test]
    fn demos_default_counts_per_task() {
        let d = tmp("defaults");
        let ds = demos("joint-reach", lite(), &d.join("jr"), 1, (None, None), None).unwrap();
        assert_eq!((ds.train.len(), ds.val.len()), (6, 2));
        let ds = demos(
            "table-cleaning",
            lite(),
            &d.join("tc"),
            1,
            (None, None),
            None,
        )
        .unwrap();
        assert_eq!((ds.train.len(), ds.val.len()), (3, 2));
        // The paper's counts at its pace, stretched into the arm's envelope.
        assert!(ds.n_train() >= 509, "{}", ds.n_train());
        // Read back through the loader: the same tuples.
        let back = dataset::load(&d.join("tc")).unwrap();
        assert_eq!(back.n_train(), ds.n_train());
        assert_eq!(back.train.len(), 3);
        let e = demos("juggling", lite(), &d.join("x"), 1, (None, None), None).unwrap_err();
        assert!(e.to_string().starts_with("unknown task `juggling`"), "{e}");
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn demos_with_a_plot_and_no_overwrites() {
        let d = tmp("plot");
        let png = d.join("p.png");
        demos(
            "planar-reach",
            lite(),
            &d.join("pr"),
            2,
            (Some(3), Some(1)),
            Some(&png),
        )
        .unwrap();
        assert!(png.is_file());
        // The PNG exists: refused before anything is generated or written.
        let e = demos(
            "planar-reach",
            lite(),
            &d.join("pr2"),
            2,
            (Some(3), Some(1)),
            Some(&png),
        );
        assert!(matches!(
            e,
            Err(ToolError::Plot(plot::PlotError::Exists(_)))
        ));
        assert!(!d.join("pr2").exists());
        // The data exist: refused.
        assert!(matches!(
            demos(
                "planar-reach",
                lite(),
                &d.join("pr"),
                2,
                (Some(3), Some(1)),
                None
            ),
            Err(ToolError::Dataset(dataset::DatasetError::Exists(_)))
        ));
        // scl plot on the written data; --force replaces.
        plot(&d.join("pr"), &png, Some("t"), None, true).unwrap();
        assert!(plot(&d.join("pr"), &png, None, None, false).is_err());
        std::fs::remove_dir_all(&d).unwrap();
    }
}
