//! `scl record --convert OLD.mcap --out NEW.mcap`: a copy of a recording with the 3D channels
//! added ([`crate::VizTopic`]), computed from its robot states, commands and heartbeats with
//! the robot, scene and models the recording itself holds (the safety process's embedded
//! graph TOML, the mapper's embedded model); a recording without them gets the default
//! robot and scene, and no map arrows unless its mapper served a built-in model.

use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use mapper::LoadedModel;
use recording::{Event, LogClock, LogWriter, Payload, RecordError, Topic};
use scl_config::GraphConfig;

use crate::{Viz, VizError, VizMessage, VizTopic};

/// Metadata record written at the end of a converted recording.
pub const CONVERTED_METADATA: &str = "scl.converted";

/// What a conversion did.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct ConvertReport {
    /// Messages copied from the source.
    pub copied: u64,
    /// 3D-view messages added.
    pub added: u64,
    /// Robot states seen.
    pub states: u64,
    /// Notes on what could not be shown (no model, no configuration, undecodable messages).
    pub notes: Vec<String>,
}

/// Decodes a message of a graph topic.
pub fn payload(
    path: &Path,
    channel: &recording::ChannelInfo,
    sequence: u32,
    data: &[u8],
) -> Option<Result<Payload, RecordError>> {
    let topic = Topic::from_channel(&channel.topic)?;
    Some(match topic {
        // Robot states of every format (the hand-written format 1 too).
        Topic::RobotState => {
            recording::decode_robot_state(path, channel, sequence, data).map(Payload::RobotState)
        }
        _ => Payload::from_json(topic, data).map_err(|e| RecordError::Decode {
            path: path.to_owned(),
            topic: channel.topic.clone(),
            sequence,
            reason: e.to_string(),
        }),
    })
}

/// What a `scl.process` record says the process ran, applied to `viz`: a safety process's
/// configuration (robot, scene, bounds), a mapper's model. Attachments are looked up in
/// `attachments`; what cannot be used is said in `notes`.
pub fn apply_process_record(
    viz: &mut Viz,
    entries: &BTreeMap<String, String>,
    attachments: &HashMap<String, Vec<u8>>,
    notes: &mut Vec<String>,
) {
    match entries.get("role").map(String::as_str) {
        Some("safety") => {
            let Some(name) = entries.get("config_attachment") else {
                return;
            };
            let Some(bytes) = attachments.get(name) else {
                notes.push(format!("the configuration {name} is not in the file"));
                return;
            };
            let cfg = std::str::from_utf8(bytes)
                .map_err(|e| e.to_string())
                .and_then(|t| GraphConfig::parse(t, Path::new(name)).map_err(|e| e.to_string()));
            match cfg.map(|c| viz.configure(&c).map_err(|e| e.to_string())) {
                Ok(Ok(())) => {}
                Ok(Err(e)) | Err(e) => notes.push(format!("configuration {name}: {e}")),
            }
        }
        Some("mapper") => {
            let Some(id) = entries.get("mapper_id").and_then(|v| v.parse::<u32>().ok()) else {
                return;
            };
            let robot = viz.robot();
            let model = if let Some(name) = entries.get("model_attachment") {
                match attachments.get(name) {
                    Some(bytes) => LoadedModel::from_bytes_for(bytes, Path::new(name), robot)
                        .map_err(|e| e.to_string()),
                    None => Err(format!("the model {name} is not in the file")),
                }
            } else {
                match entries.get("model_spec") {
                    Some(spec) if mapper::model::is_builtin(spec) => {
                        LoadedModel::load_for(spec, robot).map_err(|e| e.to_string())
                    }
                    _ => Err("its model is not in the recording".to_owned()),
                }
            };
            match model {
                Ok(m) => viz.set_model(id, m),
                Err(e) => notes.push(format!("mapper {id}: {e}: no map arrows for it")),
            }
        }
        _ => {}
    }
}

/// Adds the 3D channels to recording `from`, writing `to` (refused if it exists; nothing is
/// left behind on failure). A recording that has them already is refused.
pub fn convert(from: &Path, to: &Path) -> Result<ConvertReport, VizError> {
    let src = std::fs::File::open(from).map_err(|source| RecordError::Io {
        path: from.to_owned(),
        source,
    })?;
    let out = recording::create_new(to)?;
    let result = convert_into(
        std::io::BufReader::new(src),
        from,
        std::io::BufWriter::new(out),
        to,
    );
    if result.is_err() {
        let _ = std::fs::remove_file(to);
    }
    result.map(|(r, _)| r)
}

/// [`convert`] between streams; returns the report and the sink.
pub fn convert_into<R: std::io::Read, W: std::io::Write>(
    src: R,
    from: &Path,
    sink: W,
    to: &Path,
) -> Result<(ConvertReport, W), VizError> {
    let mut w = LogWriter::new(sink, to, None)?;
    let mut viz = Viz::new(&GraphConfig::default())?;
    let viz_ids = add_viz_channels(&mut w)?;
    let mut seq: BTreeMap<VizTopic, u32> = BTreeMap::new();
    let mut attachments: HashMap<String, Vec<u8>> = HashMap::new();
    let mut report = ConvertReport {
        copied: 0,
        added: 0,
        states: 0,
        notes: Vec::new(),
    };
    let mut undecodable = 0u64;
    let mut produced: Vec<VizMessage> = Vec::new();
    let summary = recording::read(src, from, |ev| {
        if let Event::Channel(c) = ev
            && VizTopic::from_topic(&c.topic).is_some()
        {
            return Err(RecordError::Write {
                path: to.to_owned(),
                reason: format!(
                    "{} has the 3D channels already ({}): nothing to convert",
                    from.display(),
                    c.topic
                ),
            });
        }
        w.copy_event(&ev)?;
        match ev {
            Event::Message {
                channel,
                sequence,
                log_time,
                publish_time,
                data,
            } => {
                report.copied += 1;
                // The view's messages on the clock of the message they come from.
                let clock = LogClock::of_message(log_time, publish_time);
                match payload(from, channel, sequence, data) {
                    Some(Ok(p)) => {
                        if matches!(p, Payload::RobotState(_)) {
                            report.states += 1;
                        }
                        produced.clear();
                        if let Err(e) = viz.observe(&p, &mut produced) {
                            return Err(RecordError::Write {
                                path: to.to_owned(),
                                reason: e.to_string(),
                            });
                        }
                        for m in &produced {
                            let s = seq.entry(m.topic).or_default();
                            *s = s.wrapping_add(1);
                            let id = viz_ids.get(&m.topic).copied().unwrap_or_default();
                            w.write_raw(id, *s, clock.log_time(m.t_ns), m.t_ns, &m.data)?;
                            report.added += 1;
                        }
                    }
                    Some(Err(_)) => undecodable += 1,
                    None => {}
                }
            }
            Event::Metadata { name, entries } => {
                if name == recording::PROCESS_METADATA {
                    apply_process_record(&mut viz, entries, &attachments, &mut report.notes);
                }
            }
            Event::Attachment { name, data, .. } => {
                attachments.insert(name.to_owned(), data.to_vec());
            }
            Event::Channel(_) => {}
        }
        Ok(())
    })?;
    if undecodable > 0 {
        report.notes.push(format!(
            "{undecodable} messages did not decode and add nothing"
        ));
    }
    if let Some(s) = &summary.stopped {
        report.notes.push(format!(
            "the source ends early ({s}); converted what it holds"
        ));
    }
    let mut entries = BTreeMap::new();
    entries.insert("source".to_owned(), from.display().to_string());
    entries.insert("copied".to_owned(), report.copied.to_string());
    entries.insert("added".to_owned(), report.added.to_string());
    let sink = w.finish(Some(recording::metadata(CONVERTED_METADATA, entries)))?;
    Ok((report, sink))
}

/// Adds the 3D view's channels to `w`; their ids by topic.
fn add_viz_channels<W: std::io::Write>(
    w: &mut LogWriter<W>,
) -> Result<BTreeMap<VizTopic, u16>, VizError> {
    let mut viz_ids: BTreeMap<VizTopic, u16> = BTreeMap::new();
    for t in VizTopic::ALL {
        let id = w.add_channel(
            t.topic(),
            Some(&t.schema()),
            t.message_encoding(),
            &BTreeMap::new(),
        )?;
        viz_ids.insert(t, id);
    }
    Ok(viz_ids)
}
