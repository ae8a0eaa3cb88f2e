"""What ``admittance get``, ``set`` and ``tare`` print: a daemon's parameters and replies in words.

Each parameter comes with its unit from the configuration's schema (the units ``set`` takes),
and a set says what changed and how it arrives: the gains (``virtual_*``, ``lever_arm``) ramp
over ``ramp_time_s``, ``servo_compensation`` blends in over max(``ramp_time_s``, 0.2 s), and
every other key applies at once (docs/realtime.md, "adopt_params / advance_ramp"). ``--json``
prints the daemon's own reply instead, for scripts.

Pure functions of dicts, so the wording is tested without a daemon.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from admittance.daemon.config import JOINT_LIVE, LOOP_LIVE

RAMPED = ("virtual_inertia", "virtual_damping", "virtual_coulomb", "lever_arm")
COMPENSATION_MIN_BLEND_S = 0.2


def key_of(name: str) -> str:
    """The schema key of a parameter name: ``1.limits.position_max`` → ``position_max``."""
    head, dot, rest = name.partition(".")
    bare = rest if dot and head.isdigit() else name
    return bare.removeprefix("limits.")


def unit_of(name: str) -> str:
    key = key_of(name)
    table = JOINT_LIVE if key in JOINT_LIVE else LOOP_LIVE
    return table[key][1].get("unit", "") if key in table else ""


def value_text(value: Any) -> str:
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(f"{v:.6g}" for v in value) + "]"
    return f"{value:.6g}" if isinstance(value, (int, float)) else str(value)


def with_unit(value: Any, name: str) -> str:
    unit = unit_of(name)
    return value_text(value) + (f" {unit}" if unit else "")


def params_table(params: Mapping[str, Any]) -> str:
    """One line per parameter: name, value, unit; joints' first (by id), then loop-wide."""
    def order(name: str) -> tuple:
        head, dot, _ = name.partition(".")
        return (0, int(head), name) if dot and head.isdigit() else (1, 0, name)

    names = sorted(params, key=order)
    width = max((len(n) for n in names), default=0)
    return "\n".join(f"{name:<{width}}  {value_text(params[name]):<12}  {unit_of(name)}".rstrip() for name in names)


def affected(name: str, params: Mapping[str, Any]) -> list[str]:
    """The daemon's parameter names a set's name changed: a bare joint key is every joint's."""
    key = key_of(name)
    head, dot, _ = name.partition(".")
    if dot and head.isdigit():
        return [f"{head}.{key}"]
    joint_names = sorted((n for n in params if "." in n and key_of(n) == key), key=lambda n: int(n.split(".")[0]))
    return joint_names or [key]


def arrival(key: str, after: Mapping[str, Any]) -> str:
    ramp = float(after.get("ramp_time_s", 0.0))
    if key in RAMPED:
        return f"ramping over {ramp:g} s" if ramp > 0 else "at once"
    if key == "servo_compensation":
        return f"blending in over {max(ramp, COMPENSATION_MIN_BLEND_S):g} s"
    return "at once"


def set_reply_text(request: Mapping[str, Any], reply: Mapping[str, Any], before: Mapping[str, Any],
                   after: Mapping[str, Any]) -> str:
    """``accepted: 1.virtual_damping 0.05 → 0.08 N·m·s/rad, ramping over 0.5 s`` per changed
    parameter, or ``refused: <reason>``."""
    if not reply.get("accepted", False):
        return f"refused: {reply.get('reason') or 'no reason given'}"
    lines = []
    for name in request:
        for full in affected(name, after):
            old, new = before.get(full, "?"), after.get(full, request[name])
            lines.append(f"accepted: {full} {value_text(old)} → {with_unit(new, full)}, {arrival(key_of(full), after)}")
    return "\n".join(lines) or "accepted"


def tare_reply_text(samples: int, reply: Mapping[str, Any]) -> str:
    if not reply.get("accepted", False):
        return f"refused: {reply.get('reason') or 'no reason given'}"
    return (f"accepted: the next {samples} force samples become the sensor's zero "
            "(a hand on the handle meanwhile becomes part of it)")
