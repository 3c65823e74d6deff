//! Damped least squares: joint steps `dq = Jᵀ (J Jᵀ + λ² I)⁻¹ e` for a task-space error `e`,
//! with a damping λ that grows as the chain nears a singularity, and an iterative inverse
//! kinematics built on it.
//!
//! The damping follows the smallest singular value σ_min of the (task-masked) Jacobian:
//! `λ² = λ_min² + λ_max² (1 - (σ_min / ε)²)` when `σ_min < ε`, else `λ_min²`. Far from
//! singularities the step is the plain least-squares step; at a singularity (the Gen3 lite's
//! zero pose, a stretched-out arm) it is the damped one, whose size is bounded by
//! `|e| / (2 λ)`. A configurable [`Dls::max_step`] bounds it further.
//!
//! Everything here works on fixed-size stack matrices (6 x 6 and 6 x [`MAX_DOF`]): one step
//! allocates nothing.

use nalgebra::{Isometry3, Matrix6, SMatrix, Vector6};

use crate::chain::{Chain, Jacobian, KinError, MAX_DOF};

/// Which task-space rows a step controls: `[vx, vy, vz, wx, wy, wz]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TaskMask(pub [bool; 6]);

impl TaskMask {
    /// Position and orientation (6 rows).
    pub const POSE: TaskMask = TaskMask([true; 6]);
    /// Position only (3 rows).
    pub const POSITION: TaskMask = TaskMask([true, true, true, false, false, false]);
    /// Position in the x-y plane (2 rows), for planar arms.
    pub const PLANAR_XY: TaskMask = TaskMask([true, true, false, false, false, false]);

    /// Number of controlled rows.
    pub fn dim(&self) -> usize {
        self.0.iter().filter(|b| **b).count()
    }
}

/// The difference `target - current` of two poses as a 6-vector: position difference (m)
/// over the rotation vector (axis times angle, rad) that turns `current` into `target`, both
/// in the base frame.
pub fn pose_error(current: &Isometry3<f64>, target: &Isometry3<f64>) -> Vector6<f64> {
    let dp = target.translation.vector - current.translation.vector;
    let dr = (target.rotation * current.rotation.inverse()).scaled_axis();
    Vector6::new(dp.x, dp.y, dp.z, dr.x, dr.y, dr.z)
}

/// Settings of a damped-least-squares step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Dls {
    /// The rows of the task.
    pub mask: TaskMask,
    /// ε: below this smallest singular value the damping grows.
    pub singular_threshold: f64,
    /// λ_max: the damping added at σ_min = 0.
    pub max_damping: f64,
    /// λ_min: damping always present (keeps the solve well-posed).
    pub min_damping: f64,
    /// Largest step norm `|dq|`; a longer step is scaled down uniformly (direction kept).
    pub max_step: f64,
}

impl Default for Dls {
    /// Full pose task; ε = 0.04, λ_max = 0.04, λ_min = 1e-4, unbounded step.
    fn default() -> Self {
        Self {
            mask: TaskMask::POSE,
            singular_threshold: 0.04,
            max_damping: 0.04,
            min_damping: 1e-4,
            max_step: f64::INFINITY,
        }
    }
}

/// What one step did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DlsStep {
    /// Smallest singular value of the masked Jacobian.
    pub sigma_min: f64,
    /// The damping λ used.
    pub damping: f64,
    /// Norm of the step before the [`Dls::max_step`] bound.
    pub raw_norm: f64,
    /// Whether the bound scaled the step down.
    pub limited: bool,
}

impl Dls {
    /// The damping λ for a smallest singular value `sigma_min`.
    pub fn damping(&self, sigma_min: f64) -> f64 {
        self.faded_damping(sigma_min, 1.0)
    }

    /// The damping with its singularity part scaled by `fade` in `[0, 1]`.
    fn faded_damping(&self, sigma_min: f64, fade: f64) -> f64 {
        let eps = self.singular_threshold;
        let mut l2 = self.min_damping * self.min_damping;
        if sigma_min < eps {
            let r = (sigma_min / eps).max(0.0);
            l2 += fade * self.max_damping * self.max_damping * (1.0 - r * r);
        }
        l2.sqrt()
    }

    /// Writes the damped least-squares step for the task error `err` into `dq[..n]`
    /// (`n = jac.n_joints()`). On a non-finite Jacobian or error the step is zero and the
    /// error says which input was bad.
    pub fn step(
        &self,
        jac: &Jacobian,
        err: &Vector6<f64>,
        dq: &mut [f64],
    ) -> Result<DlsStep, KinError> {
        self.faded_step(jac, err, dq, 1.0)
    }

    fn faded_step(
        &self,
        jac: &Jacobian,
        err: &Vector6<f64>,
        dq: &mut [f64],
        fade: f64,
    ) -> Result<DlsStep, KinError> {
        let n = jac.n_joints();
        if dq.len() != n {
            return Err(KinError::Length {
                expected: n,
                found: dq.len(),
            });
        }
        dq.fill(0.0);
        if let Some(index) = err.iter().position(|v| !v.is_finite()) {
            return Err(KinError::NonFinite {
                what: "task error",
                index,
            });
        }
        if let Some(index) = jac.padded().iter().position(|v| !v.is_finite()) {
            return Err(KinError::NonFinite {
                what: "Jacobian",
                index,
            });
        }
        // Masked Jacobian and error: rows outside the task are zero.
        let mut j: SMatrix<f64, 6, MAX_DOF> = *jac.padded();
        let mut e = *err;
        for r in 0..6 {
            if !self.mask.0[r] {
                j.row_mut(r).fill(0.0);
                e[r] = 0.0;
            }
        }
        let mut a: Matrix6<f64> = j * j.transpose();
        // Rows outside the task get a diagonal above every eigenvalue of the task block
        // (the trace bounds them), so the smallest eigenvalue is the task block's own and
        // their (zero) error gives a zero multiplier.
        let trace: f64 = (0..6).filter(|r| self.mask.0[*r]).map(|r| a[(r, r)]).sum();
        for r in 0..6 {
            if !self.mask.0[r] {
                a[(r, r)] = trace + 1.0;
            }
        }
        let lowest = a.symmetric_eigenvalues().min();
        let sigma_min = lowest.max(0.0).sqrt();
        let damping = self.faded_damping(sigma_min, fade);
        for r in 0..6 {
            if self.mask.0[r] {
                a[(r, r)] += damping * damping;
            }
        }
        let Some(chol) = a.cholesky() else {
            // Not positive definite: only possible with a zero damping on a singular task.
            return Ok(DlsStep {
                sigma_min,
                damping,
                raw_norm: 0.0,
                limited: true,
            });
        };
        let y = chol.solve(&e);
        let step = j.tr_mul(&y);
        let raw_norm = step.norm();
        let scale = if raw_norm > self.max_step {
            self.max_step / raw_norm
        } else {
            1.0
        };
        for (d, s) in dq.iter_mut().zip(step.iter()) {
            *d = s * scale;
        }
        Ok(DlsStep {
            sigma_min,
            damping,
            raw_norm,
            limited: scale < 1.0,
        })
    }
}

/// Settings of the iterative inverse kinematics.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ik {
    /// The step (its mask chooses what must match: pose, position, planar).
    pub dls: Dls,
    /// Iterations before giving up.
    pub max_iterations: usize,
    /// Position tolerance (m).
    pub position_tolerance: f64,
    /// Orientation tolerance (rad).
    pub rotation_tolerance: f64,
    /// Task error (m or rad) below which the singularity damping fades out in proportion to
    /// the error, so the last iterations near a singular target converge like Gauss-Newton
    /// instead of crawling; 0 keeps the full damping throughout.
    pub damping_fade_error: f64,
}

impl Default for Ik {
    /// [`Dls::default`] with steps of at most 0.2 rad, 200 iterations, 0.1 mm and 1 mrad,
    /// damping fading below 5 cm.
    fn default() -> Self {
        Self {
            dls: Dls {
                max_step: 0.2,
                ..Dls::default()
            },
            max_iterations: 200,
            position_tolerance: 1e-4,
            rotation_tolerance: 1e-3,
            damping_fade_error: 0.05,
        }
    }
}

/// How an inverse-kinematics solve ended.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IkReport {
    /// Whether the tolerances were met.
    pub converged: bool,
    /// Iterations taken.
    pub iterations: usize,
    /// Remaining position error over the task's rows (m).
    pub position_error: f64,
    /// Remaining orientation error over the task's rows (rad).
    pub rotation_error: f64,
    /// Smallest singular value seen at the last iteration.
    pub sigma_min: f64,
}

impl Ik {
    fn errors(&self, e: &Vector6<f64>) -> (f64, f64) {
        let m = &self.dls.mask.0;
        let sq = |r: std::ops::Range<usize>| -> f64 {
            r.filter(|i| m[*i]).map(|i| e[i] * e[i]).sum::<f64>().sqrt()
        };
        (sq(0..3), sq(3..6))
    }

    /// Moves `q` (the seed on entry) towards a configuration whose tip is at `target`, within
    /// the joint limits. On an unreachable target it stops after [`Ik::max_iterations`] and
    /// leaves in `q` the closest configuration it found (smallest position + rotation error),
    /// with `converged == false`; `q` stays finite and inside the limits. Allocation-free.
    pub fn solve(
        &self,
        chain: &Chain,
        target: &Isometry3<f64>,
        q: &mut [f64],
    ) -> Result<IkReport, KinError> {
        let n = chain.n_joints();
        if q.len() != n {
            return Err(KinError::Length {
                expected: n,
                found: q.len(),
            });
        }
        if let Some(index) = q.iter().position(|v| !v.is_finite()) {
            return Err(KinError::NonFinite {
                what: "joint vector",
                index,
            });
        }
        chain.clamp_to_limits(q);
        let mut jac = Jacobian::zeros(n);
        let mut dq = [0.0; MAX_DOF];
        let mut best = [0.0; MAX_DOF];
        let mut best_error = f64::INFINITY;
        let mut best_report = None;
        let mut report = IkReport {
            converged: false,
            iterations: 0,
            position_error: f64::INFINITY,
            rotation_error: f64::INFINITY,
            sigma_min: 0.0,
        };
        loop {
            let pose = chain.fk_jacobian(q, &mut jac)?;
            let e = pose_error(&pose, target);
            let (pe, re) = self.errors(&e);
            report.position_error = pe;
            report.rotation_error = re;
            if pe <= self.position_tolerance && re <= self.rotation_tolerance {
                report.converged = true;
                return Ok(report);
            }
            if pe + re < best_error {
                best_error = pe + re;
                best[..n].copy_from_slice(q);
                best_report = Some(report);
            }
            if report.iterations >= self.max_iterations {
                // Not converged: hand back the closest configuration seen.
                if let Some(b) = best_report {
                    q.copy_from_slice(&best[..n]);
                    return Ok(IkReport {
                        iterations: report.iterations,
                        ..b
                    });
                }
                return Ok(report);
            }
            let fade = if self.damping_fade_error > 0.0 {
                ((pe * pe + re * re).sqrt() / self.damping_fade_error).min(1.0)
            } else {
                1.0
            };
            let s = self.dls.faded_step(&jac, &e, &mut dq[..n], fade)?;
            report.sigma_min = s.sigma_min;
            for (qi, d) in q.iter_mut().zip(&dq[..n]) {
                *qi += d;
            }
            chain.clamp_to_limits(q);
            report.iterations += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gen3_lite::{self, Gen3Lite};
    use crate::planar5;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    /// Deterministic pseudo-random numbers in `[lo, hi)`.
    fn uniform(state: &mut u64, lo: f64, hi: f64) -> f64 {
        *state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        lo + (hi - lo) * ((*state >> 11) as f64 / (1u64 << 53) as f64)
    }

    #[test]
    fn damping_grows_towards_the_singularity() {
        let d = Dls::default();
        assert_eq!(d.damping(1.0), d.min_damping);
        assert_eq!(d.damping(d.singular_threshold), d.min_damping);
        let at_zero = d.damping(0.0);
        assert!((at_zero - (d.min_damping.powi(2) + d.max_damping.powi(2)).sqrt()).abs() < 1e-15);
        let mut last = at_zero;
        for k in 1..=10 {
            let l = d.damping(d.singular_threshold * k as f64 / 10.0);
            assert!(l < last);
            last = l;
        }
    }

    #[test]
    fn mask_dimensions() {
        assert_eq!(TaskMask::POSE.dim(), 6);
        assert_eq!(TaskMask::POSITION.dim(), 3);
        assert_eq!(TaskMask::PLANAR_XY.dim(), 2);
    }

    #[test]
    fn pose_error_is_target_minus_current() {
        let a = Isometry3::from_parts(
            Translation3::new(0.1, 0.2, 0.3),
            UnitQuaternion::from_euler_angles(0.1, 0.0, 0.0),
        );
        let b = Isometry3::from_parts(
            Translation3::new(0.2, 0.2, 0.1),
            UnitQuaternion::from_euler_angles(0.1, 0.0, 0.5),
        );
        let e = pose_error(&a, &b);
        assert!((e.fixed_rows::<3>(0) - Vector3::new(0.1, 0.0, -0.2)).norm() < 1e-12);
        // Turning a by the rotation vector gives b.
        let turn = UnitQuaternion::from_scaled_axis(Vector3::new(e[3], e[4], e[5]));
        assert!((turn * a.rotation).angle_to(&b.rotation) < 1e-12);
        assert_eq!(pose_error(&a, &a), Vector6::zeros());
    }

    #[test]
    fn ik_converges_on_reachable_targets() {
        let arm = Gen3Lite::get().arm();
        let ik = Ik::default();
        let mut s = 3u64;
        let mut q = [0.0; 6];
        for case in 0..50 {
            let truth: Vec<f64> = (0..6)
                .map(|j| uniform(&mut s, arm.lower()[j] + 0.3, arm.upper()[j] - 0.3))
                .collect();
            let target = arm.fk(&truth).unwrap();
            for j in 0..6 {
                q[j] = truth[j] + uniform(&mut s, -0.3, 0.3);
            }
            let r = ik.solve(arm, &target, &mut q).unwrap();
            assert!(r.converged, "case {case}: {r:?}");
            let reached = arm.fk(&q).unwrap();
            assert!((reached.translation.vector - target.translation.vector).norm() < 1e-4);
            assert!(arm.within_limits(&q));
        }
    }

    #[test]
    fn ik_reaches_cartesian_targets_from_home() {
        let g = Gen3Lite::get();
        let home = g.tcp(&gen3_lite::HOME).unwrap();
        let ik = Ik::default();
        for (dx, dy, dz) in [
            (0.1, 0.0, 0.0),
            (0.0, -0.2, 0.0),
            (0.0, 0.0, -0.25),
            (-0.1, 0.1, 0.1),
        ] {
            let target = Isometry3::from_parts(
                Translation3::from(home.translation.vector + Vector3::new(dx, dy, dz)),
                home.rotation,
            );
            let mut q = gen3_lite::HOME;
            let r = ik.solve(g.arm(), &target, &mut q).unwrap();
            assert!(r.converged, "({dx}, {dy}, {dz}): {r:?}");
        }
    }

    #[test]
    fn unreachable_targets_degrade_gracefully() {
        let arm = Gen3Lite::get().arm();
        let ik = Ik::default();
        let far = Isometry3::translation(2.0, 0.5, 0.3);
        for mask in [TaskMask::POSE, TaskMask::POSITION] {
            let ik = Ik {
                dls: Dls { mask, ..ik.dls },
                ..ik
            };
            let mut q = gen3_lite::HOME;
            let r = ik.solve(arm, &far, &mut q).unwrap();
            assert!(!r.converged);
            assert_eq!(r.iterations, ik.max_iterations);
            assert!(q.iter().all(|v| v.is_finite()));
            assert!(arm.within_limits(&q));
            assert!(r.position_error.is_finite() && r.rotation_error.is_finite());
            let start = (arm.fk(&gen3_lite::HOME).unwrap().translation.vector
                - far.translation.vector)
                .norm();
            assert!(r.position_error < start, "{mask:?}: {r:?}");
        }
        // Position only: the arm ends stretched out towards the target, the TCP at about
        // the arm's full reach from the shoulder (0.28 + 0.245 + 0.057 + 0.235 ≈ 0.8 m).
        let ik = Ik {
            dls: Dls {
                mask: TaskMask::POSITION,
                ..ik.dls
            },
            ..ik
        };
        let mut q = gen3_lite::HOME;
        ik.solve(arm, &far, &mut q).unwrap();
        let p = arm.fk(&q).unwrap().translation.vector;
        let shoulder = Vector3::new(0.0, 0.0, 0.24325);
        let reach = (p - shoulder).norm();
        assert!(reach > 0.75, "{reach}");
        let cos = (p - shoulder)
            .normalize()
            .dot(&(far.translation.vector - shoulder).normalize());
        assert!(cos > 0.99, "{cos}");
    }

    #[test]
    fn the_zero_pose_is_singular_and_the_step_stays_bounded() {
        let arm = Gen3Lite::get().arm();
        let mut jac = Jacobian::zeros(6);
        arm.fk_jacobian(&gen3_lite::ZERO, &mut jac).unwrap();
        let dls = Dls::default();
        let mut dq = [0.0; 6];
        // A sideways push of the straight-up arm, along the lost direction.
        let e = Vector6::new(0.0, 0.05, 0.0, 0.0, 0.0, 0.0);
        let s = dls.step(&jac, &e, &mut dq).unwrap();
        assert!(s.sigma_min < 1e-6, "{s:?}");
        assert!(s.damping > 0.9 * dls.max_damping);
        let n = dq.iter().map(|v| v * v).sum::<f64>().sqrt();
        assert!(dq.iter().all(|v| v.is_finite()));
        assert!(n <= e.norm() / (2.0 * s.damping) + 1e-12, "{n}");
        // Close to the singular pose the damping is still almost full.
        let near = [0.0, 1e-4, 0.0, 0.0, 0.0, 0.0];
        arm.fk_jacobian(&near, &mut jac).unwrap();
        let s2 = dls.step(&jac, &e, &mut dq).unwrap();
        assert!(s2.sigma_min < 1e-3 && s2.damping > 0.9 * dls.max_damping);
        // And IK from the singular pose still gets home.
        let home = arm.fk(&gen3_lite::HOME).unwrap();
        let mut q = gen3_lite::ZERO;
        let r = Ik {
            max_iterations: 500,
            ..Ik::default()
        }
        .solve(arm, &home, &mut q)
        .unwrap();
        assert!(r.converged, "{r:?}");
    }

    #[test]
    fn the_step_bound_scales_uniformly() {
        let arm = Gen3Lite::get().arm();
        let mut jac = Jacobian::zeros(6);
        arm.fk_jacobian(&gen3_lite::HOME, &mut jac).unwrap();
        let e = Vector6::new(0.3, -0.2, 0.1, 0.5, 0.0, 0.2);
        let mut free = [0.0; 6];
        let s = Dls::default().step(&jac, &e, &mut free).unwrap();
        assert!(!s.limited);
        let bounded = Dls {
            max_step: 0.1,
            ..Dls::default()
        };
        let mut dq = [0.0; 6];
        let s2 = bounded.step(&jac, &e, &mut dq).unwrap();
        assert!(s2.limited && s.raw_norm > 0.1);
        let n = dq.iter().map(|v| v * v).sum::<f64>().sqrt();
        assert!((n - 0.1).abs() < 1e-12);
        for j in 0..6 {
            assert!((dq[j] - free[j] * 0.1 / s.raw_norm).abs() < 1e-12);
        }
    }

    #[test]
    fn bad_inputs_give_zero_steps() {
        let arm = Gen3Lite::get().arm();
        let mut jac = Jacobian::zeros(6);
        arm.fk_jacobian(&gen3_lite::HOME, &mut jac).unwrap();
        let mut dq = [1.0; 6];
        let e = Vector6::new(f64::NAN, 0.0, 0.0, 0.0, 0.0, 0.0);
        let err = Dls::default().step(&jac, &e, &mut dq).unwrap_err();
        assert_eq!(
            err.to_string(),
            "the task error holds a non-finite value (at index 0)"
        );
        assert_eq!(dq, [0.0; 6]);
        let mut short = [0.0; 5];
        assert!(
            Dls::default()
                .step(&jac, &Vector6::zeros(), &mut short)
                .is_err()
        );
        let mut q = [0.0, f64::INFINITY, 0.0, 0.0, 0.0, 0.0];
        let target = arm.fk(&gen3_lite::HOME).unwrap();
        assert!(matches!(
            Ik::default().solve(arm, &target, &mut q),
            Err(KinError::NonFinite { index: 1, .. })
        ));
    }

    #[test]
    fn masked_tasks() {
        // Position only on the Gen3 lite: any orientation will do.
        let g = Gen3Lite::get();
        let target = Isometry3::translation(0.35, -0.15, 0.25);
        let mut q = gen3_lite::HOME;
        let ik = Ik {
            dls: Dls {
                mask: TaskMask::POSITION,
                ..Ik::default().dls
            },
            ..Ik::default()
        };
        let r = ik.solve(g.arm(), &target, &mut q).unwrap();
        assert!(r.converged && r.rotation_error == 0.0, "{r:?}");
        // x-y on the planar arm (5 joints, 2 task rows: redundant).
        let chain = planar5::get();
        let mut q = [0.3, 0.4, 0.3, 0.2, 0.1];
        let ik = Ik {
            dls: Dls {
                mask: TaskMask::PLANAR_XY,
                ..Ik::default().dls
            },
            ..Ik::default()
        };
        let target = Isometry3::translation(0.6, -0.3, 0.0);
        let r = ik.solve(chain, &target, &mut q).unwrap();
        assert!(r.converged, "{r:?}");
        // With the full pose task the 5-joint arm has no sixth direction: always damped.
        let mut jac = Jacobian::zeros(5);
        chain.fk_jacobian(&q, &mut jac).unwrap();
        let mut dq = [0.0; 5];
        let full = Dls::default()
            .step(&jac, &Vector6::zeros(), &mut dq)
            .unwrap();
        assert!(full.sigma_min < 1e-6);
        let planar = Dls {
            mask: TaskMask::PLANAR_XY,
            ..Dls::default()
        }
        .step(&jac, &Vector6::zeros(), &mut dq)
        .unwrap();
        assert!(planar.sigma_min > 0.05, "{planar:?}");
    }
}
