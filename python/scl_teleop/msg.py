"""The graph's message types as ``ctypes`` structures.

Each class is field for field the ``#[repr(C)]`` Rust type of the same name in
``ipc-types/src/msg.rs`` and ``ipc-types/src/control.rs``, and ``type_name()`` returns the
iceoryx2 type name the Rust side opens its services with (``scl::RobotState``), so a Python
process and the Rust processes share one service. ``tests/test_layout.py`` compares every
class with what ``scl layout`` prints (size, alignment, every field's offset and type, the
type name) and fails when the two languages drift apart.

Bit constants (``buttons``, ``state_flags``, ``mapper_flags``, ``safe_flags``,
``safety_state``) and their names, in bit order, are here too.
"""

from __future__ import annotations

import ctypes
from typing import Dict, List, Tuple, Type

#: Capacity of every joint array (``MAX_JOINTS``); the Gen3 lite uses 6.
MAX_JOINTS = 8
#: Number of joystick axes the maps take (``ACTION_DIM``).
ACTION_DIM = 2
#: The tick value of "no tick" (``NO_TICK``): a sample taken before the first robot state.
NO_TICK = 2**64 - 1
#: Capacity of the control messages' text fields (``TEXT_CAP``, bytes).
TEXT_CAP = 512


class _Bits:
    """A set of bit constants with their names in bit order."""

    NAMES: Tuple[str, ...] = ()

    @classmethod
    def names_of(cls, bits: int) -> List[str]:
        """The names of the bits set in ``bits``, in bit order."""
        return [n for i, n in enumerate(cls.NAMES) if bits & (1 << i)]


class buttons(_Bits):  # noqa: N801 (named as in Rust)
    """Joystick button bits in :attr:`JoystickInput.buttons`."""

    DEADMAN = 1 << 0
    MODE = 1 << 1
    ESTOP = 1 << 2
    GRIPPER = 1 << 3
    NO_DEVICE = 1 << 4
    NAMES = ("deadman", "mode", "estop", "gripper", "no-device")


class state_flags(_Bits):  # noqa: N801
    """:attr:`RobotState.flags` bits."""

    STOPPING = 1 << 0
    MISSED = 1 << 1
    SHUTDOWN = 1 << 2
    AT_LIMIT = 1 << 3
    MOCK = 1 << 4
    SAFETY_STOP = 1 << 5
    NAMES = ("stopping", "missed", "shutdown", "at-limit", "mock", "safety-stop")


class mapper_flags(_Bits):  # noqa: N801
    """:attr:`MapperCommand.flags` bits."""

    NO_INPUT = 1 << 0
    INPUT_NON_FINITE = 1 << 1
    INPUT_CLAMPED = 1 << 2
    OUTPUT_NON_FINITE = 1 << 3
    STATE_INVALID = 1 << 4
    INPUT_STALE = 1 << 5
    IGNORES_INPUT = 1 << 6
    INPUT_NO_TICK = 1 << 7
    NAMES = (
        "no-input",
        "input-non-finite",
        "input-clamped",
        "output-non-finite",
        "state-invalid",
        "input-stale",
        "ignores-input",
        "input-no-tick",
    )


class safe_flags(_Bits):  # noqa: N801
    """:attr:`SafeCommand.flags` bits: which rule of the safety filter acted."""

    NON_FINITE = 1 << 0
    STALE_STATE = 1 << 1
    STALE_JOYSTICK = 1 << 2
    STALE_COMMAND = 1 << 3
    VELOCITY_SCALED = 1 << 4
    STOP = 1 << 5
    BAD_SHAPE = 1 << 6
    ACCEL_LIMITED = 1 << 7
    HOLD = 1 << 8
    POSITION_LIMITED = 1 << 9
    WORKSPACE_LIMITED = 1 << 10
    DEADMAN = 1 << 11
    ESTOP = 1 << 12
    AWAITING_NEUTRAL = 1 << 13
    CLEARANCE_LIMITED = 1 << 14
    SPEED_CAPPED = 1 << 15
    NAMES = (
        "non-finite",
        "stale-state",
        "stale-joystick",
        "stale-command",
        "velocity",
        "stop",
        "bad-shape",
        "acceleration",
        "hold",
        "position",
        "workspace",
        "deadman",
        "e-stop",
        "awaiting-neutral",
        "clearance",
        "tcp-speed",
    )


class safety_state(_Bits):  # noqa: N801
    """:attr:`NodeStatus.safety_state` bits (safety's heartbeat)."""

    ESTOP = 1 << 0
    HOLD = 1 << 1
    AWAITING_NEUTRAL = 1 << 2
    NAMES = ("e-stop", "hold", "awaiting-neutral")


#: Every bit set by its Rust module name.
BITS: Dict[str, Type[_Bits]] = {
    "buttons": buttons,
    "state_flags": state_flags,
    "mapper_flags": mapper_flags,
    "safe_flags": safe_flags,
    "safety_state": safety_state,
}

#: :attr:`NodeStatus.role` values.
ROLES = {1: "joystick", 2: "mapper", 3: "safety", 4: "bridge", 5: "recorder", 6: "gateway"}
#: :attr:`NodeStatus.phase` values.
PHASES = {1: "ready", 2: "running", 3: "stopping"}
#: :attr:`EstopCommand.action` values.
ESTOP_ACTION_ESTOP = 1
ESTOP_ACTION_RESET = 2
#: :attr:`ControlRequest.kind` of a swap.
REQUEST_SWAP = 1

_u8, _u16, _u32, _u64 = ctypes.c_uint8, ctypes.c_uint16, ctypes.c_uint32, ctypes.c_uint64
_f32, _f64 = ctypes.c_float, ctypes.c_double


class Message(ctypes.Structure):
    """Base of the message classes: the iceoryx2 type name and a readable ``repr``."""

    _type_name_ = ""

    @classmethod
    def type_name(cls) -> str:
        """The iceoryx2 type name (``scl::RobotState``), as the Rust type declares it."""
        return cls._type_name_

    def to_dict(self) -> Dict[str, object]:
        """The fields as plain Python values (arrays as lists, nested structs as dicts)."""
        out: Dict[str, object] = {}
        for name, _ty in self._fields_:
            v = getattr(self, name)
            if isinstance(v, Message):
                v = v.to_dict()
            elif isinstance(v, ctypes.Array):
                v = list(v)
            out[name] = v
        return out

    def __repr__(self) -> str:
        inner = ", ".join(f"{k}={v!r}" for k, v in self.to_dict().items())
        return f"{type(self).__name__}({inner})"


class JoystickInput(Message):
    """One sample of the operator's input device (``scl::JoystickInput``).

    ``tick`` is the newest robot tick the publisher had seen (:data:`NO_TICK` before the
    first): a sample two or more ticks behind the state is stale and stops the arm.
    """

    _type_name_ = "scl::JoystickInput"
    _fields_ = [
        ("tick", _u64),
        ("t_ns", _u64),
        ("seq", _u64),
        ("axes", _f32 * ACTION_DIM),
        ("gripper", _f32),
        ("buttons", _u32),
    ]


class RobotState(Message):
    """The arm's state at tick ``tick``, published by the bridge (``scl::RobotState``)."""

    _type_name_ = "scl::RobotState"
    _fields_ = [
        ("tick", _u64),
        ("t_ns", _u64),
        ("applied_tick", _u64),
        ("missed", _u64),
        ("n_joints", _u32),
        ("flags", _u32),
        ("q_rad", _f64 * MAX_JOINTS),
        ("qdot_rad_s", _f64 * MAX_JOINTS),
        ("gripper", _f64),
    ]

    def q(self) -> List[float]:
        """The valid joint angles (rad)."""
        return list(self.q_rad)[: min(self.n_joints, MAX_JOINTS)]

    def qdot(self) -> List[float]:
        """The valid joint velocities (rad/s)."""
        return list(self.qdot_rad_s)[: min(self.n_joints, MAX_JOINTS)]


class MapperCommand(Message):
    """A joint-velocity command for tick ``tick`` from one mapper (``scl::MapperCommand``)."""

    _type_name_ = "scl::MapperCommand"
    _fields_ = [
        ("tick", _u64),
        ("t_ns", _u64),
        ("state_t_ns", _u64),
        ("state_rx_ns", _u64),
        ("joystick_t_ns", _u64),
        ("joystick_rx_ns", _u64),
        ("joystick_seq", _u64),
        ("compute_ns", _u64),
        ("mapper_id", _u32),
        ("n_joints", _u32),
        ("flags", _u32),
        ("buttons", _u32),
        ("action", _f32 * ACTION_DIM),
        ("qdot_rad_s", _f64 * MAX_JOINTS),
        ("gripper_rate", _f64),
    ]


class SafeCommand(Message):
    """The command the arm executes at tick ``tick``: safety's output (``scl::SafeCommand``)."""

    _type_name_ = "scl::SafeCommand"
    _fields_ = [
        ("tick", _u64),
        ("t_ns", _u64),
        ("state_t_ns", _u64),
        ("state_rx_ns", _u64),
        ("joystick_t_ns", _u64),
        ("joystick_rx_ns", _u64),
        ("mapper_t_ns", _u64),
        ("mapper_rx_ns", _u64),
        ("mapper_compute_ns", _u64),
        ("compute_ns", _u64),
        ("mapper_id", _u32),
        ("n_joints", _u32),
        ("flags", _u32),
        ("control", _u32),
        ("qdot_rad_s", _f64 * MAX_JOINTS),
        ("gripper_rate", _f64),
        ("clearance_m", _f64),
        ("tcp_speed_m_s", _f64),
        ("closest_pair", _u16 * 2),
        ("reserved_tail", _u32),
    ]


class TickReport(Message):
    """The bridge's account of one tick: every timestamp (``scl::TickReport``)."""

    _type_name_ = "scl::TickReport"
    _fields_ = [
        ("tick", _u64),
        ("ideal_ns", _u64),
        ("lateness_ns", _u64),
        ("state_t_ns", _u64),
        ("state_rx_ns", _u64),
        ("joystick_t_ns", _u64),
        ("joystick_rx_ns", _u64),
        ("mapper_t_ns", _u64),
        ("mapper_rx_ns", _u64),
        ("safe_t_ns", _u64),
        ("safe_rx_ns", _u64),
        ("mapper_compute_ns", _u64),
        ("safety_compute_ns", _u64),
        ("missed", _u64),
        ("executed", _u32),
        ("reserved", _u32),
    ]


class NodeStatus(Message):
    """Heartbeat of one process, once per tick it handled (``scl::NodeStatus``)."""

    _type_name_ = "scl::NodeStatus"
    _fields_ = [
        ("t_ns", _u64),
        ("tick", _u64),
        ("handled", _u64),
        ("faults", _u64),
        ("latency_ns", _u64),
        ("lateness_ns", _u64),
        ("joint_travel_rad", _f64),
        ("pid", _u32),
        ("role", _u32),
        ("phase", _u32),
        ("mapper_id", _u32),
        ("safety_state", _u32),
        ("rule_counts", _u32 * 16),
        ("mode", _u32),
        ("mode_switches", _u32),
        ("held_up", _u32),
    ]


class SafetyControl(Message):
    """The supervisor's word to safety: active mapper, hold, e-stop (``scl::SafetyControl``)."""

    _type_name_ = "scl::SafetyControl"
    _fields_ = [
        ("seq", _u64),
        ("t_ns", _u64),
        ("from_tick", _u64),
        ("active_mapper", _u32),
        ("hold", _u32),
        ("estop_seq", _u32),
        ("estop", _u32),
    ]


class EstopCommand(Message):
    """Latches (action 1) or releases (action 2) safety's e-stop (``scl::EstopCommand``)."""

    _type_name_ = "scl::EstopCommand"
    _fields_ = [("t_ns", _u64), ("action", _u32), ("source_pid", _u32)]


class Text(Message):
    """A short UTF-8 text in a fixed array (``scl::Text``)."""

    _type_name_ = "scl::Text"
    _fields_ = [("len", _u32), ("bytes", _u8 * TEXT_CAP)]

    @classmethod
    def of(cls, s: str) -> "Text":
        """``s`` as a Text; raises ``ValueError`` if its UTF-8 form does not fit."""
        data = s.encode("utf-8")
        if len(data) > TEXT_CAP:
            raise ValueError(f"text of {len(data)} bytes is longer than {TEXT_CAP}: {s!r}")
        t = cls()
        t.len = len(data)
        ctypes.memmove(t.bytes, data, len(data))
        return t

    def text(self) -> str:
        """The text (invalid UTF-8, which only a corrupt message has, is replaced)."""
        n = min(self.len, TEXT_CAP)
        return bytes(self.bytes[:n]).decode("utf-8", errors="replace")


class ControlRequest(Message):
    """A request to the graph's supervisor (``scl::ControlRequest``)."""

    _type_name_ = "scl::ControlRequest"
    _fields_ = [("kind", _u32), ("reserved", _u32), ("path", Text)]


class ControlResponse(Message):
    """The supervisor's answer (``scl::ControlResponse``)."""

    _type_name_ = "scl::ControlResponse"
    _fields_ = [
        ("ok", _u32),
        ("new_mapper", _u32),
        ("old_mapper", _u32),
        ("held_up_during", _u32),
        ("switch_tick", _u64),
        ("elapsed_ns", _u64),
        ("missed_during", _u64),
        ("message", Text),
    ]


#: Every structure, by its Rust name.
TYPES: Dict[str, Type[Message]] = {
    t.__name__: t
    for t in (
        JoystickInput,
        RobotState,
        MapperCommand,
        SafeCommand,
        TickReport,
        NodeStatus,
        SafetyControl,
        EstopCommand,
        Text,
        ControlRequest,
        ControlResponse,
    )
}

_PRIMITIVES = {
    ctypes.c_uint8: "u8",
    ctypes.c_uint16: "u16",
    ctypes.c_uint32: "u32",
    ctypes.c_uint64: "u64",
    ctypes.c_int32: "i32",
    ctypes.c_int64: "i64",
    ctypes.c_float: "f32",
    ctypes.c_double: "f64",
}


def describe_type(ty: type) -> str:
    """A ctypes field type spelled as the Rust layout spells it: ``u64``, ``[f64; 8]``,
    ``Text``."""
    if ty in _PRIMITIVES:
        return _PRIMITIVES[ty]
    if issubclass(ty, ctypes.Array):
        return f"[{describe_type(ty._type_)}; {ty._length_}]"
    if issubclass(ty, Message):
        return ty.__name__
    raise TypeError(f"{ty!r} has no Rust counterpart")


def layout_of(cls: Type[Message]) -> Dict[str, object]:
    """The layout of ``cls`` in the form ``scl layout`` prints for each type."""
    fields = []
    for name, ty in cls._fields_:
        f = getattr(cls, name)
        fields.append(
            {"name": name, "offset": f.offset, "size": f.size, "type": describe_type(ty)}
        )
    return {
        "name": cls.__name__,
        "type_name": cls.type_name(),
        "size": ctypes.sizeof(cls),
        "align": ctypes.alignment(cls),
        "fields": fields,
    }
