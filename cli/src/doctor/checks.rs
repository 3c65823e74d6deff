//! The checks, as pure functions of what was read from the machine (limits, `/proc` and
//! `/sys` text, device lists, a Kortex probe's answer): each returns one [`Finding`], so
//! every answer, ok and fail alike, is unit-tested from prepared inputs.

use std::fmt::Write as _;

use serde::Serialize;

/// How an item stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Level {
    /// Ready.
    Ok,
    /// The graph runs, but not as well as it could (latency tails, a missing joystick).
    Warn,
    /// The graph cannot drive the arm as configured.
    Fail,
}

impl Level {
    /// `ok`, `warn` or `fail`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Ok => "ok",
            Self::Warn => "warn",
            Self::Fail => "fail",
        }
    }
}

/// One checked item: what, how it stands, what was found, and what to do about it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Finding {
    /// The item, e.g. `real-time scheduling`.
    pub item: &'static str,
    /// How it stands.
    pub level: Level,
    /// What was found.
    pub detail: String,
    /// What to do (empty when nothing needs doing).
    pub fix: String,
}

impl Finding {
    fn ok(item: &'static str, detail: impl Into<String>) -> Self {
        Self {
            item,
            level: Level::Ok,
            detail: detail.into(),
            fix: String::new(),
        }
    }

    fn warn(item: &'static str, detail: impl Into<String>, fix: impl Into<String>) -> Self {
        Self {
            item,
            level: Level::Warn,
            detail: detail.into(),
            fix: fix.into(),
        }
    }

    fn fail(item: &'static str, detail: impl Into<String>, fix: impl Into<String>) -> Self {
        Self {
            item,
            level: Level::Fail,
            detail: detail.into(),
            fix: fix.into(),
        }
    }
}

/// A resource limit as `getrlimit` gives it (the soft limit, which is what a process gets).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Limit {
    /// `RLIM_INFINITY`.
    Unlimited,
    /// A finite value.
    Value(u64),
}

/// The capabilities of interest from `/proc/self/status`'s `CapEff` line.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Caps {
    /// `CAP_SYS_NICE` (23): SCHED_FIFO at any priority.
    pub sys_nice: bool,
    /// `CAP_IPC_LOCK` (14): locking memory beyond the limit.
    pub ipc_lock: bool,
}

const CAP_IPC_LOCK: u32 = 14;
const CAP_SYS_NICE: u32 = 23;

/// The effective capabilities from the text of `/proc/self/status` (`None` when the line is
/// missing or not hexadecimal).
pub fn parse_caps(status: &str) -> Option<Caps> {
    let hex = status
        .lines()
        .find_map(|l| l.strip_prefix("CapEff:"))?
        .trim();
    let bits = u64::from_str_radix(hex, 16).ok()?;
    Some(Caps {
        sys_nice: bits & (1 << CAP_SYS_NICE) != 0,
        ipc_lock: bits & (1 << CAP_IPC_LOCK) != 0,
    })
}

/// SCHED_FIFO for the control path: the bridge asks for `priority` (`None`: real-time is off
/// in the configuration).
pub fn realtime_scheduling(priority: Option<i32>, rtprio: Limit, caps: Caps) -> Finding {
    const ITEM: &str = "real-time scheduling";
    let Some(p) = priority else {
        return Finding::warn(
            ITEM,
            "off in the configuration ([graph] realtime = false)",
            "set [graph] realtime = true for the arm: without SCHED_FIFO a busy machine delays ticks",
        );
    };
    let allowed = caps.sys_nice
        || match rtprio {
            Limit::Unlimited => true,
            Limit::Value(v) => v >= p.max(0) as u64,
        };
    let limit = match rtprio {
        Limit::Unlimited => "unlimited".to_owned(),
        Limit::Value(v) => v.to_string(),
    };
    if allowed {
        let how = if caps.sys_nice {
            "CAP_SYS_NICE".to_owned()
        } else {
            format!("rtprio limit {limit}")
        };
        Finding::ok(ITEM, format!("SCHED_FIFO priority {p} allowed ({how})"))
    } else {
        Finding::warn(
            ITEM,
            format!(
                "SCHED_FIFO priority {p} will be refused: rtprio limit {limit}, no CAP_SYS_NICE; \
                 the graph runs at normal priority"
            ),
            format!(
                "run the packaged service (LimitRTPRIO=95, AmbientCapabilities=CAP_SYS_NICE), or \
                 add `<user> - rtprio {p}` to /etc/security/limits.d/scl.conf and log in again"
            ),
        )
    }
}

/// The memory lock each control-path process asks for (`mlockall`) with real-time on; a
/// finite limit below this is reported.
pub const MEMLOCK_WANTED: u64 = 1 << 30;

/// `mlockall` for the control path (`realtime`: whether the configuration asks for it).
pub fn memory_locking(realtime: bool, memlock: Limit, caps: Caps) -> Finding {
    const ITEM: &str = "memory locking";
    if !realtime {
        return Finding::ok(ITEM, "not asked for ([graph] realtime = false)");
    }
    match memlock {
        _ if caps.ipc_lock => Finding::ok(ITEM, "allowed (CAP_IPC_LOCK)"),
        Limit::Unlimited => Finding::ok(ITEM, "allowed (memlock limit unlimited)"),
        Limit::Value(v) if v >= MEMLOCK_WANTED => {
            Finding::ok(ITEM, format!("allowed (memlock limit {} MiB)", v >> 20))
        }
        Limit::Value(v) => Finding::warn(
            ITEM,
            format!(
                "memlock limit {} KiB: mlockall will be refused, so page faults can stall a tick",
                v >> 10
            ),
            "run the packaged service (LimitMEMLOCK=infinity), or add `<user> - memlock \
             unlimited` to /etc/security/limits.d/scl.conf and log in again",
        ),
    }
}

/// The kernel's preemption model from `/proc/sys/kernel/version` (the `uname -v` text) and
/// `/sys/kernel/realtime` (present and `1` on PREEMPT_RT kernels).
pub fn kernel(version: &str, realtime_flag: Option<&str>) -> Finding {
    const ITEM: &str = "kernel";
    let version = version.trim();
    if realtime_flag.is_some_and(|f| f.trim() == "1") || version.contains("PREEMPT_RT") {
        return Finding::ok(ITEM, format!("PREEMPT_RT ({version})"));
    }
    let model = if version.contains("PREEMPT_DYNAMIC") || version.contains("PREEMPT ") {
        "preemptible, not PREEMPT_RT"
    } else {
        "not preemptible"
    };
    Finding::warn(
        ITEM,
        format!("{model} ({version}): 40 Hz works, wake-up tails are longer"),
        "for the lowest latency install a PREEMPT_RT kernel (Debian: linux-image-rt-amd64)",
    )
}

/// The CPU frequency governors, one per CPU (`/sys/devices/system/cpu/cpu*/cpufreq/
/// scaling_governor`; empty when the machine has no cpufreq, as in most VMs).
pub fn cpu_governor(governors: &[String]) -> Finding {
    const ITEM: &str = "CPU frequency governor";
    if governors.is_empty() {
        return Finding::ok(ITEM, "no cpufreq on this machine (fixed frequency or a VM)");
    }
    let slow: Vec<&String> = governors
        .iter()
        .filter(|g| g.trim() != "performance")
        .collect();
    if slow.is_empty() {
        return Finding::ok(ITEM, format!("performance on all {} CPUs", governors.len()));
    }
    let mut names: Vec<&str> = slow.iter().map(|g| g.trim()).collect();
    names.sort_unstable();
    names.dedup();
    Finding::warn(
        ITEM,
        format!(
            "{} of {} CPUs on `{}`: the first ticks after idle run slower",
            slow.len(),
            governors.len(),
            names.join("`, `")
        ),
        "cpupower frequency-set -g performance (Debian package linux-cpupower)",
    )
}

/// A CPU idle state: its name and exit latency (µs), from `/sys/devices/system/cpu/cpu0/
/// cpuidle/state*/{name,latency}`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct IdleState {
    /// `POLL`, `C1`, `C6`, ...
    pub name: String,
    /// Exit latency (µs).
    pub latency_us: u64,
}

/// Idle states deeper than this exit latency are reported (µs): a tick's wake-up can pay it
/// at every hop.
pub const IDLE_LATENCY_WARN_US: u64 = 50;

/// The CPU idle driver (`/sys/devices/system/cpu/cpuidle/current_driver`) and its states.
pub fn cpu_idle(driver: Option<&str>, states: &[IdleState]) -> Finding {
    const ITEM: &str = "CPU idle states";
    let driver = driver.map(str::trim).unwrap_or("");
    if driver.is_empty() || driver == "none" {
        return Finding::ok(ITEM, "no cpuidle driver (the CPUs halt or poll when idle)");
    }
    let deep: Vec<&IdleState> = states
        .iter()
        .filter(|s| s.latency_us > IDLE_LATENCY_WARN_US)
        .collect();
    if deep.is_empty() {
        return Finding::ok(
            ITEM,
            format!("{driver}: no state slower than {IDLE_LATENCY_WARN_US} µs to leave"),
        );
    }
    let mut list = String::new();
    for s in &deep {
        let _ = write!(
            list,
            "{}{} ({} µs)",
            if list.is_empty() { "" } else { ", " },
            s.name,
            s.latency_us
        );
    }
    Finding::warn(
        ITEM,
        format!("{driver}: deep states {list} can delay each wake-up of the graph"),
        "limit them with the kernel parameter processor.max_cstate=1 (intel_idle.max_cstate=1 on \
         Intel), or `cpupower idle-set -D 10` before starting the graph",
    )
}

/// What `/dev/shm` holds for the graphs: its free and total bytes, and the prefixes that have
/// files there, each with how many files and whether a process of that graph is alive.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ShmGraph {
    /// The graph prefix.
    pub prefix: String,
    /// Its files in `/dev/shm`.
    pub files: usize,
    /// Live processes of that graph.
    pub alive: usize,
}

/// Below this much free shared memory a graph may not start (bytes).
pub const SHM_MIN_FREE: u64 = 64 << 20;

/// Shared-memory space and leftovers of dead graphs.
pub fn shared_memory(free: u64, total: u64, graphs: &[ShmGraph]) -> Finding {
    const ITEM: &str = "shared memory";
    if free < SHM_MIN_FREE {
        return Finding::fail(
            ITEM,
            format!(
                "/dev/shm has {} MiB free of {} MiB; a graph needs at least {} MiB",
                free >> 20,
                total >> 20,
                SHM_MIN_FREE >> 20
            ),
            "free /dev/shm (remove leftovers below, or remount it larger: mount -o remount,size=512M /dev/shm)",
        );
    }
    let dead: Vec<&ShmGraph> = graphs.iter().filter(|g| g.alive == 0).collect();
    let live = graphs.len() - dead.len();
    if dead.is_empty() {
        return Finding::ok(
            ITEM,
            format!(
                "/dev/shm {} MiB free; {live} graph(s) running, no leftovers",
                free >> 20
            ),
        );
    }
    let files: usize = dead.iter().map(|g| g.files).sum();
    let names: Vec<String> = dead.iter().map(|g| format!("`{}`", g.prefix)).collect();
    Finding::warn(
        ITEM,
        format!(
            "{files} file(s) of dead graph(s) {} in /dev/shm ({} MiB free)",
            names.join(", "),
            free >> 20
        ),
        format!(
            "`scl up --prefix P` removes a dead graph's files when it starts; or remove them: {}",
            dead.iter()
                .map(|g| format!("rm /dev/shm/scl_{}_*", g.prefix))
                .collect::<Vec<_>>()
                .join("; ")
        ),
    )
}

/// The graph prefix of an iceoryx2 file in `/dev/shm` named `scl_<prefix>_<40 hex>...`
/// (prefixes may hold `_`, the 40-hex service or node hash ends them); `None` for other files.
pub fn shm_prefix(file_name: &str) -> Option<&str> {
    let rest = file_name.strip_prefix("scl_")?;
    let bytes = rest.as_bytes();
    let mut i = 0;
    while let Some(off) = rest[i..].find('_') {
        let at = i + off;
        let hash = bytes.get(at + 1..at + 41)?;
        if at > 0 && hash.iter().all(u8::is_ascii_hexdigit) {
            return Some(&rest[..at]);
        }
        i = at + 1;
    }
    None
}

/// An input device as the doctor sees it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct InputDevice {
    /// `/dev/input/eventN`.
    pub path: String,
    /// The device's name (empty when it could not be opened).
    pub name: String,
    /// Whether it has a stick and buttons (only known for opened devices).
    pub joystick: bool,
    /// Whether this user could open it.
    pub readable: bool,
}

/// The joystick devices, against the configured `[joystick] source`.
pub fn joysticks(source: &str, devices: &[InputDevice]) -> Finding {
    const ITEM: &str = "joystick devices";
    let sticks: Vec<&InputDevice> = devices.iter().filter(|d| d.joystick).collect();
    let refused = devices.iter().filter(|d| !d.readable).count();
    let needs_device = source == "evdev";
    if !sticks.is_empty() {
        let names: Vec<String> = sticks
            .iter()
            .map(|d| format!("{} ({})", d.path, d.name))
            .collect();
        return Finding::ok(ITEM, format!("readable: {}", names.join(", ")));
    }
    let fix_access = "add the user to the `input` group (the packaged service runs as `scl`, \
                      which is in it) or install a udev rule for the device";
    let (detail, fix) = if refused > 0 {
        (
            format!(
                "no readable joystick; {refused} input device(s) could not be opened (permission)"
            ),
            fix_access.to_owned(),
        )
    } else if devices.is_empty() {
        (
            "no input devices in /dev/input".to_owned(),
            "plug in the joystick or gamepad (`scl joystick --list` shows what is seen)".to_owned(),
        )
    } else {
        (
            format!("{} input device(s), none a joystick", devices.len()),
            "plug in the joystick or gamepad (`scl joystick --list` shows what is seen)".to_owned(),
        )
    };
    if needs_device {
        Finding::fail(
            ITEM,
            format!("[joystick] source = \"evdev\": {detail}"),
            fix,
        )
    } else {
        Finding::ok(
            ITEM,
            format!("{detail}; not needed: [joystick] source = \"{source}\""),
        )
    }
}

/// The configuration: loaded and validated (`Err` holds the error's text).
pub fn configuration(path: &str, result: Result<(), String>) -> Finding {
    const ITEM: &str = "configuration";
    match result {
        Ok(()) => Finding::ok(ITEM, format!("{path}: valid")),
        Err(e) => Finding::fail(
            ITEM,
            e.trim_end(),
            format!("fix {path} (every key: examples/graph.toml)"),
        ),
    }
}

/// The model the configuration serves, loaded for its robot (`Err` holds the error's text).
pub fn model(spec: &str, robot: &str, result: Result<(), String>) -> Finding {
    const ITEM: &str = "model";
    match result {
        Ok(()) => Finding::ok(ITEM, format!("`{spec}` loads for {robot}")),
        Err(e) => Finding::fail(
            ITEM,
            format!("`{spec}`: {e}"),
            "point [mapper] model at a model file trained for this robot, or `bundled`",
        ),
    }
}

/// What a read-only Kortex session told (see `hw_bridge::kortex::probe`), or its error text.
#[derive(Debug, Clone, PartialEq)]
pub struct KortexAnswer {
    /// `address:port`.
    pub addr: String,
    /// The firmware version, `major.minor.patch`.
    pub firmware: String,
    /// Actuators reported.
    pub actuators: u32,
    /// What the arm says it is (its actuator count and Kortex model).
    pub found: hw_bridge::kortex::FoundRobot,
    /// The arm's joint speed hard limits (rad/s).
    pub speed_limits_rad_s: Vec<f64>,
}

/// The arm, for a configuration with `[bridge] robot = "kortex"`: reachable, a session
/// opened and closed, the arm the bridge would accept for `robot` (its actuator count and
/// Kortex model, [`hw_bridge::kortex::FoundRobot::check`]), its firmware and its limits against
/// the robot profile's (`profile_speed_rad_s` the speeds the graph may command).
pub fn kortex(
    answer: Result<KortexAnswer, String>,
    robot: &kinematics::RobotProfile,
    profile_speed_rad_s: &[f64],
) -> Finding {
    const ITEM: &str = "Kortex arm";
    let expected_joints = robot.n_joints();
    let a = match answer {
        Ok(a) => a,
        Err(e) => {
            let fix = if e.contains("password") || e.contains("sub-code 15") {
                "check SCL_KORTEX_USER / SCL_KORTEX_PASSWORD or bridge.kortex.credentials_file"
            } else {
                "check the arm is powered, the cable, and [bridge.kortex] address and port (the \
                 arm's default is 192.168.1.10:10000)"
            };
            return Finding::fail(ITEM, e, fix);
        }
    };
    if let Err(e) = a.found.check(robot) {
        return Finding::fail(
            ITEM,
            format!("{}: firmware {}; {e}", a.addr, a.firmware),
            "set [graph] robot to this arm's profile",
        );
    }
    let over: Vec<String> = profile_speed_rad_s
        .iter()
        .zip(&a.speed_limits_rad_s)
        .enumerate()
        .filter(|(_, (p, arm))| **p > **arm + 1e-6)
        .map(|(j, (p, arm))| format!("joint {} {p:.2} > {arm:.2} rad/s", j + 1))
        .collect();
    if a.speed_limits_rad_s.len() != expected_joints {
        return Finding::fail(
            ITEM,
            format!(
                "{}: the arm reports {} joint speed limits for {expected_joints} joints",
                a.addr,
                a.speed_limits_rad_s.len()
            ),
            "update the arm's firmware or report this arm's answer",
        );
    }
    if !over.is_empty() {
        return Finding::warn(
            ITEM,
            format!(
                "{}: firmware {}; the profile's speed limits exceed the arm's: {} (the bridge \
                 scales commands into the arm's limits)",
                a.addr,
                a.firmware,
                over.join(", ")
            ),
            "lower [safety] max_velocity_rad_s to the arm's limits",
        );
    }
    Finding::ok(
        ITEM,
        format!(
            "{}: session opened and closed; {}, firmware {}, speed limits within the arm's",
            a.addr, a.found, a.firmware
        ),
    )
}

/// The Kortex part when the configuration drives the mock arm.
pub fn kortex_not_used(backend: &str) -> Finding {
    Finding::ok(
        "Kortex arm",
        format!("not used: [bridge] robot = \"{backend}\""),
    )
}

/// The fault drills, which the doctor does not run (they drive the arm): how to prove on this
/// machine, with this configuration (`config`, as the user named it), that every fault stops
/// the arm as promised.
pub fn drills(config: &str) -> Finding {
    Finding {
        item: "fault drills",
        level: Level::Ok,
        detail: "not run by the doctor: they drive the arm".into(),
        fix: format!(
            "before a person sits down, run `scl drill{config}` (the mock arm; docs/safety-drills.md)"
        ),
    }
}

/// The exit code of a report: non-zero on any fail.
pub fn exit_code(findings: &[Finding]) -> i32 {
    i32::from(findings.iter().any(|f| f.level == Level::Fail))
}

/// The report as text, one item per line with its fix indented below.
pub fn render(findings: &[Finding]) -> String {
    let mut s = String::new();
    for f in findings {
        let _ = writeln!(s, "{:<5} {:<24} {}", f.level.name(), f.item, f.detail);
        if !f.fix.is_empty() {
            let _ = writeln!(s, "{:<30} -> {}", "", f.fix);
        }
    }
    let count = |l: Level| findings.iter().filter(|f| f.level == l).count();
    let _ = writeln!(
        s,
        "{} ok, {} warn, {} fail",
        count(Level::Ok),
        count(Level::Warn),
        count(Level::Fail)
    );
    s
}

/// `[graph] wait` on `machine`: how each control-path process will wait and where it is
/// pinned (`scl_config::GraphSection::placement`; a polling wait with no CPUs given pins
/// itself to the isolated or the last CPUs), refused where polling would starve another,
/// and what the machine allows: how many processes can poll with `predictive` on the spread
/// placement, and whether `spin` fits.
pub fn wait_strategy(
    graph: &scl_config::GraphSection,
    machine: &scl_config::placement::MachineCpus,
) -> Finding {
    const ITEM: &str = "wait strategy";
    let online_cpus = machine.online;
    let spread = scl_config::placement::spread_cpus(online_cpus);
    let polling = |cpus: &[i32], wait| {
        let g = scl_config::GraphSection {
            wait,
            rt_cpu: -1,
            rt_cpus: cpus.to_vec(),
            ..graph.clone()
        };
        g.placement(&scl_config::placement::MachineCpus::online(online_cpus))
            .map_or(0, |p| p.waits.iter().filter(|w| w.polls()).count())
    };
    let supports = format!(
        "{online_cpus} CPUs: predictive polls in {} of 3 processes with rt_cpus = {spread:?}; spin {}",
        polling(&spread, scl_config::WaitStrategy::Predictive),
        if polling(&spread, scl_config::WaitStrategy::Spin) > 0 {
            "fits (a CPU each)"
        } else {
            "needs 4 CPUs with SCHED_FIFO"
        }
    );
    let supports = if graph.auto_pins() {
        format!(
            "{supports}; no CPUs given, so pinned to {:?} (bridge, safety, mapper, joystick; from {})",
            machine.auto_cpus(),
            if machine.isolated.is_empty() {
                "the last CPUs".to_owned()
            } else {
                format!("the isolated CPUs {:?}", machine.isolated)
            }
        )
    } else {
        supports
    };
    match graph.placement(machine) {
        Err(e) => Finding::fail(
            ITEM,
            format!("{e}; {supports}"),
            "give each polling process its own CPU in [graph] rt_cpus, or use wait = \"predictive\" or \"event\"",
        ),
        Ok(p) => {
            let names = ["bridge", "safety", "mapper"];
            let waits: Vec<String> = names
                .iter()
                .zip(p.waits)
                .map(|(n, w)| format!("{n} {w}"))
                .collect();
            let detail = format!("wait = {}: {}; {supports}", graph.wait, waits.join(", "));
            if p.notes.is_empty() {
                Finding::ok(ITEM, detail)
            } else {
                Finding::warn(
                    ITEM,
                    format!("{detail}; {}", p.notes.join("; ")),
                    format!("[graph] rt_cpus = {spread:?} lets more of them poll"),
                )
            }
        }
    }
}

/// What the operator feels with `graph`'s `wait`: with `event` the joystick answers each
/// state on its arrival, so its sample reaches the arm about a period after it was read; with
/// `predictive` or `spin` it reads the stick `margin_us` before each tick
/// (`scl_joystick::sampling`). A robot PC should poll: `predictive` anywhere, `spin` where each
/// polling process has a CPU of its own.
pub fn stick_latency(graph: &scl_config::GraphSection, margin_us: u32) -> Finding {
    const ITEM: &str = "stick to arm";
    let period_ns = graph.period_ns();
    let ms = |ns: u64| ns as f64 * 1e-6;
    if graph.wait.polls() {
        let margin = scl_joystick::sampling::margin_ns(margin_us, period_ns);
        Finding::ok(
            ITEM,
            format!(
                "wait = {}: the joystick reads the stick {:.2} ms before each tick, and its \
                 sample is executed about that much later",
                graph.wait,
                ms(margin)
            ),
        )
    } else {
        Finding::warn(
            ITEM,
            format!(
                "wait = event: the joystick answers each robot state on its arrival, so its \
                 sample is executed about a period ({:.1} ms) after it was read",
                ms(period_ns)
            ),
            "on a robot PC use [graph] wait = \"predictive\" (the joystick reads the stick 1 ms \
             before each tick; \"spin\" where each process has a CPU of its own): \
             docs/benchmarks.md",
        )
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn the_stick_latency_says_a_robot_pc_should_poll() {
        let mut g = scl_config::GraphSection::default();
        let f = stick_latency(&g, 0);
        assert_eq!(f.level, Level::Warn, "{f:?}");
        assert!(
            f.detail.contains("25.0 ms") && f.fix.contains("predictive"),
            "{f:?}"
        );
        g.wait = scl_config::WaitStrategy::Predictive;
        let f = stick_latency(&g, 0);
        assert_eq!(f.level, Level::Ok, "{f:?}");
        assert!(f.detail.contains("1.00 ms before each tick"), "{f:?}");
        g.rate_hz = 1000.0;
        assert!(stick_latency(&g, 0).detail.contains("0.25 ms"));
        assert!(stick_latency(&g, 300).detail.contains("0.30 ms"));
    }

    #[test]
    fn the_wait_strategy_says_how_each_process_waits_and_what_the_machine_allows() {
        let mut g = scl_config::GraphSection::default();
        let f = wait_strategy(&g, &scl_config::placement::MachineCpus::online(2));
        assert_eq!(f.level, Level::Ok);
        assert!(
            f.detail.contains("wait = event")
                && f.detail.contains("2 of 3")
                && f.detail.contains("needs 4 CPUs"),
            "{f:?}"
        );
        g.wait = scl_config::WaitStrategy::Predictive;
        let f = wait_strategy(&g, &scl_config::placement::MachineCpus::online(2));
        assert_eq!(f.level, Level::Warn, "{f:?}");
        assert!(f.detail.contains("mapper predictive") && f.fix.contains("rt_cpus"));
        assert!(f.detail.contains("pinned to [0, 1, 1, 1]"), "{f:?}");
        g.wait = scl_config::WaitStrategy::Spin;
        let f = wait_strategy(&g, &scl_config::placement::MachineCpus::online(2));
        assert_eq!(f.level, Level::Fail, "{f:?}");
        assert!(f.detail.contains("graph.rt_cpus"), "{f:?}");
        g.rt_cpus = vec![7, 6, 5, 4];
        let f = wait_strategy(&g, &scl_config::placement::MachineCpus::online(8));
        assert_eq!(f.level, Level::Ok, "{f:?}");
        assert!(f.detail.contains("spin fits"), "{f:?}");
    }

    const NONE: Caps = Caps {
        sys_nice: false,
        ipc_lock: false,
    };

    #[test]
    fn capabilities_come_from_the_effective_set() {
        let status = "Name:\tscl\nCapInh:\t0000000000000000\nCapEff:\t0000000000800000\n";
        assert_eq!(
            parse_caps(status),
            Some(Caps {
                sys_nice: true,
                ipc_lock: false
            })
        );
        let root = "CapEff:\t000001ffffffffff\n";
        assert_eq!(
            parse_caps(root),
            Some(Caps {
                sys_nice: true,
                ipc_lock: true
            })
        );
        assert_eq!(parse_caps("Name: x\n"), None);
        assert_eq!(parse_caps("CapEff:\tzz\n"), None);
    }

    #[test]
    fn real_time_scheduling_ok_by_limit_or_capability_and_warned_otherwise() {
        assert_eq!(
            realtime_scheduling(Some(80), Limit::Value(95), NONE).level,
            Level::Ok
        );
        assert_eq!(
            realtime_scheduling(Some(80), Limit::Unlimited, NONE).level,
            Level::Ok
        );
        let cap = Caps {
            sys_nice: true,
            ipc_lock: false,
        };
        assert_eq!(
            realtime_scheduling(Some(80), Limit::Value(0), cap).level,
            Level::Ok
        );
        let f = realtime_scheduling(Some(80), Limit::Value(0), NONE);
        assert_eq!(f.level, Level::Warn);
        assert!(f.detail.contains("priority 80"), "{}", f.detail);
        assert!(f.fix.contains("rtprio 80"), "{}", f.fix);
        assert_eq!(
            realtime_scheduling(Some(80), Limit::Value(79), NONE).level,
            Level::Warn
        );
        assert_eq!(
            realtime_scheduling(None, Limit::Value(99), NONE).level,
            Level::Warn
        );
    }

    #[test]
    fn memory_locking_needs_a_large_limit_or_the_capability() {
        assert_eq!(
            memory_locking(true, Limit::Unlimited, NONE).level,
            Level::Ok
        );
        assert_eq!(
            memory_locking(true, Limit::Value(MEMLOCK_WANTED), NONE).level,
            Level::Ok
        );
        let lock = Caps {
            sys_nice: false,
            ipc_lock: true,
        };
        assert_eq!(memory_locking(true, Limit::Value(0), lock).level, Level::Ok);
        let f = memory_locking(true, Limit::Value(8 << 20), NONE);
        assert_eq!(f.level, Level::Warn);
        assert!(f.detail.contains("8192 KiB"), "{}", f.detail);
        assert_eq!(
            memory_locking(false, Limit::Value(0), NONE).level,
            Level::Ok
        );
    }

    #[test]
    fn kernel_rt_by_flag_or_version_and_warned_otherwise() {
        assert_eq!(
            kernel("#1 SMP PREEMPT_RT Debian 6.1.0-rt", None).level,
            Level::Ok
        );
        assert_eq!(
            kernel("#1 SMP PREEMPT_DYNAMIC", Some("1\n")).level,
            Level::Ok
        );
        let f = kernel("#1 SMP PREEMPT_DYNAMIC Debian 6.1.76-1", None);
        assert_eq!(f.level, Level::Warn);
        assert!(f.detail.starts_with("preemptible"), "{}", f.detail);
        let f = kernel("#1 SMP Debian", Some("0"));
        assert_eq!(f.level, Level::Warn);
        assert!(f.detail.starts_with("not preemptible"), "{}", f.detail);
    }

    #[test]
    fn governor_performance_everywhere_or_none_is_ok() {
        assert_eq!(cpu_governor(&[]).level, Level::Ok);
        let perf = vec!["performance\n".to_owned(); 4];
        assert_eq!(cpu_governor(&perf).level, Level::Ok);
        let mixed = vec![
            "performance".to_owned(),
            "powersave".to_owned(),
            "schedutil".to_owned(),
            "powersave".to_owned(),
        ];
        let f = cpu_governor(&mixed);
        assert_eq!(f.level, Level::Warn);
        assert!(
            f.detail.contains("3 of 4") && f.detail.contains("`powersave`, `schedutil`"),
            "{}",
            f.detail
        );
    }

    #[test]
    fn deep_idle_states_are_warned() {
        assert_eq!(cpu_idle(None, &[]).level, Level::Ok);
        assert_eq!(cpu_idle(Some("none\n"), &[]).level, Level::Ok);
        let shallow = [
            IdleState {
                name: "POLL".into(),
                latency_us: 0,
            },
            IdleState {
                name: "C1".into(),
                latency_us: 2,
            },
        ];
        assert_eq!(cpu_idle(Some("intel_idle"), &shallow).level, Level::Ok);
        let mut deep = shallow.to_vec();
        deep.push(IdleState {
            name: "C6".into(),
            latency_us: 133,
        });
        let f = cpu_idle(Some("intel_idle"), &deep);
        assert_eq!(f.level, Level::Warn);
        assert!(f.detail.contains("C6 (133 µs)"), "{}", f.detail);
    }

    #[test]
    fn shared_memory_space_and_leftovers() {
        let live = ShmGraph {
            prefix: "scl".into(),
            files: 30,
            alive: 5,
        };
        let dead = ShmGraph {
            prefix: "t_old".into(),
            files: 12,
            alive: 0,
        };
        assert_eq!(
            shared_memory(1 << 30, 2 << 30, std::slice::from_ref(&live)).level,
            Level::Ok
        );
        let f = shared_memory(1 << 30, 2 << 30, &[live.clone(), dead]);
        assert_eq!(f.level, Level::Warn);
        assert!(
            f.detail.contains("12 file(s)") && f.fix.contains("rm /dev/shm/scl_t_old_*"),
            "{f:?}"
        );
        let f = shared_memory(10 << 20, 64 << 20, &[]);
        assert_eq!(f.level, Level::Fail);
    }

    #[test]
    fn shm_prefix_ends_at_the_hash() {
        let h = "0354a209029e7d094a819e2d4030ea331e6caaf0";
        assert_eq!(
            shm_prefix(&format!("scl_tdrillfold21112x5_{h}_7922855.data")),
            Some("tdrillfold21112x5")
        );
        assert_eq!(
            shm_prefix(&format!("scl_my_lab_graph_{h}_node.0_10_0.global_mgmt")),
            Some("my_lab_graph")
        );
        assert_eq!(shm_prefix("scl_short_abc"), None);
        assert_eq!(shm_prefix(&format!("other_x_{h}")), None);
    }

    fn dev(path: &str, joystick: bool, readable: bool) -> InputDevice {
        InputDevice {
            path: path.into(),
            name: if readable {
                "pad".into()
            } else {
                String::new()
            },
            joystick,
            readable,
        }
    }

    #[test]
    fn joysticks_against_the_source() {
        let pad = dev("/dev/input/event3", true, true);
        let locked = dev("/dev/input/event4", false, false);
        assert_eq!(
            joysticks("evdev", std::slice::from_ref(&pad)).level,
            Level::Ok
        );
        let f = joysticks("evdev", std::slice::from_ref(&locked));
        assert_eq!(f.level, Level::Fail);
        assert!(f.fix.contains("`input` group"), "{}", f.fix);
        assert_eq!(joysticks("evdev", &[]).level, Level::Fail);
        // The scripted joystick needs no device.
        assert_eq!(joysticks("script", &[locked]).level, Level::Ok);
        assert_eq!(joysticks("keyboard", &[]).level, Level::Ok);
    }

    #[test]
    fn configuration_and_model_fail_with_the_error() {
        assert_eq!(configuration("g.toml", Ok(())).level, Level::Ok);
        let f = configuration("g.toml", Err("unknown key `x`".into()));
        assert_eq!(f.level, Level::Fail);
        assert_eq!(f.detail, "unknown key `x`");
        assert_eq!(model("bundled", "gen3_lite", Ok(())).level, Level::Ok);
        let f = model("m.safetensors", "gen3_lite", Err("bad header".into()));
        assert_eq!(f.level, Level::Fail);
        assert!(f.detail.contains("m.safetensors"));
    }

    fn lite() -> &'static kinematics::RobotProfile {
        kinematics::RobotProfile::by_name("gen3_lite").unwrap()
    }

    fn answer() -> KortexAnswer {
        KortexAnswer {
            addr: "127.0.0.1:10000".into(),
            firmware: "2.3.0".into(),
            actuators: 6,
            found: hw_bridge::kortex::FoundRobot::of_profile(lite()),
            speed_limits_rad_s: vec![1.6; 6],
        }
    }

    #[test]
    fn kortex_answers() {
        let f = kortex(Ok(answer()), lite(), &[1.0; 6]);
        assert_eq!(f.level, Level::Ok);
        assert!(
            f.detail
                .contains("a Gen3 lite (Kortex model L31, 6 actuators)"),
            "{}",
            f.detail
        );
        let f = kortex(Ok(answer()), lite(), &[1.0, 1.0, 2.0, 1.0, 1.0, 1.0]);
        assert_eq!(f.level, Level::Warn);
        assert!(f.detail.contains("joint 3 2.00 > 1.60"), "{}", f.detail);
        // Another arm: its actuator count and model, or its model alone, fail naming both.
        let gen3 = kinematics::RobotProfile::by_name("gen3").unwrap();
        let mut a = answer();
        a.found = hw_bridge::kortex::FoundRobot::of_profile(gen3);
        let f = kortex(Ok(a), lite(), &[1.0; 6]);
        assert_eq!(f.level, Level::Fail);
        assert!(
            f.detail.contains("a Gen3 (Kortex model L53, 7 actuators)")
                && f.detail.contains("gen3_lite"),
            "{}",
            f.detail
        );
        let mut a = answer();
        a.found.model = hw_bridge::kortex::FoundRobot::of_profile(gen3).model;
        let f = kortex(Ok(a), lite(), &[1.0; 6]);
        assert_eq!(f.level, Level::Fail, "{}", f.detail);
        let mut a = answer();
        a.speed_limits_rad_s.pop();
        assert_eq!(kortex(Ok(a), lite(), &[1.0; 6]).level, Level::Fail);
        let f = kortex(Err("wrong user name or password".into()), lite(), &[1.0; 6]);
        assert_eq!(f.level, Level::Fail);
        assert!(f.fix.contains("SCL_KORTEX_PASSWORD"));
        let f = kortex(
            Err("cannot connect to 10.0.0.1:10000".into()),
            lite(),
            &[1.0; 6],
        );
        assert!(f.fix.contains("powered"));
    }

    #[test]
    fn exit_code_is_non_zero_on_any_fail_only() {
        let ok = Finding::ok("a", "");
        let warn = Finding::warn("b", "", "");
        let fail = Finding::fail("c", "", "");
        assert_eq!(exit_code(&[ok.clone(), warn.clone()]), 0);
        assert_eq!(exit_code(&[ok, warn, fail]), 1);
        let text = render(&[Finding::fail("model", "bad", "fix it")]);
        assert!(
            text.contains("fail  model") && text.contains("-> fix it"),
            "{text}"
        );
        assert!(text.ends_with("0 ok, 0 warn, 1 fail\n"), "{text}");
    }
}
