use super::*;
use foxglove::messages::{ArrowPrimitive, FrameTransforms, SceneUpdate};
use ipc_types::NodeStatus;
use nalgebra::{Quaternion as NQ, UnitQuaternion};
use prost::Message;
use std::path::Path;

fn state(tick: u64, q: [f64; 6]) -> RobotState {
    let mut s = RobotState::at_rest(tick, 1_000_000_000 + tick * 25_000_000, 6);
    s.q_rad[..6].copy_from_slice(&q);
    s.qdot_rad_s[..6].copy_from_slice(&[0.1, -0.2, 0.05, 0.3, 0.0, -0.1]);
    s
}

const Q: [f64; 6] = [0.3, 0.4, 1.9, -0.5, 0.8, 0.2];

fn viz_with_bundled() -> Viz {
    let mut v = Viz::new(&GraphConfig::default()).unwrap();
    v.set_model(1, LoadedModel::load("bundled").unwrap());
    v
}

fn messages(v: &mut Viz, s: &RobotState) -> Vec<VizMessage> {
    let mut out = Vec::new();
    v.observe(&Payload::RobotState(*s), &mut out).unwrap();
    out
}

fn arrow_vector(a: &ArrowPrimitive) -> Vector3<f64> {
    let p = a.pose.unwrap();
    let o = p.orientation.unwrap();
    let r = UnitQuaternion::from_quaternion(NQ::new(o.w, o.x, o.y, o.z));
    r * Vector3::x() * (a.shaft_length + a.head_length)
}

#[test]
fn frames_of_every_link_and_the_tool_agree_with_the_kinematics() {
    let mut v = viz_with_bundled();
    let out = messages(&mut v, &state(7, Q));
    let tf = out.iter().find(|m| m.topic == VizTopic::Tf).unwrap();
    let tf = FrameTransforms::decode(tf.data.as_slice()).unwrap();
    let chain = v.robot().arm();
    let names: Vec<&str> = chain.link_names().filter(|n| *n != chain.base()).collect();
    // The gripper's links come from the collision model (at the state's gripper opening).
    let cm = v.robot().collision_model().unwrap();
    let (lo, hi) = cm.gripper_range();
    let mut q7 = Q.to_vec();
    q7.push(hi);
    let mut cl = Clearance::default();
    cm.clearance(&q7, &Scene::empty(), &mut cl).unwrap();
    let extra: Vec<kinematics::CollisionLink> = kinematics::CollisionLink::ALL
        .into_iter()
        .filter(|l| chain.link_id(l.name()).is_none())
        .collect();
    assert!(!extra.is_empty());
    let _ = lo;
    assert_eq!(tf.transforms.len(), names.len() + 1 + extra.len());
    for name in &names {
        assert!(
            tf.transforms.iter().any(|t| t.child_frame_id == *name),
            "{name}"
        );
    }
    // Each link hangs from the link before it along the chain, the tool and the gripper's
    // links from the tip; composed down from the base, each frame is where the kinematics
    // put it.
    let chain_names: Vec<&str> = chain.link_names().collect();
    let by_child: std::collections::BTreeMap<&str, &foxglove::messages::FrameTransform> = tf
        .transforms
        .iter()
        .map(|t| (t.child_frame_id.as_str(), t))
        .collect();
    let in_base = |name: &str| {
        let mut pose = nalgebra::Isometry3::identity();
        let mut at = name;
        while at != chain.base() {
            let t = by_child[at];
            let tr = t.translation.unwrap();
            let r = t.rotation.unwrap();
            let iso = nalgebra::Isometry3::from_parts(
                nalgebra::Translation3::new(tr.x, tr.y, tr.z),
                UnitQuaternion::from_quaternion(NQ::new(r.w, r.x, r.y, r.z)),
            );
            pose = iso * pose;
            at = t.parent_frame_id.as_str();
        }
        pose
    };
    for t in &tf.transforms {
        let parent = if let Some(i) = chain_names.iter().position(|n| *n == t.child_frame_id) {
            chain_names[i - 1]
        } else {
            chain.tip()
        };
        assert_eq!(t.parent_frame_id, parent, "{}", t.child_frame_id);
        let want = if t.child_frame_id == TOOL_FRAME {
            chain.fk(&Q).unwrap()
        } else if let Some(id) = chain.link_id(&t.child_frame_id) {
            chain.link_pose(&Q, id).unwrap()
        } else {
            *cl.link_pose(kinematics::CollisionLink::from_name(&t.child_frame_id).unwrap())
        };
        let got = in_base(&t.child_frame_id);
        assert!(
            (got.translation.vector - want.translation.vector).norm() < 1e-9,
            "{}",
            t.child_frame_id
        );
        assert!(
            got.rotation.angle_to(&want.rotation) < 1e-9,
            "{}",
            t.child_frame_id
        );
    }
}

#[test]
fn arm_capsules_are_sent_whole_once_a_second_and_on_a_colour_change() {
    let mut v = viz_with_bundled();
    let first = messages(&mut v, &state(0, Q));
    let arm = SceneUpdate::decode(
        first
            .iter()
            .find(|m| m.topic == VizTopic::Arm)
            .unwrap()
            .data
            .as_slice(),
    )
    .unwrap();
    assert_eq!(arm.entities.len(), v.refs.len());
    assert!(arm.entities.iter().all(|e| e.frame_locked));
    // The same pose: nothing changed, no arm message.
    let same = messages(&mut v, &state(1, Q));
    assert!(!same.iter().any(|m| m.topic == VizTopic::Arm));
    // A second later: the whole arm again.
    let later = messages(&mut v, &state(40, Q));
    let arm = SceneUpdate::decode(
        later
            .iter()
            .find(|m| m.topic == VizTopic::Arm)
            .unwrap()
            .data
            .as_slice(),
    )
    .unwrap();
    assert_eq!(arm.entities.len(), v.refs.len());
}

/// The Gen3's seven joints: the clearance and the arm's capsules as for the Gen3 lite's six,
/// every capsule of its collision model sent, the gripper's links hung from the chain's tip.
#[test]
fn a_gen3_state_gets_its_clearance_and_every_capsule() {
    let cfg = GraphConfig::parse("[graph]\nrobot = \"gen3\"\n", Path::new("g.toml")).unwrap();
    let mut v = Viz::new(&cfg).unwrap();
    assert_eq!(v.robot().n_joints(), 7);
    let home = v.robot().named_pose("home").unwrap();
    let mut s = RobotState::at_rest(0, 1_000_000_000, 7);
    s.q_rad[..7].copy_from_slice(home);
    let out = messages(&mut v, &s);
    let arm = out.iter().find(|m| m.topic == VizTopic::Arm).unwrap();
    let arm = SceneUpdate::decode(arm.data.as_slice()).unwrap();
    assert!(!v.refs.is_empty());
    assert_eq!(arm.entities.len(), v.refs.len());
    let tick = out.iter().find(|m| m.topic == VizTopic::Tick).unwrap();
    let row: serde_json::Value = serde_json::from_slice(&tick.data).unwrap();
    let d = row["clearance_m"].as_f64().unwrap();
    // The one the collision model computes at that pose in the graph's scene (the gripper
    // at rest, open: the state's 0).
    let cm = v.robot().collision_model().unwrap();
    let mut q = home.to_vec();
    q.push(cm.gripper_range().1);
    let mut cl = Box::<kinematics::collision::Clearance>::default();
    cm.clearance(&q, &cfg.safety.scene.scene().unwrap(), &mut cl)
        .unwrap();
    assert!(
        d > 0.0 && d == cl.min_distance_m(),
        "{d} {}",
        cl.min_distance_m()
    );
}

#[test]
fn the_map_arrows_are_j_s_h_e_i() {
    let mut v = viz_with_bundled();
    let s = state(3, Q);
    let out = messages(&mut v, &s);
    let map = out.iter().find(|m| m.topic == VizTopic::Map).unwrap();
    let map = SceneUpdate::decode(map.data.as_slice()).unwrap();
    // Independently: a fresh model, e_i through eval, the speed scale, the Jacobian.
    let mut model = LoadedModel::load("bundled").unwrap();
    let chain = v.robot().arm();
    let mut jac = Jacobian::zeros(6);
    let tool = chain.fk_jacobian(&Q, &mut jac).unwrap();
    for i in 0..2 {
        let mut a = [0.0; 2];
        a[i] = 1.0;
        let mut qd = [0.0; 6];
        model.map.eval(&Q, s.gripper, &a, &mut qd);
        let qd: Vec<f64> = qd
            .iter()
            .map(|x| x * model.header.speed_scale_rad_s)
            .collect();
        let tw = jac.matrix() * DVector::from_column_slice(&qd);
        let e = map
            .entities
            .iter()
            .find(|e| e.id == format!("map/axis{}", i + 1))
            .unwrap();
        let lin = arrow_vector(&e.arrows[0]) / LINEAR_ARROW_S;
        let ang = arrow_vector(&e.arrows[1]) / ANGULAR_ARROW_M_PER_RAD_S;
        assert!(
            (lin - Vector3::new(tw[0], tw[1], tw[2])).norm() < 1e-9,
            "{lin} {tw}"
        );
        assert!((ang - Vector3::new(tw[3], tw[4], tw[5])).norm() < 1e-9);
        let p = e.arrows[0].pose.unwrap().position.unwrap();
        assert!((Vector3::new(p.x, p.y, p.z) - tool.translation.vector).norm() < 1e-12);
    }
    let tick = out.iter().find(|m| m.topic == VizTopic::Tick).unwrap();
    let row: serde_json::Value = serde_json::from_slice(&tick.data).unwrap();
    assert_eq!(row["tick"], 3);
    assert_eq!(row["mapper_id"], 1);
    assert!(row["clearance_m"].as_f64().unwrap() > 0.0);
}

#[test]
fn mode_switching_arrows_follow_the_mappers_mode() {
    let mut v = Viz::new(&GraphConfig::default()).unwrap();
    v.set_model(2, LoadedModel::load("modeswitch").unwrap());
    // Away from singularities, where mode switching slows down.
    let home: [f64; 6] = v.robot().named_pose("home").unwrap().try_into().unwrap();
    let s = state(1, home);
    let lin = |v: &mut Viz| {
        let out = messages(v, &s);
        let row: serde_json::Value =
            serde_json::from_slice(&out.iter().find(|m| m.topic == VizTopic::Tick).unwrap().data)
                .unwrap();
        (
            row["mode"].as_str().unwrap().to_owned(),
            row["axis1_m_s"].clone(),
            row,
        )
    };
    let (mode, a1, _) = lin(&mut v);
    assert_eq!(mode, "x-y");
    // x-y: axis 1 drives x at the linear limit.
    assert!((a1[0].as_f64().unwrap() - 0.3).abs() < 1e-3, "{a1}");
    // The mapper reports z-yaw (mode 2): axis 1 turns the tool about z, axis 2 drives z.
    let mut st = NodeStatus::new(NodeRole::Mapper, ipc_types::phase::RUNNING, 0);
    st.mapper_id = 2;
    st.mode = 2;
    v.observe(&Payload::Status(st), &mut Vec::new()).unwrap();
    let (mode, a1, row) = lin(&mut v);
    assert_eq!(mode, "z-yaw");
    let w1 = &row["axis1_rad_s"];
    let a2 = &row["axis2_m_s"];
    assert!((w1[2].as_f64().unwrap() - 0.85).abs() < 1e-3, "{w1}");
    assert!(a1[0].as_f64().unwrap().abs() < 1e-3, "{a1}");
    assert!((a2[2].as_f64().unwrap() - 0.3).abs() < 1e-3, "{a2}");
}

#[test]
fn without_a_model_the_axes_are_deleted_and_the_executed_arrow_stays() {
    let mut v = Viz::new(&GraphConfig::default()).unwrap();
    let out = messages(&mut v, &state(0, Q));
    let map = out.iter().find(|m| m.topic == VizTopic::Map).unwrap();
    let map = SceneUpdate::decode(map.data.as_slice()).unwrap();
    assert_eq!(map.deletions.len(), 2);
    assert_eq!(map.entities.len(), 1);
    assert_eq!(map.entities[0].id, "map/executed");
    // The world comes with the first state, then once a second.
    assert!(out.iter().any(|m| m.topic == VizTopic::World));
    let later = messages(&mut v, &state(1, Q));
    assert!(!later.iter().any(|m| m.topic == VizTopic::World));
    let arm = out.iter().find(|m| m.topic == VizTopic::Arm).unwrap();
    let arm = SceneUpdate::decode(arm.data.as_slice()).unwrap();
    assert_eq!(arm.entities.len(), v.refs.len());
    assert!(!arm.entities.is_empty());
}

#[test]
fn clearance_colours_go_from_green_to_red() {
    let far = scene::clearance_color(1.0);
    let near = scene::clearance_color(0.0);
    assert!(far.g > 0.9 && far.r < 0.1, "{far:?}");
    assert!(near.r > 0.9 && near.g < 0.1, "{near:?}");
}

/// A recording of `n` states plus a mapper's process record naming the bundled model.
fn old_recording(n: u64) -> Vec<u8> {
    let mut w = LogWriter::new(Vec::new(), Path::new("old.mcap"), None).unwrap();
    w.add_topic(recording::Topic::RobotState, &BTreeMap::new())
        .unwrap();
    let mut m = BTreeMap::new();
    m.insert("role".to_owned(), "mapper".to_owned());
    m.insert("mapper_id".to_owned(), "1".to_owned());
    m.insert("model_spec".to_owned(), "bundled".to_owned());
    w.write_metadata(&recording::metadata(recording::PROCESS_METADATA, m))
        .unwrap();
    for k in 0..n {
        w.write(&Payload::RobotState(state(k, Q))).unwrap();
    }
    w.finish(None).unwrap()
}

use recording::LogWriter;

#[test]
fn convert_adds_the_3d_channels_and_refuses_a_converted_file() {
    let old = old_recording(50);
    let (r, bytes) = convert::convert_into(
        old.as_slice(),
        Path::new("old.mcap"),
        Vec::new(),
        Path::new("new.mcap"),
    )
    .unwrap();
    assert_eq!(r.copied, 50);
    assert_eq!(r.states, 50);
    assert!(r.notes.is_empty(), "{:?}", r.notes);
    let mut per: BTreeMap<String, u64> = BTreeMap::new();
    recording::read(bytes.as_slice(), Path::new("new.mcap"), |ev| {
        if let recording::Event::Message { channel, .. } = ev {
            *per.entry(channel.topic.clone()).or_default() += 1;
        }
        Ok(())
    })
    .unwrap();
    assert_eq!(per["/robot_state"], 50);
    assert_eq!(per["/tf"], 50);
    assert_eq!(per["/scl/map"], 50);
    assert_eq!(per["/scl/tick"], 50);
    assert_eq!(per["/scl/world"], 2, "{per:?}");
    let e = convert::convert_into(
        bytes.as_slice(),
        Path::new("new.mcap"),
        Vec::new(),
        Path::new("again.mcap"),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("has the 3D channels already"), "{e}");
}

#[test]
fn every_topic_has_a_schema_foxglove_knows() {
    for t in VizTopic::ALL {
        let s = t.schema();
        assert!(!s.data.is_empty(), "{t:?}");
        match t.message_encoding() {
            "protobuf" => assert!(s.name.starts_with("foxglove."), "{}", s.name),
            _ => assert_eq!(s.encoding, "jsonschema"),
        }
        assert_eq!(VizTopic::from_topic(t.topic()), Some(t));
    }
}
