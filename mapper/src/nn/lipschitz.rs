//! Lipschitz bounds by spectral normalisation (Gouk et al. 2021, "Regularisation of neural
//! networks by enforcing Lipschitz continuity", Algorithm 1).
//!
//! A tanh network is Lipschitz with constant at most the product of its layers' spectral
//! norms (`tanh` is 1-Lipschitz). After every optimiser step each weight matrix is projected,
//! `W ← W / max(1, σ(W) / λ)`, with `σ(W)` estimated by power iteration whose vector persists
//! across steps (so one iteration per step suffices once it has converged) and
//! `λ = L^(1/layers)`, so that the whole network's bound is `L`.
//!
//! Inputs are normalised, `x = (o − μ) / s`, before the first layer; the bound is wanted
//! with respect to the raw observation `o` (joint angles), so the first layer's norm is that
//! of the *effective* matrix `diag(1/s) · W` (its rows scaled by `1/s`).
//!
//! Power iteration approaches `σ` from below, so after training [`certify`] computes every
//! norm exactly (a singular value decomposition in f64) and scales any layer still above `λ`.

use nalgebra::DMatrix;

use super::mlp::Mlp;
use crate::rng::Rng;

/// Power-iteration state for one layer: its right singular vector estimate.
#[derive(Debug, Clone)]
pub struct PowerIteration {
    u: Vec<f32>,
    v: Vec<f32>,
}

impl PowerIteration {
    /// A random start for a `(n_in, n_out)` matrix.
    pub fn new(n_in: usize, n_out: usize, rng: &mut Rng) -> Self {
        let mut u: Vec<f32> = (0..n_out).map(|_| rng.normal() as f32).collect();
        normalise(&mut u);
        Self {
            u,
            v: vec![0.0; n_in],
        }
    }

    /// Runs `iters` iterations on the effective matrix `diag(row_scale) · W` (`W` row-major
    /// `(n_in, n_out)`) and returns the estimate of its largest singular value.
    pub fn step(
        &mut self,
        w: &[f32],
        n_in: usize,
        n_out: usize,
        row_scale: Option<&[f32]>,
        iters: usize,
    ) -> f32 {
        debug_assert_eq!(w.len(), n_in * n_out);
        let mut sigma = 0.0;
        for _ in 0..iters.max(1) {
            // v = M u
            for (k, vk) in self.v.iter_mut().enumerate() {
                let row = &w[k * n_out..(k + 1) * n_out];
                let s: f32 = row.iter().zip(&self.u).map(|(a, b)| a * b).sum();
                *vk = s * row_scale.map_or(1.0, |r| r[k]);
            }
            normalise(&mut self.v);
            // u = Mᵀ v
            self.u.fill(0.0);
            for (k, vk) in self.v.iter().enumerate() {
                let c = vk * row_scale.map_or(1.0, |r| r[k]);
                let row = &w[k * n_out..(k + 1) * n_out];
                for (uj, wkj) in self.u.iter_mut().zip(row) {
                    *uj += c * wkj;
                }
            }
            sigma = normalise(&mut self.u);
        }
        sigma
    }
}

fn normalise(x: &mut [f32]) -> f32 {
    let n = x.iter().map(|v| v * v).sum::<f32>().sqrt();
    if n > 0.0 {
        x.iter_mut().for_each(|v| *v /= n);
    }
    n
}

/// Spectral norm of `diag(row_scale) · W` computed exactly (singular values, f64).
pub fn spectral_norm(w: &[f32], n_in: usize, n_out: usize, row_scale: Option<&[f32]>) -> f64 {
    let m = DMatrix::from_fn(n_in, n_out, |k, j| {
        f64::from(w[k * n_out + j]) * row_scale.map_or(1.0, |r| f64::from(r[k]))
    });
    m.singular_values().max()
}

/// Per-layer bound `L^(1/layers)` that makes a `layers`-layer network `L`-Lipschitz.
pub fn per_layer_bound(l: f64, layers: usize) -> f64 {
    l.powf(1.0 / layers.max(1) as f64)
}

/// Projects `net` after an optimiser step: every layer whose estimated norm exceeds
/// `per_layer` is scaled down to it. `input_scale` is `1/s` of the input normalisation.
pub fn project(
    net: &mut Mlp,
    state: &mut [PowerIteration],
    per_layer: f32,
    input_scale: &[f32],
    iters: usize,
) {
    for (i, (layer, pi)) in net.layers.iter_mut().zip(state.iter_mut()).enumerate() {
        let scale = (i == 0).then_some(input_scale);
        let sigma = pi.step(&layer.w, layer.n_in, layer.n_out, scale, iters);
        if sigma > per_layer {
            let f = per_layer / sigma;
            layer.w.iter_mut().for_each(|v| *v *= f);
        }
    }
}

/// Makes the bound exact: computes every layer's spectral norm (with the input scaling on the
/// first) and scales any layer above `per_layer` down to `per_layer · (1 − 1e-6)`. Returns the
/// certified bound of the whole network, the product of the final norms.
pub fn certify(net: &mut Mlp, per_layer: f64, input_scale: &[f32]) -> f64 {
    let mut product = 1.0;
    for (i, layer) in net.layers.iter_mut().enumerate() {
        let scale = (i == 0).then_some(input_scale);
        let mut sigma = spectral_norm(&layer.w, layer.n_in, layer.n_out, scale);
        if sigma > per_layer {
            let f = (per_layer * (1.0 - 1e-6) / sigma) as f32;
            layer.w.iter_mut().for_each(|v| *v *= f);
            sigma = spectral_norm(&layer.w, layer.n_in, layer.n_out, scale);
        }
        product *= sigma;
    }
    product
}

/// The Lipschitz bound of `net` with respect to its raw input: the product of the exact
/// spectral norms, the first scaled by `input_scale`.
pub fn bound(net: &Mlp, input_scale: &[f32]) -> f64 {
    net.layers
        .iter()
        .enumerate()
        .map(|(i, l)| spectral_norm(&l.w, l.n_in, l.n_out, (i == 0).then_some(input_scale)))
        .product()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn power_iteration_converges_to_the_exact_norm() {
        let mut r = Rng::new(4);
        let net = Mlp::init(&[7, 40, 30], &mut r);
        let l = &net.layers[0];
        let scale: Vec<f32> = (0..7).map(|i| 0.5 + i as f32 * 0.3).collect();
        let exact = spectral_norm(&l.w, 7, 40, Some(&scale));
        let mut pi = PowerIteration::new(7, 40, &mut r);
        let est = pi.step(&l.w, 7, 40, Some(&scale), 200);
        assert!(
            (f64::from(est) - exact).abs() < 1e-4 * exact,
            "{est} vs {exact}"
        );
        // A lower bound at every stage.
        let mut pi = PowerIteration::new(7, 40, &mut r);
        assert!(f64::from(pi.step(&l.w, 7, 40, Some(&scale), 1)) <= exact * (1.0 + 1e-5));
    }

    #[test]
    fn projection_and_certification_bound_the_network() {
        let mut r = Rng::new(5);
        let mut net = Mlp::init(&[7, 64, 64, 12], &mut r);
        // Make it steep first.
        for l in &mut net.layers {
            l.w.iter_mut().for_each(|v| *v *= 5.0);
        }
        let scale = vec![2.0f32; 7];
        assert!(bound(&net, &scale) > 1.0);
        let per = per_layer_bound(0.5, 3) as f32;
        let mut state: Vec<PowerIteration> = net
            .layers
            .iter()
            .map(|l| PowerIteration::new(l.n_in, l.n_out, &mut r))
            .collect();
        for _ in 0..50 {
            project(&mut net, &mut state, per, &scale, 1);
        }
        assert!(bound(&net, &scale) < 0.5 * 1.01);
        let certified = certify(&mut net, per_layer_bound(0.5, 3), &scale);
        assert!(certified <= 0.5);
        assert!((bound(&net, &scale) - certified).abs() < 1e-9);
    }
}
