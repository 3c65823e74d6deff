"""Python on a live scl-teleop graph.

``Graph(prefix)`` joins the graph a ``scl up --prefix PREFIX`` runs (iceoryx2 shared memory,
the official ``iceoryx2`` Python package): subscribe to robot states, executed and mapper
commands and heartbeats, read the active mapper and the graph's status, publish the
operator's joystick input (with ``scl up --joystick external``), latch and release the
e-stop, request a live mapper swap. The message classes in :mod:`scl_teleop.msg` are the
Rust ``#[repr(C)]`` types field for field.

>>> from scl_teleop import Graph
>>> with Graph("lab2") as g:                                        # doctest: +SKIP
...     states = g.robot_states()
...     s = states.next(timeout_s=1.0)
...     print(s.tick, s.q())
"""

from .graph import (
    Graph,
    GraphNotRunning,
    GraphStatus,
    NodeInfo,
    NotConfirmed,
    Operator,
    PortRefused,
    RequestFailed,
    SclError,
    Subscription,
    SwapResult,
    VersionMismatch,
    now_ns,
)
from .msg import (
    NO_TICK,
    ControlRequest,
    ControlResponse,
    EstopCommand,
    JoystickInput,
    MapperCommand,
    NodeStatus,
    RobotState,
    SafeCommand,
    SafetyControl,
    TickReport,
    buttons,
    mapper_flags,
    safe_flags,
    safety_state,
    state_flags,
)

__version__ = "0.1.0"

__all__ = [
    "Graph",
    "GraphNotRunning",
    "GraphStatus",
    "NodeInfo",
    "NotConfirmed",
    "Operator",
    "PortRefused",
    "RequestFailed",
    "SclError",
    "Subscription",
    "SwapResult",
    "VersionMismatch",
    "now_ns",
    "NO_TICK",
    "ControlRequest",
    "ControlResponse",
    "EstopCommand",
    "JoystickInput",
    "MapperCommand",
    "NodeStatus",
    "RobotState",
    "SafeCommand",
    "SafetyControl",
    "TickReport",
    "buttons",
    "mapper_flags",
    "safe_flags",
    "safety_state",
    "state_flags",
]
