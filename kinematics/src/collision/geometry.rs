//! Exact distances between capsules, a half-space (the table) and axis-aligned boxes, with
//! the closest points: pure functions, allocation-free.
//!
//! Every result is a [`Proximity`]: the signed distance (negative when the shapes overlap),
//! the two closest points, the unit normal `n` pointing from the second shape towards the
//! first, and the gradient `g` with which the distance changes, `d_dot = g · (v_a - v_b)` when
//! the shapes move so that their closest points move at `v_a`, `v_b`. `g` is `n` except inside
//! a box, see [`segment_box`]. Capsules are a segment `a-b` swept by a sphere of `radius_m`;
//! every distance is the segments' (or segment-to-shape) exact distance less the radii.

use nalgebra::{Point3, Vector3};

/// Below this length (m) a segment is a point and two points coincide.
const TINY_M: f64 = 1e-12;

/// A capsule: the points within `radius_m` of the segment `a-b`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Capsule {
    /// One end of the segment.
    pub a: Point3<f64>,
    /// The other end.
    pub b: Point3<f64>,
    /// Radius (m), positive.
    pub radius_m: f64,
}

impl Capsule {
    /// A capsule from its segment and radius.
    pub fn new(a: Point3<f64>, b: Point3<f64>, radius_m: f64) -> Self {
        Self { a, b, radius_m }
    }

    /// The point of the segment at parameter `t` in `[0, 1]` (`a` at 0, `b` at 1).
    pub fn at(&self, t: f64) -> Point3<f64> {
        self.a + (self.b - self.a) * t
    }

    /// Distance (m) from a point to the capsule's surface; negative inside.
    pub fn point_distance(&self, p: &Point3<f64>) -> f64 {
        let t = segment_point_parameter(&self.a, &self.b, p);
        (p - self.at(t)).norm() - self.radius_m
    }
}

/// An axis-aligned box: the points with `min <= p <= max` on every axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    /// The corner with the smallest coordinates (m).
    pub min: Point3<f64>,
    /// The corner with the largest coordinates (m).
    pub max: Point3<f64>,
}

impl Aabb {
    /// A box from two opposite corners (in any order).
    pub fn from_corners(p: Point3<f64>, q: Point3<f64>) -> Self {
        Self {
            min: p.inf(&q),
            max: p.sup(&q),
        }
    }

    /// Signed distance (m) from a point to the box's surface: the Euclidean distance outside,
    /// minus the distance to the nearest face inside.
    pub fn signed_distance(&self, p: &Point3<f64>) -> f64 {
        let mut outside = 0.0;
        let mut inside = f64::NEG_INFINITY;
        for i in 0..3 {
            let below = self.min[i] - p[i];
            let above = p[i] - self.max[i];
            let d = below.max(above);
            if d > 0.0 {
                outside += d * d;
            }
            inside = inside.max(d);
        }
        if outside > 0.0 {
            outside.sqrt()
        } else {
            inside
        }
    }
}

/// How close two shapes are: see the module docs for the conventions.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Proximity {
    /// Signed distance (m): the gap between the surfaces, negative when they overlap (then
    /// minus the depth of the overlap along `normal`).
    pub distance_m: f64,
    /// The point of the first shape closest to the second: on its surface when the shapes
    /// are apart; when they overlap, its deepest point (inside it for a capsule in a box).
    pub point_a: Point3<f64>,
    /// The point of the second shape closest to the first (on its surface).
    pub point_b: Point3<f64>,
    /// Unit vector from the second shape towards the first along which the distance is
    /// measured; `None` when it is undefined (the segments of two capsules cross).
    pub normal: Option<Vector3<f64>>,
    /// The distance's gradient with respect to the motion of the closest points:
    /// `d_dot = gradient · (v_a - v_b)`. Equal to `normal`, except for a capsule whose
    /// deepest point in a box lies where two faces are equally near (see [`segment_box`]);
    /// `None` with `normal`.
    pub gradient: Option<Vector3<f64>>,
}

/// The closest points of two segments.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SegmentPair {
    /// Parameter of the closest point on the first segment (0 at its start, 1 at its end).
    pub s: f64,
    /// Parameter of the closest point on the second segment.
    pub t: f64,
    /// The closest point on the first segment.
    pub point_1: Point3<f64>,
    /// The closest point on the second segment.
    pub point_2: Point3<f64>,
    /// Their distance (m).
    pub distance_m: f64,
}

/// Parameter in `[0, 1]` of the point of segment `a-b` closest to `p`.
pub fn segment_point_parameter(a: &Point3<f64>, b: &Point3<f64>, p: &Point3<f64>) -> f64 {
    let d = b - a;
    let len2 = d.norm_squared();
    if len2 <= TINY_M * TINY_M {
        0.0
    } else {
        ((p - a).dot(&d) / len2).clamp(0.0, 1.0)
    }
}

/// Exact closest points of the segments `p1-q1` and `p2-q2` (points and parallel segments
/// included; for parallel segments one of the equally close pairs).
///
/// The minimum of the convex quadratic `|p1 + s d1 - p2 - t d2|²` over the unit square: the
/// unconstrained `s` for the infinite lines clamped to `[0, 1]`, then `t` for that `s`, and
/// `s` again for a clamped `t` (Ericson, *Real-Time Collision Detection*, 5.1.9).
pub fn segment_segment(
    p1: &Point3<f64>,
    q1: &Point3<f64>,
    p2: &Point3<f64>,
    q2: &Point3<f64>,
) -> SegmentPair {
    let d1 = q1 - p1;
    let d2 = q2 - p2;
    let r = p1 - p2;
    let a = d1.norm_squared();
    let e = d2.norm_squared();
    let f = d2.dot(&r);
    let eps = TINY_M * TINY_M;
    let (s, t) = if a <= eps && e <= eps {
        (0.0, 0.0)
    } else if a <= eps {
        (0.0, (f / e).clamp(0.0, 1.0))
    } else {
        let c = d1.dot(&r);
        if e <= eps {
            ((-c / a).clamp(0.0, 1.0), 0.0)
        } else {
            let b = d1.dot(&d2);
            let denom = a * e - b * b;
            // Parallel (or nearly): any s gives a closest pair once t is clamped; take 0.
            let mut s = if denom > 1e-12 * a * e {
                ((b * f - c * e) / denom).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let mut t = (b * s + f) / e;
            if t < 0.0 {
                t = 0.0;
                s = (-c / a).clamp(0.0, 1.0);
            } else if t > 1.0 {
                t = 1.0;
                s = ((b - c) / a).clamp(0.0, 1.0);
            }
            (s, t)
        }
    };
    let point_1 = p1 + d1 * s;
    let point_2 = p2 + d2 * t;
    SegmentPair {
        s,
        t,
        point_1,
        point_2,
        distance_m: (point_1 - point_2).norm(),
    }
}

/// Exact distance between two capsules: the segments' distance less both radii.
pub fn capsule_capsule(a: &Capsule, b: &Capsule) -> Proximity {
    let sp = segment_segment(&a.a, &a.b, &b.a, &b.b);
    let gap = sp.distance_m;
    if gap > TINY_M {
        let n = (sp.point_1 - sp.point_2) / gap;
        Proximity {
            distance_m: gap - a.radius_m - b.radius_m,
            point_a: sp.point_1 - n * a.radius_m,
            point_b: sp.point_2 + n * b.radius_m,
            normal: Some(n),
            gradient: Some(n),
        }
    } else {
        Proximity {
            distance_m: gap - a.radius_m - b.radius_m,
            point_a: sp.point_1,
            point_b: sp.point_2,
            normal: None,
            gradient: None,
        }
    }
}

/// Exact distance from a capsule to the half-space `z <= z_m` (a table top at height `z_m`,
/// infinite in x and y): the lower end's height above it less the radius. The normal is `+z`.
pub fn capsule_plane(c: &Capsule, z_m: f64) -> Proximity {
    let low = if c.b.z < c.a.z { c.b } else { c.a };
    Proximity {
        distance_m: low.z - z_m - c.radius_m,
        point_a: Point3::new(low.x, low.y, low.z - c.radius_m),
        point_b: Point3::new(low.x, low.y, z_m),
        normal: Some(Vector3::z()),
        gradient: Some(Vector3::z()),
    }
}

/// Exact distance from a capsule to an axis-aligned box: the segment's exact (signed)
/// distance to the box less the radius. See [`segment_box`].
pub fn capsule_box(c: &Capsule, b: &Aabb) -> Proximity {
    let sb = segment_box(&c.a, &c.b, b);
    Proximity {
        distance_m: sb.distance_m - c.radius_m,
        point_a: sb.point_segment - sb.normal * c.radius_m,
        point_b: sb.point_box,
        normal: Some(sb.normal),
        gradient: Some(sb.gradient),
    }
}

/// The closest points of a segment and a box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SegmentBox {
    /// Parameter of the segment's closest point (0 at its start, 1 at its end).
    pub t: f64,
    /// The segment's closest (or, inside the box, deepest) point.
    pub point_segment: Point3<f64>,
    /// The point of the box's surface closest to it.
    pub point_box: Point3<f64>,
    /// Signed distance (m): positive outside, minus the depth below the nearest face inside.
    pub distance_m: f64,
    /// Unit vector from `point_box` towards `point_segment` (the outward face normal inside).
    pub normal: Vector3<f64>,
    /// `d_dot = gradient · v` when the segment moves with its point at `t` moving at `v`:
    /// `normal`, except inside the box where the deepest point lies on the line where two
    /// faces are equally near; there the two faces' normals weighted so that the deepest
    /// point's slide along the segment cancels (halfway through a slab between two opposite
    /// faces it is zero: the depth does not change as the segment turns).
    pub gradient: Vector3<f64>,
}

/// Exact signed distance between the segment `p-q` and a box, the minimum over the segment of
/// the box's signed distance function.
///
/// Outside: the squared distance to the box is convex and piecewise quadratic in the segment
/// parameter, its pieces separated where the segment crosses one of the six face planes; the
/// exact minimum is the least of each piece's minimum. If the segment reaches the box, the
/// signed distance inside is the largest of six linear functions (`min_i - p_i`,
/// `p_i - max_i`), convex and piecewise linear, so its minimum over `[0, 1]` lies at an end or
/// where two of them meet: all those candidates are evaluated. At a minimum inside the segment
/// where a decreasing face function (slope `s1 < 0`, normal `n1`) meets an increasing one
/// (`s2 > 0`, `n2`), the depth's derivative is that of `λ1 g1 + λ2 g2` with
/// `λ1 = s2 / (s2 - s1)`, `λ2 = -s1 / (s2 - s1)` (the multipliers that keep the meeting
/// point stationary): the gradient is `λ1 n1 + λ2 n2`.
pub fn segment_box(p: &Point3<f64>, q: &Point3<f64>, b: &Aabb) -> SegmentBox {
    let d = q - p;
    let (cuts, n) = face_plane_cuts(p, &d, b);
    let best_t = nearest_parameter_outside(p, &d, b, &cuts[..n]);
    let c = p + d * best_t;
    let clamped = c.sup(&b.min).inf(&b.max);
    let gap = (c - clamped).norm();
    if gap > TINY_M {
        let normal = (c - clamped) / gap;
        return SegmentBox {
            t: best_t,
            point_segment: c,
            point_box: clamped,
            distance_m: gap,
            normal,
            gradient: normal,
        };
    }
    deepest_inside(p, &d, b)
}

/// The pieces of the segment `p + t d` (`t` in `[0, 1]`): 0, the parameters where it crosses
/// a face plane of `b`, and 1, sorted; with how many there are.
fn face_plane_cuts(p: &Point3<f64>, d: &Vector3<f64>, b: &Aabb) -> ([f64; 8], usize) {
    let mut cuts = [0.0f64; 8];
    let mut n = 1;
    for i in 0..3 {
        if d[i].abs() > TINY_M {
            for bound in [b.min[i], b.max[i]] {
                let t = (bound - p[i]) / d[i];
                if t > 0.0 && t < 1.0 {
                    cuts[n] = t;
                    n += 1;
                }
            }
        }
    }
    cuts[n] = 1.0;
    n += 1;
    // Insertion sort of at most 8 values.
    for i in 1..n {
        let mut j = i;
        while j > 0 && cuts[j - 1] > cuts[j] {
            cuts.swap(j - 1, j);
            j -= 1;
        }
    }
    (cuts, n)
}

/// The parameter of the segment's point nearest to the box: the least of each piece's
/// minimum of the squared distance (a quadratic on each piece between two `cuts`).
fn nearest_parameter_outside(p: &Point3<f64>, d: &Vector3<f64>, b: &Aabb, cuts: &[f64]) -> f64 {
    let mut best_t = 0.0;
    let mut best_f = f64::INFINITY;
    for w in cuts.windows(2) {
        let (t0, t1) = (w[0], w[1]);
        let tm = 0.5 * (t0 + t1);
        // On this piece each axis is below, inside or above the box throughout.
        let (mut qa, mut qb, mut qc) = (0.0, 0.0, 0.0);
        for i in 0..3 {
            let x = p[i] + d[i] * tm;
            let bound = if x < b.min[i] {
                b.min[i]
            } else if x > b.max[i] {
                b.max[i]
            } else {
                continue;
            };
            let e = p[i] - bound;
            qa += d[i] * d[i];
            qb += 2.0 * d[i] * e;
            qc += e * e;
        }
        let t = if qa > 0.0 {
            (-qb / (2.0 * qa)).clamp(t0, t1)
        } else {
            t0
        };
        let f = (qa * t + qb) * t + qc;
        if f < best_f {
            best_f = f;
            best_t = t;
        }
    }
    best_t
}

/// The outward normal of face `k` of a box (`2 i`: the low face of axis `i`, `2 i + 1` the
/// high one).
fn face_normal(k: usize) -> Vector3<f64> {
    let mut n = Vector3::zeros();
    n[k / 2] = if k.is_multiple_of(2) { -1.0 } else { 1.0 };
    n
}

/// The segment reaches the box: the deepest point, minimising the largest of the six face
/// functions `g_k(t) = slope_k t + value_k` over the ends and where two of them meet.
fn deepest_inside(p: &Point3<f64>, d: &Vector3<f64>, b: &Aabb) -> SegmentBox {
    let mut slope = [0.0f64; 6];
    let mut value = [0.0f64; 6];
    for i in 0..3 {
        slope[2 * i] = -d[i];
        value[2 * i] = b.min[i] - p[i];
        slope[2 * i + 1] = d[i];
        value[2 * i + 1] = p[i] - b.max[i];
    }
    let g = |t: f64| -> (f64, usize) {
        let mut best = (f64::NEG_INFINITY, 0);
        for k in 0..6 {
            let v = slope[k] * t + value[k];
            if v > best.0 {
                best = (v, k);
            }
        }
        best
    };
    let mut best = (g(0.0), 0.0);
    let mut consider = |t: f64| {
        let v = g(t);
        if v.0 < best.0.0 {
            best = (v, t);
        }
    };
    consider(1.0);
    for j in 0..6 {
        for k in (j + 1)..6 {
            let ds = slope[j] - slope[k];
            if ds.abs() > TINY_M {
                let t = (value[k] - value[j]) / ds;
                if (0.0..=1.0).contains(&t) {
                    consider(t);
                }
            }
        }
    }
    let ((depth, face), t) = best;
    let c = p + d * t;
    let axis = face / 2;
    let mut point_box = c;
    point_box[axis] = if face.is_multiple_of(2) {
        b.min[axis]
    } else {
        b.max[axis]
    };
    let normal = face_normal(face);
    let gradient = if t > 0.0 && t < 1.0 {
        meeting_faces_gradient(&slope, &value, t, depth).unwrap_or(normal)
    } else {
        normal
    };
    SegmentBox {
        t,
        point_segment: c,
        point_box,
        distance_m: depth,
        normal,
        gradient,
    }
}

/// At a minimum inside the segment: the faces as near as the chosen one (at `depth`), the
/// most decreasing and most increasing of them, and their normals weighted by the
/// multipliers that keep the meeting point stationary; `None` without such a pair.
fn meeting_faces_gradient(
    slope: &[f64; 6],
    value: &[f64; 6],
    t: f64,
    depth: f64,
) -> Option<Vector3<f64>> {
    let (mut down, mut up) = (None::<usize>, None::<usize>);
    for k in 0..6 {
        if (slope[k] * t + value[k] - depth).abs() <= 1e-12 {
            if slope[k] < 0.0 && down.is_none_or(|j| slope[k] < slope[j]) {
                down = Some(k);
            }
            if slope[k] > 0.0 && up.is_none_or(|j| slope[k] > slope[j]) {
                up = Some(k);
            }
        }
    }
    let (k1, k2) = (down?, up?);
    let (s1, s2) = (slope[k1], slope[k2]);
    Some(face_normal(k1) * (s2 / (s2 - s1)) - face_normal(k2) * (s1 / (s2 - s1)))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(x: f64, y: f64, z: f64) -> Point3<f64> {
        Point3::new(x, y, z)
    }

    #[test]
    fn segments_in_the_usual_cases() {
        // Crossing at right angles, 1 apart in z.
        let r = segment_segment(
            &p(-1., 0., 0.),
            &p(1., 0., 0.),
            &p(0., -1., 1.),
            &p(0., 1., 1.),
        );
        assert!((r.distance_m - 1.0).abs() < 1e-15);
        assert!((r.s - 0.5).abs() < 1e-15 && (r.t - 0.5).abs() < 1e-15);
        // Parallel, overlapping: distance between the lines.
        let r = segment_segment(
            &p(0., 0., 0.),
            &p(2., 0., 0.),
            &p(1., 0.5, 0.),
            &p(3., 0.5, 0.),
        );
        assert!((r.distance_m - 0.5).abs() < 1e-15);
        // Parallel, apart along their line: end to end.
        let r = segment_segment(
            &p(0., 0., 0.),
            &p(1., 0., 0.),
            &p(2., 0., 0.),
            &p(3., 0., 0.),
        );
        assert!((r.distance_m - 1.0).abs() < 1e-15);
        // Degenerate: two points, a point and a segment.
        let r = segment_segment(
            &p(0., 0., 0.),
            &p(0., 0., 0.),
            &p(0., 3., 4.),
            &p(0., 3., 4.),
        );
        assert!((r.distance_m - 5.0).abs() < 1e-15);
        let r = segment_segment(
            &p(0., 1., 0.),
            &p(0., 1., 0.),
            &p(-1., 0., 0.),
            &p(1., 0., 0.),
        );
        assert!((r.distance_m - 1.0).abs() < 1e-15 && (r.t - 0.5).abs() < 1e-15);
    }

    #[test]
    fn capsules_plane_and_box() {
        let c = Capsule::new(p(0., 0., 0.5), p(1., 0., 0.2), 0.1);
        let pl = capsule_plane(&c, 0.0);
        assert!((pl.distance_m - 0.1).abs() < 1e-15);
        assert_eq!(pl.point_b, p(1., 0., 0.));
        let d = Capsule::new(p(0., 0., 0.), p(0., 0., 0.), 0.2);
        let e = Capsule::new(p(0., 1., 0.), p(0., 1., 0.), 0.3);
        let cc = capsule_capsule(&d, &e);
        assert!((cc.distance_m - 0.5).abs() < 1e-15);
        assert_eq!(cc.normal, Some(-Vector3::y()));
        assert!((cc.point_a - p(0., 0.2, 0.)).norm() < 1e-15);
        assert!((cc.point_b - p(0., 0.7, 0.)).norm() < 1e-15);
        let b = Aabb::from_corners(p(1., 1., 1.), p(-1., -1., -1.));
        assert_eq!(b.min, p(-1., -1., -1.));
        // A segment passing over an edge of the box.
        let s = Capsule::new(p(2., -1., 2.), p(0., 1., 2.), 0.25);
        let r = capsule_box(&s, &b);
        assert!((r.distance_m - 0.75).abs() < 1e-12, "{r:?}");
        // A segment through the box: the depth at its deepest point.
        let s = Capsule::new(p(-2., 0.2, 0.), p(2., 0.2, 0.), 0.1);
        let r = capsule_box(&s, &b);
        assert!((r.distance_m - (-0.8 - 0.1)).abs() < 1e-12, "{r:?}");
        assert_eq!(r.normal, Some(Vector3::y()));
        assert_eq!(r.gradient, r.normal);
        // Through a slab between two opposite faces: the depth is the half-width whatever
        // the tilt, so the gradient is zero.
        let slab = Aabb::from_corners(p(-0.01, -1., -1.), p(0.01, 1., 1.));
        let s = Capsule::new(p(-1., 0., -0.5), p(1., 0., 0.5), 0.1);
        let r = capsule_box(&s, &slab);
        assert!((r.distance_m - (-0.01 - 0.1)).abs() < 1e-12, "{r:?}");
        assert!(r.gradient.unwrap().norm() < 1e-12, "{r:?}");
        assert!((b.signed_distance(&p(0., 0.2, 0.)) + 0.8).abs() < 1e-15);
        assert!((b.signed_distance(&p(2., 0., 3.)) - 5f64.sqrt()).abs() < 1e-15);
    }
}
