"""Typed facade over the plant simulator of ``admittance._rtcore`` (Contract 1).

The Rust core takes a flat parameter vector in ``PARAM_NAMES`` order; people and config files
speak in names. ``pack_params`` / ``unpack_params`` are the one translation between the two,
with the defaults coming from the Rust side (``_rtcore.PARAM_DEFAULTS``) so they cannot drift.

The same model written again in plain Python, the second reading of Contract 1 that the tests
hold the Rust simulator to, is a test oracle (``tests/oracles/reference.py``), not shipped.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from admittance import _rtcore
from admittance.errors import ConfigError, DataError

__all__ = [
    "DEFAULT_MAX_STEP", "FRICTION_LAWS", "PARAM_DEFAULTS", "PARAM_NAMES", "REQUIRED_PARAMS", "Trial",
    "make_trial", "pack_params", "simulate", "simulate_batch", "simulate_many", "unpack_params",
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
