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
from admittance.ident.dataset import TrialData
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


def _regression_rows(d: Derivatives, trial: TrialData, mode: str, with_tau: bool):
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
