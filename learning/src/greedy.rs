//! The paper's simulated greedy user (Section "Simulation Experiments for Human Prior
//! Configuration"): at every step it draws candidate actions `a ~ N(0, I)` and takes the one
//! whose next joint state is closest to the goal,
//!
//! ```text
//! a* = argmin_a |q* − T(q_t, a)|,   T(q, a) = clamp(q + Δ · s · map(q, c, a)),
//! ```
//!
//! where `s` is the model's speed scale and `Δ` the control period (the paper writes
//! `q_t + g(o, a)`, treating the decoder's output as joint velocities; here they are integrated
//! over one period, as the served command is). With [`GreedyConfig::clip`] (the default) the
//! action is clamped radially to `|a| <= 1` before the map, as the mapper does with a joystick
//! sample ([`crate::rollout::served_command`]); without it the Gaussian sample is used as
//! drawn (the paper's literal formula). The state is clamped into the joint limits when
//! [`GreedyConfig::limits`] are given.
//!
//! The candidates are evaluated in one batch per step ([`BatchMap`]): a map linear in `a`
//! (PCA, SCL with or without Gram-Schmidt) is evaluated once per column of `H(q)` and the
//! candidates are cheap matrix-vector products ([`LinearBatch`]); a CAE decoder runs over all
//! candidates as one batched forward pass ([`NetBatch`]). The transition itself always uses
//! the served map ([`mapper::ActionMap::eval`]), so the user moves exactly as the mapper would
//! move the arm.
//!
//! [`GreedyUser::forward_back`] runs the paper's evaluation of one test trajectory: from its
//! start to its end state, then from wherever that got to back to the start, and reports both
//! final joint-space distances.

use crate::eval::AnyModel;
use mapper::ActionMap;
use mapper::model::{ModelKind, ObsInputs};
use mapper::network::{Normaliser, observation};
use mapper::nn::{BatchCache, Mlp};
use mapper::rng::Rng;

/// The paper's number of candidate actions per step.
pub const PAPER_CANDIDATES: usize = 4096;

/// Rows of one batched decoder pass (the candidates are split into chunks of this size, so
/// the activations stay in cache).
const CHUNK: usize = 512;

/// Why a greedy run could not start.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GreedyError {
    /// No candidates to choose from.
    #[error("the greedy user needs at least one candidate action per step")]
    NoCandidates,
    /// The control period or the speed scale is unusable.
    #[error("time step {dt_s} s and speed scale {speed_scale} rad/s must be positive and finite")]
    Step {
        /// The period (s).
        dt_s: f64,
        /// The speed scale (rad/s).
        speed_scale: f64,
    },
    /// A vector has the wrong length.
    #[error("{what} has {found} values, the model drives {expected} joints")]
    Length {
        /// Which vector.
        what: &'static str,
        /// Its length.
        found: usize,
        /// The model's joint count.
        expected: usize,
    },
    /// A vector holds NaN or infinity.
    #[error("{0} is not finite")]
    NonFinite(&'static str),
    /// The joint limits are inconsistent.
    #[error("joint limits: lower {lower} > upper {upper} at joint {joint}")]
    Limits {
        /// The joint.
        joint: usize,
        /// Its lower limit.
        lower: f64,
        /// Its upper limit.
        upper: f64,
    },
    /// The batched and the served map disagree on their dimensions.
    #[error("the batched map is {batch_m} x {batch_d}, the served map {served_m} x {served_d}")]
    Mismatch {
        /// Batched map's joints.
        batch_m: usize,
        /// Batched map's action dimension.
        batch_d: usize,
        /// Served map's joints.
        served_m: usize,
        /// Served map's action dimension.
        served_d: usize,
    },
}

/// How the greedy user acts.
#[derive(Debug, Clone, PartialEq)]
pub struct GreedyConfig {
    /// Candidate actions per step (the paper's 4096).
    pub candidates: usize,
    /// Control period `Δ` (s): one step integrates the command over it.
    pub dt_s: f64,
    /// Clamp each action radially to `|a| <= 1` (the served command's joystick contract).
    pub clip: bool,
    /// Joint limits `(lower, upper)` the state is clamped into, if any.
    pub limits: Option<(Vec<f64>, Vec<f64>)>,
}

impl Default for GreedyConfig {
    /// The paper's 4096 candidates, one 40 Hz period, clipped actions, no limits.
    fn default() -> Self {
        Self {
            candidates: PAPER_CANDIDATES,
            dt_s: crate::demos::DT,
            clip: true,
            limits: None,
        }
    }
}

/// A map evaluated for many actions at one state.
pub trait BatchMap: Send {
    /// Joints `m` of the output.
    fn n_joints(&self) -> usize;
    /// Action dimension `d`.
    fn latent_dim(&self) -> usize;
    /// Writes `map(q, c, a_k)` into `out[k·m..(k+1)·m]` for the `n` actions `a_k =
    /// actions[k·d..(k+1)·d]` (before the speed scale).
    fn eval_batch(&mut self, q: &[f64], c: f64, actions: &[f64], n: usize, out: &mut [f64]);
}

/// A map linear in the action, `map(q, c, a) = H(q, c) a` (PCA, SCL): `H`'s columns are
/// evaluated once per state through the served map, then every action is a matrix-vector
/// product.
pub struct LinearBatch {
    map: Box<dyn ActionMap>,
    m: usize,
    d: usize,
    /// Column-major `H` (`d` columns of `m`).
    cols: Vec<f64>,
    unit: Vec<f64>,
}

impl LinearBatch {
    /// Wraps a map that is linear in `a` (the caller's promise: PCA or SCL).
    pub fn new(map: Box<dyn ActionMap>) -> Self {
        let (m, d) = (map.n_joints(), map.latent_dim());
        Self {
            map,
            m,
            d,
            cols: vec![0.0; m * d],
            unit: vec![0.0; d],
        }
    }
}

impl BatchMap for LinearBatch {
    fn n_joints(&self) -> usize {
        self.m
    }
    fn latent_dim(&self) -> usize {
        self.d
    }
    fn eval_batch(&mut self, q: &[f64], c: f64, actions: &[f64], n: usize, out: &mut [f64]) {
        let (m, d) = (self.m, self.d);
        for j in 0..d {
            self.unit.fill(0.0);
            self.unit[j] = 1.0;
            self.map
                .eval(q, c, &self.unit, &mut self.cols[j * m..(j + 1) * m]);
        }
        for (a, o) in actions.chunks_exact(d).zip(out.chunks_exact_mut(m)).take(n) {
            o.fill(0.0);
            for (aj, col) in a.iter().zip(self.cols.chunks_exact(m)) {
                for (oi, hi) in o.iter_mut().zip(col) {
                    *oi += hi * aj;
                }
            }
        }
    }
}

/// A CAE decoder `g(x, a)` run over a batch of actions at once (the training code's batched
/// forward pass; it agrees with the served single-sample kernel to f32 rounding).
pub struct NetBatch {
    decoder: Mlp,
    norm: Normaliser,
    inputs: ObsInputs,
    m: usize,
    d: usize,
    cache: BatchCache,
    obs: Vec<f64>,
    xo: Vec<f32>,
    x: Vec<f32>,
}

impl NetBatch {
    /// The batched decoder of a CAE model (`None` for other kinds).
    pub fn new(model: &AnyModel) -> Option<Self> {
        let AnyModel::Net(net) = model else {
            return None;
        };
        if net.header().kind != ModelKind::Cae {
            return None;
        }
        let (m, d) = (net.header().n_joints, net.header().latent_dim);
        let inputs = net.info().inputs;
        let width = inputs.width(m) + d;
        let decoder = net.decoder().clone();
        let cache = BatchCache::new(&decoder, CHUNK);
        Some(Self {
            norm: net.obs_normaliser(),
            inputs,
            m,
            d,
            cache,
            obs: vec![0.0; m + 1],
            xo: vec![0.0; m + 1],
            x: vec![0.0; CHUNK * width],
            decoder,
        })
    }
}

impl BatchMap for NetBatch {
    fn n_joints(&self) -> usize {
        self.m
    }
    fn latent_dim(&self) -> usize {
        self.d
    }
    fn eval_batch(&mut self, q: &[f64], c: f64, actions: &[f64], n: usize, out: &mut [f64]) {
        let (m, d) = (self.m, self.d);
        let n_obs = observation(self.inputs, &q[..m], c, &mut self.obs);
        self.norm.apply(&self.obs[..n_obs], &mut self.xo);
        let width = n_obs + d;
        let mut start = 0;
        while start < n {
            let rows = CHUNK.min(n - start);
            for (r, row) in self.x.chunks_exact_mut(width).take(rows).enumerate() {
                row[..n_obs].copy_from_slice(&self.xo[..n_obs]);
                let a = &actions[(start + r) * d..(start + r + 1) * d];
                for (x, a) in row[n_obs..].iter_mut().zip(a) {
                    *x = *a as f32;
                }
            }
            self.decoder
                .forward_batch(&self.x[..rows * width], rows, &mut self.cache);
            for (o, y) in out[start * m..(start + rows) * m]
                .iter_mut()
                .zip(self.cache.output())
            {
                *o = f64::from(*y);
            }
            start += rows;
        }
    }
}

/// The batched evaluation of any model file's map: [`LinearBatch`] for PCA and SCL,
/// [`NetBatch`] for CAE.
pub fn batch_map(model: &AnyModel) -> Box<dyn BatchMap> {
    match NetBatch::new(model) {
        Some(b) => Box::new(b),
        None => Box::new(LinearBatch::new(model.map())),
    }
}

/// The outcome of one leg: where the user ended and how far from the goal.
#[derive(Debug, Clone, PartialEq)]
pub struct Leg {
    /// The final joint state.
    pub q: Vec<f64>,
    /// `|q* − q_final|` (rad).
    pub error: f64,
}

/// The outcome of [`GreedyUser::forward_back`].
#[derive(Debug, Clone, PartialEq)]
pub struct ForwardBack {
    /// `|q_start − q_end|`: how far the goal was (rad).
    pub start_distance: f64,
    /// From the start towards the end state.
    pub forward: Leg,
    /// From where the forward leg ended back towards the start.
    pub back: Leg,
}

/// The greedy user of one model, with its buffers (allocated once).
pub struct GreedyUser {
    batch: Box<dyn BatchMap>,
    served: Box<dyn ActionMap>,
    speed_scale: f64,
    cfg: GreedyConfig,
    m: usize,
    d: usize,
    actions: Vec<f64>,
    outputs: Vec<f64>,
    cmd: Vec<f64>,
    next: Vec<f64>,
    chosen: Vec<f64>,
}

impl std::fmt::Debug for GreedyUser {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GreedyUser")
            .field("speed_scale", &self.speed_scale)
            .field("cfg", &self.cfg)
            .field("m", &self.m)
            .field("d", &self.d)
            .finish_non_exhaustive()
    }
}

impl GreedyUser {
    /// The greedy user of a model file (its served map, its speed scale).
    pub fn new(model: &AnyModel, cfg: GreedyConfig) -> Result<Self, GreedyError> {
        Self::from_maps(
            batch_map(model),
            model.map(),
            model.header().speed_scale_rad_s,
            cfg,
        )
    }

    /// The greedy user of a batched map, the served map it stands for, and the speed scale.
    pub fn from_maps(
        batch: Box<dyn BatchMap>,
        served: Box<dyn ActionMap>,
        speed_scale: f64,
        cfg: GreedyConfig,
    ) -> Result<Self, GreedyError> {
        if cfg.candidates == 0 {
            return Err(GreedyError::NoCandidates);
        }
        if !(cfg.dt_s.is_finite() && cfg.dt_s > 0.0 && speed_scale.is_finite() && speed_scale > 0.0)
        {
            return Err(GreedyError::Step {
                dt_s: cfg.dt_s,
                speed_scale,
            });
        }
        let (m, d) = (served.n_joints(), served.latent_dim());
        if (batch.n_joints(), batch.latent_dim()) != (m, d) {
            return Err(GreedyError::Mismatch {
                batch_m: batch.n_joints(),
                batch_d: batch.latent_dim(),
                served_m: m,
                served_d: d,
            });
        }
        if let Some((lo, hi)) = &cfg.limits {
            check_len("lower limits", lo, m)?;
            check_len("upper limits", hi, m)?;
            if let Some(j) = (0..m).find(|&j| lo[j] > hi[j] || lo[j].is_nan() || hi[j].is_nan()) {
                return Err(GreedyError::Limits {
                    joint: j,
                    lower: lo[j],
                    upper: hi[j],
                });
            }
        }
        let n = cfg.candidates;
        Ok(Self {
            batch,
            served,
            speed_scale,
            m,
            d,
            actions: vec![0.0; n * d],
            outputs: vec![0.0; n * m],
            cmd: vec![0.0; m],
            next: vec![0.0; m],
            chosen: vec![0.0; d],
            cfg,
        })
    }

    /// Joints of the model.
    pub fn n_joints(&self) -> usize {
        self.m
    }

    /// One step from `q` (updated in place; `q` and `goal` hold `m` values, checked by the
    /// callers) towards `goal`: draws the candidates from `rng`, picks the best and moves
    /// with the served map. Returns the chosen action (as applied, i.e. clipped when the
    /// configuration says so; zero when every candidate's output was non-finite).
    fn step(&mut self, q: &mut [f64], c: f64, goal: &[f64], rng: &mut Rng) -> &[f64] {
        let (m, d, n) = (self.m, self.d, self.cfg.candidates);
        for a in self.actions.chunks_exact_mut(d) {
            for v in a.iter_mut() {
                *v = rng.normal();
            }
            if self.cfg.clip {
                clip_unit(a);
            }
        }
        self.batch
            .eval_batch(q, c, &self.actions, n, &mut self.outputs);
        let gain = self.cfg.dt_s * self.speed_scale;
        let mut best = (f64::INFINITY, usize::MAX);
        for (k, y) in self.outputs.chunks_exact(m).enumerate() {
            if y.iter().any(|v| !v.is_finite()) {
                continue;
            }
            let mut dist2 = 0.0;
            for (j, ((qj, gj), yj)) in q.iter().zip(goal).zip(y).enumerate() {
                let next = clamp(&self.cfg.limits, j, qj + gain * yj);
                dist2 += (gj - next).powi(2);
            }
            if dist2 < best.0 {
                best = (dist2, k);
            }
        }
        if best.1 == usize::MAX {
            // Every candidate's output was non-finite: the served command is zero.
            self.chosen.fill(0.0);
            return &self.chosen;
        }
        self.chosen
            .copy_from_slice(&self.actions[best.1 * d..(best.1 + 1) * d]);
        self.served.eval(q, c, &self.chosen, &mut self.cmd);
        if self.cmd.iter().all(|v| v.is_finite()) {
            for (j, ((n, qj), v)) in self.next.iter_mut().zip(&*q).zip(&self.cmd).enumerate() {
                *n = clamp(&self.cfg.limits, j, qj + gain * v);
            }
            q[..m].copy_from_slice(&self.next);
        }
        &self.chosen
    }

    /// `steps` greedy steps from `start` towards `goal`; the candidates come from `rng`.
    pub fn reach(
        &mut self,
        start: &[f64],
        c: f64,
        goal: &[f64],
        steps: usize,
        rng: &mut Rng,
    ) -> Result<Leg, GreedyError> {
        check_len("start", start, self.m)?;
        check_len("goal", goal, self.m)?;
        if !c.is_finite() {
            return Err(GreedyError::NonFinite("gripper"));
        }
        let mut q = start.to_vec();
        for _ in 0..steps {
            self.step(&mut q, c, goal, rng);
        }
        let error = crate::rollout::distance(goal, &q);
        Ok(Leg { q, error })
    }

    /// The paper's evaluation of one test trajectory: `steps_forward` steps from `start`
    /// towards `end`, then `steps_back` steps from there back towards `start`.
    pub fn forward_back(
        &mut self,
        start: &[f64],
        end: &[f64],
        c: f64,
        steps_forward: usize,
        steps_back: usize,
        rng: &mut Rng,
    ) -> Result<ForwardBack, GreedyError> {
        let forward = self.reach(start, c, end, steps_forward, rng)?;
        let back = self.reach(&forward.q, c, start, steps_back, rng)?;
        Ok(ForwardBack {
            start_distance: crate::rollout::distance(start, end),
            forward,
            back,
        })
    }
}

/// `v` clamped into joint `j`'s limits, if any.
#[inline]
fn clamp(limits: &Option<(Vec<f64>, Vec<f64>)>, j: usize, v: f64) -> f64 {
    match limits {
        Some((lo, hi)) => v.clamp(lo[j], hi[j]),
        None => v,
    }
}

/// Clamps `a` radially to the unit ball (the served command's arithmetic).
fn clip_unit(a: &mut [f64]) {
    let norm = a.iter().map(|v| v * v).sum::<f64>().sqrt();
    if norm > 1.0 {
        a.iter_mut().for_each(|v| *v /= norm);
    }
}

fn check_len(what: &'static str, v: &[f64], m: usize) -> Result<(), GreedyError> {
    if v.len() != m {
        return Err(GreedyError::Length {
            what,
            found: v.len(),
            expected: m,
        });
    }
    if v.iter().any(|x| !x.is_finite()) {
        return Err(GreedyError::NonFinite(what));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use mapper::model::{EncoderKind, FORMAT, ModelHeader, NetworkInfo, TrainingInfo, VERSION};
    use mapper::network::{NetworkModel, decoder_widths};

    /// `map(q, a) = H a` with a fixed `H` (5 × 2), orthonormal columns.
    #[derive(Clone)]
    struct Constant {
        h: [[f64; 2]; 5],
    }

    impl Constant {
        fn new() -> Self {
            let s = 0.5f64.sqrt();
            Self {
                h: [[s, 0.0], [s, 0.0], [0.0, 1.0], [0.0, 0.0], [0.0, 0.0]],
            }
        }
    }

    impl ActionMap for Constant {
        fn kind(&self) -> ModelKind {
            ModelKind::Pca
        }
        fn n_joints(&self) -> usize {
            5
        }
        fn latent_dim(&self) -> usize {
            2
        }
        fn eval(&mut self, _q: &[f64], _c: f64, a: &[f64], out: &mut [f64]) {
            for (o, row) in out.iter_mut().zip(&self.h) {
                *o = row[0] * a[0] + row[1] * a[1];
            }
        }
    }

    fn user(candidates: usize, clip: bool) -> GreedyUser {
        let cfg = GreedyConfig {
            candidates,
            dt_s: 0.025,
            clip,
            limits: None,
        };
        GreedyUser::from_maps(
            Box::new(LinearBatch::new(Box::new(Constant::new()))),
            Box::new(Constant::new()),
            2.0,
            cfg,
        )
        .unwrap()
    }

    #[test]
    fn greedy_reaches_a_goal_in_the_span_and_comes_back() {
        let start = [0.1, -0.2, 0.3, 0.4, -0.5];
        // 0.6 along the first column, -0.4 along the second: in the span.
        let s = 0.5f64.sqrt();
        let end: Vec<f64> = start
            .iter()
            .zip([0.6 * s, 0.6 * s, -0.4, 0.0, 0.0])
            .map(|(a, b)| a + b)
            .collect();
        let mut u = user(4096, true);
        let mut rng = Rng::new(3);
        // At most 0.05 rad per step: 0.72 rad takes at least 15 steps.
        let r = u.forward_back(&start, &end, 0.0, 40, 40, &mut rng).unwrap();
        assert!((r.start_distance - 0.52f64.sqrt()).abs() < 1e-12);
        assert!(r.forward.error < 5e-3, "{r:?}");
        assert!(r.back.error < 5e-3, "{r:?}");
        // Too few steps to get there: clipped actions move at most dt * s per step.
        let short = u.reach(&start, 0.0, &end, 5, &mut rng).unwrap();
        assert!(
            short.error > r.start_distance - 5.0 * 0.05 - 1e-9,
            "{short:?}"
        );
    }

    #[test]
    fn the_part_of_the_goal_outside_the_span_stays() {
        let start = [0.0; 5];
        let end = [0.0, 0.0, 0.2, 0.3, 0.0];
        let mut u = user(1024, true);
        let leg = u.reach(&start, 0.0, &end, 30, &mut Rng::new(1)).unwrap();
        assert!((leg.error - 0.3).abs() < 2e-3, "{leg:?}");
        // Joint 4 never moves.
        assert_eq!(leg.q[3], 0.0);
    }

    #[test]
    fn clipping_bounds_each_step_and_limits_hold() {
        let start = [0.0; 5];
        let end = [0.0, 0.0, 10.0, 0.0, 0.0];
        let mut q = start;
        let mut u = user(4096, true);
        let mut rng = Rng::new(9);
        let a = u.step(&mut q, 0.0, &end, &mut rng).to_vec();
        let norm = (a[0] * a[0] + a[1] * a[1]).sqrt();
        assert!(norm <= 1.0 + 1e-12 && norm > 0.99, "{a:?}");
        assert!((q[2] - 0.05).abs() < 1e-3, "{q:?}");
        // Unclipped, the best of 4096 Gaussian samples goes much further.
        let mut q = start;
        user(4096, false).step(&mut q, 0.0, &end, &mut Rng::new(9));
        assert!(q[2] > 0.1, "{q:?}");
        // A joint limit stops the state.
        let mut limited = user(256, true);
        limited.cfg.limits = Some((vec![-1.0; 5], vec![1.0, 1.0, 0.12, 1.0, 1.0]));
        let leg = limited
            .reach(&start, 0.0, &end, 20, &mut Rng::new(2))
            .unwrap();
        assert!((leg.q[2] - 0.12).abs() < 1e-12, "{leg:?}");
    }

    #[test]
    fn deterministic_per_seed() {
        let start = [0.0; 5];
        let end = [0.3, 0.2, -0.1, 0.0, 0.1];
        let run = |seed| {
            user(64, true)
                .forward_back(&start, &end, 0.0, 10, 10, &mut Rng::new(seed))
                .unwrap()
        };
        assert_eq!(run(4), run(4));
        assert_ne!(run(4), run(5));
    }

    #[test]
    fn refuses_bad_inputs() {
        let err = |cfg: GreedyConfig, s: f64| {
            GreedyUser::from_maps(
                Box::new(LinearBatch::new(Box::new(Constant::new()))),
                Box::new(Constant::new()),
                s,
                cfg,
            )
            .unwrap_err()
        };
        let ok = GreedyConfig::default();
        assert_eq!(
            err(
                GreedyConfig {
                    candidates: 0,
                    ..ok.clone()
                },
                1.0
            ),
            GreedyError::NoCandidates
        );
        assert!(matches!(err(ok.clone(), 0.0), GreedyError::Step { .. }));
        assert!(matches!(
            err(
                GreedyConfig {
                    limits: Some((vec![0.0; 5], vec![-1.0; 5])),
                    ..ok.clone()
                },
                1.0
            ),
            GreedyError::Limits { joint: 0, .. }
        ));
        let mut u = user(8, true);
        let e = u
            .reach(&[0.0; 4], 0.0, &[0.0; 5], 1, &mut Rng::new(1))
            .unwrap_err();
        assert!(e.to_string().contains("start has 4 values"), "{e}");
        let e = u
            .reach(&[0.0; 5], 0.0, &[f64::NAN; 5], 1, &mut Rng::new(1))
            .unwrap_err();
        assert_eq!(e, GreedyError::NonFinite("goal"));
    }

    fn cae_model() -> AnyModel {
        let (m, d) = (5, 2);
        let header = ModelHeader {
            format: FORMAT.into(),
            version: VERSION,
            kind: ModelKind::Cae,
            n_joints: m,
            latent_dim: d,
            joint_names: (1..=m).map(|i| format!("joint_{i}")).collect(),
            speed_scale_rad_s: 0.5,
            lipschitz_bound: None,
            network: Some(NetworkInfo {
                inputs: ObsInputs::JointsAndGripper,
                input_mean: vec![0.1; m + 1],
                input_std: vec![0.7; m + 1],
                hidden: vec![16, 16],
                gram_schmidt: false,
                gs_epsilon: 1e-8,
                encoder: EncoderKind::None,
                encoder_input_mean: Vec::new(),
                encoder_input_std: Vec::new(),
                li_losses: None,
            }),
            training: TrainingInfo::default(),
        };
        let info = header.network.clone().unwrap();
        let dec = Mlp::init(
            &decoder_widths(ModelKind::Cae, &info, m, d),
            &mut Rng::new(7),
        );
        AnyModel::Net(Box::new(NetworkModel::new(header, dec, None).unwrap()))
    }

    #[test]
    fn the_batched_cae_decoder_is_the_served_one() {
        let model = cae_model();
        let mut batch = batch_map(&model);
        let mut served = model.map();
        let n = CHUNK + 37;
        let mut rng = Rng::new(2);
        let actions: Vec<f64> = (0..2 * n).map(|_| rng.normal()).collect();
        let q = [0.3, -0.2, 0.5, 0.0, 1.0];
        let mut out = vec![0.0; 5 * n];
        batch.eval_batch(&q, 0.0, &actions, n, &mut out);
        let mut one = [0.0; 5];
        for k in 0..n {
            served.eval(&q, 0.0, &actions[2 * k..2 * k + 2], &mut one);
            for j in 0..5 {
                assert!((one[j] - out[5 * k + j]).abs() < 1e-5, "{k} {j}");
            }
        }
        // And the whole user runs on it.
        let mut u = GreedyUser::new(&model, GreedyConfig::default()).unwrap();
        let r = u
            .forward_back(&q, &[0.0; 5], 0.0, 5, 5, &mut Rng::new(1))
            .unwrap();
        assert!(r.forward.error.is_finite() && r.back.error.is_finite());
    }
}
