"""Joining a running graph from Python: subscriptions, the operator's input, e-stop, swaps.

A :class:`Graph` is an iceoryx2 node in the graph's domain (every shared-memory file named
``scl_<prefix>_*``). It opens each topic with the same settings as the Rust processes
(``transport::graph``), so it reads the same samples and wakes on the same events.
"""

from __future__ import annotations

import ctypes
import gc
import os
import re
import time
from dataclasses import dataclass, field
from typing import Dict, Generic, Iterator, List, Optional, Sequence, Type, TypeVar

import iceoryx2 as iox2

from . import msg
from .msg import (
    NO_TICK,
    ControlRequest,
    ControlResponse,
    EstopCommand,
    JoystickInput,
    MapperCommand,
    Message,
    NodeStatus,
    RobotState,
    SafeCommand,
    SafetyControl,
    TickReport,
)

#: The iceoryx2 release the Rust crate is built with; the shared-memory formats of other
#: releases are not compatible.
ICEORYX2_VERSION = "0.10"
#: Longest graph prefix (``ipc_types::prefix::MAX_PREFIX_LEN``).
MAX_PREFIX_LEN = 32
#: A heartbeat younger than this counts as alive (as ``scl status`` counts it), seconds.
ALIVE_S = 0.25

_PREFIX_RE = re.compile(r"^[A-Za-z0-9_-]+$")

M = TypeVar("M", bound=Message)


class SclError(Exception):
    """Base of the errors of this package; the message names the graph and what is wrong."""


class GraphNotRunning(SclError):
    """No process of the graph is alive under the prefix."""


class VersionMismatch(SclError):
    """The running graph was built with other message layouts or another iceoryx2."""


class PortRefused(SclError):
    """The graph refused a port: e.g. the joystick topic already has its one publisher."""


class RequestFailed(SclError):
    """A request to the supervisor found no supervisor, got no answer, or was refused."""


class NotConfirmed(SclError):
    """Safety did not confirm an e-stop or reset in time."""


@dataclass(frozen=True)
class TopicSettings:
    """A topic's quality-of-service settings, as ``ipc_types::topics::TopicSettings``."""

    name: str
    message: Type[Message]
    history: int
    buffer: int
    max_publishers: int
    max_subscribers: int


#: Every topic of the graph, by name; the drift test compares them with ``scl layout``.
TOPICS: Dict[str, TopicSettings] = {
    t.name: t
    for t in (
        TopicSettings("joystick", JoystickInput, 1, 64, 1, 16),
        TopicSettings("robot_state", RobotState, 1, 64, 1, 16),
        TopicSettings("mapper_command", MapperCommand, 0, 64, 4, 8),
        TopicSettings("safe_command", SafeCommand, 0, 64, 1, 8),
        TopicSettings("status", NodeStatus, 0, 512, 16, 8),
        TopicSettings("tick_report", TickReport, 0, 256, 2, 8),
        TopicSettings("safety_control", SafetyControl, 1, 8, 2, 8),
        TopicSettings("estop", EstopCommand, 1, 8, 8, 8),
    )
}
#: The supervisor's request-response service below the prefix.
SUPERVISOR_SERVICE = "supervisor"


def now_ns() -> int:
    """``CLOCK_MONOTONIC`` in nanoseconds: the clock every message of the graph is stamped
    with, so ``now_ns() - state.t_ns`` is a sample's age."""
    return time.clock_gettime_ns(time.CLOCK_MONOTONIC)


def check_prefix(prefix: str) -> str:
    """Returns ``prefix`` if it is a valid graph prefix, else raises ``ValueError`` saying
    why (the rules of ``ipc_types::Prefix``)."""
    if not prefix:
        raise ValueError("the graph prefix is empty; give a name such as `scl` or `lab2`")
    if len(prefix) > MAX_PREFIX_LEN:
        raise ValueError(f"the graph prefix `{prefix}` is longer than {MAX_PREFIX_LEN} characters")
    if not _PREFIX_RE.match(prefix):
        raise ValueError(
            f"the graph prefix `{prefix}` has a character other than letters, digits, `_` and `-`"
        )
    return prefix


def _iceoryx2_version() -> str:
    try:
        from importlib.metadata import version

        return version("iceoryx2")
    except Exception:  # pragma: no cover - metadata missing only in odd installs
        return "unknown"


def _copy(ptr: "ctypes._Pointer[M]", ty: Type[M]) -> M:
    out = ty()
    ctypes.memmove(ctypes.byref(out), ptr, ctypes.sizeof(ty))
    return out


class Subscription(Generic[M]):
    """A subscriber of one topic, with the topic's wake-up event when asked for.

    Samples are copied out of shared memory, so they stay valid after the graph is gone.
    """

    def __init__(self, graph: "Graph", topic: TopicSettings, wake: bool) -> None:
        self._graph = graph
        self.topic = topic
        self.service_name = graph.service_name(topic.name)
        service = graph._pubsub(topic)
        self._sub = graph._port(lambda: service.subscriber_builder().create(), topic, "subscriber")
        self._listener = None
        if wake:
            event = graph._event(topic)
            try:
                self._listener = graph._port(
                    lambda: event.listener_builder().create(), topic, "listener"
                )
            except SclError:
                self._sub.delete()
                raise
        graph._owned.append(self)

    def _live_sub(self):
        if self._sub is None:
            raise SclError(f"`{self.service_name}`: this subscription was closed")
        return self._sub

    def receive(self) -> Optional[M]:
        """The oldest buffered message, or ``None`` if there is none."""
        sample = self._live_sub().receive()
        if sample is None:
            return None
        out = _copy(sample.payload(), self.topic.message)
        sample.delete()
        return out  # type: ignore[return-value]

    def drain(self) -> List[M]:
        """Every buffered message, oldest first."""
        out: List[M] = []
        while True:
            m = self.receive()
            if m is None:
                return out
            out.append(m)

    def latest(self) -> Optional[M]:
        """The newest buffered message, discarding older ones; ``None`` if there is none."""
        msgs = self.drain()
        return msgs[-1] if msgs else None

    def wait(self, timeout_s: float) -> bool:
        """Blocks until the topic's event fires or ``timeout_s`` passes; returns whether it
        fired. Without a wake-up (``wake=False``) this sleeps briefly and checks the buffer."""
        sub = self._live_sub()
        if self._listener is None:
            deadline = time.monotonic() + timeout_s
            while time.monotonic() < deadline:
                if sub.has_samples():
                    return True
                time.sleep(0.002)
            return sub.has_samples()
        fired = self._listener.timed_wait(iox2.Duration.from_secs_f64(max(timeout_s, 0.0)))
        return len(fired) > 0

    def next(self, timeout_s: float = 1.0) -> Optional[M]:
        """The next message: the oldest buffered one, else the first to arrive within
        ``timeout_s``; ``None`` if none did."""
        deadline = time.monotonic() + timeout_s
        while True:
            m = self.receive()
            if m is not None:
                return m
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            self.wait(left)

    def next_latest(self, timeout_s: float = 1.0) -> Optional[M]:
        """The newest message, discarding older ones; if none is buffered, the first to
        arrive within ``timeout_s`` (``None`` if none did). What a control loop wants: the
        state of the current tick, never a backlog."""
        deadline = time.monotonic() + timeout_s
        while True:
            m = self.latest()
            if m is not None:
                return m
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            self.wait(left)

    def __iter__(self) -> Iterator[M]:
        """Messages as they arrive, until the topic is quiet for a second."""
        while True:
            m = self.next(1.0)
            if m is None:
                return
            yield m

    def close(self) -> None:
        """Releases the ports (also done when the graph closes); using the subscription
        afterwards raises :class:`SclError`."""
        if self._listener is not None:
            self._listener.delete()
            self._listener = None
        if self._sub is not None:
            self._sub.delete()
            self._sub = None
        if self in self._graph._owned:
            self._graph._owned.remove(self)


def _busy(prefix: str) -> PortRefused:
    return PortRefused(
        f"graph `{prefix}`: the joystick topic already has its publisher (a joystick process "
        "or another operator); start the graph with `scl up --joystick external` and run one "
        "operator at a time"
    )


class Operator:
    """The graph's operator: publishes :class:`JoystickInput` samples as a joystick would.

    The joystick topic admits one publisher, so an operator exists only while the graph has
    no other one (``[joystick] source = "external"``, ``scl up --joystick external``). Every
    sample answers the newest robot tick this operator has seen, as the joystick process's
    samples do, so input that stops stops the arm within two ticks. A press of the e-stop
    button (the rising edge of :attr:`msg.buttons.ESTOP`) also goes out on the e-stop topic,
    so it latches with safety alone.
    """

    def __init__(self, graph: "Graph") -> None:
        self._graph = graph
        topic = TOPICS["joystick"]
        service = graph._pubsub(topic)
        self._pub = self._notifier = self._estop = None
        self._states: Optional[Subscription[RobotState]] = None
        if service.dynamic_config.number_of_publishers >= topic.max_publishers:
            raise _busy(graph.prefix)
        try:
            try:
                self._pub = service.publisher_builder().create()
            except Exception as e:  # the service admits one publisher: another won the race
                raise _busy(graph.prefix) from e
            event = graph._event(topic)
            self._notifier = graph._port(
                lambda: event.notifier_builder().create(), topic, "notifier"
            )
            self._states = Subscription(graph, TOPICS["robot_state"], False)
            estop = graph._pubsub(TOPICS["estop"])
            self._estop = graph._port(
                lambda: estop.publisher_builder().create(), TOPICS["estop"], "publisher"
            )
        except SclError:
            self.close()
            raise
        graph._owned.append(self)
        self._seq = 0
        self._tick = NO_TICK
        self._estop_held = False

    @property
    def tick(self) -> int:
        """The newest robot tick this operator has seen (:data:`NO_TICK` before the first)."""
        if self._states is None:
            raise SclError(f"graph `{self._graph.prefix}`: this operator was closed")
        for s in self._states.drain():
            self._tick = s.tick
        return self._tick

    def publish(
        self,
        axes: Sequence[float] = (0.0, 0.0),
        gripper: float = 0.0,
        buttons: int = 0,
    ) -> JoystickInput:
        """Publishes one sample and wakes the mapper; returns what was sent.

        ``axes`` are the two axes (the mapper clamps ``|a|`` to 1), ``gripper`` the gripper
        rate in ``[-1, 1]`` (positive closes), ``buttons`` :class:`msg.buttons` bits.
        """
        if len(axes) != msg.ACTION_DIM:
            raise ValueError(f"axes must have {msg.ACTION_DIM} values, got {len(axes)}: {axes!r}")
        m = JoystickInput()
        m.tick = self.tick  # raises once closed
        m.t_ns = now_ns()
        m.seq = self._seq
        m.axes[0], m.axes[1] = float(axes[0]), float(axes[1])
        m.gripper = float(gripper)
        m.buttons = int(buttons)
        self._pub.send_copy(m)
        self._notifier.notify()
        self._seq += 1
        held = bool(buttons & msg.buttons.ESTOP)
        if held and not self._estop_held:
            self._graph._send_estop(self._estop, msg.ESTOP_ACTION_ESTOP)
        self._estop_held = held
        return m

    def close(self) -> None:
        """Releases the publisher: another operator may take over."""
        for port in ("_pub", "_notifier", "_estop"):
            p = getattr(self, port, None)
            if p is not None:
                p.delete()
                setattr(self, port, None)
        if self._states is not None:
            self._states.close()
            self._states = None
        if self in self._graph._owned:
            self._graph._owned.remove(self)
        if self._graph._operator is self:
            self._graph._operator = None


@dataclass
class NodeInfo:
    """One node of the graph as its newest heartbeat shows it."""

    role: str
    pid: int
    mapper_id: int
    phase: str
    tick: Optional[int]
    handled: int
    faults: int
    heartbeat_age_s: float
    alive: bool
    #: Safety: how many ticks each rule acted (only rules that did).
    rules: Dict[str, int] = field(default_factory=dict)
    #: Mapper: the map's mode plus one (0: a map without modes) and the switches made.
    mode: int = 0
    mode_switches: int = 0
    #: Safety: what holds the arm (``e-stop``, ``hold``, ``awaiting-neutral``).
    safety_state: List[str] = field(default_factory=list)


@dataclass
class GraphStatus:
    """The graph as its heartbeats show it (``scl status``)."""

    prefix: str
    nodes: List[NodeInfo]
    #: The mapper safety forwards (``None`` without a live safety).
    active_mapper: Optional[int]
    #: What holds the arm on safety's side.
    safety_state: List[str]
    #: Names of the graph's live iceoryx2 nodes (supervisor, observers, this process).
    iceoryx2_nodes: List[str]


@dataclass
class SwapResult:
    """The supervisor's answer to a swap that succeeded."""

    new_mapper: int
    old_mapper: int
    switch_tick: int
    elapsed_s: float
    #: Ticks the bridge missed between the request and the switch-over.
    missed_during: int
    #: How many of them the machine took (the bridge or a process held up: the heartbeat's
    #: ``held_up``); the graph's own misses are ``missed_during - held_up_during``.
    held_up_during: int
    message: str


class Graph:
    """Membership in the running graph ``prefix``.

    Raises :class:`GraphNotRunning` when no process of the graph is alive (after waiting up
    to ``wait_s`` seconds for one to start),
    :class:`VersionMismatch` when the installed ``iceoryx2`` or the graph's message layouts
    differ from this package's. Use it as a context manager, or call :meth:`close`: a
    process that leaves without closing leaves its node for the next ``scl up`` to clean.
    """

    def __init__(
        self, prefix: str = "scl", *, name: Optional[str] = None, wait_s: float = 0.0
    ) -> None:
        self.prefix = check_prefix(prefix)
        version = _iceoryx2_version()
        if not version.startswith(ICEORYX2_VERSION + "."):
            raise VersionMismatch(
                f"graph `{prefix}`: the installed iceoryx2 Python package is {version}, the "
                f"graph speaks iceoryx2 {ICEORYX2_VERSION}; install iceoryx2=={ICEORYX2_VERSION}.*"
            )
        self._config = iox2.config.default()
        self._config.global_cfg.prefix = iox2.FileName.new(self.file_prefix)
        self._node = None
        self._owned: List[object] = []
        self._services: Dict[object, object] = {}
        self._operator: Optional[Operator] = None
        self._status_sub: Optional[Subscription[NodeStatus]] = None
        deadline = time.monotonic() + wait_s
        while not self._alive_nodes() and time.monotonic() < deadline:
            time.sleep(0.05)  # a graph still starting (``wait_s``)
        if not self._alive_nodes():
            raise GraphNotRunning(
                f"no graph is running under the prefix `{prefix}` (no live process in "
                f"/dev/shm/{self.file_prefix}*); start one with `scl up --prefix {prefix}`"
            )
        node_name = name or f"python-{os.getpid()}"
        self._node = (
            iox2.NodeBuilder.new()
            .name(iox2.NodeName.new(node_name))
            .config(self._config)
            .signal_handling_mode(iox2.SignalHandlingMode.Disabled)
            .create(iox2.ServiceType.Ipc)
        )

    # -- plumbing ---------------------------------------------------------------------------

    @property
    def file_prefix(self) -> str:
        """The name prefix of every shared-memory file of the graph (``scl_<prefix>_``)."""
        return f"scl_{self.prefix}_"

    def service_name(self, topic: str) -> str:
        """The full service name of ``topic`` (``lab2/robot_state``)."""
        return f"{self.prefix}/{topic}"

    def _alive_nodes(self) -> List[str]:
        names: List[str] = []
        for state in iox2.Node.list(iox2.ServiceType.Ipc, self._config):
            if isinstance(state, iox2.NodeState.Alive):
                details = state._0.details
                names.append(details.name.as_str() if details is not None else "?")
        return names

    def _require_open(self) -> None:
        if self._node is None:
            raise SclError(f"graph `{self.prefix}`: this Graph was closed")

    def _pubsub(self, topic: TopicSettings):
        self._require_open()
        key = (topic.name, topic.message)
        if key not in self._services:
            name = self.service_name(topic.name)
            try:
                self._services[key] = (
                    self._node.service_builder(iox2.ServiceName.new(name))
                    .publish_subscribe(topic.message)
                    .history_size(topic.history)
                    .subscriber_max_buffer_size(max(topic.buffer, topic.history))
                    .enable_safe_overflow(True)
                    .max_publishers(topic.max_publishers)
                    .max_subscribers(topic.max_subscribers)
                    .open_or_create()
                )
            except iox2.PublishSubscribeOpenOrCreateError as e:
                raise self._open_error(name, topic.message, e) from e
        return self._services[key]

    def _event(self, topic: TopicSettings):
        self._require_open()
        key = topic.name + "/event"
        if key not in self._services:
            name = self.service_name(key)
            try:
                self._services[key] = (
                    self._node.service_builder(iox2.ServiceName.new(name))
                    .event()
                    .max_notifiers(topic.max_publishers)
                    .max_listeners(topic.max_subscribers)
                    .open_or_create()
                )
            except iox2.EventOpenOrCreateError as e:
                raise SclError(f"graph `{self.prefix}`: cannot open the event `{name}`: {e!r}") from e
        return self._services[key]

    def _open_error(self, service: str, ty: Type[Message], e: Exception) -> SclError:
        text = repr(e)
        if "Incompatible" in text or "TypeName" in text or "Type" in text:
            return VersionMismatch(
                f"graph `{self.prefix}`: the service `{service}` carries another `{ty.type_name()}` "
                f"than this package's ({ctypes.sizeof(ty)} bytes): the running `scl` and this "
                f"Python package come from different versions; install the package from the "
                f"checkout the graph was built from ({text})"
            )
        return SclError(f"graph `{self.prefix}`: cannot open `{service}`: {text}")

    def _port(self, make, topic: TopicSettings, port: str):
        try:
            return make()
        except Exception as e:  # iceoryx2 raises one exception class per port kind
            if port == "publisher":
                raise PortRefused(
                    f"graph `{self.prefix}`: cannot publish on `{self.service_name(topic.name)}` "
                    f"(it admits {topic.max_publishers} publisher(s)): {e!r}"
                ) from e
            raise SclError(
                f"graph `{self.prefix}`: cannot create a {port} on "
                f"`{self.service_name(topic.name)}`: {e!r}"
            ) from e

    def _send_estop(self, publisher, action: int) -> None:
        m = EstopCommand()
        m.t_ns = now_ns()
        m.action = action
        m.source_pid = os.getpid()
        publisher.send_copy(m)

    # -- subscriptions ----------------------------------------------------------------------

    def robot_states(self, wake: bool = True) -> Subscription[RobotState]:
        """The bridge's robot states, one per tick; ``wake`` attaches the tick's event so
        :meth:`Subscription.wait` / :meth:`Subscription.next` block until the next one."""
        return Subscription(self, TOPICS["robot_state"], wake)

    def safe_commands(self) -> Subscription[SafeCommand]:
        """The commands the arm executes (safety's output)."""
        return Subscription(self, TOPICS["safe_command"], False)

    def mapper_commands(self) -> Subscription[MapperCommand]:
        """Every mapper's commands (several during a live swap)."""
        return Subscription(self, TOPICS["mapper_command"], False)

    def heartbeats(self) -> Subscription[NodeStatus]:
        """Every node's heartbeat, once per tick it handled."""
        return Subscription(self, TOPICS["status"], False)

    def joystick_inputs(self, wake: bool = False) -> Subscription[JoystickInput]:
        """The operator's samples, whoever publishes them."""
        return Subscription(self, TOPICS["joystick"], wake)

    def tick_reports(self) -> Subscription[TickReport]:
        """The bridge's per-tick timing reports."""
        return Subscription(self, TOPICS["tick_report"], False)

    # -- the operator -----------------------------------------------------------------------

    def operator(self) -> Operator:
        """This process as the graph's operator (one per graph, see :class:`Operator`)."""
        if self._operator is None:
            self._operator = Operator(self)
        return self._operator

    def publish_joystick(
        self, axes: Sequence[float] = (0.0, 0.0), gripper: float = 0.0, buttons: int = 0
    ) -> JoystickInput:
        """Publishes one joystick sample as the graph's operator (:meth:`operator`)."""
        return self.operator().publish(axes, gripper, buttons)

    # -- status, e-stop, swaps --------------------------------------------------------------

    def status(self, listen_s: float = 0.3) -> GraphStatus:
        """The graph's nodes from their heartbeats over ``listen_s`` seconds, the active
        mapper and what holds the arm, as ``scl status`` reports them."""
        if self._status_sub is None:
            self._status_sub = self.heartbeats()
        newest: Dict[tuple, NodeStatus] = {}
        end = time.monotonic() + listen_s
        while True:
            for s in self._status_sub.drain():
                newest[(s.role, s.pid)] = s
            if time.monotonic() >= end:
                break
            time.sleep(0.01)
        now = now_ns()
        nodes: List[NodeInfo] = []
        active: Optional[int] = None
        holds: List[str] = []
        for s in sorted(newest.values(), key=lambda s: (s.role, s.mapper_id, s.pid)):
            age = max(now - s.t_ns, 0) / 1e9
            alive = age < ALIVE_S and s.phase != 3 and _pid_alive(s.pid)
            info = NodeInfo(
                role=msg.ROLES.get(s.role, "unknown"),
                pid=s.pid,
                mapper_id=s.mapper_id,
                phase=msg.PHASES.get(s.phase, "?"),
                tick=None if s.tick == NO_TICK else s.tick,
                handled=s.handled,
                faults=s.faults,
                heartbeat_age_s=age,
                alive=alive,
                rules={n: c for n, c in zip(msg.safe_flags.NAMES, s.rule_counts) if c},
                mode=s.mode,
                mode_switches=s.mode_switches,
                safety_state=msg.safety_state.names_of(s.safety_state),
            )
            if alive and info.role == "safety":
                active = s.mapper_id
                holds = info.safety_state
            nodes.append(info)
        return GraphStatus(self.prefix, nodes, active, holds, self._alive_nodes())

    def active_mapper(self, listen_s: float = 0.3) -> Optional[int]:
        """The id of the mapper whose commands reach the arm (from safety's heartbeat)."""
        return self.status(listen_s).active_mapper

    def estop(self, timeout_s: float = 2.0) -> int:
        """Latches the e-stop (safety commands zero until :meth:`reset`); returns the pid of
        the safety process that confirmed it. Raises :class:`NotConfirmed` otherwise."""
        return self._estop_action(msg.ESTOP_ACTION_ESTOP, timeout_s)

    def reset(self, timeout_s: float = 2.0) -> int:
        """Releases a latched e-stop; returns the confirming safety's pid."""
        return self._estop_action(msg.ESTOP_ACTION_RESET, timeout_s)

    def _estop_action(self, action: int, timeout_s: float) -> int:
        topic = TOPICS["estop"]
        service = self._pubsub(topic)
        status = self.heartbeats()
        publisher = self._port(lambda: service.publisher_builder().create(), topic, "publisher")
        try:
            sent = now_ns()
            self._send_estop(publisher, action)
            want = action == msg.ESTOP_ACTION_ESTOP
            end = time.monotonic() + timeout_s
            while time.monotonic() < end:
                for s in status.drain():
                    latched = bool(s.safety_state & msg.safety_state.ESTOP)
                    if s.role == 3 and s.t_ns > sent and latched == want:
                        return s.pid
                time.sleep(0.005)
        finally:
            # Kept until confirmed: a sample of a publisher that is gone is not delivered.
            publisher.delete()
            status.close()
        what = "e-stop" if action == msg.ESTOP_ACTION_ESTOP else "reset"
        raise NotConfirmed(
            f"graph `{self.prefix}`: no safety process confirmed the {what} within {timeout_s} s"
        )

    def swap(self, model: str, timeout_s: float = 30.0) -> SwapResult:
        """Swaps the active mapper for one serving ``model`` (a model file, ``bundled``,
        ``modeswitch[:...]`` or ``constant:qdot=...``), live, through the supervisor.

        Raises :class:`RequestFailed` with the supervisor's reason when it refuses (a model
        that does not load: the old mapper keeps running), or when no supervisor answers.
        """
        spec = os.path.abspath(model) if os.path.exists(model) else model
        name = self.service_name(SUPERVISOR_SERVICE)
        self._require_open()
        try:
            service = (
                self._node.service_builder(iox2.ServiceName.new(name))
                .request_response(ControlRequest, ControlResponse)
                .max_servers(1)
                .max_clients(8)
                .max_active_requests_per_client(1)
                .max_response_buffer_size(2)
                .open_or_create()
            )
        except iox2.RequestResponseOpenOrCreateError as e:
            raise self._open_error(name, ControlRequest, e) from e
        if service.dynamic_config.number_of_servers == 0:
            raise RequestFailed(
                f"graph `{self.prefix}`: no supervisor serves `{name}` (is `scl up --prefix "
                f"{self.prefix}` running?)"
            )
        req = ControlRequest()
        req.kind = msg.REQUEST_SWAP
        req.path = msg.Text.of(spec)
        client = service.client_builder().create()
        try:
            pending = client.send_copy(req)
            end = time.monotonic() + timeout_s
            while time.monotonic() < end:
                r = pending.receive()
                if r is not None:
                    resp = _copy(r.payload(), ControlResponse)
                    r.delete()
                    break
                time.sleep(0.005)
            else:
                raise RequestFailed(
                    f"graph `{self.prefix}`: the supervisor did not answer the swap to "
                    f"`{model}` within {timeout_s} s"
                )
            pending.delete()
        finally:
            client.delete()
        if not resp.ok:
            raise RequestFailed(
                f"graph `{self.prefix}`: swap to `{model}` refused: {resp.message.text()}"
            )
        return SwapResult(
            new_mapper=resp.new_mapper,
            old_mapper=resp.old_mapper,
            switch_tick=resp.switch_tick,
            elapsed_s=resp.elapsed_ns / 1e9,
            missed_during=resp.missed_during,
            held_up_during=resp.held_up_during,
            message=resp.message.text(),
        )

    # -- life cycle -------------------------------------------------------------------------

    def close(self) -> None:
        """Leaves the graph: closes every subscription and the operator, releases this
        process's iceoryx2 node and, if it was the graph's last process, the graph's domain
        (so nothing of it is left in ``/dev/shm``). Idempotent."""
        if self._node is None:
            return
        for owner in list(reversed(self._owned)):
            owner.close()
        self._owned.clear()
        self._operator = None
        self._status_sub = None
        self._services.clear()
        try:
            self._node.try_cleanup_dead_nodes()
        except Exception:  # cleaning up after others is best effort
            pass
        self._node = None
        # Objects of iceoryx2 caught in reference cycles (a frame kept by a traceback) would
        # keep the node alive until the next collection; leave now.
        gc.collect()
        self._release_domain_if_last()

    def _release_domain_if_last(self) -> None:
        """Removes the domain's management segment once no process of the graph is alive,
        as the Rust side's ``release_domain`` does (``scl up`` does it when it is the last to
        leave; an observer that outlives it does it here). The Python binding has no call for
        it, so the segment is found by its name: ``scl_<prefix>_<hash>_node.<version>.global_mgmt``.
        """
        try:
            if self._alive_nodes():
                return
            for name in os.listdir("/dev/shm"):
                if name.startswith(self.file_prefix) and name.endswith(".global_mgmt"):
                    os.unlink(os.path.join("/dev/shm", name))
        except OSError:  # another process released it first
            pass

    def __enter__(self) -> "Graph":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass

    def __repr__(self) -> str:
        return f"Graph({self.prefix!r})"


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
