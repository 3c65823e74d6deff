//! One SCL decode as the mapper runs it every tick: normalise `(q, c)`, `h` (7 -> 256 -> 256
//! -> 12, tanh), Gram-Schmidt on the 6 x 2 `H`, `H a`. Run: `cargo bench -p mapper --bench
//! decode`. Per-call percentiles: `--bench decode_latency`.
#![allow(missing_docs, clippy::unwrap_used)]

mod common;

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use mapper::ActionMap;
use mapper::nn::Kernel;

fn decode(c: &mut Criterion) {
    let mut out = [0.0f64; common::M];
    // Inputs computed beforehand, so the timed loop holds the decode alone.
    let inputs: Vec<_> = (0..1024).map(common::inputs).collect();
    for (name, gs, kernel) in [
        ("scl_decode_m6_d2", true, Kernel::detect()),
        ("scl_decode_m6_d2_no_gram_schmidt", false, Kernel::detect()),
        ("scl_decode_m6_d2_portable_kernel", true, Kernel::portable()),
    ] {
        let mut map = common::scl_model(gs).scl_map().unwrap();
        map.set_kernel(kernel);
        let mut i = 0usize;
        c.bench_function(name, |b| {
            b.iter(|| {
                i = (i + 1) % inputs.len();
                let (q, gripper, a) = &inputs[i];
                map.eval(black_box(q), black_box(*gripper), black_box(a), &mut out);
                black_box(&out);
            })
        });
    }
}

criterion_group!(benches, decode);
criterion_main!(benches);
