"""TEST ORACLE: pendulum data from an integrator that shares nothing with the fit.

``identify`` fits with the Rust plant (semi-implicit Euler, 1 ms substeps, the stick law as a
per-step clip). Data made by that same code at a finer step would still hand the fit its own
discretisation and its own reading of Contract 1. So this module writes the model a third time
(after the Rust plant and the oracle ``reference.simulate_reference``), with another scheme:

- SciPy's ``solve_ivp`` (DOP853, adaptive, rtol 1e-10) between friction events;
- Coulomb friction as a *switching* system, not a clip: while sliding, friction is
  −sgn(ω)·level; an event stops the integration where ω crosses 0; there the joint sticks if the
  static level holds the drive (a second event ends the stick when the drive outgrows it, e.g.
  under a driven torque), else it slides on the other way;
- "unnamed" effects the library has no name for (backlash, Dahl presliding, position-dependent
  damping, a speed-dependent ripple, a cable spring, friction that warms up), some with their own
  states, integrated with a stiff solver (LSODA);
- sensor noise the fit does not assume: encoder quantisation, AR(1)-coloured noise, outliers.

It is a test and bench helper only (bench/identify_vs_thesis.py imports it too). It writes the
contract's folder format, so ``load_dataset`` reads it like any recording; ``truth.json``
beside the manifest records what was simulated.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import tomli_w
from scipy.integrate import solve_ivp

from admittance.ident.synthetic import EFFECT_MAIN

GRAVITY = 9.80665
ROD = {"mass": 0.0402, "length": 0.456}
BOB = {"mass": 0.1034}
MX64 = {"motor_inertia": 0.0147, "damping": 0.035, "coulomb": 0.084}
RTOL, ATOL = 1e-10, 1e-12

# Contract 1's parameters with their "off" values: the library effects the oracle reproduces.
LIBRARY_DEFAULTS = {
    "coulomb_asym": 0.0, "stribeck_torque": 0.0, "stribeck_velocity": 0.1, "load_coulomb": 0.0,
    "angle_offset": 0.0, "quadratic_drag": 0.0, "cogging_amplitude": 0.0, "cogging_period": 0.0,
    "cogging_phase": 0.0, "time_delay": 0.0, "torque_bias": 0.0, "torque_drift": 0.0, "torque_gain": 1.0,
    "spring_stiffness": 0.0, "spring_neutral": 0.0, "friction_ripple_amplitude": 0.0,
    "friction_ripple_period": 0.0, "friction_ripple_phase": 0.0,
}
# What an effect name sets (main parameter, companions): the same names as the synthetic
# generator's, so the two sources of test data inject the same effects. (Names only: the physics
# below is written independently.)
LIBRARY_MAIN = EFFECT_MAIN
# Effects with no library name, each a physically motivated torque (the value is its size):
UNNAMED = (
    "backlash",  # rad of half-gap between the gear train (armature, friction) and the load
    "dahl",  # presliding: friction builds up over this deflection (rad) instead of jumping
    "position_damping",  # N·m·s/rad at θ = 1 rad: damping growing as θ² (a grease pocket)
    "speed_ripple",  # N·m·s/rad: a ripple A·|ω|·sin(5.3·θ + 0.7) that grows with speed
    "friction_warmup",  # fraction by which the Coulomb level falls over a trial (grease warming up)
    "eccentric_encoder",  # rad: the encoder reads θ + e·sin(θ + 0.5) (a magnet off the axis)
)


@dataclass
class OracleSpec:
    n_trials: int = 6
    duration: float = 5.0
    rate: float = 120.0
    distances: tuple[float, ...] = (0.20, 0.25, 0.30, 0.35, 0.40)
    release: float = math.pi / 2
    params: dict = field(default_factory=lambda: dict(MX64))
    effect: str = ""  # a library or an unnamed effect name ("" = clean)
    size: float = 0.0
    with_torque: bool = False
    mixed: bool = False  # with_torque: every other trial a free swing (released from the side, no tau)
    # sensor
    noise: float = 0.002  # rad, Gaussian
    noise_correlation: float = 0.0  # AR(1)
    ticks: int = 0  # encoder ticks per revolution (0: not quantised)
    declare_ticks: bool = False  # write encoder_ticks into the manifest
    outliers: float = 0.0  # fraction of samples with a 20σ spike
    seed: int = 0


def library_params(spec: OracleSpec) -> dict:
    p = {**LIBRARY_DEFAULTS, **spec.params}
    if spec.effect in LIBRARY_MAIN:
        main, companions = LIBRARY_MAIN[spec.effect]
        for k, v in companions.items():
            p[k] = v
        p[main] = spec.size
    return p


def load_of(distance: float) -> tuple[float, float]:
    inertia = ROD["mass"] * ROD["length"] ** 2 / 3 + BOB["mass"] * distance**2
    gravity = ROD["mass"] * GRAVITY * ROD["length"] / 2 + BOB["mass"] * GRAVITY * distance
    return inertia, gravity


class _Plant:
    """The library model with an optional unnamed extra, as functions of (t, θ, ω)."""

    def __init__(self, p: dict, inertia_load: float, gravity: float, tau_fn, effect: str, size: float):
        self.p, self.gravity, self.tau_fn = p, gravity, tau_fn
        self.inertia = p["motor_inertia"] + inertia_load
        self.effect, self.size = effect, size

    def applied(self, t: float) -> float:
        if self.tau_fn is None:
            return 0.0
        p = self.p
        return p["torque_gain"] * self.tau_fn(t - p["time_delay"]) - p["torque_bias"] - p["torque_drift"] * t

    def drive(self, t: float, theta: float) -> tuple[float, float]:
        """(velocity-independent torque, load torque on the gearbox)."""
        p = self.p
        tau = self.applied(t)
        g = self.gravity * math.sin(theta - p["angle_offset"])
        cog = p["cogging_amplitude"] * math.sin(p["cogging_period"] * theta + p["cogging_phase"])
        spring = p["spring_stiffness"] * (theta - p["spring_neutral"])
        return tau - g - cog - spring, g - tau

    def level(self, t: float, theta: float, omega: float, direction: float, load: float) -> float:
        p = self.p
        level = p["coulomb"] + direction * p["coulomb_asym"] + p["load_coulomb"] * abs(load)
        level += p["friction_ripple_amplitude"] * math.sin(p["friction_ripple_period"] * theta + p["friction_ripple_phase"])
        if p["stribeck_torque"]:
            level += p["stribeck_torque"] * math.exp(-((omega / p["stribeck_velocity"]) ** 2))
        if self.effect == "friction_warmup":
            level *= 1.0 - self.size * min(t / 5.0, 1.0)
        return max(level, 0.0)

    def dissipation(self, theta: float, omega: float) -> float:
        p = self.p
        out = p["damping"] * omega + p["quadratic_drag"] * omega * abs(omega)
        if self.effect == "position_damping":
            out += self.size * theta**2 * omega
        if self.effect == "speed_ripple":
            out += self.size * omega * math.sin(5.3 * theta + 0.7)
        return out


def _simulate_switching(plant: _Plant, t: np.ndarray, x0: tuple[float, float]) -> np.ndarray:
    """θ at ``t`` under exact stick-slip: slide phases and stick phases joined by events."""
    out = np.full(t.size, np.nan)
    t_now, theta, omega = float(t[0]), float(x0[0]), float(x0[1])
    t_end = float(t[-1])
    while t_now < t_end:
        if omega == 0.0:
            drive, load = plant.drive(t_now, theta)
            direction = math.copysign(1.0, drive) if drive else 0.0
            if abs(drive) <= plant.level(t_now, theta, 0.0, direction, load):
                t_now = _stick(plant, t, out, t_now, theta)
                continue
            sign = direction
        else:
            sign = math.copysign(1.0, omega)
        t_now, theta, omega = _slide(plant, t, out, t_now, theta, omega, sign)
    assert not np.isnan(out).any(), "the oracle left samples unset"
    return out


def _slide(plant: _Plant, t, out, t0, theta, omega, sign):
    def rhs(tk, y):
        drive, load = plant.drive(tk, y[0])
        friction = sign * plant.level(tk, y[0], y[1], sign, load)
        return [y[1], (drive - plant.dissipation(y[0], y[1]) - friction) / plant.inertia]

    def reversal(tk, y):
        return y[1] if tk > t0 else sign  # not at the very start, where ω may be exactly 0

    reversal.terminal, reversal.direction = True, -sign
    sol = solve_ivp(rhs, (t0, t[-1]), [theta, omega], method="DOP853", rtol=RTOL, atol=ATOL,
                    events=reversal, dense_output=True, max_step=0.01)
    t_stop = sol.t[-1]
    pick = (t >= t0) & (t <= t_stop)
    out[pick] = sol.sol(t[pick])[0]
    if sol.status == 1:  # ω reached 0
        return t_stop, float(sol.y[0, -1]), 0.0
    return t[-1] + 1.0, float(sol.y[0, -1]), float(sol.y[1, -1])


def _stick(plant: _Plant, t, out, t0, theta) -> float:
    """Held at θ until the drive outgrows the static friction level (never, on a free swing)."""
    if plant.tau_fn is None and plant.effect != "friction_warmup":
        out[t >= t0] = theta
        return t[-1] + 1.0

    def margin(tk, _y):
        drive, load = plant.drive(tk, theta)
        direction = math.copysign(1.0, drive) if drive else 0.0
        return abs(drive) - plant.level(tk, theta, 0.0, direction, load)

    margin.terminal, margin.direction = True, 1
    sol = solve_ivp(lambda tk, y: [0.0], (t0, t[-1]), [0.0], events=margin, max_step=0.002, rtol=RTOL, atol=ATOL)
    t_stop = sol.t[-1] if sol.status == 1 else t[-1] + 1.0
    out[(t >= t0) & (t <= t_stop)] = theta
    return t_stop + 1e-9 if sol.status == 1 else t_stop


def _simulate_stateful(plant: _Plant, t: np.ndarray, x0: tuple[float, float]) -> np.ndarray:
    """Backlash and Dahl friction: extra states, smooth but stiff (LSODA)."""
    p = plant.p
    size = plant.size
    if plant.effect == "dahl":
        # z: the bristle deflection; friction σ·z saturates at the Coulomb level after ~size rad.
        sigma = p["coulomb"] / size

        def rhs(tk, y):
            theta, omega, z = y
            drive, _ = plant.drive(tk, theta)
            dz = omega - sigma * abs(omega) * z / p["coulomb"]
            return [omega, (drive - plant.dissipation(theta, omega) - sigma * z) / plant.inertia, dz]

        y0 = [x0[0], x0[1], 0.0]
    else:  # backlash: the load (θ) and the gear train (φ: armature, damping, friction) share a gap
        inertia_load = plant.inertia - p["motor_inertia"]
        stiffness, contact_damping, eps, width = 200.0, 0.5, 2e-3, 2e-4

        def rhs(tk, y):
            theta, omega, phi, dphi = y
            gap = theta - phi
            # The dead zone ±size, its corners rounded over `width` (a smooth right-hand side
            # keeps the stiff solver's steps long): penetration beyond the gap on either side.
            inside = width * (np.logaddexp(0.0, (gap - size) / width) - np.logaddexp(0.0, (-gap - size) / width))
            engaged = 1.0 - 1.0 / (1.0 + math.exp(min((abs(gap) - size) / width, 50.0)))
            coupling = stiffness * inside + contact_damping * (omega - dphi) * engaged
            drive, _ = plant.drive(tk, theta)
            gear = coupling - p["damping"] * dphi - p["coulomb"] * math.tanh(dphi / eps)
            return [omega, (drive - coupling) / inertia_load, dphi, gear / p["motor_inertia"]]

        y0 = [x0[0], x0[1], x0[0] - size, x0[1]]
    sol = solve_ivp(rhs, (t[0], t[-1]), y0, method="LSODA", t_eval=t, rtol=1e-8, atol=1e-10, max_step=0.02)
    return sol.y[0]


def simulate(params: dict, load_inertia: float, gravity: float, t: np.ndarray, x0: tuple[float, float],
             tau=None) -> np.ndarray:
    """θ at ``t`` of the library model (``params``: Contract 1 names, defaults filled in) under a
    recorded torque ``tau`` (an array at ``t``, or None), by the switching integrator."""
    p = {**LIBRARY_DEFAULTS, **params}
    tau_fn = None if tau is None else (lambda tk: float(np.interp(tk, t, tau)))
    return _simulate_switching(_Plant(p, load_inertia, gravity, tau_fn, "", 0.0), np.asarray(t, float), x0)


def _hand_torque(t: np.ndarray, rng: np.random.Generator, gravity: float):
    freqs = rng.uniform(0.3, 1.2, 3)
    amps = rng.uniform(0.15, 0.3, 3) * gravity
    phases = rng.uniform(0, 2 * math.pi, 3)

    def tau(tk):
        ramp = min(max(tk / 0.5, 0.0), 1.0) ** 2
        return ramp * float(np.sum(amps * np.sin(2 * math.pi * freqs * tk + phases)))

    return tau


def _sensor(theta: np.ndarray, spec: OracleSpec, rng: np.random.Generator) -> np.ndarray:
    white = rng.normal(0.0, spec.noise * math.sqrt(1 - spec.noise_correlation**2), theta.size)
    noise = np.empty(theta.size)
    noise[0] = rng.normal(0.0, spec.noise)
    for i in range(1, theta.size):
        noise[i] = spec.noise_correlation * noise[i - 1] + white[i]
    out = theta + noise
    if spec.outliers > 0:
        hit = rng.random(theta.size) < spec.outliers
        out[hit] += rng.choice([-1.0, 1.0], hit.sum()) * 20 * max(spec.noise, 1e-3)
    if spec.ticks:
        step = 2 * math.pi / spec.ticks
        out = step * np.round(out / step)
    return out


def generate(out_dir: str | Path, spec: OracleSpec) -> Path:
    """A contract dataset in ``out_dir`` from the oracle; ``truth.json`` records the truth."""
    if spec.effect and spec.effect not in LIBRARY_MAIN and spec.effect not in UNNAMED:
        raise ValueError(f"unknown effect {spec.effect!r}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(spec.seed)
    params = library_params(spec)
    entries = []
    for i in range(spec.n_trials):
        distance = spec.distances[(i // 2) % len(spec.distances)]
        direction = "cw" if i % 2 == 0 else "ccw"
        name = f"oracle_{i:02d}_{round(distance * 100):02d}cm_{direction}.csv"
        inertia, gravity = load_of(distance)
        t = np.arange(int(round(spec.duration * spec.rate)) + 1) / spec.rate
        driven = spec.with_torque and not (spec.mixed and i % 2)
        tau_fn = _hand_torque(t, rng, gravity) if driven else None
        sign = 1.0 if direction == "cw" else -1.0
        theta0 = 0.0 if driven else sign * (spec.release + rng.uniform(-0.08, 0.08))
        plant = _Plant(params, inertia, gravity, tau_fn, spec.effect if spec.effect in UNNAMED else "", spec.size)
        simulate = _simulate_stateful if plant.effect in ("backlash", "dahl") else _simulate_switching
        theta = simulate(plant, t, (theta0, 0.0))
        if spec.effect == "eccentric_encoder":  # the sensor, not the joint: applied to the reading
            theta = theta + spec.size * np.sin(theta + 0.5)
        measured = _sensor(theta, spec, rng)
        cols = [t, measured]
        header = "t,theta"
        if tau_fn is not None:
            # what the sensor records: the plant sees gain·recorded − bias (Contract 1)
            cols.append(np.array([tau_fn(tk) for tk in t]))
            header += ",tau"
        np.savetxt(out / name, np.column_stack(cols), delimiter=",", header=header, comments="", fmt="%.10g")
        entries.append({"file": name, "bob_distance": distance, "direction": direction})
    manifest = {"motor": "MX-64 (oracle)", "rod": dict(ROD), "bob": dict(BOB), "trials": entries}
    if spec.declare_ticks and spec.ticks:
        manifest["encoder_ticks"] = spec.ticks
    (out / "manifest.toml").write_text(tomli_w.dumps(manifest))
    truth = {"params": params, "effect": spec.effect, "size": spec.size,
             "library": spec.effect in LIBRARY_MAIN, "noise": spec.noise, "ticks": spec.ticks}
    (out / "truth.json").write_text(json.dumps(truth, indent=2))
    return out
