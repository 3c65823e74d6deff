//! A branch-free f32 `tanh` that compilers vectorise.
//!
//! `std`'s `f32::tanh` calls libm one element at a time; the networks here spend a large share
//! of their time in activations, so both training and serving use [`tanh`] instead (the same
//! function, so a served model computes what it was trained to compute).
//!
//! Method: `tanh(x) = (e - 1) / (e + 1)` with `e = exp(2x)`. The exponential is evaluated as
//! `2^n · exp(r)` with `n = round(2x·log2 e)` and `|r| <= ln 2 / 2`; `exp(r)` is its Taylor
//! polynomial of degree 7 (truncation error below 6e-9 relative) and `2^n` is built from its
//! exponent bits. Inputs are clamped to `±9`, where `tanh` is 1 to f32 precision. The absolute
//! error against `f64::tanh` is below 2e-7 everywhere (see the tests); NaN propagates.

/// Inputs beyond this magnitude give `±1`.
const CLAMP: f32 = 9.0;
/// `1.5 · 2^23`: adding it rounds an f32 of magnitude below 2^22 to an integer, whose value
/// is then in the low mantissa bits.
const ROUND_MAGIC: f32 = 12_582_912.0;
/// Bits of [`ROUND_MAGIC`], minus the f32 exponent bias 127.
const MAGIC_BITS_MINUS_BIAS: u32 = 0x4B40_0000 - 127;

/// Fast `tanh` (absolute error < 2e-7; see the module docs).
#[inline(always)]
pub fn tanh(x: f32) -> f32 {
    // `clamp` (unlike `min` / `max`) lets NaN pass through.
    let x = x.clamp(-CLAMP, CLAMP);
    let t = x * (2.0 * std::f32::consts::LOG2_E);
    let shifted = t + ROUND_MAGIC;
    let n = shifted - ROUND_MAGIC;
    let r = (t - n) * std::f32::consts::LN_2;
    // exp(r), Horner form of 1 + r + r²/2! + ... + r⁷/7!.
    let mut p = 1.0 / 5040.0;
    p = p * r + 1.0 / 720.0;
    p = p * r + 1.0 / 120.0;
    p = p * r + 1.0 / 24.0;
    p = p * r + 1.0 / 6.0;
    p = p * r + 0.5;
    p = p * r + 1.0;
    p = p * r + 1.0;
    // 2^n from the integer held in the low bits of `shifted` (|n| <= 26).
    let two_n = f32::from_bits(shifted.to_bits().wrapping_sub(MAGIC_BITS_MINUS_BIAS) << 23);
    let e = p * two_n;
    (e - 1.0) / (e + 1.0)
}

/// Applies [`tanh`] to every element, using AVX2 when the CPU has it.
pub fn tanh_in_place(xs: &mut [f32]) {
    #[cfg(target_arch = "x86_64")]
    if crate::nn::kernel::Kernel::avx2_fma().is_some() {
        // SAFETY: `avx2_fma` found AVX2 and FMA on this CPU.
        unsafe { tanh_in_place_avx2(xs) };
        return;
    }
    tanh_in_place_body(xs);
}

#[inline(always)]
pub(crate) fn tanh_in_place_body(xs: &mut [f32]) {
    for x in xs {
        *x = tanh(*x);
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn tanh_in_place_avx2(xs: &mut [f32]) {
    tanh_in_place_body(xs);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn close_to_libm_everywhere() {
        let mut worst = 0.0f64;
        let mut x = -12.0f32;
        while x <= 12.0 {
            let e = (f64::from(tanh(x)) - f64::from(x).tanh()).abs();
            worst = worst.max(e);
            x += 1.0e-3;
        }
        assert!(worst < 2e-7, "worst abs error {worst:e}");
        // Tiny inputs: relative accuracy is not promised, absolute is.
        for x in [0.0f32, 1e-30, -1e-8, 1e-4] {
            assert!((f64::from(tanh(x)) - f64::from(x).tanh()).abs() < 2e-7);
        }
    }

    #[test]
    fn odd_bounded_and_saturating() {
        for x in [
            0.1f32,
            0.5,
            1.0,
            3.0,
            8.9,
            9.5,
            100.0,
            f32::MAX,
            f32::INFINITY,
        ] {
            assert!((tanh(x) + tanh(-x)).abs() < 1e-7, "{x}");
            assert!(tanh(x).abs() <= 1.0);
        }
        assert_eq!(tanh(f32::INFINITY), 1.0);
        assert_eq!(tanh(f32::NEG_INFINITY), -1.0);
        assert!(tanh(f32::NAN).is_nan());
    }

    #[test]
    fn slice_version_matches_scalar() {
        let mut xs: Vec<f32> = (0..1000).map(|i| (i as f32 - 500.0) * 0.013).collect();
        let expect: Vec<f32> = xs.iter().map(|x| tanh(*x)).collect();
        tanh_in_place(&mut xs);
        for (a, b) in xs.iter().zip(&expect) {
            assert!((a - b).abs() <= 1e-7);
        }
    }
}
