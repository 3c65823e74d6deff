#!/usr/bin/env python3
"""An agent as the operator: drives the live arm's tool to a goal position through whatever
map the graph serves, greedily over sampled actions, and prints the final error.

Start a graph whose operator is outside it, then run the agent:

    scl up --prefix lab --joystick external &            # the bundled model
    python python/examples/reach.py --prefix lab

The agent knows nothing of the map: every tick it reads the robot state, estimates the map's
local effect ``qdot = H a`` from the mapper's recent commands (least squares over the last
ticks' actions and joint velocities), turns it into the tool's motion with the arm's forward
kinematics (read from the URDF), and sends the best of the sampled actions: the one whose
predicted next tool position is nearest the goal. When safety waits for the stick to pass
through neutral (after a fault stop: restart prevention), it lets go for a tick. A map with modes (``--model modeswitch``)
gets a press of the mode button when the current mode serves the goal poorly (its best
action's progress is under 30 % of its longest move, for 20 ticks).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import List, Optional, Sequence, Tuple

import numpy as np

from scl_teleop import Graph, buttons, mapper_flags, safe_flags

REPO = Path(__file__).resolve().parents[2]
DT = 0.025  # the graph's period (40 Hz)
APPROACH_M = 0.10  # the default goal's height above the demonstrations' pick


class Chain:
    """Forward kinematics of a URDF chain from ``base`` to ``tip`` (revolute and fixed
    joints), enough to place the tool."""

    def __init__(self, urdf: Path, base: str = "base_link", tip: str = "tool_frame") -> None:
        root = ET.parse(urdf).getroot()
        by_child = {j.find("child").get("link"): j for j in root.findall("joint")}
        joints = []
        link = tip
        while link != base:
            j = by_child.get(link)
            if j is None:
                raise ValueError(f"{urdf}: no joint leads to link `{link}` from `{base}`")
            joints.append(j)
            link = j.find("parent").get("link")
        self.steps = []
        for j in reversed(joints):
            o = j.find("origin")
            xyz = [float(v) for v in (o.get("xyz", "0 0 0") if o is not None else "0 0 0").split()]
            rpy = [float(v) for v in (o.get("rpy", "0 0 0") if o is not None else "0 0 0").split()]
            a = j.find("axis")
            axis = [float(v) for v in (a.get("xyz") if a is not None else "0 0 1").split()]
            self.steps.append((_transform(xyz, rpy), j.get("type") != "fixed", np.array(axis)))
        self.n = sum(1 for _, moving, _ in self.steps if moving)

    def position(self, q: Sequence[float]) -> np.ndarray:
        """The tip's position in the base frame (m)."""
        return self.position_and_jacobian(q)[0]

    def position_and_jacobian(self, q: Sequence[float]) -> Tuple[np.ndarray, np.ndarray]:
        """The tip's position (m) and its Jacobian (3 x n) in one pass down the chain: a
        revolute joint's column is its axis crossed with the lever from the joint to the tip.
        (In one pass, not by differences: the agent answers every tick, and on a loaded
        machine a slow answer is a stale-joystick stop.)"""
        t = np.eye(4)
        axes, origins = [], []
        i = 0
        for origin, moving, axis in self.steps:
            t = t @ origin
            if moving:
                axes.append(t[:3, :3] @ axis)
                origins.append(t[:3, 3].copy())
                r = np.eye(4)
                r[:3, :3] = _rotation(axis, q[i])
                t = t @ r
                i += 1
        tip = t[:3, 3]
        jac = np.stack([np.cross(a, tip - o) for a, o in zip(axes, origins)], axis=1)
        return tip, jac


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    x, y, z = axis / np.linalg.norm(axis)
    c, s = math.cos(angle), math.sin(angle)
    k = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
    return np.eye(3) + s * k + (1 - c) * (k @ k)


def _transform(xyz: List[float], rpy: List[float]) -> np.ndarray:
    r, p, y = rpy
    rot = _rotation(np.array([0, 0, 1.0]), y) @ _rotation(np.array([0, 1.0, 0]), p) @ _rotation(
        np.array([1.0, 0, 0]), r
    )
    t = np.eye(4)
    t[:3, :3] = rot
    t[:3, 3] = xyz
    return t


def default_goal(chain: Chain) -> np.ndarray:
    """Above the pick of the pick-and-place demonstrations (the bundled model's data): the
    tool position where ``data/pick-and-place/val/val_00.csv`` starts closing the gripper,
    raised by :data:`APPROACH_M` (where a grasp starts, clear of the table's slow-down zone)."""
    rows = (REPO / "data/pick-and-place/val/val_00.csv").read_text().strip().splitlines()
    header = rows[0].split(",")
    for row in rows[1:]:
        r = dict(zip(header, row.split(",")))
        if float(r["c"]) > 0.05:
            pick = chain.position([float(r[f"q{i}"]) for i in range(chain.n)])
            return pick + np.array([0.0, 0.0, APPROACH_M])
    raise ValueError("val_00.csv never closes the gripper")


class MapEstimate:
    """The served map's local effect ``qdot ~= H a``, from the mapper's recent commands."""

    def __init__(self, n: int, window: int = 8) -> None:
        self.n = n
        self.window = window
        self.pairs: List[Tuple[np.ndarray, np.ndarray]] = []

    def add(self, action: Sequence[float], qdot: Sequence[float]) -> None:
        a = np.asarray(action, dtype=float)
        if np.linalg.norm(a) < 0.05:
            return
        self.pairs = (self.pairs + [(a, np.asarray(qdot[: self.n], dtype=float))])[-self.window :]

    def reset(self) -> None:
        self.pairs = []

    def h(self) -> Optional[np.ndarray]:
        """``H`` (n x 2), or ``None`` until two independent actions were seen."""
        if len(self.pairs) < 2:
            return None
        a = np.stack([p[0] for p in self.pairs])
        if np.linalg.matrix_rank(a, tol=0.1) < 2:
            return None
        qd = np.stack([p[1] for p in self.pairs])
        sol, *_ = np.linalg.lstsq(a, qd, rcond=None)
        return sol.T


def sample_actions(rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` actions uniform on the unit disk, and zero."""
    r = np.sqrt(rng.uniform(0, 1, n))
    phi = rng.uniform(0, 2 * math.pi, n)
    return np.vstack([np.zeros(2), np.stack([r * np.cos(phi), r * np.sin(phi)], axis=1)])


def run(args: argparse.Namespace) -> dict:
    chain = Chain(Path(args.urdf))
    goal = np.array([float(v) for v in args.goal.split(",")]) if args.goal else default_goal(chain)
    rng = np.random.default_rng(args.seed)
    with Graph(args.prefix, wait_s=10.0) as g:
        states = g.robot_states()
        commands = g.mapper_commands()
        beats = g.heartbeats()
        executed = g.safe_commands()
        op = g.operator()
        est = MapEstimate(chain.n)
        has_modes = False
        active = None
        for _ in range(8):  # the stick at rest first: restart prevention arms the arm
            if states.next_latest(2.0) is None:
                raise SystemExit(f"graph `{args.prefix}`: no robot state")
            op.publish((0.0, 0.0))
        t0 = time.monotonic()
        ticks = 0
        switches = 0
        stalled = 0
        # Probing actions for learning the map's effect anew: both axes, both signs, so a
        # probe leaves the tool about where it was.
        probe = [(0.6, 0.0), (0.0, 0.6), (-0.6, 0.0), (0.0, -0.6)]
        error = best_error = float("inf")
        best_tick = 0
        # Ticks the agent drove the arm (not stopped by safety, waiting for neutral): the
        # patience counts only these, so a loaded machine's stale-input stops do not end
        # the run early.
        driving = best_driving = 0
        settled_from = 0
        idle = 0
        neutral_passes = 0
        start_error = start_m = None
        while True:
            s = states.next_latest(2.0)
            if s is None:
                raise SystemExit(f"graph `{args.prefix}`: the bridge stopped publishing")
            ticks += 1
            for b in beats.drain():
                if b.role == 3:  # safety forwards this mapper
                    active = b.mapper_id
                elif b.role == 2 and b.mapper_id == active:
                    has_modes = b.mode > 0
            for c in commands.drain():
                usable = mapper_flags.NO_INPUT | mapper_flags.INPUT_STALE | mapper_flags.STATE_INVALID
                fresh = c.tick > settled_from
                if (active is None or c.mapper_id == active) and not c.flags & usable and fresh:
                    est.add(c.action, c.qdot_rad_s)
            q = np.array(s.q())
            p, jac = chain.position_and_jacobian(q)
            error = float(np.linalg.norm(goal - p))
            if start_error is None:
                start_error, start_m = error, p
            if error < best_error - 0.001:
                best_error, best_tick, best_driving = error, ticks, driving
            stuck = driving - best_driving > args.patience / DT
            if error < args.tolerance or stuck or time.monotonic() - t0 > args.timeout:
                break
            if args.verbose and ticks % 40 == 0:
                print(f"reach: {ticks / 40:4.0f} s  error {error * 1000:6.1f} mm  "
                      f"tool {np.round(p, 3)}", file=sys.stderr)
            waiting = [c for c in executed.drain() if c.flags & safe_flags.AWAITING_NEUTRAL]
            if waiting:
                # Safety stopped the arm for a fault (a missed tick, stale input) and waits
                # for the stick to pass through neutral, as a person would let go of it.
                op.publish((0.0, 0.0))
                neutral_passes += 1
                continue
            driving += 1
            h = est.h()
            if h is None:
                op.publish(probe[ticks % 4])
                continue
            b_mat = jac @ h  # tool velocity per unit action (3 x 2)
            cands = sample_actions(rng, args.samples)
            predicted = p + DT * args.lookahead * (cands @ b_mat.T)
            dist = np.linalg.norm(predicted - goal, axis=1)
            best = cands[int(np.argmin(dist))]
            gain = error - float(dist.min())
            # How well this mode serves the goal: the best progress against the longest move
            # any action makes (1: straight at the goal; near 0: the goal is off this mode's
            # span).
            reach_m = float(np.linalg.norm(predicted - p, axis=1).max())
            efficiency = gain / min(reach_m, error) if reach_m > 1e-3 else 0.0
            stalled = stalled + 1 if efficiency < args.switch_below else 0
            if has_modes and stalled > args.switch_after:
                # This mode serves the goal poorly: press the mode button (one tick) and learn
                # the next mode anew, from commands made after the map has settled into it.
                op.publish((0.0, 0.0), buttons=buttons.MODE)
                est.reset()
                settled_from = s.tick + 4
                switches += 1
                stalled = 0
                continue
            if np.linalg.norm(best) < 0.05 and not has_modes:
                # Standing still cannot teach the estimate anything: if the map seems to
                # offer nothing, look again (probe both axes, learn anew). (A map with modes
                # offers nothing in a mode that cannot serve the goal: the mode button above
                # answers that.)
                idle += 1
                if idle > 3:
                    est.reset()
                    idle = 0
                    op.publish(probe[ticks % 4])
                    continue
            else:
                idle = 0
            # Keep both action directions in the estimate: a small alternating dither.
            dither = 0.15 * (1 if ticks % 2 else -1)
            a = best + dither * np.array([-best[1], best[0]])
            n = np.linalg.norm(a)
            op.publish(tuple(a / n) if n > 1 else tuple(a))
        for _ in range(4):
            states.next_latest(1.0)
            op.publish((0.0, 0.0))
        return {
            "prefix": args.prefix,
            "goal_m": [round(float(v), 4) for v in goal],
            "start_m": [round(float(v), 4) for v in (start_m if start_m is not None else goal)],
            "start_error_m": round(float(start_error or 0.0), 4),
            "final_error_m": round(error, 4),
            "reached": error < args.tolerance,
            "time_s": round(time.monotonic() - t0, 2),
            # Ticks until the error was last improved by 1 mm: the time the agent needed.
            "converged_s": round(best_tick * DT, 2),
            "ticks": ticks,
            "mode_switches": switches,
            "neutral_passes": neutral_passes,
        }


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--prefix", default="scl", help="the graph's prefix (scl up --prefix)")
    ap.add_argument("--goal", help="goal tool position x,y,z in the base frame (m); default: "
                    "10 cm above the pick of the pick-and-place demonstrations")
    ap.add_argument("--tolerance", type=float, default=0.02, help="reached within this (m)")
    ap.add_argument("--timeout", type=float, default=60.0, help="give up after this (s)")
    ap.add_argument("--patience", type=float, default=5.0,
                    help="stop when the error has not improved by 1 mm for this long (s of "
                    "driving: ticks where safety held the arm do not count)")
    ap.add_argument("--samples", type=int, default=64, help="actions sampled per tick")
    ap.add_argument("--lookahead", type=float, default=4.0,
                    help="ticks of motion the greedy choice looks ahead")
    ap.add_argument("--switch-below", type=float, default=0.3,
                    help="maps with modes: press the mode button when the best action's "
                    "progress is below this fraction of the mode's longest move ...")
    ap.add_argument("--switch-after", type=int, default=20, help="... for this many ticks")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--urdf", default=str(REPO / "robots/gen3_lite.urdf"))
    ap.add_argument("--json", action="store_true", help="print the result as JSON")
    ap.add_argument("--verbose", action="store_true", help="print the error once a second")
    args = ap.parse_args(argv)
    r = run(args)
    if args.json:
        print(json.dumps(r))
    else:
        print(
            f"reach: final error {r['final_error_m'] * 1000:.1f} mm (from "
            f"{r['start_error_m'] * 1000:.1f} mm) in {r['converged_s']:.1f} s "
            f"(stopped after {r['time_s']:.1f} s, {r['ticks']} ticks), "
            f"{r['mode_switches']} mode switches; {'reached' if r['reached'] else 'not reached'}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
