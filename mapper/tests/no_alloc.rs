//! The mapper's tick never touches the heap: `MapperStep::step` with every kind of model
//! (SCL with and without Gram-Schmidt, CAE, PCA) is run under a counting global allocator.
//! The allocator (`test_support`) counts only the test's own thread.
#![allow(missing_docs, clippy::unwrap_used)]

use std::path::Path;

use ipc_types::{JoystickInput, RobotState};
use mapper::LoadedModel;
use mapper::model::{
    EncoderKind, FORMAT, ModelHeader, ModelKind, NetworkInfo, ObsInputs, TrainingInfo, VERSION,
};
use mapper::network::NetworkModel;
use mapper::nn::Mlp;
use mapper::rng::Rng;
use mapper::step::MapperStep;
use test_support::count_allocations;

#[global_allocator]
static ALLOCATOR: test_support::CountingAllocator = test_support::CountingAllocator;

fn network_model(kind: ModelKind, gram_schmidt: bool) -> NetworkModel {
    let (m, d) = (6, 2);
    let mut rng = Rng::new(7);
    let sizes: Vec<usize> = match kind {
        ModelKind::Cae => vec![m + 1 + d, 256, 256, m],
        _ => vec![m + 1, 256, 256, m * d],
    };
    let header = ModelHeader {
        format: FORMAT.into(),
        version: VERSION,
        kind,
        n_joints: m,
        latent_dim: d,
        joint_names: (1..=m).map(|i| format!("joint_{i}")).collect(),
        speed_scale_rad_s: 0.5,
        lipschitz_bound: None,
        network: Some(NetworkInfo {
            inputs: ObsInputs::JointsAndGripper,
            input_mean: vec![0.0; m + 1],
            input_std: vec![1.0; m + 1],
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
    NetworkModel::new(header, Mlp::init(&sizes, &mut rng), None).unwrap()
}

fn network(kind: ModelKind, gram_schmidt: bool) -> LoadedModel {
    let model = network_model(kind, gram_schmidt);
    LoadedModel::from_bytes(&model.to_bytes().unwrap(), Path::new("test")).unwrap()
}

/// A PCA model file's bytes, loaded as the mapper loads any file: one basis column moves
/// joint 1, the other joints 2 and 3 against each other (orthonormal columns).
fn pca() -> LoadedModel {
    let (m, d) = (6, 2);
    let h = std::f32::consts::FRAC_1_SQRT_2;
    // Row-major m x d.
    let basis = vec![1.0, 0.0, 0.0, h, 0.0, -h, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    let mut header = network_model(ModelKind::Scl, true).header().clone();
    header.kind = ModelKind::Pca;
    header.network = None;
    let bytes = mapper::model::to_bytes(&header, &[(mapper::pca::BASIS_TENSOR, vec![m, d], basis)])
        .unwrap();
    LoadedModel::from_bytes(&bytes, Path::new("pca")).unwrap()
}

fn joystick(i: usize) -> JoystickInput {
    let t = i as f32 * 0.01;
    JoystickInput {
        tick: i as u64,
        t_ns: 0,
        seq: i as u64,
        // Some samples beyond the unit disc, so the clamping path runs too.
        axes: [1.3 * t.cos(), 1.3 * t.sin()],
        gripper: 0.2,
        buttons: 0,
    }
}

#[test]
fn the_counter_sees_allocations() {
    // Without this the test below could pass with a broken counter.
    let n = count_allocations(|| {
        let v: Vec<u64> = std::hint::black_box(Vec::with_capacity(4));
        drop(v);
    });
    assert_eq!(n, 1);
}

#[test]
fn mapper_step_never_allocates() {
    let models = [
        ("scl", network(ModelKind::Scl, true)),
        ("scl without Gram-Schmidt", network(ModelKind::Scl, false)),
        ("cae", network(ModelKind::Cae, false)),
        ("pca", pca()),
        (
            "bundled (scl)",
            LoadedModel::load(mapper::model::BUNDLED_NAME).unwrap(),
        ),
    ];
    for (name, model) in models {
        let mut step = MapperStep::new(1, model, 6).unwrap();
        let mut state = RobotState::at_rest(0, 0, 6);
        let mut moved = 0.0;
        let n = count_allocations(|| {
            for i in 0..100 {
                state.tick = i as u64;
                state.q_rad[0] = (i as f64 * 0.01).sin();
                let cmd = step.step(&state, Some(&joystick(i)));
                moved += cmd.qdot_rad_s.iter().map(|v| v.abs()).sum::<f64>();
                // No input and a bad state take their own paths.
                std::hint::black_box(step.step(&state, None));
            }
        });
        assert_eq!(n, 0, "{name}: {n} allocations in 200 steps");
        assert!(moved > 0.0, "{name}: the map produced no motion");
    }
}

#[test]
fn both_kernels_evaluate_without_allocating() {
    use mapper::ActionMap;
    use mapper::nn::Kernel;
    for kernel in [Kernel::portable(), Kernel::detect()] {
        let mut map = network_model(ModelKind::Scl, true).scl_map().unwrap();
        map.set_kernel(kernel);
        let mut out = [0.0; 6];
        let n = count_allocations(|| {
            for i in 0..100 {
                let q = [0.01 * i as f64, 0.2, -0.3, 0.4, 0.0, 0.1];
                map.eval(&q, 0.5, &[0.3, -0.4], &mut out);
            }
        });
        assert_eq!(n, 0, "{kernel:?}: {n} allocations");
        assert!(out.iter().any(|v| *v != 0.0));
    }
}
