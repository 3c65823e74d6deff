//! Single-sample evaluation of a dense tanh network into caller buffers: the serving path.
//!
//! A layer is `y = b + x · W` with `W` row-major `(n_in, n_out)`. The loops are written in
//! the "axpy" order (for each input `k`, add `x_k · W[k, ..]` to a block of outputs), so
//! every operation is element-wise across outputs and vectorises without reordering a sum;
//! blocks of 64 outputs stay in registers while all inputs stream past. On x86-64 CPUs with
//! AVX2 and FMA a copy of the loops compiled for those features is chosen at run time
//! ([`Kernel::detect`]); otherwise the portable copy (SSE2) runs. No function here allocates.

use super::mlp::Dense;
use super::tanh::tanh_in_place_body;

/// Which compiled copy of the loops to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kernel {
    /// Baseline x86-64 / other architectures.
    Portable,
    /// x86-64 with AVX2 and FMA (fused multiply-add in the dense loops).
    #[cfg(target_arch = "x86_64")]
    Avx2Fma,
}

impl Kernel {
    /// The best copy this CPU can run.
    pub fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma") {
            return Self::Avx2Fma;
        }
        Self::Portable
    }
}

/// Outputs held in registers per pass over the inputs.
const BLOCK: usize = 64;

#[inline(always)]
fn madd<const FMA: bool>(acc: f32, w: f32, x: f32) -> f32 {
    if FMA { w.mul_add(x, acc) } else { acc + w * x }
}

/// `y = b + x · W` for one sample.
#[inline(always)]
fn affine_body<const FMA: bool>(layer: &Dense, x: &[f32], y: &mut [f32]) {
    let n_out = layer.b.len();
    let y = &mut y[..n_out];
    let mut j0 = 0;
    while j0 + BLOCK <= n_out {
        let mut acc = [0.0f32; BLOCK];
        acc.copy_from_slice(&layer.b[j0..j0 + BLOCK]);
        for (row, &xk) in layer.w.chunks_exact(n_out).zip(x) {
            let wr = &row[j0..j0 + BLOCK];
            for (a, &wv) in acc.iter_mut().zip(wr) {
                *a = madd::<FMA>(*a, wv, xk);
            }
        }
        y[j0..j0 + BLOCK].copy_from_slice(&acc);
        j0 += BLOCK;
    }
    if j0 < n_out {
        let tail = &mut y[j0..];
        tail.copy_from_slice(&layer.b[j0..]);
        for (row, &xk) in layer.w.chunks_exact(n_out).zip(x) {
            for (a, &wv) in tail.iter_mut().zip(&row[j0..]) {
                *a = madd::<FMA>(*a, wv, xk);
            }
        }
    }
}

/// Runs the layers on `x`: tanh after every layer but the last. `a` and `b` are scratch of at
/// least the widest hidden layer; the result is written to `out[..n_out_last]`.
#[inline(always)]
fn forward_body<const FMA: bool>(
    layers: &[Dense],
    x: &[f32],
    a: &mut [f32],
    b: &mut [f32],
    out: &mut [f32],
) {
    let n = layers.len();
    let mut input_is_a = false;
    for (l, layer) in layers.iter().enumerate() {
        let n_out = layer.b.len();
        let last = l + 1 == n;
        let (src, dst): (&[f32], &mut [f32]) = match (l, last, input_is_a) {
            (0, true, _) => (x, &mut *out),
            (0, false, _) => (x, &mut *a),
            (_, true, true) => (&*a, &mut *out),
            (_, true, false) => (&*b, &mut *out),
            (_, false, true) => (&*a, &mut *b),
            (_, false, false) => (&*b, &mut *a),
        };
        affine_body::<FMA>(layer, src, dst);
        if !last {
            tanh_in_place_body(&mut dst[..n_out]);
            input_is_a = l == 0 || !input_is_a;
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn forward_avx2(layers: &[Dense], x: &[f32], a: &mut [f32], b: &mut [f32], out: &mut [f32]) {
    forward_body::<true>(layers, x, a, b, out);
}

/// Evaluates a tanh MLP on one sample with the given kernel (see the module docs). `scratch_a`
/// and `scratch_b` must hold the widest hidden layer; `out` the last layer's outputs.
pub fn forward(
    kernel: Kernel,
    layers: &[Dense],
    x: &[f32],
    scratch_a: &mut [f32],
    scratch_b: &mut [f32],
    out: &mut [f32],
) {
    match kernel {
        Kernel::Portable => forward_body::<false>(layers, x, scratch_a, scratch_b, out),
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `Kernel::Avx2Fma` is only constructed by `Kernel::detect` after it found
        // AVX2 and FMA on this CPU.
        Kernel::Avx2Fma => unsafe { forward_avx2(layers, x, scratch_a, scratch_b, out) },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    fn reference(layers: &[(Vec<f32>, Vec<f32>)], x: &[f32]) -> Vec<f64> {
        let mut h: Vec<f64> = x.iter().map(|v| f64::from(*v)).collect();
        for (l, (w, b)) in layers.iter().enumerate() {
            let n_out = b.len();
            let mut y: Vec<f64> = b.iter().map(|v| f64::from(*v)).collect();
            for (k, hk) in h.iter().enumerate() {
                for j in 0..n_out {
                    y[j] += f64::from(w[k * n_out + j]) * hk;
                }
            }
            if l + 1 < layers.len() {
                y.iter_mut().for_each(|v| *v = v.tanh());
            }
            h = y;
        }
        h
    }

    #[test]
    fn kernels_agree_with_an_f64_reference() {
        let mut r = Rng::new(3);
        for sizes in [
            vec![7, 256, 256, 12],
            vec![9, 70, 130, 6],
            vec![3, 5, 2],
            vec![4, 1],
        ] {
            let layers: Vec<(Vec<f32>, Vec<f32>)> = sizes
                .windows(2)
                .map(|p| {
                    let s = 1.0 / (p[0] as f64).sqrt();
                    let w = (0..p[0] * p[1]).map(|_| r.range(-s, s) as f32).collect();
                    let b = (0..p[1]).map(|_| r.range(-s, s) as f32).collect();
                    (w, b)
                })
                .collect();
            let refs: Vec<Dense> = layers
                .iter()
                .map(|(w, b)| Dense {
                    n_in: w.len() / b.len(),
                    n_out: b.len(),
                    w: w.clone(),
                    b: b.clone(),
                })
                .collect();
            let x: Vec<f32> = (0..sizes[0]).map(|_| r.normal() as f32).collect();
            let expect = reference(&layers, &x);
            let n_out = *sizes.last().unwrap();
            let mut kernels = vec![Kernel::Portable];
            if Kernel::detect() != Kernel::Portable {
                kernels.push(Kernel::detect());
            }
            for k in kernels {
                let (mut a, mut b) = (vec![0.0; 256], vec![0.0; 256]);
                let mut out = vec![0.0; n_out];
                forward(k, &refs, &x, &mut a, &mut b, &mut out);
                for (o, e) in out.iter().zip(&expect) {
                    assert!(
                        (f64::from(*o) - e).abs() < 1e-5,
                        "{k:?} {sizes:?}: {o} vs {e}"
                    );
                }
            }
        }
    }
}
