"""Fitted parameter files (Contract 2): the TOML that ``identify`` writes and the daemon reads.

A file has three tables: ``[model]`` (labels: motor, friction law, mode, source), ``[params]``
(the plant parameters of Contract 1 by name, SI units; absent names keep their defaults) and
``[fit]`` (provenance); and optionally ``[servo]``, the servo's tracking dynamics that
``admittance fidelity`` identifies (docs/fidelity.md): ``SERVO_KEYS`` (the five of the lag form
required, the gear play's two optional, 0 when absent). A
joint whose file has ``[servo]`` compensates for it. The parameter names are checked against
one list, so a typo in a hand-edited file is an error naming the file and key instead of a
silently ignored value.

The name list lives here rather than being read from ``_rtcore.PARAM_NAMES`` so that reading a
parameter file never needs the compiled extension (the daemon's config check runs before it
loads); ``tests/test_ident_paramfile.py`` checks that the two lists agree.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import tomli_w

from admittance.errors import ConfigError

# Contract 1's parameter order, with defaults (None: required).
PARAM_DEFAULTS: dict[str, float | None] = {
    "motor_inertia": None,
    "damping": 0.0,
    "coulomb": 0.0,
    "coulomb_asym": 0.0,
    "stribeck_torque": 0.0,
    "stribeck_velocity": 0.1,
    "load_coulomb": 0.0,
    "angle_offset": 0.0,
    "quadratic_drag": 0.0,
    "cogging_amplitude": 0.0,
    "cogging_period": 0.0,
    "cogging_phase": 0.0,
    "time_delay": 0.0,
    "torque_bias": 0.0,
    "torque_drift": 0.0,
    "tanh_k": 100.0,
    "torque_gain": 1.0,
    "spring_stiffness": 0.0,
    "spring_neutral": 0.0,
    "friction_ripple_amplitude": 0.0,
    "friction_ripple_period": 0.0,
    "friction_ripple_phase": 0.0,
}
PARAM_NAMES: tuple[str, ...] = tuple(PARAM_DEFAULTS)
# Each plant parameter's physical domain: a value outside is refused with the file and key, so
# an absurd hand edit (1e300) never reaches the daemon. Generous, because in lumped mode the
# torque parameters are per unit inertia (a small servo's Coulomb/I reaches 10^4).
TORQUE_RANGE = (-1e6, 1e6)
PARAM_BOUNDS: dict[str, tuple[float, float]] = {
    "motor_inertia": (0.0, 100.0),  # kg·m² (0: a passive rig with no motor)
    "damping": (0.0, 1e6),
    "coulomb": (0.0, 1e6),
    "coulomb_asym": TORQUE_RANGE,
    "stribeck_torque": (0.0, 1e6),
    "stribeck_velocity": (1e-4, 100.0),  # rad/s
    "load_coulomb": (0.0, 10.0),  # a fraction of the load torque
    "angle_offset": (-math.pi, math.pi),
    "quadratic_drag": (0.0, 1e6),
    "cogging_amplitude": (0.0, 1e6),
    "cogging_period": (0.0, 1000.0),  # cycles/rev
    "cogging_phase": (-100.0, 100.0),
    "time_delay": (0.0, 1.0),  # s
    "torque_bias": TORQUE_RANGE,
    "torque_drift": TORQUE_RANGE,
    "tanh_k": (1e-6, 1e6),
    "torque_gain": (1e-6, 100.0),  # > 0: the plant refuses a reversed or dead sensor
    "spring_stiffness": (0.0, 1e6),
    "spring_neutral": (-100.0, 100.0),
    "friction_ripple_amplitude": (0.0, 1e6),
    "friction_ripple_period": (0.0, 1000.0),
    "friction_ripple_phase": (-100.0, 100.0),
}


@dataclass(frozen=True)
class ServoKey:
    """One ``[servo]`` key: what validation checks and ``admittance docs servo`` prints."""

    unit: str
    bounds: tuple[float, float]  # the physical domain (time_constant's is open at 0)
    default: float | None  # None: required
    meaning: str


# plant::servo's parameters in its order, each with its physical domain (plant::servo::
# SERVO_DOMAIN and SERVO_PARAM_DEFAULTS: tests/test_ident_paramfile.py checks they agree).
SERVO_KEYS: dict[str, ServoKey] = {
    "time_constant": ServoKey("s", (0.0, 1.0), None, "the lag T: a ramp at v rad/s is followed T·v behind"),
    "inertial_time": ServoKey("s", (0.0, 0.5), None, "m, the second-order part (horn inertia over damping; 0: "
                                                     "a first-order lag)"),
    "dead_time": ServoKey("s", (-0.02, 0.2), None, "d: the goal acts this late"),
    "compliance": ServoKey("rad/(N·m)", (-0.5, 0.5), None, "s: how far the hand's torque pushes the horn off its "
                                                             "goal at rest"),
    "deadband": ServoKey("rad", (0.0, 0.05), None, "b: the horn sticks while its error is within ±b"),
    "backlash": ServoKey("rad", (0.0, 0.035), 0.0, "the gear play between motor and horn (MX: a few tenths "
                                                   "of a degree; 0: none)"),
    "backlash_torque": ServoKey("N·m", (0.0, 2.0), 0.0, "the hand torque that holds the horn against a side of "
                                                        "the play (below it the horn stays, or the motor drags it)"),
}
SERVO_PARAM_NAMES: tuple[str, ...] = tuple(SERVO_KEYS)
SERVO_BOUNDS: dict[str, tuple[float, float]] = {name: key.bounds for name, key in SERVO_KEYS.items()}

FRICTION_LAWS = ("stick", "tanh")
MODES = ("geometry", "lumped")


def load(path: str | Path) -> dict[str, Any]:
    """Read and validate a parameter file: ``{"model": {...}, "params": {...}, "fit": {...}}``."""
    path = Path(path)
    doc = read_toml(path, ConfigError, "parameter file")
    model = _table(doc, "model", path)
    fit = _table(doc, "fit", path)
    params = validate_params(_table(doc, "params", path), where=str(path))
    _check_model(model, path)
    out = {"model": model, "params": params, "fit": fit}
    if "servo" in doc:
        out["servo"] = validate_servo(_table(doc, "servo", path), where=str(path))
    return out


# A parameter file or manifest is a few kB; a larger one is not one (a log, an image, a device).
MAX_TOML_BYTES = 1 << 20


def read_toml(path: Path, error: type[Exception], what: str) -> dict:
    """Parse a TOML file; every failure is ``error`` with one line naming the file."""
    try:
        with path.open("rb") as fh:
            data = fh.read(MAX_TOML_BYTES + 1)
        if len(data) > MAX_TOML_BYTES:
            raise error(f"{path}: larger than {MAX_TOML_BYTES >> 20} MiB: not a {what}")
        return tomllib.loads(data.decode("utf-8"))
    except FileNotFoundError:
        raise error(f"{path}: {what} not found") from None
    except UnicodeDecodeError as exc:
        raise error(f"{path}: not a text file (a {what} is UTF-8 TOML; byte {exc.start} is not UTF-8)") from None
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{path}: not valid TOML ({exc})") from None
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror})") from None


def dump(
    path: str | Path,
    params: dict[str, float],
    model: dict[str, Any] | None = None,
    fit: dict[str, Any] | None = None,
    servo: dict[str, float] | None = None,
) -> None:
    """Write a parameter file; ``params`` (and ``servo``) are validated first, so a bad value
    never reaches disk."""
    path = Path(path)
    clean = validate_params(params, where=str(path))
    model = dict(model or {})
    _check_model(model, path)
    doc: dict[str, Any] = {"model": model, "params": clean}
    if servo is not None:
        doc["servo"] = validate_servo(servo, where=str(path))
    if fit:
        doc["fit"] = _toml_safe(fit)
    try:
        path.write_text(tomli_w.dumps(doc))
    except OSError as exc:
        raise ConfigError(f"{path}: cannot write ({exc.strerror})") from None


def validate_params(params: dict[str, Any], where: str = "params") -> dict[str, float]:
    """Check names and values; return ``{name: float}`` in Contract 1's order."""
    out: dict[str, float] = {}
    for key, value in params.items():
        if key not in PARAM_DEFAULTS:
            raise ConfigError(f"{where}: [params] {key}: unknown parameter (known: {', '.join(PARAM_NAMES)})")
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: [params] {key}: expected a number, got {value!r}")
        if not math.isfinite(value):
            raise ConfigError(f"{where}: [params] {key}: value must be finite, got {value!r}")
        lo, hi = PARAM_BOUNDS[key]
        if not lo <= value <= hi:
            raise ConfigError(f"{where}: [params] {key}: {value!r} is outside its physical range [{lo:g}, {hi:g}]")
        out[key] = float(value)
    return {name: out[name] for name in PARAM_NAMES if name in out}


def validate_servo(servo: dict[str, Any], where: str = "servo") -> dict[str, float]:
    """Check a ``[servo]`` table: known names, finite numbers within their domains; a key with a
    default (the gear play's) may be left out and is then its default."""
    for key in servo:
        if key not in SERVO_BOUNDS:
            raise ConfigError(f"{where}: [servo] {key}: unknown servo parameter (known: {', '.join(SERVO_PARAM_NAMES)})")
    out: dict[str, float] = {}
    for key in SERVO_PARAM_NAMES:
        value = servo.get(key, SERVO_KEYS[key].default)
        if value is None:
            raise ConfigError(f"{where}: [servo] {key}: required (a servo model has all of "
                              f"{', '.join(k for k, v in SERVO_KEYS.items() if v.default is None)})")
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ConfigError(f"{where}: [servo] {key}: expected a finite number, got {value!r}")
        lo, hi = SERVO_BOUNDS[key]
        if not (lo < value if key == "time_constant" else lo <= value) or value > hi:
            raise ConfigError(f"{where}: [servo] {key}: must be in {'(' if key == 'time_constant' else '['}"
                              f"{lo:g}, {hi:g}], got {value!r}")
        out[key] = float(value)
    return out


def full_vector(params: dict[str, float]) -> list[float]:
    """All parameters in Contract 1's order, defaults filled in; ``motor_inertia`` is required."""
    if "motor_inertia" not in params:
        raise ConfigError("[params] motor_inertia: required")
    return [float(params.get(name, default)) for name, default in PARAM_DEFAULTS.items()]


def _table(doc: dict, name: str, path: Path) -> dict:
    table = doc.get(name, {})
    if not isinstance(table, dict):
        raise ConfigError(f"{path}: [{name}] must be a table")
    return table


def _check_model(model: dict, path: Path) -> None:
    friction = model.get("friction", "stick")
    if friction not in FRICTION_LAWS:
        raise ConfigError(f"{path}: [model] friction: expected one of {FRICTION_LAWS}, got {friction!r}")
    mode = model.get("mode", "geometry")
    if mode not in MODES:
        raise ConfigError(f"{path}: [model] mode: expected one of {MODES}, got {mode!r}")


def _toml_safe(value: Any) -> Any:
    """TOML has no null: drop None; turn NumPy scalars and tuples into plain types."""
    if isinstance(value, dict):
        return {str(k): _toml_safe(v) for k, v in value.items() if v is not None}
    if isinstance(value, (list, tuple)):
        return [_toml_safe(v) for v in value if v is not None]
    if hasattr(value, "item"):  # NumPy scalars
        return value.item()
    return value
