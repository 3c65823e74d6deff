"""The package against a real graph: ``scl up --joystick external`` on the mock arm, with the
test's Python process as the operator.

Timing is checked in ticks carried by the messages (the bridge's clock), never in wall time.
"""

from __future__ import annotations

import ctypes
import math
from typing import Dict, List, Optional

import pytest

from scl_teleop import (
    Graph,
    GraphNotRunning,
    MapperCommand,
    PortRefused,
    RequestFailed,
    RobotState,
    SafeCommand,
    VersionMismatch,
    buttons,
    mapper_flags,
    safe_flags,
)
from scl_teleop.graph import TOPICS, TopicSettings, check_prefix

from .conftest import RunningGraph, finish, start_graph

#: A stick deflection the tests drive with.
PUSH = (0.6, 0.3)


class Driver:
    """The test's operator: answers robot ticks as a joystick does, from one subscription kept
    for the whole test (opening ports between phases takes time in which no sample goes
    out).

    Like a person, it lets go of the stick for a tick when safety says it waits for neutral
    input: restart prevention after a fault, which a sample of this Python process that came
    more than a period late (a scheduling or garbage-collection pause) is. Without that, one
    late sample in a push left the arm stopped for the rest of the test; the counts the tests
    check are taken from the messages, so such a pause costs ticks, never the result."""

    def __init__(self, g: Graph) -> None:
        self.op = g.operator()
        self.states = g.robot_states()
        self.safe = g.safe_commands()
        #: Safety's commands seen, by tick.
        self.safe_by_tick: Dict[int, SafeCommand] = {}
        #: Ticks answered with neutral input because safety waited for it.
        self.rearms = 0
        #: The last sample sent.
        self.last_sent = None
        #: Every robot state answered, by tick.
        self.states_by_tick: Dict[int, RobotState] = {}

    def _newest_safe(self) -> Optional[SafeCommand]:
        newest = None
        for c in self.safe.drain():
            self.safe_by_tick[c.tick] = c
            newest = c
        return newest

    def drive(self, axes, ticks: int, btn: int = 0, until=None, max_ticks: int = 800) -> List[RobotState]:
        """Answers robot ticks with ``axes`` until ``ticks`` of them were answered so and, if
        given, ``until(self)`` holds, at most ``max_ticks`` ticks; returns the states answered
        with ``axes``."""
        seen: List[RobotState] = []
        neutral = all(a == 0.0 for a in axes)
        for _ in range(max_ticks):
            done = until is None or until(self)  # every tick: `until` may collect messages
            if len(seen) >= ticks and done:
                break
            s = self.states.next_latest(2.0)
            assert s is not None, "the bridge stopped publishing"
            self.states_by_tick[s.tick] = s
            newest = self._newest_safe()
            if not neutral and newest is not None and newest.flags & safe_flags.AWAITING_NEUTRAL:
                self.last_sent = self.op.publish((0.0, 0.0))
                self.rearms += 1
                continue
            self.last_sent = self.op.publish(axes, buttons=btn)
            seen.append(s)
        assert len(seen) >= ticks and (until is None or until(self)), (
            f"{len(seen)} of {ticks} ticks answered in {max_ticks}, {self.rearms} re-arms"
        )
        return seen

    def free_since(self, tick: int) -> int:
        """Commands of ticks from ``tick`` on that safety let through moving and unbent (no
        stop, no acceleration limit)."""
        self._newest_safe()
        return sum(
            1
            for c in self.safe_by_tick.values()
            if c.tick >= tick
            and c.flags & (safe_flags.STOP | safe_flags.ACCEL_LIMITED) == 0
            and max(abs(v) for v in c.qdot_rad_s) > 0.01
        )

    def moving_at_the_end(self, n: int) -> bool:
        """Whether safety's ``n`` newest commands all move the arm."""
        self._newest_safe()
        last = sorted(self.safe_by_tick)[-n:]
        return len(last) == n and all(
            self.safe_by_tick[t].flags & safe_flags.STOP == 0
            and max(abs(v) for v in self.safe_by_tick[t].qdot_rad_s) > 0.01
            for t in last
        )


def same_axes(a, b) -> bool:
    """Whether the axes ``a`` (f32, as carried) are ``b``."""
    return all(abs(x - y) < 1e-6 for x, y in zip(a, b))


def test_reads_every_state_at_the_bridges_rate(graph: RunningGraph) -> None:
    """Subscribe and read 40 states, a second of the bridge's 40 Hz clock, losing none."""
    g = graph.join()
    states = g.robot_states()
    got = []
    while len(got) < 40:
        s = states.next(5.0)
        assert s is not None, f"no robot state within 5 s after {len(got)}"
        got.append(s)
    ticks = [s.tick for s in got]
    assert ticks == list(range(ticks[0], ticks[0] + 40)), ticks
    # One period apart on the graph's clock (a held-up bridge skips ticks; none was skipped).
    assert all(b.t_ns > a.t_ns for a, b in zip(got, got[1:]))
    assert got[-1].n_joints == 6 and len(got[-1].q()) == 6
    assert all(math.isfinite(v) for v in got[-1].q())


def test_publishing_moves_the_arm_as_the_served_map_says(graph: RunningGraph) -> None:
    """The operator's input reaches the map and the arm executes what the map and safety
    made of it: the mapper's action is the published axes, safety's command is a
    non-negative multiple of the mapper's (unless the acceleration limit bent it), and the
    arm's next state moves with safety's command."""
    g = graph.join()
    mapper = g.mapper_commands()
    d = Driver(g)
    d.drive((0.0, 0.0), 8)  # restart prevention: the stick passes through neutral first
    m_pushed: Dict[int, MapperCommand] = {}

    def pushed() -> List[MapperCommand]:
        """The mapper's commands that carried the push (collected as they come: cheap, it
        runs between the ticks the driver answers)."""
        for c in mapper.drain():
            if c.flags & mapper_flags.NO_INPUT == 0 and same_axes(c.action, PUSH):
                m_pushed[c.tick] = c
        return list(m_pushed.values())

    def moved_freely() -> List[tuple]:
        """(mapper command, safety's, the next state) of the pushed ticks that safety let
        through unbent and the bridge executed (its miss count, carried in the states,
        unchanged: a tick the machine held up is counted there, not checked here)."""
        d.free_since(0)  # collects safety's newest commands
        out = []
        for mc in pushed():
            sc = d.safe_by_tick.get(mc.tick)
            now, nxt = d.states_by_tick.get(mc.tick), d.states_by_tick.get(mc.tick + 1)
            if sc is None or now is None or nxt is None or nxt.missed != now.missed:
                continue
            if sc.flags & (safe_flags.STOP | safe_flags.ACCEL_LIMITED) == 0:
                out.append((mc, sc, nxt))
        return out

    states = d.drive(PUSH, 40, until=lambda d: len(moved_freely()) >= 10)
    assert len(pushed()) >= 30, f"only {len(pushed())} mapper commands carried the published axes"
    checked = 0
    for mc, sc, nxt in moved_freely():
        m = list(mc.qdot_rad_s)[:6]
        s = list(sc.qdot_rad_s)[:6]
        scale = sum(a * b for a, b in zip(m, s)) / sum(a * a for a in m)
        assert 0.0 < scale <= 1.0 + 1e-9, (mc.tick, m, s)
        assert s == pytest.approx([scale * v for v in m], abs=1e-9), (mc.tick, m, s)
        # The arm executed tick k's command during the period that ended with state k+1.
        assert nxt.applied_tick == mc.tick
        assert list(nxt.qdot_rad_s)[:6] == pytest.approx(s, abs=1e-6)
        checked += 1
    assert checked >= 10, f"only {checked} ticks moved freely under the map"
    travel = [abs(a - b) for a, b in zip(states[-1].q(), states[0].q())]
    assert max(travel) > 0.01, travel
    # The opposite push drives the other way (the maps are linear in the action).
    first = pushed()[-1]
    d.drive((0.0, 0.0), 4)
    mapper.drain()
    back: List[MapperCommand] = []

    def pulled(d: Driver) -> bool:
        back.extend(c for c in mapper.drain() if same_axes(c.action, (-PUSH[0], -PUSH[1])))
        return bool(back)

    d.drive((-PUSH[0], -PUSH[1]), 4, until=pulled)
    dot = sum(a * b for a, b in zip(first.qdot_rad_s, back[-1].qdot_rad_s))
    assert dot < 0, (list(first.qdot_rad_s), list(back[-1].qdot_rad_s))


def test_input_that_stops_stops_the_arm_within_two_ticks(graph: RunningGraph) -> None:
    """When the operator stops publishing, safety commands a stop at the second tick after
    the last sample's at the latest, and keeps the arm stopped."""
    g = graph.join()
    d = Driver(g)
    d.drive((0.0, 0.0), 8)
    d.drive(PUSH, 30, until=lambda d: d.moving_at_the_end(5))
    last = d.last_sent.tick  # the tick the last sample answered
    states = g.robot_states()
    # Until the arm is at rest and 10 ticks more: how long the stop takes depends on the speed
    # the push reached, within the acceleration limits (at most about 2 s here).
    at_rest = None
    while True:
        s = states.next(2.0)
        assert s is not None
        assert s.tick < last + 400, "the arm was not at rest 10 s after the input stopped"
        if at_rest is None and s.tick > last + 2 and max(abs(v) for v in s.qdot_rad_s) == 0.0:
            at_rest = s.tick
        if at_rest is not None and s.tick >= at_rest + 10:
            break
    d.free_since(0)  # collects safety's newest commands
    after = sorted((c for c in d.safe_by_tick.values() if c.tick > last), key=lambda c: c.tick)
    assert after and after[0].tick <= last + 2
    stopped = [c for c in after if c.tick >= last + 2]
    assert stopped, "no command after the second tick"
    for c in stopped:
        assert c.flags & safe_flags.STOP, (c.tick, safe_flags.names_of(c.flags))
        assert c.flags & safe_flags.STALE_JOYSTICK, (c.tick, safe_flags.names_of(c.flags))
    # The stop decelerates (no joint speeds up), then holds zero.
    for a, b in zip(stopped, stopped[1:]):
        for va, vb in zip(a.qdot_rad_s, b.qdot_rad_s):
            assert abs(vb) <= abs(va) + 1e-12, (b.tick, list(a.qdot_rad_s), list(b.qdot_rad_s))
    assert max(abs(v) for v in stopped[-1].qdot_rad_s) == 0.0


def test_estop_from_python(graph: RunningGraph) -> None:
    """``Graph.estop`` latches safety's e-stop (zero at once, whatever the stick) until
    ``Graph.reset``; the joystick sample's e-stop button latches it too."""
    g = graph.join()
    safe = g.safe_commands()
    d = Driver(g)
    d.drive((0.0, 0.0), 8)
    d.drive(PUSH, 12)
    pid = g.estop()
    assert pid > 0
    safe.drain()
    d.drive(PUSH, 6)
    latched = safe.drain()
    assert latched
    for c in latched:
        assert c.flags & safe_flags.ESTOP and c.flags & safe_flags.STOP
        assert all(v == 0.0 for v in c.qdot_rad_s), list(c.qdot_rad_s)
    assert "e-stop" in g.status().safety_state
    g.reset()
    assert "e-stop" not in g.status().safety_state
    # Moving again after the reset (through neutral: restart prevention).
    d.drive((0.0, 0.0), 6)
    d.drive(PUSH, 10, until=lambda d: d.moving_at_the_end(1))
    # The e-stop button of the operator's own samples.
    d.drive(PUSH, 2, btn=buttons.ESTOP)
    d.drive((0.0, 0.0), 4)
    st = g.status()
    assert "e-stop" in st.safety_state, st
    safe.drain()
    d.drive(PUSH, 4)
    assert all(c.flags & safe_flags.ESTOP for c in safe.drain())
    g.reset()


def test_one_operator_at_a_time(graph: RunningGraph) -> None:
    g = graph.join()
    h = graph.join()
    op = g.operator()
    with pytest.raises(PortRefused, match="already has its publisher"):
        h.operator()
    op.close()
    assert h.operator().publish((0.0, 0.0)).seq == 0


def test_status_active_mapper_and_swap(graph: RunningGraph) -> None:
    g = graph.join()
    st = g.status()
    roles = sorted(n.role for n in st.nodes if n.alive)
    assert roles == ["bridge", "mapper", "safety"], st  # no joystick process: external source
    assert g.active_mapper() == 1
    r = g.swap("modeswitch")
    assert (r.old_mapper, r.new_mapper) == (1, 2)
    # The switch-over itself misses no tick: every miss meanwhile is one the machine took
    # (the bridge or a process held up), which the reply counts apart.
    assert r.missed_during - r.held_up_during == 0, r
    assert g.active_mapper() == 2
    modes = [n.mode for n in g.status().nodes if n.role == "mapper" and n.alive]
    assert modes == [1], modes  # mode switching serves x-y first
    with pytest.raises(RequestFailed, match="nonexistent.safetensors"):
        g.swap("/nonexistent.safetensors")
    assert g.active_mapper() == 2


def test_errors_name_the_graph_and_what_is_missing(graph: RunningGraph) -> None:
    with pytest.raises(GraphNotRunning, match="no graph is running under the prefix `nothing-here`"):
        Graph("nothing-here")
    with pytest.raises(ValueError, match="character"):
        check_prefix("a/b")
    with pytest.raises(ValueError, match="longer than 32"):
        Graph("x" * 33)

    class OtherRobotState(ctypes.Structure):
        """A robot state of another version: one more field."""

        _fields_ = RobotState._fields_ + [("torque", ctypes.c_double * 8)]

        @staticmethod
        def type_name() -> str:
            return "scl::RobotState"

    g = graph.join()
    other = TopicSettings("robot_state", OtherRobotState, 1, 64, 1, 16)  # type: ignore[arg-type]
    with pytest.raises(VersionMismatch, match=f"graph `{graph.prefix}`.*scl::RobotState"):
        g._pubsub(other)
    assert TOPICS["robot_state"].message is RobotState


def test_a_joystick_process_keeps_the_operator_out(tmp_path) -> None:
    """With a joystick process (the scripted source) the topic's one publisher is taken."""
    running = start_graph(tmp_path, "j", joystick=None)
    try:
        g = running.join()
        with pytest.raises(PortRefused, match="scl up --joystick external"):
            g.operator()
        assert any(n.role == "joystick" and n.alive for n in g.status().nodes)
        assert isinstance(g.mapper_commands().next(2.0), MapperCommand)
    finally:
        finish(running)
