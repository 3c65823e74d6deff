//! What a recording says beyond its robot states, for the episode it becomes: the operator's
//! side of each tick (the stick the mapper used, the map's mode, safety's command flags), the
//! map the run served (its kind and its model file's SHA-256) and the study task of an
//! attempt. [`RunSide::take`] gathers it from the events of the one pass that reads the
//! states; the per-frame values are resolved afterwards ([`RunSide::operator`]).

use std::collections::BTreeMap;
use std::path::Path;

use ipc_types::{MapperCommand, NO_TICK, NodeRole, NodeStatus, SafeCommand};
use mapper::model::ModelKind;
use recording::{Event, RecordError, Topic};

/// The metadata record naming a study attempt (`scl study run`, `scl study simulate
/// --record`): its `task` entry is the study task's name, `goals` which of the paper's tasks
/// its goals are (when not the name).
pub const TRIAL_METADATA: &str = "scl.trial";

/// The operator's side of one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OperatorTick {
    /// The 2-D stick input the mapper used for the tick (`MapperCommand::action`).
    pub stick: [f64; 2],
    /// The map's mode as the mapper's heartbeat gives it (`NodeStatus::mode`: 0 for a map
    /// without modes, 1 + the mode's index otherwise), latest at or before the tick.
    pub mode: i64,
    /// Safety's flags on the tick's executed command (`SafeCommand::flags`).
    pub safety_flags: i64,
}

impl OperatorTick {
    /// A tick with nothing recorded for it: the stick at rest, the mode unknown (-1, which
    /// no heartbeat carries), no safety flag.
    pub const FILL: OperatorTick = OperatorTick {
        stick: [0.0, 0.0],
        mode: -1,
        safety_flags: 0,
    };
}

/// The map a run served.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ServedModel {
    /// Its kind (`scl`, `pca`, `cae`, `modeswitch`, `constant`, `goto`); empty when the
    /// recording does not say.
    pub kind: String,
    /// The SHA-256 (hex) of its model file as the recording embeds it; empty for a built-in
    /// map without a file (mode switching, the drill and go-to maps) or when the recording
    /// holds no model.
    pub sha256: String,
}

/// What a recording holds besides its robot states, gathered message by message.
#[derive(Debug, Default)]
pub struct RunSide {
    /// Mapper commands by (tick, mapper id).
    sticks: BTreeMap<(u64, u32), [f32; 2]>,
    /// Safety's command per tick: (the mapper it forwarded, its flags).
    safe: BTreeMap<u64, (u32, u32)>,
    /// Mapper heartbeats' modes by mapper id and tick (the last in file order of a tick).
    modes: BTreeMap<u32, BTreeMap<u64, u32>>,
    /// Mapper process records, in file order.
    processes: Vec<BTreeMap<String, String>>,
    /// Model attachments' kinds by attachment name (`None`: the header did not read).
    models: BTreeMap<String, Option<ModelKind>>,
    /// The `scl.trial` record's entries.
    trial: BTreeMap<String, String>,
    /// Operator-side channels in another format than this build decodes (skipped).
    skipped: Vec<String>,
}

impl RunSide {
    /// Takes one event of recording `path`: the operator-side messages, the mapper process
    /// records and model attachments, the trial record. A message that does not decode is
    /// an error naming the file; a channel of an older format is skipped (its ticks get
    /// [`OperatorTick::FILL`]) and said once.
    pub fn take(&mut self, path: &Path, ev: &Event<'_>) -> Result<(), RecordError> {
        match ev {
            Event::Message {
                channel,
                sequence,
                data,
                ..
            } => {
                let Some(topic) = Topic::from_channel(&channel.topic) else {
                    return Ok(());
                };
                if !matches!(
                    topic,
                    Topic::MapperCommand | Topic::SafeCommand | Topic::Status
                ) {
                    return Ok(());
                }
                if channel.format() != recording::FORMAT {
                    if !self.skipped.contains(&channel.topic) {
                        tracing::warn!(
                            "{}: channel {} is in recording format {}; its operator-side values are exported as the fill values",
                            path.display(),
                            channel.topic,
                            channel.format()
                        );
                        self.skipped.push(channel.topic.clone());
                    }
                    return Ok(());
                }
                match topic {
                    Topic::MapperCommand => {
                        let c: MapperCommand = recording::decode(path, channel, *sequence, data)?;
                        self.sticks.entry((c.tick, c.mapper_id)).or_insert(c.action);
                    }
                    Topic::SafeCommand => {
                        let c: SafeCommand = recording::decode(path, channel, *sequence, data)?;
                        self.safe.entry(c.tick).or_insert((c.mapper_id, c.flags));
                    }
                    _ => {
                        let s: NodeStatus = recording::decode(path, channel, *sequence, data)?;
                        if s.role == NodeRole::Mapper as u32 && s.tick != NO_TICK {
                            self.modes
                                .entry(s.mapper_id)
                                .or_default()
                                .insert(s.tick, s.mode);
                        }
                    }
                }
            }
            Event::Metadata { name, entries } => {
                if *name == recording::PROCESS_METADATA
                    && entries.get("role").map(String::as_str) == Some(NodeRole::Mapper.name())
                {
                    self.processes.push((*entries).clone());
                } else if *name == TRIAL_METADATA {
                    self.trial
                        .extend(entries.iter().map(|(k, v)| (k.clone(), v.clone())));
                }
            }
            Event::Attachment { name, data, .. } if name.starts_with("model/") => {
                let kind = match mapper::model::read_header(data, Path::new(name)) {
                    Ok(h) => Some(h.kind),
                    Err(e) => {
                        tracing::warn!(
                            "{}: the embedded model {name} does not read ({e}); its kind is exported empty",
                            path.display()
                        );
                        None
                    }
                };
                self.models.insert((*name).to_owned(), kind);
            }
            _ => {}
        }
        Ok(())
    }

    /// The mapper safety forwarded at or most recently before `tick`.
    fn active(&self, tick: u64) -> Option<u32> {
        self.safe.range(..=tick).next_back().map(|(_, (id, _))| *id)
    }

    /// The operator's side of each of `ticks` (the frames' ticks). The stick is the mapper
    /// command of the tick from the mapper safety forwarded (at the tick, else most recently
    /// before it; the lowest mapper id's when no safe command came yet); the mode that
    /// mapper's heartbeat latest at or before the tick; the flags the tick's safe command's.
    /// What is not recorded is [`OperatorTick::FILL`]'s.
    pub fn operator(&self, ticks: &[u64]) -> Vec<OperatorTick> {
        ticks
            .iter()
            .map(|&k| {
                let active = self.active(k);
                let stick = match active {
                    Some(id) => self.sticks.get(&(k, id)).map(|a| (id, *a)),
                    None => self
                        .sticks
                        .range((k, 0)..=(k, u32::MAX))
                        .next()
                        .map(|((_, id), a)| (*id, *a)),
                };
                let mapper = stick
                    .map(|(id, _)| id)
                    .or(active)
                    .or_else(|| self.modes.keys().next().copied());
                let mode = mapper
                    .and_then(|id| self.modes.get(&id))
                    .and_then(|beats| beats.range(..=k).next_back())
                    .map(|(_, mode)| *mode)
                    .map_or(OperatorTick::FILL.mode, i64::from);
                OperatorTick {
                    stick: stick.map_or(OperatorTick::FILL.stick, |(_, a)| {
                        [f64::from(a[0]), f64::from(a[1])]
                    }),
                    mode,
                    safety_flags: self
                        .safe
                        .get(&k)
                        .map_or(OperatorTick::FILL.safety_flags, |(_, f)| i64::from(*f)),
                }
            })
            .collect()
    }

    /// The map the run served: that of the mapper safety forwarded most often (the lowest
    /// mapper id of a recording without safe commands), as its first process record names
    /// it. `source` names the recording in a warning when that mapper served more than one
    /// model (a restart with another file).
    pub fn served_model(&self, source: &str) -> ServedModel {
        let mut counts: BTreeMap<u32, usize> = BTreeMap::new();
        for (id, _) in self.safe.values() {
            *counts.entry(*id).or_default() += 1;
        }
        let id_of =
            |p: &BTreeMap<String, String>| p.get("mapper_id").and_then(|s| s.parse::<u32>().ok());
        let chosen = counts
            .iter()
            .max_by_key(|(id, n)| (**n, std::cmp::Reverse(**id)))
            .map(|(id, _)| *id)
            .or_else(|| self.processes.iter().filter_map(id_of).min());
        let records: Vec<&BTreeMap<String, String>> = self
            .processes
            .iter()
            .filter(|p| chosen.is_some() && id_of(p) == chosen)
            .collect();
        let Some(first) = records.first() else {
            return ServedModel::default();
        };
        let sha = |p: &BTreeMap<String, String>| p.get("model_sha256").cloned().unwrap_or_default();
        if records.iter().any(|p| sha(p) != sha(first)) {
            tracing::warn!(
                "{source}: mapper {} served more than one model; the episode names the first",
                chosen.unwrap_or_default()
            );
        }
        let kind = match first.get("model_attachment") {
            Some(name) => self.models.get(name).copied().flatten(),
            None => first.get("model_spec").and_then(|s| builtin_kind(s)),
        };
        ServedModel {
            kind: kind.map(|k| k.to_string()).unwrap_or_default(),
            sha256: sha(first),
        }
    }

    /// The study task of an attempt's recording as the episode's task text
    /// ([`task_text`]), if its `scl.trial` record names one.
    pub fn study_task(&self) -> Option<String> {
        let name = self.trial.get("task")?;
        let goals = self.trial.get("goals").unwrap_or(name);
        Some(task_text(name, goals))
    }
}

/// The study task of a simulated attempt's recording whose `scl.trial` record does not name
/// it (recorded before it did): the `task` of the row of `trials.csv` in the participant's
/// directory (`Pnn/`, the parent of the recording's `recordings/` directory) whose
/// `recording` column names the file, as [`task_text`] words it. `None` when the recording
/// is not in such a directory or no row names it; a `trials.csv` that does not read is an
/// error naming it.
pub fn study_task_from_trials(recording: &Path) -> Result<Option<String>, super::LeRobotError> {
    let (Some(dir), Some(file)) = (recording.parent(), recording.file_name()) else {
        return Ok(None);
    };
    if dir.file_name().and_then(|d| d.to_str()) != Some("recordings") {
        return Ok(None);
    }
    let Some(participant) = dir.parent() else {
        return Ok(None);
    };
    let trials = participant.join("trials.csv");
    if !trials.is_file() {
        return Ok(None);
    }
    let csv_error = |source| super::LeRobotError::Csv {
        path: trials.clone(),
        source,
    };
    let mut r = csv::Reader::from_path(&trials).map_err(csv_error)?;
    let headers = r.headers().map_err(csv_error)?.clone();
    let column = |name: &str| headers.iter().position(|h| h == name);
    let (Some(rec_col), Some(task_col)) = (column("recording"), column("task")) else {
        return Ok(None);
    };
    let want = Path::new("recordings").join(file);
    for row in r.records() {
        let row = row.map_err(csv_error)?;
        if row.get(rec_col).map(Path::new) == Some(want.as_path())
            && let Some(task) = row.get(task_col)
        {
            return Ok(Some(task_text(task, task)));
        }
    }
    Ok(None)
}

/// The kind of a built-in map's spec (one served without a file).
fn builtin_kind(spec: &str) -> Option<ModelKind> {
    if mapper::modeswitch::is_spec(spec) {
        Some(ModelKind::ModeSwitch)
    } else if mapper::constant::is_spec(spec) {
        Some(ModelKind::Constant)
    } else if mapper::goto::is_spec(spec) {
        Some(ModelKind::Goto)
    } else {
        None
    }
}

/// The task text of an episode of study task or demonstration task `name` whose goals are
/// the paper's task `goals`: `name: instructions` (the instructions of
/// [`crate::tasks::Task::instructions`]), or `name` alone for goals this stack has no
/// instructions for.
pub fn task_text(name: &str, goals: &str) -> String {
    match crate::tasks::Task::from_name(goals) {
        Ok(t) => format!("{name}: {}", t.instructions()),
        Err(_) => name.to_owned(),
    }
}
