//! The Gen3 lite's collision model at one joint state, as the safety filter will call it once
//! per tick: forward kinematics of every link, the 42 self pairs, the 12 link capsules against
//! the table (and, in the second case, all 15 capsules against each of two boxes), the closest
//! pair with its points, then the closest pair's rate row.
//!
//! Run: `cargo bench -p kinematics --bench collision`.
#![allow(missing_docs, clippy::unwrap_used)]

use criterion::{Criterion, criterion_group, criterion_main};
use kinematics::collision::{Clearance, CollisionModel, Scene};
use kinematics::gen3_lite;
use nalgebra::Point3;
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let model = CollisionModel::get();
    let q = gen3_lite::HOME;
    let table = Scene::default();
    let mut boxes = Scene::default();
    boxes
        .add_box(Point3::new(0.3, -0.3, 0.0), Point3::new(0.5, -0.1, 0.2))
        .unwrap();
    boxes
        .add_box(Point3::new(-0.4, 0.2, 0.0), Point3::new(-0.2, 0.5, 0.6))
        .unwrap();
    let mut out = Box::new(Clearance::default());
    c.bench_function("gen3 lite collision: clearance, table", |b| {
        b.iter(|| {
            model
                .clearance(black_box(&q), black_box(&table), &mut out)
                .unwrap();
            black_box(out.min_distance_m())
        })
    });
    c.bench_function("gen3 lite collision: clearance, table + 2 boxes", |b| {
        b.iter(|| {
            model
                .clearance(black_box(&q), black_box(&boxes), &mut out)
                .unwrap();
            black_box(out.min_distance_m())
        })
    });
    model.clearance(&q, &table, &mut out).unwrap();
    c.bench_function("gen3 lite collision: closest pair's rate row", |b| {
        b.iter(|| black_box(black_box(&out).closest_rate_row()))
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
