"""Scripted hand-torque profiles: what the simulated user does to the joint, in N·m over time.

A profile is a pure function of the time since the bench started, so a run is repeatable:
the same profile gives the same torque at the same instant, whatever the machine's load. The
built-ins repeat forever (the bench runs until it is stopped); a CSV profile is a recorded or
hand-written (t, tau) series, linearly interpolated and held at its end values, like the
applied torque of an identification trial (architecture.md, Contract 1).

A profile is named on the command line as ``NAME`` or ``NAME:key=value,key=value``
(``sine:amplitude=0.2,frequency=1``), or as the path of a CSV file.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from admittance.errors import ConfigError, DataError

Profile = Callable[[float], float]


def _smoothstep(x: float) -> float:
    """0 → 1 on [0, 1] with zero slope at both ends (a hand does not jerk)."""
    x = min(max(x, 0.0), 1.0)
    return 0.5 - 0.5 * math.cos(math.pi * x)


@dataclass(frozen=True)
class PushRelease:
    """Push up to ``amplitude``, hold, let go; repeat every ``period`` seconds."""

    amplitude: float = 0.3
    period: float = 4.0
    rise: float = 0.3
    hold: float = 1.0
    fall: float = 0.05

    def __call__(self, t: float) -> float:
        s = t % self.period
        if s < self.rise:
            return self.amplitude * _smoothstep(s / self.rise)
        s -= self.rise
        if s < self.hold:
            return self.amplitude
        s -= self.hold
        if s < self.fall:
            return self.amplitude * (1.0 - _smoothstep(s / self.fall))
        return 0.0


@dataclass(frozen=True)
class Sine:
    amplitude: float = 0.2
    frequency: float = 0.5
    offset: float = 0.0

    def __call__(self, t: float) -> float:
        return self.offset + self.amplitude * math.sin(2.0 * math.pi * self.frequency * t)


@dataclass(frozen=True)
class Ramp:
    """A slow triangle 0 → amplitude → 0 over ``period`` (breakaway-style), then ``rest`` at 0."""

    amplitude: float = 0.4
    period: float = 6.0
    rest: float = 1.0

    def __call__(self, t: float) -> float:
        s = t % (self.period + self.rest)
        if s >= self.period:
            return 0.0
        return self.amplitude * (1.0 - abs(2.0 * s / self.period - 1.0))


@dataclass(frozen=True)
class Steps:
    """A staircase 0, a/2, a, -a/2, -a, each level held ``step`` seconds, repeated."""

    amplitude: float = 0.3
    step: float = 1.0

    def __call__(self, t: float) -> float:
        levels = (0.0, 0.5, 1.0, -0.5, -1.0)
        return self.amplitude * levels[int(t // self.step) % len(levels)]


@dataclass(frozen=True)
class Still:
    """No hand: the user does not touch the joint (a constant ``torque``, 0 by default)."""

    torque: float = 0.0

    def __call__(self, t: float) -> float:
        return self.torque


@dataclass(frozen=True)
class TabulatedProfile:
    """A (t, tau) series, linearly interpolated, held at its first and last values."""

    t: tuple[float, ...]
    tau: tuple[float, ...]

    def __call__(self, t: float) -> float:
        return float(np.interp(t, self.t, self.tau))


# A table has at most this many points (the Rust stream's own bound, dxlsim::daq).
MAX_TABLE_POINTS = 1_000_000


def period_of(profile: Profile) -> float | None:
    """The period after which a built-in profile repeats; None for one that does not."""
    if isinstance(profile, PushRelease | Ramp):
        return profile.period + (profile.rest if isinstance(profile, Ramp) else 0.0)
    if isinstance(profile, Sine):
        return 1.0 / profile.frequency
    if isinstance(profile, Steps):
        return 5 * profile.step
    return None


def tabulate(profile: Profile, step_s: float) -> tuple[list[float], list[float], float | None] | None:
    """(t, τ, period) that reproduce ``profile`` by linear interpolation at the times a stream
    samples it (multiples of ``step_s``), for a stream outside Python (dxlsim's simulated DAQ);
    None for a callable this module did not make (only Python can evaluate it)."""
    if isinstance(profile, TabulatedProfile):
        return list(profile.t), list(profile.tau), None
    if isinstance(profile, Still):
        return [0.0], [profile.torque], None
    period = period_of(profile)
    if period is None:
        return None
    n = min(max(math.ceil(period / step_s), 1), MAX_TABLE_POINTS - 1)
    t = [period * k / n for k in range(n + 1)]
    return t, [profile(x) for x in t], period


BUILTIN_PROFILES: dict[str, type] = {
    "push-release": PushRelease,
    "sine": Sine,
    "ramp": Ramp,
    "steps": Steps,
    "still": Still,
}


def make_profile(spec: str) -> Profile:
    """A profile from ``NAME``, ``NAME:key=value,...`` or a CSV file path."""
    name, _, options = spec.partition(":")
    if name in BUILTIN_PROFILES:
        return _builtin(name, options)
    if spec.endswith(".csv") or Path(spec).is_file():
        return load_csv_profile(Path(spec))
    raise ConfigError(f"unknown hand profile '{spec}': use one of {', '.join(BUILTIN_PROFILES)}, or a CSV file (t, tau)")


def _builtin(name: str, options: str) -> Profile:
    cls = BUILTIN_PROFILES[name]
    allowed = {f.name for f in fields(cls)}
    values: dict[str, float] = {}
    for item in filter(None, options.split(",")):
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or key not in allowed:
            raise ConfigError(f"profile '{name}' takes {', '.join(sorted(allowed))} (as key=value), not '{item}'")
        try:
            values[key] = float(text)
        except ValueError:
            raise ConfigError(f"profile '{name}': {key} must be a number, not '{text}'") from None
    profile = cls(**values)
    for key in ("period", "frequency", "step", "rise"):
        if key in allowed and getattr(profile, key) <= 0:
            raise ConfigError(f"profile '{name}': {key} must be positive")
    return profile


def load_csv_profile(path: Path) -> TabulatedProfile:
    """Read a two-column CSV (t in s, tau in N·m); a non-numeric first row is a header."""
    try:
        with path.open(newline="") as f:
            rows = [r for r in csv.reader(f) if r and not r[0].lstrip().startswith("#")]
    except OSError as exc:
        raise DataError(f"cannot read hand profile {path}: {exc.strerror}") from None
    if rows and not _is_number(rows[0][0]):
        rows = rows[1:]
    if not rows:
        raise DataError(f"hand profile {path} has no rows")
    try:
        t, tau = zip(*((float(r[0]), float(r[1])) for r in rows))
    except (ValueError, IndexError):
        raise DataError(f"hand profile {path}: every row needs two numbers (t, tau)") from None
    if any(b <= a for a, b in zip(t, t[1:])) or not all(map(math.isfinite, t + tau)):
        raise DataError(f"hand profile {path}: t must increase strictly and every value be finite")
    return TabulatedProfile(t, tau)


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True
