"""Synthetic pendulum datasets in the contract's folder format, with known truth.

Thesis-like by default (section 2.1): a 45.6 cm, 40.2 g rod and a 103.4 g bob at 20–40 cm on an
MX-64 (the thesis's averages, I ≈ 0.0147 kg·m², B ≈ 0.035 N·m·s/rad, F ≈ 0.084 N·m),
released from about ±90° (alternately cw and ccw), sampled at 120 Hz with optional jitter and
OptiTrack-like Gaussian noise (~2 mrad, white or AR(1)-correlated). Any candidate effect can be injected, *undeclared*:
the manifest never mentions it, only ``truth.json`` (beside the manifest, ignored by
``identify``) records what was simulated, so a test can check what the fit found.

The data are simulated with the same Rust plant the fit uses, but at a 10× finer substep
(1e-4 s against 1e-3 s), so the fit does not get its own discretisation back for free.

Torque-driven trials (``with_torque``) start at rest near the bottom and are pushed by a
scripted "hand": a sum of three smooth sinusoids (0.3–1.2 Hz) with a soft start. The recorded
``tau`` column is what a force sensor would report; ``torque_gain``, ``torque_bias`` and
``time_delay`` act on it exactly as Contract 1 defines them: the sensor records
(τ_true + bias) / gain, which the plant turns back into τ_true.

Torque-ramp trials (``ramps``) are the thesis's breakaway test (section 2.3, table 3.1): the
joint at rest at the bottom, a torque growing linearly from zero (cw positive, ccw negative) to
:data:`RAMP_PEAK` times the true breakaway level (Coulomb plus any Stribeck excess) over the
trial, so ``admittance breakaway`` can be tried on a known truth.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import tomli_w

from admittance.errors import ConfigError
from admittance.formats.dataset import load_geometry
from admittance.ident.model import EFFECTS, vector_from
from admittance.formats.paramfile import PARAM_NAMES

MX64 = {"motor_inertia": 0.0147, "damping": 0.035, "coulomb": 0.084}
ROD = {"mass": 0.0402, "length": 0.456}
BOB = {"mass": 0.1034}
GENERATION_STEP = 1e-4  # s: 10× finer than the fit's substep
RAMP_PEAK = 2.5  # a ramp ends at this many times the breakaway torque: it breaks away at 40 % of the trial

# What ``--effect NAME=VALUE`` sets for an effect name: its main parameter, plus companions
# that make the effect visible in a pendulum drop (a Stribeck velocity, a cogging period).
EFFECT_MAIN = {
    "stribeck": ("stribeck_torque", {"stribeck_velocity": 0.15}),
    "asymmetric_coulomb": ("coulomb_asym", {}),
    "load_dependent_coulomb": ("load_coulomb", {}),
    "angle_offset": ("angle_offset", {}),
    "quadratic_drag": ("quadratic_drag", {}),
    "cogging": ("cogging_amplitude", {"cogging_period": 8.0, "cogging_phase": 0.4}),
    "time_delay": ("time_delay", {}),
    "torque_bias": ("torque_bias", {}),
    "torque_gain": ("torque_gain", {}),
    "spring": ("spring_stiffness", {"spring_neutral": 0.2}),
    "friction_ripple": ("friction_ripple_amplitude", {"friction_ripple_period": 6.0, "friction_ripple_phase": 0.3}),
}


@dataclass
class SynthSpec:
    n_trials: int = 10
    duration: float = 8.0  # s per trial
    rate: float = 120.0  # Hz
    jitter: float = 0.0  # sampling-time jitter, as a fraction of the interval (< 0.45)
    noise: float = 0.002  # rad, Gaussian angle noise
    noise_correlation: float = 0.0  # AR(1) coefficient of the noise per sample (0: white)
    distances: tuple[float, ...] = (0.20, 0.25, 0.30, 0.35, 0.40)
    release: float = math.pi / 2  # rad from the vertical
    params: dict[str, float] = field(default_factory=lambda: dict(MX64))
    effects: dict[str, float] = field(default_factory=dict)  # effect or parameter name -> value
    with_torque: bool = False
    ramps: bool = False  # slow torque ramps from rest (the breakaway test) instead of drops
    geometry: bool = True  # False writes no [rod]/[bob]: a lumped-mode dataset
    seed: int = 0
    motor: str = "MX-64 (synthetic)"


def true_params(spec: SynthSpec) -> dict[str, float]:
    """The full set of simulated parameters: the motor's plus the injected effects'."""
    params = dict(spec.params)
    for name, value in spec.effects.items():
        if name in EFFECT_MAIN:
            main, companions = EFFECT_MAIN[name]
            for key, default in companions.items():
                params.setdefault(key, default)
            params[main] = float(value)
        elif name in PARAM_NAMES:
            params[name] = float(value)
        else:
            known = ", ".join([*EFFECT_MAIN, *PARAM_NAMES])
            raise ConfigError(f"unknown effect or parameter {name!r} (known: {known})")
    if params.get("torque_gain", 1.0) <= 0:
        raise ConfigError(f"torque_gain must be > 0, got {params['torque_gain']}")
    return params


def trial_plan(spec: SynthSpec) -> list[dict]:
    """Bob distance and direction per trial: distances cycle, directions alternate."""
    plan = []
    for i in range(spec.n_trials):
        distance = spec.distances[(i // 2) % len(spec.distances)]
        direction = "cw" if i % 2 == 0 else "ccw"
        repeat = sum(1 for p in plan if p["bob_distance"] == distance and p["direction"] == direction) + 1
        name = f"synth_{round(distance * 100):02d}cm_{direction}_{repeat}.csv"
        plan.append({"file": name, "bob_distance": distance, "direction": direction})
    return plan


def generate(out_dir: str | Path, spec: SynthSpec) -> Path:
    """Write ``manifest.toml``, one CSV per trial and ``truth.json`` into ``out_dir``."""
    from admittance import _rtcore

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(spec.seed)
    params = true_params(spec)
    row = vector_from(params)[None, :]
    plan = trial_plan(spec)
    for entry in plan:
        t = _sample_times(spec, rng)
        sign = 1.0 if entry["direction"] == "cw" else -1.0
        tau = _driving_torque(spec, t, rng, entry["bob_distance"], sign, params)
        inertia, gravity = load_geometry(ROD, BOB, entry["bob_distance"])
        theta0 = 0.0 if tau is not None else sign * (spec.release + rng.uniform(-0.08, 0.08))
        recorded_tau = None if tau is None else _recorded(tau, params)
        trial = _rtcore.Trial(t, recorded_tau, load_inertia=inertia, gravity_torque=gravity)
        x0 = np.array([[[theta0, 0.0]]])
        theta = _rtcore.simulate_batch([trial], row, x0, max_step=GENERATION_STEP)[0][0]
        theta = theta + _noise(rng, spec.noise, spec.noise_correlation, theta.size)
        entry["x0"] = [theta0, 0.0]
        _write_csv(out / entry["file"], t, theta, recorded_tau)
    _write_manifest(out, spec, plan)
    truth = {"params": params, "effects": sorted(n for n in spec.effects if n in EFFECTS),
             "trials": plan, "noise": spec.noise}
    (out / "truth.json").write_text(json.dumps(truth, indent=2))
    return out


def _recorded(tau: np.ndarray, params: dict[str, float]) -> np.ndarray:
    """What the torque sensor reports for a true torque ``tau``: Contract 1's correction
    gain·τ_measured − bias, inverted."""
    return (tau + params.get("torque_bias", 0.0)) / params.get("torque_gain", 1.0)


def _noise(rng: np.random.Generator, sigma: float, rho: float, n: int) -> np.ndarray:
    """Gaussian noise of standard deviation ``sigma``, AR(1)-correlated with coefficient ``rho``
    (motion capture filters its output, so its noise is rarely white)."""
    white = rng.normal(0.0, sigma * np.sqrt(1.0 - rho**2), n)
    out = np.empty(n)
    out[0] = rng.normal(0.0, sigma)
    for i in range(1, n):
        out[i] = rho * out[i - 1] + white[i]
    return out


def _sample_times(spec: SynthSpec, rng: np.random.Generator) -> np.ndarray:
    dt = 1.0 / spec.rate
    n = int(round(spec.duration * spec.rate)) + 1
    t = dt * np.arange(n)
    if spec.jitter > 0:
        jitter = min(spec.jitter, 0.45)
        t = t + dt * rng.uniform(-jitter, jitter, n)
        t[0] = 0.0
    return t


def _driving_torque(spec: SynthSpec, t: np.ndarray, rng: np.random.Generator, distance: float, sign: float,
                    params: dict[str, float]) -> np.ndarray | None:
    """The true torque on the horn of one trial: a ramp, a hand, or none (a free drop)."""
    if spec.ramps:
        return sign * breakaway_level(params) * RAMP_PEAK * (t / t[-1])
    return _hand_torque(t, rng, distance) if spec.with_torque else None


def breakaway_level(params: dict[str, float]) -> float:
    """The torque at which a joint at rest at the bottom starts to move: Coulomb plus the
    Stribeck excess (gravity is zero there)."""
    return params.get("coulomb", 0.0) + params.get("stribeck_torque", 0.0)


def _hand_torque(t: np.ndarray, rng: np.random.Generator, distance: float) -> np.ndarray:
    """A person pushing the pendulum: three sinusoids, amplitude ~0.6 of the gravity torque."""
    _, gravity = load_geometry(ROD, BOB, distance)
    tau = np.zeros_like(t)
    for freq in rng.uniform(0.3, 1.2, 3):
        tau += rng.uniform(0.15, 0.3) * gravity * np.sin(2 * math.pi * freq * t + rng.uniform(0, 2 * math.pi))
    ramp = np.clip(t / 0.5, 0.0, 1.0)
    return tau * ramp**2


def _write_csv(path: Path, t: np.ndarray, theta: np.ndarray, tau: np.ndarray | None) -> None:
    cols = [t, theta] + ([tau] if tau is not None else [])
    header = "t,theta" + (",tau" if tau is not None else "")
    np.savetxt(path, np.column_stack(cols), delimiter=",", header=header, comments="", fmt="%.9g")


def _write_manifest(out: Path, spec: SynthSpec, plan: list[dict]) -> None:
    manifest: dict = {"motor": spec.motor}
    if spec.geometry:
        manifest["rod"] = dict(ROD)
        manifest["bob"] = dict(BOB)
    manifest["trials"] = [{k: e[k] for k in ("file", "bob_distance", "direction")} for e in plan]
    (out / "manifest.toml").write_text(tomli_w.dumps(manifest))


def parse_effect_args(items: list[str] | None) -> dict[str, float]:
    """``["stribeck=0.03", ...]`` → ``{"stribeck": 0.03}``; ConfigError on a malformed item."""
    effects: dict[str, float] = {}
    for item in items or []:
        name, sep, value = item.partition("=")
        try:
            number = float(value)
        except ValueError:
            number = math.nan
        if not sep or not math.isfinite(number):
            raise ConfigError(f"--effect {item!r}: expected NAME=NUMBER, e.g. stribeck=0.03")
        effects[name.strip()] = number
    true_params(SynthSpec(effects=effects))  # validates the names
    return effects


