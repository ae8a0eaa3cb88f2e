"""The force sensor against the servo: which axis a push loads, its sign, and the lever arm.

Method (docs/bring-up.md): the servo holds the arm in position mode while the user presses
the handle in the positive direction, slowly harder and then slowly off. Holding still, the
motor's torque balances the hand's, so the hand torque about the joint is
``τ = −direction · (τ_motor − τ_motor at rest)``, and ``τ_motor`` is read from the servo:
``kt · Present Current`` where the model reports current, else Present Load (a fraction of the
stall torque ``kt/R · Vin · max_pwm``), with kt and R the motor constants the simulated servos
use (``_rtcore.motor_constants``). Over the press, the axis whose force moves most is the
driving axis, and the least-squares slope of τ against that force is the lever arm, sign
included (the configuration's convention: τ = F_axis · lever_arm). Pressing harder *and* easing
off matters: gear friction holds part of the hand torque with one sign while the push grows and
the other while it falls, so the slope over both halves averages it out; the intercept absorbs
the sensor's bias.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from admittance.bringup.prompt import Prompter
from admittance.drivers.dynamixel import ServoBus
from admittance.errors import DataError

AXES = ("x", "y", "z")
MIN_R2 = 0.8
MIN_SPAN_N = 1.0  # a press that moves the force less than this says nothing about the axis
SAMPLE_WINDOW_NS = 20_000_000  # force samples averaged around each torque reading
MAX_ROUND_TRIP_NS = 30_000_000  # a reading slower than this cannot be placed in time
PRESS_S = 6.0


@dataclass(frozen=True)
class SensorReading:
    axis: str
    lever_arm: float  # m, signed: τ = F_axis · lever_arm
    r2: float
    span_n: float
    n: int

    def line(self) -> str:
        sign = "+" if self.lever_arm > 0 else "-"
        return (f"axis = {self.axis!r} (a positive push reads {sign}F{self.axis}), lever_arm = {self.lever_arm:.4f} m "
                f"(R² {self.r2:.3f} over {self.n} readings, force span {self.span_n:.1f} N)")


def motor_torque_reader(bus: ServoBus, servo_id: int, model: str) -> Callable[[], float] | None:
    """A function that reads the motor's output torque (N·m, tick-positive), or None if the model
    reports neither current nor load or has no motor constants."""
    from admittance import _rtcore

    constants = _rtcore.motor_constants(model)
    table = bus.table(servo_id)
    if constants is None:
        return None
    for current in ("Present Current", "Current"):
        if table.has(current):
            return lambda: constants["kt"] * bus.read(servo_id, current)
    if not table.has("Present Load"):
        return None
    volts = next(name for name in ("Present Input Voltage", "Present Voltage") if table.has(name))
    stall = constants["kt"] / constants["resistance"] * bus.read(servo_id, volts) * constants["max_pwm"]
    return lambda: bus.read(servo_id, "Present Load") / 100.0 * stall


def fit_lever_arm(forces: np.ndarray, torques: np.ndarray) -> SensorReading:
    """The driving axis and the slope of ``torques`` (N·m, joint frame) on its force (N).

    ``forces`` has one row per reading and a column per axis (x, y, z).
    """
    forces, torques = np.asarray(forces, float), np.asarray(torques, float)
    if len(torques) < 10 or not (np.all(np.isfinite(forces)) and np.all(np.isfinite(torques))):
        raise DataError(f"too few finite readings during the press ({len(torques)}): press for longer")
    spans = forces.max(axis=0) - forces.min(axis=0)
    k = int(np.argmax(spans))
    if spans[k] < MIN_SPAN_N:
        raise DataError(f"the force moved by only {spans[k]:.2f} N during the press: is the sensor streaming, "
                        "and was the handle pressed?")
    f = forces[:, k]
    slope, intercept = np.polyfit(f, torques, 1)
    residual = torques - (slope * f + intercept)
    total = float(np.sum((torques - torques.mean()) ** 2))
    r2 = 1.0 - float(np.sum(residual**2)) / total if total > 0 else 0.0
    if not r2 >= MIN_R2 or not math.isfinite(slope) or slope == 0.0:
        raise DataError(f"the servo's torque does not follow the force on {AXES[k]} (R² {r2:.2f} < {MIN_R2}): "
                        "did the arm stay held, and did the push go through the sensor?")
    return SensorReading(AXES[k], float(slope), r2, float(spans[k]), len(torques))


def measure_sensor(bus: ServoBus, servo_id: int, model: str, direction: int, samples: Any, prompter: Prompter,
                   *, press_s: float = PRESS_S) -> SensorReading:
    """Hold the arm, record torque and force while the user presses; ``samples`` is the sensor's
    SampleBuffer (rows of t_ns, [fx, fy, fz, ...])."""
    torque = motor_torque_reader(bus, servo_id, model)
    if torque is None:
        raise DataError(f"{model} reports neither current nor load with known motor constants: measure the lever "
                        "arm with a ruler and give --lever-arm and --axis")
    _hold_here(bus, servo_id)
    try:
        prompter.act("press", f"The servo holds the arm. Press the handle in the positive direction, slowly harder "
                              f"then slowly off, for about {press_s:g} s (keep it gentle: below 20 N).")
        readings = _record(torque, press_s)
    finally:
        bus.set_torque(servo_id, False)
    return fit_lever_arm(*_paired(readings, samples.snapshot(), direction))


def _hold_here(bus: ServoBus, servo_id: int) -> None:
    bus.set_torque(servo_id, False)
    bus.set_position_mode(servo_id)
    bus.write_raw(servo_id, "Goal Position", bus.read_raw(servo_id, "Present Position"))
    bus.set_torque(servo_id, True)


def _record(torque: Callable[[], float], seconds: float) -> list[tuple[int, float]]:
    """Torque readings for ``seconds``; a reply lost now and then costs one reading, not the press."""
    from admittance.drivers.dynamixel import ServoTimeout

    out, lost, deadline = [], 0, time.monotonic() + seconds
    while time.monotonic() < deadline:
        t0 = time.monotonic_ns()
        try:
            tau = torque()
        except ServoTimeout:
            tau = None
        t1 = time.monotonic_ns()
        if tau is not None and t1 - t0 <= MAX_ROUND_TRIP_NS:
            out.append(((t0 + t1) // 2, tau))  # the servo sampled somewhere in between
        else:  # no reply, or one too late to say when the servo read its current
            lost += 1
            if lost > 10 + len(out):
                raise DataError(f"{lost} of {lost + len(out)} torque readings were lost or late: is the host "
                                "overloaded, or the bus too slow?")
        time.sleep(0.01)
    return out


def _paired(readings: list[tuple[int, float]], samples: list[tuple[int, list[float]]],
            direction: int) -> tuple[np.ndarray, np.ndarray]:
    """Each torque reading with the mean force of the samples around it; the hand's torque
    in the joint's frame is the opposite of the motor's change from its first reading."""
    if not samples:
        raise DataError("the force sensor sent no samples during the press")
    t = np.array([s[0] for s in samples])
    f = np.array([s[1][:3] for s in samples], float)
    forces, torques = [], []
    base = readings[0][1]
    for t_ns, tau in readings:
        lo, hi = np.searchsorted(t, t_ns - SAMPLE_WINDOW_NS // 2), np.searchsorted(t, t_ns + SAMPLE_WINDOW_NS // 2)
        if hi > lo:
            forces.append(f[lo:hi].mean(axis=0))
            torques.append(-direction * (tau - base))
    return np.array(forces).reshape(-1, 3), np.array(torques)
