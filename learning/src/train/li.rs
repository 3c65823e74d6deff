//! The Li et al. (2020) loss terms for the CAE baseline ("Learning user-preferred mappings
//! for intuitive robot control", Section 4.B), as the SCL paper re-implemented them for its
//! grid search (consistency with temperature `γ = 2`, proportionality with `α` sampled in a
//! range within `[0.1, 1]`, reversibility; each switchable).
//!
//! The SCL paper names the terms but does not restate them; the definitions used here are
//! written for this project's unsupervised setting, where the latent action of a training
//! tuple is the encoder's `a_b = f(o_b, qdot_b)`. Velocities are in speed-scale units
//! (`y = qdot / s`), `g` is the decoder, and each term is averaged over the batch (and over
//! joints where it is a squared vector), then multiplied by [`LiLosses::weight`]:
//!
//! * **Consistency** (the same action in similar states should move the arm similarly): each
//!   sample `b` is paired with another sample `p(b)` of the same (shuffled) batch, and
//!   `L = mean_b w_b · |g(o_b, a_b) − g(o_p(b), a_b)|² / m` with the similarity weight
//!   `w_b = exp(−|x_b − x_p(b)| / γ)` of the *normalised* observations (so `γ` is unitless;
//!   `w` is a constant, no gradient flows through it). Pairs far apart count little; `γ` is
//!   the temperature.
//! * **Proportionality** (scaling the action scales the motion): with `α_b` uniform in
//!   `[α_min, α_max]`, `L = mean_b (|g(o_b, α_b a_b)| − α_b |g(o_b, a_b)|)²`. (With a single
//!   `α = 1` the term vanishes identically, so the paper's "α = 1.0" is read as the upper end
//!   of the sampling range; the default range is `[0.1, 1]`.)
//! * **Reversibility** (undoing an action returns the arm): with the one-step transition
//!   `T(q, a) = q + Δ · s · g(o, a)` (`Δ` = [`LiLosses::step_s`], one control period by
//!   default) and `o' = (T(q, a_b), c_b)`, returning with `−a_b` gives back `q` exactly when
//!   `g(o_b, a_b) + g(o', −a_b) = 0`, so `L = mean_b |g(o_b, a_b) + g(o'_b, −a_b)|² / m`.
//!   The gradient flows through `o'` as well.
//!
//! [`LiLosses::weight`]: mapper::model::LiLosses::weight
//! [`LiLosses::step_s`]: mapper::model::LiLosses::step_s

use mapper::model::LiLosses;
use mapper::nn::{BatchCache, Mlp};
use mapper::rng::Rng;

/// Default temperature of the consistency term (the SCL paper's choice).
pub const DEFAULT_GAMMA: f64 = 2.0;
/// Default sampling range of the proportionality scale `α`.
pub const DEFAULT_ALPHA: [f64; 2] = [0.1, 1.0];
/// Default time step of the reversibility transition: one 40 Hz control period (s).
pub const DEFAULT_STEP_S: f64 = 0.025;

/// The three terms as named on the command line.
pub const TERM_NAMES: [&str; 3] = ["consistency", "proportionality", "reversibility"];

/// Li-loss settings from a comma-separated list of term names (see [`TERM_NAMES`]); `None`
/// for an empty list. Errors name the unknown term.
pub fn parse_terms(list: &str) -> Result<Option<LiLosses>, String> {
    let mut li = LiLosses {
        consistency_gamma: None,
        proportionality_alpha: None,
        reversibility: false,
        weight: 1.0,
        step_s: DEFAULT_STEP_S,
    };
    let mut any = false;
    for t in list.split(',').map(str::trim).filter(|t| !t.is_empty()) {
        any = true;
        match t {
            "consistency" => li.consistency_gamma = Some(DEFAULT_GAMMA),
            "proportionality" => li.proportionality_alpha = Some(DEFAULT_ALPHA),
            "reversibility" => li.reversibility = true,
            other => {
                return Err(format!(
                    "unknown Li loss term `{other}`; available: {}",
                    TERM_NAMES.join(", ")
                ));
            }
        }
    }
    Ok(any.then_some(li))
}

/// Buffers of the extra decoder passes, sized for the largest batch.
#[derive(Debug, Clone)]
pub(crate) struct LiWorkspace {
    cache: BatchCache,
    x: Vec<f32>,
    gx: Vec<f32>,
    g_out: Vec<f32>,
    alpha: Vec<f32>,
}

impl LiWorkspace {
    pub(crate) fn new(decoder: &Mlp, max_batch: usize) -> Self {
        let n_in = decoder.n_in();
        let m = decoder.n_out();
        Self {
            cache: BatchCache::new(decoder, max_batch),
            x: vec![0.0; max_batch * n_in],
            gx: vec![0.0; max_batch * n_in],
            g_out: vec![0.0; max_batch * m],
            alpha: vec![0.0; max_batch],
        }
    }
}

/// One batch's view of the CAE pass the terms build on.
pub(crate) struct CaeBatch<'a> {
    /// Batch size.
    pub batch: usize,
    /// Observation width (normalised part of the decoder input).
    pub n_obs: usize,
    /// Joints.
    pub m: usize,
    /// Latent size.
    pub d: usize,
    /// Decoder inputs `[x | a]` of the main pass (`batch × (n_obs + d)`).
    pub xin: &'a [f32],
    /// Decoder outputs of the main pass (`batch × m`).
    pub yhat: &'a [f32],
    /// `Δ · s / σ_q` per joint: how a velocity (speed-scale units) moves the normalised `q`
    /// in one reversibility step.
    pub q_step: &'a [f32],
}

/// Adds the enabled terms: their loss (returned), their parameter gradients into `grads`,
/// and their gradients with respect to the main pass's outputs and actions into `g_yhat`
/// and `g_a`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn add_terms(
    li: &LiLosses,
    decoder: &Mlp,
    cb: &CaeBatch<'_>,
    ws: &mut LiWorkspace,
    rng: &mut Rng,
    grads: &mut Mlp,
    g_yhat: &mut [f32],
    g_a: &mut [f32],
) -> f64 {
    let mut loss = 0.0;
    let (b_n, n_obs, m, d) = (cb.batch, cb.n_obs, cb.m, cb.d);
    let n_in = n_obs + d;
    let lam = li.weight as f32;
    if let Some(gamma) = li.consistency_gamma {
        let gamma = gamma as f32;
        let partner = |b: usize| (b + b_n / 2) % b_n;
        for b in 0..b_n {
            let p = partner(b);
            ws.x[b * n_in..b * n_in + n_obs].copy_from_slice(&cb.xin[p * n_in..p * n_in + n_obs]);
            ws.x[b * n_in + n_obs..(b + 1) * n_in]
                .copy_from_slice(&cb.xin[b * n_in + n_obs..(b + 1) * n_in]);
        }
        decoder.forward_batch(&ws.x, b_n, &mut ws.cache);
        let out = ws.cache.output();
        let scale = 1.0 / (b_n * m) as f32;
        for b in 0..b_n {
            let p = partner(b);
            let dist: f32 = (0..n_obs)
                .map(|k| (cb.xin[b * n_in + k] - cb.xin[p * n_in + k]).powi(2))
                .sum::<f32>()
                .sqrt();
            let w = (-dist / gamma).exp();
            for i in 0..m {
                let diff = cb.yhat[b * m + i] - out[b * m + i];
                loss += f64::from(lam * w * diff * diff * scale);
                let g = 2.0 * lam * w * diff * scale;
                g_yhat[b * m + i] += g;
                ws.g_out[b * m + i] = -g;
            }
        }
        decoder.backward_batch(&mut ws.cache, &ws.g_out, grads, Some(&mut ws.gx));
        for b in 0..b_n {
            for j in 0..d {
                g_a[b * d + j] += ws.gx[b * n_in + n_obs + j];
            }
        }
    }
    if let Some([lo, hi]) = li.proportionality_alpha {
        for b in 0..b_n {
            let alpha = rng.range(lo, hi) as f32;
            ws.alpha[b] = alpha;
            ws.x[b * n_in..b * n_in + n_obs].copy_from_slice(&cb.xin[b * n_in..b * n_in + n_obs]);
            for j in 0..d {
                ws.x[b * n_in + n_obs + j] = alpha * cb.xin[b * n_in + n_obs + j];
            }
        }
        decoder.forward_batch(&ws.x, b_n, &mut ws.cache);
        let out = ws.cache.output();
        let scale = 1.0 / b_n as f32;
        for b in 0..b_n {
            let alpha = ws.alpha[b];
            let y1 = &cb.yhat[b * m..(b + 1) * m];
            let y2 = &out[b * m..(b + 1) * m];
            let p1 = y1.iter().map(|v| v * v).sum::<f32>().sqrt();
            let p2 = y2.iter().map(|v| v * v).sum::<f32>().sqrt();
            let r = p2 - alpha * p1;
            loss += f64::from(lam * r * r * scale);
            let dr = 2.0 * lam * r * scale;
            for i in 0..m {
                ws.g_out[b * m + i] = dr * y2[i] / (p2 + 1e-12);
                g_yhat[b * m + i] -= dr * alpha * y1[i] / (p1 + 1e-12);
            }
        }
        decoder.backward_batch(&mut ws.cache, &ws.g_out, grads, Some(&mut ws.gx));
        for b in 0..b_n {
            for j in 0..d {
                g_a[b * d + j] += ws.alpha[b] * ws.gx[b * n_in + n_obs + j];
            }
        }
    }
    if li.reversibility {
        for b in 0..b_n {
            let row = &mut ws.x[b * n_in..(b + 1) * n_in];
            row.copy_from_slice(&cb.xin[b * n_in..(b + 1) * n_in]);
            let y = &cb.yhat[b * m..(b + 1) * m];
            for ((x, step), v) in row[..m].iter_mut().zip(cb.q_step).zip(y) {
                *x += step * v;
            }
            for x in &mut row[n_obs..n_obs + d] {
                *x = -*x;
            }
        }
        decoder.forward_batch(&ws.x, b_n, &mut ws.cache);
        let out = ws.cache.output();
        let scale = 1.0 / (b_n * m) as f32;
        for b in 0..b_n {
            for i in 0..m {
                let s = cb.yhat[b * m + i] + out[b * m + i];
                loss += f64::from(lam * s * s * scale);
                let g = 2.0 * lam * s * scale;
                ws.g_out[b * m + i] = g;
                g_yhat[b * m + i] += g;
            }
        }
        decoder.backward_batch(&mut ws.cache, &ws.g_out, grads, Some(&mut ws.gx));
        for b in 0..b_n {
            for i in 0..m {
                g_yhat[b * m + i] += ws.gx[b * n_in + i] * cb.q_step[i];
            }
            for j in 0..d {
                g_a[b * d + j] -= ws.gx[b * n_in + n_obs + j];
            }
        }
    }
    loss
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_term_lists() {
        let li = parse_terms("consistency, reversibility").unwrap().unwrap();
        assert_eq!(li.consistency_gamma, Some(DEFAULT_GAMMA));
        assert!(li.reversibility);
        assert_eq!(li.proportionality_alpha, None);
        assert_eq!(parse_terms("").unwrap(), None);
        let e = parse_terms("consistency,bogus").unwrap_err();
        assert!(e.contains("bogus") && e.contains("proportionality"), "{e}");
    }

    const B: usize = 4;
    const M: usize = 2;
    const N_OBS: usize = 3;
    const D: usize = 2;
    const N_IN: usize = N_OBS + D;

    /// The decoder on one input, through its own batch of one.
    fn g(decoder: &Mlp, x: &[f32]) -> Vec<f32> {
        let mut cache = BatchCache::new(decoder, 1);
        decoder.forward_batch(x, 1, &mut cache);
        cache.output().to_vec()
    }

    fn norm(v: &[f32]) -> f64 {
        v.iter().map(|x| f64::from(*x).powi(2)).sum::<f64>().sqrt()
    }

    /// A small decoder, a batch of inputs `[q (2) | c | a (2)]`, and its outputs.
    fn batch() -> (Mlp, Vec<f32>, Vec<f32>) {
        let mut rng = Rng::new(11);
        let decoder = Mlp::init(&[N_IN, 8, M], &mut rng);
        let xin: Vec<f32> = (0..B * N_IN).map(|_| rng.range(-1.0, 1.0) as f32).collect();
        let yhat: Vec<f32> = (0..B)
            .flat_map(|b| g(&decoder, &xin[b * N_IN..(b + 1) * N_IN]))
            .collect();
        (decoder, xin, yhat)
    }

    /// The loss `add_terms` returns for `li` on [`batch`], with the generator it samples α from.
    fn loss(li: &LiLosses, rng: &mut Rng, q_step: &[f32]) -> f64 {
        let (decoder, xin, yhat) = batch();
        let cb = CaeBatch {
            batch: B,
            n_obs: N_OBS,
            m: M,
            d: D,
            xin: &xin,
            yhat: &yhat,
            q_step,
        };
        let mut ws = LiWorkspace::new(&decoder, B);
        let mut grads = decoder.zeros_like();
        let (mut g_yhat, mut g_a) = (vec![0.0; B * M], vec![0.0; B * D]);
        add_terms(
            li,
            &decoder,
            &cb,
            &mut ws,
            rng,
            &mut grads,
            &mut g_yhat,
            &mut g_a,
        )
    }

    fn only(terms: &str, weight: f64) -> LiLosses {
        LiLosses {
            weight,
            ..parse_terms(terms).unwrap().unwrap()
        }
    }

    /// Each term's value, against its definition evaluated one sample at a time:
    /// consistency `w |g(o, a) - g(o', a)|²` with `w = exp(-|o - o'|/γ)` for a partner `o'`
    /// from the batch; proportionality `(|g(o, αa)| - α|g(o, a)|)²`; reversibility
    /// `|g(o, a) + g(T(o, a), -a)|²` with `T` one step of `s·g` in `q`. Means over the batch
    /// (and joints for the vector terms), scaled by the weight.
    #[test]
    fn each_term_is_its_definition() {
        let (decoder, xin, yhat) = batch();
        let x = |b: usize| &xin[b * N_IN..(b + 1) * N_IN];
        let y = |b: usize| &yhat[b * M..(b + 1) * M];
        let q_step = [0.3f32, -0.2];

        // Consistency, γ = 2: the partner of sample b is b + B/2 (mod B).
        let mut want = 0.0;
        for b in 0..B {
            let p = (b + B / 2) % B;
            let dist = norm(&(0..N_OBS).map(|k| x(b)[k] - x(p)[k]).collect::<Vec<_>>());
            let w = (-dist / DEFAULT_GAMMA).exp();
            let mut xp = x(p)[..N_OBS].to_vec();
            xp.extend_from_slice(&x(b)[N_OBS..]);
            let other = g(&decoder, &xp);
            want += w
                * (0..M)
                    .map(|i| f64::from(y(b)[i] - other[i]).powi(2))
                    .sum::<f64>();
        }
        want /= (B * M) as f64;
        let got = loss(&only("consistency", 1.0), &mut Rng::new(5), &q_step);
        assert!(
            (got - want).abs() < 1e-5 * want.max(1e-3),
            "{got} vs {want}"
        );
        let twice = loss(&only("consistency", 2.0), &mut Rng::new(5), &q_step);
        assert!((twice - 2.0 * want).abs() < 2e-5 * want.max(1e-3));

        // Proportionality: α drawn per sample, in batch order, from the generator given.
        let mut rng = Rng::new(5);
        let mut want = 0.0;
        for b in 0..B {
            let alpha = rng.range(DEFAULT_ALPHA[0], DEFAULT_ALPHA[1]) as f32;
            assert!((0.1..=1.0).contains(&alpha));
            let mut xs = x(b).to_vec();
            xs[N_OBS..].iter_mut().for_each(|a| *a *= alpha);
            let r = norm(&g(&decoder, &xs)) - f64::from(alpha) * norm(y(b));
            want += r * r;
        }
        want /= B as f64;
        let got = loss(&only("proportionality", 1.0), &mut Rng::new(5), &q_step);
        assert!(
            (got - want).abs() < 1e-5 * want.max(1e-3),
            "{got} vs {want}"
        );

        // Reversibility: one step along the predicted velocity, then the opposite action.
        let mut want = 0.0;
        for b in 0..B {
            let mut xs = x(b).to_vec();
            for i in 0..M {
                xs[i] += q_step[i] * y(b)[i];
            }
            xs[N_OBS..].iter_mut().for_each(|a| *a = -*a);
            let back = g(&decoder, &xs);
            want += (0..M)
                .map(|i| f64::from(y(b)[i] + back[i]).powi(2))
                .sum::<f64>();
        }
        want /= (B * M) as f64;
        let got = loss(&only("reversibility", 1.0), &mut Rng::new(5), &q_step);
        assert!(
            (got - want).abs() < 1e-5 * want.max(1e-3),
            "{got} vs {want}"
        );

        // All three: the sum.
        let all = loss(
            &only("consistency,proportionality,reversibility", 1.0),
            &mut Rng::new(5),
            &q_step,
        );
        let parts = loss(&only("consistency", 1.0), &mut Rng::new(5), &q_step)
            + loss(&only("proportionality", 1.0), &mut Rng::new(5), &q_step)
            + got;
        assert!((all - parts).abs() < 1e-5 * parts);
    }
}
