//! Property tests of the collision geometry: the exact distances against brute-force sampled
//! ones (capsule-capsule, capsule-table, capsule-box), and the distance's rate of change
//! against finite differences along random joint velocities.
#![allow(clippy::unwrap_used, clippy::needless_range_loop)]

use kinematics::Gen3Lite;
use kinematics::collision::geometry::{
    Aabb, Capsule, capsule_box, capsule_capsule, capsule_plane, segment_segment,
};
use kinematics::collision::{Clearance, CollisionModel, Scene};
use nalgebra::Point3;
use proptest::prelude::*;

/// Samples per segment: 1000 over at most 0.7 m, so a sampled distance is at most 0.7 mm
/// above the exact one.
const SAMPLES: usize = 1000;

fn point() -> impl Strategy<Value = Point3<f64>> {
    prop::array::uniform3(-0.2..0.2f64).prop_map(Point3::from)
}

/// Segments of every kind: general, one end on the other (a point), axis-parallel.
fn segment() -> impl Strategy<Value = (Point3<f64>, Point3<f64>)> {
    prop_oneof![
        6 => (point(), point()),
        1 => point().prop_map(|p| (p, p)),
        1 => (point(), 0usize..3, -0.2..0.2f64).prop_map(|(p, axis, l)| {
            let mut q = p;
            q[axis] += l;
            (p, q)
        }),
    ]
}

fn capsule() -> impl Strategy<Value = Capsule> {
    (segment(), 0.001..0.06f64).prop_map(|((a, b), r)| Capsule::new(a, b, r))
}

/// The box's signed distance at a point, written out again for the test.
fn box_sdf(b: &Aabb, p: &Point3<f64>) -> f64 {
    let d = [0, 1, 2].map(|i| (b.min[i] - p[i]).max(p[i] - b.max[i]));
    let outside: f64 = d.iter().map(|v| v.max(0.0).powi(2)).sum::<f64>().sqrt();
    let inside = d[0].max(d[1]).max(d[2]).min(0.0);
    outside + inside
}

fn samples(c: &Capsule) -> impl Iterator<Item = Point3<f64>> + '_ {
    (0..SAMPLES).map(move |i| c.at(i as f64 / (SAMPLES - 1) as f64))
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]

    #[test]
    fn capsule_capsule_matches_sampling(a in capsule(), b in capsule()) {
        let exact = capsule_capsule(&a, &b);
        let mut sampled = f64::INFINITY;
        let pb: Vec<Point3<f64>> = samples(&b).collect();
        for p in samples(&a) {
            for q in &pb {
                sampled = sampled.min((p - q).norm_squared());
            }
        }
        let sampled = sampled.sqrt() - a.radius_m - b.radius_m;
        // Never above the truth, and within 1 mm of the sampled distance.
        prop_assert!(exact.distance_m <= sampled + 1e-12, "{exact:?} vs {sampled}");
        prop_assert!(sampled - exact.distance_m < 1e-3, "{exact:?} vs {sampled}");
        // The closest points are on the surfaces, the normal between them.
        prop_assert!(a.point_distance(&exact.point_a).abs() < 1e-9);
        prop_assert!(b.point_distance(&exact.point_b).abs() < 1e-9);
        if let Some(n) = exact.normal {
            let gap = exact.point_a - exact.point_b;
            prop_assert!((gap.dot(&n) - exact.distance_m).abs() < 1e-9);
            prop_assert!((n.norm() - 1.0).abs() < 1e-12);
        }
        // Symmetric.
        let back = segment_segment(&b.a, &b.b, &a.a, &a.b);
        prop_assert!((back.distance_m - (exact.distance_m + a.radius_m + b.radius_m)).abs() < 1e-9);
    }

    #[test]
    fn capsule_table_matches_sampling(c in capsule(), z in -0.2..0.2f64) {
        let exact = capsule_plane(&c, z);
        let sampled = samples(&c).map(|p| p.z).fold(f64::INFINITY, f64::min) - z - c.radius_m;
        prop_assert!(exact.distance_m <= sampled + 1e-12);
        prop_assert!(sampled - exact.distance_m < 1e-3);
        prop_assert!((exact.point_b.z - z).abs() < 1e-15);
        prop_assert!((exact.point_a.z - exact.point_b.z - exact.distance_m).abs() < 1e-12);
    }

    #[test]
    fn capsule_box_matches_sampling(c in capsule(), p in point(), q in point()) {
        let b = Aabb::from_corners(p, q);
        let exact = capsule_box(&c, &b);
        let sampled = samples(&c).map(|x| box_sdf(&b, &x)).fold(f64::INFINITY, f64::min)
            - c.radius_m;
        // Exact, so never above the sampled distance (the conservative side), and within 1 mm.
        prop_assert!(exact.distance_m <= sampled + 1e-12, "{exact:?} vs {sampled}");
        prop_assert!(sampled - exact.distance_m < 1e-3, "{exact:?} vs {sampled}");
        // The box point is on the box's surface; the capsule point on the capsule's when
        // apart, in the capsule when not.
        prop_assert!(box_sdf(&b, &exact.point_b).abs() < 1e-9);
        if exact.distance_m > 0.0 {
            prop_assert!(c.point_distance(&exact.point_a).abs() < 1e-9);
        } else {
            prop_assert!(c.point_distance(&exact.point_a) < 1e-9);
        }
        let n = exact.normal.unwrap();
        prop_assert!(((exact.point_a - exact.point_b).dot(&n) - exact.distance_m).abs() < 1e-9);
    }
}

/// Joint angles inside the limits, and the gripper inside its range.
fn gen3_q() -> impl Strategy<Value = Vec<f64>> {
    let g = Gen3Lite::get();
    let mut ranges: Vec<_> = g
        .arm()
        .lower()
        .iter()
        .zip(g.arm().upper())
        .map(|(lo, hi)| *lo..*hi)
        .collect();
    let (closed, open) = g.gripper_range();
    ranges.push(closed..open);
    ranges
}

fn distances(q: &[f64], scene: &Scene, out: &mut Clearance) -> Vec<f64> {
    CollisionModel::get().clearance(q, scene, out).unwrap();
    out.distances_m().to_vec()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]

    /// d_dot = g · qdot against central differences of the same pair's distance along qdot,
    /// for every pair with a normal, where the distance is smooth: the differences over h
    /// and 2h agree (they do not where the closest features switch, e.g. a capsule's axis
    /// turning level with the table).
    #[test]
    fn the_rate_row_is_the_derivative(
        q in gen3_q(),
        qdot in prop::array::uniform6(-1.0..1.0f64),
        corner in prop::array::uniform3(-0.6..0.6f64),
        size in prop::array::uniform3(0.02..0.3f64),
    ) {
        let mut scene = Scene::with_table(-0.02).unwrap();
        let c = Point3::from(corner);
        scene.add_box(c, c + nalgebra::Vector3::from(size)).unwrap();
        let mut out = Clearance::default();
        let d0 = distances(&q, &scene, &mut out);
        let step = |h: f64| -> Vec<f64> {
            let mut qq = q.clone();
            for i in 0..6 {
                qq[i] += h * qdot[i];
            }
            distances(&qq, &scene, &mut Clearance::default())
        };
        let h = 1e-5;
        let (p1, m1, p2, m2) = (step(h), step(-h), step(2.0 * h), step(-2.0 * h));
        CollisionModel::get().clearance(&q, &scene, &mut out).unwrap();
        let mut checked = 0;
        for i in 0..d0.len() {
            let Some(contact) = out.contact(i) else { continue };
            prop_assert!((contact.distance_m - d0[i]).abs() < 1e-12);
            let Some(g) = out.rate_row(&contact) else { continue };
            let fd1 = (p1[i] - m1[i]) / (2.0 * h);
            let fd2 = (p2[i] - m2[i]) / (4.0 * h);
            if (fd1 - fd2).abs() > 1e-6 {
                continue;
            }
            let analytic: f64 = g.iter().zip(qdot).map(|(g, v)| g * v).sum();
            prop_assert!(
                (analytic - fd1).abs() < 1e-5,
                "pair {} at {q:?}: d_dot {analytic} vs finite differences {fd1}",
                contact.pair
            );
            checked += 1;
        }
        prop_assert!(checked > 0);
        // The closest pair's row is the same thing.
        let closest = out.closest().unwrap();
        prop_assert_eq!(out.closest_rate_row(), out.rate_row(closest));
    }
}
