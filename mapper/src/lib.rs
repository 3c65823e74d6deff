//! Action maps: from a 2-D joystick action `a` (`|a| <= 1`) and the robot observation
//! `o = (q, c)` to a joint-velocity command `qdot = s * map(o, a)`.
//!
//! * [`ActionMap`]: the one trait every map implements (PCA and mode switching now; SCL and
//!   CAE join it). Evaluation writes into a caller's buffer and never allocates.
//! * [`pca`]: the paper's linear baseline `qdot = Σ a`, and its fit from demonstrations.
//! * [`modeswitch`]: Cartesian mode switching (x-y, z-yaw, roll-pitch) by damped least squares
//!   on the Gen3 lite's Jacobian, with Cartesian speed limits and a slowdown near singularities.
//! * [`constant`]: the drill map (`constant:qdot=...`), one joint velocity whatever the stick.
//! * [`model`]: the model file (`*.safetensors` with a JSON header in its metadata) and the
//!   reader that turns a file into a ready [`ActionMap`], refusing bad files at load time.
//! * [`dataset`]: demonstrations as CSV trajectories of `(t, q, c, qdot, cdot)`.
//! * [`demos`]: generated demonstrations (a joint-space reaching set for the bundled model).
//! * [`tasks`]: generated demonstrations of the paper's tasks (table cleaning, pick and place,
//!   pouring on the Gen3 lite; the 5-DOF planar reach) by Cartesian waypoints and DLS.
//! * [`greedy`]: the paper's simulated greedy user (best of 4096 Gaussian actions per step
//!   towards a goal joint state), batched over the candidates.
//! * [`rollout`]: closed-loop forward-then-reverse runs of a map on a simulated arm (the
//!   proportionality and soft-reversibility experiment).
//! * [`step`]: the mapper process's pure step function, `(RobotState, JoystickInput) ->
//!   MapperCommand`.
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

pub mod constant;
pub mod goto;
pub mod model;
pub mod modeswitch;
pub mod network;
pub mod nn;
pub mod pca;
pub mod rng;
pub mod step;

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
    /// Takes the joystick buttons pressed since the previous tick (the rising edges of
    /// [`ipc_types::buttons`] bits), before this tick's `eval`. Maps without modes ignore
    /// them. Must not allocate.
    fn press(&mut self, _pressed: u32) {}
    /// The current mode, for maps that have modes (mode switching); `None` otherwise.
    fn mode(&self) -> Option<MapMode> {
        None
    }
    /// Whether the output depends on the action. A map that ignores it by design (the drill
    /// map, [`constant`]) says so: its commands carry
    /// [`ipc_types::mapper_flags::IGNORES_INPUT`], so safety does not take a graph without a
    /// joystick sample for a stale one, and with the deadman required re-arms on the deadman
    /// alone after a stop.
    fn uses_input(&self) -> bool {
        true
    }
    /// The joint velocity (before the speed scale) that a full deflection of action axis
    /// `axis` alone asks for at `(q, c)` now, written into `out[..n_joints]`: column `axis`
    /// of `H(o)` for the maps linear in the action (SCL, PCA), `map(o, e_axis)` otherwise.
    /// It leaves the map's memory (mode, last command) as it was, so an observer can draw
    /// the map's directions beside the served map. The default evaluates `e_axis`, exact for
    /// every map without memory; mode switching overrides it (its current mode's axis twist
    /// at full speed through the Jacobian, without the ramp from the last command). An axis
    /// outside the action gives zeros.
    fn direction(&mut self, q: &[f64], c: f64, axis: usize, out: &mut [f64]) {
        let mut a = [0.0; ipc_types::ACTION_DIM];
        match a.get_mut(axis) {
            Some(v) => *v = 1.0,
            None => {
                out.iter_mut().for_each(|v| *v = 0.0);
                return;
            }
        }
        self.eval(q, c, &a, out);
    }

    /// Takes the graph's tick period (`[graph] rate_hz`), once at load, before the first
    /// `eval`. Maps whose rules depend on the period (the acceleration per tick of mode
    /// switching) follow it; the others ignore it.
    fn set_period(&mut self, _period_s: f64) {}
}

/// The operating mode of a map that has modes, as the mapper's status reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MapMode {
    /// Index of the current mode, from 0.
    pub index: u32,
    /// Its name (`x-y`, `z-yaw`, `roll-pitch` for mode switching).
    pub name: &'static str,
    /// Mode switches since the map was loaded.
    pub switches: u32,
}
