//! A dense tanh network (multi-layer perceptron) in f32: parameters, initialisation, the
//! batched forward and backward passes used in training, and the model-file tensors.
//!
//! Layout: a layer is `y = b + x · W` with `W` row-major `(n_in, n_out)` (the layout of the
//! authors' exported weights); `tanh` follows every layer but the last. A batch is a row-major
//! `(batch, width)` matrix. Matrix products use `matrixmultiply`'s packed kernels (chosen at
//! run time for AVX2/FMA; single-threaded, so the result is deterministic).

use std::path::Path;

use safetensors::SafeTensors;

use super::kernel;
use super::tanh::tanh_in_place;
use crate::model::{ModelError, tensor_f32};
use crate::rng::Rng;

/// One dense layer.
#[derive(Debug, Clone, PartialEq)]
pub struct Dense {
    /// Inputs.
    pub n_in: usize,
    /// Outputs.
    pub n_out: usize,
    /// Weights, row-major `(n_in, n_out)`.
    pub w: Vec<f32>,
    /// Biases (`n_out`).
    pub b: Vec<f32>,
}

impl Dense {
    /// A layer of zeros.
    pub fn zeros(n_in: usize, n_out: usize) -> Self {
        Self {
            n_in,
            n_out,
            w: vec![0.0; n_in * n_out],
            b: vec![0.0; n_out],
        }
    }
}

/// A tanh MLP: `tanh` after every layer but the last.
#[derive(Debug, Clone, PartialEq)]
pub struct Mlp {
    /// The layers, input first.
    pub layers: Vec<Dense>,
}

/// `C = op(A) · op(B) + beta · C` on row-major buffers: `C` is `(m, n)`; `A` is stored as
/// `(m, k)`, or as `(k, m)` when `ta` (so `op(A)` is its transpose); `B` as `(k, n)`, or
/// `(n, k)` when `tb`. With `beta = 0`, `C` is not read.
#[allow(clippy::too_many_arguments)]
pub(crate) fn gemm(
    m: usize,
    k: usize,
    n: usize,
    a: &[f32],
    ta: bool,
    b: &[f32],
    tb: bool,
    beta: f32,
    c: &mut [f32],
) {
    assert!(
        a.len() >= m * k && b.len() >= k * n && c.len() >= m * n,
        "gemm: buffers too small for ({m} x {k}) · ({k} x {n})"
    );
    let (rsa, csa) = if ta { (1, m) } else { (k, 1) };
    let (rsb, csb) = if tb { (1, k) } else { (n, 1) };
    // SAFETY: the assertion above guarantees that every element addressed through these
    // strides, (m-1)·rsa + (k-1)·csa for A and likewise for B and C, lies inside its slice;
    // `c` is borrowed mutably, so it aliases neither `a` nor `b`.
    unsafe {
        matrixmultiply::sgemm(
            m,
            k,
            n,
            1.0,
            a.as_ptr(),
            rsa as isize,
            csa as isize,
            b.as_ptr(),
            rsb as isize,
            csb as isize,
            beta,
            c.as_mut_ptr(),
            n as isize,
            1,
        );
    }
}

/// Activations of one batched forward pass, kept for the backward pass, and its scratch.
/// Sized once for the largest batch; reused across batches without allocating.
#[derive(Debug, Clone)]
pub struct BatchCache {
    /// `acts[0]` is the input, `acts[l + 1]` the output of layer `l` (after tanh for hidden
    /// layers); each holds `max_batch × width` values, the first `batch × width` in use.
    acts: Vec<Vec<f32>>,
    widths: Vec<usize>,
    grad_a: Vec<f32>,
    grad_b: Vec<f32>,
    max_batch: usize,
    batch: usize,
}

impl BatchCache {
    /// Buffers for `mlp` and batches of up to `max_batch`.
    pub fn new(mlp: &Mlp, max_batch: usize) -> Self {
        let widths = mlp.widths();
        let widest = widths.iter().copied().max().unwrap_or(0);
        Self {
            acts: widths.iter().map(|w| vec![0.0; w * max_batch]).collect(),
            widths,
            grad_a: vec![0.0; widest * max_batch],
            grad_b: vec![0.0; widest * max_batch],
            max_batch,
            batch: 0,
        }
    }

    /// The network output of the last forward pass (`batch × n_out`, row-major).
    pub fn output(&self) -> &[f32] {
        let l = self.widths.len() - 1;
        &self.acts[l][..self.batch * self.widths[l]]
    }

    /// The input of the last forward pass (`batch × n_in`, row-major).
    pub fn input(&self) -> &[f32] {
        &self.acts[0][..self.batch * self.widths[0]]
    }

    /// The batch size of the last forward pass.
    pub fn batch(&self) -> usize {
        self.batch
    }

    /// The largest batch these buffers hold.
    pub fn max_batch(&self) -> usize {
        self.max_batch
    }
}

impl Mlp {
    /// A network with layer widths `sizes` (input first, at least two entries), initialised as
    /// PyTorch's `nn.Linear` does by default (weights and biases uniform in `±1/sqrt(n_in)`),
    /// from the seeded generator `rng`.
    pub fn init(sizes: &[usize], rng: &mut Rng) -> Self {
        let layers = sizes
            .windows(2)
            .map(|p| {
                let bound = 1.0 / (p[0] as f64).sqrt();
                let mut l = Dense::zeros(p[0], p[1]);
                l.w.iter_mut()
                    .for_each(|v| *v = rng.range(-bound, bound) as f32);
                l.b.iter_mut()
                    .for_each(|v| *v = rng.range(-bound, bound) as f32);
                l
            })
            .collect();
        Self { layers }
    }

    /// A network of zeros with the same shapes (a gradient accumulator).
    pub fn zeros_like(&self) -> Self {
        Self {
            layers: self
                .layers
                .iter()
                .map(|l| Dense::zeros(l.n_in, l.n_out))
                .collect(),
        }
    }

    /// Sets every parameter to zero.
    pub fn fill_zero(&mut self) {
        for l in &mut self.layers {
            l.w.fill(0.0);
            l.b.fill(0.0);
        }
    }

    /// Layer widths, input first.
    pub fn widths(&self) -> Vec<usize> {
        let mut w: Vec<usize> = self.layers.iter().map(|l| l.n_in).collect();
        w.extend(self.layers.last().map(|l| l.n_out));
        w
    }

    /// Input width.
    pub fn n_in(&self) -> usize {
        self.layers.first().map_or(0, |l| l.n_in)
    }

    /// Output width.
    pub fn n_out(&self) -> usize {
        self.layers.last().map_or(0, |l| l.n_out)
    }

    /// Widest layer output (a scratch size for single-sample evaluation).
    pub fn widest(&self) -> usize {
        self.layers.iter().map(|l| l.n_out).max().unwrap_or(0)
    }

    /// Number of parameters.
    pub fn n_params(&self) -> usize {
        self.layers.iter().map(|l| l.w.len() + l.b.len()).sum()
    }

    /// The layers rearranged for single-sample evaluation ([`kernel::Packed`]).
    pub fn packed(&self) -> kernel::Packed {
        kernel::Packed::new(&self.layers)
    }

    /// One sample in f64 with `f64::tanh` (a reference for tests and analyses, not the
    /// serving path).
    pub fn forward_f64(&self, x: &[f64]) -> Vec<f64> {
        let mut h = x.to_vec();
        let n = self.layers.len();
        for (i, l) in self.layers.iter().enumerate() {
            let mut y: Vec<f64> = l.b.iter().map(|v| f64::from(*v)).collect();
            for (k, hk) in h.iter().enumerate().take(l.n_in) {
                let row = &l.w[k * l.n_out..(k + 1) * l.n_out];
                for (yj, wkj) in y.iter_mut().zip(row) {
                    *yj += f64::from(*wkj) * hk;
                }
            }
            if i + 1 < n {
                y.iter_mut().for_each(|v| *v = v.tanh());
            }
            h = y;
        }
        h
    }

    /// Forward pass of `batch` rows of `x` (row-major `batch × n_in`), keeping the
    /// activations in `cache`. The output is [`BatchCache::output`].
    pub fn forward_batch(&self, x: &[f32], batch: usize, cache: &mut BatchCache) {
        assert!(batch <= cache.max_batch, "batch larger than the cache");
        cache.batch = batch;
        let n_in = self.n_in();
        cache.acts[0][..batch * n_in].copy_from_slice(&x[..batch * n_in]);
        let n = self.layers.len();
        for (l, layer) in self.layers.iter().enumerate() {
            let (before, after) = cache.acts.split_at_mut(l + 1);
            let input = &before[l][..batch * layer.n_in];
            let out = &mut after[0][..batch * layer.n_out];
            for row in out.chunks_exact_mut(layer.n_out) {
                row.copy_from_slice(&layer.b);
            }
            gemm(
                batch,
                layer.n_in,
                layer.n_out,
                input,
                false,
                &layer.w,
                false,
                1.0,
                out,
            );
            if l + 1 < n {
                tanh_in_place(out);
            }
        }
    }

    /// Backward pass of the last [`Mlp::forward_batch`] in `cache`: given the gradient of the
    /// loss with respect to the output (`g_out`, `batch × n_out`), adds the parameter
    /// gradients into `grads` (same shapes as `self`) and, when `g_in` is given, writes the
    /// gradient with respect to the input into it (`batch × n_in`).
    pub fn backward_batch(
        &self,
        cache: &mut BatchCache,
        g_out: &[f32],
        grads: &mut Mlp,
        g_in: Option<&mut [f32]>,
    ) {
        let batch = cache.batch;
        let n = self.layers.len();
        let BatchCache {
            acts,
            grad_a,
            grad_b,
            ..
        } = cache;
        let n_out = self.n_out();
        grad_a[..batch * n_out].copy_from_slice(&g_out[..batch * n_out]);
        let (mut g, mut g_next) = (grad_a, grad_b);
        let want_input = g_in.is_some();
        for l in (0..n).rev() {
            let layer = &self.layers[l];
            let gl = &mut grads.layers[l];
            let input = &acts[l][..batch * layer.n_in];
            let gz = &g[..batch * layer.n_out];
            // gW += Xᵀ · G
            gemm(
                layer.n_in,
                batch,
                layer.n_out,
                input,
                true,
                gz,
                false,
                1.0,
                &mut gl.w,
            );
            for row in gz.chunks_exact(layer.n_out) {
                for (gb, v) in gl.b.iter_mut().zip(row) {
                    *gb += v;
                }
            }
            if l == 0 && !want_input {
                break;
            }
            let gx = &mut g_next[..batch * layer.n_in];
            // G_in = G · Wᵀ
            gemm(
                batch,
                layer.n_out,
                layer.n_in,
                gz,
                false,
                &layer.w,
                true,
                0.0,
                gx,
            );
            if l > 0 {
                // Through the tanh that produced this layer's input: d tanh = 1 − y².
                for (gv, y) in gx.iter_mut().zip(input) {
                    *gv *= 1.0 - y * y;
                }
            }
            std::mem::swap(&mut g, &mut g_next);
        }
        if let Some(dst) = g_in {
            let n_in = self.n_in();
            dst[..batch * n_in].copy_from_slice(&g[..batch * n_in]);
        }
    }

    /// The model-file tensors of this network: `{prefix}.{l}.weight` (`[n_in, n_out]`) and
    /// `{prefix}.{l}.bias` (`[n_out]`).
    pub fn tensors(&self, prefix: &str) -> Vec<(String, Vec<usize>, Vec<f32>)> {
        let mut out = Vec::new();
        for (i, l) in self.layers.iter().enumerate() {
            out.push((
                format!("{prefix}.{i}.weight"),
                vec![l.n_in, l.n_out],
                l.w.clone(),
            ));
            out.push((format!("{prefix}.{i}.bias"), vec![l.n_out], l.b.clone()));
        }
        out
    }

    /// Reads a network of widths `sizes` written by [`Mlp::tensors`], checking every shape
    /// and value.
    pub fn from_tensors(
        st: &SafeTensors<'_>,
        prefix: &str,
        sizes: &[usize],
        path: &Path,
    ) -> Result<Self, ModelError> {
        let mut layers = Vec::new();
        for (i, p) in sizes.windows(2).enumerate() {
            let w = tensor_f32(st, &format!("{prefix}.{i}.weight"), &[p[0], p[1]], path)?;
            let b = tensor_f32(st, &format!("{prefix}.{i}.bias"), &[p[1]], path)?;
            layers.push(Dense {
                n_in: p[0],
                n_out: p[1],
                w,
                b,
            });
        }
        // No extra layers beyond the declared ones.
        let extra = format!("{prefix}.{}.weight", sizes.len().saturating_sub(1));
        if st.tensor(&extra).is_ok() {
            return Err(ModelError::BadTensor {
                path: path.to_owned(),
                name: extra,
                reason: format!(
                    "the header declares {} layers, the file has more",
                    sizes.len() - 1
                ),
            });
        }
        Ok(Self { layers })
    }
}

/// Adam (Kingma & Ba) exactly as PyTorch's `torch.optim.Adam` with no weight decay: bias-
/// corrected first and second moments, `p ← p − lr · m̂ / (sqrt(v̂) + eps)`.
#[derive(Debug, Clone)]
pub struct Adam {
    /// Learning rate.
    pub lr: f32,
    /// First-moment decay.
    pub beta1: f32,
    /// Second-moment decay.
    pub beta2: f32,
    /// Denominator guard.
    pub eps: f32,
    t: i32,
    m: Mlp,
    v: Mlp,
}

impl Adam {
    /// Adam state for `params` with PyTorch's defaults (`betas = (0.9, 0.999)`, `eps = 1e-8`).
    pub fn new(params: &Mlp, lr: f32) -> Self {
        Self {
            lr,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
            t: 0,
            m: params.zeros_like(),
            v: params.zeros_like(),
        }
    }

    /// One update of `params` with gradient `grads`.
    pub fn step(&mut self, params: &mut Mlp, grads: &Mlp) {
        self.t = self.t.saturating_add(1);
        let (b1, b2) = (self.beta1, self.beta2);
        let c1 = 1.0 - b1.powi(self.t);
        let c2 = 1.0 - b2.powi(self.t);
        let step = self.lr / c1;
        let c2_sqrt = c2.sqrt();
        let eps = self.eps;
        let update = |p: &mut [f32], g: &[f32], m: &mut [f32], v: &mut [f32]| {
            for (((p, g), m), v) in p.iter_mut().zip(g).zip(m.iter_mut()).zip(v.iter_mut()) {
                *m = b1 * *m + (1.0 - b1) * g;
                *v = b2 * *v + (1.0 - b2) * g * g;
                *p -= step * *m / (v.sqrt() / c2_sqrt + eps);
            }
        };
        for (((p, g), m), v) in params
            .layers
            .iter_mut()
            .zip(&grads.layers)
            .zip(&mut self.m.layers)
            .zip(&mut self.v.layers)
        {
            update(&mut p.w, &g.w, &mut m.w, &mut v.w);
            update(&mut p.b, &g.b, &mut m.b, &mut v.b);
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// Mean of `0.5 · (out − target)²` and its backward, for gradient checks.
    fn loss_and_grad(mlp: &Mlp, x: &[f32], target: &[f32], batch: usize) -> (f64, Mlp, Vec<f32>) {
        let mut cache = BatchCache::new(mlp, batch);
        mlp.forward_batch(x, batch, &mut cache);
        let out = cache.output().to_vec();
        let loss: f64 = out
            .iter()
            .zip(target)
            .map(|(o, t)| 0.5 * f64::from(o - t).powi(2))
            .sum();
        let g: Vec<f32> = out.iter().zip(target).map(|(o, t)| o - t).collect();
        let mut grads = mlp.zeros_like();
        let mut gx = vec![0.0; batch * mlp.n_in()];
        mlp.backward_batch(&mut cache, &g, &mut grads, Some(&mut gx));
        (loss, grads, gx)
    }

    fn loss_only(mlp: &Mlp, x: &[f32], target: &[f32], batch: usize) -> f64 {
        let mut cache = BatchCache::new(mlp, batch);
        mlp.forward_batch(x, batch, &mut cache);
        cache
            .output()
            .iter()
            .zip(target)
            .map(|(o, t)| 0.5 * f64::from(o - t).powi(2))
            .sum()
    }

    #[test]
    fn batched_forward_matches_single_sample_and_f64() {
        let mut r = Rng::new(1);
        let mlp = Mlp::init(&[7, 64, 48, 12], &mut r);
        let batch = 9;
        let x: Vec<f32> = (0..batch * 7).map(|_| r.normal() as f32).collect();
        let mut cache = BatchCache::new(&mlp, 16);
        mlp.forward_batch(&x, batch, &mut cache);
        let packed = mlp.packed();
        let (mut a, mut b) = (
            vec![0.0; packed.scratch_len()],
            vec![0.0; packed.scratch_len()],
        );
        let mut out = vec![0.0; 12];
        for s in 0..batch {
            let xs = &x[s * 7..(s + 1) * 7];
            kernel::forward(
                kernel::Kernel::detect(),
                &packed,
                xs,
                &mut a,
                &mut b,
                &mut out,
            );
            let reference = mlp.forward_f64(&xs.iter().map(|v| f64::from(*v)).collect::<Vec<_>>());
            for j in 0..12 {
                let batched = cache.output()[s * 12 + j];
                assert!((batched - out[j]).abs() < 1e-5);
                assert!((f64::from(out[j]) - reference[j]).abs() < 1e-5);
            }
        }
    }

    #[test]
    fn gradients_match_finite_differences() {
        let mut r = Rng::new(2);
        let mlp = Mlp::init(&[5, 8, 7, 3], &mut r);
        let batch = 4;
        let x: Vec<f32> = (0..batch * 5).map(|_| r.normal() as f32).collect();
        let t: Vec<f32> = (0..batch * 3).map(|_| r.normal() as f32).collect();
        let (_, grads, gx) = loss_and_grad(&mlp, &x, &t, batch);
        let h = 1e-2f32;
        for l in 0..mlp.layers.len() {
            for idx in [0, 3, mlp.layers[l].w.len() - 1] {
                let mut p = mlp.clone();
                p.layers[l].w[idx] += h;
                let mut n = mlp.clone();
                n.layers[l].w[idx] -= h;
                let fd = (loss_only(&p, &x, &t, batch) - loss_only(&n, &x, &t, batch))
                    / (2.0 * f64::from(h));
                let an = f64::from(grads.layers[l].w[idx]);
                assert!(
                    (fd - an).abs() < 2e-3 * (1.0 + fd.abs()),
                    "w{l}[{idx}] {fd} {an}"
                );
            }
            let mut p = mlp.clone();
            p.layers[l].b[1] += h;
            let mut n = mlp.clone();
            n.layers[l].b[1] -= h;
            let fd = (loss_only(&p, &x, &t, batch) - loss_only(&n, &x, &t, batch))
                / (2.0 * f64::from(h));
            let an = f64::from(grads.layers[l].b[1]);
            assert!((fd - an).abs() < 2e-3 * (1.0 + fd.abs()), "b{l} {fd} {an}");
        }
        for idx in [0, 7, 19] {
            let mut p = x.clone();
            p[idx] += h;
            let mut n = x.clone();
            n[idx] -= h;
            let fd = (loss_only(&mlp, &p, &t, batch) - loss_only(&mlp, &n, &t, batch))
                / (2.0 * f64::from(h));
            let an = f64::from(gx[idx]);
            assert!(
                (fd - an).abs() < 2e-3 * (1.0 + fd.abs()),
                "x[{idx}] {fd} {an}"
            );
        }
    }

    #[test]
    fn adam_matches_hand_computed_first_steps() {
        // One parameter, constant gradient g: after bias correction every step is lr·g/(|g|+eps').
        let mut p = Mlp {
            layers: vec![Dense {
                n_in: 1,
                n_out: 1,
                w: vec![1.0],
                b: vec![0.0],
            }],
        };
        let mut g = p.zeros_like();
        g.layers[0].w[0] = 0.5;
        g.layers[0].b[0] = -2.0;
        let mut adam = Adam::new(&p, 0.1);
        adam.step(&mut p, &g);
        adam.step(&mut p, &g);
        assert!(
            (p.layers[0].w[0] - 0.8).abs() < 1e-6,
            "{}",
            p.layers[0].w[0]
        );
        assert!(
            (p.layers[0].b[0] - 0.2).abs() < 1e-6,
            "{}",
            p.layers[0].b[0]
        );
    }
}
