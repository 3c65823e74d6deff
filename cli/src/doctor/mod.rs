//! `scl doctor`: is this machine ready to drive the arm?
//!
//! Reads what the checks need (resource limits, capabilities, `/proc` and `/sys` files,
//! `/dev/shm`, the input devices, the configuration and its model, and, with `[bridge] robot =
//! "kortex"`, a read-only session with the arm), hands it to the pure checks of [`checks`],
//! and prints one line per item: ok / warn / fail with what to do. The exit code is non-zero
//! on any fail. Nothing here moves the arm or changes the machine.

pub mod checks;

use std::path::{Path, PathBuf};
use std::time::Duration;

use checks::{Finding, IdleState, InputDevice, KortexAnswer, Limit, ShmGraph};
use scl_config::GraphConfig;

/// How long the Kortex probe may wait to connect and for each reply.
pub const KORTEX_TIMEOUT: Duration = Duration::from_millis(800);

/// Why the doctor could not run at all (a failed check is a finding, not an error).
#[derive(Debug, thiserror::Error)]
pub enum DoctorError {
    /// The report could not be written as JSON.
    #[error("cannot write the report as JSON: {0}")]
    Json(#[from] serde_json::Error),
}

/// `scl doctor`.
#[derive(clap::Args, Debug, Clone)]
#[command(
    about = "Check that this machine is ready to drive the arm: real-time rights, kernel, CPU \
             power settings, shared memory, joysticks, the configuration, its model and (for \
             robot = \"kortex\") the arm itself, read-only. Exit code 1 on any fail"
)]
pub struct DoctorArgs {
    /// Print the findings as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

/// The report, as `--json` prints it.
#[derive(Debug, serde::Serialize)]
pub struct Report {
    /// Every item, in the order checked.
    pub findings: Vec<Finding>,
    /// Whether any item failed.
    pub failed: bool,
}

/// Runs every check on the configuration at `config` (`scl doctor --config FILE`; without
/// it, the defaults: mock arm, scripted joystick, bundled model) and prints the report;
/// returns the exit code (1 on any fail).
pub fn run(config: Option<&Path>, args: &DoctorArgs) -> Result<i32, DoctorError> {
    let findings = examine(config);
    let code = checks::exit_code(&findings);
    if args.json {
        let report = Report {
            failed: code != 0,
            findings,
        };
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print!("{}", checks::render(&findings));
    }
    Ok(code)
}

/// Every finding for the configuration at `config` (or the defaults).
pub fn examine(config: Option<&Path>) -> Vec<Finding> {
    let path_text = config.map_or_else(
        || "the default configuration".to_owned(),
        |p| p.display().to_string(),
    );
    let loaded = GraphConfig::load(config)
        .and_then(|c| {
            c.validate_file(config)?;
            scl_joystick::validate(&c.joystick)?;
            Ok(c)
        })
        .map_err(|e| e.to_string());
    let cfg = loaded.as_ref().ok();
    let caps = std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| checks::parse_caps(&s))
        .unwrap_or_default();
    let realtime = cfg.is_none_or(|c| c.graph.realtime);
    let priority = match cfg {
        Some(c) => c.graph.rt_priority_of(scl_config::RtRole::Bridge),
        None => GraphConfig::default()
            .graph
            .rt_priority_of(scl_config::RtRole::Bridge),
    };
    let mut out = vec![
        checks::realtime_scheduling(priority, rtprio_limit(), caps),
        checks::memory_locking(realtime, memlock_limit(), caps),
        checks::kernel(
            &read("/proc/sys/kernel/version").unwrap_or_default(),
            read("/sys/kernel/realtime").as_deref(),
        ),
        checks::cpu_governor(&governors()),
        checks::cpu_idle(
            read("/sys/devices/system/cpu/cpuidle/current_driver").as_deref(),
            &idle_states(),
        ),
        shm_finding(),
        checks::joysticks(
            cfg.map_or("script", |c| c.joystick.source.as_str()),
            &input_devices(),
        ),
        checks::configuration(
            &path_text,
            loaded.as_ref().map(|_| ()).map_err(Clone::clone),
        ),
    ];
    let Some(cfg) = cfg else {
        return out;
    };
    out.push(checks::wait_strategy(
        &cfg.graph,
        &node_rt::wait::machine_cpus(),
    ));
    out.push(checks::stick_latency(
        &cfg.graph,
        cfg.joystick.sample_margin_us,
    ));
    let robot = match cfg.profile() {
        Ok(r) => r,
        Err(e) => {
            out.push(checks::model(
                &cfg.mapper.model,
                &cfg.graph.robot,
                Err(e.to_string()),
            ));
            return out;
        }
    };
    out.push(checks::model(
        &cfg.mapper.model,
        &cfg.graph.robot,
        mapper::step::MapperStep::load(&cfg.mapper.model, cfg.mapper.id, robot, cfg.period_s())
            .map(|_| ())
            .map_err(|e| e.to_string()),
    ));
    out.push(if cfg.bridge.robot == "kortex" {
        checks::kortex(kortex_answer(cfg), robot, &cfg.safety.max_velocity_rad_s)
    } else {
        checks::kortex_not_used(&cfg.bridge.robot)
    });
    out.push(checks::drills(&config.map_or_else(String::new, |p| {
        format!(" --config {}", p.display())
    })));
    out
}

/// The arm's answer to a read-only session, with the configuration's credentials.
pub fn kortex_answer(cfg: &GraphConfig) -> Result<KortexAnswer, String> {
    let creds = scl_bridge_node::kortex_credentials(
        &cfg.bridge.kortex,
        &scl_bridge_node::CredentialArgs {
            user: std::env::var(scl_bridge_node::USER_ENV).ok(),
            password: std::env::var(scl_bridge_node::PASSWORD_ENV).ok(),
        },
    )
    .map_err(|e| e.to_string())?;
    let info = hw_bridge::kortex::KortexArm::probe(&cfg.bridge.kortex, &creds, KORTEX_TIMEOUT)
        .map_err(|e| e.to_string())?;
    Ok(KortexAnswer {
        addr: info.addr.to_string(),
        firmware: info.firmware(),
        actuators: info.actuators,
        found: info.found,
        speed_limits_rad_s: info.speed_limits_rad_s,
    })
}

fn read(path: &str) -> Option<String> {
    std::fs::read_to_string(path).ok()
}

fn limit_of(resource: nix::sys::resource::Resource) -> Limit {
    match nix::sys::resource::getrlimit(resource) {
        Ok((soft, _)) if soft == nix::sys::resource::RLIM_INFINITY => Limit::Unlimited,
        Ok((soft, _)) => Limit::Value(soft),
        Err(_) => Limit::Value(0),
    }
}

fn rtprio_limit() -> Limit {
    limit_of(nix::sys::resource::Resource::RLIMIT_RTPRIO)
}

fn memlock_limit() -> Limit {
    limit_of(nix::sys::resource::Resource::RLIMIT_MEMLOCK)
}

/// `cpu<N>` directories of `/sys/devices/system/cpu`, in number order.
fn cpu_dirs() -> Vec<PathBuf> {
    let Ok(rd) = std::fs::read_dir("/sys/devices/system/cpu") else {
        return Vec::new();
    };
    let mut v: Vec<(u32, PathBuf)> = rd
        .flatten()
        .filter_map(|e| {
            let n = e.file_name().to_str()?.strip_prefix("cpu")?.parse().ok()?;
            Some((n, e.path()))
        })
        .collect();
    v.sort();
    v.into_iter().map(|(_, p)| p).collect()
}

fn governors() -> Vec<String> {
    cpu_dirs()
        .iter()
        .filter_map(|d| std::fs::read_to_string(d.join("cpufreq/scaling_governor")).ok())
        .collect()
}

fn idle_states() -> Vec<IdleState> {
    let Some(cpu0) = cpu_dirs().into_iter().next() else {
        return Vec::new();
    };
    let Ok(rd) = std::fs::read_dir(cpu0.join("cpuidle")) else {
        return Vec::new();
    };
    let mut v: Vec<IdleState> = rd
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().starts_with("state"))
        .filter_map(|e| {
            let name = std::fs::read_to_string(e.path().join("name")).ok()?;
            let latency = std::fs::read_to_string(e.path().join("latency")).ok()?;
            Some(IdleState {
                name: name.trim().to_owned(),
                latency_us: latency.trim().parse().ok()?,
            })
        })
        .collect();
    v.sort_by_key(|s| s.latency_us);
    v
}

fn shm_finding() -> Finding {
    let (free, total) = match nix::sys::statvfs::statvfs("/dev/shm") {
        Ok(s) => (
            s.blocks_available().saturating_mul(s.fragment_size()),
            s.blocks().saturating_mul(s.fragment_size()),
        ),
        Err(_) => (0, 0),
    };
    let mut graphs: Vec<ShmGraph> = Vec::new();
    if let Ok(rd) = std::fs::read_dir("/dev/shm") {
        for e in rd.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            let Some(prefix) = checks::shm_prefix(&name) else {
                continue;
            };
            match graphs.iter_mut().find(|g| g.prefix == prefix) {
                Some(g) => g.files += 1,
                None => graphs.push(ShmGraph {
                    prefix: prefix.to_owned(),
                    files: 1,
                    alive: 0,
                }),
            }
        }
    }
    for g in &mut graphs {
        g.alive = ipc_types::Prefix::new(&g.prefix)
            .ok()
            .and_then(|p| transport::graph::census(&p).ok())
            .map_or(0, |(alive, _)| alive);
    }
    graphs.sort_by(|a, b| a.prefix.cmp(&b.prefix));
    checks::shared_memory(free, total, &graphs)
}

fn input_devices() -> Vec<InputDevice> {
    let (rows, refused) = scl_joystick::device::list();
    let mut v: Vec<InputDevice> = rows
        .into_iter()
        .map(|r| InputDevice {
            path: r.path.display().to_string(),
            name: r.name,
            joystick: r.joystick,
            readable: true,
        })
        .collect();
    v.extend(refused.into_iter().map(|(p, _)| InputDevice {
        path: p.display().to_string(),
        name: String::new(),
        joystick: false,
        readable: false,
    }));
    v
}
