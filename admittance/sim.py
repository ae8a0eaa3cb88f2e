"""Typed facade over the plant simulator of ``admittance._rtcore`` (Contract 1).

The Rust core takes a flat parameter vector in ``PARAM_NAMES`` order; people and config files
speak in names. ``pack_params`` / ``unpack_params`` are the one translation between the two,
with the defaults coming from the Rust side (``_rtcore.PARAM_DEFAULTS``) so they cannot drift.

``simulate_reference`` is the same model written again in plain Python, one substep at a time,
deliberately naive (``math`` on floats, a bisection per torque lookup). It is not for use: it
is the independent second reading of Contract 1 that the tests hold the Rust simulator to, and
the baseline the benchmark measures against.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Mapping, Sequence

import numpy as np

from admittance import _rtcore
from admittance.errors import ConfigError, DataError

__all__ = [
    "DEFAULT_MAX_STEP", "FRICTION_LAWS", "PARAM_DEFAULTS", "PARAM_NAMES", "REQUIRED_PARAMS", "Trial",
    "make_trial", "pack_params", "simulate", "simulate_batch", "simulate_many", "simulate_reference",
    "unpack_params",
]

PARAM_NAMES: tuple[str, ...] = tuple(_rtcore.PARAM_NAMES)
PARAM_DEFAULTS: dict[str, float] = dict(zip(PARAM_NAMES, _rtcore.PARAM_DEFAULTS))
REQUIRED_PARAMS: tuple[str, ...] = ("motor_inertia",)
FRICTION_LAWS: tuple[str, ...] = ("stick", "tanh")
DEFAULT_MAX_STEP = 5e-4

Trial = _rtcore.Trial
simulate_batch = _rtcore.simulate_batch


def make_trial(t, tau=None, load_inertia: float = 0.0, gravity_torque: float = 0.0) -> Trial:
    """Builds a ``Trial``, reporting bad arrays as ``DataError``."""
    try:
        return Trial(t, tau, load_inertia, gravity_torque)
    except ValueError as exc:
        raise DataError(f"invalid trial: {exc}") from exc


def pack_params(params: Mapping[str, float]) -> np.ndarray:
    """The parameter vector (``PARAM_NAMES`` order) of a name → value mapping; defaults fill
    the gaps. Unknown names, a missing required name or a non-finite value raise ConfigError."""
    unknown = sorted(set(params) - set(PARAM_NAMES))
    if unknown:
        raise ConfigError(f"unknown plant parameter(s) {', '.join(unknown)}; known: {', '.join(PARAM_NAMES)}")
    missing = [name for name in REQUIRED_PARAMS if name not in params]
    if missing:
        raise ConfigError(f"missing required plant parameter(s): {', '.join(missing)}")
    vector = np.array([PARAM_DEFAULTS[name] for name in PARAM_NAMES], dtype=np.float64)
    for name, value in params.items():
        try:
            number = float(value)
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"plant parameter {name} must be a number, got {value!r}") from exc
        if not math.isfinite(number):
            raise ConfigError(f"plant parameter {name} must be finite, got {number}")
        vector[PARAM_NAMES.index(name)] = number
    return vector


def unpack_params(vector) -> dict[str, float]:
    """The name → value mapping of a parameter vector."""
    array = np.asarray(vector, dtype=np.float64)
    if array.shape != (len(PARAM_NAMES),):
        raise ConfigError(f"a parameter vector has shape ({len(PARAM_NAMES)},), got {array.shape}")
    return {name: float(value) for name, value in zip(PARAM_NAMES, array)}


def simulate(
    trial: Trial,
    params: Mapping[str, float],
    theta0: float,
    omega0: float,
    *,
    max_step: float = DEFAULT_MAX_STEP,
    friction: str = "stick",
    return_velocity: bool = False,
) -> np.ndarray:
    """One run: θ at the trial's sample times, shape (n,), or (n, 2) with ω."""
    x0 = np.array([[[theta0, omega0]]], dtype=np.float64)
    (out,) = simulate_many([trial], pack_params(params)[None, :], x0, max_step=max_step,
                           friction=friction, return_velocity=return_velocity)
    return out[0]


def simulate_many(
    trials: Sequence[Trial],
    param_sets,
    x0,
    *,
    max_step: float = DEFAULT_MAX_STEP,
    friction: str = "stick",
    return_velocity: bool = False,
    threads: int | None = None,
) -> list[np.ndarray]:
    """``_rtcore.simulate_batch`` with its ValueErrors reported as ConfigError.

    param_sets: (S, P) vectors; x0: (S, T, 2). Returns per trial (S, n) or (S, n, 2).
    """
    try:
        return simulate_batch(list(trials), param_sets, x0, max_step=max_step, friction=friction,
                              return_velocity=return_velocity, threads=threads)
    except ValueError as exc:
        raise ConfigError(f"cannot simulate: {exc}") from exc


# --- the reference implementation: Contract 1 read a second time, in plain Python ---------


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
