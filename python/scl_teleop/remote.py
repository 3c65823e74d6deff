"""A graph on another machine, through its Zenoh gateway (``[network]`` on the robot PC).

``RemoteGraph(endpoint, prefix)`` is a Zenoh client (the ``eclipse-zenoh`` package: install
``scl-teleop[network]``) of the gateway: the same messages as :class:`scl_teleop.Graph`
(robot states, executed and mapper commands, heartbeats, tick reports) and, where the robot PC
accepts a remote operator (``accept_joystick``), an :class:`RemoteOperator` that drives the
arm under the rules of a remote joystick: it must log in (a ``user:password`` credentials
file, mode 0600), its session's liveliness token must be alive, every sample answers the
newest robot tick it has seen, input that goes stale or a lost link stops the arm, and after
either the input must pass through neutral.

>>> from scl_teleop.remote import RemoteGraph
>>> with RemoteGraph("tcp/192.0.2.10:7447", "scl", credentials="op.creds") as g:  # doctest: +SKIP
...     op = g.operator()
...     s = g.robot_states().next(1.0)
...     op.publish((0.0, 0.0))
"""

from __future__ import annotations

import ctypes
import json
import os
import queue
import stat
from pathlib import Path
from typing import Generic, List, Optional, Sequence, Type, TypeVar, Union

from . import msg
from .graph import SclError, now_ns
from .msg import (
    NO_TICK,
    EstopCommand,
    JoystickInput,
    MapperCommand,
    Message,
    NodeStatus,
    RobotState,
    SafeCommand,
    TickReport,
)

M = TypeVar("M", bound=ctypes.Structure)

OCTET = "application/octet-stream"


class GatewayStatus(Message):
    """The gateway's account (``scl::GatewayStatus``, published on ``NS/gateway``)."""

    _type_name_ = "scl::GatewayStatus"
    _fields_ = [
        ("t_ns", ctypes.c_uint64),
        ("tick", ctypes.c_uint64),
        ("acked_seq", ctypes.c_uint64),
        ("forwarded", ctypes.c_uint64),
        ("refused", ctypes.c_uint64),
        ("link_losses", ctypes.c_uint64),
        ("stale_stops", ctypes.c_uint64),
        ("outbound_dropped", ctypes.c_uint64),
        ("link", ctypes.c_uint32),
        ("reserved", ctypes.c_uint32),
    ]

    LINK_NAMES = ("none", "awaiting-neutral", "live", "lost")


def _zenoh():
    try:
        import zenoh
    except ImportError as e:  # pragma: no cover - depends on the installation
        raise SclError(
            "a remote graph needs the eclipse-zenoh package: pip install 'scl-teleop[network]'"
        ) from e
    return zenoh


def read_credentials(path: Union[str, Path]) -> "tuple[str, str]":
    """The first ``user:password`` line of ``path``, which only its owner may read."""
    p = Path(path)
    mode = stat.S_IMODE(os.stat(p).st_mode)
    if mode & 0o077:
        raise SclError(
            f"credentials file {p} has mode {mode:04o}: others than its owner may read or "
            f"change it; run `chmod 600 {p}`"
        )
    for line in p.read_text().splitlines():
        line = line.strip()
        if line:
            user, sep, password = line.partition(":")
            if not sep or not user.strip() or not password.strip():
                raise SclError(f"credentials file {p}: `{line[:20]}...` is not user:password")
            return user.strip(), password.strip()
    raise SclError(f"credentials file {p} holds no user:password line")


class RemoteSubscription(Generic[M]):
    """The samples of one key, queued as they arrive (at most ``depth``; the oldest dropped)."""

    def __init__(self, graph: "RemoteGraph", key: str, ty: Type[M], depth: int = 256) -> None:
        self._ty = ty
        # Every robot state any subscription receives moves the graph's newest tick first, so
        # an operator answers at least the state its caller just took.
        seen = graph._saw_state if ty is RobotState else None
        self._q: "queue.Queue[M]" = queue.Queue(maxsize=depth)
        want = f"{OCTET};{ty._type_name_}"
        size = ctypes.sizeof(ty)

        def take(sample) -> None:
            payload = sample.payload.to_bytes()
            if str(sample.encoding) != want or len(payload) != size:
                return  # another type or a short payload is never read
            m = ty.from_buffer_copy(payload)
            if seen is not None:
                seen(m)
            try:
                self._q.put_nowait(m)
            except queue.Full:
                try:
                    self._q.get_nowait()
                except queue.Empty:
                    pass
                self._q.put_nowait(m)

        self._sub = graph._session.declare_subscriber(key, take)

    def next(self, timeout_s: float = 1.0) -> Optional[M]:
        """The next sample, or ``None`` after ``timeout_s``."""
        try:
            return self._q.get(timeout=timeout_s)
        except queue.Empty:
            return None

    def drain(self) -> List[M]:
        """Every sample queued, oldest first."""
        out = []
        while True:
            try:
                out.append(self._q.get_nowait())
            except queue.Empty:
                return out

    def latest(self) -> Optional[M]:
        """The newest queued sample (the rest dropped), or ``None``."""
        d = self.drain()
        return d[-1] if d else None

    def close(self) -> None:
        """Ends the subscription (idempotent)."""
        if self._sub is not None:
            self._sub.undeclare()
            self._sub = None


class RemoteOperator:
    """A remote operator of the graph: a liveliness token for its session and its samples on
    ``NS/in/joystick/<session>``, each answering the newest robot tick it has seen."""

    def __init__(self, graph: "RemoteGraph") -> None:
        s = graph._session
        zid = str(s.zid())
        ns = graph.namespace
        self._states = RemoteSubscription(graph, f"{ns}/robot_state", RobotState, depth=8)
        self._token = s.liveliness().declare_token(f"{ns}/in/operator/{zid}")
        z = _zenoh()
        self._pub = s.declare_publisher(
            f"{ns}/in/joystick/{zid}", encoding=z.Encoding(f"{OCTET};{JoystickInput._type_name_}")
        )
        self._estop = s.declare_publisher(
            f"{ns}/in/estop", encoding=z.Encoding(f"{OCTET};{EstopCommand._type_name_}")
        )
        self._graph = graph
        self._seq = 0
        self._estop_held = False

    @property
    def tick(self) -> int:
        """The newest robot tick this client has seen (:data:`NO_TICK` before the first)."""
        self._states.drain()
        return self._graph._tick

    def publish(
        self, axes: Sequence[float] = (0.0, 0.0), gripper: float = 0.0, buttons: int = 0
    ) -> JoystickInput:
        """Publishes one sample answering the newest tick seen; returns what was sent. A press
        of the e-stop button also goes to ``NS/in/estop``."""
        if len(axes) != msg.ACTION_DIM:
            raise ValueError(f"axes must have {msg.ACTION_DIM} values, got {len(axes)}: {axes!r}")
        m = JoystickInput()
        m.tick = self.tick
        m.t_ns = now_ns()
        m.seq = self._seq
        m.axes[0], m.axes[1] = float(axes[0]), float(axes[1])
        m.gripper = float(gripper)
        m.buttons = int(buttons)
        self._pub.put(bytes(m))
        self._seq += 1
        held = bool(buttons & msg.buttons.ESTOP)
        if held and not self._estop_held:
            self._estop.put(bytes(EstopCommand(t_ns=now_ns(), action=msg.ESTOP_ACTION_ESTOP)))
        self._estop_held = held
        return m

    def close(self) -> None:
        """Ends the session's token: the gateway counts the link lost (idempotent)."""
        if self._token is None:
            return
        for e in (self._pub, self._estop, self._token):
            e.undeclare()
        self._token = None
        self._states.close()


class RemoteGraph:
    """A Zenoh client of graph ``prefix``'s gateway at ``endpoint`` (``tcp/HOST:PORT``)."""

    def __init__(
        self,
        endpoint: str,
        prefix: str = "scl",
        *,
        namespace: Optional[str] = None,
        credentials: Optional[Union[str, Path]] = None,
        lease_ms: int = 1000,
    ) -> None:
        z = _zenoh()
        conf = {
            "mode": "client",
            "connect": {"endpoints": [endpoint]},
            "scouting": {"multicast": {"enabled": False}},
            "transport": {"link": {"tx": {"lease": lease_ms}}},
        }
        if credentials is not None:
            user, password = read_credentials(credentials)
            conf["transport"]["auth"] = {"usrpwd": {"user": user, "password": password}}
        self.namespace = namespace or f"scl/{prefix}"
        try:
            self._session = z.open(z.Config.from_json5(json.dumps(conf)))
        except Exception as e:
            raise SclError(f"cannot join the gateway at {endpoint}: {e}") from e
        self._owned: list = []
        self._tick = NO_TICK

    def _saw_state(self, s: RobotState) -> None:
        if self._tick == NO_TICK or s.tick > self._tick:
            self._tick = s.tick

    def _sub(self, topic: str, ty: Type[M]) -> RemoteSubscription[M]:
        s = RemoteSubscription(self, f"{self.namespace}/{topic}", ty)
        self._owned.append(s)
        return s

    def robot_states(self) -> RemoteSubscription[RobotState]:
        return self._sub("robot_state", RobotState)

    def safe_commands(self) -> RemoteSubscription[SafeCommand]:
        return self._sub("safe_command", SafeCommand)

    def mapper_commands(self) -> RemoteSubscription[MapperCommand]:
        return self._sub("mapper_command", MapperCommand)

    def heartbeats(self) -> RemoteSubscription[NodeStatus]:
        return self._sub("status", NodeStatus)

    def tick_reports(self) -> RemoteSubscription[TickReport]:
        return self._sub("tick_report", TickReport)

    def gateway_status(self) -> RemoteSubscription[GatewayStatus]:
        return self._sub("gateway", GatewayStatus)

    def operator(self) -> RemoteOperator:
        """A remote operator (the robot PC must accept one, and this client must have logged
        in with credentials the gateway lists)."""
        op = RemoteOperator(self)
        self._owned.append(op)
        return op

    def close(self) -> None:
        """Closes the operator and subscriptions, then the session."""
        for o in reversed(self._owned):
            o.close()
        self._owned.clear()
        self._session.close()

    def __enter__(self) -> "RemoteGraph":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
