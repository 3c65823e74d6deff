//! The study models the repository ships (`models/study/`, what `examples/study/study1.toml`
//! and `study2.toml` serve) are the ones `scripts/study-models.sh` produces: each was trained
//! on the demonstrations `scl demos --task T --seed 1` generates (the data hash in its header),
//! the networks at the paper's settings, and each PCA model is byte for byte what fitting it
//! again gives (PCA is deterministic; the networks' training is deterministic per seed too, but
//! ten seeds of 200 epochs per model do not belong in a test run).
#![allow(clippy::unwrap_used)]

use std::path::{Path, PathBuf};

use learning::dataset;
use learning::tasks::Task;
use learning::tools::{TrainOptions, train_pca};
use mapper::model::{ModelKind, read_header};

const TASKS: [&str; 3] = ["table-cleaning", "pick-and-place", "pouring"];

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

#[test]
fn the_shipped_study_models_are_what_the_script_makes() {
    let tmp = std::env::temp_dir().join(format!("scl-study-models-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    for task in TASKS {
        let t = Task::from_name(task).unwrap();
        let (n_train, n_val) = t.default_counts();
        let data = tmp.join(task);
        dataset::write_dir(
            &data,
            &learning::tasks::generate(t, n_train, n_val, 1).unwrap(),
        )
        .unwrap();
        let ds = dataset::load(&data).unwrap();
        for kind in ["pca", "scl", "cae"] {
            let path = repo().join(format!("models/study/{kind}-{task}.safetensors"));
            let bytes = std::fs::read(&path)
                .unwrap_or_else(|e| panic!("{}: {e} (scripts/study-models.sh)", path.display()));
            let h = read_header(&bytes, &path).unwrap();
            let what = path.display();
            assert_eq!(
                h.training.data_hash, ds.hash,
                "{what}: trained on other data"
            );
            assert_eq!(
                (h.training.n_train, h.training.n_val),
                (ds.n_train(), ds.n_val())
            );
            assert_eq!(h.latent_dim, 2, "{what}");
            if kind == "pca" {
                assert_eq!(h.kind, ModelKind::Pca);
                // Fitted again on the regenerated data, with the command the file records.
                let again = tmp.join(format!("pca-{task}.safetensors"));
                train_pca(&TrainOptions {
                    data: &data,
                    out: &again,
                    latent_dim: 2,
                    speed_scale: None,
                    force: false,
                    command: h.training.command.clone(),
                    lerobot: Default::default(),
                })
                .unwrap();
                assert!(
                    std::fs::read(&again).unwrap() == bytes,
                    "{what}: not what PCA fits"
                );
                continue;
            }
            // The networks: the paper's settings (d = 2, 2 x 256, 200 epochs, best of 10
            // seeds; SCL with Gram-Schmidt and the Lipschitz bound 1).
            let net = h.network.as_ref().unwrap();
            let s = h.training.settings.as_ref().unwrap();
            assert_eq!(net.hidden, [256, 256], "{what}");
            assert_eq!((s.epochs, s.seeds), (200, 10), "{what}");
            if kind == "scl" {
                assert_eq!(h.kind, ModelKind::Scl, "{what}");
                assert!(net.gram_schmidt, "{what}");
                assert_eq!(h.lipschitz_bound, Some(1.0), "{what}");
            } else {
                assert_eq!(h.kind, ModelKind::Cae, "{what}");
            }
        }
    }
    std::fs::remove_dir_all(&tmp).unwrap();
}
