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
    if let Some(f) = &what.safety {
        let other = scl_config::GraphConfig::load(Some(f))
            .map_err(|e| config_error(rec, format!("--safety {}", f.display()), e))?;
        cfg.safety = other.safety;
    }
    let robot = cfg
        .profile()
        .map_err(|e| config_error(rec, "the graph configuration".into(), e))?;
    let step = match &what.model {
        Some(spec) => Some(mapper_step(rec, spec, &cfg, robot)?),
        None => None,
    };
    let filter = SafetyFilter::for_graph(cfg.safety.clone(), robot, cfg.period_s())
        .map_err(|e| config_error(rec, "the safety filter".into(), e))?;
    let mut replay = Counterfactual {
        rec,
        closed_loop: what.closed_loop,
        robot,
        n: robot.n_joints(),
        period_s: cfg.period_s(),
        step,
        filter,
        tcp: safety::ChainTcp::of(robot),
        arm: None,
        sim: None,
    };
    let recorded_mapper: std::collections::HashMap<(u32, u64, u64), &MapperCommand> = rec
        .mapper
        .iter()
        .map(|c| ((c.mapper_id, c.tick, c.t_ns), c))
        .collect();

    let mut whatif: Vec<(MapperCommand, SafeCommand, RobotState)> = Vec::new();
    let mut tally = Tally::default();
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
        whatif.push(replay.tick(safe, rec_cmd, recorded_state, &mut tally)?);
    }
    if whatif.is_empty() {
        return Err(ReplayError::Empty {
            path: rec.path.clone(),
            reason: "no tick has both its command and its robot state recorded".into(),
        });
    }
    write(rec, what, out, &whatif)?;
    Ok(tally.summary(what.closed_loop, out, notes))
}

/// A configuration error of the counterfactual (`what` did not load), naming the recording.
fn config_error(rec: &Recording, what: String, reason: impl ToString) -> ReplayError {
    ReplayError::Config {
        path: rec.path.clone(),
        what,
        reason: reason.to_string(),
    }
}

/// The mapper of `--model` (`spec`) on the recording's arm, at its control period.
fn mapper_step(
    rec: &Recording,
    spec: &str,
    cfg: &scl_config::GraphConfig,
    robot: &'static kinematics::RobotProfile,
) -> Result<MapperStep, ReplayError> {
    let model = LoadedModel::load_for(spec, robot).map_err(|source| ReplayError::Model {
        path: rec.path.clone(),
        mapper_id: 0,
        pid: 0,
        source,
    })?;
    MapperStep::for_robot(0, model.at_period(cfg.period_s()), robot).map_err(|source| {
        ReplayError::Model {
            path: rec.path.clone(),
            mapper_id: 0,
            pid: 0,
            source,
        }
    })
}

/// The counterfactual graph: the what-if mapper (if any), the safety filter, the tool model,
/// and in closed loop the mock arm and its simulated state.
struct Counterfactual<'a> {
    rec: &'a Recording,
    closed_loop: bool,
    robot: &'static kinematics::RobotProfile,
    n: usize,
    period_s: f64,
    step: Option<MapperStep>,
    filter: SafetyFilter,
    tcp: safety::ChainTcp,
    arm: Option<hw_bridge::mock::MockArm>,
    sim: Option<RobotState>,
}

/// What the ticks differ by, so far.
#[derive(Default)]
struct Tally {
    diffs: Vec<TickDifference>,
    /// Per rule: ticks it fired (recorded, what-if).
    rules: BTreeMap<String, [u64; 2]>,
    first_difference: Option<u64>,
    first_map_difference: Option<u64>,
    pos_max: f64,
    pos_final: f64,
}

impl Counterfactual<'_> {
    /// One recorded tick again: the state (simulated in closed loop), the what-if mapper's
    /// command, the safety filter's; the differences go to `tally`.
    fn tick(
        &mut self,
        safe: &SafeCommand,
        rec_cmd: &MapperCommand,
        recorded_state: &RobotState,
        tally: &mut Tally,
    ) -> Result<(MapperCommand, SafeCommand, RobotState), ReplayError> {
        if self.closed_loop && self.arm.is_none() {
            self.start_arm(recorded_state)?;
        }
        let state = &self.state_at(recorded_state);
        let cmd = self.map(rec_cmd, state);
        if tally.first_map_difference.is_none()
            && commands_differ(&rec_cmd.qdot_rad_s, &cmd.qdot_rad_s)
        {
            tally.first_map_difference = Some(safe.tick);
        }
        let res = self.filter(safe, &cmd, state);
        tally.count_rules(safe, &res);
        let n = self.n;
        let mut dq = [0.0; MAX_JOINTS];
        for ((d, a), b) in dq.iter_mut().zip(&res.qdot_rad_s).zip(&safe.qdot_rad_s) {
            *d = a - b;
        }
        let tool = self.tool_difference(safe, &res, state, recorded_state, &dq, tally);
        let joint = norm(&dq[..n]);
        if tally.first_difference.is_none() && commands_differ(&safe.qdot_rad_s, &res.qdot_rad_s) {
            tally.first_difference = Some(safe.tick);
        }
        tally.diffs.push(TickDifference {
            tick: safe.tick,
            joint_rad_s: joint,
            tool_m_s: if tool.is_finite() { tool } else { 0.0 },
        });
        self.advance_arm(&res, safe.tick);
        Ok((cmd, res, *state))
    }

    /// Closed loop: the mock arm, started at the first recorded state.
    fn start_arm(&mut self, recorded_state: &RobotState) -> Result<(), ReplayError> {
        let mut a = hw_bridge::mock::MockArm::for_robot(
            self.robot,
            hw_bridge::mock::MockConfig::for_robot(self.robot),
        )
        .map_err(|e| config_error(self.rec, "the mock arm".into(), e))?;
        a.resume(recorded_state.q(), recorded_state.gripper);
        self.arm = Some(a);
        self.sim = Some(*recorded_state);
        Ok(())
    }

    /// The state the tick sees: closed loop, the simulated arm's, stamped as the recorded
    /// one (tick, time); else the recorded one.
    fn state_at(&mut self, recorded_state: &RobotState) -> RobotState {
        match self.sim.as_mut() {
            Some(s) => {
                s.tick = recorded_state.tick;
                s.t_ns = recorded_state.t_ns;
                s.missed = recorded_state.missed;
                s.flags = recorded_state.flags;
                *s
            }
            None => *recorded_state,
        }
    }

    /// The what-if mapper's command at `state` (the recorded one without `--model`), with
    /// the recorded command's stamps.
    fn map(&mut self, rec_cmd: &MapperCommand, state: &RobotState) -> MapperCommand {
        let mut cmd = match self.step.as_mut() {
            Some(s) => {
                let joy = joystick_for(self.rec, rec_cmd);
                let mut c = s.step(state, joy.as_ref().map(|(j, _)| j));
                c.mapper_id = rec_cmd.mapper_id;
                c
            }
            None => *rec_cmd,
        };
        cmd.t_ns = rec_cmd.t_ns;
        cmd.state_rx_ns = rec_cmd.state_rx_ns;
        cmd.joystick_rx_ns = rec_cmd.joystick_rx_ns;
        cmd.compute_ns = rec_cmd.compute_ns;
        cmd
    }

    /// The safety filter's command for `cmd`, under the recorded control bits (or those its
    /// flags imply in a recording without them), with the recorded command's stamps.
    fn filter(
        &mut self,
        safe: &SafeCommand,
        cmd: &MapperCommand,
        state: &RobotState,
    ) -> SafeCommand {
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
        self.filter.apply_control(control);
        let mut res = self
            .filter
            .step(cmd, state, safe.t_ns.saturating_sub(safe.compute_ns));
        res.t_ns = safe.t_ns;
        res.mapper_rx_ns = safe.mapper_rx_ns;
        res.compute_ns = safe.compute_ns;
        res
    }

    /// The tool's speed difference (m/s): closed loop, each command at its own state (the
    /// position difference goes to `tally`); else the joint difference `dq` at `state`.
    fn tool_difference(
        &mut self,
        safe: &SafeCommand,
        res: &SafeCommand,
        state: &RobotState,
        recorded_state: &RobotState,
        dq: &[f64; MAX_JOINTS],
        tally: &mut Tally,
    ) -> f64 {
        let n = self.n;
        let mut p = [0.0; 3];
        let mut jv = [[0.0; MAX_JOINTS]; 3];
        self.tcp.tcp(state.q(), &mut p, &mut jv);
        if self.closed_loop {
            // Each command at its own state: the tool's velocities and positions compared.
            let mut pr = [0.0; 3];
            let mut jr = [[0.0; MAX_JOINTS]; 3];
            self.tcp.tcp(recorded_state.q(), &mut pr, &mut jr);
            let vw = safety::rules::tcp_velocity(&jv, &res.qdot_rad_s[..n]);
            let vr = safety::rules::tcp_velocity(&jr, &safe.qdot_rad_s[..n]);
            let d = norm(&[pr[0] - p[0], pr[1] - p[1], pr[2] - p[2]]);
            if d.is_finite() {
                tally.pos_max = tally.pos_max.max(d);
                tally.pos_final = d;
            }
            norm(&[vw[0] - vr[0], vw[1] - vr[1], vw[2] - vr[2]])
        } else {
            norm(&safety::rules::tcp_velocity(&jv, &dq[..n]))
        }
    }

    /// Closed loop: the mock arm follows the what-if command for a period.
    fn advance_arm(&mut self, res: &SafeCommand, tick: u64) {
        if let (Some(a), Some(s)) = (self.arm.as_mut(), self.sim.as_mut()) {
            a.set_command(&res.qdot_rad_s[..self.n], res.gripper_rate);
            let r = a.step(self.period_s);
            s.q_rad = r.q_rad;
            s.qdot_rad_s = r.qdot_rad_s;
            s.gripper = r.gripper;
            s.applied_tick = tick;
        }
    }
}

impl Tally {
    /// Counts the ticks each rule fired in the recording and in the what-if.
    fn count_rules(&mut self, safe: &SafeCommand, res: &SafeCommand) {
        for (bit, name) in safe_flags::NAMES.iter().enumerate() {
            let e = self.rules.entry((*name).to_owned()).or_default();
            e[0] += u64::from(safe.flags & (1 << bit) != 0);
            e[1] += u64::from(res.flags & (1 << bit) != 0);
        }
    }

    /// The summary of the differences, the largest ten ticks among them.
    fn summary(self, closed_loop: bool, out: &Path, notes: Vec<String>) -> Summary {
        let diffs = &self.diffs;
        let ticks = diffs.len() as u64;
        let mean =
            |f: &dyn Fn(&TickDifference) -> f64| diffs.iter().map(f).sum::<f64>() / ticks as f64;
        Summary {
            ticks,
            ticks_differing: diffs.iter().filter(|d| d.joint_rad_s > 0.0).count() as u64,
            first_difference: self.first_difference,
            first_map_difference: self.first_map_difference,
            joint_rad_s_max: diffs.iter().map(|d| d.joint_rad_s).fold(0.0, f64::max),
            joint_rad_s_mean: mean(&|d| d.joint_rad_s),
            tool_m_s_max: diffs.iter().map(|d| d.tool_m_s).fold(0.0, f64::max),
            tool_m_s_mean: mean(&|d| d.tool_m_s),
            tool_position_m_max: closed_loop.then_some(self.pos_max),
            tool_position_m_final: closed_loop.then_some(self.pos_final),
            rules: self
                .rules
                .into_iter()
                .filter(|(_, c)| c[0] + c[1] > 0)
                .collect(),
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
        }
    }
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
