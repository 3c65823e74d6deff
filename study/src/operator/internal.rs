//! The practiced operator's internal model of a map: what a person learns in practice about
//! how the stick moves the tool, from what they saw (the stick they pushed, the tool's
//! resulting motion, at the states they visited), never from the map's internals.
//!
//! It is a locally linear model, one per mode: at a tool state `x` (the tool's position, its
//! orientation, the gripper) the tool's twist is `G(x) a` for stick input `a` (6 x 2: linear
//! velocity in m/s, angular velocity in rad/s, both in the base frame). The visited states
//! are gathered into centres (a new one where an observation is more than one kernel width
//! from every centre); each centre keeps the least-squares statistics of its observations
//! (`sum a a^T`, `sum v a^T`) and so its own `G`. A prediction blends the centres' `G` by a
//! Gaussian kernel of the distance to them; far from everything it has seen, the nearest
//! centre's `G` is all it has. Every SCL, PCA, CAE and mode-switching map is linear in the
//! stick at a fixed state, so this is the shape of what there is to learn; what it can get
//! wrong is how `G` changes from state to state.
//!
//! Where the arm stops (the table, a joint limit), it learns that the stick does nothing
//! there, as a person does.

use nalgebra::{Isometry3, Matrix2, SMatrix, UnitQuaternion, Vector3, Vector6};

/// Observations a centre needs before its `G` counts.
const MIN_OBSERVATIONS: u32 = 4;

/// Ridge regularisation of a centre's least squares, per observation (a stick seen only
/// along one axis learns nothing about the other).
const RIDGE: f64 = 0.02;

/// A stick input smaller than this teaches nothing (noise at rest).
const MIN_STICK: f64 = 0.05;

/// A centre forgets: each observation there weighs the older ones down by this factor, so
/// the last 64 or so count (1.6 s of pushing at 40 Hz): where the arm stops moving, it soon
/// expects nothing, as a person does.
const FORGET: f64 = 1.0 - 1.0 / 64.0;

/// At most this many centres per mode (the oldest are kept).
const MAX_CENTRES: usize = 4000;

/// The kernel's widths: how far apart two states are, for the model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Widths {
    /// Position (m).
    pub position_m: f64,
    /// Orientation (rad).
    pub angle_rad: f64,
    /// Gripper (0 open to 1 closed).
    pub gripper: f64,
}

impl Widths {
    /// The practiced operator's kernel widths (`[simulation.practiced]`; the gripper's 0.5).
    pub fn of(p: &crate::setup::PracticedParams) -> Self {
        Self {
            position_m: p.position_width_m,
            angle_rad: p.angle_width_rad,
            gripper: 0.5,
        }
    }
}

/// A tool state as the model knows it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ToolState {
    /// The tool's position (m).
    pub p: Vector3<f64>,
    /// Its orientation.
    pub r: UnitQuaternion<f64>,
    /// The gripper (0 open, 1 closed).
    pub c: f64,
}

impl ToolState {
    /// The state of `tool` with the gripper at `c`.
    pub fn of(tool: &Isometry3<f64>, c: f64) -> Self {
        Self {
            p: tool.translation.vector,
            r: tool.rotation,
            c,
        }
    }

    /// The squared kernel distance to `o`.
    fn d2(&self, o: &Self, w: &Widths) -> f64 {
        let dp = (self.p - o.p).norm_squared() / (w.position_m * w.position_m);
        let dot = self.r.coords.dot(&o.r.coords).abs().min(1.0);
        let angle = 2.0 * dot.acos();
        let dr = angle * angle / (w.angle_rad * w.angle_rad);
        let dc = (self.c - o.c) * (self.c - o.c) / (w.gripper * w.gripper);
        dp + dr + dc
    }
}

/// One centre of visited states and its observations' statistics.
#[derive(Debug, Clone)]
struct Centre {
    at: ToolState,
    aa: Matrix2<f64>,
    va: SMatrix<f64, 6, 2>,
    n: u32,
    /// The observations' weight after forgetting.
    w: f64,
    /// `G` from the statistics.
    g: SMatrix<f64, 6, 2>,
}

impl Centre {
    fn empty(at: ToolState) -> Self {
        Self {
            at,
            aa: Matrix2::zeros(),
            va: SMatrix::zeros(),
            n: 0,
            w: 0.0,
            g: SMatrix::zeros(),
        }
    }

    /// Adds an observation, the older ones weighed down by `forget`.
    fn add(&mut self, a: &nalgebra::Vector2<f64>, v: &Vector6<f64>, forget: f64) {
        self.aa = self.aa * forget + a * a.transpose();
        self.va = self.va * forget + v * a.transpose();
        self.w = self.w * forget + 1.0;
        self.n = self.n.saturating_add(1);
    }

    fn refit(&mut self) {
        let reg = self.aa + Matrix2::identity() * (RIDGE * self.w).max(1e-6);
        if let Some(inv) = reg.try_inverse() {
            self.g = self.va * inv;
        }
    }
}

/// The weight of what the stick does in general (all of a mode's observations) against the
/// centres' kernel weights (each at most 1): where it has seen a state within about 2.5
/// kernel widths, what it saw there counts more; farther away, what it does in general.
const GENERAL_WEIGHT: f64 = 0.05;

/// The model of one mode.
#[derive(Debug, Clone)]
struct ModeModel {
    centres: Vec<Centre>,
    /// Every observation of the mode: what the stick does in general.
    all: Centre,
}

impl Default for ModeModel {
    fn default() -> Self {
        Self {
            centres: Vec::new(),
            all: Centre::empty(ToolState {
                p: Vector3::zeros(),
                r: UnitQuaternion::identity(),
                c: 0.0,
            }),
        }
    }
}

/// What the practiced operator has learned of a map.
#[derive(Debug, Clone)]
pub struct InternalModel {
    widths: Widths,
    modes: Vec<ModeModel>,
    observations: u64,
}

impl InternalModel {
    /// An empty model (nothing learned) with kernel widths `widths`.
    pub fn new(widths: Widths) -> Self {
        Self {
            widths,
            modes: Vec::new(),
            observations: 0,
        }
    }

    /// Observations taken so far.
    pub fn observations(&self) -> u64 {
        self.observations
    }

    /// The modes it has seen the stick used in.
    pub fn modes(&self) -> usize {
        self.modes.len().max(1)
    }

    /// Centres in mode `m`.
    pub fn centres(&self, m: usize) -> usize {
        self.modes.get(m).map_or(0, |x| x.centres.len())
    }

    /// What the stick does in general in mode `m`: the least-squares `G` of all its
    /// observations there (6 x 2, row-major: linear then angular velocity per stick axis).
    pub fn general(&self, m: usize) -> Option<[[f64; 2]; 6]> {
        let g = self.modes.get(m)?.all.g;
        Some(std::array::from_fn(|r| [g[(r, 0)], g[(r, 1)]]))
    }

    /// Learns that stick input `a` in mode `m` at state `x` moved the tool at `twist`.
    pub fn observe(&mut self, m: usize, x: &ToolState, a: [f64; 2], twist: &Vector6<f64>) {
        if a[0].hypot(a[1]) < MIN_STICK || !twist.iter().all(|v| v.is_finite()) {
            return;
        }
        if self.modes.len() <= m {
            self.modes.resize_with(m + 1, ModeModel::default);
        }
        let Some(mode) = self.modes.get_mut(m) else {
            return;
        };
        let w = self.widths;
        let nearest = mode
            .centres
            .iter()
            .enumerate()
            .map(|(i, c)| (i, x.d2(&c.at, &w)))
            .min_by(|a, b| a.1.total_cmp(&b.1));
        let i = match nearest {
            Some((i, d2)) if d2 <= 1.0 || mode.centres.len() >= MAX_CENTRES => i,
            _ => {
                mode.centres.push(Centre::empty(*x));
                mode.centres.len() - 1
            }
        };
        let Some(c) = mode.centres.get_mut(i) else {
            return;
        };
        let av = nalgebra::Vector2::new(a[0], a[1]);
        c.add(&av, twist, FORGET);
        c.refit();
        let all = &mut mode.all;
        all.add(&av, twist, 1.0);
        all.refit();
        self.observations += 1;
    }

    /// The twist it expects from stick input `a` in mode `m` at state `x` (zero where it has
    /// learned nothing in that mode).
    pub fn twist(&self, m: usize, x: &ToolState, a: [f64; 2]) -> Vector6<f64> {
        let Some(mode) = self.modes.get(m) else {
            return Vector6::zeros();
        };
        let w = self.widths;
        let general = mode.all.n >= MIN_OBSERVATIONS;
        let (mut g, mut total) = if general {
            (mode.all.g * GENERAL_WEIGHT, GENERAL_WEIGHT)
        } else {
            (SMatrix::<f64, 6, 2>::zeros(), 0.0)
        };
        for c in mode.centres.iter().filter(|c| c.n >= MIN_OBSERVATIONS) {
            let d2 = x.d2(&c.at, &w);
            if d2 < 16.0 {
                let k = (-0.5 * d2).exp();
                g += c.g * k;
                total += k;
            }
        }
        if total <= 0.0 {
            return Vector6::zeros();
        }
        let g = g / total;
        g * nalgebra::Vector2::new(a[0], a[1])
    }

    /// The state `step` s on from `x` at twist `v`.
    pub fn advance(&self, x: &ToolState, v: &Vector6<f64>, step: f64) -> ToolState {
        let p = x.p + v.fixed_rows::<3>(0) * step;
        let w: Vector3<f64> = v.fixed_rows::<3>(3).into_owned() * step;
        ToolState {
            p,
            r: UnitQuaternion::from_scaled_axis(w) * x.r,
            c: x.c,
        }
    }
}

/// The twist that took the tool from `a` to `b` in `dt` s (linear, then angular, base frame).
pub fn twist_between(a: &Isometry3<f64>, b: &Isometry3<f64>, dt: f64) -> Vector6<f64> {
    let lin = (b.translation.vector - a.translation.vector) / dt;
    let ang = (b.rotation * a.rotation.inverse()).scaled_axis() / dt;
    Vector6::new(lin.x, lin.y, lin.z, ang.x, ang.y, ang.z)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn widths() -> Widths {
        Widths {
            position_m: 0.05,
            angle_rad: 0.35,
            gripper: 0.5,
        }
    }

    fn at(x: f64) -> ToolState {
        ToolState {
            p: Vector3::new(x, 0.0, 0.3),
            r: UnitQuaternion::identity(),
            c: 0.0,
        }
    }

    /// A map that is linear and the same everywhere is learned from a handful of pushes
    /// along each axis, and a prediction integrates its twist.
    #[test]
    fn a_constant_map_is_learned_from_a_few_pushes() {
        let mut m = InternalModel::new(widths());
        let g = |a: [f64; 2]| Vector6::new(0.1 * a[0], 0.0, 0.1 * a[1], 0.0, 0.0, 0.5 * a[0]);
        for k in 0..20 {
            let a = if k % 2 == 0 { [1.0, 0.0] } else { [0.0, -0.7] };
            m.observe(0, &at(0.0), a, &g(a));
        }
        // Within the ridge's shrinkage (a few per cent).
        let v = m.twist(0, &at(0.01), [0.5, 0.5]);
        assert!(
            (v - g([0.5, 0.5])).norm() < 0.05 * g([0.5, 0.5]).norm(),
            "{v}"
        );
        let next = m.advance(&at(0.0), &v, 0.1);
        assert!((next.p.x - 0.005).abs() < 1e-3, "{:?}", next.p);
        // Nothing learned in another mode.
        assert_eq!(m.twist(1, &at(0.0), [1.0, 0.0]), Vector6::zeros());
    }

    /// Where the map differs from state to state, each visited state keeps its own answer;
    /// far from everything seen, what the stick does in general.
    #[test]
    fn a_state_dependent_map_is_learned_where_it_was_visited() {
        let mut m = InternalModel::new(widths());
        let g = |x: f64, a: [f64; 2]| {
            let s = if x < 0.0 { 1.0 } else { -1.0 };
            Vector6::new(s * 0.1 * a[0], 0.1 * a[1], 0.0, 0.0, 0.0, 0.0)
        };
        for x in [-0.2, 0.2] {
            for k in 0..10 {
                let a = if k % 2 == 0 { [1.0, 0.0] } else { [0.0, 1.0] };
                m.observe(0, &at(x), a, &g(x, a));
            }
        }
        assert_eq!(m.centres(0), 2);
        for x in [-0.2, 0.2] {
            let v = m.twist(0, &at(x), [1.0, 0.0]);
            assert!((v - g(x, [1.0, 0.0])).norm() < 0.1 * 0.1, "at {x}: {v}");
        }
        // Far from both: the two answers average out; the other axis is the same everywhere.
        let v = m.twist(0, &at(1.0), [1.0, 1.0]);
        assert!(v[0].abs() < 0.01 && (v[1] - 0.1).abs() < 0.01, "{v}");
    }

    /// Rest teaches nothing; a push that moved nothing teaches that the stick does nothing
    /// there, and only there.
    #[test]
    fn rest_teaches_nothing_and_a_stop_is_learned_where_it_was() {
        let mut m = InternalModel::new(widths());
        m.observe(0, &at(0.0), [0.01, 0.0], &Vector6::repeat(1.0));
        assert_eq!(m.observations(), 0);
        let g = |a: [f64; 2]| Vector6::new(0.1 * a[0], 0.1 * a[1], 0.0, 0.0, 0.0, 0.0);
        for k in 0..20 {
            let a = if k % 2 == 0 { [1.0, 0.0] } else { [0.0, 1.0] };
            m.observe(0, &at(0.0), a, &g(a));
            m.observe(0, &at(0.3), a, &Vector6::zeros());
        }
        assert!(m.twist(0, &at(0.3), [1.0, 0.0]).norm() < 0.01);
        assert!((m.twist(0, &at(0.0), [1.0, 0.0]) - g([1.0, 0.0])).norm() < 0.01);
    }

    #[test]
    fn the_twist_between_two_poses() {
        let a = Isometry3::identity();
        let b = Isometry3::from_parts(
            nalgebra::Translation3::new(0.01, 0.0, 0.0),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, 0.02)),
        );
        let v = twist_between(&a, &b, 0.1);
        assert!((v - Vector6::new(0.1, 0.0, 0.0, 0.0, 0.0, 0.2)).norm() < 1e-9);
    }
}
