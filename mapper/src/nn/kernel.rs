//! Single-sample evaluation of a dense tanh network into caller buffers: the serving path.
//!
//! A layer is `y = b + x · W` with `W` row-major `(n_in, n_out)`. The loops are written in
//! the "axpy" order (for each input `k`, add `x_k · W[k, ..]` to a block of outputs), so
//! every operation is element-wise across outputs and vectorises without reordering a sum
//! within a lane; blocks of up to 64 outputs stay in registers while the inputs stream past.
//! The weights are first rearranged once ([`Packed`]) so that this stream is sequential in
//! memory (the 256 × 256 layer, 256 KiB, does not fit in L1 and is read from L2 every call;
//! that read is most of the cost). On x86-64 CPUs with AVX2 and FMA a copy of the loops
//! compiled for those features is chosen at run time ([`Kernel::detect`]; only a run-time check
//! makes that [`Kernel`]); otherwise the portable copy (SSE2) runs. No function here allocates.

use super::mlp::Dense;
use super::tanh::tanh_in_place_body;

/// Which compiled copy of the loops to run: a token that the CPU can run it.
///
/// The AVX2 / FMA copy is only obtainable from a run-time check of this CPU
/// ([`Kernel::detect`], [`Kernel::avx2_fma`]), so safe code cannot run instructions the CPU
/// lacks. Which copy a kernel is shows in its `Debug` form (`Portable`, `Avx2Fma`) and in
/// [`Kernel::is_avx2_fma`].
///
/// ```
/// use mapper::nn::Kernel;
///
/// let best = Kernel::detect();
/// assert_eq!(best.is_avx2_fma(), Kernel::avx2_fma().is_some());
/// assert!(!Kernel::portable().is_avx2_fma());
/// ```
///
/// The kernel cannot be built by hand, so the AVX2 copy cannot be chosen on a CPU without
/// AVX2:
///
/// ```compile_fail
/// let k = mapper::nn::Kernel::Avx2Fma;
/// ```
///
/// ```compile_fail
/// let k = mapper::nn::Kernel(mapper::nn::kernel::Isa::Avx2Fma);
/// ```
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Kernel(Isa);

/// The compiled copies (private: a [`Kernel`] of `Avx2Fma` proves that the CPU has both).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Isa {
    /// Baseline x86-64 / other architectures.
    Portable,
    /// x86-64 with AVX2 and FMA (fused multiply-add in the dense loops).
    #[cfg(target_arch = "x86_64")]
    Avx2Fma,
}

impl Kernel {
    /// The best copy this CPU can run.
    pub fn detect() -> Self {
        Self::avx2_fma().unwrap_or(Self::portable())
    }

    /// The portable copy (SSE2 on x86-64), which every CPU runs.
    pub const fn portable() -> Self {
        Self(Isa::Portable)
    }

    /// The AVX2 / FMA copy if this CPU has both features (checked now), `None` otherwise
    /// and on other architectures.
    pub fn avx2_fma() -> Option<Self> {
        #[cfg(target_arch = "x86_64")]
        if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma") {
            return Some(Self(Isa::Avx2Fma));
        }
        None
    }

    /// Whether this is the AVX2 / FMA copy.
    pub fn is_avx2_fma(self) -> bool {
        self != Self::portable()
    }
}

impl std::fmt::Debug for Kernel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        self.0.fmt(f)
    }
}

/// Outputs held in registers per pass over the inputs.
const BLOCK: usize = 64;
/// Output blocks are padded to a multiple of this (one AVX register of f32).
const LANES: usize = 8;

/// A network's weights rearranged for single-sample evaluation: each layer's outputs are cut
/// into blocks of up to 64 (padded with zeros to a multiple of 8), and each block's weights
/// are stored contiguously (`[block][input][output in block]`), so one pass over the inputs
/// streams through memory sequentially with the block's outputs held in registers. The
/// arithmetic is that of `y = b + x · W`, only the order of the sums differs from the batched
/// training pass.
#[derive(Debug, Clone, PartialEq)]
pub struct Packed {
    layers: Vec<PackedLayer>,
    widest: usize,
}

#[derive(Debug, Clone, PartialEq)]
struct PackedLayer {
    n_in: usize,
    n_out: usize,
    /// `(start, width)` of each block; widths are multiples of [`LANES`].
    blocks: Vec<(usize, usize)>,
    /// Concatenated blocks, each `n_in × width`.
    w: Vec<f32>,
    /// Biases padded to the blocks' total width.
    b: Vec<f32>,
}

impl Packed {
    /// Packs the layers of a network.
    pub fn new(layers: &[Dense]) -> Self {
        let mut widest = 0;
        let layers = layers
            .iter()
            .map(|l| {
                let mut blocks = Vec::new();
                let mut start = 0;
                while start < l.n_out {
                    let width = (l.n_out - start).min(BLOCK).div_ceil(LANES) * LANES;
                    blocks.push((start, width));
                    start += width;
                }
                let padded = start;
                widest = widest.max(padded);
                let mut w = Vec::with_capacity(l.n_in * padded);
                for &(j0, width) in &blocks {
                    for k in 0..l.n_in {
                        for j in j0..j0 + width {
                            w.push(if j < l.n_out {
                                l.w[k * l.n_out + j]
                            } else {
                                0.0
                            });
                        }
                    }
                }
                let mut b = l.b.clone();
                b.resize(padded, 0.0);
                PackedLayer {
                    n_in: l.n_in,
                    n_out: l.n_out,
                    blocks,
                    w,
                    b,
                }
            })
            .collect();
        Self { layers, widest }
    }

    /// Scratch length [`forward`] needs per buffer (the widest padded layer).
    pub fn scratch_len(&self) -> usize {
        self.widest
    }

    /// Output width of the network.
    pub fn n_out(&self) -> usize {
        self.layers.last().map_or(0, |l| l.n_out)
    }
}

#[inline(always)]
fn madd<const FMA: bool>(acc: f32, w: f32, x: f32) -> f32 {
    if FMA { w.mul_add(x, acc) } else { acc + w * x }
}

/// One block of `W` outputs: `S` interleaved partial sums over the inputs (input `k` goes to
/// sum `k mod S`, so that narrow blocks still keep several independent multiply-add chains in
/// flight), then their sum.
#[inline(always)]
fn block<const FMA: bool, const W: usize, const S: usize>(
    w: &[f32],
    b: &[f32],
    x: &[f32],
    y: &mut [f32],
) {
    let mut acc = [[0.0f32; W]; S];
    acc[0].copy_from_slice(&b[..W]);
    let mut wc = w.chunks_exact(W * S);
    let mut xc = x.chunks_exact(S);
    for (ws, xs) in (&mut wc).zip(&mut xc) {
        for s in 0..S {
            let xk = xs[s];
            let row = &ws[s * W..(s + 1) * W];
            for j in 0..W {
                acc[s][j] = madd::<FMA>(acc[s][j], row[j], xk);
            }
        }
    }
    for (row, &xk) in wc.remainder().chunks_exact(W).zip(xc.remainder()) {
        for j in 0..W {
            acc[0][j] = madd::<FMA>(acc[0][j], row[j], xk);
        }
    }
    for j in 0..W {
        let mut v = acc[0][j];
        for part in &acc[1..] {
            v += part[j];
        }
        y[j] = v;
    }
}

/// `y = b + x · W` for one sample, over the padded width.
#[inline(always)]
fn affine_body<const FMA: bool>(layer: &PackedLayer, x: &[f32], y: &mut [f32]) {
    let mut offset = 0;
    for &(j0, width) in &layer.blocks {
        let w = &layer.w[offset..offset + layer.n_in * width];
        let b = &layer.b[j0..j0 + width];
        let y = &mut y[j0..j0 + width];
        match width {
            64 => block::<FMA, 64, 1>(w, b, x, y),
            56 => block::<FMA, 56, 1>(w, b, x, y),
            48 => block::<FMA, 48, 1>(w, b, x, y),
            40 => block::<FMA, 40, 1>(w, b, x, y),
            32 => block::<FMA, 32, 2>(w, b, x, y),
            24 => block::<FMA, 24, 2>(w, b, x, y),
            16 => block::<FMA, 16, 4>(w, b, x, y),
            _ => block::<FMA, 8, 8>(w, b, x, y),
        }
        offset += layer.n_in * width;
    }
}

/// Runs the layers on `x`: tanh after every layer but the last. `a` and `b` are scratch of
/// [`Packed::scratch_len`]; the result is written to `out[..n_out]`.
#[inline(always)]
fn forward_body<const FMA: bool>(
    net: &Packed,
    x: &[f32],
    a: &mut [f32],
    b: &mut [f32],
    out: &mut [f32],
) {
    let n = net.layers.len();
    let mut input_is_a = false;
    for (l, layer) in net.layers.iter().enumerate() {
        let last = l + 1 == n;
        let (src, dst): (&[f32], &mut [f32]) = match (l, input_is_a) {
            (0, _) => (x, &mut *a),
            (_, true) => (&*a, &mut *b),
            (_, false) => (&*b, &mut *a),
        };
        affine_body::<FMA>(layer, &src[..layer.n_in], dst);
        if last {
            out[..layer.n_out].copy_from_slice(&dst[..layer.n_out]);
        } else {
            tanh_in_place_body(&mut dst[..layer.n_out]);
            input_is_a = l == 0 || !input_is_a;
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn forward_avx2(net: &Packed, x: &[f32], a: &mut [f32], b: &mut [f32], out: &mut [f32]) {
    forward_body::<true>(net, x, a, b, out);
}

/// Evaluates a packed tanh MLP on one sample with the given kernel (see the module docs).
/// `scratch_a` and `scratch_b` must hold [`Packed::scratch_len`] values; `out` the network's
/// outputs. Never allocates.
pub fn forward(
    kernel: Kernel,
    net: &Packed,
    x: &[f32],
    scratch_a: &mut [f32],
    scratch_b: &mut [f32],
    out: &mut [f32],
) {
    match kernel.0 {
        Isa::Portable => forward_body::<false>(net, x, scratch_a, scratch_b, out),
        #[cfg(target_arch = "x86_64")]
        // SAFETY: a `Kernel` of `Isa::Avx2Fma` is only made by `Kernel::avx2_fma`, after it
        // found AVX2 and FMA on this CPU (the field is private to this module).
        Isa::Avx2Fma => unsafe { forward_avx2(net, x, scratch_a, scratch_b, out) },
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
            let mut kernels = vec![Kernel::portable()];
            if Kernel::detect() != Kernel::portable() {
                kernels.push(Kernel::detect());
            }
            for k in kernels {
                let packed = Packed::new(&refs);
                let (mut a, mut b) = (
                    vec![0.0; packed.scratch_len()],
                    vec![0.0; packed.scratch_len()],
                );
                let mut out = vec![0.0; n_out];
                forward(k, &packed, &x, &mut a, &mut b, &mut out);
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
