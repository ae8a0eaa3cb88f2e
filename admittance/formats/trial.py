"""What a trial and a dataset are in memory, and the checks every trial passes.

Every reader of the formats (``dataset`` for contract folders, ``converters`` for foreign
recordings, ``recording`` for a daemon's ``session.mcap``) validates its series here
(:func:`check_series`) and builds :class:`TrialData` and :class:`Dataset`, so the pipeline never
meets a NaN or a time series that goes backwards, whatever the file was. A load's inertia and
gravity torque come from its geometry here (:func:`load_geometry`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from admittance.errors import DataError

GRAVITY = 9.80665  # m/s², standard gravity
MIN_SAMPLES = 10  # fewer cannot pin an initial state and three parameters

TrialArrays = tuple[np.ndarray, np.ndarray, np.ndarray | None]  # t, theta, tau (None: free swing)


@dataclass(frozen=True)
class TrialData:
    """One trial: time (s), angle (rad, 0 = hanging down), optional applied torque (N·m)."""

    name: str
    t: np.ndarray
    theta: np.ndarray
    tau: np.ndarray | None
    load_inertia: float
    gravity_torque: float
    meta: dict = field(default_factory=dict)

    @property
    def n_samples(self) -> int:
        return int(self.t.size)


@dataclass(frozen=True)
class Dataset:
    """A validated dataset. ``mode`` is "geometry" when [rod] or [bob] is given, else "lumped"."""

    mode: str
    trials: tuple[TrialData, ...]
    motor: str = ""
    folder: Path | None = None
    geometry: dict = field(default_factory=dict)
    # Ticks per revolution of the angle encoder (manifest key ``encoder_ticks``, an extension of
    # the contract); None: not declared (identify then looks for a grid in the data).
    encoder_ticks: int | None = None

    @property
    def has_torque(self) -> bool:
        return any(tr.tau is not None for tr in self.trials)


def load_geometry(rod: dict | None, bob: dict | None, bob_distance: float | None) -> tuple[float, float]:
    """(inertia about the axis, gravity torque amplitude m·g·l) of a rod pivoted at its end and a
    point bob at ``bob_distance``."""
    inertia = 0.0
    gravity = 0.0
    if rod:
        inertia += rod["mass"] * rod["length"] ** 2 / 3.0
        gravity += rod["mass"] * GRAVITY * rod["length"] / 2.0
    if bob:
        inertia += bob["mass"] * bob_distance**2
        gravity += bob["mass"] * GRAVITY * bob_distance
    return inertia, gravity


def _floats(values) -> np.ndarray | None:
    return None if values is None else np.asarray(values, dtype=float)


def check_series(path: Path, t, theta, tau=None, min_samples: int = MIN_SAMPLES) -> TrialArrays:
    """Validate a trial's series (same lengths, enough samples, finite, time strictly
    increasing) and return them as float arrays. Shared with the recorder-format loaders."""
    t, theta, tau = _floats(t), _floats(theta), _floats(tau)
    if t.ndim != 1 or theta.shape != t.shape or (tau is not None and tau.shape != t.shape):
        raise DataError(f"{path}: columns have different lengths")
    if t.size == 0:
        raise DataError(f"{path}: empty trial (no usable samples)")
    if t.size < min_samples:
        raise DataError(f"{path}: only {t.size} samples; at least {min_samples} usable samples are needed")
    for name, values in (("t", t), ("theta", theta), ("tau", tau)):
        if values is not None and not np.all(np.isfinite(values)):
            bad = int(np.flatnonzero(~np.isfinite(values))[0])
            raise DataError(f"{path}: column {name!r}: NaN or infinite value at sample {bad}")
    steps = np.diff(t)
    if np.any(steps <= 0):
        bad = int(np.flatnonzero(steps <= 0)[0]) + 1
        raise DataError(f"{path}: time is not strictly increasing at sample {bad} "
                        f"(t = {t[bad]:.9g} after {t[bad - 1]:.9g})")
    return t, theta, tau
