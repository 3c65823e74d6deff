//! Offline evaluation of model files: reconstruction loss on a data set, and the soft-
//! reversibility experiment of the paper.
//!
//! **Soft reversibility** (paper, Theorem 1). With the transition
//! `T(q, a) = q + Δ · s · h(q) a` (the paper writes `T(q, a) = q + h(q) a`, i.e. `Δ·s = 1`; here
//! `Δ` is the control period and `s` the speed scale, so the map the arm executes in one tick
//! is `Δ s h`), if `q ↦ Δ s · vec(h(q))` is Lipschitz with constant `L_v ≤ 1` and `|a| < 1`,
//! then for `q_j = T(q_i, a) ≠ q_i`:
//!
//! ```text
//! |T(q_j, −a) − q_i| = |(h(q_i) − h(q_j)) a| Δ s ≤ L_v |a| |q_j − q_i| < |q_j − q_i|.
//! ```
//!
//! The proof needs the map to be *linear in `a`* with a Lipschitz matrix; Gram-Schmidt is not
//! Lipschitz (it divides by column norms), so the theorem says nothing about SCL with
//! Gram-Schmidt, and [`reversibility`] measures how often the inequality holds then. The
//! trained decoders here are bounded with `L` for the raw observation `(q, c)` (which bounds
//! the dependence on `q` at fixed `c`), so the theorem applies whenever `Δ · s · L ≤ 1`.

use std::path::{Path, PathBuf};

use safetensors::SafeTensors;

use crate::dataset::Trajectory;
use crate::pca;
use mapper::ActionMap;
use mapper::model::{self, EncoderKind, ModelError, ModelHeader, ModelKind};
use mapper::network::{self, NetworkModel, Normaliser, SclMap};
use mapper::nn::kernel::{self, Packed};
use mapper::nn::{Kernel, Mlp};
use mapper::pca::PcaMap;
use mapper::rng::Rng;

/// Why an evaluation could not run.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// The model file is unusable.
    #[error(transparent)]
    Model(#[from] ModelError),
    /// The model and the data disagree on the joint count.
    #[error("{path}: the model drives {model} joints, the data has {data}")]
    Joints {
        /// The model file.
        path: PathBuf,
        /// Model joints.
        model: usize,
        /// Data joints.
        data: usize,
    },
    /// The model has no encoder to reconstruct with.
    #[error(
        "{0}: the file has no encoder (imported weights) and no Gram-Schmidt to project with, so it cannot reconstruct data"
    )]
    NoEncoder(PathBuf),
    /// Nothing to evaluate on.
    #[error("no tuples to evaluate on")]
    NoData,
}

/// Any model file, with what evaluation needs.
#[derive(Debug, Clone)]
pub enum AnyModel {
    /// PCA.
    Pca {
        /// Header.
        header: Box<ModelHeader>,
        /// The map (its basis).
        map: PcaMap,
    },
    /// SCL or CAE.
    Net(Box<NetworkModel>),
}

impl AnyModel {
    /// Loads and checks a model file of any kind.
    pub fn load(path: &Path) -> Result<Self, ModelError> {
        let bytes = std::fs::read(path).map_err(|source| ModelError::Io {
            path: path.to_owned(),
            source,
        })?;
        let header = model::read_header(&bytes, path)?;
        if header.kind == ModelKind::Pca {
            let st = SafeTensors::deserialize(&bytes).map_err(|e| ModelError::NotSafetensors {
                path: path.to_owned(),
                reason: e.to_string(),
            })?;
            let map = PcaMap::from_tensors(&st, &header, path)?;
            return Ok(Self::Pca {
                header: Box::new(header),
                map,
            });
        }
        Ok(Self::Net(Box::new(NetworkModel::from_bytes(&bytes, path)?)))
    }

    /// The header.
    pub fn header(&self) -> &ModelHeader {
        match self {
            Self::Pca { header, .. } => header,
            Self::Net(n) => n.header(),
        }
    }

    /// A serving map of the model.
    pub fn map(&self) -> Box<dyn ActionMap> {
        match self {
            Self::Pca { map, .. } => Box::new(map.clone()),
            Self::Net(n) => n.clone().into_map(),
        }
    }
}

/// Mean squared reconstruction error of `qdot` ((rad/s)², over tuples and joints) of a model on
/// the tuples of `trajs`: PCA projects (`Σ Σᵀ qdot`); SCL and CAE encode with their training
/// encoder and decode with the serving map, times the speed scale. An SCL file without an
/// encoder (imported) but with Gram-Schmidt is evaluated with the projection `a = H'ᵀ qdot/s`;
/// a CAE file without one cannot be evaluated.
pub fn reconstruction_mse(
    model: &AnyModel,
    path: &Path,
    trajs: &[Trajectory],
) -> Result<f64, EvalError> {
    let m = model.header().n_joints;
    let n: usize = trajs.iter().map(Trajectory::len).sum();
    if n == 0 {
        return Err(EvalError::NoData);
    }
    if let Some(t) = trajs.iter().find(|t| t.n_joints() != m) {
        return Err(EvalError::Joints {
            path: path.to_owned(),
            model: m,
            data: t.n_joints(),
        });
    }
    match model {
        AnyModel::Pca { map, .. } => {
            let rows: Vec<Vec<f64>> = trajs.iter().flat_map(|t| t.qdot.iter().cloned()).collect();
            Ok(pca::reconstruction_mse(map, &rows))
        }
        AnyModel::Net(net) => {
            let mut enc = Encoder::new(net).ok_or_else(|| EvalError::NoEncoder(path.to_owned()))?;
            let mut map = net.clone().into_map();
            let s = net.header().speed_scale_rad_s;
            let d = net.header().latent_dim;
            let mut a = vec![0.0; d];
            let mut out = vec![0.0; m];
            let mut sum = 0.0;
            for t in trajs {
                for k in 0..t.len() {
                    enc.encode(&t.q[k], t.c[k], &t.qdot[k], &mut a);
                    map.eval(&t.q[k], t.c[k], &a, &mut out);
                    for (o, v) in out.iter().zip(&t.qdot[k]) {
                        sum += (s * o - v).powi(2);
                    }
                }
            }
            Ok(sum / (n * m) as f64)
        }
    }
}

/// A network model's training encoder, with its buffers.
struct Encoder<'a> {
    net: &'a NetworkModel,
    packed: Option<Packed>,
    norm: Option<Normaliser>,
    scl: Option<SclMap>,
    raw: Vec<f64>,
    x: Vec<f32>,
    sa: Vec<f32>,
    sb: Vec<f32>,
    out: Vec<f32>,
}

impl<'a> Encoder<'a> {
    fn new(net: &'a NetworkModel) -> Option<Self> {
        let (m, d) = (net.header().n_joints, net.header().latent_dim);
        let packed = net.encoder().map(Mlp::packed);
        let w = packed.as_ref().map_or(0, Packed::scratch_len);
        let scl = match net.info().encoder {
            EncoderKind::Mlp => None,
            EncoderKind::Projection => Some(net.scl_map()?),
            // Imported SCL weights: with orthonormal columns the projection is the best
            // encoder there is, so it stands in for the missing one.
            EncoderKind::None if net.info().gram_schmidt => Some(net.scl_map()?),
            EncoderKind::None => return None,
        };
        Some(Self {
            net,
            packed,
            norm: net.encoder_normaliser(),
            scl,
            raw: vec![0.0; 2 * m + 1],
            x: vec![0.0; 2 * m + 1],
            sa: vec![0.0; w],
            sb: vec![0.0; w],
            out: vec![0.0; d],
        })
    }

    fn encode(&mut self, q: &[f64], c: f64, qdot: &[f64], a: &mut [f64]) {
        let (m, d) = (self.net.header().n_joints, self.net.header().latent_dim);
        if let Some(scl) = &mut self.scl {
            let s = self.net.header().speed_scale_rad_s;
            let h = scl.matrix(q, c);
            for (j, aj) in a.iter_mut().enumerate().take(d) {
                *aj = (0..m).map(|i| f64::from(h[i * d + j]) * qdot[i] / s).sum();
            }
            return;
        }
        let (Some(enc), Some(norm)) = (&self.packed, &self.norm) else {
            return;
        };
        let n_obs = network::observation(self.net.info().inputs, q, c, &mut self.raw);
        self.raw[n_obs..n_obs + m].copy_from_slice(qdot);
        norm.apply(&self.raw[..n_obs + m], &mut self.x);
        kernel::forward(
            Kernel::detect(),
            enc,
            &self.x[..n_obs + m],
            &mut self.sa,
            &mut self.sb,
            &mut self.out,
        );
        for (ai, o) in a.iter_mut().zip(&self.out) {
            *ai = f64::from(*o);
        }
    }
}

/// How often an inequality held over a set of trials.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Fraction {
    /// Trials where it held.
    pub held: usize,
    /// Trials counted (those with motion).
    pub total: usize,
    /// Trials skipped because the forward action did not move the arm.
    pub no_motion: usize,
    /// Mean of `|q_back − q_0| / |q_forward − q_0|`.
    pub mean_ratio: f64,
    /// Largest such ratio.
    pub worst_ratio: f64,
}

impl Fraction {
    /// `held / total` (1 when nothing was counted).
    pub fn value(&self) -> f64 {
        if self.total == 0 {
            1.0
        } else {
            self.held as f64 / self.total as f64
        }
    }

    fn add(&mut self, forward: f64, back: f64) {
        if forward <= 0.0 {
            self.no_motion += 1;
            return;
        }
        let r = back / forward;
        self.total += 1;
        if back < forward {
            self.held += 1;
        }
        self.mean_ratio += (r - self.mean_ratio) / self.total as f64;
        self.worst_ratio = self.worst_ratio.max(r);
    }
}

/// The two reversibility experiments on one set of states and actions.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Reversibility {
    /// One transition forward, one back (the theorem's statement).
    pub one_step: Fraction,
    /// The paper's experiment: `a` for `ticks` transitions, then `−a` for as many.
    pub repeated: Fraction,
}

fn dist(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// Runs both experiments: for each `(q, c)` in `states` and a random action of norm in
/// `[0, max_norm)` (uniform direction, uniform norm), with the transition
/// `T(q, a) = q + step · map(q, c, a)` (`step` = `Δ · s`).
pub fn reversibility(
    map: &mut dyn ActionMap,
    states: &[(Vec<f64>, f64)],
    step: f64,
    ticks: usize,
    max_norm: f64,
    rng: &mut Rng,
) -> Reversibility {
    let m = map.n_joints();
    let d = map.latent_dim();
    let mut out = vec![0.0; m];
    let mut r = Reversibility::default();
    let mut a = vec![0.0; d];
    let mut neg = vec![0.0; d];
    for (q0, c) in states {
        // A uniform direction in d dimensions, a uniform norm below `max_norm`.
        for v in a.iter_mut() {
            *v = rng.normal();
        }
        let n = a.iter().map(|v| v * v).sum::<f64>().sqrt().max(1e-300);
        let norm = rng.uniform() * max_norm;
        a.iter_mut().for_each(|v| *v *= norm / n);
        neg.iter_mut().zip(&a).for_each(|(n, v)| *n = -v);
        let mut apply = |q: &mut Vec<f64>, act: &[f64], times: usize| {
            for _ in 0..times {
                map.eval(q, *c, act, &mut out);
                q.iter_mut().zip(&out).for_each(|(qi, o)| *qi += step * o);
            }
        };
        let mut q = q0.clone();
        apply(&mut q, &a, 1);
        let fwd = dist(&q, q0);
        apply(&mut q, &neg, 1);
        r.one_step.add(fwd, dist(&q, q0));
        let mut q = q0.clone();
        apply(&mut q, &a, ticks);
        let fwd = dist(&q, q0);
        apply(&mut q, &neg, ticks);
        r.repeated.add(fwd, dist(&q, q0));
    }
    r
}

/// Robot states `(q, c)` to start experiments from.
pub type States = Vec<(Vec<f64>, f64)>;

/// `n` states drawn uniformly from the tuples of `trajs`.
pub fn states_from_data(trajs: &[Trajectory], n: usize, rng: &mut Rng) -> States {
    let all: Vec<(&Vec<f64>, f64)> = trajs
        .iter()
        .flat_map(|t| t.q.iter().zip(t.c.iter().copied()))
        .collect();
    if all.is_empty() {
        return Vec::new();
    }
    (0..n)
        .map(|_| {
            let (q, c) = all[(rng.next_u64() % all.len() as u64) as usize];
            (q.clone(), c)
        })
        .collect()
}

/// `n` states uniform in the box `[lower, upper]`, gripper uniform in `[0, 1]`.
pub fn states_uniform(lower: &[f64], upper: &[f64], n: usize, rng: &mut Rng) -> States {
    (0..n)
        .map(|_| {
            let q = lower
                .iter()
                .zip(upper)
                .map(|(lo, hi)| rng.range(*lo, *hi))
                .collect();
            (q, rng.uniform())
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use mapper::model::{FORMAT, NetworkInfo, ObsInputs, TrainingInfo, VERSION};
    use mapper::nn::gram_schmidt::GS_EPSILON;
    use mapper::nn::lipschitz;
    use mapper::rng::Rng;
    use nalgebra::DMatrix;
    use proptest::prelude::*;
    use std::sync::OnceLock;

    /// An SCL model (m = 6, d = 2, hidden 24) with random weights made steep, then bounded
    /// to exactly `l` with respect to the raw observation under a random normalisation.
    fn bounded_scl(seed: u64, l: f64, gram_schmidt: bool) -> NetworkModel {
        let mut r = Rng::new(seed);
        let mut dec = Mlp::init(&[7, 24, 24, 12], &mut r);
        for layer in &mut dec.layers {
            layer.w.iter_mut().for_each(|v| *v *= 4.0);
        }
        let mean: Vec<f64> = (0..7).map(|_| r.range(-1.0, 1.0)).collect();
        let std: Vec<f64> = (0..7).map(|_| r.range(0.2, 2.0)).collect();
        let norm = Normaliser::from_lists(&mean, &std);
        let per = lipschitz::per_layer_bound(l, 3);
        let certified = lipschitz::certify(&mut dec, per, &norm.inv_std());
        assert!(certified <= l);
        header_model(dec, norm, gram_schmidt, Some(certified))
    }

    fn header_model(
        dec: Mlp,
        norm: Normaliser,
        gram_schmidt: bool,
        bound: Option<f64>,
    ) -> NetworkModel {
        let header = ModelHeader {
            format: FORMAT.into(),
            version: VERSION,
            kind: ModelKind::Scl,
            n_joints: 6,
            latent_dim: 2,
            joint_names: crate::train::joint_names(6),
            speed_scale_rad_s: 1.0,
            lipschitz_bound: bound,
            network: Some(NetworkInfo {
                inputs: ObsInputs::JointsAndGripper,
                input_mean: norm.mean_list(),
                input_std: norm.std_list(),
                hidden: dec.layers[..dec.layers.len() - 1]
                    .iter()
                    .map(|l| l.n_out)
                    .collect(),
                gram_schmidt,
                gs_epsilon: f64::from(GS_EPSILON),
                encoder: EncoderKind::None,
                encoder_input_mean: Vec::new(),
                encoder_input_std: Vec::new(),
                li_losses: None,
            }),
            training: TrainingInfo::default(),
        };
        NetworkModel::new(header, dec, None).unwrap()
    }

    /// `h(q, c)` in f64 (exact tanh), through the model's normalisation.
    fn h_f64(model: &NetworkModel, q: &[f64], c: f64) -> DMatrix<f64> {
        let info = model.info();
        let mut x: Vec<f64> = q.to_vec();
        x.push(c);
        for (i, v) in x.iter_mut().enumerate() {
            *v = (*v - info.input_mean[i]) / info.input_std[i];
        }
        let v = model.decoder().forward_f64(&x);
        DMatrix::from_row_slice(6, 2, &v)
    }

    /// One SCL model trained on a little data with L = 1 and no Gram-Schmidt.
    fn trained_scl() -> &'static NetworkModel {
        static MODEL: OnceLock<NetworkModel> = OnceLock::new();
        MODEL.get_or_init(|| {
            let ds = crate::demos::joint_reach(3, 1, 11);
            let cfg = crate::train::TrainConfig {
                hidden: vec![24, 24],
                epochs: 4,
                seeds: 1,
                threads: 1,
                gram_schmidt: false,
                ..crate::train::TrainConfig::default()
            };
            let out = crate::train::train(&cfg, &ds, "test", &|_| {}, &Default::default()).unwrap();
            assert!(out.model.header().lipschitz_bound.unwrap() <= 1.0);
            out.model
        })
    }

    /// Checks the theorem's inequality in f64 for one state and action; returns
    /// `(|T(T(q,a),−a) − q|, |T(q,a) − q|)`.
    fn one_step(model: &NetworkModel, q: &[f64], c: f64, a: &[f64; 2], step: f64) -> (f64, f64) {
        let a = nalgebra::DVector::from_row_slice(a);
        let q0 = nalgebra::DVector::from_row_slice(q);
        let qj = &q0 + step * (h_f64(model, q, c) * &a);
        let qk = &qj - step * (h_f64(model, qj.as_slice(), c) * &a);
        ((qk - &q0).norm(), (qj - q0).norm())
    }

    proptest! {
        /// Theorem 1 (soft reversibility), sampled: `L ≤ 1` with respect to the raw
        /// observation, no Gram-Schmidt, `|a| < 1`, `Δ·s ≤ 1` (the paper's `T` is `Δ·s = 1`):
        /// returning with `−a` ends strictly closer to the start than the forward step went.
        #[test]
        fn soft_reversibility_holds_for_bounded_random_networks(
            seed in 0u64..1000,
            l in 0.05f64..=1.0,
            step in 0.01f64..=1.0,
            q in proptest::collection::vec(-2.6f64..2.6, 6),
            c in 0.0f64..=1.0,
            theta in 0.0f64..std::f64::consts::TAU,
            norm in 0.0f64..0.999,
        ) {
            let model = bounded_scl(seed, l, false);
            let a = [norm * theta.cos(), norm * theta.sin()];
            let (back, fwd) = one_step(&model, &q, c, &a, step);
            prop_assume!(fwd > 0.0);
            prop_assert!(back < fwd, "back {back} >= forward {fwd}");
            prop_assert!(back <= step * l * norm * fwd * (1.0 + 1e-9) + 1e-15);
        }

        /// The same for a model trained by `train` (L = 1, no Gram-Schmidt), through the
        /// served f32 map for the forward step and exact arithmetic for the inequality.
        #[test]
        fn soft_reversibility_holds_for_a_trained_network(
            q in proptest::collection::vec(-2.6f64..2.6, 6),
            theta in 0.0f64..std::f64::consts::TAU,
            norm in 0.0f64..0.999,
        ) {
            let model = trained_scl();
            let a = [norm * theta.cos(), norm * theta.sin()];
            let (back, fwd) = one_step(model, &q, 0.0, &a, 1.0);
            prop_assume!(fwd > 0.0);
            prop_assert!(back < fwd, "back {back} >= forward {fwd}");
            // The served f32 map computes the same H a.
            let mut map = model.clone().into_map();
            let mut out = [0.0; 6];
            map.eval(&q, 0.0, &a, &mut out);
            let exact = h_f64(model, &q, 0.0) * nalgebra::DVector::from_row_slice(&a);
            for i in 0..6 {
                prop_assert!((out[i] - exact[i]).abs() < 1e-5);
            }
        }
    }

    /// The inequality is not vacuous: without the bound it fails.
    #[test]
    fn soft_reversibility_fails_for_steep_networks() {
        let mut r = Rng::new(3);
        let mut dec = Mlp::init(&[7, 24, 24, 12], &mut r);
        for layer in &mut dec.layers {
            layer.w.iter_mut().for_each(|v| *v *= 6.0);
        }
        let model = header_model(dec, Normaliser::identity(7), false, None);
        let mut failures = 0;
        for _ in 0..200 {
            let q: Vec<f64> = (0..6).map(|_| r.range(-2.6, 2.6)).collect();
            let t = r.range(0.0, std::f64::consts::TAU);
            let (back, fwd) = one_step(&model, &q, 0.0, &[0.95 * t.cos(), 0.95 * t.sin()], 1.0);
            if back >= fwd {
                failures += 1;
            }
        }
        assert!(failures > 0);
    }

    #[test]
    fn experiments_measure_known_maps() {
        // PCA is state-independent: going back returns exactly.
        let basis = DMatrix::from_fn(6, 2, |i, j| if i == j { 1.0 } else { 0.0 });
        let mut pca = PcaMap::new(basis);
        let mut rng = Rng::new(1);
        let states = states_uniform(&[-1.0; 6], &[1.0; 6], 50, &mut rng);
        let r = reversibility(&mut pca, &states, 0.1, 40, 1.0, &mut rng);
        assert_eq!(r.one_step.held, 50);
        assert_eq!(r.repeated.held, 50);
        assert!(r.one_step.worst_ratio < 1e-12);
        // A steep bounded-free network fails some of the time.
        let model = bounded_scl(5, 1.0, true);
        let mut map = model.into_map();
        let r = reversibility(map.as_mut(), &states, 0.025, 40, 1.0, &mut rng);
        assert_eq!(r.one_step.total + r.one_step.no_motion, 50);
        assert!(r.one_step.value() >= 0.0 && r.one_step.value() <= 1.0);
    }
}
