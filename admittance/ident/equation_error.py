"""Equation-error initialiser: smoothed derivatives and a bounded linear least squares.

Output-error fitting (``fit.py``) is accurate but local: started far from the answer, a swing
simulated with the wrong period drifts out of phase and the cost has other minima. The
equation error, ``I·θ'' + B·θ' + F·sgn θ' = τ − G·sin θ``, is *linear* in the unknowns, so one
least squares gives a start without any guess.

Derivatives of a noisy angle are the weak point (identification-anchors.md §5: plain finite
differences of mrad noise give accelerations noisier than the whole friction torque). So the
angle is first put on a uniform grid (the sampling may be non-uniform) and then differentiated
by a Savitzky–Golay filter (smoothing.py): a local cubic fit over ~0.1 s, which keeps the pendulum's swing
(periods ≥ 0.5 s) and removes the sensor noise. Samples near zero speed are left out of the
regression, because there the sign of θ' is unknown and a sticking joint breaks the equation.
The parameters are bounded (I > 0, B ≥ 0, F ≥ 0) by an exact small bounded least squares: an
unbounded solve readily returns a negative friction on short or poorly excited data.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from admittance.errors import DataError
from admittance.formats.dataset import TrialData
from admittance.ident.model import INDEX, default_vector
from admittance.ident.smoothing import nonneg_lstsq, savgol

SMOOTH_WINDOW_S = 0.1  # s: well below a pendulum period, well above the sample interval
POLY_ORDER = 3
MIN_SPEED_FRACTION = 0.05  # of the trial's peak speed: below it the sign of ω is unreliable


@dataclass(frozen=True)
class Derivatives:
    """A trial on a uniform grid: angle, velocity, acceleration and the applied torque."""

    t: np.ndarray
    theta: np.ndarray
    omega: np.ndarray
    alpha: np.ndarray
    tau: np.ndarray | None


def derivatives(trial: TrialData, window_s: float = SMOOTH_WINDOW_S) -> Derivatives:
    """Smoothed θ, θ', θ'' of a trial on a uniform grid at its median sample interval."""
    t = trial.t
    dt = float(np.median(np.diff(t)))
    grid = t[0] + dt * np.arange(int(np.floor((t[-1] - t[0]) / dt)) + 1)
    theta = np.interp(grid, t, trial.theta)
    tau = None if trial.tau is None else np.interp(grid, t, trial.tau)
    window = _odd_window(window_s / dt, grid.size)
    if window <= POLY_ORDER:
        # Too few samples to smooth: central differences are all that is left.
        omega = np.gradient(theta, dt)
        return Derivatives(grid, theta, omega, np.gradient(omega, dt), tau)
    smooth = [savgol(theta, window, POLY_ORDER, deriv, dt) for deriv in (0, 1, 2)]
    return Derivatives(grid, *smooth, tau)


def _odd_window(samples: float, n: int) -> int:
    window = max(int(round(samples)) | 1, POLY_ORDER + 2 | 1)
    limit = n if n % 2 else n - 1
    return min(window, limit)


def initial_state(trial: TrialData) -> tuple[float, float]:
    """(θ0, ω0) from the smoothed start of the trial: the output-error fit's first guess."""
    d = derivatives(trial)
    return float(d.theta[0]), float(d.omega[0])


def initial_states(trials: Sequence[TrialData]) -> np.ndarray:
    return np.array([initial_state(tr) for tr in trials], dtype=float).reshape(len(trials), 2)


def initial_state_starts(trials: Sequence[TrialData]) -> list[np.ndarray]:
    """Starting points for fitting initial states: the smoothed start, the first sample at
    rest, and the first sample with the smoothed velocity (a release is often at rest, and the
    smoothing window then blurs a sharp start)."""
    smooth = initial_states(trials)
    first = np.array([tr.theta[0] for tr in trials], dtype=float)
    at_rest = np.column_stack([first, np.zeros(len(trials))])
    raw = np.column_stack([first, smooth[:, 1]])
    return [smooth, at_rest, raw]


def fit_equation_error(trials: Sequence[TrialData], mode: str) -> tuple[np.ndarray, float]:
    """Base-model parameters (sim units, see model.py) and the lumped torque scale.

    Geometry mode solves ``I_m·α + B·ω + F·sgn ω = τ − G·sin θ − I_load·α`` for (I_m, B, F).
    Lumped mode solves ``α = κ·τ − Γ·sin θ − β·ω − φ·sgn ω`` for (Γ, β, φ[, κ]) and returns
    them scaled as the simulator needs them (I = 1/Γ, torques / Γ, tau scale κ/Γ).
    """
    with_tau = any(tr.tau is not None for tr in trials)
    rows, targets = [], []
    for trial in trials:
        a, y = _regression_rows(derivatives(trial), trial, mode, with_tau)
        rows.append(a)
        targets.append(y)
    a = np.vstack(rows)
    y = np.concatenate(targets)
    if a.shape[0] < a.shape[1] * 3:
        raise DataError("too little motion to identify the model (the trials barely move)")
    scale = np.maximum(np.abs(a).max(axis=0), 1e-12)  # column scaling: the unknowns differ by 1e3
    lower = np.array([1e-9] + [0.0] * (a.shape[1] - 1))
    sol = nonneg_lstsq(a / scale, y, lower) / scale
    return _to_sim_vector(sol, mode, with_tau)


def _regression_rows(d: Derivatives, trial: TrialData, mode: str, with_tau: bool, return_keep: bool = False):
    speed = np.abs(d.omega)
    keep = speed > MIN_SPEED_FRACTION * max(speed.max(), 1e-9)
    sgn = np.sign(d.omega)
    tau = np.zeros_like(d.theta) if d.tau is None else d.tau
    if mode == "lumped":
        cols = [-np.sin(d.theta), -d.omega, -sgn] + ([tau] if with_tau else [])
        target = d.alpha
    else:
        cols = [d.alpha, d.omega, sgn]
        target = tau - trial.gravity_torque * np.sin(d.theta) - trial.load_inertia * d.alpha
    a = np.column_stack(cols)[keep]
    if return_keep:
        return a, target[keep], keep
    return a, target[keep]


def _to_sim_vector(sol: np.ndarray, mode: str, with_tau: bool) -> tuple[np.ndarray, float]:
    vec = default_vector()
    if mode == "lumped":
        gamma = max(sol[0], 1e-9)
        vec[INDEX["motor_inertia"]] = 1.0 / gamma
        vec[INDEX["damping"]] = sol[1] / gamma
        vec[INDEX["coulomb"]] = sol[2] / gamma
        tau_scale = sol[3] / gamma if with_tau else 1.0
        return vec, float(max(tau_scale, 1e-12))
    vec[INDEX["motor_inertia"]] = sol[0]
    vec[INDEX["damping"]] = sol[1]
    vec[INDEX["coulomb"]] = sol[2]
    return vec, 1.0


# Each effect's equation-error columns: (parameter, column, lower bound). A column is the
# effect's torque per unit of its parameter, on the left of I_m·α + B·ω + F·sgn ω + … = τ − G·sin θ.
def _effect_columns(effect: str, d: Derivatives, trial: TrialData, shape: dict, mode: str):
    sgn = np.sign(d.omega)
    tau = np.zeros_like(d.theta) if d.tau is None else d.tau
    gravity = 1.0 if mode == "lumped" else trial.gravity_torque
    if effect == "quadratic_drag":
        return [("quadratic_drag", d.omega * np.abs(d.omega), 0.0)]
    if effect == "stribeck":
        v_s = shape.get("stribeck_velocity", 0.1)
        return [("stribeck_torque", np.exp(-((d.omega / v_s) ** 2)) * sgn, 0.0)]
    if effect == "asymmetric_coulomb":
        return [("coulomb_asym", np.ones_like(d.theta), -np.inf)]
    if effect == "load_dependent_coulomb":
        return [("load_coulomb", np.abs(gravity * np.sin(d.theta) - tau) * sgn, 0.0)]
    if effect == "angle_offset":
        return [("angle_offset", -gravity * np.cos(d.theta), -np.inf)]
    if effect == "cogging":
        p = shape.get("cogging_period", 2.0)
        return [("cogging_sin", np.sin(p * d.theta), -np.inf), ("cogging_cos", np.cos(p * d.theta), -np.inf)]
    if effect == "time_delay":
        return [("time_delay", np.gradient(tau, d.t), 0.0)]
    if effect == "torque_bias":
        return [("torque_bias", np.ones_like(d.theta), -np.inf)]
    if effect == "torque_gain":
        return [("torque_gain", -tau, 0.05)]
    if effect == "spring":  # k·(θ − n) = k·θ − (k·n)
        return [("spring_stiffness", d.theta, 0.0), ("spring_offset_torque", -np.ones_like(d.theta), -np.inf)]
    if effect == "friction_ripple":
        p = shape.get("friction_ripple_period", 3.0)
        return [("ripple_sin", np.sin(p * d.theta) * sgn, -np.inf), ("ripple_cos", np.cos(p * d.theta) * sgn, -np.inf)]
    return []


def effect_start(trials: Sequence[TrialData], mode: str, effect: str, shape: dict | None = None,
                 with_cost: bool = False):
    """Base parameters and ``effect``'s parameters (sim units) from one linear least squares
    with the effect's columns beside the base model's, or None when the data cannot carry it.

    The output-error fit of the current model can sit in a basin where the base parameters
    have absorbed the missing effect (on three long swings with quadratic drag: damping 6×
    too high, Coulomb 17× too low); refitted from there with the effect, LM stops half way.
    The equation error does not care where the current fit is: with the effect's column in
    the regression it splits the dissipation between the terms from the data alone."""
    shape = shape or {}
    with_tau = any(tr.tau is not None for tr in trials)
    rows, targets, names, lower = [], [], None, None
    for trial in trials:
        d = derivatives(trial)
        a, y, keep = _regression_rows(d, trial, mode, with_tau, return_keep=True)
        extra = _effect_columns(effect, d, trial, shape, mode)
        if not extra:
            return (None, np.inf) if with_cost else None
        cols = [c[keep] * (-1.0 if mode == "lumped" else 1.0) for _, c, _ in extra]
        if effect == "torque_gain":  # the gain multiplies τ, which sits in the target
            y = y - (d.tau[keep] if d.tau is not None else 0.0)
        rows.append(np.column_stack([a, *cols]))
        targets.append(y)
        names = [n for n, _, _ in extra]
        lower = [lo for _, _, lo in extra]
    a = np.vstack(rows)
    y = np.concatenate(targets)
    if a.shape[0] < a.shape[1] * 3:
        return (None, np.inf) if with_cost else None
    n_base = a.shape[1] - len(names)
    scale = np.maximum(np.abs(a).max(axis=0), 1e-12)
    bounds = np.array([1e-9] + [0.0] * (n_base - 1) + [lo * s if np.isfinite(lo) else -np.inf
                                                        for lo, s in zip(lower, scale[n_base:])])
    sol = nonneg_lstsq(a / scale, y, bounds) / scale
    cost = float(np.sum((a @ sol - y) ** 2))
    vec, _ = _to_sim_vector(sol[:n_base], mode, with_tau)
    out = {n: float(vec[INDEX[n]]) for n in ("motor_inertia", "damping", "coulomb")}
    gamma = sol[0] if mode == "lumped" else 1.0
    values = dict(zip(names, sol[n_base:] / (gamma if mode == "lumped" else 1.0)))
    if "cogging_sin" in values:
        a_, b_ = values.pop("cogging_sin"), values.pop("cogging_cos")
        values.update(cogging_amplitude=float(np.hypot(a_, b_)), cogging_phase=float(np.arctan2(b_, a_)),
                      cogging_period=float(shape.get("cogging_period", 2.0)))
    if "ripple_sin" in values:
        a_, b_ = values.pop("ripple_sin"), values.pop("ripple_cos")
        values.update(friction_ripple_amplitude=float(np.hypot(a_, b_)), friction_ripple_phase=float(np.arctan2(b_, a_)),
                      friction_ripple_period=float(shape.get("friction_ripple_period", 3.0)))
    if "spring_offset_torque" in values:
        torque = values.pop("spring_offset_torque")
        stiffness = values["spring_stiffness"]
        values["spring_neutral"] = float(torque / stiffness) if stiffness > 0 else 0.0
    if effect == "stribeck":
        values["stribeck_velocity"] = float(shape.get("stribeck_velocity", 0.1))
    out.update({k: float(v) for k, v in values.items()})
    good = all(np.isfinite(v) for v in out.values())
    if with_cost:
        return (out, cost) if good else (None, np.inf)
    return out if good else None
