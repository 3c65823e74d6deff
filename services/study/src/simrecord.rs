//! `scl study simulate --record`: each in-process attempt written as the MCAP `scl up
//! --record` writes for a live run (the graph's topics with their schemas, the served model
//! and the graph configuration embedded in process records, the 3D view's channels), so that
//! `scl replay` re-executes it and Foxglove shows it, plus what the goal tracker and the
//! operator saw each tick on [`OPERATOR_TOPIC`].
//!
//! The in-process graph has no processes: its mapper and safety filter are named by the
//! stand-in pids [`MAPPER_PID`] and [`SAFETY_PID`] in their heartbeats and process records.
//! Times are the attempt's simulated clock (log time = publish time = the message's `t_ns`),
//! so the same seed writes the same file.

use std::collections::BTreeMap;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use ipc_types::{NodeRole, NodeStatus, phase};
use recording::{LogWriter, Payload, RecordError, SchemaInfo, Topic};
use study::simulate::{Observe, Observed, SimError};

/// The channel of what the goal tracker and the operator saw each tick
/// ([`study::simulate::TickNote`], JSON).
pub const OPERATOR_TOPIC: &str = "/scl/sim/operator";
/// The stand-in pid of the in-process mapper.
pub const MAPPER_PID: u32 = 1;
/// The stand-in pid of the in-process safety filter.
pub const SAFETY_PID: u32 = 2;
/// The metadata record naming the simulated attempt (its name, the study task and its goals,
/// the model, the seed), as `scl study run` names a live one (`scl.trial`; `scl dataset
/// --format lerobot` takes the episode's task from it).
pub const TRIAL_METADATA: &str = learning::lerobot::run::TRIAL_METADATA;

/// One attempt being written.
pub struct AttemptRecording {
    path: PathBuf,
    w: LogWriter<BufWriter<std::fs::File>>,
    viz: viz::Viz,
    viz_ids: BTreeMap<viz::VizTopic, u16>,
    viz_seq: BTreeMap<viz::VizTopic, u32>,
    viz_out: Vec<viz::VizMessage>,
    viz_errors: u64,
    operator_id: u16,
    operator_seq: u32,
    json: Vec<u8>,
    started: bool,
    graph: scl_config::GraphConfig,
    spec: String,
    ticks: u64,
}

/// What the file of an attempt holds besides its ticks.
#[derive(Debug, Clone)]
pub struct AttemptMeta<'a> {
    /// The graph configuration of the run (its robot, rate and safety).
    pub graph: &'a scl_config::GraphConfig,
    /// The served model's spec.
    pub spec: &'a str,
    /// The `scl.trial` entries.
    pub trial: BTreeMap<String, String>,
}

fn werr(path: &Path, reason: impl std::fmt::Display) -> SimError {
    SimError::Setup(format!("recording {}: {reason}", path.display()))
}

fn rec_err(e: RecordError) -> SimError {
    SimError::Setup(format!("recording: {e}"))
}

impl AttemptRecording {
    /// Creates `path` (refused if it exists: nothing is written over) with its channels.
    pub fn create(path: &Path, meta: &AttemptMeta<'_>) -> Result<Self, SimError> {
        let file = recording::create_new(path).map_err(rec_err)?;
        let mut start = BTreeMap::new();
        start.insert("prefix".to_owned(), "simulated".to_owned());
        start.insert(
            "topics".to_owned(),
            Topic::ALL
                .iter()
                .map(|t| t.name())
                .collect::<Vec<_>>()
                .join(","),
        );
        start.insert(
            "clock".to_owned(),
            "simulated (scl study simulate): log_time = publish_time = the message's t_ns, \
             from the attempt's start"
                .to_owned(),
        );
        start.insert(
            "simulated".to_owned(),
            "scl study simulate --record".to_owned(),
        );
        start.insert(
            "scl_version".to_owned(),
            env!("CARGO_PKG_VERSION").to_owned(),
        );
        let mut w = LogWriter::new(
            BufWriter::new(file),
            path,
            Some(recording::metadata(recording::START_METADATA, start)),
        )
        .map_err(rec_err)?;
        if !meta.trial.is_empty() {
            w.write_metadata(&recording::metadata(TRIAL_METADATA, meta.trial.clone()))
                .map_err(rec_err)?;
        }
        let mut channel_meta = BTreeMap::new();
        channel_meta.insert("prefix".to_owned(), "simulated".to_owned());
        for t in Topic::ALL {
            w.add_topic(t, &channel_meta).map_err(rec_err)?;
        }
        let viz = viz::Viz::new(meta.graph).map_err(|e| werr(path, e))?;
        let mut viz_ids = BTreeMap::new();
        for t in viz::VizTopic::ALL {
            let id = w
                .add_channel(
                    t.topic(),
                    Some(&t.schema()),
                    t.message_encoding(),
                    &channel_meta,
                )
                .map_err(rec_err)?;
            viz_ids.insert(t, id);
        }
        let schema = SchemaInfo {
            name: "scl.SimulatedOperator".to_owned(),
            encoding: "jsonschema".to_owned(),
            data: operator_schema().into_bytes(),
        };
        let operator_id = w
            .add_channel(OPERATOR_TOPIC, Some(&schema), "json", &channel_meta)
            .map_err(rec_err)?;
        Ok(Self {
            path: path.to_owned(),
            w,
            viz,
            viz_ids,
            viz_seq: BTreeMap::new(),
            viz_out: Vec::new(),
            viz_errors: 0,
            operator_id,
            operator_seq: 0,
            json: Vec::new(),
            started: false,
            graph: meta.graph.clone(),
            spec: meta.spec.to_owned(),
            ticks: 0,
        })
    }

    /// The processes' first heartbeats and records (what they run embedded), at `t_ns`.
    fn start(&mut self, t_ns: u64) -> Result<(), SimError> {
        for (role, pid) in [
            (NodeRole::Safety, SAFETY_PID),
            (NodeRole::Mapper, MAPPER_PID),
        ] {
            let model = (role == NodeRole::Mapper).then(|| self.spec.clone());
            graph_client::process::embed(
                &mut self.w,
                &graph_client::process::Runs {
                    role,
                    pid,
                    mapper_id: 0,
                    t_ns,
                    cfg: Some(&self.graph),
                    model_spec: model.clone(),
                    cwd: None,
                },
            )
            .map_err(rec_err)?;
            if let Err(e) = self
                .viz
                .take_process(role, 0, Some(&self.graph), model.as_deref())
            {
                tracing::warn!("the 3D view: {e}");
            }
            let mut st = NodeStatus::new(role, phase::RUNNING, t_ns);
            st.pid = pid;
            self.put(&Payload::Status(st))?;
        }
        Ok(())
    }

    /// Writes `p` and what it adds to the 3D view.
    fn put(&mut self, p: &Payload) -> Result<(), SimError> {
        self.w.write(p).map_err(rec_err)?;
        self.viz_out.clear();
        if let Err(e) = self.viz.observe(p, &mut self.viz_out) {
            self.viz_errors += 1;
            if self.viz_errors == 1 {
                tracing::warn!("the 3D view: {e}");
            }
        }
        for m in &self.viz_out {
            let s = self.viz_seq.entry(m.topic).or_default();
            *s = s.wrapping_add(1);
            let id = self.viz_ids.get(&m.topic).copied().unwrap_or_default();
            self.w
                .write_raw(id, *s, m.t_ns, m.t_ns, &m.data)
                .map_err(rec_err)?;
        }
        Ok(())
    }

    /// Finishes the file; returns its path.
    pub fn finish(self) -> Result<PathBuf, SimError> {
        let mut end = BTreeMap::new();
        end.insert("ticks".to_owned(), self.ticks.to_string());
        self.w
            .finish(Some(recording::metadata(recording::END_METADATA, end)))
            .map_err(rec_err)?;
        Ok(self.path)
    }
}

impl Observe for AttemptRecording {
    fn tick(&mut self, t: &Observed<'_>) -> Result<(), SimError> {
        if !self.started {
            self.started = true;
            self.start(t.state.t_ns)?;
        }
        self.put(&Payload::RobotState(*t.state))?;
        self.put(&Payload::MapperCommand(*t.mapper))?;
        self.put(&Payload::SafeCommand(*t.safe))?;
        self.put(&Payload::Joystick(*t.sample))?;
        // The mapper's heartbeat of the tick, as the live mapper publishes one: its mode.
        let mut st = NodeStatus::new(NodeRole::Mapper, phase::RUNNING, t.mapper.t_ns);
        st.pid = MAPPER_PID;
        st.mapper_id = t.mapper.mapper_id;
        st.tick = t.state.tick;
        st.handled = self.ticks + 1;
        st.mode = t.mode;
        st.mode_switches = t.mode_switches;
        self.put(&Payload::Status(st))?;
        self.json.clear();
        serde_json::to_writer(&mut self.json, t.note).map_err(|e| werr(&self.path, e))?;
        self.operator_seq = self.operator_seq.wrapping_add(1);
        self.w
            .write_raw(
                self.operator_id,
                self.operator_seq,
                t.state.t_ns,
                t.state.t_ns,
                &self.json,
            )
            .map_err(rec_err)?;
        self.ticks += 1;
        Ok(())
    }
}

/// The JSON schema of [`OPERATOR_TOPIC`]'s messages.
fn operator_schema() -> String {
    let num = serde_json::json!({"type": ["number", "null"]});
    let vec3 = serde_json::json!({"type": ["array", "null"], "items": {"type": "number"}});
    serde_json::json!({
        "title": "what the goal tracker and the simulated operator saw at a tick",
        "type": "object",
        "properties": {
            "tick": {"type": "integer", "description": "the attempt's tick, from 0"},
            "t_ns": {"type": "integer"},
            "subgoals_done": {"type": "integer"},
            "subgoal": {"type": ["string", "null"], "description": "the subgoal under way"},
            "distance_m": num,
            "aim": vec3,
            "facing_error_rad": num,
            "tool": vec3,
            "mode": {"type": ["integer", "null"]},
        }
    })
    .to_string()
}

/// Runs attempt `setup` in process, recording it into `dir/recordings/NAME.mcap` (refused if
/// it exists); the result's `recording` names the file relative to `dir`.
pub fn run_recorded(
    setup: &study::simulate::AttemptSetup<'_>,
    info: &study::simulate::AttemptInfo<'_>,
    dir: &Path,
    graph: &scl_config::GraphConfig,
    trial: BTreeMap<String, String>,
) -> Result<study::simulate::AttemptResult, SimError> {
    let rel = Path::new("recordings").join(format!("{}.mcap", info.name));
    let path = dir.join(&rel);
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(|e| werr(parent, e))?;
    }
    let meta = AttemptMeta {
        graph,
        spec: info.spec,
        trial,
    };
    let mut rec = AttemptRecording::create(&path, &meta)?;
    let mut r = study::simulate::run_attempt_observed(setup, &mut rec)?;
    rec.finish()?;
    r.recording = Some(rel.display().to_string());
    Ok(r)
}

#[cfg(test)]
mod tests {
    use super::*;
    use learning::goals::{TaskGoals, Tolerances};
    use study::simulate::{AttemptInfo, AttemptSetup, Loop, SimParams};

    /// A simulated attempt, recorded, replays bit for bit with `scl replay`'s replay: every
    /// mapper and safety command re-executed from the embedded model and configuration; the
    /// tracker's notes are on their channel, one per tick; an existing file is refused.
    #[test]
    fn a_recorded_simulated_attempt_replays_bit_for_bit() {
        let dir = std::env::temp_dir().join(format!("scl-simrecord-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let graph = scl_config::GraphConfig::default();
        let robot = graph.profile().unwrap();
        let sim = Loop {
            robot,
            safety: graph.safety.clone(),
            period_s: graph.period_s(),
        };
        let goals = TaskGoals::on(
            learning::tasks::Task::PickAndPlace,
            Tolerances::default(),
            robot,
        )
        .unwrap();
        let params = SimParams {
            candidates: 8,
            ..SimParams::default()
        };
        let q0 = robot.named_pose("home").unwrap().to_vec();
        for spec in ["bundled", "modeswitch"] {
            let make = || {
                mapper::LoadedModel::load_for(spec, robot)
                    .map(|m| m.at_period(sim.period_s))
                    .map_err(|source| SimError::Model {
                        spec: spec.into(),
                        source,
                    })
            };
            let setup = AttemptSetup {
                sim: &sim,
                start_q: &q0,
                goals: &goals,
                time_limit_s: 3.0,
                params: &params,
                model: &make,
                seed: 5,
                aim_out: None,
                learned: None,
                demos: None,
            };
            let info = AttemptInfo {
                spec,
                name: format!("P01-t1-c1-a1-{spec}"),
                task: "pick-and-place",
                goals: "pick-and-place",
            };
            let trial = BTreeMap::from([
                ("task".to_owned(), info.task.to_owned()),
                ("goals".to_owned(), info.goals.to_owned()),
            ]);
            let r = run_recorded(&setup, &info, &dir, &graph, trial).unwrap();
            let rel = r.recording.clone().unwrap();
            assert_eq!(rel, format!("recordings/P01-t1-c1-a1-{spec}.mcap"));
            let path = dir.join(&rel);
            let rec = replay::Recording::read(&path).unwrap();
            let (out, _) = replay::replay(&rec, None).unwrap();
            let ticks = (3.0 / sim.period_s).round() as u64;
            assert_eq!(out.ticks, ticks, "{spec}: {out:?}");
            assert_eq!(out.identical, out.ticks, "{spec}: {out:?}");
            assert_eq!(out.mapper_commands, ticks, "{spec}: {out:?}");
            assert_eq!(out.mapper_identical, ticks, "{spec}: {out:?}");
            assert_eq!(out.skipped, 0, "{spec}: {out:?}");
            assert!(out.notes.is_empty(), "{spec}: {:?}", out.notes);
            // One tracker note per tick, on its channel.
            let mut notes = 0u64;
            recording::read_file(&path, |ev| {
                if let recording::Event::Message { channel, data, .. } = ev
                    && channel.topic == OPERATOR_TOPIC
                {
                    let n: study::simulate::TickNote = serde_json::from_slice(data).unwrap();
                    assert_eq!(n.tick, notes);
                    notes += 1;
                }
                Ok(())
            })
            .unwrap();
            assert_eq!(notes, ticks);
            // Exported to LeRobot: an episode of its study task, every tick with the stick
            // and safety's flags the recording has and the map's mode of the tick.
            let lr = dir.join(format!("lerobot-{spec}"));
            let x = learning::to_dataset::export_lerobot(
                std::slice::from_ref(&path),
                &lr,
                robot.name(),
                None,
            )
            .unwrap();
            assert_eq!(x.frames as u64, ticks);
            let tasks = std::fs::read(lr.join(learning::lerobot::TASKS_PATH)).unwrap();
            let want = format!(
                "pick-and-place: {}",
                learning::tasks::Task::PickAndPlace.instructions()
            );
            assert!(
                tasks.windows(want.len()).any(|w| w == want.as_bytes()),
                "{spec}: the task text is in tasks.parquet"
            );
            let info_json: serde_json::Value = serde_json::from_slice(
                &std::fs::read(lr.join(learning::lerobot::INFO_PATH)).unwrap(),
            )
            .unwrap();
            assert_eq!(info_json["total_tasks"], 1);
            let stats: serde_json::Value = serde_json::from_slice(
                &std::fs::read(lr.join(learning::lerobot::STATS_PATH)).unwrap(),
            )
            .unwrap();
            let mode = &stats[learning::lerobot::column::MODE];
            if spec == "modeswitch" {
                assert!(mode["min"][0].as_f64().unwrap() >= 1.0, "{spec}: {mode}");
            } else {
                assert_eq!(mode["max"][0], 0.0, "{spec}: a map without modes: {mode}");
            }
            // Nothing is written over.
            let e = run_recorded(&setup, &info, &dir, &graph, BTreeMap::new()).unwrap_err();
            assert!(e.to_string().contains(&rel), "{e}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
