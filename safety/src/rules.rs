//! The filter's rules as pure functions on joint-velocity slices. Every rule only scales: a
//! whole command by one factor (velocity, position, workspace) or the change from the current
//! velocity by one factor (acceleration), so the result is always between zero, what the arm
//! does now and what was asked.

use ipc_types::MAX_JOINTS;

/// The largest factor `<= 1` that brings every `|qdot_j|` within `limit_j`: one factor for all
/// joints, so the direction of `qdot` is kept.
pub fn uniform_scale(qdot: &[f64], limit: &[f64]) -> f64 {
    qdot.iter()
        .zip(limit)
        .filter(|(v, _)| v.abs() > 0.0)
        .map(|(v, l)| l / v.abs())
        .fold(1.0, f64::min)
}

/// Limits the change from `base` to `out` (in place) so that every joint changes by at most
/// `accel_j * dt`, scaling the whole change by one factor: the result lies on the segment from
/// `base` to the requested `out`. Returns whether it acted.
pub fn limit_change(base: &[f64], out: &mut [f64], accel: &[f64], dt: f64) -> bool {
    let mut k: f64 = 1.0;
    for ((b, o), a) in base.iter().zip(out.iter()).zip(accel) {
        let d = (o - b).abs();
        if d > a * dt {
            k = k.min(a * dt / d);
        }
    }
    if k < 1.0 {
        for (b, o) in base.iter().zip(out.iter_mut()) {
            *o = b + k * (*o - b);
        }
        true
    } else {
        false
    }
}

/// The highest speed toward a bound `dist` away from which the arm can still stop before it,
/// decelerating at `decel` in steps of `dt`: the largest `v` with `v·dt + v²/(2·decel) <= dist`.
/// Zero at or past the bound.
pub fn brake_speed(decel: f64, dist: f64, dt: f64) -> f64 {
    if dist <= 0.0 {
        return 0.0;
    }
    (decel * decel * dt * dt + 2.0 * decel * dist).sqrt() - decel * dt
}

/// How fast the acceleration limits let `qdot` be braked along its own direction: the largest
/// `alpha` (1/s) with `alpha·|qdot_j| <= accel_j` for every joint, infinite for a zero
/// `qdot`. The acceleration rule scales a change as a whole, so braking a command keeps its
/// direction and slows joint `j` at `alpha·|qdot_j|`, not at `accel_j`: the braking
/// distances of the position and workspace rules use these decelerations.
pub fn brake_rate(qdot: &[f64], accel: &[f64]) -> f64 {
    qdot.iter()
        .zip(accel)
        .filter(|(v, _)| v.abs() > 0.0)
        .map(|(v, a)| a / v.abs())
        .fold(f64::INFINITY, f64::min)
}

/// The factor `<= 1` for `qdot` so that no joint moving toward its bound
/// `[lower_j, upper_j]` (the limits less the margin) goes faster than it can stop before it;
/// with `hard` the bound is only "not past it within the next tick" (`dist / dt`). Motion away
/// from a bound is never limited. Joint `j` is braked at `min(accel_j, alpha·|qdot_j|)`,
/// `alpha` the [`brake_rate`] of the command (infinite: at `accel_j`).
#[allow(clippy::too_many_arguments)]
pub fn position_scale(
    q: &[f64],
    qdot: &[f64],
    lower: &[f64],
    upper: &[f64],
    accel: &[f64],
    alpha: f64,
    dt: f64,
    hard: bool,
) -> f64 {
    let mut k: f64 = 1.0;
    for j in 0..qdot.len() {
        let v = qdot[j];
        let dist = if v > 0.0 {
            upper[j] - q[j]
        } else if v < 0.0 {
            q[j] - lower[j]
        } else {
            continue;
        };
        let allowed = if hard {
            dist.max(0.0) / dt
        } else {
            brake_speed(accel[j].min(alpha * v.abs()), dist, dt)
        };
        k = k.min(allowed / v.abs());
    }
    k.max(0.0)
}

/// Forward kinematics of the tool, as the workspace rule needs it: the tool position and the
/// linear part of the geometric Jacobian at `q`, written into caller buffers (no allocation).
pub trait TcpModel: Send {
    /// Writes the tool position (m, base frame) into `p` and `∂p/∂q` into `jv` (row `i` is
    /// axis `i`, column `j` joint `j`).
    fn tcp(&mut self, q: &[f64], p: &mut [f64; 3], jv: &mut [[f64; MAX_JOINTS]; 3]);
}

/// The tool model of a kinematic chain (its tip is the tool): forward kinematics and the
/// linear rows of the geometric Jacobian, allocation-free.
#[derive(Debug, Clone)]
pub struct ChainTcp {
    chain: kinematics::Chain,
    jac: kinematics::Jacobian,
}

impl ChainTcp {
    /// The tool model of `chain`.
    pub fn new(chain: kinematics::Chain) -> Self {
        let jac = kinematics::Jacobian::zeros(chain.n_joints());
        Self { chain, jac }
    }

    /// The tool model of a robot profile: its arm chain, base to tool centre point.
    pub fn of(robot: &kinematics::RobotProfile) -> Self {
        Self::new(robot.arm().clone())
    }
}

impl TcpModel for ChainTcp {
    fn tcp(&mut self, q: &[f64], p: &mut [f64; 3], jv: &mut [[f64; MAX_JOINTS]; 3]) {
        match self.chain.fk_jacobian(q, &mut self.jac) {
            Ok(pose) => {
                let t = pose.translation.vector;
                *p = [t.x, t.y, t.z];
                let n = self.chain.n_joints().min(MAX_JOINTS);
                for (i, row) in jv.iter_mut().enumerate() {
                    *row = [0.0; MAX_JOINTS];
                    for (j, v) in row.iter_mut().enumerate().take(n) {
                        *v = self.jac.get(i, j);
                    }
                }
            }
            // A q the chain refuses (wrong length) makes the rule inactive for the tick: the
            // filter checks finiteness and shape itself and stops the arm for those.
            Err(_) => *p = [f64::NAN; 3],
        }
    }
}

/// Half-spaces `n·x >= b` that bound the tool: the table plane and the six faces of the box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bounds {
    planes: [([f64; 3], f64); 7],
}

impl Bounds {
    /// The table plane `z >= table_z` and the box `min <= x <= max`.
    pub fn new(table_z: f64, min: [f64; 3], max: [f64; 3]) -> Self {
        Self {
            planes: [
                ([0.0, 0.0, 1.0], table_z),
                ([1.0, 0.0, 0.0], min[0]),
                ([0.0, 1.0, 0.0], min[1]),
                ([0.0, 0.0, 1.0], min[2]),
                ([-1.0, 0.0, 0.0], -max[0]),
                ([0.0, -1.0, 0.0], -max[1]),
                ([0.0, 0.0, -1.0], -max[2]),
            ],
        }
    }

    /// Whether `p` is inside every half-space, with `slack` (m) of tolerance.
    pub fn contains(&self, p: &[f64; 3], slack: f64) -> bool {
        self.planes
            .iter()
            .all(|(n, b)| n[0] * p[0] + n[1] * p[1] + n[2] * p[2] >= b - slack)
    }

    /// The factor `<= 1` for a tool velocity `v` at position `p` so that it approaches no
    /// bound faster than it can stop before it (or, with `hard`, does not cross it within the
    /// next tick); motion back inside is never limited, motion further out of a violated bound
    /// is stopped. An approach at rate `r` is braked at `min(decel, alpha·r)`, `alpha` the
    /// [`brake_rate`] of the joint command behind `v` (infinite: at `decel`).
    pub fn scale(
        &self,
        p: &[f64; 3],
        v: &[f64; 3],
        decel: f64,
        alpha: f64,
        dt: f64,
        hard: bool,
    ) -> f64 {
        let mut k: f64 = 1.0;
        for (n, b) in &self.planes {
            let rate = n[0] * v[0] + n[1] * v[1] + n[2] * v[2];
            if rate >= 0.0 {
                continue;
            }
            let dist = n[0] * p[0] + n[1] * p[1] + n[2] * p[2] - b;
            let allowed = if hard {
                dist.max(0.0) / dt
            } else {
                brake_speed(decel.min(alpha * -rate), dist, dt)
            };
            k = k.min(allowed / -rate);
        }
        k.max(0.0)
    }
}

/// `jv · qdot` for the first `n` joints.
pub fn tcp_velocity(jv: &[[f64; MAX_JOINTS]; 3], qdot: &[f64]) -> [f64; 3] {
    let mut v = [0.0; 3];
    for (vi, row) in v.iter_mut().zip(jv) {
        *vi = row.iter().zip(qdot).map(|(a, b)| a * b).sum();
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn braking_speed_stops_in_time() {
        let (a, dt) = (0.5, 0.025);
        for dist in [0.0001, 0.01, 0.1, 1.0] {
            let mut v = brake_speed(a, dist, dt);
            let mut travelled = 0.0;
            while v > 0.0 {
                travelled += v * dt;
                v = (v - a * dt).max(0.0);
            }
            assert!(travelled <= dist + 1e-12, "{dist}: {travelled}");
        }
        assert_eq!(brake_speed(a, -1.0, dt), 0.0);
    }

    #[test]
    fn braking_keeps_the_direction_at_the_slowest_joints_pace() {
        // Joint 0 (0.4 rad/s at 0.4 rad/s²) needs 1 s to stop; braking the whole command in
        // that second slows joint 1 at 0.1 rad/s², not at its own 10 rad/s².
        let (qdot, acc) = ([0.4, 0.1], [0.4, 10.0]);
        let alpha = brake_rate(&qdot, &acc);
        assert!((alpha - 1.0).abs() < 1e-12);
        assert_eq!(brake_rate(&[0.0, 0.0], &acc), f64::INFINITY);
        // Joint 1 is 6 mm from its bound: at 10 rad/s² it could go on at 0.1 rad/s, at
        // 0.1 rad/s² it must slow down.
        let (lo, hi) = ([-1.0; 2], [1.0, 0.006]);
        let own = position_scale(
            &[0.0; 2],
            &qdot,
            &lo,
            &hi,
            &acc,
            f64::INFINITY,
            0.025,
            false,
        );
        let along = position_scale(&[0.0; 2], &qdot, &lo, &hi, &acc, alpha, 0.025, false);
        assert_eq!(own, 1.0);
        assert!(along < 0.9, "{along}");
        let v = along * qdot[1];
        assert!(v * 0.025 + v * v / (2.0 * 0.1) <= 0.006 + 1e-12);
    }

    #[test]
    fn position_scale_leaves_motion_away_free() {
        let (lo, hi, acc) = ([-1.0; 2], [1.0; 2], [1.0; 2]);
        // At the upper bound: moving up is stopped, moving down is free.
        assert_eq!(
            position_scale(
                &[1.0, 0.0],
                &[0.5, 0.0],
                &lo,
                &hi,
                &acc,
                f64::INFINITY,
                0.025,
                false
            ),
            0.0
        );
        assert_eq!(
            position_scale(
                &[1.0, 0.0],
                &[-0.5, 0.0],
                &lo,
                &hi,
                &acc,
                f64::INFINITY,
                0.025,
                false
            ),
            1.0
        );
        // Past the bound: moving further out is stopped.
        assert_eq!(
            position_scale(
                &[1.2, 0.0],
                &[0.1, 0.0],
                &lo,
                &hi,
                &acc,
                f64::INFINITY,
                0.025,
                true
            ),
            0.0
        );
    }

    #[test]
    fn bounds_contain_and_scale() {
        let b = Bounds::new(0.0, [-1.0; 3], [1.0; 3]);
        assert!(b.contains(&[0.0, 0.0, 0.5], 0.0));
        assert!(!b.contains(&[0.0, 0.0, -0.01], 0.0));
        // Moving down onto the table from 1 cm at 1 m/s: must slow down.
        let k = b.scale(
            &[0.0, 0.0, 0.01],
            &[0.0, 0.0, -1.0],
            0.5,
            f64::INFINITY,
            0.025,
            false,
        );
        assert!(k < 0.2);
        // Moving up from below the table is free; moving down from there is stopped.
        assert_eq!(
            b.scale(
                &[0.0, 0.0, -0.01],
                &[0.0, 0.0, 0.1],
                0.5,
                f64::INFINITY,
                0.025,
                false
            ),
            1.0
        );
        assert_eq!(
            b.scale(
                &[0.0, 0.0, -0.01],
                &[0.0, 0.0, -1.0],
                0.5,
                f64::INFINITY,
                0.025,
                true
            ),
            0.0
        );
    }

    proptest! {
        #[test]
        fn limit_change_stays_within_limits_and_on_the_segment(
            base in proptest::array::uniform6(-2.0f64..2.0),
            want in proptest::array::uniform6(-2.0f64..2.0),
        ) {
            let accel = [1.0, 0.5, 0.4, 1.0, 10.0, 10.0];
            let mut out = want;
            limit_change(&base, &mut out, &accel, 0.025);
            let mut k: Option<f64> = None;
            for j in 0..6 {
                prop_assert!((out[j] - base[j]).abs() <= accel[j] * 0.025 * (1.0 + 1e-12));
                let d = want[j] - base[j];
                if d.abs() > 1e-9 {
                    let kj = (out[j] - base[j]) / d;
                    if let Some(k) = k {
                        prop_assert!((kj - k).abs() < 1e-6);
                    }
                    k = Some(kj);
                }
            }
        }
    }
}
