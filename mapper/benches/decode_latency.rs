//! Per-call latency of one SCL decode (m = 6, d = 2, 2 x 256 tanh, Gram-Schmidt): times
//! 200 000 single calls one by one (after 20 000 warm-up calls) and prints percentiles as
//! JSON. The clock read adds a few tens of ns to every sample (printed as `clock_ns`).
//! Run: `cargo bench -p mapper --bench decode_latency`.
#![allow(missing_docs, clippy::unwrap_used)]

mod common;

use std::hint::black_box;
use std::time::Instant;

use ipc_types::stats::quantile as percentile;
use mapper::ActionMap;
use mapper::nn::Kernel;

fn main() {
    // `cargo bench` passes --bench; nothing else is expected.
    let n = 200_000;
    let mut out = [0.0f64; common::M];
    let mut clock = Vec::with_capacity(n);
    for _ in 0..n {
        let t0 = Instant::now();
        clock.push(t0.elapsed().as_nanos() as f64);
    }
    clock.sort_by(f64::total_cmp);
    let clock_ns = percentile(&clock, 0.5);
    for (name, gs, kernel) in [
        ("scl_decode_m6_d2", true, Kernel::detect()),
        ("scl_decode_m6_d2_portable_kernel", true, Kernel::portable()),
    ] {
        let mut map = common::scl_model(gs).scl_map().unwrap();
        map.set_kernel(kernel);
        for i in 0..20_000 {
            let (q, c, a) = common::inputs(i);
            map.eval(&q, c, &a, &mut out);
        }
        let mut us = Vec::with_capacity(n);
        for i in 0..n {
            let (q, c, a) = common::inputs(i);
            let t0 = Instant::now();
            map.eval(black_box(&q), black_box(c), black_box(&a), &mut out);
            black_box(&out);
            us.push(t0.elapsed().as_nanos() as f64 / 1000.0);
        }
        us.sort_by(f64::total_cmp);
        println!(
            "{{\"bench\": \"{name}\", \"kernel\": \"{kernel:?}\", \"calls\": {n}, \"p50_us\": {:.3}, \"p90_us\": {:.3}, \"p99_us\": {:.3}, \"p999_us\": {:.3}, \"max_us\": {:.3}, \"clock_ns\": {clock_ns:.0}}}",
            percentile(&us, 0.5),
            percentile(&us, 0.9),
            percentile(&us, 0.99),
            percentile(&us, 0.999),
            us[n - 1],
        );
    }
}
