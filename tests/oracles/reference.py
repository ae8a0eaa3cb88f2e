"""TEST ORACLE: Contract 1 read a second time, in plain Python, one substep at a time.

Deliberately naive (``math`` on floats, a bisection per torque lookup) and written apart from
the Rust plant, on the same scheme (semi-implicit Euler on the same substeps), so the tests can
hold the Rust simulator to it sample by sample; also the pure-Python baseline of
bench/sim_step.py. Not shipped: production code simulates with the Rust plant only.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Mapping, Sequence

import numpy as np

from admittance.errors import ConfigError
from admittance.sim import DEFAULT_MAX_STEP, FRICTION_LAWS, Trial, pack_params, unpack_params


def _substep_count(dt: float, max_step: float) -> int:
    return max(1, math.ceil(dt / max_step - 1e-9))


def _interp(t: Sequence[float], tau: Sequence[float], q: float) -> float:
    if q <= t[0]:
        return tau[0]
    if q >= t[-1]:
        return tau[-1]
    j = bisect.bisect_right(t, q) - 1
    slope = (tau[j + 1] - tau[j]) / (t[j + 1] - t[j])
    return tau[j] + slope * (q - t[j])


def _sign(x: float) -> float:
    return 1.0 if x > 0 else -1.0 if x < 0 else 0.0


def _friction_level(p: Mapping[str, float], theta: float, omega: float, drive: float, load_torque: float) -> float:
    direction = _sign(omega) if omega != 0 else _sign(drive)
    level = p["coulomb"] + direction * p["coulomb_asym"]
    level += p["friction_ripple_amplitude"] * math.sin(p["friction_ripple_period"] * theta + p["friction_ripple_phase"])
    if p["stribeck_torque"] != 0:
        level += p["stribeck_torque"] * math.exp(-((omega / p["stribeck_velocity"]) ** 2))
    level += p["load_coulomb"] * abs(load_torque)
    return max(level, 0.0)


def _next_velocity(omega: float, inertia: float, drive: float, dissipation: float, level: float,
                   friction: str, tanh_k: float, h: float) -> float:
    gain = h / inertia
    free = omega + gain * drive  # the velocity without friction, (h/I)·τ_stop
    if friction == "stick":
        if abs(free) <= gain * level:
            return 0.0
        numerator = free - math.copysign(gain * level, free)
    else:
        numerator = free - gain * level * math.tanh(tanh_k * omega)
    return numerator / (1.0 + gain * dissipation)


def _reference_step(theta: float, omega: float, p: Mapping[str, float], inertia: float, gravity: float,
                    tau: float, t: float, h: float, friction: str) -> tuple[float, float]:
    tau_corrected = p["torque_gain"] * tau - p["torque_bias"] - p["torque_drift"] * t
    g = gravity * math.sin(theta - p["angle_offset"])
    cogging = p["cogging_amplitude"] * math.sin(p["cogging_period"] * theta + p["cogging_phase"])
    spring = p["spring_stiffness"] * (theta - p["spring_neutral"])
    drive = tau_corrected - g - cogging - spring
    dissipation = p["damping"] + p["quadratic_drag"] * abs(omega)  # taken at the new velocity
    level = _friction_level(p, theta, omega, drive, g - tau_corrected)
    omega = _next_velocity(omega, inertia, drive, dissipation, level, friction, p["tanh_k"], h)
    return theta + h * omega, omega


def simulate_reference(
    trial: Trial,
    params: Mapping[str, float],
    theta0: float,
    omega0: float,
    *,
    max_step: float = DEFAULT_MAX_STEP,
    friction: str = "stick",
    return_velocity: bool = False,
) -> np.ndarray:
    """The same simulation as ``simulate``, in plain Python (slow; for tests and benchmarks)."""
    if friction not in FRICTION_LAWS:
        raise ConfigError(f"unknown friction law {friction!r}: expected one of {FRICTION_LAWS}")
    p = unpack_params(pack_params(params))
    t = trial.t.tolist()
    tau = trial.tau.tolist() if trial.has_tau else None
    if tau is None:  # gain, bias and drift correct a measured torque; a free swing has none
        p["torque_bias"] = p["torque_drift"] = 0.0
    inertia = p["motor_inertia"] + trial.load_inertia
    theta, omega = float(theta0), float(omega0)
    out = [(theta, omega)]
    for i in range(1, len(t)):
        n = _substep_count(t[i] - t[i - 1], max_step)
        h = (t[i] - t[i - 1]) / n
        for k in range(n):
            tk = t[i - 1] + k * h
            applied = _interp(t, tau, tk - p["time_delay"]) if tau is not None else 0.0
            theta, omega = _reference_step(theta, omega, p, inertia, trial.gravity_torque,
                                           applied, tk - t[0], h, friction)
        out.append((theta, omega))
    states = np.array(out, dtype=np.float64)
    return states if return_velocity else states[:, 0]
