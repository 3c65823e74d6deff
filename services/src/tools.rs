//! The offline tools: `scl demos` (generate demonstrations) and `scl train` (fit a model).

use std::path::Path;

use mapper::dataset;
use mapper::model::{self, FORMAT, ModelHeader, ModelKind, PCA_VERSION, TrainingInfo};
use mapper::pca;

use crate::SclError;

/// Generates the demonstrations of `task` into `out` (refusing to overwrite any file).
pub fn demos(
    task: &str,
    out: &Path,
    seed: u64,
    n_train: usize,
    n_val: usize,
) -> Result<usize, SclError> {
    let ds = match task {
        "joint-reach" => mapper::demos::joint_reach(n_train, n_val, seed),
        other => {
            return Err(SclError::Graph(format!(
                "unknown task `{other}`; available: joint-reach"
            )));
        }
    };
    let files = dataset::write_dir(out, &ds)?;
    let tuples = ds.n_train() + ds.n_val();
    eprintln!(
        "wrote {} trajectories ({} train / {} validation tuples) to {}",
        files.len(),
        ds.n_train(),
        ds.n_val(),
        out.display()
    );
    Ok(tuples)
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
}

/// Fits PCA on a data set and writes the model file. Returns the header written.
pub fn train_pca(o: &TrainOptions<'_>) -> Result<ModelHeader, SclError> {
    if o.out.exists() && !o.force {
        return Err(mapper::ModelError::Exists(o.out.to_owned()).into());
    }
    let ds = dataset::load_dir(o.data)?;
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
        return Err(SclError::Graph(format!(
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
            pca::BASIS_TENSOR,
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
