//! Forward kinematics and the geometric Jacobian of the Gen3 lite's arm chain
//! (`base_link -> tool_frame`), as the safety filter's workspace rule and mode switching call
//! them once per tick.
//!
//! Run: `cargo bench -p kinematics --bench fk`.
#![allow(missing_docs, clippy::unwrap_used)]

use criterion::{Criterion, criterion_group, criterion_main};
use kinematics::{Gen3Lite, Jacobian, gen3_lite};
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let arm = Gen3Lite::get().arm();
    let q = gen3_lite::HOME;
    let mut jac = Jacobian::zeros(arm.n_joints());
    c.bench_function("gen3 lite: FK of the TCP", |b| {
        b.iter(|| black_box(arm.fk(black_box(&q)).unwrap()))
    });
    c.bench_function("gen3 lite: FK + geometric Jacobian", |b| {
        b.iter(|| black_box(arm.fk_jacobian(black_box(&q), &mut jac).unwrap()))
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
