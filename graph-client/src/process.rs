//! What each process of the graph runs, as the recorder finds it: the first heartbeat of a
//! mapper or safety process (at start, at every swap and restart) names its pid; its command
//! line and working directory come from `/proc` at once (on the subscriber thread: procfs, no
//! disk), and the writer thread then reads the files they name (the model, the graph TOML),
//! embeds them as attachments with their SHA-256 and writes a [`recording::PROCESS_METADATA`]
//! record. A replay of the recording ([`recording`] readers, `scl replay`) takes the model and
//! the safety configuration from there.
//!
//! The gateway serves the same capture to other machines ([`capture_bytes`]: what [`capture`]
//! writes, as a small MCAP file of its own); a remote recorder reads it back ([`Captured`])
//! and writes exactly those records into its recording.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use ipc_types::{NodeRole, NodeStatus};
use recording::{LogWriter, RecordError};
use scl_config::GraphConfig;

/// Which heartbeats name a process to capture: a mapper's or safety's, the first from each
/// pid (the local recorder, the live server, the gateway and the remote observers all keep
/// one).
#[derive(Debug, Default)]
pub struct NewProcesses {
    seen: BTreeSet<u32>,
}

impl NewProcesses {
    /// The role of the process `st` comes from, if it is a mapper or safety process not seen
    /// before (it is seen from now on).
    pub fn first(&mut self, st: &NodeStatus) -> Option<NodeRole> {
        let role = NodeRole::from_u32(st.role)?;
        (matches!(role, NodeRole::Mapper | NodeRole::Safety) && self.seen.insert(st.pid))
            .then_some(role)
    }
}

/// A process seen for the first time, with what `/proc` said about it.
#[derive(Debug, Clone)]
pub struct ProcessSeen {
    /// Its role.
    pub role: NodeRole,
    /// Its pid.
    pub pid: u32,
    /// Mapper id (mappers).
    pub mapper_id: u32,
    /// Its heartbeat's time (ns): the attachment's log time.
    pub t_ns: u64,
    /// Its command line, or why it could not be read.
    pub argv: Result<Vec<String>, String>,
    /// Its working directory (relative paths of its command line are against it).
    pub cwd: Option<PathBuf>,
}

impl ProcessSeen {
    /// Reads the command line and working directory of the process `st` comes from.
    pub fn of(st: &NodeStatus, role: NodeRole) -> Self {
        let argv = std::fs::read(format!("/proc/{}/cmdline", st.pid))
            .map(|b| {
                b.split(|c| *c == 0)
                    .filter(|a| !a.is_empty())
                    .map(|a| String::from_utf8_lossy(a).into_owned())
                    .collect()
            })
            .map_err(|e| format!("cannot read /proc/{}/cmdline: {e}", st.pid));
        Self {
            role,
            pid: st.pid,
            mapper_id: st.mapper_id,
            t_ns: st.t_ns,
            argv,
            cwd: std::fs::read_link(format!("/proc/{}/cwd", st.pid)).ok(),
        }
    }
}

/// The value of option `--name` in `argv` (`--name VALUE` or `--name=VALUE`).
pub fn option(argv: &[String], name: &str) -> Option<String> {
    let flag = format!("--{name}");
    let eq = format!("--{name}=");
    argv.iter().enumerate().find_map(|(i, a)| {
        if *a == flag {
            argv.get(i + 1).cloned()
        } else {
            a.strip_prefix(&eq).map(str::to_owned)
        }
    })
}

/// `p` against the working directory `cwd` of the process whose command line names it.
pub fn resolve(cwd: Option<&Path>, p: &str) -> PathBuf {
    let p = Path::new(p);
    match cwd {
        Some(d) if p.is_relative() => d.join(p),
        _ => p.to_owned(),
    }
}

/// What a mapper or safety process runs, from its command line: the graph configuration it
/// reads (`--config`, else the defaults) and, for a mapper, its model spec (`--model`, else the
/// configuration's; a file resolved against the process's working directory).
pub fn runs(p: &ProcessSeen) -> (Option<GraphConfig>, Option<String>) {
    let Ok(argv) = &p.argv else {
        return (None, None);
    };
    let cwd = p.cwd.as_deref();
    let config_path = option(argv, "config").map(|c| resolve(cwd, &c));
    let cfg = GraphConfig::load(config_path.as_deref()).ok();
    let model = if p.role == NodeRole::Mapper {
        option(argv, "model").or_else(|| cfg.as_ref().map(|c| c.mapper.model.clone()))
    } else {
        None
    };
    let model = model.map(|spec| {
        if mapper::model::is_builtin(&spec) {
            spec
        } else {
            resolve(cwd, &spec).display().to_string()
        }
    });
    (cfg, model)
}

/// Writes what `p` runs into the recording: attachments and one metadata record. A file
/// that cannot be read is named in the record's `error` entry (the recording goes on).
pub fn capture<W: std::io::Write>(
    w: &mut LogWriter<W>,
    p: &ProcessSeen,
) -> Result<(), RecordError> {
    let mut m = BTreeMap::new();
    m.insert("role".to_owned(), p.role.name().to_owned());
    m.insert("pid".to_owned(), p.pid.to_string());
    m.insert("t_ns".to_owned(), p.t_ns.to_string());
    if p.role == NodeRole::Mapper {
        m.insert("mapper_id".to_owned(), p.mapper_id.to_string());
    }
    if let Some(d) = &p.cwd {
        m.insert("cwd".to_owned(), d.display().to_string());
    }
    let argv = match &p.argv {
        Ok(a) => a.clone(),
        Err(e) => {
            m.insert("error".to_owned(), e.clone());
            w.write_metadata(&recording::metadata(recording::PROCESS_METADATA, m))?;
            return Ok(());
        }
    };
    m.insert(
        "argv".to_owned(),
        serde_json::to_string(&argv).unwrap_or_default(),
    );
    let cwd = p.cwd.as_deref();
    let config_path = option(&argv, "config").map(|c| resolve(cwd, &c));
    let mut errors = Vec::new();
    let cfg = match GraphConfig::load(config_path.as_deref()) {
        Ok(c) => Some(c),
        Err(e) => {
            errors.push(e.to_string());
            None
        }
    };
    if let Some(c) = &config_path {
        m.insert("config_path".to_owned(), c.display().to_string());
    }
    let spec = (p.role == NodeRole::Mapper)
        .then(|| option(&argv, "model").or_else(|| cfg.as_ref().map(|c| c.mapper.model.clone())))
        .flatten();
    let runs = Runs {
        role: p.role,
        pid: p.pid,
        mapper_id: p.mapper_id,
        t_ns: p.t_ns,
        cfg: cfg.as_ref(),
        model_spec: spec,
        cwd,
    };
    write_runs(w, &runs, m, errors)
}

/// What a mapper or safety process runs, as [`embed`] is told it.
#[derive(Debug, Clone)]
pub struct Runs<'a> {
    /// Its role.
    pub role: NodeRole,
    /// Its pid (or a stand-in: the attachments are named by it).
    pub pid: u32,
    /// Mapper id (mappers).
    pub mapper_id: u32,
    /// When it was first seen (ns): the attachments' log time.
    pub t_ns: u64,
    /// The graph configuration it reads.
    pub cfg: Option<&'a GraphConfig>,
    /// A mapper's model spec (a file against `cwd`).
    pub model_spec: Option<String>,
    /// Its working directory.
    pub cwd: Option<&'a Path>,
}

/// Writes what a process runs into the recording as [`capture`] does, told rather than read
/// from `/proc` (a graph run in process: `scl study simulate --record`).
pub fn embed<W: std::io::Write>(w: &mut LogWriter<W>, r: &Runs<'_>) -> Result<(), RecordError> {
    let mut m = BTreeMap::new();
    m.insert("role".to_owned(), r.role.name().to_owned());
    m.insert("pid".to_owned(), r.pid.to_string());
    m.insert("t_ns".to_owned(), r.t_ns.to_string());
    if r.role == NodeRole::Mapper {
        m.insert("mapper_id".to_owned(), r.mapper_id.to_string());
    }
    write_runs(w, r, m, Vec::new())
}

/// The configuration and model entries and attachments of `r`, then the record `m`.
fn write_runs<W: std::io::Write>(
    w: &mut LogWriter<W>,
    r: &Runs<'_>,
    mut m: BTreeMap<String, String>,
    mut errors: Vec<String>,
) -> Result<(), RecordError> {
    let cfg = r.cfg;
    let cwd = r.cwd;
    let p = r;
    if let Some(cfg) = &cfg {
        m.insert("robot".to_owned(), cfg.graph.robot.clone());
        m.insert("period_s".to_owned(), cfg.period_s().to_string());
    }
    match p.role {
        NodeRole::Safety => {
            if let Some(cfg) = &cfg {
                match toml::to_string(cfg) {
                    Ok(text) => {
                        let name = format!("config/safety/{}/graph.toml", p.pid);
                        w.attach(&name, p.t_ns, "application/toml", text.as_bytes())?;
                        m.insert("config_attachment".to_owned(), name);
                        m.insert(
                            "config_sha256".to_owned(),
                            recording::sha256_hex(text.as_bytes()),
                        );
                    }
                    Err(e) => errors.push(format!("cannot write the configuration: {e}")),
                }
            }
        }
        NodeRole::Mapper => {
            if let Some(spec) = p.model_spec.clone() {
                let builtin = mapper::model::is_builtin(&spec);
                m.insert("model_spec".to_owned(), spec.clone());
                let bytes = if spec == mapper::model::BUNDLED_NAME {
                    // The graph's robot's bundled model.
                    let robot = cfg
                        .as_ref()
                        .map_or(Ok(kinematics::RobotProfile::default_robot()), |c| {
                            kinematics::RobotProfile::by_name(&c.graph.robot)
                        });
                    Some(
                        robot
                            .map_err(|e| e.to_string())
                            .and_then(|r| mapper::model::bundled(r).map_err(|e| e.to_string()))
                            .map(<[u8]>::to_vec),
                    )
                } else if builtin {
                    None
                } else {
                    let path = resolve(cwd, &spec);
                    m.insert("model_path".to_owned(), path.display().to_string());
                    Some(
                        std::fs::read(&path)
                            .map_err(|e| format!("cannot read the model {}: {e}", path.display())),
                    )
                };
                match bytes {
                    Some(Ok(b)) => {
                        let file = Path::new(&spec)
                            .file_name()
                            .map_or_else(|| spec.clone(), |f| f.to_string_lossy().into_owned());
                        let name = format!("model/mapper-{}/{}/{file}", p.mapper_id, p.pid);
                        w.attach(&name, p.t_ns, "application/octet-stream", &b)?;
                        m.insert("model_attachment".to_owned(), name);
                        m.insert("model_sha256".to_owned(), recording::sha256_hex(&b));
                        m.insert("model_bytes".to_owned(), b.len().to_string());
                    }
                    Some(Err(e)) => errors.push(e),
                    None => {}
                }
            }
        }
        _ => {}
    }
    if !errors.is_empty() {
        tracing::warn!(pid = p.pid, role = p.role.name(), "{}", errors.join("; "));
        m.insert("error".to_owned(), errors.join("; "));
    }
    w.write_metadata(&recording::metadata(recording::PROCESS_METADATA, m))
}

/// The name a capture's bytes are read and written under (in error messages).
const CAPTURE_NAME: &str = "process-capture.mcap";

/// [`capture`] into an MCAP file of its own: the bytes the gateway serves for process `p`.
pub fn capture_bytes(p: &ProcessSeen) -> Result<Vec<u8>, RecordError> {
    let mut w = LogWriter::new(Vec::new(), Path::new(CAPTURE_NAME), None)?;
    capture(&mut w, p)?;
    w.finish(None)
}

/// One attachment of a capture.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CapturedFile {
    /// The attachment's name (`model/mapper-<id>/<pid>/<file>`, `config/safety/<pid>/graph.toml`).
    pub name: String,
    /// Its log time (ns).
    pub log_time: u64,
    /// Its media type.
    pub media_type: String,
    /// Its bytes.
    pub data: Vec<u8>,
}

/// What [`capture`] wrote for one process, read back from [`capture_bytes`]' bytes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Captured {
    /// The [`recording::PROCESS_METADATA`] record's entries.
    pub entries: BTreeMap<String, String>,
    /// The attachments, in the order they were written.
    pub attachments: Vec<CapturedFile>,
}

/// Why a capture's bytes were refused.
#[derive(Debug, thiserror::Error)]
pub enum CaptureError {
    /// The bytes are not a readable MCAP file.
    #[error("the capture of process {pid} from {from}: {source}")]
    Read {
        /// The process asked for.
        pid: u32,
        /// Where the bytes came from.
        from: String,
        /// Why.
        #[source]
        source: RecordError,
    },
    /// The file is readable but not one capture of this process.
    #[error("the capture of process {pid} from {from}: {reason}")]
    Content {
        /// The process asked for.
        pid: u32,
        /// Where the bytes came from.
        from: String,
        /// What was wrong.
        reason: String,
    },
}

impl Captured {
    /// Reads the capture of process `pid` from `bytes` (which came `from`: named in errors):
    /// a complete MCAP file with one [`recording::PROCESS_METADATA`] record of that pid, and
    /// every attachment the record names.
    pub fn read(bytes: &[u8], pid: u32, from: &str) -> Result<Self, CaptureError> {
        let content = |reason: String| CaptureError::Content {
            pid,
            from: from.to_owned(),
            reason,
        };
        let mut records = Vec::new();
        let mut attachments = Vec::new();
        let summary = recording::read(bytes, Path::new(CAPTURE_NAME), |ev| {
            match ev {
                recording::Event::Metadata { name, entries }
                    if name == recording::PROCESS_METADATA =>
                {
                    records.push(entries.clone());
                }
                recording::Event::Attachment {
                    name,
                    log_time,
                    media_type,
                    data,
                } => attachments.push(CapturedFile {
                    name: name.to_owned(),
                    log_time,
                    media_type: media_type.to_owned(),
                    data: data.to_vec(),
                }),
                _ => {}
            }
            Ok(())
        })
        .map_err(|source| CaptureError::Read {
            pid,
            from: from.to_owned(),
            source,
        })?;
        if !summary.complete {
            return Err(content(format!(
                "the file is cut ({})",
                summary
                    .stopped
                    .map_or_else(|| "no end".to_owned(), |s| format!("{s:?}"))
            )));
        }
        let [entries] = <[_; 1]>::try_from(records)
            .map_err(|r| content(format!("{} process records, not one", r.len())))?;
        if entries.get("pid").map(String::as_str) != Some(pid.to_string().as_str()) {
            return Err(content(format!(
                "its record is of process {}",
                entries.get("pid").map_or("(none)", String::as_str)
            )));
        }
        for key in ["model_attachment", "config_attachment"] {
            if let Some(name) = entries.get(key)
                && !attachments.iter().any(|a| &a.name == name)
            {
                return Err(content(format!("its record names {name}, which it lacks")));
            }
        }
        Ok(Self {
            entries,
            attachments,
        })
    }

    /// Writes the capture into `w` as [`capture`] wrote it: the attachments, then the record.
    pub fn write_to<W: std::io::Write>(&self, w: &mut LogWriter<W>) -> Result<(), RecordError> {
        for a in &self.attachments {
            w.attach(&a.name, a.log_time, &a.media_type, &a.data)?;
        }
        w.write_metadata(&recording::metadata(
            recording::PROCESS_METADATA,
            self.entries.clone(),
        ))
    }

    /// The attachments by name (what `viz::convert::apply_process_record` looks them up in).
    pub fn attachment_map(&self) -> std::collections::HashMap<String, Vec<u8>> {
        self.attachments
            .iter()
            .map(|a| (a.name.clone(), a.data.clone()))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bundled_mapper() -> ProcessSeen {
        ProcessSeen {
            role: NodeRole::Mapper,
            pid: 42,
            mapper_id: 3,
            t_ns: 7,
            argv: Ok(vec![
                "scl".into(),
                "mapper".into(),
                "--model".into(),
                "bundled".into(),
            ]),
            cwd: None,
        }
    }

    #[test]
    fn a_mapper_or_safety_process_is_new_once_and_other_roles_never() {
        let status = |role: NodeRole, pid: u32| {
            let mut st = NodeStatus::new(role, ipc_types::phase::RUNNING, 5);
            st.pid = pid;
            st
        };
        let mut n = NewProcesses::default();
        assert_eq!(
            n.first(&status(NodeRole::Mapper, 7)),
            Some(NodeRole::Mapper)
        );
        assert_eq!(n.first(&status(NodeRole::Mapper, 7)), None);
        assert_eq!(
            n.first(&status(NodeRole::Safety, 8)),
            Some(NodeRole::Safety)
        );
        assert_eq!(n.first(&status(NodeRole::Bridge, 9)), None);
        let mut bad = status(NodeRole::Mapper, 10);
        bad.role = 999;
        assert_eq!(n.first(&bad), None);
        assert_eq!(
            n.first(&status(NodeRole::Mapper, 10)),
            Some(NodeRole::Mapper)
        );
    }

    /// Written through its bytes, a capture is the same records as written directly.
    #[test]
    fn a_capture_read_back_from_its_bytes_writes_the_same_records() {
        let p = bundled_mapper();
        let direct = {
            let mut w = LogWriter::new(Vec::new(), Path::new("a.mcap"), None).unwrap();
            capture(&mut w, &p).unwrap();
            w.finish(None).unwrap()
        };
        let bytes = capture_bytes(&p).unwrap();
        let c = Captured::read(&bytes, 42, "test").unwrap();
        assert_eq!(c.attachments.len(), 1);
        assert_eq!(c.entries["model_spec"], "bundled");
        let through = {
            let mut w = LogWriter::new(Vec::new(), Path::new("a.mcap"), None).unwrap();
            c.write_to(&mut w).unwrap();
            w.finish(None).unwrap()
        };
        assert_eq!(direct, through);
        assert_eq!(c.attachment_map().len(), 1);
    }

    #[test]
    fn a_corrupt_cut_or_foreign_capture_is_refused_naming_the_process() {
        let bytes = capture_bytes(&bundled_mapper()).unwrap();
        let e = Captured::read(&bytes, 43, "gw").unwrap_err().to_string();
        assert!(
            e.contains("process 43 from gw") && e.contains("of process 42"),
            "{e}"
        );
        // Cut before its end (in the model's bytes, or before anything).
        for cut in [0, 8, bytes.len() / 3, bytes.len() / 2] {
            let Err(e) = Captured::read(&bytes[..cut], 42, "gw") else {
                panic!("a capture cut at {cut} of {} was taken", bytes.len());
            };
            let e = e.to_string();
            assert!(e.contains("process 42 from gw"), "{cut}: {e}");
        }
        let mut flipped = bytes.clone();
        for i in (20..flipped.len()).step_by(37) {
            flipped[i] ^= 0x5a;
        }
        assert!(Captured::read(&flipped, 42, "gw").is_err());
        // A file with no process record.
        let empty = LogWriter::new(Vec::new(), Path::new("e.mcap"), None)
            .unwrap()
            .finish(None)
            .unwrap();
        let e = Captured::read(&empty, 42, "gw").unwrap_err().to_string();
        assert!(e.contains("0 process records"), "{e}");
    }

    #[test]
    fn options_in_both_spellings() {
        let argv: Vec<String> = [
            "scl",
            "mapper",
            "--model",
            "a b.safetensors",
            "--config=g.toml",
        ]
        .iter()
        .map(|s| (*s).to_owned())
        .collect();
        assert_eq!(option(&argv, "model").as_deref(), Some("a b.safetensors"));
        assert_eq!(option(&argv, "config").as_deref(), Some("g.toml"));
        assert_eq!(option(&argv, "id"), None);
        assert_eq!(
            resolve(Some(Path::new("/w")), "m.safetensors"),
            Path::new("/w/m.safetensors")
        );
        assert_eq!(resolve(Some(Path::new("/w")), "/m"), Path::new("/m"));
    }

    #[test]
    fn a_mapper_of_the_bundled_model_embeds_it_with_its_digest() {
        let p = bundled_mapper();
        let bundled = mapper::model::bundled(kinematics::RobotProfile::default_robot()).unwrap();
        let path = Path::new("p.mcap");
        let mut w = LogWriter::new(Vec::new(), path, None).unwrap();
        capture(&mut w, &p).unwrap();
        let bytes = w.finish(None).unwrap();
        let (mut att, mut meta) = (Vec::new(), Vec::new());
        recording::read(&bytes[..], path, |ev| {
            match ev {
                recording::Event::Attachment { name, data, .. } => {
                    att.push((name.to_owned(), data.len()));
                }
                recording::Event::Metadata { name, entries } => {
                    meta.push((name.to_owned(), entries.clone()));
                }
                _ => {}
            }
            Ok(())
        })
        .unwrap();
        assert_eq!(
            att,
            vec![("model/mapper-3/42/bundled".to_owned(), bundled.len())]
        );
        let m = &meta[0].1;
        assert_eq!(meta[0].0, recording::PROCESS_METADATA);
        assert_eq!(m["model_sha256"], recording::sha256_hex(bundled));
        assert_eq!(m["model_spec"], "bundled");
        assert_eq!(m["robot"], "gen3_lite");
        assert!(!m.contains_key("error"), "{m:?}");
    }
}
