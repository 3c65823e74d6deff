//! Robot profiles: everything the graph needs to know about the arm it drives, under one name.
//!
//! A [`RobotProfile`] bundles the robot description (URDF), the arm chain from the base to the
//! tool centre point (the tool model: FK and Jacobian for the workspace bounds and the
//! Cartesian modes), the teleoperation limits ([`ArmLimits`]: positions from the URDF, speeds
//! capped by it), the named poses, the control rate and the mock gripper's lag. The graph
//! chooses one by name (`[graph] robot` in the graph TOML) and every node takes its facts from
//! it, so a second arm is a new entry of [`RobotProfile::names`], not edits across crates.
//!
//! This module is the one place that names the robots the graph can drive (a test in
//! `tests/tests/robot_named_once.rs` checks that no other crate of the graph names one).
//!
//! ```
//! use kinematics::RobotProfile;
//!
//! let arm = RobotProfile::by_name("gen3_lite").unwrap();
//! assert_eq!(arm.n_joints(), 6);
//! assert_eq!(arm.control_rate_hz(), 40.0);
//! let home = arm.named_pose("home").unwrap();
//! assert!((arm.arm().fk(home).unwrap().translation.x - 0.43882).abs() < 1e-4);
//! assert!(RobotProfile::by_name("ur5").is_err());
//! ```

use std::sync::OnceLock;

use crate::ArmLimits;
use crate::chain::Chain;
use crate::collision::CollisionModel;
use crate::robot::{RobotModel, UrdfError};

/// The facts that define a profile, checked by [`RobotProfile::new`].
#[derive(Debug, Clone)]
pub struct ProfileSpec<'a> {
    /// The name the graph TOML uses (`[graph] robot`), e.g. `gen3_lite`.
    pub name: &'a str,
    /// How people call the robot, for messages (`Gen3 lite`).
    pub description: &'a str,
    /// The robot description (URDF text).
    pub urdf: &'a str,
    /// How the description is named in messages (`robots/gen3_lite.urdf`).
    pub urdf_name: &'a str,
    /// The base link: every pose is expressed in its frame.
    pub base_link: &'a str,
    /// The tool centre point: the tip of the arm chain.
    pub tcp_link: &'a str,
    /// The arm's joints, base to tip, as the chain `base_link -> tcp_link` must have them.
    pub joint_names: &'a [&'a str],
    /// Teleoperation speed defaults (rad/s), one per joint; capped by the URDF's velocity
    /// limits in [`RobotProfile::limits`].
    pub teleop_velocity_rad_s: &'a [f64],
    /// Teleoperation acceleration defaults (rad/s²), one per joint.
    pub teleop_acceleration_rad_s2: &'a [f64],
    /// Named poses (rad), within the position limits; `home` is required (the mock's start).
    pub poses: &'a [(&'a str, &'a [f64])],
    /// The rate of the robot's control interface (Hz): the graph's default tick rate.
    pub control_rate_hz: f64,
    /// The mock gripper's first-order lag (s).
    pub gripper_time_constant_s: f64,
    /// The arm's collision model (capsules per link), if it has one: the safety filter's
    /// whole-arm rules need it.
    pub collision: Option<fn() -> &'static CollisionModel>,
    /// Software position limit (rad) for the joints the URDF leaves unlimited (`continuous`):
    /// they get `[-limit, limit]`. Required when the arm chain has such a joint; at least π,
    /// so that a whole turn fits.
    pub continuous_limit_rad: Option<f64>,
    /// The gripper, if the arm carries one.
    pub gripper: Option<GripperSpec<'a>>,
    /// The learned map built into `scl` for this arm (the bytes of a model file,
    /// `models/<name>.safetensors`, embedded with `include_bytes!`): what `[mapper] model =
    /// "bundled"`, the default, drives, so the graph runs on the arm with no training step.
    /// The mapper checks it like any model file; `None` for an arm without one.
    pub bundled_model: Option<ModelBytes>,
}

/// The bytes of a model file built into the binary; its `Debug` shows their number, not them.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct ModelBytes(pub &'static [u8]);

impl std::fmt::Debug for ModelBytes {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "ModelBytes({} bytes)", self.0.len())
    }
}

/// A gripper the stack drives as one scalar `c` in `[0, 1]` (0 open, 1 closed): the joint of
/// the URDF that `c` sets, and its values at both ends.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GripperSpec<'a> {
    /// The actuated gripper joint (the URDF's other finger joints mimic it).
    pub joint: &'a str,
    /// The joint's value when open (`c = 0`), rad.
    pub open_rad: f64,
    /// The joint's value when closed (`c = 1`), rad.
    pub closed_rad: f64,
}

/// A profile's gripper: see [`GripperSpec`].
#[derive(Debug, Clone, PartialEq)]
pub struct Gripper {
    joint: String,
    open_rad: f64,
    closed_rad: f64,
}

impl Gripper {
    /// The actuated gripper joint's name.
    pub fn joint(&self) -> &str {
        &self.joint
    }

    /// The joint's value when open (rad).
    pub fn open_rad(&self) -> f64 {
        self.open_rad
    }

    /// The joint's value when closed (rad).
    pub fn closed_rad(&self) -> f64 {
        self.closed_rad
    }

    /// The joint's value for the gripper state `c` (0 open .. 1 closed; clamped).
    pub fn angle(&self, c: f64) -> f64 {
        let c = if c.is_nan() { 0.0 } else { c.clamp(0.0, 1.0) };
        // Exact at both ends.
        self.open_rad * (1.0 - c) + self.closed_rad * c
    }
}

/// Why a profile could not be had.
#[derive(Debug, thiserror::Error)]
pub enum ProfileError {
    /// No profile has this name.
    #[error("`{name}` is not a known robot; known: {known}")]
    Unknown {
        /// The name asked for.
        name: String,
        /// The known names, comma-separated.
        known: String,
    },
    /// The robot description does not load or lacks the arm chain.
    #[error(transparent)]
    Urdf(#[from] UrdfError),
    /// A fact of the profile is unusable.
    #[error("robot {robot}: {reason}")]
    Spec {
        /// The profile's name.
        robot: String,
        /// What is wrong.
        reason: String,
    },
}

/// One robot, as the graph sees it. Built once per process by [`RobotProfile::by_name`];
/// [`RobotProfile::new`] builds one from a [`ProfileSpec`] (tests, experiments).
#[derive(Debug, Clone)]
pub struct RobotProfile {
    name: String,
    description: String,
    urdf_name: String,
    model: RobotModel,
    arm: Chain,
    limits: ArmLimits,
    poses: Vec<(String, Vec<f64>)>,
    control_rate_hz: f64,
    gripper_time_constant_s: f64,
    collision: Option<fn() -> &'static CollisionModel>,
    continuous: Vec<bool>,
    gripper: Option<Gripper>,
    bundled_model: Option<ModelBytes>,
}

/// The built-in profiles, the default first. A new arm is a new function here.
const ROBOTS: [fn() -> ProfileSpec<'static>; 2] = [gen3_lite, gen3];

/// Each built-in profile, parsed once per process when first asked for.
static LOADED: [OnceLock<RobotProfile>; ROBOTS.len()] = [const { OnceLock::new() }; ROBOTS.len()];

/// The spec of a Kinova arm from its module (`crate::gen3_lite`, `crate::gen3`), which names
/// its URDF, links, joints, teleoperation limits, poses, rates, gripper joint and bundled model
/// alike; what
/// differs between the arms is given: the collision model, the continuous joints' software
/// limit and the gripper joint's open and closed positions (rad).
macro_rules! kinova_spec {
    ($module:ident, $name:literal, $description:literal, collision: $collision:expr,
     continuous_limit_rad: $continuous:expr, gripper_rad: ($open:expr, $closed:expr)) => {{
        use crate::$module as g;
        const POSES: &[(&str, &[f64])] = &[
            ("home", &g::HOME),
            ("zero", &g::ZERO),
            ("retract", &g::RETRACT),
        ];
        ProfileSpec {
            name: $name,
            description: $description,
            urdf: g::URDF,
            urdf_name: g::URDF_NAME,
            base_link: g::BASE_LINK,
            tcp_link: g::TCP_LINK,
            joint_names: &g::JOINT_NAMES,
            teleop_velocity_rad_s: &g::DEFAULT_VELOCITY_RAD_S,
            teleop_acceleration_rad_s2: &g::DEFAULT_ACCELERATION_RAD_S2,
            poses: POSES,
            control_rate_hz: g::CONTROL_RATE_HZ,
            gripper_time_constant_s: g::GRIPPER_TIME_CONSTANT_S,
            collision: $collision,
            continuous_limit_rad: $continuous,
            gripper: Some(GripperSpec {
                joint: g::GRIPPER_JOINT,
                open_rad: $open,
                closed_rad: $closed,
            }),
            bundled_model: Some(ModelBytes(g::BUNDLED_MODEL)),
        }
    }};
}

/// The Kinova Gen3 lite ([`crate::gen3_lite`]).
fn gen3_lite() -> ProfileSpec<'static> {
    kinova_spec!(
        gen3_lite,
        "gen3_lite",
        "Gen3 lite",
        collision: Some(CollisionModel::get),
        continuous_limit_rad: None,
        gripper_rad: (0.96, -0.09)
    )
}

/// The Kinova Gen3, 7 DoF, with a Robotiq 2F-85 ([`crate::gen3`]).
fn gen3() -> ProfileSpec<'static> {
    kinova_spec!(
        gen3,
        "gen3",
        "Gen3",
        collision: Some(crate::gen3::collision_model),
        continuous_limit_rad: Some(crate::gen3::CONTINUOUS_LIMIT_RAD),
        gripper_rad: (crate::gen3::GRIPPER_OPEN_RAD, crate::gen3::GRIPPER_CLOSED_RAD)
    )
}

impl ProfileSpec<'static> {
    /// The paper's planar 5-DOF reaching arm ([`crate::planar5`]) as a profile, for tests and
    /// experiments that run a node on another arm; not a robot the graph offers by name.
    pub fn planar5() -> Self {
        use crate::planar5 as p;
        const NAMES: [&str; p::N_JOINTS] = ["joint_1", "joint_2", "joint_3", "joint_4", "joint_5"];
        const POSES: &[(&str, &[f64])] = &[("home", &[0.0; p::N_JOINTS])];
        ProfileSpec {
            name: "planar5",
            description: "planar 5-DOF reaching arm",
            urdf: p::URDF,
            urdf_name: p::URDF_NAME,
            base_link: p::BASE_LINK,
            tcp_link: p::TIP_LINK,
            joint_names: &NAMES,
            teleop_velocity_rad_s: &[1.0; p::N_JOINTS],
            teleop_acceleration_rad_s2: &[2.0; p::N_JOINTS],
            poses: POSES,
            control_rate_hz: 40.0,
            gripper_time_constant_s: 0.1,
            collision: None,
            continuous_limit_rad: None,
            gripper: None,
            bundled_model: None,
        }
    }
}

impl RobotProfile {
    /// The built-in profile `name`, parsed once per process.
    ///
    /// # Panics
    ///
    /// If a built-in profile does not load, which is a build defect that the crate's tests
    /// catch (`every_builtin_profile_loads`).
    pub fn by_name(name: &str) -> Result<&'static RobotProfile, ProfileError> {
        for (spec, cell) in ROBOTS.iter().zip(&LOADED) {
            let spec = spec();
            if spec.name == name {
                return Ok(cell.get_or_init(|| match Self::new(&spec) {
                    Ok(p) => p,
                    Err(e) => panic!("the built-in robot profile {name} is broken: {e}"),
                }));
            }
        }
        Err(ProfileError::Unknown {
            name: name.to_owned(),
            known: Self::names().collect::<Vec<_>>().join(", "),
        })
    }

    /// The names of the built-in profiles, the default first.
    pub fn names() -> impl Iterator<Item = &'static str> {
        ROBOTS.iter().map(|spec| spec().name)
    }

    /// The name of the default profile (the graph's robot when the TOML names none).
    pub fn default_name() -> &'static str {
        ROBOTS[0]().name
    }

    /// The default profile ([`RobotProfile::default_name`]).
    pub fn default_robot() -> &'static RobotProfile {
        match Self::by_name(Self::default_name()) {
            Ok(p) => p,
            Err(e) => panic!("{e}"),
        }
    }

    /// Builds and checks a profile: the URDF loads, the chain `base_link -> tcp_link` has the
    /// joints named, every per-joint list has one entry per joint, the poses are within the
    /// position limits and `home` is one of them.
    pub fn new(spec: &ProfileSpec<'_>) -> Result<Self, ProfileError> {
        let model = RobotModel::from_urdf_str(spec.urdf, spec.urdf_name)?;
        let mut arm = model.chain(spec.base_link, spec.tcp_link)?;
        let continuous = Self::unlimited_joints(spec, &mut arm)?;
        let gripper = Self::gripper_of(spec, &model)?;
        Self::check_spec(spec, &arm)?;
        let limits = ArmLimits {
            names: arm.joint_names().to_vec(),
            lower_rad: arm.lower().to_vec(),
            upper_rad: arm.upper().to_vec(),
            max_velocity_rad_s: spec
                .teleop_velocity_rad_s
                .iter()
                .zip(arm.velocity_limits())
                .map(|(d, u)| d.min(*u))
                .collect(),
            max_acceleration_rad_s2: spec.teleop_acceleration_rad_s2.to_vec(),
        };
        Ok(Self {
            name: spec.name.to_owned(),
            description: spec.description.to_owned(),
            urdf_name: spec.urdf_name.to_owned(),
            model,
            arm,
            limits,
            poses: spec
                .poses
                .iter()
                .map(|(name, q)| ((*name).to_owned(), q.to_vec()))
                .collect(),
            control_rate_hz: spec.control_rate_hz,
            gripper_time_constant_s: spec.gripper_time_constant_s,
            collision: spec.collision,
            continuous,
            gripper,
            bundled_model: spec.bundled_model,
        })
    }

    /// The joints without position limits in the URDF (continuous joints), given
    /// `continuous_limit_rad` (at least π) as their limits on `arm`.
    fn unlimited_joints(
        spec: &ProfileSpec<'_>,
        arm: &mut Chain,
    ) -> Result<Vec<bool>, ProfileError> {
        let bad = |reason: String| ProfileError::Spec {
            robot: spec.name.to_owned(),
            reason,
        };
        let unlimited: Vec<&String> = arm
            .joint_names()
            .iter()
            .zip(arm.lower().iter().zip(arm.upper()))
            .filter(|(_, (lo, hi))| !(lo.is_finite() && hi.is_finite()))
            .map(|(name, _)| name)
            .collect();
        let continuous = match (unlimited.is_empty(), spec.continuous_limit_rad) {
            (true, _) => vec![false; arm.n_joints()],
            (false, None) => {
                return Err(bad(format!(
                    "the joints {unlimited:?} have no position limits in {}; give continuous_limit_rad",
                    spec.urdf_name
                )));
            }
            (false, Some(w)) if !(w.is_finite() && w >= std::f64::consts::PI) => {
                return Err(bad(format!(
                    "continuous_limit_rad is {w}; it must be a number of at least π"
                )));
            }
            (false, Some(w)) => arm.limit_unlimited(w)[..arm.n_joints()].to_vec(),
        };
        Ok(continuous)
    }

    /// The gripper: a joint of the URDF whose open and closed angles are within its range.
    fn gripper_of(
        spec: &ProfileSpec<'_>,
        model: &RobotModel,
    ) -> Result<Option<Gripper>, ProfileError> {
        let bad = |reason: String| ProfileError::Spec {
            robot: spec.name.to_owned(),
            reason,
        };
        Ok(match &spec.gripper {
            None => None,
            Some(g) => {
                let j = model.joint(g.joint).ok_or_else(|| {
                    bad(format!(
                        "the gripper joint `{}` is not a joint of {}",
                        g.joint, spec.urdf_name
                    ))
                })?;
                for (what, v) in [("open_rad", g.open_rad), ("closed_rad", g.closed_rad)] {
                    if !(v.is_finite() && v >= j.lower && v <= j.upper) {
                        return Err(bad(format!(
                            "the gripper's {what} {v} is outside the joint `{}`'s range [{}, {}]",
                            g.joint, j.lower, j.upper
                        )));
                    }
                }
                Some(Gripper {
                    joint: g.joint.to_owned(),
                    open_rad: g.open_rad,
                    closed_rad: g.closed_rad,
                })
            }
        })
    }

    /// The chain's joints are the profile's; the teleoperation limits, rates and poses fit
    /// them; there is a `home` pose.
    fn check_spec(spec: &ProfileSpec<'_>, arm: &Chain) -> Result<(), ProfileError> {
        let bad = |reason: String| ProfileError::Spec {
            robot: spec.name.to_owned(),
            reason,
        };
        if arm.joint_names() != spec.joint_names {
            return Err(bad(format!(
                "the chain {} -> {} in {} has the joints {:?}, the profile names {:?}",
                spec.base_link,
                spec.tcp_link,
                spec.urdf_name,
                arm.joint_names(),
                spec.joint_names
            )));
        }
        let n = arm.n_joints();
        for (what, values) in [
            ("teleop_velocity_rad_s", spec.teleop_velocity_rad_s),
            (
                "teleop_acceleration_rad_s2",
                spec.teleop_acceleration_rad_s2,
            ),
        ] {
            if values.len() != n || values.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
                return Err(bad(format!(
                    "{what} needs {n} positive numbers, one per joint"
                )));
            }
        }
        for (what, v) in [
            ("control_rate_hz", spec.control_rate_hz),
            ("gripper_time_constant_s", spec.gripper_time_constant_s),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(bad(format!("{what} is {v}; it must be a positive number")));
            }
        }
        for (name, q) in spec.poses {
            if q.len() != n || !arm.within_limits(q) {
                return Err(bad(format!(
                    "the pose `{name}` {q:?} is not {n} joint angles within the limits"
                )));
            }
        }
        if !spec.poses.iter().any(|(name, _)| *name == "home") {
            return Err(bad("there is no `home` pose".into()));
        }
        Ok(())
    }

    /// The name the graph TOML uses.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// How people call the robot.
    pub fn description(&self) -> &str {
        &self.description
    }

    /// How the robot description is named in messages.
    pub fn urdf_name(&self) -> &str {
        &self.urdf_name
    }

    /// The parsed robot description.
    pub fn model(&self) -> &RobotModel {
        &self.model
    }

    /// The arm chain from the base to the tool centre point: the tool model (FK, Jacobian).
    pub fn arm(&self) -> &Chain {
        &self.arm
    }

    /// Number of arm joints.
    pub fn n_joints(&self) -> usize {
        self.arm.n_joints()
    }

    /// The arm's joint names, base to tip.
    pub fn joint_names(&self) -> &[String] {
        self.arm.joint_names()
    }

    /// Teleoperation limits: position limits from the URDF; speeds the teleoperation
    /// defaults capped by the URDF's velocity limits; the default accelerations.
    pub fn limits(&self) -> &ArmLimits {
        &self.limits
    }

    /// The URDF's velocity limits (rad/s): no configured speed may exceed them.
    pub fn urdf_velocity_rad_s(&self) -> &[f64] {
        self.arm.velocity_limits()
    }

    /// A named pose by name.
    pub fn named_pose(&self, name: &str) -> Option<&[f64]> {
        self.poses
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, q)| q.as_slice())
    }

    /// The names of the named poses.
    pub fn pose_names(&self) -> impl Iterator<Item = &str> {
        self.poses.iter().map(|(n, _)| n.as_str())
    }

    /// The rate of the robot's control interface (Hz).
    pub fn control_rate_hz(&self) -> f64 {
        self.control_rate_hz
    }

    /// The mock gripper's first-order lag (s).
    pub fn gripper_time_constant_s(&self) -> f64 {
        self.gripper_time_constant_s
    }

    /// Which joints turn without end on the arm (URDF `continuous`): their limits are the
    /// profile's software limits, and [`RobotProfile::wrap_for_maps`] wraps them.
    pub fn continuous_joints(&self) -> &[bool] {
        &self.continuous
    }

    /// Brings each continuous joint of `q` into the turn centred on the home pose,
    /// `(home - π, home + π]`, for the inputs of learned maps: the same arm pose always gives
    /// the same numbers, with no jump near home. Limited joints (and entries beyond the arm's
    /// joints) are left as they are; the pose the angles describe does not change.
    pub fn wrap_for_maps(&self, q: &mut [f64]) {
        use std::f64::consts::{PI, TAU};
        let home = self.named_pose("home").unwrap_or(&[]);
        for ((v, cont), h) in q.iter_mut().zip(&self.continuous).zip(home) {
            if *cont && v.is_finite() {
                // (h - π, h + π]: shift so the interval is (0, 2π], wrap, shift back.
                let r = (*v - h + PI).rem_euclid(TAU);
                let r = if r == 0.0 { TAU } else { r };
                *v = h - PI + r;
            }
        }
    }

    /// The gripper, if the arm carries one: the joint the scalar state `c` sets.
    pub fn gripper(&self) -> Option<&Gripper> {
        self.gripper.as_ref()
    }

    /// The model file built into `scl` for this arm ([`ProfileSpec::bundled_model`]), if any.
    pub fn bundled_model(&self) -> Option<&'static [u8]> {
        self.bundled_model.map(|m| m.0)
    }

    /// The arm's collision model, if the profile has one (the Gen3 lite's is
    /// `robots/gen3_lite_collision.toml`).
    pub fn collision_model(&self) -> Option<&'static CollisionModel> {
        self.collision.map(|get| get())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gen3_lite::{self, Gen3Lite};

    #[test]
    fn every_builtin_profile_loads() {
        for name in RobotProfile::names() {
            let p = RobotProfile::by_name(name).unwrap();
            assert_eq!(p.name(), name);
            assert!(p.named_pose("home").is_some());
        }
        assert_eq!(
            RobotProfile::default_robot().name(),
            RobotProfile::default_name()
        );
    }

    /// The profile says what the Gen3 lite module says.
    #[test]
    fn the_gen3_lite_profile_is_the_gen3_lite() {
        let p = RobotProfile::by_name("gen3_lite").unwrap();
        assert_eq!(p.limits(), &gen3_lite::limits());
        assert_eq!(p.arm(), Gen3Lite::get().arm());
        assert_eq!(p.model(), Gen3Lite::get().model());
        for name in ["zero", "home", "retract"] {
            assert_eq!(
                p.named_pose(name).unwrap(),
                gen3_lite::named_pose(name).unwrap()
            );
        }
        assert!(p.named_pose("nowhere").is_none());
        assert_eq!(p.control_rate_hz(), gen3_lite::CONTROL_RATE_HZ);
        assert_eq!(
            p.gripper_time_constant_s(),
            gen3_lite::GRIPPER_TIME_CONSTANT_S
        );
        assert_eq!(
            p.urdf_velocity_rad_s(),
            Gen3Lite::get().arm().velocity_limits()
        );
        assert_eq!(p.description(), "Gen3 lite");
    }

    #[test]
    fn unknown_robots_are_named_with_the_known_ones() {
        let e = RobotProfile::by_name("ur5").unwrap_err().to_string();
        assert_eq!(e, "`ur5` is not a known robot; known: gen3_lite, gen3");
    }

    /// The Gen3's spec with its continuous joints and gripper, and what the checks refuse.
    #[test]
    fn continuous_joints_and_grippers_are_checked() {
        let spec = gen3();
        let p = RobotProfile::new(&spec).unwrap();
        assert_eq!(p.continuous_joints().iter().filter(|c| **c).count(), 4);
        let e = RobotProfile::new(&ProfileSpec {
            continuous_limit_rad: None,
            ..spec.clone()
        })
        .unwrap_err()
        .to_string();
        assert_eq!(
            e,
            "robot gen3: the joints [\"joint_1\", \"joint_3\", \"joint_5\", \"joint_7\"] have no position limits in robots/gen3.urdf; give continuous_limit_rad"
        );
        for w in [3.0, f64::NAN, f64::INFINITY] {
            let e = RobotProfile::new(&ProfileSpec {
                continuous_limit_rad: Some(w),
                ..spec.clone()
            })
            .unwrap_err()
            .to_string();
            assert!(e.contains("continuous_limit_rad is"), "{e}");
        }
        let e = RobotProfile::new(&ProfileSpec {
            gripper: Some(GripperSpec {
                joint: "thumb",
                open_rad: 0.0,
                closed_rad: 0.8,
            }),
            ..spec.clone()
        })
        .unwrap_err()
        .to_string();
        assert_eq!(
            e,
            "robot gen3: the gripper joint `thumb` is not a joint of robots/gen3.urdf"
        );
        let e = RobotProfile::new(&ProfileSpec {
            gripper: Some(GripperSpec {
                joint: "finger_joint",
                open_rad: 0.0,
                closed_rad: 0.9,
            }),
            ..spec.clone()
        })
        .unwrap_err()
        .to_string();
        assert_eq!(
            e,
            "robot gen3: the gripper's closed_rad 0.9 is outside the joint `finger_joint`'s range [0, 0.8]"
        );
        // An arm without a gripper is a profile too.
        let bare = RobotProfile::new(&ProfileSpec {
            gripper: None,
            ..spec
        })
        .unwrap();
        assert!(bare.gripper().is_none());
        // The Gen3 lite: no continuous joint, nothing wrapped; its gripper opens at 0.96.
        let lite = RobotProfile::by_name("gen3_lite").unwrap();
        assert!(lite.continuous_joints().iter().all(|c| !c));
        let mut q = [9.0, -9.0, 1.0, 2.0, 3.0, 4.0];
        lite.wrap_for_maps(&mut q);
        assert_eq!(q, [9.0, -9.0, 1.0, 2.0, 3.0, 4.0]);
        let g = lite.gripper().unwrap();
        assert_eq!((g.angle(0.0), g.angle(1.0)), (0.96, -0.09));
        assert_eq!(g.angle(f64::NAN), 0.96);
    }

    /// Another arm is another spec: the planar reaching arm as a profile.
    #[test]
    fn a_profile_from_another_description_and_its_checks() {
        let spec = ProfileSpec::planar5();
        let p = RobotProfile::new(&spec).unwrap();
        assert_eq!(p.n_joints(), 5);
        assert_eq!(p.limits().max_acceleration_rad_s2, [2.0; 5]);
        let e = RobotProfile::new(&ProfileSpec {
            poses: &[("rest", &[0.0; 5])],
            ..spec.clone()
        })
        .unwrap_err();
        assert_eq!(e.to_string(), "robot planar5: there is no `home` pose");
        let e = RobotProfile::new(&ProfileSpec {
            teleop_velocity_rad_s: &[1.0; 4],
            ..spec.clone()
        })
        .unwrap_err();
        assert!(
            e.to_string().contains("teleop_velocity_rad_s needs 5"),
            "{e}"
        );
        let e = RobotProfile::new(&ProfileSpec {
            poses: &[("home", &[9.0; 5])],
            ..spec
        })
        .unwrap_err();
        assert!(e.to_string().contains("pose `home`"), "{e}");
    }
}
