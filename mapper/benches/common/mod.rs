//! A decoder of the paper's size for the benchmarks: m = 6 joints, d = 2, hidden 256 x 256
//! tanh, Gram-Schmidt, random weights from a fixed seed (the cost does not depend on the
//! values), identity-free normalisation.

use mapper::model::{
    EncoderKind, FORMAT, ModelHeader, ModelKind, NetworkInfo, ObsInputs, TrainingInfo, VERSION,
};
use mapper::network::NetworkModel;
use mapper::nn::Mlp;
use mapper::rng::Rng;

pub const M: usize = 6;
pub const D: usize = 2;

pub fn scl_model(gram_schmidt: bool) -> NetworkModel {
    let mut rng = Rng::new(42);
    let decoder = Mlp::init(&[M + 1, 256, 256, M * D], &mut rng);
    let header = ModelHeader {
        format: FORMAT.into(),
        version: VERSION,
        kind: ModelKind::Scl,
        n_joints: M,
        latent_dim: D,
        joint_names: (1..=M).map(|i| format!("joint_{i}")).collect(),
        speed_scale_rad_s: 0.5,
        lipschitz_bound: None,
        network: Some(NetworkInfo {
            inputs: ObsInputs::JointsAndGripper,
            input_mean: vec![0.1; M + 1],
            input_std: vec![0.7; M + 1],
            hidden: vec![256, 256],
            gram_schmidt,
            gs_epsilon: 1e-8,
            encoder: EncoderKind::None,
            encoder_input_mean: Vec::new(),
            encoder_input_std: Vec::new(),
            li_losses: None,
        }),
        training: TrainingInfo::default(),
    };
    match NetworkModel::new(header, decoder, None) {
        Ok(m) => m,
        Err(e) => panic!("benchmark model: {e}"),
    }
}

/// A state and an action that change every call, so nothing is cached.
pub fn inputs(i: usize) -> ([f64; M], f64, [f64; D]) {
    let t = i as f64 * 0.001;
    let q = [
        0.1 + t.sin(),
        -0.3 + 0.5 * t.cos(),
        0.7,
        -0.2 * t.sin(),
        0.4,
        0.05 * t,
    ];
    (
        [q[0], q[1], q[2], q[3], q[4], q[5] % 1.0],
        0.5,
        [0.6 * t.cos(), 0.6 * t.sin()],
    )
}
