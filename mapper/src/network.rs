//! The network models, SCL and CAE: their file representation ([`NetworkModel`]) and their
//! serving maps ([`SclMap`], [`CaeMap`]).
//!
//! Both condition on the observation `o = (q, c)` (or `q` alone, [`ObsInputs`]), normalised
//! as `x = (o − μ) / σ` with the header's `input_mean` / `input_std`, and work in units of
//! the speed scale: the network's output `y` is `qdot / s`, and the mapper multiplies by `s`.
//!
//! * SCL (the paper's method): the decoder `h(x)` outputs the `m × d` matrix `H` (row-major,
//!   `H[i][j]` at output `i·d + j`); with `gram_schmidt` its columns are orthonormalised
//!   ([`crate::nn::gram_schmidt`]), and `map(o, a) = H' a`.
//! * CAE (the conditional-autoencoder baseline): the decoder `g(x, a)` outputs `y` directly
//!   from the concatenated normalised observation and action; it is affine, so `a = 0` may
//!   still move the arm (the behaviour the paper reports).
//!
//! Serving evaluates the decoder in f32 with [`crate::nn::kernel`] into buffers allocated once
//! at load: `eval` never allocates.

use std::path::{Path, PathBuf};

use safetensors::SafeTensors;

use crate::ActionMap;
use crate::model::{self, EncoderKind, ModelError, ModelHeader, ModelKind, NetworkInfo, ObsInputs};
use crate::nn::gram_schmidt::{self, MAX_COLUMNS};
use crate::nn::kernel::{self, Packed};
use crate::nn::{Kernel, Mlp};

/// Tensor name prefix of the decoder layers.
pub const DECODER: &str = "decoder";
/// Tensor name prefix of the encoder layers.
pub const ENCODER: &str = "encoder";
/// Widest hidden layer a model file may declare.
pub const MAX_HIDDEN: usize = 4096;

/// `x = (v − mean) / std`, computed in f64 and rounded to f32, identically in training and
/// serving.
#[derive(Debug, Clone, PartialEq)]
pub struct Normaliser {
    /// Per-input mean.
    pub mean: Vec<f32>,
    /// Per-input scale (strictly positive).
    pub std: Vec<f32>,
}

impl Normaliser {
    /// Mean and standard deviation of each column of `rows`; a column whose spread is below
    /// `1e-6` (e.g. a gripper that never moved) gets scale 1 so it is only centred.
    pub fn fit(rows: &[Vec<f64>]) -> Self {
        let w = rows.first().map_or(0, Vec::len);
        let n = rows.len().max(1) as f64;
        let mut mean = vec![0.0f64; w];
        for r in rows {
            for (m, v) in mean.iter_mut().zip(r) {
                *m += v / n;
            }
        }
        let mut var = vec![0.0f64; w];
        for r in rows {
            for ((s, v), m) in var.iter_mut().zip(r).zip(&mean) {
                *s += (v - m).powi(2) / n;
            }
        }
        Self {
            mean: mean.iter().map(|v| *v as f32).collect(),
            std: var
                .iter()
                .map(|v| {
                    let s = v.sqrt();
                    if s < 1e-6 { 1.0 } else { s as f32 }
                })
                .collect(),
        }
    }

    /// The identity (mean 0, scale 1) on `n` inputs.
    pub fn identity(n: usize) -> Self {
        Self {
            mean: vec![0.0; n],
            std: vec![1.0; n],
        }
    }

    /// From a header's f64 lists.
    pub fn from_lists(mean: &[f64], std: &[f64]) -> Self {
        Self {
            mean: mean.iter().map(|v| *v as f32).collect(),
            std: std.iter().map(|v| *v as f32).collect(),
        }
    }

    /// The mean as f64 (exactly the f32 values) for a header.
    pub fn mean_list(&self) -> Vec<f64> {
        self.mean.iter().map(|v| f64::from(*v)).collect()
    }

    /// The scale as f64 for a header.
    pub fn std_list(&self) -> Vec<f64> {
        self.std.iter().map(|v| f64::from(*v)).collect()
    }

    /// `1 / std`, the row scaling that turns a first layer into its effect on raw inputs.
    pub fn inv_std(&self) -> Vec<f32> {
        self.std.iter().map(|s| 1.0 / s).collect()
    }

    /// Writes the normalised `v` into `out[..v.len()]`.
    #[inline]
    pub fn apply(&self, v: &[f64], out: &mut [f32]) {
        for (((o, x), m), s) in out.iter_mut().zip(v).zip(&self.mean).zip(&self.std) {
            *o = ((x - f64::from(*m)) / f64::from(*s)) as f32;
        }
    }
}

/// Writes the observation `(q, c)` or `q` into `out` as f64 (`out` holds `m + 1`).
#[inline]
pub fn observation(inputs: ObsInputs, q: &[f64], c: f64, out: &mut [f64]) -> usize {
    let m = q.len();
    out[..m].copy_from_slice(q);
    match inputs {
        ObsInputs::JointsAndGripper => {
            out[m] = c;
            m + 1
        }
        ObsInputs::Joints => m,
    }
}

/// A network model as stored in a file: header and weights, checked to agree.
#[derive(Debug, Clone, PartialEq)]
pub struct NetworkModel {
    header: ModelHeader,
    info: NetworkInfo,
    decoder: Mlp,
    encoder: Option<Mlp>,
}

/// Widths of the decoder of a `kind` model.
pub fn decoder_widths(kind: ModelKind, info: &NetworkInfo, m: usize, d: usize) -> Vec<usize> {
    let n_obs = info.inputs.width(m);
    let mut w = vec![if kind == ModelKind::Cae {
        n_obs + d
    } else {
        n_obs
    }];
    w.extend(&info.hidden);
    w.push(if kind == ModelKind::Cae { m } else { m * d });
    w
}

/// Widths of the MLP encoder of a model: input `(o, qdot)`, output `d`.
pub fn encoder_widths(info: &NetworkInfo, m: usize, d: usize) -> Vec<usize> {
    let mut w = vec![info.inputs.width(m) + m];
    w.extend(&info.hidden);
    w.push(d);
    w
}

impl NetworkModel {
    /// The header (kind SCL or CAE).
    pub fn header(&self) -> &ModelHeader {
        &self.header
    }

    /// The network section of the header.
    pub fn info(&self) -> &NetworkInfo {
        &self.info
    }

    /// The decoder (`h` for SCL, `g` for CAE).
    pub fn decoder(&self) -> &Mlp {
        &self.decoder
    }

    /// The training encoder `f(o, qdot) -> a`, when it is an MLP.
    pub fn encoder(&self) -> Option<&Mlp> {
        self.encoder.as_ref()
    }

    /// Replaces the provenance section of the header.
    pub fn set_training(&mut self, training: model::TrainingInfo) {
        self.header.training = training;
    }

    /// A model from its parts, checked as a loaded file would be.
    pub fn new(
        header: ModelHeader,
        decoder: Mlp,
        encoder: Option<Mlp>,
    ) -> Result<Self, ModelError> {
        let path = PathBuf::from("<in memory>");
        let info = check_info(&header, &path)?.clone();
        let me = Self {
            header,
            info,
            decoder,
            encoder,
        };
        let info = me.info();
        let (m, d) = (me.header.n_joints, me.header.latent_dim);
        let bad = |name: &str, reason: String| ModelError::BadTensor {
            path: path.clone(),
            name: name.to_owned(),
            reason,
        };
        if me.decoder.widths() != decoder_widths(me.header.kind, info, m, d) {
            return Err(bad(
                DECODER,
                format!(
                    "widths {:?}, the header needs {:?}",
                    me.decoder.widths(),
                    decoder_widths(me.header.kind, info, m, d)
                ),
            ));
        }
        match (&me.encoder, info.encoder) {
            (Some(e), EncoderKind::Mlp) if e.widths() == encoder_widths(info, m, d) => {}
            (None, EncoderKind::Projection | EncoderKind::None) => {}
            _ => {
                return Err(bad(
                    ENCODER,
                    format!("does not match the header's encoder `{:?}`", info.encoder),
                ));
            }
        }
        Ok(me)
    }

    /// Reads the weights of a checked header from a file's tensors.
    pub fn from_tensors(
        st: &SafeTensors<'_>,
        header: ModelHeader,
        path: &Path,
    ) -> Result<Self, ModelError> {
        let info = check_info(&header, path)?.clone();
        let (m, d) = (header.n_joints, header.latent_dim);
        let decoder =
            Mlp::from_tensors(st, DECODER, &decoder_widths(header.kind, &info, m, d), path)?;
        let encoder = match info.encoder {
            EncoderKind::Mlp => Some(Mlp::from_tensors(
                st,
                ENCODER,
                &encoder_widths(&info, m, d),
                path,
            )?),
            EncoderKind::Projection | EncoderKind::None => None,
        };
        Ok(Self {
            header,
            info,
            decoder,
            encoder,
        })
    }

    /// Parses and checks a network model file's bytes; `path` names it in errors.
    pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Self, ModelError> {
        let st = SafeTensors::deserialize(bytes).map_err(|e| ModelError::NotSafetensors {
            path: path.to_owned(),
            reason: e.to_string(),
        })?;
        let header = model::read_header(bytes, path)?;
        Self::from_tensors(&st, header, path)
    }

    /// Loads a network model file.
    pub fn load(path: &Path) -> Result<Self, ModelError> {
        let bytes = std::fs::read(path).map_err(|source| ModelError::Io {
            path: path.to_owned(),
            source,
        })?;
        Self::from_bytes(&bytes, path)
    }

    /// The file bytes.
    pub fn to_bytes(&self) -> Result<Vec<u8>, ModelError> {
        let mut tensors = self.decoder.tensors(DECODER);
        if let Some(e) = &self.encoder {
            tensors.extend(e.tensors(ENCODER));
        }
        let borrowed: Vec<(&str, Vec<usize>, Vec<f32>)> = tensors
            .iter()
            .map(|(n, s, v)| (n.as_str(), s.clone(), v.clone()))
            .collect();
        model::to_bytes(&self.header, &borrowed)
    }

    /// The decoder's input normalisation (observation part).
    pub fn obs_normaliser(&self) -> Normaliser {
        let info = self.info();
        Normaliser::from_lists(&info.input_mean, &info.input_std)
    }

    /// The encoder's input normalisation (`(o, qdot)`), if it has an MLP encoder.
    pub fn encoder_normaliser(&self) -> Option<Normaliser> {
        let info = self.info();
        (info.encoder == EncoderKind::Mlp)
            .then(|| Normaliser::from_lists(&info.encoder_input_mean, &info.encoder_input_std))
    }

    /// The serving map.
    pub fn into_map(self) -> Box<dyn ActionMap> {
        match self.header.kind {
            ModelKind::Cae => Box::new(CaeMap::new(&self)),
            _ => Box::new(SclMap::new(&self)),
        }
    }

    /// The SCL serving map (also for a CAE file's decoder it would be wrong: SCL only).
    pub fn scl_map(&self) -> Option<SclMap> {
        (self.header.kind == ModelKind::Scl).then(|| SclMap::new(self))
    }
}

fn check_info<'h>(header: &'h ModelHeader, path: &Path) -> Result<&'h NetworkInfo, ModelError> {
    let bad = |reason: String| ModelError::BadHeader {
        path: path.to_owned(),
        reason,
    };
    let Some(info) = &header.network else {
        return Err(bad(format!(
            "a {} model needs a `network` section",
            header.kind
        )));
    };
    let (m, d) = (header.n_joints, header.latent_dim);
    let n_obs = info.inputs.width(m);
    if info.input_mean.len() != n_obs || info.input_std.len() != n_obs {
        return Err(bad(format!(
            "input_mean / input_std have {} / {} values, the {:?} input needs {n_obs}",
            info.input_mean.len(),
            info.input_std.len(),
            info.inputs
        )));
    }
    check_norm("input", &info.input_mean, &info.input_std).map_err(bad)?;
    if info.hidden.is_empty() || info.hidden.iter().any(|h| *h == 0 || *h > MAX_HIDDEN) {
        return Err(bad(format!(
            "hidden is {:?}, expected one or more widths in 1..={MAX_HIDDEN}",
            info.hidden
        )));
    }
    if !(info.gs_epsilon.is_finite() && info.gs_epsilon >= 0.0) {
        return Err(bad(format!("gs_epsilon is {}", info.gs_epsilon)));
    }
    if d > MAX_COLUMNS {
        return Err(bad(format!("latent_dim {d} exceeds {MAX_COLUMNS}")));
    }
    match header.kind {
        ModelKind::Cae if info.gram_schmidt => {
            return Err(bad("gram_schmidt is for scl models only".into()));
        }
        ModelKind::Cae if info.encoder == EncoderKind::Projection => {
            return Err(bad("the projection encoder is for scl models only".into()));
        }
        ModelKind::Scl if info.li_losses.is_some() => {
            return Err(bad("li_losses are for cae models only".into()));
        }
        _ => {}
    }
    if info.encoder == EncoderKind::Mlp {
        let n = n_obs + m;
        if info.encoder_input_mean.len() != n || info.encoder_input_std.len() != n {
            return Err(bad(format!(
                "encoder_input_mean / encoder_input_std need {n} values each"
            )));
        }
        check_norm(
            "encoder input",
            &info.encoder_input_mean,
            &info.encoder_input_std,
        )
        .map_err(bad)?;
    }
    Ok(info)
}

fn check_norm(what: &str, mean: &[f64], std: &[f64]) -> Result<(), String> {
    if let Some(i) = mean.iter().position(|v| !v.is_finite()) {
        return Err(format!("{what} mean {i} is {}", mean[i]));
    }
    if let Some(i) = std
        .iter()
        .position(|v| !(v.is_finite() && *v > 0.0 && (*v as f32) > 0.0))
    {
        return Err(format!(
            "{what} std {i} is {}, expected a positive number",
            std[i]
        ));
    }
    Ok(())
}

/// The SCL map served by the mapper: `map(o, a) = GS(h(o)) a` (or `h(o) a`).
#[derive(Debug, Clone)]
pub struct SclMap {
    m: usize,
    d: usize,
    inputs: ObsInputs,
    norm: Normaliser,
    decoder: Packed,
    gram_schmidt: bool,
    eps: f32,
    kernel: Kernel,
    obs: Vec<f64>,
    x: Vec<f32>,
    scratch_a: Vec<f32>,
    scratch_b: Vec<f32>,
    h: Vec<f32>,
    norms: [f32; MAX_COLUMNS],
}

impl SclMap {
    /// The map of a checked model, with its buffers.
    pub fn new(model: &NetworkModel) -> Self {
        let info = model.info();
        let (m, d) = (model.header.n_joints, model.header.latent_dim);
        let decoder = model.decoder.packed();
        let w = decoder.scratch_len();
        Self {
            m,
            d,
            inputs: info.inputs,
            norm: model.obs_normaliser(),
            decoder,
            gram_schmidt: info.gram_schmidt,
            eps: info.gs_epsilon as f32,
            kernel: Kernel::detect(),
            obs: vec![0.0; m + 1],
            x: vec![0.0; m + 1],
            scratch_a: vec![0.0; w],
            scratch_b: vec![0.0; w],
            h: vec![0.0; m * d],
            norms: [0.0; MAX_COLUMNS],
        }
    }

    /// Evaluates `H'(o)` (row-major `m × d`, orthonormalised when the model says so).
    pub fn matrix(&mut self, q: &[f64], c: f64) -> &[f32] {
        let n = observation(self.inputs, &q[..self.m], c, &mut self.obs);
        self.norm.apply(&self.obs[..n], &mut self.x);
        kernel::forward(
            self.kernel,
            &self.decoder,
            &self.x[..n],
            &mut self.scratch_a,
            &mut self.scratch_b,
            &mut self.h,
        );
        if self.gram_schmidt {
            gram_schmidt::orthonormalise(&mut self.h, self.m, self.d, self.eps, &mut self.norms);
        }
        &self.h
    }

    /// Guarded column norms of the last Gram-Schmidt (a column whose norm is near
    /// `sqrt(ε)` had collapsed into the span of the earlier ones and now moves almost nothing).
    pub fn column_norms(&self) -> &[f32] {
        &self.norms[..self.d]
    }

    /// Uses the given kernel instead of the detected one (benchmarks, tests). Any [`Kernel`]
    /// is one this CPU runs: the AVX2 copy only comes from a run-time check.
    pub fn set_kernel(&mut self, kernel: Kernel) {
        self.kernel = kernel;
    }
}

impl ActionMap for SclMap {
    fn kind(&self) -> ModelKind {
        ModelKind::Scl
    }
    fn n_joints(&self) -> usize {
        self.m
    }
    fn latent_dim(&self) -> usize {
        self.d
    }
    fn eval(&mut self, q: &[f64], c: f64, a: &[f64], out: &mut [f64]) {
        let d = self.d;
        self.matrix(q, c);
        for (i, o) in out.iter_mut().enumerate().take(self.m) {
            let row = &self.h[i * d..(i + 1) * d];
            *o = row.iter().zip(a).map(|(h, a)| f64::from(*h) * a).sum();
        }
    }
}

/// The CAE decoder served by the mapper: `map(o, a) = g(x, a)`.
#[derive(Debug, Clone)]
pub struct CaeMap {
    m: usize,
    d: usize,
    inputs: ObsInputs,
    norm: Normaliser,
    decoder: Packed,
    kernel: Kernel,
    obs: Vec<f64>,
    x: Vec<f32>,
    scratch_a: Vec<f32>,
    scratch_b: Vec<f32>,
    y: Vec<f32>,
}

impl CaeMap {
    /// The map of a checked model, with its buffers.
    pub fn new(model: &NetworkModel) -> Self {
        let info = model.info();
        let (m, d) = (model.header.n_joints, model.header.latent_dim);
        let decoder = model.decoder.packed();
        let w = decoder.scratch_len();
        Self {
            m,
            d,
            inputs: info.inputs,
            norm: model.obs_normaliser(),
            decoder,
            kernel: Kernel::detect(),
            obs: vec![0.0; m + 1],
            x: vec![0.0; m + 1 + d],
            scratch_a: vec![0.0; w],
            scratch_b: vec![0.0; w],
            y: vec![0.0; m],
        }
    }
}

impl ActionMap for CaeMap {
    fn kind(&self) -> ModelKind {
        ModelKind::Cae
    }
    fn n_joints(&self) -> usize {
        self.m
    }
    fn latent_dim(&self) -> usize {
        self.d
    }
    fn eval(&mut self, q: &[f64], c: f64, a: &[f64], out: &mut [f64]) {
        let n = observation(self.inputs, &q[..self.m], c, &mut self.obs);
        self.norm.apply(&self.obs[..n], &mut self.x);
        for (x, a) in self.x[n..n + self.d].iter_mut().zip(a) {
            *x = *a as f32;
        }
        kernel::forward(
            self.kernel,
            &self.decoder,
            &self.x[..n + self.d],
            &mut self.scratch_a,
            &mut self.scratch_b,
            &mut self.y,
        );
        for (o, y) in out.iter_mut().zip(&self.y) {
            *o = f64::from(*y);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::LoadedModel;
    use crate::model::{FORMAT, TrainingInfo, VERSION};
    use crate::rng::Rng;

    fn header(kind: ModelKind, m: usize, d: usize) -> ModelHeader {
        ModelHeader {
            format: FORMAT.into(),
            version: VERSION,
            kind,
            n_joints: m,
            latent_dim: d,
            joint_names: (1..=m).map(|i| format!("joint_{i}")).collect(),
            speed_scale_rad_s: 0.5,
            lipschitz_bound: Some(1.0),
            network: Some(NetworkInfo {
                inputs: ObsInputs::JointsAndGripper,
                input_mean: vec![0.0; m + 1],
                input_std: vec![1.0; m + 1],
                hidden: vec![8, 8],
                gram_schmidt: kind == ModelKind::Scl,
                gs_epsilon: 1e-8,
                encoder: EncoderKind::Mlp,
                encoder_input_mean: vec![0.0; 2 * m + 1],
                encoder_input_std: vec![1.0; 2 * m + 1],
                li_losses: None,
            }),
            training: TrainingInfo::default(),
        }
    }

    fn model(kind: ModelKind, m: usize, d: usize) -> NetworkModel {
        let h = header(kind, m, d);
        let mut r = Rng::new(1);
        let info = h.network.clone().unwrap();
        let dec = Mlp::init(&decoder_widths(kind, &info, m, d), &mut r);
        let enc = Mlp::init(&encoder_widths(&info, m, d), &mut r);
        NetworkModel::new(h, dec, Some(enc)).unwrap()
    }

    fn load(bytes: &[u8]) -> Result<LoadedModel, ModelError> {
        LoadedModel::from_bytes(bytes, Path::new("net.safetensors"))
    }

    #[test]
    fn round_trips_and_checks_dimensions() {
        for kind in [ModelKind::Scl, ModelKind::Cae] {
            let m = model(kind, 6, 2);
            let bytes = m.to_bytes().unwrap();
            let back = NetworkModel::from_bytes(&bytes, Path::new("x")).unwrap();
            assert_eq!(back, m);
            let loaded = load(&bytes).unwrap();
            assert_eq!(loaded.map.kind(), kind);
            loaded.expect_dims(6, 2).unwrap();
            // A 7-joint robot or a 3-axis joystick is refused at load, naming the file.
            let e = loaded.expect_dims(7, 2).unwrap_err().to_string();
            assert!(
                e.contains("net.safetensors") && e.contains("joint count"),
                "{e}"
            );
            let e = loaded.expect_dims(6, 3).unwrap_err().to_string();
            assert!(e.contains("latent"), "{e}");
        }
        // Another robot's model is refused by the mapper step at construction.
        let bytes = model(ModelKind::Scl, 7, 2).to_bytes().unwrap();
        assert!(crate::step::MapperStep::new(1, load(&bytes).unwrap(), 6).is_err());
    }

    #[test]
    fn refuses_corrupt_or_inconsistent_files() {
        let m = model(ModelKind::Scl, 6, 2);
        let bytes = m.to_bytes().unwrap();
        for cut in [10, bytes.len() / 3, bytes.len() - 7] {
            assert!(matches!(
                load(&bytes[..cut]),
                Err(ModelError::NotSafetensors { .. })
            ));
        }
        let with = |f: &dyn Fn(&mut ModelHeader)| {
            let mut h = m.header().clone();
            f(&mut h);
            let mut t = m.decoder().tensors(DECODER);
            t.extend(m.encoder().unwrap().tensors(ENCODER));
            let b: Vec<(&str, Vec<usize>, Vec<f32>)> = t
                .iter()
                .map(|(n, s, v)| (n.as_str(), s.clone(), v.clone()))
                .collect();
            load(&model::to_bytes(&h, &b).unwrap())
        };
        let reason = |r: Result<LoadedModel, ModelError>| r.unwrap_err().to_string();
        assert!(reason(with(&|h| h.network = None)).contains("needs a `network` section"));
        assert!(reason(with(&|h| h.version = 1)).contains("version 2"));
        assert!(
            reason(with(&|h| h.network.as_mut().unwrap().hidden = vec![8, 9])).contains("shape")
        );
        assert!(
            reason(with(&|h| h.network.as_mut().unwrap().hidden = vec![8]))
                .contains("decoder.1.weight")
        );
        assert!(
            reason(with(&|h| h.network.as_mut().unwrap().input_std[3] = 0.0))
                .contains("input std 3")
        );
        assert!(
            reason(with(&|h| h
                .network
                .as_mut()
                .unwrap()
                .input_mean
                .pop()
                .map(|_| ())
                .unwrap_or(())))
            .contains("input_mean")
        );
        assert!(
            reason(with(
                &|h| h.network.as_mut().unwrap().inputs = ObsInputs::Joints
            ))
            .contains("7 values")
        );
        assert!(reason(with(&|h| h.lipschitz_bound = Some(-1.0))).contains("lipschitz_bound"));
        assert!(reason(with(&|h| h.kind = ModelKind::Cae)).contains("gram_schmidt"));
        assert!(reason(with(&|h| h.n_joints = 5)).contains("joint names"));
        // Non-finite weights.
        let mut dec = m.decoder().clone();
        dec.layers[1].w[17] = f32::NAN;
        let mut t = dec.tensors(DECODER);
        t.extend(m.encoder().unwrap().tensors(ENCODER));
        let b: Vec<(&str, Vec<usize>, Vec<f32>)> = t
            .iter()
            .map(|(n, s, v)| (n.as_str(), s.clone(), v.clone()))
            .collect();
        let e = reason(load(&model::to_bytes(m.header(), &b).unwrap()));
        assert!(e.contains("decoder.1.weight") && e.contains("NaN"), "{e}");
        // Missing encoder tensors.
        let t = m.decoder().tensors(DECODER);
        let b: Vec<(&str, Vec<usize>, Vec<f32>)> = t
            .iter()
            .map(|(n, s, v)| (n.as_str(), s.clone(), v.clone()))
            .collect();
        let e = reason(load(&model::to_bytes(m.header(), &b).unwrap()));
        assert!(
            e.contains("encoder.0.weight") && e.contains("missing"),
            "{e}"
        );
        // A PCA header with a network section.
        let e = reason(with(&|h| {
            h.kind = ModelKind::Pca;
        }));
        assert!(e.contains("pca model has no `network`"), "{e}");
    }

    #[test]
    fn a_collapsed_column_moves_nothing_instead_of_nan() {
        // A decoder whose two columns are always equal: H' keeps one unit column and a
        // near-zero second one.
        let mut m = model(ModelKind::Scl, 6, 2);
        let mut dec = m.decoder().clone();
        let last = dec.layers.len() - 1;
        let l = &mut dec.layers[last];
        for k in 0..l.n_in {
            for i in 0..6 {
                l.w[k * 12 + i * 2 + 1] = l.w[k * 12 + i * 2];
            }
        }
        for i in 0..6 {
            l.b[i * 2 + 1] = l.b[i * 2];
        }
        m = NetworkModel::new(m.header().clone(), dec, m.encoder().cloned()).unwrap();
        let mut map = m.scl_map().unwrap();
        let mut out = [0.0; 6];
        map.eval(&[0.2; 6], 0.0, &[0.0, 1.0], &mut out);
        assert!(out.iter().all(|v| v.is_finite()));
        let n: f64 = out.iter().map(|v| v * v).sum::<f64>().sqrt();
        assert!(n < 1e-2, "second direction moves {n}");
        assert!(map.column_norms()[1] < 1e-3);
        map.eval(&[0.2; 6], 0.0, &[1.0, 0.0], &mut out);
        let n: f64 = out.iter().map(|v| v * v).sum::<f64>().sqrt();
        assert!(
            (n - 1.0).abs() < 1e-5,
            "first direction is a unit vector: {n}"
        );
    }
}
