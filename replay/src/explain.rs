//! `scl replay RUN.mcap --tick K --explain`: one tick of a replay spelled out: the inputs,
//! the map's output, what each safety rule did and the final command.

use ipc_types::{mapper_flags, safe_control, safe_flags};

use crate::{TickTrace, bit_names, mapper_diff, safe_diff};

fn joints(v: &[f64], n: usize) -> String {
    v.iter()
        .take(n)
        .map(|x| format!("{x:+.5}"))
        .collect::<Vec<_>>()
        .join(" ")
}

/// What each flag of the safety filter means, as the explanation says it.
fn rule_line(bit: u32) -> &'static str {
    match bit {
        safe_flags::NON_FINITE => "a non-finite value in the command or state: stop",
        safe_flags::STALE_STATE => "the robot state was older than max_state_age_ms: stop",
        safe_flags::STALE_JOYSTICK => "the joystick sample was stale or missing: stop",
        safe_flags::STALE_COMMAND => "the command was not for the newest tick: stop",
        safe_flags::VELOCITY_SCALED => "scaled uniformly into the joint speed limits",
        safe_flags::STOP => "the output is a controlled stop",
        safe_flags::BAD_SHAPE => "the joint count did not match the robot: stop",
        safe_flags::ACCEL_LIMITED => "the change was scaled into the acceleration limits",
        safe_flags::HOLD => "the supervisor held the arm: stop",
        safe_flags::POSITION_LIMITED => "braking before a joint's limit margin",
        safe_flags::WORKSPACE_LIMITED => "braking before a workspace bound of the tool",
        safe_flags::DEADMAN => "the deadman was required and not held: stop",
        safe_flags::ESTOP => "the e-stop was latched: zero at once",
        safe_flags::AWAITING_NEUTRAL => {
            "restart prevention: waiting for the input to pass through neutral"
        }
        safe_flags::CLEARANCE_LIMITED => {
            "a pair of the collision model was approaching: slowed / braked"
        }
        safe_flags::SPEED_CAPPED => "scaled into the Cartesian speed caps",
        _ => "",
    }
}

/// The explanation of one replayed tick, as text.
pub fn render(t: &TickTrace) -> String {
    let mut s = String::new();
    let n = t.state.n_joints as usize;
    push_inputs(&mut s, t, n);
    push_map(&mut s, t, n);
    push_safety(&mut s, t, n);
    push_command(&mut s, t, n);
    s
}

/// The tick's inputs: the robot state, the joystick sample and the control bits.
fn push_inputs(s: &mut String, t: &TickTrace, n: usize) {
    use std::fmt::Write as _;
    let st = &t.state;
    let _ = writeln!(s, "tick {}", st.tick);
    let _ = writeln!(s, "inputs");
    let _ = writeln!(
        s,
        "  robot state   t_ns {}  applied_tick {}  flags [{}]",
        st.t_ns,
        if st.applied_tick == ipc_types::NO_TICK {
            "none".to_owned()
        } else {
            st.applied_tick.to_string()
        },
        bit_names(st.flags, &ipc_types::state_flags::NAMES).join(", ")
    );
    let _ = writeln!(s, "    q (rad)     {}", joints(&st.q_rad, n));
    let _ = writeln!(s, "    qdot (rad/s) {}", joints(&st.qdot_rad_s, n));
    let _ = writeln!(s, "    gripper     {:.4}", st.gripper);
    match &t.joystick {
        Some((j, rebuilt)) => {
            let _ = writeln!(
                s,
                "  joystick      seq {}  t_ns {}  received {}  axes [{:+.4}, {:+.4}]  gripper {:+.3}  buttons [{}]{}",
                j.seq,
                j.t_ns,
                t.mapper_recorded.joystick_rx_ns,
                j.axes[0],
                j.axes[1],
                j.gripper,
                bit_names(j.buttons, &ipc_types::buttons::NAMES).join(", "),
                if *rebuilt {
                    "  (rebuilt from the command: not in the recording)"
                } else {
                    ""
                }
            );
        }
        None => {
            let _ = writeln!(s, "  joystick      none yet");
        }
    }
    let _ = writeln!(
        s,
        "  control       [{}]  filter time {} ns (state age {:.3} ms, joystick age {:.3} ms)",
        bit_names(t.control & !safe_control::RECORDED, &safe_control::NAMES).join(", "),
        t.now_ns,
        t.now_ns.saturating_sub(t.safe_recorded.state_t_ns) as f64 / 1e6,
        t.now_ns.saturating_sub(t.safe_recorded.joystick_t_ns) as f64 / 1e6,
    );
}

/// The map's part: its action, the map at this state, its output and the replay's.
fn push_map(s: &mut String, t: &TickTrace, n: usize) {
    use std::fmt::Write as _;
    let m = &t.mapper_recorded;
    let _ = writeln!(
        s,
        "map (mapper {}, model {})",
        m.mapper_id,
        t.model.as_deref().unwrap_or("not in the recording")
    );
    let _ = writeln!(
        s,
        "  action        [{:+.5}, {:+.5}]  flags [{}]",
        m.action[0],
        m.action[1],
        bit_names(m.flags, &mapper_flags::NAMES).join(", ")
    );
    if let Some(h) = &t.h {
        let _ = writeln!(s, "  s·H (rad/s per unit action, the map at this state)");
        for (i, col) in h.iter().enumerate() {
            let _ = writeln!(s, "    a{i} -> {}", joints(col, n));
        }
    }
    let _ = writeln!(s, "  qdot (rad/s)  {}", joints(&m.qdot_rad_s, n));
    let _ = writeln!(s, "  gripper rate  {:+.4}", m.gripper_rate);
    match &t.mapper_replayed {
        Some(r) => {
            let d = mapper_diff(m, r);
            if d.is_empty() {
                let _ = writeln!(s, "  replayed      identical");
            } else {
                for f in d {
                    let _ = writeln!(
                        s,
                        "  replayed      {} {} (recorded {})",
                        f.field, f.replayed, f.recorded
                    );
                }
            }
        }
        None => {
            let _ = writeln!(s, "  replayed      not re-executed");
        }
    }
}

/// The safety filter's part: what each rule did, the hard guarantees, the closest pair.
fn push_safety(s: &mut String, t: &TickTrace, n: usize) {
    use std::fmt::Write as _;
    let r = &t.safe_replayed;
    let c = &t.config;
    let _ = writeln!(
        s,
        "safety (speed override {}, stop distance {} m, slowdown {} m, tcp cap {} m/s)",
        c.speed_override, c.stop_distance_m, c.slowdown_distance_m, c.max_tcp_speed_m_s
    );
    let _ = writeln!(
        s,
        "  from the arm's velocity {}",
        joints(&t.report.base_rad_s, n)
    );
    if r.flags == 0 {
        let _ = writeln!(s, "  no rule acted: the command passes as mapped");
    }
    let sc = &t.report.scales;
    let factor = |b: u32| match b {
        safe_flags::VELOCITY_SCALED => Some(sc.velocity),
        safe_flags::SPEED_CAPPED => Some(sc.speed_cap),
        safe_flags::POSITION_LIMITED => Some(sc.position),
        safe_flags::WORKSPACE_LIMITED => Some(sc.workspace),
        safe_flags::CLEARANCE_LIMITED => Some(sc.clearance),
        _ => None,
    };
    for bit in 0..safe_flags::COUNT {
        let b = 1u32 << bit;
        if r.flags & b != 0 {
            let k = factor(b)
                .filter(|k| *k < 1.0)
                .map_or(String::new(), |k| format!(" (target x {k:.4})"));
            let _ = writeln!(s, "  {:<17} {}{k}", safe_flags::NAMES[bit], rule_line(b));
        }
    }
    if let Some(l) = t.report.toward_braking {
        let _ = writeln!(
            s,
            "  braking           the acceleration-limited output could not brake in time: moved \
             to {l:.4} of the way from braking the arm's velocity"
        );
    }
    for (on, what) in [
        (
            t.report.hard_position,
            "hard position guarantee overrode the acceleration limit",
        ),
        (
            t.report.hard_workspace,
            "hard workspace guarantee overrode the acceleration limit",
        ),
        (
            t.report.hard_clearance,
            "hard clearance guarantee scaled the output",
        ),
        (
            t.report.hard_speed,
            "the speed caps scaled the acceleration-limited output",
        ),
    ] {
        if on {
            let _ = writeln!(s, "  {what}");
        }
    }
    let pair = if r.closest_pair == [0xFFFF; 2] {
        "none checked".to_owned()
    } else {
        format!(
            "{} at {:.4} m",
            safety::scene::pair_name(r.closest_pair, &c.scene.box_names())
                .unwrap_or_else(|| format!("{:?}", r.closest_pair)),
            r.clearance_m
        )
    };
    let _ = writeln!(
        s,
        "  closest pair  {pair}; tool speed {:.4} m/s",
        r.tcp_speed_m_s
    );
}

/// The final command, and how it differs from the recorded one.
fn push_command(s: &mut String, t: &TickTrace, n: usize) {
    use std::fmt::Write as _;
    let r = &t.safe_replayed;
    let _ = writeln!(s, "command");
    let _ = writeln!(s, "  qdot (rad/s)  {}", joints(&r.qdot_rad_s, n));
    let _ = writeln!(s, "  gripper rate  {:+.4}", r.gripper_rate);
    let d = safe_diff(&t.safe_recorded, r);
    if d.is_empty() {
        let _ = writeln!(s, "  identical to the recorded command");
    } else {
        for f in d {
            let _ = writeln!(
                s,
                "  differs: {} recorded {} replayed {}",
                f.field, f.recorded, f.replayed
            );
        }
    }
}
