"""The loop's per-cycle telemetry, turned into what the daemon publishes and records.

``AdmittanceLoop.drain_telemetry()`` hands over a NumPy structured array, one row per joint
per cycle (see docs/realtime.md). The conversion works on whole columns rather than row by row:
at the usual 10 cycles per tick both cost about the same, but a tick that fell behind (the
main thread was descheduled, a recording flush was slow) drains hundreds of cycles at once,
and there the columns are ~4× cheaper (bench/daemon_tick.py), so a late tick catches up
instead of falling further behind.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from admittance import _rtcore
from admittance.daemon.config import TICKS_PER_REV
from admittance.daemon.messages import JointState, State

RAD_PER_TICK = 2.0 * math.pi / TICKS_PER_REV
NOT_READ = -1  # present_tick of a cycle that did not read the servo


def tick_to_rad(tick: np.ndarray | int, joint) -> np.ndarray | float:
    """The joint angle of an encoder tick (the loop's goal_tick mapping, inverted)."""
    return (np.asarray(tick, dtype=float) - joint.zero_tick) * RAD_PER_TICK * joint.direction


def columns_by_joint(records: np.ndarray, cfg) -> dict[int, dict[str, np.ndarray]]:
    """Per joint ID, the recorder's columns (see Recorder.append)."""
    ids = records["id"]
    out = {}
    for joint in cfg.joints:
        rows = records[ids == joint.id]
        if len(rows) == 0:
            continue
        present = rows["present_tick"].astype(float)
        present[rows["present_tick"] == NOT_READ] = np.nan
        out[joint.id] = {
            # The cycle's deadline on the model's clock (not its start: a sample may start a cycle
            # anywhere in its window, and the grid may be phase-locked to the sensor).
            "t": rows["deadline_ns"] * 1e-9,
            "t_wake": rows["t_ns"] * 1e-9,
            "tau": rows["torque"].astype(float),
            "force": rows["force"].astype(float),
            "theta_model": rows["theta"].astype(float),
            "omega_model": rows["omega"].astype(float),
            "theta_goal": tick_to_rad(rows["goal_tick"], joint),
            "theta_present": tick_to_rad(present, joint),
            "cycle": rows["cycle"].astype(float),
            "fault": rows["fault"].astype(float),
            "mode": rows["mode"].astype(float),  # the recorder's "held" (recording.held_cycles)
            # The passivity guard: its energy balance (J) and the damping it adds (N·m·s/rad).
            "passivity_energy": guard_column(rows, "passivity_energy"),
            "passivity_damping": guard_column(rows, "passivity_damping"),
        }
    return out


class RenderingError:
    """The live rendering error per joint: a running RMS of θ_present − θ_model over the cycles
    that read the servo, exponentially weighted with a ``window_s`` time constant.

    What the user feels is the horn, not the goal: this is the gap between the two that
    `admittance fidelity` measures offline, kept up to date for ``stats``, ``state`` and
    ``monitor``. None until a joint has been read.
    """

    def __init__(self, cfg, window_s: float = 1.0) -> None:
        self.cfg = cfg
        self.window_s = window_s
        self._mean_square: dict[int, float] = {}
        self._last_t: dict[int, float] = {}

    def update(self, records: np.ndarray) -> None:
        ids = records["id"]
        for joint in self.cfg.joints:
            rows = records[(ids == joint.id) & (records["present_tick"] != NOT_READ)]
            if len(rows) == 0:
                continue
            error = tick_to_rad(rows["present_tick"], joint) - rows["theta"]
            times = rows["t_ns"] * 1e-9
            ms = self._mean_square.get(joint.id, float(error[0] ** 2))
            last = self._last_t.get(joint.id, float(times[0]))
            for t, e in zip(times.tolist(), error.tolist()):
                ms += (1.0 - math.exp(-max(t - last, 0.0) / self.window_s)) * (e * e - ms)
                last = t
            self._mean_square[joint.id], self._last_t[joint.id] = ms, last

    def rms(self, joint_id: int) -> float | None:
        ms = self._mean_square.get(joint_id)
        return None if ms is None else math.sqrt(ms)

    def by_joint(self) -> dict[str, float]:
        """For the stats object: ``{"<id>": rad}``."""
        return {str(jid): math.sqrt(ms) for jid, ms in self._mean_square.items()}


def guard_column(rows: np.ndarray, name: str) -> np.ndarray:
    """A passivity guard column of the rows, zeros for rows from a loop without one (a test's fake)."""
    if name in (rows.dtype.names or ()):
        return rows[name].astype(float)
    return np.zeros(len(rows))


def joint_name(joint) -> str:
    return getattr(joint, "name", "") or f"joint{joint.id}"


OFFSET_READS = 5  # tries at reading both clocks back to back (the narrowest bracket wins)


def wall_offset_ns() -> int:
    """CLOCK_REALTIME − CLOCK_MONOTONIC now: the loop stamps cycles on the monotonic clock only.
    The wall clock is read between two monotonic reads, and of a few tries the one whose reads
    lay closest together is taken: a thread preempted between two reads (a loaded machine)
    would otherwise be off by the whole preemption, milliseconds."""
    return min(_bracketed_offset() for _ in range(OFFSET_READS))[1]


def _bracketed_offset() -> tuple[int, int]:
    """(how far apart the two monotonic reads were, the offset at their midpoint), ns."""
    before, wall, after = time.monotonic_ns(), time.time_ns(), time.monotonic_ns()
    return after - before, wall - (before + after) // 2


def latest_state(records: np.ndarray, cfg, rendering: RenderingError | None = None) -> State:
    """The newest row of each joint as a State message (present_tick from its last read)."""
    ids = records["id"]
    wall_ns = wall_offset_ns()
    joints = []
    for joint in cfg.joints:
        rows = records[ids == joint.id]
        if len(rows) == 0:
            continue
        row = rows[-1]
        read = rows["present_tick"][rows["present_tick"] != NOT_READ]
        present = int(read[-1]) if len(read) else None
        joints.append(JointState(
            id=joint.id, t=int(row["t_ns"]) * 1e-9, force=float(row["force"]), tau=float(row["torque"]),
            theta=float(row["theta"]), omega=float(row["omega"]), goal_tick=int(row["goal_tick"]),
            present_tick=present, fault=int(row["fault"]), name=joint_name(joint),
            wall=(int(row["t_ns"]) + wall_ns) * 1e-9,
            position=None if present is None else float(tick_to_rad(present, joint)),
            rendering_rms=rendering.rms(joint.id) if rendering is not None else None,
            passivity_energy=float(guard_column(rows[-1:], "passivity_energy")[0]),
            passivity_damping=float(guard_column(rows[-1:], "passivity_damping")[0]),
            goal=float(tick_to_rad(int(row["goal_tick"]), joint)),
        ))
    return State(cycle=int(records["cycle"][-1]), joints=joints, mode=mode_name(int(records["mode"][-1])))


def mode_name(code: int) -> str:
    """The loop's mode code in a telemetry row, by name ("running", "holding", "faulted")."""
    modes = _rtcore.LOOP_MODES
    return modes[code] if 0 <= code < len(modes) else f"unknown ({code})"


def fault_names(bits: int) -> list[str]:
    """The fault kinds set in a row's ``fault`` bitmask."""
    return [name for k, name in enumerate(_rtcore.FAULT_KINDS) if bits >> k & 1]


def params_values(params: dict[str, Any]) -> dict[str, float | list[float]]:
    """The loop's params() with plain Python numbers (``bias`` stays a list of 6)."""
    return {name: [float(v) for v in value] if isinstance(value, (list, tuple)) else float(value)
            for name, value in params.items()}
