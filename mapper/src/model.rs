//! The model file: weights in safetensors, a JSON [`ModelHeader`] in the file's metadata under
//! the key [`HEADER_KEY`].
//!
//! A file is checked completely when it is loaded (format, version, kind, shapes, finiteness,
//! agreement between header and tensors), so a bad file is an error at start-up and never at
//! tick time. The reader dispatches on [`ModelHeader::kind`].
//!
//! Versions: 1 is PCA only (a `basis` tensor). Version 2 adds [`ModelHeader::network`] (the
//! architecture and input normalisation of the SCL and CAE networks, whose tensors are
//! `decoder.{l}.weight` / `.bias` and, when trained here, `encoder.{l}.*`; see
//! [`crate::network`]) and [`TrainingInfo::settings`]. PCA files are still written as version
//! 1, byte for byte as before, so older readers keep loading them.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use safetensors::tensor::{Dtype, SafeTensors, TensorView};
use serde::{Deserialize, Serialize};

use crate::ActionMap;
use crate::network::NetworkModel;
use crate::pca::PcaMap;

/// Metadata key that holds the JSON header.
pub const HEADER_KEY: &str = "scl";
/// Value of [`ModelHeader::format`].
pub const FORMAT: &str = "scl-model";
/// Highest header version this reader understands.
pub const VERSION: u32 = 2;
/// The version written for PCA files (which need nothing newer).
pub const PCA_VERSION: u32 = 1;

/// The model bundled into the `scl` binary: SCL (the paper's defaults, speed scale 0.6 rad/s)
/// trained on the generated pick-and-place demonstrations in `data/pick-and-place`
/// (regenerate with `scripts/regenerate-bundled-model.sh`).
pub const BUNDLED: &[u8] = include_bytes!("../../models/default.safetensors");
/// The name by which configs and the CLI refer to [`BUNDLED`].
pub const BUNDLED_NAME: &str = "bundled";

/// Whether `spec` names a map built into the binary ([`BUNDLED_NAME`], the mode-switching
/// spec, the drill map's spec) rather than a file, so configs and clients leave it as it is
/// instead of resolving it as a path.
pub fn is_builtin(spec: &str) -> bool {
    spec == BUNDLED_NAME
        || crate::modeswitch::is_spec(spec)
        || crate::constant::is_spec(spec)
        || crate::goto::is_spec(spec)
}

/// The kind of map a file holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ModelKind {
    /// Principal component analysis: a constant orthonormal basis.
    Pca,
    /// State-conditioned linear map (the paper's method).
    Scl,
    /// Conditional autoencoder decoder.
    Cae,
    /// Cartesian mode switching ([`crate::modeswitch`]): header only, no tensors.
    ModeSwitch,
    /// The drill map ([`crate::constant`]): one joint velocity, served from its spec only.
    Constant,
    /// The go-to map ([`crate::goto`]): drives to a pose, served from its spec only.
    Goto,
}

impl std::fmt::Display for ModelKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Pca => "pca",
            Self::Scl => "scl",
            Self::Cae => "cae",
            Self::ModeSwitch => "modeswitch",
            Self::Constant => "constant",
            Self::Goto => "goto",
        })
    }
}

/// Where a model came from: enough to reproduce it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct TrainingInfo {
    /// FNV-1a 64 hash of the training files' bytes, hex.
    pub data_hash: String,
    /// Tuples used for fitting.
    pub n_train: usize,
    /// Tuples used for validation.
    pub n_val: usize,
    /// Mean squared reconstruction error of `qdot` on the validation tuples ((rad/s)²).
    pub validation_loss: Option<f64>,
    /// Seed of the run.
    pub seed: u64,
    /// The command that produced the file.
    pub command: String,
    /// How a network was trained (version 2; absent for PCA).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub settings: Option<TrainSettings>,
}

/// The optimisation settings and outcome of a network's training run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainSettings {
    /// Epochs per seed.
    pub epochs: usize,
    /// Mini-batch size.
    pub batch: usize,
    /// Adam learning rate.
    pub learning_rate: f64,
    /// Seeds trained; the file holds the best by validation loss.
    pub seeds: usize,
    /// Epoch (1-based) of the kept weights: the best validation loss of the best seed.
    pub best_epoch: usize,
    /// Power iterations per optimiser step of the Lipschitz projection (0: none).
    pub power_iterations: usize,
    /// Wall time of the training (all seeds), seconds.
    pub train_seconds: f64,
}

/// What the network conditions on (its observation input, before normalisation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ObsInputs {
    /// Joint angles and gripper state `(q, c)`: `m + 1` values.
    JointsAndGripper,
    /// Joint angles only: `m` values (the paper's `h: R^m -> R^{m×d}`).
    Joints,
}

impl ObsInputs {
    /// Number of observation values for an `m`-joint arm.
    pub fn width(self, m: usize) -> usize {
        match self {
            Self::JointsAndGripper => m + 1,
            Self::Joints => m,
        }
    }
}

/// How the training encoder produced the latent action.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EncoderKind {
    /// An MLP `f(o, qdot) -> a`, stored as `encoder.*` tensors (the paper's method).
    Mlp,
    /// The analytic `a = H'ᵀ qdot` (SCL only): no parameters.
    Projection,
    /// No encoder in the file (weights imported from elsewhere).
    None,
}

/// The Li et al. (2020) loss terms a CAE was trained with (see [`crate::train::li`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LiLosses {
    /// Consistency, with this temperature `γ`.
    pub consistency_gamma: Option<f64>,
    /// Proportionality, with `α` drawn uniformly from this range.
    pub proportionality_alpha: Option<[f64; 2]>,
    /// Reversibility.
    pub reversibility: bool,
    /// Weight of each term added to the reconstruction loss.
    pub weight: f64,
    /// Time step (s) of the transition `T(q, a) = q + step · s · g(o, a)` in the
    /// reversibility term.
    pub step_s: f64,
}

/// Architecture and input preprocessing of a network model (SCL or CAE).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NetworkInfo {
    /// The observation the decoder conditions on.
    pub inputs: ObsInputs,
    /// Mean subtracted from the observation before the network (rad; 1 for `c`).
    pub input_mean: Vec<f64>,
    /// Scale the observation is divided by after the mean (strictly positive).
    pub input_std: Vec<f64>,
    /// Hidden layer widths of the decoder (and encoder).
    pub hidden: Vec<usize>,
    /// Orthonormalise `H`'s columns (SCL only).
    pub gram_schmidt: bool,
    /// The guard `ε` of the Gram-Schmidt normalisation.
    pub gs_epsilon: f64,
    /// The training encoder.
    pub encoder: EncoderKind,
    /// Mean of the encoder's raw input `(o, qdot)` (empty without an MLP encoder).
    #[serde(default)]
    pub encoder_input_mean: Vec<f64>,
    /// Scale of the encoder's raw input.
    #[serde(default)]
    pub encoder_input_std: Vec<f64>,
    /// Li et al. loss terms (CAE only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub li_losses: Option<LiLosses>,
}

/// The JSON header of a model file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelHeader {
    /// Always [`FORMAT`].
    pub format: String,
    /// Header version, at most [`VERSION`].
    pub version: u32,
    /// Model kind.
    pub kind: ModelKind,
    /// Output joints `m`.
    pub n_joints: usize,
    /// Action dimension `d`.
    pub latent_dim: usize,
    /// Joint names, in output order.
    pub joint_names: Vec<String>,
    /// Speed scale `s` (rad/s): `qdot = s * map(o, a)`, so a full deflection of an
    /// orthonormal map moves the joints at `s` in norm. Finite, above 0 and at most
    /// [`max_speed_scale_rad_s`] of the robot served.
    #[serde(deserialize_with = "speed_scale")]
    pub speed_scale_rad_s: f64,
    /// Lipschitz bound of the decoder network with respect to the raw observation, where one
    /// was enforced (certified from the exact spectral norms after training).
    #[serde(default)]
    pub lipschitz_bound: Option<f64>,
    /// The network of an SCL or CAE model (version 2; absent for PCA).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub network: Option<NetworkInfo>,
    /// Provenance.
    #[serde(default)]
    pub training: TrainingInfo,
}

/// Reads `speed_scale_rad_s`, naming it when it is `null` (how JSON writers store a NaN or an
/// infinity), where serde's own message would name only the type.
fn speed_scale<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Option::<f64>::deserialize(d)?.ok_or_else(|| {
        serde::de::Error::custom(
            "speed_scale_rad_s is null (a NaN or an infinity when written); expected a finite \
             number above 0",
        )
    })
}

/// Why a model file was refused.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// The file could not be read.
    #[error("cannot read model file {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The file could not be written.
    #[error("cannot write model file {path}: {source}")]
    Write {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The file exists and overwriting was not asked for.
    #[error("model file {0} already exists; pass --force to overwrite it")]
    Exists(PathBuf),
    /// The bytes are not a safetensors file.
    #[error("model file {path} is not a safetensors file (corrupt or truncated?): {reason}")]
    NotSafetensors {
        /// The file.
        path: PathBuf,
        /// What the parser said.
        reason: String,
    },
    /// The safetensors metadata has no SCL header.
    #[error(
        "model file {0} has no `scl` header in its metadata; it was not written by `scl train`"
    )]
    MissingHeader(PathBuf),
    /// The header is not valid JSON of the expected shape.
    #[error("model file {path}: bad header: {reason}")]
    BadHeader {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// A tensor the kind needs is missing.
    #[error("model file {path}: tensor `{name}` is missing")]
    MissingTensor {
        /// The file.
        path: PathBuf,
        /// The tensor.
        name: String,
    },
    /// A tensor has the wrong type, shape or values.
    #[error("model file {path}: tensor `{name}`: {reason}")]
    BadTensor {
        /// The file.
        path: PathBuf,
        /// The tensor.
        name: String,
        /// What is wrong.
        reason: String,
    },
    /// The model does not fit the robot or the input device.
    #[error("model file {path}: {what} is {found}, but the {against} needs {expected}")]
    Mismatch {
        /// The file.
        path: PathBuf,
        /// Which quantity.
        what: &'static str,
        /// The model's value.
        found: usize,
        /// The required value.
        expected: usize,
        /// What requires it.
        against: &'static str,
    },
    /// A built-in map's parameters (from its spec or its file's metadata) are unusable.
    #[error("model {model}: {reason}")]
    Parameters {
        /// The spec or file.
        model: String,
        /// Which parameter and what is wrong with it.
        reason: String,
    },
    /// The header declares a kind this build cannot serve yet.
    #[error("model file {path}: models of kind `{kind}` are not supported by this build")]
    Unsupported {
        /// The file.
        path: PathBuf,
        /// The kind.
        kind: ModelKind,
    },
}

/// A checked model: its header and a ready map.
pub struct LoadedModel {
    /// Where it was loaded from (`bundled` for the built-in model).
    pub source: String,
    /// The header.
    pub header: ModelHeader,
    /// The map.
    pub map: Box<dyn ActionMap>,
}

impl std::fmt::Debug for LoadedModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LoadedModel")
            .field("source", &self.source)
            .field("header", &self.header)
            .finish()
    }
}

impl LoadedModel {
    /// This model ticking every `period_s` seconds ([`ActionMap::set_period`]): what the
    /// mapper process and replay serve at the graph's rate.
    pub fn at_period(mut self, period_s: f64) -> Self {
        self.map.set_period(period_s);
        self
    }

    /// Loads `spec` for the default robot profile ([`LoadedModel::load_for`]).
    pub fn load(spec: &str) -> Result<Self, ModelError> {
        Self::load_for(spec, kinematics::RobotProfile::default_robot())
    }

    /// Loads `spec`: a path, [`BUNDLED_NAME`] for the model built into the binary,
    /// `modeswitch[:key=value,...]` for the mode-switching map ([`crate::modeswitch::SPEC`]),
    /// which drives `robot`'s arm with its kinematics and limits, or `constant:qdot=v1,...,v6`
    /// for the drill map ([`crate::constant::SPEC`]), or `goto:pose=NAME` / `goto:q=...` for
    /// the go-to map ([`crate::goto`]).
    pub fn load_for(
        spec: &str,
        robot: &'static kinematics::RobotProfile,
    ) -> Result<Self, ModelError> {
        if spec == BUNDLED_NAME {
            return Self::from_bytes_for(BUNDLED, Path::new(BUNDLED_NAME), robot);
        }
        if crate::constant::is_spec(spec) {
            let (header, map) = crate::constant::ConstantMap::from_spec_for(robot, spec)?;
            return Ok(Self {
                source: spec.to_owned(),
                header,
                map: Box::new(map),
            });
        }
        if crate::goto::is_spec(spec) {
            let (header, map) = crate::goto::GotoMap::from_spec_for(robot, spec)?;
            return Ok(Self {
                source: spec.to_owned(),
                header,
                map: Box::new(map),
            });
        }
        if crate::modeswitch::is_spec(spec) {
            let (header, map) = crate::modeswitch::ModeSwitchMap::from_spec_for(robot, spec)?;
            return Ok(Self {
                source: spec.to_owned(),
                header,
                map: Box::new(map),
            });
        }
        let path = Path::new(spec);
        let bytes = std::fs::read(path).map_err(|source| ModelError::Io {
            path: path.to_owned(),
            source,
        })?;
        Self::from_bytes_for(&bytes, path, robot)
    }

    /// [`LoadedModel::from_bytes_for`] the default robot profile.
    pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Self, ModelError> {
        Self::from_bytes_for(bytes, path, kinematics::RobotProfile::default_robot())
    }

    /// Parses and checks a model from its bytes (a mode-switching file drives `robot`'s arm);
    /// `path` names it in errors.
    pub fn from_bytes_for(
        bytes: &[u8],
        path: &Path,
        robot: &'static kinematics::RobotProfile,
    ) -> Result<Self, ModelError> {
        let st = SafeTensors::deserialize(bytes).map_err(|e| ModelError::NotSafetensors {
            path: path.to_owned(),
            reason: e.to_string(),
        })?;
        let header = read_header(bytes, path)?;
        check_speed_scale(&header, robot, path)?;
        let map: Box<dyn ActionMap> = match header.kind {
            ModelKind::Pca => Box::new(PcaMap::from_tensors(&st, &header, path)?),
            ModelKind::Scl | ModelKind::Cae => {
                NetworkModel::from_tensors(&st, header.clone(), path)?.into_map()
            }
            ModelKind::ModeSwitch => Box::new(crate::modeswitch::ModeSwitchMap::from_file_for(
                robot, bytes, &header, path,
            )?),
            ModelKind::Constant | ModelKind::Goto => {
                return Err(ModelError::BadHeader {
                    path: path.to_owned(),
                    reason: format!(
                        "the {} map is served from its spec (`constant:qdot=...`, \
                         `goto:pose=...`), not from a file",
                        header.kind
                    ),
                });
            }
        };
        Ok(Self {
            source: path.display().to_string(),
            header,
            map,
        })
    }

    /// Refuses the model unless it drives `n_joints` joints from a `latent_dim`-D input.
    pub fn expect_dims(&self, n_joints: usize, latent_dim: usize) -> Result<(), ModelError> {
        let path = PathBuf::from(&self.source);
        if self.header.n_joints != n_joints {
            return Err(ModelError::Mismatch {
                path,
                what: "the joint count",
                found: self.header.n_joints,
                expected: n_joints,
                against: "robot",
            });
        }
        if self.header.latent_dim != latent_dim {
            return Err(ModelError::Mismatch {
                path,
                what: "the latent (action) size",
                found: self.header.latent_dim,
                expected: latent_dim,
                against: "joystick",
            });
        }
        Ok(())
    }
}

/// Reads and checks the header of a safetensors byte buffer.
pub fn read_header(bytes: &[u8], path: &Path) -> Result<ModelHeader, ModelError> {
    let (_, meta) = SafeTensors::read_metadata(bytes).map_err(|e| ModelError::NotSafetensors {
        path: path.to_owned(),
        reason: e.to_string(),
    })?;
    let json = meta
        .metadata()
        .as_ref()
        .and_then(|m| m.get(HEADER_KEY))
        .ok_or_else(|| ModelError::MissingHeader(path.to_owned()))?;
    let header: ModelHeader = serde_json::from_str(json).map_err(|e| ModelError::BadHeader {
        path: path.to_owned(),
        reason: e.to_string(),
    })?;
    let bad = |reason: String| ModelError::BadHeader {
        path: path.to_owned(),
        reason,
    };
    if header.format != FORMAT {
        return Err(bad(format!(
            "format is `{}`, expected `{FORMAT}`",
            header.format
        )));
    }
    if header.version == 0 || header.version > VERSION {
        return Err(bad(format!(
            "version {} is not supported (this build reads 1..={VERSION})",
            header.version
        )));
    }
    if header.n_joints == 0 || header.n_joints > ipc_types::MAX_JOINTS {
        return Err(bad(format!(
            "n_joints is {}, expected 1..={}",
            header.n_joints,
            ipc_types::MAX_JOINTS
        )));
    }
    if header.latent_dim == 0 || header.latent_dim > header.n_joints {
        return Err(bad(format!(
            "latent_dim is {}, expected 1..={}",
            header.latent_dim, header.n_joints
        )));
    }
    if header.joint_names.len() != header.n_joints {
        return Err(bad(format!(
            "{} joint names for {} joints",
            header.joint_names.len(),
            header.n_joints
        )));
    }
    if !(header.speed_scale_rad_s.is_finite() && header.speed_scale_rad_s > 0.0) {
        return Err(bad(format!(
            "speed_scale_rad_s is {}, expected a finite number above 0",
            header.speed_scale_rad_s
        )));
    }
    match (header.kind, &header.network) {
        (ModelKind::Pca, Some(_)) => {
            return Err(bad("a pca model has no `network` section".into()));
        }
        (ModelKind::Scl | ModelKind::Cae, None) => {
            return Err(bad(format!(
                "a {} model needs a `network` section (header version 2)",
                header.kind
            )));
        }
        (ModelKind::Scl | ModelKind::Cae, Some(_)) if header.version < 2 => {
            return Err(bad(format!(
                "a {} model needs header version 2, the file says {}",
                header.kind, header.version
            )));
        }
        _ => {}
    }
    if let Some(b) = header.lipschitz_bound
        && !(b.is_finite() && b > 0.0)
    {
        return Err(bad(format!(
            "lipschitz_bound is {b}, expected a positive number"
        )));
    }
    Ok(header)
}

/// The largest speed scale a model may have to drive `robot` (rad/s): the norm of its URDF
/// velocity limits, the joint-space speed of every joint at its limit at once.
///
/// A full deflection of an orthonormal map (PCA, SCL with Gram-Schmidt) moves the joints at
/// the speed scale in norm, so a larger scale asks, in every direction of the map, for more
/// than the arm can do: the header is wrong (a value in deg/s: 0.6 rad/s is 34 deg/s, beyond
/// the Gen3 lite's 4.8 rad/s; or a corrupt one: `1e300`), and is refused rather than left to
/// safety's limits. A trained model's default scale, the 95th percentile of the demonstrated
/// speed norm, is below it by construction.
pub fn max_speed_scale_rad_s(robot: &kinematics::RobotProfile) -> f64 {
    robot
        .urdf_velocity_rad_s()
        .iter()
        .map(|v| v * v)
        .sum::<f64>()
        .sqrt()
}

/// Refuses a header whose `speed_scale_rad_s` is above [`max_speed_scale_rad_s`] of `robot`
/// ([`read_header`] has already refused a non-finite, zero or negative one).
pub fn check_speed_scale(
    header: &ModelHeader,
    robot: &kinematics::RobotProfile,
    path: &Path,
) -> Result<(), ModelError> {
    let (s, max) = (header.speed_scale_rad_s, max_speed_scale_rad_s(robot));
    if s > max {
        return Err(ModelError::BadHeader {
            path: path.to_owned(),
            reason: format!(
                "speed_scale_rad_s is {s}, above {max:.3} rad/s: the speed of every joint of \
                 the {} at its URDF velocity limit at once (a value in deg/s?)",
                robot.name()
            ),
        });
    }
    Ok(())
}

/// Reads tensor `name` as f32 values of shape `shape`, checking type, shape and finiteness.
pub fn tensor_f32(
    st: &SafeTensors<'_>,
    name: &str,
    shape: &[usize],
    path: &Path,
) -> Result<Vec<f32>, ModelError> {
    let t = st.tensor(name).map_err(|_| ModelError::MissingTensor {
        path: path.to_owned(),
        name: name.to_owned(),
    })?;
    let bad = |reason: String| ModelError::BadTensor {
        path: path.to_owned(),
        name: name.to_owned(),
        reason,
    };
    if t.dtype() != Dtype::F32 {
        return Err(bad(format!("dtype is {:?}, expected F32", t.dtype())));
    }
    if t.shape() != shape {
        return Err(bad(format!("shape is {:?}, expected {shape:?}", t.shape())));
    }
    let values: Vec<f32> = t
        .data()
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    if let Some(i) = values.iter().position(|v| !v.is_finite()) {
        return Err(bad(format!("element {i} is {}", values[i])));
    }
    Ok(values)
}

/// Serialises `header` and the named f32 tensors (row-major) into safetensors bytes.
pub fn to_bytes(
    header: &ModelHeader,
    tensors: &[(&str, Vec<usize>, Vec<f32>)],
) -> Result<Vec<u8>, ModelError> {
    let encoded: Vec<(String, Vec<usize>, Vec<u8>)> = tensors
        .iter()
        .map(|(n, s, v)| {
            (
                (*n).to_owned(),
                s.clone(),
                v.iter().flat_map(|x| x.to_le_bytes()).collect(),
            )
        })
        .collect();
    let views = encoded
        .iter()
        .map(|(n, s, b)| {
            TensorView::new(Dtype::F32, s.clone(), b)
                .map(|v| (n.clone(), v))
                .map_err(|e| ModelError::BadTensor {
                    path: PathBuf::new(),
                    name: n.clone(),
                    reason: e.to_string(),
                })
        })
        .collect::<Result<Vec<_>, _>>()?;
    let json = serde_json::to_string(header).map_err(|e| ModelError::BadHeader {
        path: PathBuf::new(),
        reason: e.to_string(),
    })?;
    let meta = HashMap::from([(HEADER_KEY.to_owned(), json)]);
    safetensors::serialize(views, Some(meta)).map_err(|e| ModelError::NotSafetensors {
        path: PathBuf::new(),
        reason: e.to_string(),
    })
}

/// Writes model bytes to `path`, refusing to replace an existing file unless `force`. The
/// bytes go to a temporary file first and are renamed into place, so a crash never leaves a
/// half-written model under the final name.
pub fn write_file(path: &Path, bytes: &[u8], force: bool) -> Result<(), ModelError> {
    if path.exists() && !force {
        return Err(ModelError::Exists(path.to_owned()));
    }
    let werr = |source| ModelError::Write {
        path: path.to_owned(),
        source,
    };
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(werr)?;
    }
    let tmp = path.with_extension("safetensors.partial");
    std::fs::write(&tmp, bytes).map_err(werr)?;
    std::fs::rename(&tmp, path).map_err(werr)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pca::tests::sample_header;

    fn pca_bytes(header: &ModelHeader, basis: Vec<f32>) -> Vec<u8> {
        to_bytes(
            header,
            &[("basis", vec![header.n_joints, header.latent_dim], basis)],
        )
        .unwrap()
    }

    fn identity_basis() -> Vec<f32> {
        let mut b = vec![0.0f32; 12];
        b[0] = 1.0; // row 0, col 0
        b[3] = 1.0; // row 1, col 1
        b
    }

    #[test]
    fn round_trip() {
        let h = sample_header();
        let m = LoadedModel::from_bytes(&pca_bytes(&h, identity_basis()), Path::new("x")).unwrap();
        assert_eq!(m.header, h);
        assert_eq!(m.map.kind(), ModelKind::Pca);
        m.expect_dims(6, 2).unwrap();
        assert!(matches!(
            m.expect_dims(7, 2),
            Err(ModelError::Mismatch {
                found: 6,
                expected: 7,
                ..
            })
        ));
        assert!(matches!(
            m.expect_dims(6, 3),
            Err(ModelError::Mismatch {
                found: 2,
                expected: 3,
                ..
            })
        ));
    }

    #[test]
    fn bundled_model_loads() {
        let m = LoadedModel::load(BUNDLED_NAME).unwrap();
        m.expect_dims(6, 2).unwrap();
        // The paper's SCL, as the README promises: Gram-Schmidt on, two hidden layers of 256.
        assert_eq!(m.header.kind, ModelKind::Scl);
        let net = m.header.network.as_ref().unwrap();
        assert!(net.gram_schmidt);
        assert_eq!(net.hidden, [256, 256]);
    }

    #[test]
    fn refuses_corrupt_and_truncated_files() {
        let bytes = pca_bytes(&sample_header(), identity_basis());
        let p = Path::new("m.safetensors");
        for cut in [0, 4, 8, bytes.len() / 2, bytes.len() - 1] {
            let e = LoadedModel::from_bytes(&bytes[..cut], p).unwrap_err();
            assert!(
                matches!(e, ModelError::NotSafetensors { .. }),
                "cut {cut}: {e}"
            );
            assert!(e.to_string().contains("m.safetensors"));
        }
        let e = LoadedModel::from_bytes(b"hello world, not a model", p).unwrap_err();
        assert!(matches!(e, ModelError::NotSafetensors { .. }));
    }

    #[test]
    fn refuses_bad_headers() {
        let mut h = sample_header();
        h.version = 99;
        let e = LoadedModel::from_bytes(&pca_bytes(&h, identity_basis()), Path::new("m"));
        assert!(matches!(e, Err(ModelError::BadHeader { .. })));
        let mut h = sample_header();
        h.speed_scale_rad_s = f64::NAN;
        // serde_json writes NaN as null, which then fails to parse as a number.
        let e = LoadedModel::from_bytes(&pca_bytes(&h, identity_basis()), Path::new("m"));
        assert!(matches!(e, Err(ModelError::BadHeader { .. })));
        let mut h = sample_header();
        h.joint_names.pop();
        let e = LoadedModel::from_bytes(&pca_bytes(&h, identity_basis()), Path::new("m"));
        assert!(matches!(e, Err(ModelError::BadHeader { .. })));
        // No header at all.
        let v: Vec<u8> = identity_basis()
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        let view = TensorView::new(Dtype::F32, vec![6, 2], &v).unwrap();
        let bytes = safetensors::serialize([("basis", view)], None).unwrap();
        let e = LoadedModel::from_bytes(&bytes, Path::new("m"));
        assert!(matches!(e, Err(ModelError::MissingHeader(_))));
    }

    #[test]
    fn refuses_speed_scales_out_of_range() {
        // The Gen3 lite's URDF limits: five joints at 1.6 rad/s and one at 3.2, 4.8 in norm.
        let robot = kinematics::RobotProfile::default_robot();
        assert!((max_speed_scale_rad_s(robot) - 4.8).abs() < 1e-12);
        // (value, what the error says); serde_json writes a non-finite number as `null`.
        let cases = [
            (1e300, "above 4.800 rad/s"),
            (34.4, "deg/s"),
            (4.81, "above 4.800"),
            (0.0, "finite number above 0"),
            (-0.5, "finite number above 0"),
            (f64::NAN, "speed_scale_rad_s"),
            (f64::INFINITY, "speed_scale_rad_s"),
        ];
        for (v, needle) in cases {
            let mut h = sample_header();
            h.speed_scale_rad_s = v;
            let e = LoadedModel::from_bytes(&pca_bytes(&h, identity_basis()), Path::new("m.st"))
                .unwrap_err();
            let text = e.to_string();
            assert!(matches!(e, ModelError::BadHeader { .. }), "{v}: {text}");
            assert!(
                text.contains("m.st")
                    && text.contains("speed_scale_rad_s")
                    && text.contains(needle),
                "{v}: {text}"
            );
        }
        // Up to the bound is accepted.
        for v in [0.01, 0.6, 4.8] {
            let mut h = sample_header();
            h.speed_scale_rad_s = v;
            LoadedModel::from_bytes(&pca_bytes(&h, identity_basis()), Path::new("m.st")).unwrap();
        }
    }

    #[test]
    fn refuses_bad_tensors() {
        let h = sample_header();
        let mut b = identity_basis();
        b[5] = f32::NAN;
        let e = LoadedModel::from_bytes(&pca_bytes(&h, b), Path::new("m")).unwrap_err();
        assert!(matches!(e, ModelError::BadTensor { .. }), "{e}");
        // Wrong shape.
        let bytes = to_bytes(&h, &[("basis", vec![2, 6], identity_basis())]).unwrap();
        let e = LoadedModel::from_bytes(&bytes, Path::new("m")).unwrap_err();
        assert!(matches!(e, ModelError::BadTensor { .. }), "{e}");
        // Missing tensor.
        let bytes = to_bytes(&h, &[("other", vec![6, 2], identity_basis())]).unwrap();
        let e = LoadedModel::from_bytes(&bytes, Path::new("m")).unwrap_err();
        assert!(matches!(e, ModelError::MissingTensor { .. }), "{e}");
        // Columns not orthonormal.
        let e = LoadedModel::from_bytes(&pca_bytes(&h, vec![1.0; 12]), Path::new("m")).unwrap_err();
        assert!(matches!(e, ModelError::BadTensor { .. }), "{e}");
    }

    #[test]
    fn write_refuses_to_overwrite() {
        let dir = std::env::temp_dir().join(format!("scl-model-test-{}", std::process::id()));
        let p = dir.join("m.safetensors");
        let _ = std::fs::remove_dir_all(&dir);
        let bytes = pca_bytes(&sample_header(), identity_basis());
        write_file(&p, &bytes, false).unwrap();
        assert!(matches!(
            write_file(&p, &bytes, false),
            Err(ModelError::Exists(_))
        ));
        write_file(&p, &bytes, true).unwrap();
        LoadedModel::load(p.to_str().unwrap()).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
