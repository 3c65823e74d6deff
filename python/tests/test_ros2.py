"""The gateway as a ROS 2 node on Zenoh, seen by a peer that knows ROS 2 only from its
published message definitions (``rosbags``: the CDR decoder and its own computation of
ROS 2's type hashes) and rmw_zenoh's key-expression and liveliness-token formats; no ROS
installation."""

from __future__ import annotations

import json
import math
import queue
import socket
from pathlib import Path

import zenoh
from rosbags.typesys import Stores, get_typestore

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
