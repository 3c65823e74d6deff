//! Quick versions of the experiments on tiny settings: they check the direction of each
//! result, that a second run resumes from the cached models, and that a mismatching or
//! corrupt cached model is a clear error.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::time::SystemTime;

use crate::tasks::Task;
use mapper::model::ModelKind;

use super::greedy_user::{GreedyUserArgs, Metric};
use super::reconstruction::ReconstructionArgs;
use super::reversibility::ReversibilityArgs;
use super::theorem::TheoremArgs;
use super::*;

/// A small pick-and-place data set (2 train, 1 val trajectories), generated once.
fn data() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let d = std::env::temp_dir().join(format!("scl-exp-data-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        let ds = crate::tasks::generate(Task::PickAndPlace, 2, 1, 1).unwrap();
        dataset::write_dir(&d.join("pick-and-place"), &ds).unwrap();
        d
    })
}

/// A small planar-reach data set (8 train, 2 val trajectories), generated once.
fn planar_data() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let d = std::env::temp_dir().join(format!("scl-exp-planar-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        let ds = crate::tasks::generate(Task::PlanarReach, 8, 2, 1).unwrap();
        dataset::write_dir(&d.join("planar-reach"), &ds).unwrap();
        d
    })
}

fn out_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("scl-exp-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn common(out: &Path, seeds: usize, epochs: usize) -> CommonArgs {
    CommonArgs {
        out: out.to_owned(),
        seeds,
        epochs: Some(epochs),
        threads: 2,
        data: Some(data().to_owned()),
        models: Vec::new(),
        hidden: "16,16".into(),
        robot: kinematics::RobotProfile::default_robot(),
    }
}

fn mtimes(dir: &Path) -> Vec<(PathBuf, SystemTime)> {
    let mut v = Vec::new();
    let mut stack = vec![dir.to_owned()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|x| x == "safetensors") {
                let t = std::fs::metadata(&p).unwrap().modified().unwrap();
                v.push((p, t));
            }
        }
    }
    v.sort();
    v
}

fn mean_reverse(c: &[reversibility::Point]) -> f64 {
    let moving: Vec<_> = c.iter().filter(|p| p.alpha > 0.0).collect();
    moving.iter().map(|p| p.reverse_mean).sum::<f64>() / moving.len() as f64
}

#[test]
fn reversibility_quick_has_the_expected_direction_and_resumes() {
    let out = out_dir("rev");
    let mut args = ReversibilityArgs {
        common: common(&out, 2, 5),
        task: "pick-and-place".into(),
        states: 3,
        alphas: 3,
        seed: 1,
    };
    let o = reversibility::run(&args, 0.025, "test").unwrap();
    let scl = o.curve(ModelKind::Scl).unwrap();
    let cae = o.curve(ModelKind::Cae).unwrap();
    let pca = o.curve(ModelKind::Pca).unwrap();
    assert_eq!(scl.len(), 3);
    assert_eq!(scl[2].n, 2 * 3);
    // PCA returns exactly; SCL moves and comes back closer than CAE.
    // (Runs that reach a joint limit are clamped by the mock and excluded.)
    assert!(pca.iter().all(|p| p.reverse_max_inside < 1e-9), "{pca:?}");
    assert!(pca.iter().all(|p| p.limited < p.n), "{pca:?}");
    assert!(pca[2].forward_mean > 0.01 && scl[2].forward_mean > 0.01);
    assert!(
        mean_reverse(scl) < mean_reverse(cae),
        "scl {scl:?}\ncae {cae:?}"
    );
    // Proportionality: PCA's forward distance doubles from alpha 0.5 to 1.
    assert!((pca[1].forward_mean / 0.5 - pca[2].forward_mean).abs() < 0.05 * pca[2].forward_mean);
    for f in [
        "runs.csv",
        "curves.csv",
        "summary.md",
        "reversibility.png",
        "reversibility.svg",
    ] {
        assert!(out.join(f).is_file(), "{f}");
    }
    let runs = std::fs::read_to_string(out.join("runs.csv")).unwrap();
    assert_eq!(runs.lines().count(), 1 + 3 * 2 * 3 * 3);
    let summary = std::fs::read_to_string(out.join("summary.md")).unwrap();
    assert!(summary.contains("PCA returns exactly") && summary.contains("identical"));
    let models = out.join("models/pick-and-place");
    assert!(models.join("scl/seed-1.safetensors").is_file());
    // The rollout's command is the served path's: MapperStep on the same model file.
    let file = models.join("scl/seed-0.safetensors");
    let any = load_model(&file).unwrap();
    let mut map = any.map();
    let mut step = mapper::step::MapperStep::new(
        1,
        mapper::LoadedModel::load(file.to_str().unwrap()).unwrap(),
        6,
    )
    .unwrap();
    let ds = dataset::load_dir(&data().join("pick-and-place")).unwrap();
    for (k, a) in [[0.5f32, -0.75], [1.5, 2.0], [0.0, 0.0]].iter().enumerate() {
        let t = &ds.val[0];
        let mut state = ipc_types::RobotState::at_rest(10, 0, 6);
        state.q_rad[..6].copy_from_slice(&t.q[k * 7]);
        state.gripper = t.c[k * 7];
        let joy = ipc_types::JoystickInput {
            tick: ipc_types::NO_TICK,
            t_ns: 0,
            seq: 1,
            axes: *a,
            gripper: 0.0,
            buttons: 0,
        };
        let served = step.step(&state, Some(&joy));
        let mut out = [0.0; 6];
        let s = any.header().speed_scale_rad_s;
        crate::rollout::served_command(
            map.as_mut(),
            s,
            &t.q[k * 7],
            t.c[k * 7],
            &[f64::from(a[0]), f64::from(a[1])],
            &mut out,
        );
        for i in 0..6 {
            assert!(
                (served.qdot_rad_s[i] - out[i]).abs() < 1e-12,
                "{a:?}: {served:?} vs {out:?}"
            );
        }
    }
    // A second run trains nothing and measures the same.
    let before = mtimes(&out);
    assert_eq!(before.len(), 3 * 2);
    let again = reversibility::run(&args, 0.025, "test").unwrap();
    assert_eq!(mtimes(&out), before);
    assert_eq!(again.curves, o.curves);
    // Other settings against the cache: a clear error naming the file, nothing replaced.
    args.common.epochs = Some(6);
    let e = reversibility::run(&args, 0.025, "test")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("seed-0.safetensors") && e.contains("pick another --out"),
        "{e}"
    );
    assert_eq!(mtimes(&out), before);
    std::fs::remove_dir_all(&out).unwrap();
}

#[test]
fn theorem_quick_holds_without_gram_schmidt() {
    let out = out_dir("theorem");
    let args = TheoremArgs {
        common: common(&out, 2, 5),
        task: "pick-and-place".into(),
        samples: 300,
        seed: 1,
    };
    let o = theorem::run(&args, 0.025, "test").unwrap();
    assert!(o.theorem_holds);
    let no_gs: Vec<_> = o.rows.iter().filter(|r| r.group == "scl-no-gs").collect();
    assert_eq!(no_gs.len(), 4);
    for r in &no_gs {
        assert!(r.theorem_applies, "{r:?}");
        assert!(r.fraction.total > 500, "{r:?}");
        assert_eq!(r.fraction.held, r.fraction.total, "{r:?}");
        assert!(r.fraction.worst_ratio < 1.0);
    }
    // CAE is not soft-reversible: somewhere the inequality fails.
    let cae_fails = o
        .rows
        .iter()
        .filter(|r| r.group == "cae")
        .any(|r| r.fraction.held < r.fraction.total);
    assert!(cae_fails, "{:?}", o.rows);
    assert!(
        o.rows
            .iter()
            .filter(|r| r.group != "scl-no-gs")
            .all(|r| !r.theorem_applies)
    );
    let summary = std::fs::read_to_string(out.join("summary.md")).unwrap();
    assert!(summary.contains("as it must"), "{summary}");
    // The same check on a given file (the former `scl eval reversibility --model`).
    let file = out.join("models/pick-and-place/scl-no-gs/seed-0.safetensors");
    let given = TheoremArgs {
        common: CommonArgs {
            models: vec![file],
            data: Some(data().join("pick-and-place")),
            ..common(&out_dir("theorem-given"), 2, 5)
        },
        ..args
    };
    let g = theorem::run(&given, 0.025, "test").unwrap();
    assert!(g.theorem_holds && g.rows.len() == 4 && g.rows.iter().all(|r| r.theorem_applies));
    std::fs::remove_dir_all(&out).unwrap();
    std::fs::remove_dir_all(&given.common.out).unwrap();
}

#[test]
fn reconstruction_reuses_prepopulated_models_and_refuses_bad_ones() {
    let out = out_dir("recon");
    let models = out.join("models/pick-and-place");
    std::fs::create_dir_all(&models).unwrap();
    // As scripts/learning-table.sh leaves it.
    let pca = models.join("pca.safetensors");
    crate::tools::train_pca(&crate::tools::TrainOptions {
        data: &data().join("pick-and-place"),
        out: &pca,
        latent_dim: 2,
        speed_scale: None,
        force: false,
        command: "scl train --kind pca".into(),
        lerobot: Default::default(),
    })
    .unwrap();
    let t0 = std::fs::metadata(&pca).unwrap().modified().unwrap();
    let args = ReconstructionArgs {
        common: CommonArgs {
            ..common(&out, 1, 30)
        },
        tasks: "pick-and-place".into(),
    };
    let o = reconstruction::run(&args, "test").unwrap();
    assert_eq!(std::fs::metadata(&pca).unwrap().modified().unwrap(), t0);
    let names: Vec<&str> = o.entries.iter().map(|e| e.variant.as_str()).collect();
    assert_eq!(names, Variant::ALL.map(Variant::name));
    // Every model reconstructs better than the zero map (the mean square of qdot).
    let ds = dataset::load_dir(&data().join("pick-and-place")).unwrap();
    let zero: f64 = ds.val_qdot().iter().flatten().map(|v| v * v).sum::<f64>()
        / ds.val_qdot().iter().flatten().count() as f64;
    for e in &o.entries {
        assert!(e.val_mse > 0.0 && e.val_mse < zero, "{e:?} vs {zero}");
    }
    assert!(models.join("scl.loss.png").is_file());
    for f in [
        "reconstruction.csv",
        "reconstruction.md",
        "reconstruction.png",
        "reconstruction.svg",
        "summary.md",
    ] {
        assert!(out.join(f).is_file(), "{f}");
    }
    let csv = std::fs::read_to_string(out.join("reconstruction.csv")).unwrap();
    assert!(
        csv.lines()
            .nth(2)
            .unwrap()
            .starts_with("pick-and-place,scl,\"scl, hidden 16x16, GS"),
        "{csv}"
    );
    // A corrupt cached model is named.
    std::fs::write(models.join("cae.safetensors"), b"not a model").unwrap();
    let e = reconstruction::run(&args, "test").unwrap_err().to_string();
    assert!(
        e.contains("cae.safetensors") && e.contains("unusable"),
        "{e}"
    );
    // Data without a validation split is refused, naming it.
    let bad = out.join("no-val");
    dataset::write_dir(
        &bad.join("pick-and-place"),
        &dataset::Dataset {
            val: Vec::new(),
            ..ds.clone()
        },
    )
    .unwrap();
    let e = reconstruction::run(
        &ReconstructionArgs {
            common: CommonArgs {
                data: Some(bad.clone()),
                ..args.common.clone()
            },
            ..args.clone()
        },
        "test",
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("no-val") && e.contains("validation"), "{e}");
    std::fs::remove_dir_all(&out).unwrap();
}

fn greedy_cache_mtimes(dir: &Path) -> Vec<(PathBuf, SystemTime)> {
    let mut v = Vec::new();
    for g in std::fs::read_dir(dir.join("greedy")).unwrap() {
        for f in std::fs::read_dir(g.unwrap().path()).unwrap() {
            let p = f.unwrap().path();
            let t = std::fs::metadata(&p).unwrap().modified().unwrap();
            v.push((p, t));
        }
    }
    v.sort();
    v
}

#[test]
fn greedy_user_quick_scl_returns_closer_than_cae_and_resumes() {
    let out = out_dir("greedy");
    let mut args = GreedyUserArgs {
        common: CommonArgs {
            data: Some(planar_data().to_owned()),
            ..common(&out, 2, 30)
        },
        test_trajectories: 3,
        candidates: 256,
        horizon: 1.5,
        no_clip: false,
        seed: 2,
        variants: "scl,scl-no-gs,cae,cae-li-rev".into(),
    };
    let o = greedy_user::run(&args, "test").unwrap();
    let names: Vec<&str> = o.groups.iter().map(|g| g.name.as_str()).collect();
    assert_eq!(names, ["scl", "scl-no-gs", "cae", "cae-li-rev"]);
    for g in &o.groups {
        assert_eq!(g.models.len(), 2, "{}", g.name);
        assert!(g.models.iter().all(|m| m.rows.len() == 3));
        assert!(g.errors(Metric::Return).iter().all(|e| e.is_finite()));
    }
    // The best CAE configuration by validation loss is one of the two CAE groups.
    let best = o.best_cae.unwrap();
    assert!(o.groups[best].name.starts_with("cae"));
    // The paper's direction: SCL (both versions) returns closer to the start than CAE, and it
    // gets closer to the end state than it started.
    let scl = o.group("scl").unwrap();
    let no_gs = o.group("scl-no-gs").unwrap();
    for cae in [o.group("cae").unwrap(), &o.groups[best]] {
        assert!(
            scl.median(Metric::Return) < cae.median(Metric::Return)
                && no_gs.median(Metric::Return) < cae.median(Metric::Return),
            "scl {} / {}, {} {}",
            scl.median(Metric::Return),
            no_gs.median(Metric::Return),
            cae.name,
            cae.median(Metric::Return)
        );
    }
    let start = scl.models[0].rows[0].start_distance;
    assert!(scl.median(Metric::Forward) < 0.5 * start, "{scl:?}");
    assert!(o.checks[0].holds, "{:?}", o.checks);
    // The tests ran on the paper's three groups.
    let f = o
        .family("paper", Metric::Return, greedy_user::Unit::Trajectory)
        .unwrap();
    let t = f.tests.as_ref().unwrap();
    assert_eq!((t.kruskal.df, t.kruskal.n, t.dunn.len()), (2, 18, 3));
    assert!(t.kruskal.h > 0.0 && t.kruskal.p > 0.0 && t.kruskal.p < 1.0);
    for f in [
        "errors.csv",
        "models.csv",
        "groups.csv",
        "stats.csv",
        "summary.md",
        "greedy-user.png",
        "greedy-user.svg",
    ] {
        assert!(out.join(f).is_file(), "{f}");
    }
    let errors = std::fs::read_to_string(out.join("errors.csv")).unwrap();
    assert_eq!(errors.lines().count(), 1 + 4 * 2 * 3);
    assert!(
        errors.lines().all(|l| l.split(',').count() == 8),
        "{errors}"
    );
    let stats = std::fs::read_to_string(out.join("stats.csv")).unwrap();
    // 2 families x 2 metrics x 2 units, each one Kruskal-Wallis row.
    assert_eq!(stats.matches(",kruskal-wallis,").count(), 8, "{stats}");
    assert!(
        stats.contains("paper,back-to-start,model-mean,dunn,scl,cae"),
        "{stats}"
    );
    let summary = std::fs::read_to_string(out.join("summary.md")).unwrap();
    assert!(summary.contains("Kruskal-Wallis H =") && summary.contains("best CAE by val. loss"));
    // A second run trains and evaluates nothing and measures the same.
    let models = mtimes(&out);
    let evals = greedy_cache_mtimes(&out);
    assert_eq!((models.len(), evals.len()), (8, 8));
    let again = greedy_user::run(&args, "test").unwrap();
    assert_eq!(mtimes(&out), models);
    assert_eq!(greedy_cache_mtimes(&out), evals);
    assert_eq!(again.groups, o.groups);
    // Other evaluation settings: the models are reused, the evaluations redone.
    args.candidates = 64;
    let other = greedy_user::run(&args, "test").unwrap();
    assert_eq!(mtimes(&out), models);
    assert_ne!(other.groups, o.groups);
    std::fs::remove_dir_all(&out).unwrap();
}

#[test]
fn a_file_in_place_of_the_output_directory_is_refused() {
    let f = out_dir("file");
    std::fs::write(&f, b"x").unwrap();
    let e = Run::new("t", &common(&f, 1, 1), 1, "t")
        .unwrap_err()
        .to_string();
    assert!(e.contains("--out") && e.contains("not a directory"), "{e}");
    std::fs::remove_file(&f).unwrap();
}

/// `--robot gen3`: reconstruction and reversibility on the Gen3, its demonstrations generated
/// into the output directory (`scl demos --robot gen3`), every kind trained on seven joints,
/// the rollouts on its mock arm; a planar task is refused for the mock arm.
#[test]
fn the_experiments_run_on_the_gen3() {
    let gen3 = kinematics::RobotProfile::by_name("gen3").unwrap();
    let out = out_dir("gen3");
    let on_gen3 = |seeds, epochs| CommonArgs {
        data: None,
        robot: gen3,
        ..common(&out, seeds, epochs)
    };
    let o = reconstruction::run(
        &ReconstructionArgs {
            common: on_gen3(1, 3),
            tasks: "pick-and-place".into(),
        },
        "test",
    )
    .unwrap();
    assert_eq!(o.entries.len(), Variant::ALL.len());
    assert!(
        o.entries.iter().all(|e| e.val_mse.is_finite()),
        "{:?}",
        o.entries
    );
    for e in &o.entries {
        let m = load_model(&e.path).unwrap();
        assert_eq!(m.header().n_joints, 7, "{}", e.variant);
    }
    let summary = std::fs::read_to_string(out.join("summary.md")).unwrap();
    assert!(
        summary.starts_with("# Validation reconstruction loss on the Gen3's tasks"),
        "{summary}"
    );
    let data = dataset::load_dir(&out.join("data/pick-and-place")).unwrap();
    // The paper's counts at its pace, stretched into the arm's envelope.
    assert!(
        data.n_train() >= 2001 && data.n_val() >= 667,
        "{} {}",
        data.n_train(),
        data.n_val()
    );
    let args = ReversibilityArgs {
        common: on_gen3(1, 3),
        task: "pick-and-place".into(),
        states: 2,
        alphas: 3,
        seed: 1,
    };
    let r = reversibility::run(&args, 0.025, "test").unwrap();
    let pca = r.curve(ModelKind::Pca).unwrap();
    assert!(pca.iter().all(|p| p.reverse_max_inside < 1e-9), "{pca:?}");
    assert!(pca[2].forward_mean > 0.01, "{pca:?}");
    let summary = std::fs::read_to_string(out.join("summary.md")).unwrap();
    assert!(summary.contains("on the mock Gen3\n"), "{summary}");
    // The theorem's check on the same models, its uniform states within the Gen3's limits.
    let t = theorem::run(
        &TheoremArgs {
            common: on_gen3(1, 3),
            task: "pick-and-place".into(),
            samples: 100,
            seed: 1,
        },
        0.025,
        "test",
    )
    .unwrap();
    assert!(t.theorem_holds, "{:?}", t.rows);
    assert!(t.rows.iter().any(|r| r.states == "uniform"), "{:?}", t.rows);
    let summary = std::fs::read_to_string(out.join("summary.md")).unwrap();
    assert!(
        summary.contains("within the Gen3's joint limits"),
        "{summary}"
    );
    let e = reversibility::run(
        &ReversibilityArgs {
            task: "planar-reach".into(),
            ..args
        },
        0.025,
        "test",
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("planar"), "{e}");
    std::fs::remove_dir_all(&out).unwrap();
}
