//! `scl doctor`'s Kortex part against the fake robot: a read-only session, a wrong password,
//! an address nobody answers on, and a robot that accepts and never replies. Each ends in a
//! finding within the probe's timeout, never a hang, and nothing is commanded.
#![allow(clippy::unwrap_used)]

use std::net::TcpListener;
use std::time::{Duration, Instant};

use hw_bridge::kortex::{Credentials, FakeConfig, FakeKortex, Function, KortexConfig};
use scl::doctor::checks::{self, Level};
use scl_config::GraphConfig;

fn config_for(addr: std::net::SocketAddr) -> GraphConfig {
    let mut cfg = GraphConfig::default();
    cfg.bridge.robot = "kortex".into();
    cfg.bridge.kortex = KortexConfig {
        address: addr.ip().to_string(),
        port: addr.port(),
        ..KortexConfig::default()
    };
    cfg
}

fn probe(cfg: &GraphConfig, user: &str, password: &str) -> (checks::Finding, Duration) {
    let t0 = Instant::now();
    let answer = hw_bridge::kortex::KortexArm::probe(
        &cfg.bridge.kortex,
        &Credentials::new(user, password),
        scl::doctor::KORTEX_TIMEOUT,
    )
    .map(|info| checks::KortexAnswer {
        addr: info.addr.to_string(),
        firmware: info.firmware(),
        actuators: info.actuators,
        found: info.found,
        speed_limits_rad_s: info.speed_limits_rad_s,
    })
    .map_err(|e| e.to_string());
    let robot = kinematics::RobotProfile::by_name(&cfg.graph.robot).unwrap();
    let f = checks::kortex(answer, robot, &cfg.safety.max_velocity_rad_s);
    (f, t0.elapsed())
}

/// The probe's own bound: a connect and one reply, each within the timeout, plus slack for a
/// loaded machine (this is a hang guard, not a latency figure).
const NEVER_LONGER: Duration = Duration::from_secs(5);

#[test]
fn a_read_only_session_reports_firmware_and_limits_and_commands_nothing() {
    let fake = FakeKortex::start(FakeConfig {
        firmware_version: 0x02_02_01,
        ..FakeConfig::default()
    })
    .unwrap();
    let cfg = config_for(fake.addr());
    let (f, _) = probe(&cfg, "admin", "admin");
    assert_eq!(f.level, Level::Ok, "{f:?}");
    assert!(f.detail.contains("firmware 2.2.1"), "{}", f.detail);
    let functions: Vec<Function> = fake
        .request_log()
        .iter()
        .filter_map(|r| r.function())
        .collect();
    assert_eq!(
        functions,
        [
            Function::CreateSession,
            Function::GetFirmwareVersion,
            Function::GetActuatorCount,
            Function::GetProductConfiguration,
            Function::GetKinematicHardLimits,
            Function::CloseSession,
        ],
        "the probe must only read"
    );
    assert!(!fake.snapshot().commanded_to_move());
    fake.shutdown();
}

/// The probe reads the arm's model as the bridge does: a Gen3 passes with a `gen3` graph and
/// fails with the Gen3 lite's, naming both.
#[test]
fn the_arms_model_is_read_and_checked_against_the_graphs_robot() {
    let gen3 = kinematics::RobotProfile::by_name("gen3").unwrap();
    let fake = FakeKortex::start(FakeConfig::for_robot(gen3)).unwrap();
    let mut cfg = config_for(fake.addr());
    let (f, _) = probe(&cfg, "admin", "admin");
    assert_eq!(f.level, Level::Fail, "{f:?}");
    assert!(
        f.detail.contains("a Gen3 (Kortex model L53, 7 actuators)")
            && f.detail.contains("gen3_lite"),
        "{}",
        f.detail
    );
    cfg.graph.robot = "gen3".into();
    cfg.safety.max_velocity_rad_s = gen3.limits().max_velocity_rad_s.clone();
    let (f, _) = probe(&cfg, "admin", "admin");
    assert_eq!(f.level, Level::Ok, "{f:?}");
    assert!(
        f.detail.contains("a Gen3 (Kortex model L53"),
        "{}",
        f.detail
    );
    assert!(!fake.snapshot().commanded_to_move());
    fake.shutdown();
}

#[test]
fn the_arms_limits_below_the_profiles_are_a_warning() {
    let fake = FakeKortex::start(FakeConfig {
        joint_speed_limits_deg_s: vec![20.0; 6],
        ..FakeConfig::default()
    })
    .unwrap();
    let (f, _) = probe(&config_for(fake.addr()), "admin", "admin");
    assert_eq!(f.level, Level::Warn, "{f:?}");
    assert!(f.detail.contains("joint 1"), "{}", f.detail);
    fake.shutdown();
}

#[test]
fn a_wrong_password_fails_clearly() {
    let fake = FakeKortex::start(FakeConfig::default()).unwrap();
    let (f, took) = probe(&config_for(fake.addr()), "admin", "wrong");
    assert_eq!(f.level, Level::Fail, "{f:?}");
    assert!(f.detail.contains("password"), "{}", f.detail);
    assert!(f.fix.contains("SCL_KORTEX_PASSWORD"), "{}", f.fix);
    assert!(took < NEVER_LONGER, "took {took:?}");
    fake.shutdown();
}

#[test]
fn an_address_nobody_answers_on_fails_without_hanging() {
    // A port just freed: nothing listens on it.
    let addr = TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap();
    let (f, took) = probe(&config_for(addr), "admin", "admin");
    assert_eq!(f.level, Level::Fail, "{f:?}");
    assert!(f.detail.contains(&addr.to_string()), "{}", f.detail);
    assert!(f.fix.contains("powered"), "{}", f.fix);
    assert!(took < NEVER_LONGER, "took {took:?}");
    // TEST-NET-1 (RFC 5737): never routed; the connect times out or is refused at once.
    let far: std::net::SocketAddr = "192.0.2.1:10000".parse().unwrap();
    let (f, took) = probe(&config_for(far), "admin", "admin");
    assert_eq!(f.level, Level::Fail, "{f:?}");
    assert!(took < NEVER_LONGER, "took {took:?}");
    println!("unroutable address: {} after {took:?}", f.detail);
}

#[test]
fn a_robot_that_never_replies_fails_after_the_reply_timeout() {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    // Accepts and holds the connection, never answers.
    let holder = std::thread::spawn(move || listener.accept().map(|(s, _)| s));
    let (f, took) = probe(&config_for(addr), "admin", "admin");
    assert_eq!(f.level, Level::Fail, "{f:?}");
    assert!(f.detail.contains("no reply"), "{}", f.detail);
    assert!(took >= scl::doctor::KORTEX_TIMEOUT, "took {took:?}");
    assert!(took < NEVER_LONGER, "took {took:?}");
    drop(holder.join());
}
