//! The counterfactual (`scl replay RUN.mcap --model B [--safety FILE] --out WHATIF.mcap`):
//! the recorded robot states and joystick samples through another model and / or another
//! safety configuration, open loop (the states stay the recorded ones), written as a copy of
//! the recording with `/whatif/mapper_command` and `/whatif/safe_command` channels beside the
//! recorded commands (Foxglove plots both), and a summary: per-tick differences of the joint
//! velocity and of the tool's velocity, how often each safety rule acted in either, and the
//! ticks where the two differ most. `--closed-loop` instead drives a mock arm of the robot
//! profile, from the recorded first state, with the what-if commands (`/whatif/robot_state`
//! too): the states then differ from the recording, and the summary says how far the tool
//! would have been from where it was.
//!
//! Each tick the recording has a safety command for, the what-if mapper (one
//! [`MapperStep`] over the whole run, serving B) maps the joystick sample the forwarded
//! command used, and the what-if filter filters its command with the recorded state, time
//! and control inputs.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use ipc_types::{
    MAX_JOINTS, MapperCommand, NO_TICK, RobotState, SafeCommand, safe_control, safe_flags,
};
use mapper::LoadedModel;
use mapper::step::MapperStep;
use recording::{Event, LogClock, LogWriter, Payload, SchemaInfo, Topic};
use safety::{SafetyFilter, TcpModel};
use serde::Serialize;

use crate::{Recording, ReplayError, joystick_for};

/// What to put in place of the recorded model and configuration.
#[derive(Debug, Clone, Default)]
pub struct WhatIf {
    /// The model spec to serve instead (a file, `bundled`, `modeswitch`, `constant:...`);
    /// `None`: the recorded mapper's commands as they were.
    pub model: Option<String>,
    /// A graph TOML whose `[safety]` replaces the recorded one; `None`: the recorded one.
    pub safety: Option<PathBuf>,
    /// Drive a mock arm with the what-if commands instead of taking the recorded states.
    pub closed_loop: bool,
}

/// One tick where the what-if command differs.
#[derive(Debug, Clone, Serialize)]
pub struct TickDifference {
    /// The tick.
    pub tick: u64,
    /// `|qdot_whatif - qdot_recorded|` of the safety commands (rad/s).
    pub joint_rad_s: f64,
    /// The tool's linear speed difference under them at the tick's state (m/s).
    pub tool_m_s: f64,
}

/// The counterfactual's summary.
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    /// Ticks compared.
    pub ticks: u64,
    /// Ticks whose safety commands differ at all.
    pub ticks_differing: u64,
    /// The first tick whose safety command's joint velocity differs (`null`: none).
    pub first_difference: Option<u64>,
    /// The first tick whose map output (the mapper command's joint velocity) differs
    /// (`null`: none).
    pub first_map_difference: Option<u64>,
    /// Largest and mean joint-velocity difference of the safety commands (rad/s).
    pub joint_rad_s_max: f64,
    /// Mean over the ticks compared.
    pub joint_rad_s_mean: f64,
    /// Largest tool-velocity difference (m/s).
    pub tool_m_s_max: f64,
    /// Mean over the ticks compared.
    pub tool_m_s_mean: f64,
    /// Closed loop: the largest distance between the tool's what-if and recorded positions
    /// (m); `null` open loop.
    pub tool_position_m_max: Option<f64>,
    /// Closed loop: that distance at the last tick (m); `null` open loop.
    pub tool_position_m_final: Option<f64>,
    /// How many ticks each safety rule acted: recorded and what-if, by rule name.
    pub rules: BTreeMap<String, [u64; 2]>,
    /// The ticks where the two differ most (joint velocity), largest first (up to 10).
    pub largest: Vec<TickDifference>,
    /// The output file.
    pub out: String,
    /// What stood in for missing inputs.
    pub notes: Vec<String>,
}

/// Whether two commanded velocities differ as numbers (`-0.0 == 0.0`: the counterfactual asks
/// what the arm would have done, not whether the bits agree; the replay compares bits).
fn commands_differ(a: &[f64], b: &[f64]) -> bool {
    a.iter().zip(b).any(|(x, y)| x != y)
}

fn norm(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

/// Runs the counterfactual on `rec` and writes `out` (never over an existing file).
pub fn run(rec: &Recording, what: &WhatIf, out: &Path) -> Result<Summary, ReplayError> {
    let mut notes = Vec::new();
    let mut cfg = rec.graph_config(&mut notes)?;
    let cerr = |what: String, reason: String| ReplayError::Config {
        path: rec.path.clone(),
        what,
        reason,
    };
    if let Some(f) = &what.safety {
        let other = scl_config::GraphConfig::load(Some(f))
            .map_err(|e| cerr(format!("--safety {}", f.display()), e.to_string()))?;
        cfg.safety = other.safety;
    }
    let robot = cfg
        .profile()
        .map_err(|e| cerr("the graph configuration".into(), e.to_string()))?;
    let n = robot.n_joints();
    let mut step = match &what.model {
        Some(spec) => {
            let model =
                LoadedModel::load_for(spec, robot).map_err(|source| ReplayError::Model {
                    path: rec.path.clone(),
                    mapper_id: 0,
                    pid: 0,
                    source,
                })?;
            Some(
                MapperStep::for_robot(0, model.at_period(cfg.period_s()), robot).map_err(
                    |source| ReplayError::Model {
                        path: rec.path.clone(),
                        mapper_id: 0,
                        pid: 0,
                        source,
                    },
                )?,
            )
        }
        None => None,
    };
    let mut filter = SafetyFilter::for_graph(cfg.safety.clone(), robot, cfg.period_s())
        .map_err(|e| cerr("the safety filter".into(), e.to_string()))?;
    let mut tcp = safety::ChainTcp::of(robot);
    let recorded_mapper: std::collections::HashMap<(u32, u64, u64), &MapperCommand> = rec
        .mapper
        .iter()
        .map(|c| ((c.mapper_id, c.tick, c.t_ns), c))
        .collect();

    let mut whatif: Vec<(MapperCommand, SafeCommand, RobotState)> = Vec::new();
    let mut arm: Option<hw_bridge::mock::MockArm> = None;
    let mut sim: Option<RobotState> = None;
    let (mut pos_max, mut pos_final) = (0.0f64, 0.0f64);
    let mut diffs = Vec::new();
    let mut rules: BTreeMap<String, [u64; 2]> = BTreeMap::new();
    let mut first_difference = None;
    let mut first_map_difference = None;
    let mut last_tick = NO_TICK;
    for safe in &rec.safe {
        let key = (safe.mapper_id, safe.tick, safe.mapper_t_ns);
        let (Some(rec_cmd), Some(recorded_state)) =
            (recorded_mapper.get(&key), rec.states.get(&safe.state_t_ns))
        else {
            continue;
        };
        if safe.tick == last_tick {
            continue;
        }
        last_tick = safe.tick;
        if what.closed_loop && arm.is_none() {
            let mut a = hw_bridge::mock::MockArm::for_robot(
                robot,
                hw_bridge::mock::MockConfig::for_robot(robot),
            )
            .map_err(|e| cerr("the mock arm".into(), e.to_string()))?;
            a.resume(recorded_state.q(), recorded_state.gripper);
            arm = Some(a);
            sim = Some(*recorded_state);
        }
        // Closed loop: the simulated arm's state, stamped as the recorded one (tick, time).
        let state_owned = match sim.as_mut() {
            Some(s) => {
                s.tick = recorded_state.tick;
                s.t_ns = recorded_state.t_ns;
                s.missed = recorded_state.missed;
                s.flags = recorded_state.flags;
                *s
            }
            None => *recorded_state,
        };
        let state = &state_owned;
        let mut cmd = match step.as_mut() {
            Some(s) => {
                let joy = joystick_for(rec, rec_cmd);
                let mut c = s.step(state, joy.as_ref().map(|(j, _)| j));
                c.mapper_id = rec_cmd.mapper_id;
                c
            }
            None => **rec_cmd,
        };
        cmd.t_ns = rec_cmd.t_ns;
        cmd.state_rx_ns = rec_cmd.state_rx_ns;
        cmd.joystick_rx_ns = rec_cmd.joystick_rx_ns;
        cmd.compute_ns = rec_cmd.compute_ns;
        if first_map_difference.is_none() && commands_differ(&rec_cmd.qdot_rad_s, &cmd.qdot_rad_s) {
            first_map_difference = Some(safe.tick);
        }
        let control = if safe.control & safe_control::RECORDED != 0 {
            safe.control
        } else {
            (if safe.flags & safe_flags::ESTOP != 0 {
                safe_control::ESTOP
            } else {
                0
            }) | if safe.flags & safe_flags::HOLD != 0 {
                safe_control::HOLD
            } else {
                0
            }
        };
        filter.apply_control(control);
        let mut res = filter.step(&cmd, state, safe.t_ns.saturating_sub(safe.compute_ns));
        res.t_ns = safe.t_ns;
        res.mapper_rx_ns = safe.mapper_rx_ns;
        res.compute_ns = safe.compute_ns;
        for (bit, name) in safe_flags::NAMES.iter().enumerate() {
            let e = rules.entry((*name).to_owned()).or_default();
            e[0] += u64::from(safe.flags & (1 << bit) != 0);
            e[1] += u64::from(res.flags & (1 << bit) != 0);
        }
        let mut dq = [0.0; MAX_JOINTS];
        for ((d, a), b) in dq.iter_mut().zip(&res.qdot_rad_s).zip(&safe.qdot_rad_s) {
            *d = a - b;
        }
        let mut p = [0.0; 3];
        let mut jv = [[0.0; MAX_JOINTS]; 3];
        tcp.tcp(state.q(), &mut p, &mut jv);
        let tool = if what.closed_loop {
            // Each command at its own state: the tool's velocities and positions compared.
            let mut pr = [0.0; 3];
            let mut jr = [[0.0; MAX_JOINTS]; 3];
            tcp.tcp(recorded_state.q(), &mut pr, &mut jr);
            let vw = safety::rules::tcp_velocity(&jv, &res.qdot_rad_s[..n]);
            let vr = safety::rules::tcp_velocity(&jr, &safe.qdot_rad_s[..n]);
            let d = norm(&[pr[0] - p[0], pr[1] - p[1], pr[2] - p[2]]);
            if d.is_finite() {
                pos_max = pos_max.max(d);
                pos_final = d;
            }
            norm(&[vw[0] - vr[0], vw[1] - vr[1], vw[2] - vr[2]])
        } else {
            norm(&safety::rules::tcp_velocity(&jv, &dq[..n]))
        };
        let joint = norm(&dq[..n]);
        if first_difference.is_none() && commands_differ(&safe.qdot_rad_s, &res.qdot_rad_s) {
            first_difference = Some(safe.tick);
        }
        diffs.push(TickDifference {
            tick: safe.tick,
            joint_rad_s: joint,
            tool_m_s: if tool.is_finite() { tool } else { 0.0 },
        });
        whatif.push((cmd, res, *state));
        if let (Some(a), Some(s)) = (arm.as_mut(), sim.as_mut()) {
            a.set_command(&res.qdot_rad_s[..n], res.gripper_rate);
            let r = a.step(cfg.period_s());
            s.q_rad = r.q_rad;
            s.qdot_rad_s = r.qdot_rad_s;
            s.gripper = r.gripper;
            s.applied_tick = safe.tick;
        }
    }
    if whatif.is_empty() {
        return Err(ReplayError::Empty {
            path: rec.path.clone(),
            reason: "no tick has both its command and its robot state recorded".into(),
        });
    }
    write(rec, what, out, &whatif)?;
    let ticks = diffs.len() as u64;
    let mean = |f: &dyn Fn(&TickDifference) -> f64| diffs.iter().map(f).sum::<f64>() / ticks as f64;
    let summary = Summary {
        ticks,
        ticks_differing: diffs.iter().filter(|d| d.joint_rad_s > 0.0).count() as u64,
        first_difference,
        first_map_difference,
        joint_rad_s_max: diffs.iter().map(|d| d.joint_rad_s).fold(0.0, f64::max),
        joint_rad_s_mean: mean(&|d| d.joint_rad_s),
        tool_m_s_max: diffs.iter().map(|d| d.tool_m_s).fold(0.0, f64::max),
        tool_m_s_mean: mean(&|d| d.tool_m_s),
        tool_position_m_max: what.closed_loop.then_some(pos_max),
        tool_position_m_final: what.closed_loop.then_some(pos_final),
        rules: rules.into_iter().filter(|(_, c)| c[0] + c[1] > 0).collect(),
        largest: {
            let mut v: Vec<TickDifference> = diffs
                .iter()
                .filter(|d| d.joint_rad_s > 0.0)
                .cloned()
                .collect();
            v.sort_by(|a, b| b.joint_rad_s.total_cmp(&a.joint_rad_s));
            v.truncate(10);
            v
        },
        out: out.display().to_string(),
        notes,
    };
    Ok(summary)
}

/// The recording copied to `out` with the what-if commands on their own channels.
fn write(
    rec: &Recording,
    what: &WhatIf,
    out: &Path,
    whatif: &[(MapperCommand, SafeCommand, RobotState)],
) -> Result<(), ReplayError> {
    let file = recording::create_new(out)?;
    let mut w = LogWriter::new(std::io::BufWriter::new(file), out, None)?;
    // The what-if commands are stamped on the recording's clock (its first message's).
    let mut clock = None;
    recording::read_file(&rec.path, |ev| {
        if let Event::Message {
            log_time,
            publish_time,
            ..
        } = ev
        {
            clock.get_or_insert(LogClock::of_message(log_time, publish_time));
        }
        w.copy_event(&ev).map(|_| ())
    })?;
    let clock = clock.unwrap_or_default();
    let mut meta = BTreeMap::new();
    meta.insert(
        recording::FORMAT_KEY.to_owned(),
        recording::FORMAT.to_string(),
    );
    let channel = |w: &mut LogWriter<_>, t: Topic| {
        w.add_channel(
            &format!("/whatif{}", t.channel()),
            Some(&SchemaInfo {
                name: t.schema_name().to_owned(),
                encoding: "jsonschema".to_owned(),
                data: t.schema().to_string().into_bytes(),
            }),
            "json",
            &meta,
        )
    };
    let mc = channel(&mut w, Topic::MapperCommand)?;
    let sc = channel(&mut w, Topic::SafeCommand)?;
    let rc = if what.closed_loop {
        Some(channel(&mut w, Topic::RobotState)?)
    } else {
        None
    };
    let mut json = Vec::new();
    let werr = |e: serde_json::Error| RecordError::Write {
        path: out.to_owned(),
        reason: e.to_string(),
    };
    use recording::RecordError;
    for (i, (m, s, st)) in whatif.iter().enumerate() {
        if let Some(rc) = rc {
            json.clear();
            Payload::RobotState(*st)
                .write_json(&mut json)
                .map_err(werr)?;
            w.write_raw(rc, i as u32 + 1, clock.log_time(st.t_ns), st.t_ns, &json)?;
        }
        json.clear();
        Payload::MapperCommand(*m)
            .write_json(&mut json)
            .map_err(werr)?;
        w.write_raw(mc, i as u32 + 1, clock.log_time(m.t_ns), m.t_ns, &json)?;
        json.clear();
        Payload::SafeCommand(*s)
            .write_json(&mut json)
            .map_err(werr)?;
        w.write_raw(sc, i as u32 + 1, clock.log_time(s.t_ns), s.t_ns, &json)?;
    }
    let mut m = BTreeMap::new();
    m.insert("source".to_owned(), rec.path.display().to_string());
    m.insert(
        "model".to_owned(),
        what.model.clone().unwrap_or_else(|| "as recorded".into()),
    );
    if let Some(spec) = &what.model
        && let Ok(bytes) = std::fs::read(spec)
    {
        m.insert("model_sha256".to_owned(), recording::sha256_hex(&bytes));
    }
    m.insert(
        "safety".to_owned(),
        what.safety
            .as_ref()
            .map_or_else(|| "as recorded".into(), |p| p.display().to_string()),
    );
    m.insert(
        "loop".to_owned(),
        if what.closed_loop { "closed" } else { "open" }.to_owned(),
    );
    w.finish(Some(recording::metadata("scl.whatif", m)))?;
    Ok(())
}

/// The summary as text.
pub fn render(s: &Summary) -> String {
    use std::fmt::Write as _;
    let mut t = String::new();
    for n in &s.notes {
        let _ = writeln!(t, "note: {n}");
    }
    let first = |v: Option<u64>| v.map_or("none".to_owned(), |k| format!("tick {k}"));
    let _ = writeln!(
        t,
        "what-if over {} ticks ({} loop) -> {}: {} ticks differ; first difference {} (map output: {})",
        s.ticks,
        if s.tool_position_m_max.is_some() {
            "closed"
        } else {
            "open"
        },
        s.out,
        s.ticks_differing,
        first(s.first_difference),
        first(s.first_map_difference)
    );
    let _ = writeln!(
        t,
        "  joint velocity difference  max {:.4} rad/s  mean {:.4} rad/s",
        s.joint_rad_s_max, s.joint_rad_s_mean
    );
    let _ = writeln!(
        t,
        "  tool velocity difference   max {:.4} m/s    mean {:.4} m/s",
        s.tool_m_s_max, s.tool_m_s_mean
    );
    if let (Some(max), Some(last)) = (s.tool_position_m_max, s.tool_position_m_final) {
        let _ = writeln!(
            t,
            "  tool position difference   max {max:.4} m      at the end {last:.4} m"
        );
    }
    let _ = writeln!(t, "  safety rules (ticks acted: recorded / what-if)");
    for (name, c) in &s.rules {
        let _ = writeln!(t, "    {name:<17} {:>6} / {:<6}", c[0], c[1]);
    }
    if !s.largest.is_empty() {
        let _ = writeln!(t, "  largest differences");
        for d in s.largest.iter().take(5) {
            let _ = writeln!(
                t,
                "    tick {:<8} {:.4} rad/s  {:.4} m/s",
                d.tick, d.joint_rad_s, d.tool_m_s
            );
        }
    }
    t
}
