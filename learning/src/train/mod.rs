//! Training of the network maps (SCL and the CAE baseline) on demonstrations.
//!
//! The paper's procedure and defaults ([`TrainConfig::default`]): an autoencoder trained with
//! mean squared error on `qdot`, Adam (learning rate 1e-3, PyTorch's betas and eps, no weight
//! decay), mini-batches of 256 reshuffled every epoch, 200 epochs, two hidden layers of 256
//! with tanh in both encoder and decoder, 10 seeds of which the one with the lowest
//! validation loss is kept (each seed keeps its weights from its best epoch).
//!
//! * SCL: `ŷ = GS(h(x)) · f(x_e)`, with `h` Lipschitz-bounded (L = 1 by default) by
//!   projecting its weights after every step ([`mapper::nn::lipschitz`]); the encoder `f` is an
//!   MLP on `(o, qdot)` or, optionally, the analytic `a = H'ᵀ y`.
//! * CAE: `ŷ = g(x, f(x_e))`, optionally with the Li et al. terms ([`li`]).
//!
//! Targets are in speed-scale units, `y = qdot / s` (the mapper multiplies by `s`); reported
//! losses are converted back to `(rad/s)²`, averaged over tuples and joints (PyTorch's
//! `MSELoss`), so they compare directly with PCA's.
//!
//! Every seed is deterministic: its weights, batch order and sampled values come from
//! [`Rng`] seeded with `base_seed + index`, and the arithmetic is single-threaded, so the
//! result does not depend on how many seeds run in parallel (a rayon pool of
//! [`TrainConfig::threads`], one seed per task; results are collected in seed order).

pub mod li;

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use rayon::prelude::*;

use crate::dataset::Dataset;
use mapper::model::{
    EncoderKind, FORMAT, LiLosses, ModelError, ModelHeader, ModelKind, NetworkInfo, ObsInputs,
    TrainSettings, TrainingInfo, VERSION,
};
use mapper::network::{self, NetworkModel, Normaliser};
use mapper::nn::gram_schmidt::{self, GS_EPSILON, MAX_COLUMNS};
use mapper::nn::lipschitz::{self, PowerIteration};
use mapper::nn::{Adam, BatchCache, Mlp};
use mapper::rng::Rng;

/// Everything `train` needs to know besides the data.
#[derive(Debug, Clone, PartialEq)]
pub struct TrainConfig {
    /// `Scl` or `Cae`.
    pub kind: ModelKind,
    /// Action dimension `d`.
    pub latent_dim: usize,
    /// Hidden widths of decoder and encoder.
    pub hidden: Vec<usize>,
    /// Epochs per seed.
    pub epochs: usize,
    /// Mini-batch size.
    pub batch: usize,
    /// Adam learning rate.
    pub learning_rate: f64,
    /// Seeds to train; the best by validation loss is kept.
    pub seeds: usize,
    /// Seed of the first run (run `i` uses `base_seed + i`).
    pub base_seed: u64,
    /// Seeds trained at once, one thread each (0: one per CPU).
    pub threads: usize,
    /// Lipschitz bound `L` of the decoder with respect to the raw observation (SCL).
    pub lipschitz: Option<f64>,
    /// Power iterations per optimiser step of the projection.
    pub power_iterations: usize,
    /// Orthonormalise `H` (SCL).
    pub gram_schmidt: bool,
    /// The training encoder (SCL: `Mlp` or `Projection`; CAE: `Mlp`).
    pub encoder: EncoderKind,
    /// What the decoder conditions on.
    pub inputs: ObsInputs,
    /// Speed scale `s` (rad/s); the data's 95th percentile joint speed when `None`.
    pub speed_scale: Option<f64>,
    /// Li et al. terms (CAE only).
    pub li: Option<LiLosses>,
}

impl Default for TrainConfig {
    /// The paper's SCL settings: d = 2, 2 × 256 tanh, 200 epochs, batch 256, lr 1e-3, 10
    /// seeds, L = 1, Gram-Schmidt, MLP encoder, input `(q, c)`.
    fn default() -> Self {
        Self {
            kind: ModelKind::Scl,
            latent_dim: 2,
            hidden: vec![256, 256],
            epochs: 200,
            batch: 256,
            learning_rate: 1e-3,
            seeds: 10,
            base_seed: 0,
            threads: 0,
            lipschitz: Some(1.0),
            power_iterations: 1,
            gram_schmidt: true,
            encoder: EncoderKind::Mlp,
            inputs: ObsInputs::JointsAndGripper,
            speed_scale: None,
            li: None,
        }
    }
}

impl TrainConfig {
    /// The paper's CAE settings: as [`TrainConfig::default`] without the SCL-only parts.
    pub fn cae() -> Self {
        Self {
            kind: ModelKind::Cae,
            lipschitz: None,
            gram_schmidt: false,
            ..Self::default()
        }
    }
}

/// Why training could not run or finish.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    /// An option is out of range or contradicts another.
    #[error("training option {option}: {reason}")]
    Config {
        /// The option.
        option: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// The data set cannot be trained on.
    #[error("training data: {0}")]
    Data(String),
    /// A seed's loss became non-finite.
    #[error("seed {seed} diverged at epoch {epoch} (loss {loss}); lower --lr or check the data")]
    Diverged {
        /// The seed.
        seed: u64,
        /// The epoch.
        epoch: usize,
        /// The loss.
        loss: f64,
    },
    /// Building the model file failed.
    #[error(transparent)]
    Model(#[from] ModelError),
}

/// What a seed reports as it trains.
#[derive(Debug, Clone, PartialEq)]
pub enum Progress {
    /// An epoch finished.
    Epoch {
        /// Index of the seed (0-based).
        seed_index: usize,
        /// Epoch (1-based).
        epoch: usize,
        /// Mean training objective over the epoch's batches ((rad/s)²).
        train_loss: f64,
        /// Validation reconstruction MSE after the epoch ((rad/s)²).
        val_loss: Option<f64>,
    },
}

/// One epoch of one seed in the loss log.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EpochLoss {
    /// Epoch (1-based).
    pub epoch: usize,
    /// Mean training objective over the epoch's batches ((rad/s)²).
    pub train_loss: f64,
    /// Validation reconstruction MSE ((rad/s)²).
    pub val_loss: Option<f64>,
}

/// The run of one seed.
#[derive(Debug, Clone, PartialEq)]
pub struct SeedRun {
    /// The seed.
    pub seed: u64,
    /// Loss per epoch.
    pub history: Vec<EpochLoss>,
    /// Epoch whose weights were kept (lowest validation loss; the last without validation).
    pub best_epoch: usize,
    /// Its validation loss (or final training loss without validation).
    pub best_loss: f64,
}

/// The result of [`train`].
#[derive(Debug, Clone)]
pub struct TrainOutcome {
    /// The best model, ready to write.
    pub model: NetworkModel,
    /// Every seed's run, in seed order.
    pub runs: Vec<SeedRun>,
    /// Index into `runs` of the kept model.
    pub best_index: usize,
    /// Wall time of the training of all seeds (s), excluding data preparation.
    pub train_seconds: f64,
    /// Validation reconstruction MSE of the kept model after certification ((rad/s)²).
    pub validation_loss: Option<f64>,
}

/// The data as the networks see it: normalised inputs and scaled targets, row-major f32.
#[derive(Debug, Clone)]
pub struct TrainData {
    /// Joints `m`.
    pub m: usize,
    /// Observation width.
    pub n_obs: usize,
    /// Speed scale `s`.
    pub speed_scale: f64,
    /// Decoder observation normalisation.
    pub obs_norm: Normaliser,
    /// Encoder input normalisation (on `(o, qdot)`).
    pub enc_norm: Normaliser,
    /// Training split.
    pub train: Split,
    /// Validation split (empty when the data set has none).
    pub val: Split,
}

/// One split, prepared.
#[derive(Debug, Clone, Default)]
pub struct Split {
    /// Tuples.
    pub n: usize,
    /// Normalised observations (`n × n_obs`).
    pub x_obs: Vec<f32>,
    /// Normalised encoder inputs (`n × (n_obs + m)`).
    pub x_enc: Vec<f32>,
    /// Targets `qdot / s` (`n × m`).
    pub y: Vec<f32>,
}

/// The default speed scale: the 95th percentile of the demonstrated joint-speed norm `|qdot|`.
pub fn default_speed_scale(qdot: &[Vec<f64>]) -> Option<f64> {
    let mut norms: Vec<f64> = qdot
        .iter()
        .map(|r| r.iter().map(|v| v * v).sum::<f64>().sqrt())
        .collect();
    if norms.is_empty() {
        return None;
    }
    norms.sort_by(f64::total_cmp);
    let s = norms[((norms.len() as f64 * 0.95) as usize).min(norms.len() - 1)];
    (s.is_finite() && s > 0.0).then_some(s)
}

fn rows(
    ds_trajs: &[crate::dataset::Trajectory],
    inputs: ObsInputs,
) -> (Vec<Vec<f64>>, Vec<Vec<f64>>) {
    let mut obs = Vec::new();
    let mut qdot = Vec::new();
    for t in ds_trajs {
        for k in 0..t.len() {
            let mut o = t.q[k].clone();
            if inputs == ObsInputs::JointsAndGripper {
                o.push(t.c[k]);
            }
            obs.push(o);
            qdot.push(t.qdot[k].clone());
        }
    }
    (obs, qdot)
}

impl TrainData {
    /// Prepares a data set: fits the normalisations on the training split, scales targets.
    pub fn new(
        ds: &Dataset,
        inputs: ObsInputs,
        speed_scale: Option<f64>,
    ) -> Result<Self, TrainError> {
        let (obs, qdot) = rows(&ds.train, inputs);
        let m = qdot.first().map_or(0, Vec::len);
        if obs.len() < 2 || m == 0 {
            return Err(TrainError::Data(format!(
                "{} training tuples; at least 2 are needed",
                obs.len()
            )));
        }
        if m > gram_schmidt::MAX_ROWS {
            return Err(TrainError::Data(format!(
                "{m} joints; at most {} are supported",
                gram_schmidt::MAX_ROWS
            )));
        }
        let s = match speed_scale {
            Some(s) if s.is_finite() && s > 0.0 => s,
            Some(s) => {
                return Err(TrainError::Config {
                    option: "--speed-scale",
                    reason: format!("{s} is not a positive number"),
                });
            }
            None => default_speed_scale(&qdot).ok_or_else(|| {
                TrainError::Data("the demonstrations never move (speed scale 0)".into())
            })?,
        };
        let obs_norm = Normaliser::fit(&obs);
        let enc_rows: Vec<Vec<f64>> = obs
            .iter()
            .zip(&qdot)
            .map(|(o, v)| o.iter().chain(v).copied().collect())
            .collect();
        let enc_norm = Normaliser::fit(&enc_rows);
        let n_obs = obs[0].len();
        let prep = |obs: &[Vec<f64>], qdot: &[Vec<f64>]| -> Split {
            let n = obs.len();
            let mut sp = Split {
                n,
                x_obs: vec![0.0; n * n_obs],
                x_enc: vec![0.0; n * (n_obs + m)],
                y: vec![0.0; n * m],
            };
            let mut raw = vec![0.0f64; n_obs + m];
            for k in 0..n {
                obs_norm.apply(&obs[k], &mut sp.x_obs[k * n_obs..(k + 1) * n_obs]);
                raw[..n_obs].copy_from_slice(&obs[k]);
                raw[n_obs..].copy_from_slice(&qdot[k]);
                enc_norm.apply(&raw, &mut sp.x_enc[k * (n_obs + m)..(k + 1) * (n_obs + m)]);
                for (y, v) in sp.y[k * m..(k + 1) * m].iter_mut().zip(&qdot[k]) {
                    *y = (v / s) as f32;
                }
            }
            sp
        };
        let train = prep(&obs, &qdot);
        let (vobs, vqdot) = rows(&ds.val, inputs);
        let val = prep(&vobs, &vqdot);
        Ok(Self {
            m,
            n_obs,
            speed_scale: s,
            obs_norm,
            enc_norm,
            train,
            val,
        })
    }
}

fn check_config(cfg: &TrainConfig, m: usize) -> Result<(), TrainError> {
    let bad = |option: &'static str, reason: String| Err(TrainError::Config { option, reason });
    if !matches!(cfg.kind, ModelKind::Scl | ModelKind::Cae) {
        return bad("--kind", format!("`{}` is not a network model", cfg.kind));
    }
    if cfg.latent_dim == 0 || cfg.latent_dim > m.min(MAX_COLUMNS) {
        return bad(
            "--latent-dim",
            format!("{} (expected 1..={})", cfg.latent_dim, m.min(MAX_COLUMNS)),
        );
    }
    if cfg.hidden.is_empty()
        || cfg
            .hidden
            .iter()
            .any(|h| *h == 0 || *h > network::MAX_HIDDEN)
    {
        return bad("--hidden", format!("{:?}", cfg.hidden));
    }
    if cfg.epochs == 0 {
        return bad("--epochs", "must be at least 1".into());
    }
    if cfg.batch == 0 {
        return bad("--batch", "must be at least 1".into());
    }
    if cfg.seeds == 0 {
        return bad("--seeds", "must be at least 1".into());
    }
    if !(cfg.learning_rate.is_finite() && cfg.learning_rate > 0.0) {
        return bad(
            "--lr",
            format!("{} is not a positive number", cfg.learning_rate),
        );
    }
    if let Some(l) = cfg.lipschitz
        && !(l.is_finite() && l > 0.0)
    {
        return bad("--lipschitz", format!("{l} is not a positive number"));
    }
    match cfg.kind {
        ModelKind::Cae if cfg.gram_schmidt => {
            return bad("--gram-schmidt", "applies to scl models only".into());
        }
        ModelKind::Cae if cfg.encoder != EncoderKind::Mlp => {
            return bad("--encoder", "a cae model trains an mlp encoder".into());
        }
        ModelKind::Scl if cfg.li.is_some() => {
            return bad(
                "--li-losses",
                "the Li et al. terms apply to cae models only".into(),
            );
        }
        _ => {}
    }
    if cfg.encoder == EncoderKind::None {
        return bad(
            "--encoder",
            "training needs an encoder (mlp or projection)".into(),
        );
    }
    if let Some(li) = &cfg.li {
        if !(li.weight.is_finite() && li.weight >= 0.0) {
            return bad("--li-weight", format!("{}", li.weight));
        }
        if let Some(g) = li.consistency_gamma
            && !(g.is_finite() && g > 0.0)
        {
            return bad("--li-gamma", format!("{g} is not a positive number"));
        }
        if let Some([lo, hi]) = li.proportionality_alpha
            && !(lo.is_finite() && hi.is_finite() && 0.0 < lo && lo <= hi)
        {
            return bad(
                "--li-alpha",
                format!("[{lo}, {hi}] is not a range in (0, inf)"),
            );
        }
        if !(li.step_s.is_finite() && li.step_s > 0.0) {
            return bad(
                "--li-step",
                format!("{} is not a positive number", li.step_s),
            );
        }
    }
    Ok(())
}

/// Layer widths of the networks of a configuration.
fn widths(cfg: &TrainConfig, m: usize, n_obs: usize) -> (Vec<usize>, Option<Vec<usize>>) {
    let d = cfg.latent_dim;
    let mut dec = vec![if cfg.kind == ModelKind::Cae {
        n_obs + d
    } else {
        n_obs
    }];
    dec.extend(&cfg.hidden);
    dec.push(if cfg.kind == ModelKind::Cae { m } else { m * d });
    let enc = (cfg.encoder == EncoderKind::Mlp).then(|| {
        let mut e = vec![n_obs + m];
        e.extend(&cfg.hidden);
        e.push(d);
        e
    });
    (dec, enc)
}

/// The networks of one seed.
#[derive(Debug, Clone, PartialEq)]
pub struct Nets {
    /// Decoder.
    pub decoder: Mlp,
    /// MLP encoder.
    pub encoder: Option<Mlp>,
}

/// Batch buffers of one seed, allocated once.
struct Workspace {
    xd: Vec<f32>,
    xe: Vec<f32>,
    y: Vec<f32>,
    dec: BatchCache,
    enc: Option<BatchCache>,
    a: Vec<f32>,
    ga: Vec<f32>,
    v: Vec<f32>,
    h: Vec<f32>,
    norms: Vec<f32>,
    gh: Vec<f32>,
    gv: Vec<f32>,
    yhat: Vec<f32>,
    gy: Vec<f32>,
    xin: Vec<f32>,
    gxin: Vec<f32>,
    li: Option<li::LiWorkspace>,
    q_step: Vec<f32>,
}

impl Workspace {
    fn new(cfg: &TrainConfig, nets: &Nets, data: &TrainData) -> Self {
        let b = cfg.batch;
        let (m, d, n_obs) = (data.m, cfg.latent_dim, data.n_obs);
        let dec_in = nets.decoder.n_in();
        let q_step = match &cfg.li {
            Some(li) => (0..m)
                .map(|i| (li.step_s * data.speed_scale / f64::from(data.obs_norm.std[i])) as f32)
                .collect(),
            None => vec![0.0; m],
        };
        Self {
            xd: vec![0.0; b * n_obs],
            xe: vec![0.0; b * (n_obs + m)],
            y: vec![0.0; b * m],
            dec: BatchCache::new(&nets.decoder, b),
            enc: nets.encoder.as_ref().map(|e| BatchCache::new(e, b)),
            a: vec![0.0; b * d],
            ga: vec![0.0; b * d],
            v: vec![0.0; b * m * d],
            h: vec![0.0; b * m * d],
            norms: vec![0.0; b * d],
            gh: vec![0.0; b * m * d],
            gv: vec![0.0; b * m * d],
            yhat: vec![0.0; b * m],
            gy: vec![0.0; b * m],
            xin: vec![0.0; b * dec_in],
            gxin: vec![0.0; b * dec_in],
            li: cfg
                .li
                .as_ref()
                .map(|_| li::LiWorkspace::new(&nets.decoder, b)),
            q_step,
        }
    }

    fn gather(&mut self, split: &Split, idx: &[usize], n_obs: usize, m: usize) {
        let ne = n_obs + m;
        for (r, &k) in idx.iter().enumerate() {
            self.xd[r * n_obs..(r + 1) * n_obs]
                .copy_from_slice(&split.x_obs[k * n_obs..(k + 1) * n_obs]);
            self.xe[r * ne..(r + 1) * ne].copy_from_slice(&split.x_enc[k * ne..(k + 1) * ne]);
            self.y[r * m..(r + 1) * m].copy_from_slice(&split.y[k * m..(k + 1) * m]);
        }
    }
}

/// Forward pass of the batch in `ws` (rows `0..bn`): fills `ws.yhat` and returns the
/// reconstruction MSE in speed-scale units.
fn forward(
    cfg: &TrainConfig,
    nets: &Nets,
    ws: &mut Workspace,
    bn: usize,
    m: usize,
    n_obs: usize,
) -> f64 {
    let d = cfg.latent_dim;
    if let (Some(enc), Some(cache)) = (&nets.encoder, &mut ws.enc) {
        enc.forward_batch(&ws.xe, bn, cache);
        ws.a[..bn * d].copy_from_slice(cache.output());
    }
    match cfg.kind {
        ModelKind::Cae => {
            let n_in = n_obs + d;
            for r in 0..bn {
                ws.xin[r * n_in..r * n_in + n_obs]
                    .copy_from_slice(&ws.xd[r * n_obs..(r + 1) * n_obs]);
                ws.xin[r * n_in + n_obs..(r + 1) * n_in].copy_from_slice(&ws.a[r * d..(r + 1) * d]);
            }
            nets.decoder.forward_batch(&ws.xin, bn, &mut ws.dec);
            ws.yhat[..bn * m].copy_from_slice(ws.dec.output());
        }
        _ => {
            nets.decoder.forward_batch(&ws.xd, bn, &mut ws.dec);
            let md = m * d;
            ws.v[..bn * md].copy_from_slice(ws.dec.output());
            ws.h[..bn * md].copy_from_slice(&ws.v[..bn * md]);
            for r in 0..bn {
                let h = &mut ws.h[r * md..(r + 1) * md];
                if cfg.gram_schmidt {
                    gram_schmidt::orthonormalise(
                        h,
                        m,
                        d,
                        GS_EPSILON,
                        &mut ws.norms[r * d..(r + 1) * d],
                    );
                }
                if cfg.encoder == EncoderKind::Projection {
                    for j in 0..d {
                        ws.a[r * d + j] = (0..m).map(|i| h[i * d + j] * ws.y[r * m + i]).sum();
                    }
                }
                for i in 0..m {
                    ws.yhat[r * m + i] = (0..d).map(|j| h[i * d + j] * ws.a[r * d + j]).sum();
                }
            }
        }
    }
    let mut sum = 0.0f64;
    for (p, t) in ws.yhat[..bn * m].iter().zip(&ws.y[..bn * m]) {
        sum += f64::from(p - t).powi(2);
    }
    sum / (bn * m) as f64
}

/// Forward and backward of one batch; adds gradients into `grads`. Returns the objective.
#[allow(clippy::too_many_arguments)]
fn forward_backward(
    cfg: &TrainConfig,
    nets: &Nets,
    grads: &mut Nets,
    ws: &mut Workspace,
    bn: usize,
    m: usize,
    n_obs: usize,
    rng: &mut Rng,
) -> f64 {
    let d = cfg.latent_dim;
    let mut loss = forward(cfg, nets, ws, bn, m, n_obs);
    let scale = 2.0 / (bn * m) as f32;
    for ((g, p), t) in ws.gy[..bn * m]
        .iter_mut()
        .zip(&ws.yhat[..bn * m])
        .zip(&ws.y[..bn * m])
    {
        *g = scale * (p - t);
    }
    ws.ga[..bn * d].fill(0.0);
    match cfg.kind {
        ModelKind::Cae => {
            let n_in = n_obs + d;
            if let (Some(li_cfg), Some(lw)) = (&cfg.li, &mut ws.li) {
                let cb = li::CaeBatch {
                    batch: bn,
                    n_obs,
                    m,
                    d,
                    xin: &ws.xin[..bn * n_in],
                    yhat: &ws.yhat[..bn * m],
                    q_step: &ws.q_step,
                };
                loss += li::add_terms(
                    li_cfg,
                    &nets.decoder,
                    &cb,
                    lw,
                    rng,
                    &mut grads.decoder,
                    &mut ws.gy,
                    &mut ws.ga,
                );
            }
            nets.decoder.backward_batch(
                &mut ws.dec,
                &ws.gy,
                &mut grads.decoder,
                Some(&mut ws.gxin),
            );
            for r in 0..bn {
                for j in 0..d {
                    ws.ga[r * d + j] += ws.gxin[r * n_in + n_obs + j];
                }
            }
        }
        _ => {
            let md = m * d;
            for r in 0..bn {
                let h = &ws.h[r * md..(r + 1) * md];
                let gh = &mut ws.gh[r * md..(r + 1) * md];
                let gy = &ws.gy[r * m..(r + 1) * m];
                let a = &ws.a[r * d..(r + 1) * d];
                for i in 0..m {
                    for j in 0..d {
                        gh[i * d + j] = gy[i] * a[j];
                    }
                }
                for j in 0..d {
                    let ga: f32 = (0..m).map(|i| h[i * d + j] * gy[i]).sum();
                    ws.ga[r * d + j] = ga;
                }
                if cfg.encoder == EncoderKind::Projection {
                    // a_j = Σ_i H'_ij y_i: the action's gradient flows back into H'.
                    for i in 0..m {
                        for j in 0..d {
                            gh[i * d + j] += ws.y[r * m + i] * ws.ga[r * d + j];
                        }
                    }
                }
                let gv = &mut ws.gv[r * md..(r + 1) * md];
                if cfg.gram_schmidt {
                    gram_schmidt::orthonormalise_backward(
                        &ws.v[r * md..(r + 1) * md],
                        h,
                        &ws.norms[r * d..(r + 1) * d],
                        gh,
                        gv,
                        m,
                        d,
                    );
                } else {
                    gv.copy_from_slice(gh);
                }
            }
            nets.decoder
                .backward_batch(&mut ws.dec, &ws.gv[..bn * md], &mut grads.decoder, None);
        }
    }
    if let (Some(enc), Some(cache), Some(genc)) = (&nets.encoder, &mut ws.enc, &mut grads.encoder) {
        enc.backward_batch(cache, &ws.ga[..bn * d], genc, None);
    }
    loss
}

/// Validation reconstruction MSE (speed-scale units) of `nets` on `split`.
fn evaluate(
    cfg: &TrainConfig,
    nets: &Nets,
    ws: &mut Workspace,
    split: &Split,
    m: usize,
    n_obs: usize,
) -> f64 {
    let b = cfg.batch;
    let mut sum = 0.0;
    let idx: Vec<usize> = (0..split.n).collect();
    for chunk in idx.chunks(b) {
        ws.gather(split, chunk, n_obs, m);
        sum += forward(cfg, nets, ws, chunk.len(), m, n_obs) * chunk.len() as f64;
    }
    sum / split.n.max(1) as f64
}

/// Trains one seed. Returns its run and its best weights.
pub fn train_seed(
    cfg: &TrainConfig,
    data: &TrainData,
    seed: u64,
    seed_index: usize,
    on_progress: &(dyn Fn(&Progress) + Sync),
    cancel: &AtomicBool,
) -> Result<(SeedRun, Nets), TrainError> {
    let (m, n_obs) = (data.m, data.n_obs);
    let s2 = data.speed_scale * data.speed_scale;
    let mut rng = Rng::new(seed);
    let (dec_w, enc_w) = widths(cfg, m, n_obs);
    let decoder = Mlp::init(&dec_w, &mut rng);
    let encoder = enc_w.map(|w| Mlp::init(&w, &mut rng));
    let mut nets = Nets { decoder, encoder };
    let mut grads = Nets {
        decoder: nets.decoder.zeros_like(),
        encoder: nets.encoder.as_ref().map(Mlp::zeros_like),
    };
    let lr = cfg.learning_rate as f32;
    let mut adam_dec = Adam::new(&nets.decoder, lr);
    let mut adam_enc = nets.encoder.as_ref().map(|e| Adam::new(e, lr));
    let lip = cfg.lipschitz.map(|l| {
        let per = lipschitz::per_layer_bound(l, nets.decoder.layers.len()) as f32;
        let state: Vec<PowerIteration> = nets
            .decoder
            .layers
            .iter()
            .map(|l| PowerIteration::new(l.n_in, l.n_out, &mut rng))
            .collect();
        (per, state)
    });
    let mut lip = lip;
    let inv_std = data.obs_norm.inv_std();
    // The first decoder layer sees [x | a] for CAE: only the observation part is scaled.
    let mut row_scale = inv_std.clone();
    row_scale.resize(nets.decoder.n_in(), 1.0);
    if let Some((per, state)) = &mut lip {
        // Start inside the constraint set.
        lipschitz::project(&mut nets.decoder, state, *per, &row_scale, 20);
    }
    let mut ws = Workspace::new(cfg, &nets, data);
    let mut order: Vec<usize> = (0..data.train.n).collect();
    let mut history = Vec::with_capacity(cfg.epochs);
    let mut best: Option<(f64, usize, Nets)> = None;
    for epoch in 1..=cfg.epochs {
        if cancel.load(Ordering::Relaxed) {
            break;
        }
        // Fisher-Yates with the seed's generator.
        for i in (1..order.len()).rev() {
            let j = (rng.next_u64() % (i as u64 + 1)) as usize;
            order.swap(i, j);
        }
        let mut sum = 0.0;
        for chunk in order.chunks(cfg.batch) {
            let bn = chunk.len();
            ws.gather(&data.train, chunk, n_obs, m);
            grads.decoder.fill_zero();
            if let Some(g) = &mut grads.encoder {
                g.fill_zero();
            }
            let loss = forward_backward(cfg, &nets, &mut grads, &mut ws, bn, m, n_obs, &mut rng);
            sum += loss * bn as f64;
            adam_dec.step(&mut nets.decoder, &grads.decoder);
            if let (Some(a), Some(e), Some(g)) = (&mut adam_enc, &mut nets.encoder, &grads.encoder)
            {
                a.step(e, g);
            }
            if let Some((per, state)) = &mut lip {
                lipschitz::project(
                    &mut nets.decoder,
                    state,
                    *per,
                    &row_scale,
                    cfg.power_iterations,
                );
            }
        }
        let train_loss = sum / data.train.n as f64 * s2;
        if !train_loss.is_finite() {
            return Err(TrainError::Diverged {
                seed,
                epoch,
                loss: train_loss,
            });
        }
        let val_loss =
            (data.val.n > 0).then(|| evaluate(cfg, &nets, &mut ws, &data.val, m, n_obs) * s2);
        let key = val_loss.unwrap_or(train_loss);
        if best.as_ref().is_none_or(|(b, _, _)| key < *b)
            || (val_loss.is_none() && epoch == cfg.epochs)
        {
            best = Some((key, epoch, nets.clone()));
        }
        history.push(EpochLoss {
            epoch,
            train_loss,
            val_loss,
        });
        on_progress(&Progress::Epoch {
            seed_index,
            epoch,
            train_loss,
            val_loss,
        });
    }
    let (best_loss, best_epoch, best_nets) = best.ok_or(TrainError::Config {
        option: "--epochs",
        reason: "training was interrupted before the first epoch finished".into(),
    })?;
    Ok((
        SeedRun {
            seed,
            history,
            best_epoch,
            best_loss,
        },
        best_nets,
    ))
}

/// Trains `cfg.seeds` seeds on `ds` (in parallel on a pool of [`TrainConfig::threads`], each
/// seed single-threaded) and returns the best
/// model with its header filled in. `command` is recorded in the header; `on_progress` is
/// called from the worker threads after every epoch; setting `cancel` stops every seed after
/// its current epoch (the best weights so far are kept).
pub fn train(
    cfg: &TrainConfig,
    ds: &Dataset,
    command: &str,
    on_progress: &(dyn Fn(&Progress) + Sync),
    cancel: &AtomicBool,
) -> Result<TrainOutcome, TrainError> {
    let data = TrainData::new(ds, cfg.inputs, cfg.speed_scale)?;
    check_config(cfg, data.m)?;
    let threads = match cfg.threads {
        0 => std::thread::available_parallelism().map_or(1, |n| n.get()),
        n => n,
    }
    .min(cfg.seeds);
    let start = Instant::now();
    let seed_run =
        |i: usize| train_seed(cfg, &data, cfg.base_seed + i as u64, i, on_progress, cancel);
    // Results in seed order, each from its own generator: the same whatever the schedule.
    let results: Vec<Result<(SeedRun, Nets), TrainError>> = if threads <= 1 {
        // On the caller's thread (an experiment's pool runs one single-threaded job per
        // worker: a pool inside it would only add threads).
        (0..cfg.seeds).map(seed_run).collect()
    } else {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|i| format!("train-{i}"))
            .build()
            .map_err(|e| TrainError::Data(format!("cannot start {threads} training threads: {e}")))?
            .install(|| (0..cfg.seeds).into_par_iter().map(seed_run).collect())
    };
    let train_seconds = start.elapsed().as_secs_f64();
    let mut runs = Vec::new();
    let mut nets_all = Vec::new();
    for r in results {
        let (run, nets) = r?;
        runs.push(run);
        nets_all.push(nets);
    }
    let best_index = runs
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.best_loss.total_cmp(&b.1.best_loss))
        .map(|(i, _)| i)
        .ok_or_else(|| TrainError::Data("no seed finished".into()))?;
    let mut best = nets_all.swap_remove(best_index);
    let mut lipschitz_bound = None;
    if let Some(l) = cfg.lipschitz {
        let mut row_scale = data.obs_norm.inv_std();
        row_scale.resize(best.decoder.n_in(), 1.0);
        let per = lipschitz::per_layer_bound(l, best.decoder.layers.len());
        let certified = lipschitz::certify(&mut best.decoder, per, &row_scale);
        tracing::debug!(bound = l, certified, "Lipschitz bound certified");
        lipschitz_bound = Some(l);
    }
    let validation_loss = (data.val.n > 0).then(|| {
        let mut ws = Workspace::new(cfg, &best, &data);
        evaluate(cfg, &best, &mut ws, &data.val, data.m, data.n_obs)
            * data.speed_scale
            * data.speed_scale
    });
    let run = &runs[best_index];
    let m = data.m;
    let header = ModelHeader {
        format: FORMAT.into(),
        version: VERSION,
        kind: cfg.kind,
        n_joints: m,
        latent_dim: cfg.latent_dim,
        joint_names: joint_names(m),
        speed_scale_rad_s: data.speed_scale,
        lipschitz_bound,
        network: Some(NetworkInfo {
            inputs: cfg.inputs,
            input_mean: data.obs_norm.mean_list(),
            input_std: data.obs_norm.std_list(),
            hidden: cfg.hidden.clone(),
            gram_schmidt: cfg.gram_schmidt,
            gs_epsilon: f64::from(GS_EPSILON),
            encoder: cfg.encoder,
            encoder_input_mean: if cfg.encoder == EncoderKind::Mlp {
                data.enc_norm.mean_list()
            } else {
                Vec::new()
            },
            encoder_input_std: if cfg.encoder == EncoderKind::Mlp {
                data.enc_norm.std_list()
            } else {
                Vec::new()
            },
            li_losses: cfg.li.clone(),
        }),
        training: TrainingInfo {
            data_hash: ds.hash.clone(),
            n_train: data.train.n,
            n_val: data.val.n,
            validation_loss,
            seed: run.seed,
            command: command.to_owned(),
            settings: Some(TrainSettings {
                epochs: cfg.epochs,
                batch: cfg.batch,
                learning_rate: cfg.learning_rate,
                seeds: cfg.seeds,
                best_epoch: run.best_epoch,
                power_iterations: if cfg.lipschitz.is_some() {
                    cfg.power_iterations
                } else {
                    0
                },
                train_seconds,
            }),
        },
    };
    let model = NetworkModel::new(header, best.decoder, best.encoder)?;
    Ok(TrainOutcome {
        model,
        runs,
        best_index,
        train_seconds,
        validation_loss,
    })
}

/// The Gen3 lite's joint names for a 6-joint data set, `joint_1..` otherwise.
pub fn joint_names(m: usize) -> Vec<String> {
    if m == kinematics::gen3_lite::N_JOINTS {
        kinematics::gen3_lite::JOINT_NAMES
            .iter()
            .map(|s| (*s).to_owned())
            .collect()
    } else {
        (0..m).map(|i| format!("joint_{}", i + 1)).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mapper::LoadedModel;
    use std::path::Path;

    fn small(kind: ModelKind) -> TrainConfig {
        let base = if kind == ModelKind::Cae {
            TrainConfig::cae()
        } else {
            TrainConfig::default()
        };
        TrainConfig {
            hidden: vec![12, 10],
            epochs: 3,
            batch: 64,
            seeds: 2,
            threads: 1,
            ..base
        }
    }

    fn data() -> (Dataset, TrainData) {
        let ds = crate::demos::joint_reach(2, 1, 5);
        let td = TrainData::new(&ds, ObsInputs::JointsAndGripper, None).unwrap();
        (ds, td)
    }

    fn fresh_nets(cfg: &TrainConfig, td: &TrainData, seed: u64) -> Nets {
        let mut rng = Rng::new(seed);
        let (dw, ew) = widths(cfg, td.m, td.n_obs);
        Nets {
            decoder: Mlp::init(&dw, &mut rng),
            encoder: ew.map(|w| Mlp::init(&w, &mut rng)),
        }
    }

    /// Objective and gradients of one fixed batch (rows 0, 7, 14, ...).
    fn objective(cfg: &TrainConfig, nets: &Nets, td: &TrainData) -> (f64, Nets) {
        let idx: Vec<usize> = (0..10).map(|i| i * 7).collect();
        let mut ws = Workspace::new(cfg, nets, td);
        ws.gather(&td.train, &idx, td.n_obs, td.m);
        let mut grads = Nets {
            decoder: nets.decoder.zeros_like(),
            encoder: nets.encoder.as_ref().map(Mlp::zeros_like),
        };
        let mut rng = Rng::new(77);
        let loss = forward_backward(
            cfg,
            nets,
            &mut grads,
            &mut ws,
            idx.len(),
            td.m,
            td.n_obs,
            &mut rng,
        );
        (loss, grads)
    }

    fn check_gradients(cfg: &TrainConfig) {
        let (_, td) = data();
        let nets = fresh_nets(cfg, &td, 3);
        let (_, grads) = objective(cfg, &nets, &td);
        let h = 5e-3f32;
        let mut checked = 0;
        for which in 0..2 {
            let Some(net) = (if which == 0 {
                Some(&nets.decoder)
            } else {
                nets.encoder.as_ref()
            }) else {
                continue;
            };
            for l in 0..net.layers.len() {
                for idx in [0, net.layers[l].w.len() / 2, net.layers[l].w.len() - 1] {
                    let perturbed = |delta: f32| {
                        let mut n = nets.clone();
                        let t = if which == 0 {
                            &mut n.decoder
                        } else {
                            n.encoder.as_mut().unwrap()
                        };
                        t.layers[l].w[idx] += delta;
                        objective(cfg, &n, &td).0
                    };
                    let fd = (perturbed(h) - perturbed(-h)) / (2.0 * f64::from(h));
                    let g = if which == 0 {
                        &grads.decoder
                    } else {
                        grads.encoder.as_ref().unwrap()
                    };
                    let an = f64::from(g.layers[l].w[idx]);
                    let tol = 2e-2 * fd.abs().max(an.abs()) + 2e-5;
                    assert!(
                        (fd - an).abs() < tol,
                        "{:?} net {which} layer {l} w[{idx}]: fd {fd:e} vs {an:e}",
                        cfg.kind
                    );
                    checked += 1;
                }
            }
        }
        assert!(checked >= 9);
    }

    #[test]
    fn scl_gradients_match_finite_differences() {
        check_gradients(&small(ModelKind::Scl));
        check_gradients(&TrainConfig {
            gram_schmidt: false,
            ..small(ModelKind::Scl)
        });
        check_gradients(&TrainConfig {
            encoder: EncoderKind::Projection,
            ..small(ModelKind::Scl)
        });
        // With orthonormal H' the projection's action is optimal and its gradient vanishes;
        // without Gram-Schmidt the action's own gradient path is exercised.
        check_gradients(&TrainConfig {
            encoder: EncoderKind::Projection,
            gram_schmidt: false,
            ..small(ModelKind::Scl)
        });
    }

    #[test]
    fn cae_gradients_match_finite_differences() {
        check_gradients(&small(ModelKind::Cae));
        for terms in ["consistency", "proportionality", "reversibility"] {
            let mut li = li::parse_terms(terms).unwrap().unwrap();
            // A long step makes the reversibility term's dependence on o' visible.
            li.step_s = 0.5;
            check_gradients(&TrainConfig {
                li: Some(li),
                ..small(ModelKind::Cae)
            });
        }
    }

    #[test]
    fn training_reduces_the_loss_and_is_deterministic() {
        let (ds, _) = data();
        let cfg = small(ModelKind::Scl);
        let cancel = AtomicBool::new(false);
        let a = train(&cfg, &ds, "t", &|_| {}, &cancel).unwrap();
        let b = train(
            &TrainConfig {
                threads: 2,
                ..cfg.clone()
            },
            &ds,
            "t",
            &|_| {},
            &cancel,
        )
        .unwrap();
        assert_eq!(a.runs, b.runs);
        assert_eq!(a.model.decoder(), b.model.decoder());
        assert_eq!(a.model.encoder(), b.model.encoder());
        for r in &a.runs {
            let first = r.history[0].train_loss;
            let last = r.history.last().unwrap().train_loss;
            assert!(last < first, "seed {}: {first} -> {last}", r.seed);
        }
        // Another base seed gives other weights.
        let c = train(
            &TrainConfig {
                base_seed: 9,
                ..cfg
            },
            &ds,
            "t",
            &|_| {},
            &cancel,
        )
        .unwrap();
        assert_ne!(a.model.decoder(), c.model.decoder());
    }

    #[test]
    fn keeps_the_best_seed_and_bounds_the_decoder() {
        let (ds, td) = data();
        let cfg = TrainConfig {
            seeds: 3,
            lipschitz: Some(0.7),
            ..small(ModelKind::Scl)
        };
        let out = train(&cfg, &ds, "cmd line", &|_| {}, &AtomicBool::new(false)).unwrap();
        let best = out
            .runs
            .iter()
            .map(|r| r.best_loss)
            .fold(f64::INFINITY, f64::min);
        assert_eq!(out.runs[out.best_index].best_loss, best);
        let h = out.model.header();
        assert_eq!(h.training.seed, out.runs[out.best_index].seed);
        assert_eq!(h.training.command, "cmd line");
        assert_eq!(h.lipschitz_bound, Some(0.7));
        assert_eq!(h.training.n_train, td.train.n);
        // The certified bound holds on the exact spectral norms, with the normalisation.
        let mut scale = td.obs_norm.inv_std();
        scale.resize(out.model.decoder().n_in(), 1.0);
        assert!(lipschitz::bound(out.model.decoder(), &scale) <= 0.7);
        // Without the normalisation folded in, the same weights are not bounded by 0.7
        // (the joint angles' spread is well below 1 rad): the folding matters.
        let ones = vec![1.0f32; out.model.decoder().n_in()];
        assert!(
            lipschitz::bound(out.model.decoder(), &ones)
                < lipschitz::bound(out.model.decoder(), &scale)
        );
        // The validation loss in the header is the recomputed one of the kept weights.
        let v = out.validation_loss.unwrap();
        assert!(v > 0.0 && v < out.runs[out.best_index].best_loss * 1.5);
    }

    /// The served map computes what training computed: `H` and the reconstruction agree to
    /// 1e-5 between the batched training pass and the loaded model file.
    #[test]
    fn served_output_equals_the_training_forward_pass() {
        let (ds, td) = data();
        for cfg in [
            small(ModelKind::Scl),
            TrainConfig {
                gram_schmidt: false,
                ..small(ModelKind::Scl)
            },
            small(ModelKind::Cae),
        ] {
            let out = train(&cfg, &ds, "t", &|_| {}, &AtomicBool::new(false)).unwrap();
            let nets = Nets {
                decoder: out.model.decoder().clone(),
                encoder: out.model.encoder().cloned(),
            };
            let mut ws = Workspace::new(&cfg, &nets, &td);
            let idx: Vec<usize> = (0..td.val.n.min(cfg.batch)).collect();
            ws.gather(&td.val, &idx, td.n_obs, td.m);
            forward(&cfg, &nets, &mut ws, idx.len(), td.m, td.n_obs);
            let bytes = out.model.to_bytes().unwrap();
            let mut served = LoadedModel::from_bytes(&bytes, Path::new("m")).unwrap();
            let (m, d) = (td.m, cfg.latent_dim);
            let rows: Vec<(Vec<f64>, f64)> = ds
                .val
                .iter()
                .flat_map(|t| t.q.iter().cloned().zip(t.c.iter().copied()))
                .collect();
            let mut y = vec![0.0; m];
            let mut worst = 0.0f64;
            for (r, (q, c)) in rows.iter().enumerate().take(idx.len()) {
                let a: Vec<f64> = ws.a[r * d..(r + 1) * d]
                    .iter()
                    .map(|v| f64::from(*v))
                    .collect();
                served.map.eval(q, *c, &a, &mut y);
                for i in 0..m {
                    worst = worst.max((y[i] - f64::from(ws.yhat[r * m + i])).abs());
                }
                if cfg.kind == ModelKind::Scl {
                    let mut scl = out.model.scl_map().unwrap();
                    let h = scl.matrix(q, *c);
                    for k in 0..m * d {
                        worst = worst.max(f64::from((h[k] - ws.h[r * m * d + k]).abs()));
                    }
                }
            }
            assert!(worst < 1e-5, "{:?}: worst difference {worst:e}", cfg.kind);
            // And the offline evaluation reproduces the header's validation loss.
            let any = crate::eval::AnyModel::Net(Box::new(out.model.clone()));
            let mse = crate::eval::reconstruction_mse(&any, Path::new("m"), &ds.val).unwrap();
            let v = out.validation_loss.unwrap();
            assert!((mse - v).abs() < 1e-4 * v, "{mse} vs {v}");
        }
    }

    #[test]
    fn refuses_bad_options_by_name() {
        let (ds, _) = data();
        let cancel = AtomicBool::new(false);
        let cases: Vec<(TrainConfig, &str)> = vec![
            (
                TrainConfig {
                    latent_dim: 7,
                    ..small(ModelKind::Scl)
                },
                "--latent-dim",
            ),
            (
                TrainConfig {
                    epochs: 0,
                    ..small(ModelKind::Scl)
                },
                "--epochs",
            ),
            (
                TrainConfig {
                    learning_rate: -1.0,
                    ..small(ModelKind::Scl)
                },
                "--lr",
            ),
            (
                TrainConfig {
                    hidden: vec![],
                    ..small(ModelKind::Scl)
                },
                "--hidden",
            ),
            (
                TrainConfig {
                    lipschitz: Some(f64::NAN),
                    ..small(ModelKind::Scl)
                },
                "--lipschitz",
            ),
            (
                TrainConfig {
                    li: li::parse_terms("reversibility").unwrap(),
                    ..small(ModelKind::Scl)
                },
                "--li-losses",
            ),
            (
                TrainConfig {
                    gram_schmidt: true,
                    ..small(ModelKind::Cae)
                },
                "--gram-schmidt",
            ),
            (
                TrainConfig {
                    encoder: EncoderKind::Projection,
                    ..small(ModelKind::Cae)
                },
                "--encoder",
            ),
            (
                TrainConfig {
                    speed_scale: Some(0.0),
                    ..small(ModelKind::Scl)
                },
                "--speed-scale",
            ),
        ];
        for (cfg, option) in cases {
            let e = train(&cfg, &ds, "t", &|_| {}, &cancel)
                .unwrap_err()
                .to_string();
            assert!(e.contains(option), "{option}: {e}");
        }
    }
}
