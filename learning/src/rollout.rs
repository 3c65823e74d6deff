//! Closed-loop rollouts of a map on a simulated arm, for the paper's proportionality and
//! soft-reversibility experiment: apply an action `a` for a while, stop, apply `−a` for as
//! long, and measure how far the arm went and how close it came back.
//!
//! The command is the served one ([`mapper::step::MapperStep`]'s arithmetic): the action is
//! clamped radially to `|a| <= 1`, `qdot = s · map(q, c, a)`, and a non-finite output becomes
//! a zero command. The arm is anything implementing [`Plant`] (the services crate drives the
//! mock Gen3 lite; [`BoxIntegrator`] is a plain integrator clamped to a box).

use mapper::ActionMap;

/// A simulated arm stepped at a fixed period.
pub trait Plant {
    /// Joint angles now (rad).
    fn q(&self) -> &[f64];
    /// Gripper state now (`0` open .. `1` closed).
    fn gripper(&self) -> f64;
    /// Commands `qdot` (rad/s) and lets `dt` seconds pass.
    fn step(&mut self, qdot: &[f64], dt: f64);
    /// Stops the arm (zero command).
    fn halt(&mut self);
    /// Whether the last step ended with a joint at a limit.
    fn at_limit(&self) -> bool {
        false
    }
}

/// An integrator `q += qdot · dt` clamped to the box `[lower, upper]`, gripper fixed.
#[derive(Debug, Clone, PartialEq)]
pub struct BoxIntegrator {
    /// Joint angles (rad).
    pub q: Vec<f64>,
    /// Gripper state.
    pub gripper: f64,
    /// Lower joint limits (rad).
    pub lower: Vec<f64>,
    /// Upper joint limits (rad).
    pub upper: Vec<f64>,
    /// Whether the last step ended with a joint at a limit.
    pub limited: bool,
}

impl Plant for BoxIntegrator {
    fn q(&self) -> &[f64] {
        &self.q
    }
    fn gripper(&self) -> f64 {
        self.gripper
    }
    fn step(&mut self, qdot: &[f64], dt: f64) {
        self.limited = false;
        for (i, (q, v)) in self.q.iter_mut().zip(qdot).enumerate() {
            let lo = self.lower.get(i).copied().unwrap_or(f64::NEG_INFINITY);
            let hi = self.upper.get(i).copied().unwrap_or(f64::INFINITY);
            *q = (*q + v * dt).clamp(lo, hi);
            self.limited |= *q == lo || *q == hi;
        }
    }
    fn halt(&mut self) {}
    fn at_limit(&self) -> bool {
        self.limited
    }
}

/// The action `alpha · [cos theta, sin theta]`.
pub fn action(alpha: f64, theta: f64) -> [f64; 2] {
    [alpha * theta.cos(), alpha * theta.sin()]
}

/// `n` values evenly spaced over `[0, 1]` (`[0]` for `n = 1`, empty for `n = 0`).
pub fn alpha_grid(n: usize) -> Vec<f64> {
    match n {
        0 => Vec::new(),
        1 => vec![0.0],
        _ => (0..n).map(|i| i as f64 / (n - 1) as f64).collect(),
    }
}

/// The served command for state `(q, c)` and action `a`: `a` clamped radially to `|a| <= 1`,
/// `out = s · map(q, c, a)`, all zero when any output is non-finite.
pub fn served_command(
    map: &mut dyn ActionMap,
    speed_scale: f64,
    q: &[f64],
    c: f64,
    a: &[f64],
    out: &mut [f64],
) {
    let norm = a.iter().map(|v| v * v).sum::<f64>().sqrt();
    let mut clamped = [0.0; 8];
    let d = a.len().min(clamped.len());
    for (ci, ai) in clamped.iter_mut().zip(a) {
        *ci = if norm > 1.0 { ai / norm } else { *ai };
    }
    map.eval(q, c, &clamped[..d], out);
    out.iter_mut().for_each(|v| *v *= speed_scale);
    if out.iter().any(|v| !v.is_finite()) {
        out.fill(0.0);
    }
}

/// Euclidean distance of two joint vectors.
pub fn distance(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// The outcome of one forward-then-reverse run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ForwardReverse {
    /// `|q_fwd − q_0|` (rad): how far `a` moved the arm.
    pub forward: f64,
    /// `|q_rev − q_0|` (rad): how far from the start `−a` left it.
    pub reverse: f64,
    /// Whether a joint reached a limit during the run (the plant clamped the motion, so even
    /// a state-independent map cannot return exactly).
    pub limited: bool,
}

/// Runs `a` for `ticks` periods of `dt`, stops the arm, then `−a` for `ticks` periods, with
/// the served command of `map` (speed scale `speed_scale`) closing the loop through `plant`
/// (which starts at `q_0`).
pub fn forward_reverse(
    map: &mut dyn ActionMap,
    speed_scale: f64,
    plant: &mut dyn Plant,
    a: &[f64],
    ticks: usize,
    dt: f64,
) -> ForwardReverse {
    let m = map.n_joints();
    let q0 = plant.q().to_vec();
    let mut out = vec![0.0; m];
    let neg: Vec<f64> = a.iter().map(|v| -v).collect();
    let mut limited = false;
    let mut run = |plant: &mut dyn Plant, act: &[f64]| {
        for _ in 0..ticks {
            let c = plant.gripper();
            served_command(map, speed_scale, plant.q(), c, act, &mut out);
            plant.step(&out, dt);
            limited |= plant.at_limit();
        }
    };
    run(plant, a);
    plant.halt();
    let forward = distance(plant.q(), &q0);
    run(plant, &neg);
    plant.halt();
    let reverse = distance(plant.q(), &q0);
    ForwardReverse {
        forward,
        reverse,
        limited,
    }
}

/// Mean and (population) standard deviation; `(NaN, NaN)` for no values.
pub fn mean_std(values: &[f64]) -> (f64, f64) {
    if values.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
    (mean, var.sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;
    use mapper::pca::PcaMap;
    use nalgebra::DMatrix;

    /// A map linear in `a` whose matrix depends on `q` (a rotation by `q[0]`), or, with
    /// `bias`, an affine one `H a + b` (what a CAE can learn).
    struct Curved {
        bias: f64,
    }

    impl ActionMap for Curved {
        fn kind(&self) -> mapper::ModelKind {
            mapper::ModelKind::Scl
        }
        fn n_joints(&self) -> usize {
            3
        }
        fn latent_dim(&self) -> usize {
            2
        }
        fn eval(&mut self, q: &[f64], _c: f64, a: &[f64], out: &mut [f64]) {
            let (s, c) = (0.3 * q[1]).sin_cos();
            out[0] = c * a[0] - s * a[1] + self.bias;
            out[1] = s * a[0] + c * a[1];
            out[2] = 0.5 * a[0];
        }
    }

    fn free(q: Vec<f64>) -> BoxIntegrator {
        let n = q.len();
        BoxIntegrator {
            q,
            gripper: 0.0,
            lower: vec![-10.0; n],
            upper: vec![10.0; n],
            limited: false,
        }
    }

    fn pca() -> PcaMap {
        PcaMap::new(DMatrix::from_fn(3, 2, |i, j| {
            [[0.6, 0.0], [0.8, 0.0], [0.0, 1.0]][i][j]
        }))
    }

    #[test]
    fn a_linear_map_returns_exactly_and_is_proportional() {
        let mut map = pca();
        let mut fwd = Vec::new();
        for alpha in alpha_grid(5) {
            let mut arm = free(vec![0.1, -0.2, 0.3]);
            let r = forward_reverse(&mut map, 0.5, &mut arm, &action(alpha, 0.7), 40, 0.025);
            assert!(r.reverse < 1e-12 && !r.limited, "{r:?}");
            fwd.push(r.forward);
        }
        // 1 s at s = 0.5 with orthonormal columns: |q_fwd - q_0| = 0.5 alpha.
        for (f, alpha) in fwd.iter().zip(alpha_grid(5)) {
            assert!((f - 0.5 * alpha).abs() < 1e-12, "{f} vs {alpha}");
        }
    }

    #[test]
    fn actions_beyond_the_unit_disc_are_clamped() {
        let mut map = pca();
        let mut arm = free(vec![0.0; 3]);
        let r = forward_reverse(&mut map, 1.0, &mut arm, &[3.0, 4.0], 40, 0.025);
        assert!((r.forward - 1.0).abs() < 1e-12, "{r:?}");
    }

    #[test]
    fn curvature_leaves_a_small_gap_and_a_bias_a_large_one() {
        let mut curved = Curved { bias: 0.0 };
        let mut arm = free(vec![0.0, 0.5, 0.0]);
        let r = forward_reverse(&mut curved, 1.0, &mut arm, &action(1.0, 0.3), 40, 0.025);
        assert!(r.reverse > 0.0 && r.reverse < 0.2 * r.forward, "{r:?}");
        let mut biased = Curved { bias: 0.2 };
        let mut arm = free(vec![0.0, 0.5, 0.0]);
        let b = forward_reverse(&mut biased, 1.0, &mut arm, &action(1.0, 0.3), 40, 0.025);
        // The bias drifts 0.2 rad/s for 2 s whichever way the action points.
        assert!((b.reverse - 0.4).abs() < 0.05, "{b:?}");
        assert!(b.reverse > 5.0 * r.reverse);
    }

    #[test]
    fn joint_limits_break_exact_return() {
        let mut map = pca();
        let mut arm = BoxIntegrator {
            q: vec![0.0; 3],
            gripper: 0.0,
            lower: vec![-1.0; 3],
            upper: vec![1.0, 0.1, 1.0],
            limited: false,
        };
        let r = forward_reverse(&mut map, 1.0, &mut arm, &[1.0, 0.0], 40, 0.025);
        assert!(r.reverse > 0.5 && r.limited, "{r:?}");
    }

    #[test]
    fn non_finite_outputs_give_zero_commands() {
        let mut map = Curved { bias: f64::NAN };
        let mut out = [1.0; 3];
        served_command(&mut map, 1.0, &[0.0; 3], 0.0, &[0.5, 0.0], &mut out);
        assert_eq!(out, [0.0; 3]);
    }

    #[test]
    fn grid_and_statistics() {
        assert_eq!(alpha_grid(3), vec![0.0, 0.5, 1.0]);
        assert_eq!(alpha_grid(1), vec![0.0]);
        assert!(alpha_grid(0).is_empty());
        let (m, s) = mean_std(&[1.0, 3.0]);
        assert_eq!((m, s), (2.0, 1.0));
        assert!(mean_std(&[]).0.is_nan());
    }
}
