"""No drift between the languages: every ctypes structure, topic setting, constant and bit name
of the package against what the Rust build prints (``scl layout``)."""

from __future__ import annotations

import copy
import json
import subprocess
from typing import Dict, List

import pytest

from scl_teleop import msg
from scl_teleop.graph import SUPERVISOR_SERVICE, TOPICS

from .conftest import scl_bin


@pytest.fixture(scope="module")
def rust() -> Dict:
    out = subprocess.run([scl_bin(), "layout"], check=True, capture_output=True, text=True)
    return json.loads(out.stdout)


def python_side() -> Dict:
    """The package's view in the form ``scl layout`` prints."""
    return {
        "types": [msg.layout_of(t) for t in msg.TYPES.values()],
        "topics": [
            {
                "name": t.name,
                "message": t.message.__name__,
                "history": t.history,
                "buffer": t.buffer,
                "max_publishers": t.max_publishers,
                "max_subscribers": t.max_subscribers,
            }
            for t in TOPICS.values()
        ],
        "constants": {
            "max_joints": msg.MAX_JOINTS,
            "action_dim": msg.ACTION_DIM,
            "no_tick": msg.NO_TICK,
            "text_cap": msg.TEXT_CAP,
            "supervisor_service": SUPERVISOR_SERVICE,
        },
        "bits": [[name, list(bits.NAMES)] for name, bits in msg.BITS.items()],
    }


def diff(rust: Dict, py: Dict) -> List[str]:
    """Every difference between the two layouts, named (empty when they agree)."""
    out: List[str] = []
    r_types = {t["name"]: t for t in rust["types"]}
    p_types = {t["name"]: t for t in py["types"]}
    for name in sorted(set(r_types) ^ set(p_types)):
        side = "Rust" if name in r_types else "Python"
        out.append(f"{name}: only on the {side} side")
    for name in sorted(set(r_types) & set(p_types)):
        r, p = r_types[name], p_types[name]
        for key in ("type_name", "size", "align"):
            if r[key] != p[key]:
                out.append(f"{name}.{key}: Rust {r[key]!r}, Python {p[key]!r}")
        if r["fields"] != p["fields"]:
            out.append(f"{name}.fields: Rust {r['fields']}, Python {p['fields']}")
    r_topics = sorted(rust["topics"], key=lambda t: t["name"])
    p_topics = sorted(py["topics"], key=lambda t: t["name"])
    if r_topics != p_topics:
        out.append(f"topics: Rust {r_topics}, Python {p_topics}")
    if rust["constants"] != py["constants"]:
        out.append(f"constants: Rust {rust['constants']}, Python {py['constants']}")
    if rust["bits"] != py["bits"]:
        out.append(f"bits: Rust {rust['bits']}, Python {py['bits']}")
    return out


def test_python_matches_the_rust_build(rust: Dict) -> None:
    assert diff(rust, python_side()) == []


def test_bit_constants_match_their_names() -> None:
    """Each bit set has one constant per name, the bits in order without gaps."""
    for name, bits in msg.BITS.items():
        values = sorted(
            v for k, v in vars(bits).items() if k.isupper() and k != "NAMES" and isinstance(v, int)
        )
        assert values == [1 << i for i in range(len(bits.NAMES))], name


def test_the_check_sees_every_kind_of_drift(rust: Dict) -> None:
    """The comparison fails on a moved field, a new field, a renamed type, a changed size,
    a topic setting and a bit name: a Rust change without the Python side fails CI."""
    py = python_side()
    assert diff(rust, py) == []

    def drifted(edit) -> List[str]:
        r = copy.deepcopy(rust)
        edit(r)
        return diff(r, py)

    state = lambda r: next(t for t in r["types"] if t["name"] == "RobotState")  # noqa: E731
    assert drifted(lambda r: state(r)["fields"].reverse())
    assert drifted(lambda r: state(r)["fields"].append(
        {"name": "torque", "offset": 176, "size": 8, "type": "f64"}))
    assert drifted(lambda r: state(r).__setitem__("type_name", "scl::RobotStateV2"))
    assert drifted(lambda r: state(r).__setitem__("size", 184))
    assert drifted(lambda r: state(r)["fields"][4].__setitem__("type", "u64"))
    assert drifted(lambda r: r["types"].append({"name": "Wrench", "type_name": "scl::Wrench",
                                                "size": 8, "align": 8, "fields": []}))
    assert drifted(lambda r: r["topics"][0].__setitem__("max_publishers", 2))
    assert drifted(lambda r: r["bits"][0][1].append("turbo"))
    assert drifted(lambda r: r["constants"].__setitem__("max_joints", 7))
