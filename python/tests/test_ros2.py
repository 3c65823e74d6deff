"""The gateway as a ROS 2 node on Zenoh, seen by a peer that knows ROS 2 only from its
published message definitions (``rosbags``: the CDR codec and its own computation of ROS 2's
type hashes) and rmw_zenoh's key-expression and liveliness-token formats; no ROS installation.
It reads ``/joint_states`` and the tokens, and drives the arm as a ROS 2 ``joy`` node would."""

from __future__ import annotations

import json
import math
import os
import queue
import socket
import time
from pathlib import Path
from typing import Optional

import numpy as np
import zenoh
from rosbags.typesys import Stores, get_typestore

from scl_teleop.msg import RobotState

from .conftest import finish, start_graph

TYPES = get_typestore(Stores.ROS2_JAZZY)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_joint_states_and_liveliness_tokens_as_ros2_sees_them(tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    cfg = tmp_path / "graph.toml"
    cfg.write_text(
        f'[network]\nenabled = true\nros2 = true\nros2_domain_id = 7\nlisten = ["{endpoint}"]\n'
    )
    running = start_graph(tmp_path, "ros", "--config", str(cfg), joystick="script")
    try:
        conf = {
            "mode": "client",
            "connect": {"endpoints": [endpoint]},
            "scouting": {"multicast": {"enabled": False}},
        }
        session = zenoh.open(zenoh.Config.from_json5(json.dumps(conf)))
        arrived: "queue.Queue[zenoh.Sample]" = queue.Queue()
        sub = session.declare_subscriber("7/joint_states/**", arrived.put)
        sample = arrived.get(timeout=10)
        _domain, topic, type_name, type_hash = str(sample.key_expr).split("/")
        assert (topic, type_name) == ("joint_states", "sensor_msgs::msg::dds_::JointState_")
        assert type_hash == TYPES.hash_rihs01("sensor_msgs/msg/JointState")
        msg = TYPES.deserialize_cdr(sample.payload.to_bytes(), "sensor_msgs/msg/JointState")
        assert len(msg.name) == 6 and len(set(msg.name)) == 6
        assert len(msg.position) == 6 and all(math.isfinite(q) for q in msg.position)
        assert len(msg.velocity) == 6
        assert msg.header.stamp.sec > 1_600_000_000, "a wall-clock stamp"
        # rmw_zenoh's attachment: sequence number, source timestamp, 16-byte publisher id.
        att = sample.attachment.to_bytes()
        assert len(att) == 33 and att[16] == 16
        sub.undeclare()
        tokens = [str(r.ok.key_expr) for r in session.liveliness().get("@ros2_lv/7/**", timeout=5)]
        assert any(t.endswith("/NN/%/%/scl_gateway") for t in tokens), tokens
        js = f"/MP/%/%/scl_gateway/%joint_states/sensor_msgs::msg::dds_::JointState_/{type_hash}/"
        assert any(js in t for t in tokens), tokens
        status_hash = TYPES.hash_rihs01("std_msgs/msg/String")
        assert any(f"%scl%safety_status/std_msgs::msg::dds_::String_/{status_hash}/" in t for t in tokens), tokens
        session.close()
    finally:
        finish(running)


def test_a_ros2_joy_publisher_drives_the_arm_and_stopping_it_stops_the_arm(tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    creds = tmp_path / "robot.creds"
    creds.write_text("joy:pw\n")
    os.chmod(creds, 0o600)
    cfg = tmp_path / "graph.toml"
    cfg.write_text(
        "[network]\nenabled = true\nros2 = true\nros2_domain_id = 7\nros2_joy = true\n"
        f'accept_joystick = true\ncredentials = "{creds}"\nlisten = ["{endpoint}"]\n'
    )
    running = start_graph(tmp_path, "joy", "--config", str(cfg), joystick=None)
    try:
        conf = {
            "mode": "client",
            "connect": {"endpoints": [endpoint]},
            "scouting": {"multicast": {"enabled": False}},
            "transport": {"auth": {"usrpwd": {"user": "joy", "password": "pw"}}},
        }
        session = zenoh.open(zenoh.Config.from_json5(json.dumps(conf)))
        states: "queue.Queue[zenoh.Sample]" = queue.Queue()
        sub = session.declare_subscriber(f"scl/{running.prefix}/robot_state", states.put)
        joy_hash = TYPES.hash_rihs01("sensor_msgs/msg/Joy")
        joy_type = "sensor_msgs::msg::dds_::Joy_"
        zid = str(session.zid())
        # As a ROS 2 joy node appears: its node and its publisher's liveliness tokens.
        node = session.liveliness().declare_token(f"@ros2_lv/7/{zid}/0/0/NN/%/%/joy_node")
        token = session.liveliness().declare_token(
            f"@ros2_lv/7/{zid}/0/1/MP/%/%/joy_node/%joy/{joy_type}/{joy_hash}/::,10:,:,:,,"
        )
        pub = session.declare_publisher(f"7/joy/{joy_type}/{joy_hash}")
        Joy = TYPES.types["sensor_msgs/msg/Joy"]
        Header = TYPES.types["std_msgs/msg/Header"]
        Time = TYPES.types["builtin_interfaces/msg/Time"]
        def joy(x: float) -> bytes:
            msg = Joy(
                header=Header(stamp=Time(sec=0, nanosec=0), frame_id=""),
                axes=np.array([x, 0.0], dtype=np.float32),
                buttons=np.array([0, 0], dtype=np.int32),
            )
            return bytes(TYPES.serialize_cdr(msg, "sensor_msgs/msg/Joy"))

        def newest_state() -> Optional[RobotState]:
            s = None
            while not states.empty():
                s = RobotState.from_buffer_copy(states.get().payload.to_bytes())
            return s

        moved = False
        deadline = time.monotonic() + 20
        n = 0
        while not moved and time.monotonic() < deadline:
            pub.put(joy(0.0 if n < 20 else 0.6))  # neutral first, then a push
            n += 1
            time.sleep(0.025)
            s = newest_state()
            moved = s is not None and any(abs(v) > 1e-6 for v in s.qdot())
        assert moved, f"the arm never moved after {n} /joy messages"
        # The joy node goes quiet: past the timeout its input is stale and the arm stops.
        deadline = time.monotonic() + 10
        at_rest = False
        while not at_rest and time.monotonic() < deadline:
            time.sleep(0.1)
            s = newest_state()
            at_rest = s is not None and all(v == 0.0 for v in s.qdot())
        assert at_rest, "the arm did not stop when /joy went quiet"
        for entity in (pub, token, node, sub):
            entity.undeclare()
        session.close()
    finally:
        finish(running)
