//! The Cartesian side in `glam` f32 types: what the safety filter's workspace checks and the
//! mode-switching twists work with. Joint-space algebra stays in `nalgebra` f64; these are
//! the conversions at the boundary (f32 keeps a 1 m position to well under a micrometre).

use glam::{Quat, Vec3A};
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};

/// A pose of the tool centre point (or any frame) in the base frame, in f32 SIMD types.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TcpPose {
    /// Position (m).
    pub position: Vec3A,
    /// Orientation (unit quaternion).
    pub orientation: Quat,
}

impl TcpPose {
    /// The same pose as an f64 isometry.
    pub fn to_isometry(&self) -> Isometry3<f64> {
        let p = self.position;
        let o = self.orientation;
        Isometry3::from_parts(
            Translation3::new(f64::from(p.x), f64::from(p.y), f64::from(p.z)),
            UnitQuaternion::from_quaternion(Quaternion::new(
                f64::from(o.w),
                f64::from(o.x),
                f64::from(o.y),
                f64::from(o.z),
            )),
        )
    }

    /// The tool's axis `z` (the approach direction of the Gen3 lite's gripper) in the base
    /// frame.
    pub fn approach(&self) -> Vec3A {
        self.orientation * Vec3A::Z
    }
}

impl From<&Isometry3<f64>> for TcpPose {
    fn from(t: &Isometry3<f64>) -> Self {
        let v = t.translation.vector;
        let q = t.rotation.quaternion();
        Self {
            position: Vec3A::new(v.x as f32, v.y as f32, v.z as f32),
            orientation: Quat::from_xyzw(q.i as f32, q.j as f32, q.k as f32, q.w as f32)
                .normalize(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn round_trip_and_approach() {
        let iso = Isometry3::from_parts(
            Translation3::new(0.4, -0.2, 0.3),
            UnitQuaternion::from_euler_angles(0.3, -1.1, 2.0),
        );
        let p = TcpPose::from(&iso);
        let back = p.to_isometry();
        assert!((back.translation.vector - iso.translation.vector).norm() < 1e-6);
        assert!(back.rotation.angle_to(&iso.rotation) < 1e-6);
        let z = iso.rotation * Vector3::z();
        let a = p.approach();
        assert!((f64::from(a.x) - z.x).abs() < 1e-6);
        assert!((f64::from(a.y) - z.y).abs() < 1e-6);
        assert!((f64::from(a.z) - z.z).abs() < 1e-6);
    }
}
