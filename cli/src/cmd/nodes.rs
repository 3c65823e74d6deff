//! The processes of the graph, one command each (`scl up` starts them as children): `scl
//! joystick`, `scl mapper`, `scl safety`, `scl bridge`, and the fake robot `scl fake-kortex`.

use std::process::ExitCode;

use ipc_types::Prefix;
use scl::SclError;
use scl_config::GraphConfig;

/// `scl mapper`'s options.
#[derive(clap::Args, Debug)]
pub(crate) struct MapperArgs {
    /// Model file, `bundled`, `modeswitch[:key=value,...]` or the drill map
    /// `constant:qdot=v1,...,v6` (rad/s, whatever the stick).
    #[arg(long, value_name = "FILE")]
    pub(crate) model: Option<String>,
    /// Mapper id (safety forwards only the active id).
    #[arg(long)]
    pub(crate) id: Option<u32>,
}

/// `scl bridge`'s options.
#[derive(clap::Args, Debug)]
pub(crate) struct BridgeArgs {
    /// Robot backend: `mock` or `kortex` (a Gen3 lite over the Kortex API).
    #[arg(long)]
    pub(crate) robot: Option<String>,
    /// First tick number (a restarted bridge continues its predecessor's count).
    #[arg(long)]
    pub(crate) start_tick: Option<u64>,
    /// Mock arm: start from these joint angles (rad, comma-separated) instead of the
    /// configured pose.
    #[arg(long, value_name = "Q0,Q1,...", value_delimiter = ',')]
    pub(crate) resume_q: Option<Vec<f64>>,
    /// Mock arm: start with this gripper state (0 open .. 1 closed).
    #[arg(long, default_value_t = 0.0)]
    pub(crate) resume_gripper: f64,
    /// When the predecessor published its last state (monotonic ns; given by `scl up`):
    /// the periods until this bridge's first state are counted as missed.
    #[arg(long, value_name = "NS")]
    pub(crate) resume_t_ns: Option<u64>,
    /// Kortex: the robot's IP address (instead of bridge.kortex.address).
    #[arg(long, value_name = "IP")]
    pub(crate) address: Option<String>,
    /// Kortex: the robot's TCP port (instead of bridge.kortex.port).
    #[arg(long)]
    pub(crate) port: Option<u16>,
    /// Kortex: user name (else bridge.kortex.credentials_file).
    #[arg(long, env = scl_bridge_node::USER_ENV, hide_env_values = true)]
    pub(crate) user: Option<scl_bridge_node::Secret>,
    /// Kortex: password; prefer the environment variable or the credentials file, since a
    /// command line is visible to other users.
    #[arg(long, env = scl_bridge_node::PASSWORD_ENV, hide_env_values = true)]
    pub(crate) password: Option<scl_bridge_node::Secret>,
}

/// `scl fake-kortex`'s options.
#[derive(clap::Args, Debug)]
pub(crate) struct FakeKortexArgs {
    /// TCP port on 127.0.0.1 (0: a free one; the first line on stdout names it); the
    /// low-level cyclic channel listens on UDP with the same number.
    #[arg(long, default_value_t = hw_bridge::kortex::DEFAULT_PORT)]
    pub(crate) port: u16,
    /// For tests of the bridge's low-level entry check: misread the cyclic command as a
    /// robot that reads its layout differently would: `zero` (every position as 0°) or
    /// `offset:JOINT:RAD` (one joint's position off by RAD). The arm then leaves the
    /// position the bridge holds at entry, and the bridge must stop it.
    #[arg(long, value_name = "zero|offset:JOINT:RAD")]
    pub(crate) misread_cyclic: Option<hw_bridge::kortex::CyclicMisread>,
    /// The arm it plays: a robot profile, by the name `[graph] robot` takes (an unknown name
    /// is refused with the known ones). It answers with that arm's actuator count, Kortex
    /// model, joint position and speed limits, and joint arrays of its length on both
    /// channels.
    #[arg(long, value_name = "NAME", default_value = kinematics::RobotProfile::default_name(),
          value_parser = robot_profile)]
    pub(crate) robot: &'static kinematics::RobotProfile,
}

/// `--robot`: a robot profile by name; an unknown name is refused with the known ones.
pub(crate) fn robot_profile(name: &str) -> Result<&'static kinematics::RobotProfile, String> {
    kinematics::RobotProfile::by_name(name).map_err(|e| e.to_string())
}

/// `scl joystick`.
pub(crate) fn joystick(
    prefix: &Prefix,
    cfg: &mut GraphConfig,
    args: &scl_joystick::JoystickArgs,
) -> Result<ExitCode, SclError> {
    scl_joystick::main(prefix, cfg, args)?;
    Ok(ExitCode::SUCCESS)
}

/// `scl mapper`.
pub(crate) fn mapper(
    prefix: &Prefix,
    cfg: GraphConfig,
    args: MapperArgs,
) -> Result<ExitCode, SclError> {
    let MapperArgs { model, id } = args;
    let model = model.unwrap_or(cfg.mapper.model);
    scl_mapper_node::run(
        prefix,
        &cfg.graph,
        &cfg.faults,
        &model,
        id.unwrap_or(cfg.mapper.id),
    )?;
    Ok(ExitCode::SUCCESS)
}

/// `scl safety`.
pub(crate) fn safety(prefix: &Prefix, cfg: &GraphConfig) -> Result<ExitCode, SclError> {
    let period_s = cfg.period_s();
    scl_safety_node::run(prefix, &cfg.graph, &cfg.safety, &cfg.faults, period_s)?;
    Ok(ExitCode::SUCCESS)
}

/// `scl gateway`.
pub(crate) fn gateway(prefix: &Prefix, cfg: &GraphConfig) -> Result<ExitCode, SclError> {
    scl_gateway::run(prefix, cfg)?;
    Ok(ExitCode::SUCCESS)
}

/// `scl bridge`.
pub(crate) fn bridge(
    prefix: &Prefix,
    mut cfg: GraphConfig,
    args: BridgeArgs,
) -> Result<ExitCode, SclError> {
    let BridgeArgs {
        robot,
        start_tick,
        resume_q,
        resume_gripper,
        resume_t_ns,
        address,
        port,
        user,
        password,
    } = args;
    if let Some(r) = robot {
        cfg.bridge.robot = r;
    }
    if let Some(a) = address {
        cfg.bridge.kortex.address = a;
    }
    if let Some(p) = port {
        cfg.bridge.kortex.port = p;
    }
    cfg.validate()?;
    let resume = scl_bridge_node::Resume {
        start_tick,
        pose: resume_q.map(|q| (q, resume_gripper)),
        last_state_t_ns: resume_t_ns,
    };
    let creds = scl_bridge_node::CredentialArgs {
        user: user.map(scl_bridge_node::Secret::into_inner),
        password: password.map(scl_bridge_node::Secret::into_inner),
    };
    scl_bridge_node::run(
        prefix,
        &cfg.graph,
        &cfg.bridge,
        &cfg.faults,
        &resume,
        &creds,
    )?;
    Ok(ExitCode::SUCCESS)
}

/// `scl fake-kortex`.
pub(crate) fn fake_kortex(args: FakeKortexArgs) -> Result<ExitCode, SclError> {
    let FakeKortexArgs {
        port,
        misread_cyclic,
        robot,
    } = args;
    scl_bridge_node::fake_kortex::run(hw_bridge::kortex::FakeConfig {
        port,
        cyclic_misread: misread_cyclic,
        ..hw_bridge::kortex::FakeConfig::for_robot(robot)
    })?;
    Ok(ExitCode::SUCCESS)
}
