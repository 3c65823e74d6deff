//! Action maps: from a 2-D joystick action `a` (`|a| <= 1`) and the robot observation
//! `o = (q, c)` to a joint-velocity command `qdot = s * map(o, a)`.
//!
//! * [`ActionMap`]: the one trait every map implements (PCA now; SCL, CAE and mode switching
//!   join it). Evaluation writes into a caller's buffer and never allocates.
//! * [`pca`]: the paper's linear baseline `qdot = Σ a`, and its fit from demonstrations.
//! * [`model`]: the model file (`*.safetensors` with a JSON header in its metadata) and the
//!   reader that turns a file into a ready [`ActionMap`], refusing bad files at load time.
//! * [`dataset`]: demonstrations as CSV trajectories of `(t, q, c, qdot, cdot)`.
//! * [`demos`]: generated demonstrations (a joint-space reaching set for the bundled model).
//! * [`tasks`]: generated demonstrations of the paper's tasks (table cleaning, pick and place,
//!   pouring on the Gen3 lite; the 5-DOF planar reach) by Cartesian waypoints and DLS.
//! * [`step`]: the mapper process's pure step function, `(RobotState, JoystickInput) ->
//!   MapperCommand`.
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

pub mod dataset;
pub mod demos;
pub mod eval;
pub mod import;
pub mod model;
pub mod network;
pub mod nn;
pub mod pca;
pub mod rng;
pub mod step;
pub mod tasks;
pub mod train;

pub use model::{LoadedModel, ModelError, ModelHeader, ModelKind};

/// A map from action and observation to joint velocity, before the speed scale.
///
/// `eval` is called once per tick on the control path: it must not allocate, block or panic
/// on any finite input. Non-finite inputs never reach it (the step function refuses them).
pub trait ActionMap: Send {
    /// Which kind of model this is.
    fn kind(&self) -> ModelKind;
    /// Number of joints `m` of the output.
    fn n_joints(&self) -> usize;
    /// Dimension `d` of the action.
    fn latent_dim(&self) -> usize;
    /// Writes `map(o, a)` into `out[..n_joints]`, where `o = (q, c)`.
    fn eval(&mut self, q: &[f64], c: f64, a: &[f64], out: &mut [f64]);
}
