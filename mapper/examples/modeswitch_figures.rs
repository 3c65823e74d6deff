//! Figures of the mode-switching map on the Gen3 lite, for the record:
//!
//! * cross-talk per mode and input direction: the TCP motion of one tick (the joint command
//!   held for 25 ms, as the arm executes it, once the twist has ramped up) against the twist
//!   asked, and the TCP motion over 0.5 s and 1 s of full deflection from rest, integrated at
//!   40 Hz like the mock arm (`q += qdot dt`), split into the intended axis and the rest, with
//!   the twist reached;
//! * the Jacobian's condition number at the named poses and the slowdown it gives;
//! * the cost of one evaluation (Jacobian, condition number, damped least squares).
//!
//! `cargo run --release -p mapper --example modeswitch_figures`
#![allow(clippy::unwrap_used)]

use std::time::Instant;

use kinematics::{Gen3Lite, gen3_lite, pose_error};
use mapper::ActionMap;
use mapper::modeswitch::{Mode, ModeSwitchMap, ModeSwitchParams, SPEC};
use nalgebra::DVector;

const DT: f64 = 0.025;

fn main() {
    let arm = Gen3Lite::get().arm();
    let params = ModeSwitchParams::default();
    println!(
        "cross-talk from home, full deflection (one tick vs the asked twist; 0.5 s, 1 s at 40 Hz)"
    );
    println!(
        "{:<11} {:>6} {:>5}  {:>12}  {:>10} {:>12} {:>14}",
        "mode", "input", "time", "one-tick err", "along", "other lin", "other ang"
    );
    for mode in Mode::ALL {
        for ((label, a), ticks) in [("a0", [1.0, 0.0]), ("a1", [0.0, 1.0])]
            .into_iter()
            .flat_map(|x| [(x, 20), (x, 40)])
        {
            let mut map = ModeSwitchMap::new(params.clone(), SPEC).unwrap();
            while map.current_mode() != mode {
                map.press(ipc_types::buttons::MODE);
            }
            let mut q = gen3_lite::HOME;
            let mut qd = [0.0; 6];
            // One tick, once the twist has ramped up (at a fixed pose).
            let mut steady = map.clone();
            for _ in 0..400 {
                steady.eval(&q, 0.0, &a, &mut qd);
            }
            let asked = DVector::from_column_slice(&steady.diagnostics().twist);
            let mut next = q;
            for i in 0..6 {
                next[i] += qd[i] * DT;
            }
            let got = pose_error(&arm.fk(&q).unwrap(), &arm.fk(&next).unwrap()) / DT;
            let instant =
                (DVector::from_column_slice(got.as_slice()) - &asked).norm() / asked.norm();
            let start = arm.fk(&q).unwrap();
            for _ in 0..ticks {
                map.eval(&q, 0.0, &a, &mut qd);
                for i in 0..6 {
                    q[i] += qd[i] * DT;
                }
            }
            let e = pose_error(&start, &arm.fk(&q).unwrap());
            let row = mode.rows()[if label == "a0" { 0 } else { 1 }];
            let along = e[row];
            let (mut lin, mut ang) = (0.0, 0.0);
            for r in 0..6 {
                if r == row {
                    continue;
                }
                if r < 3 {
                    lin += e[r] * e[r];
                } else {
                    ang += e[r] * e[r];
                }
            }
            let reached = map.diagnostics().twist[row];
            println!(
                "{:<11} {:>6} {:>4.1}s  {:>12.2e}  {:>10.4} {:>9.2} mm {:>9.2} mrad {:>8.3}",
                mode.name(),
                label,
                ticks as f64 * DT,
                instant,
                along,
                lin.sqrt() * 1e3,
                ang.sqrt() * 1e3,
                reached
            );
        }
    }

    println!("\ncondition number, slowdown and joint-speed fit at the named poses");
    let mut qd = [0.0; 6];
    for (name, q) in [
        ("home", gen3_lite::HOME),
        ("retract", gen3_lite::RETRACT),
        ("zero+1e-3", [0.0, 1e-3, 0.0, 0.0, 1e-3, 0.0]),
        ("stretched", [0.0, 1.2, 0.2, 0.0, 0.2, 0.0]),
        ("wrist flat", [0.0, -0.28, 1.309, 0.0, 0.02, 0.0]),
    ] {
        let mut m = ModeSwitchMap::new(params.clone(), SPEC).unwrap();
        m.eval(&q, 0.0, &[1.0, 0.0], &mut qd);
        let d = m.diagnostics();
        println!(
            "{name:<11} condition {:>10.1}  slowdown {:.2}  fit {:.2}  sigma_min {:.4}",
            d.condition, d.slowdown, d.joint_speed_fit, d.sigma_min
        );
    }

    let mut map = ModeSwitchMap::new(params.clone(), SPEC).unwrap();
    let n = 200_000;
    let mut q = gen3_lite::HOME;
    let t0 = Instant::now();
    let mut acc = 0.0;
    for k in 0..n {
        q[0] = 1e-6 * k as f64;
        let th = k as f64 * 1e-3;
        map.eval(&q, 0.0, &[th.cos(), th.sin()], &mut qd);
        acc += qd[0];
    }
    let per = t0.elapsed().as_secs_f64() / n as f64;
    println!(
        "\neval cost: {:.2} µs per evaluation ({n} evaluations, checksum {acc:.3})",
        per * 1e6
    );
}
