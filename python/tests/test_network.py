"""An independent Zenoh peer (the ``eclipse-zenoh`` package, not this project's code) on the
graph's gateway: it reads the robot states and drives the arm as a remote operator, with the
message layouts of :mod:`scl_teleop.msg`; a peer without credentials is refused."""

from __future__ import annotations

import json
import os
import queue
import socket
import time
from pathlib import Path

import pytest
import zenoh

from scl_teleop.msg import JoystickInput, RobotState

from .conftest import finish, start_graph

OCTET = "application/octet-stream"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def client(endpoint: str, login: "tuple[str, str] | None") -> zenoh.Config:
    conf = {
        "mode": "client",
        "connect": {"endpoints": [endpoint]},
        "scouting": {"multicast": {"enabled": False}},
    }
    if login:
        conf["transport"] = {"auth": {"usrpwd": {"user": login[0], "password": login[1]}}}
    return zenoh.Config.from_json5(json.dumps(conf))


def network_graph(tmp_path: Path):
    creds = tmp_path / "robot.creds"
    creds.write_text("operator:right-one\n")
    os.chmod(creds, 0o600)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    cfg = tmp_path / "graph.toml"
    cfg.write_text(
        "[network]\nenabled = true\naccept_joystick = true\n"
        f'listen = ["{endpoint}"]\ncredentials = "{creds}"\n'
    )
    return start_graph(tmp_path, "net", "--config", str(cfg), joystick=None), endpoint


def test_an_eclipse_zenoh_peer_reads_states_and_drives_the_arm(tmp_path: Path) -> None:
    running, endpoint = network_graph(tmp_path)
    try:
        session = zenoh.open(client(endpoint, ("operator", "right-one")))
        ns = f"scl/{running.prefix}"
        arrived: "queue.Queue[zenoh.Sample]" = queue.Queue()
        sub = session.declare_subscriber(f"{ns}/robot_state", arrived.put)
        zid = str(session.zid())
        token = session.liveliness().declare_token(f"{ns}/in/operator/{zid}")
        pub = session.declare_publisher(
            f"{ns}/in/joystick/{zid}", encoding=zenoh.Encoding(f"{OCTET};scl::JoystickInput")
        )
        answered, moved = 0, False
        deadline = time.monotonic() + 20
        while not moved and time.monotonic() < deadline:
            sample = arrived.get(timeout=5)
            assert str(sample.encoding) == f"{OCTET};scl::RobotState"
            state = RobotState.from_buffer_copy(sample.payload.to_bytes())
            assert state.n_joints == 6
            # Neutral first (the gateway passes nothing else from a new operator), then a push.
            j = JoystickInput(tick=state.tick, t_ns=0, seq=answered, gripper=0.0, buttons=0)
            j.axes[0] = 0.0 if answered < 20 else 0.6
            pub.put(bytes(j))
            answered += 1
            moved = any(abs(v) > 1e-6 for v in state.qdot())
        assert moved, f"the arm never moved after {answered} samples"
        for entity in (pub, token, sub):
            entity.undeclare()
        session.close()
        # Without credentials the gateway refuses the connection: nothing can be published.
        with pytest.raises(zenoh.ZError):
            zenoh.open(client(endpoint, None))
        with pytest.raises(zenoh.ZError):
            zenoh.open(client(endpoint, ("operator", "wrong-one")))
    finally:
        finish(running)


def test_the_package_drives_a_remote_graph_and_its_end_is_a_lost_link(tmp_path: Path) -> None:
    from scl_teleop.remote import GatewayStatus, RemoteGraph

    running, endpoint = network_graph(tmp_path)
    creds = tmp_path / "op.creds"
    creds.write_text("operator:right-one\n")
    os.chmod(creds, 0o600)
    try:
        with RemoteGraph(endpoint, running.prefix, credentials=creds) as g:
            states = g.robot_states()
            gateway = g.gateway_status()
            op = g.operator()
            moved, n = False, 0
            deadline = time.monotonic() + 20
            while not moved and time.monotonic() < deadline:
                s = states.next(2.0)
                assert s is not None, "no robot state from the gateway"
                op.publish((0.0, 0.0) if n < 20 else (0.6, 0.0))
                n += 1
                moved = any(abs(v) > 1e-6 for v in s.qdot())
            assert moved, (n, gateway.latest())
            st = gateway.latest()
            assert st is not None and GatewayStatus.LINK_NAMES[st.link] == "live", st
            assert st.forwarded > 0
            op.close()
            deadline = time.monotonic() + 10
            lost = False
            while not lost and time.monotonic() < deadline:
                st = gateway.next(1.0)
                lost = st is not None and st.link_losses >= 1
            assert lost, "closing the operator was not a lost link"
        open_creds = tmp_path / "open.creds"
        open_creds.write_text("operator:right-one\n")
        os.chmod(open_creds, 0o644)
        with pytest.raises(Exception, match="chmod 600"):
            RemoteGraph(endpoint, running.prefix, credentials=open_creds)
    finally:
        finish(running)
