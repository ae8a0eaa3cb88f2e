"""TEST ORACLE: the thesis method in plain Python and SciPy, with no Rust: the bench's baseline.

This is what a straightforward port of the thesis's MATLAB/Simulink pipeline looks like:
a fixed-step Bogacki–Shampine integrator (Simulink's ``ode3``) written as a Python loop, and
``scipy.optimize.least_squares(method="lm")`` with SciPy's own forward-difference Jacobian
(one simulation per probe, one after the other), in the same alternating (I, B) / F scheme as
:mod:`admittance.thesis.alternating`. The scheme is shared so the bench compares only what differs:
the simulator and how the Jacobian's simulations are run.

Why a hand-written ode3 rather than ``scipy.integrate.solve_ivp``: the thesis used a fixed
step, and an adaptive solver would both differ numerically and spend most of its time in
step-size control around the steep tanh friction.
"""

from __future__ import annotations

import math

import numpy as np

from admittance.thesis import alternating as thesis

STEP = thesis.MAX_STEP


def simulate_ode3(
    t: np.ndarray,
    x0: tuple[float, float],
    inertia: float,
    damping: float,
    friction: float,
    gravity_torque: float,
    tau: np.ndarray | None = None,
    tanh_k: float = thesis.TANH_K,
    max_step: float = STEP,
) -> np.ndarray:
    """θ at the sample times of ``I·θ'' = τ − G·sin θ − B·θ' − F·tanh(k·θ')``, fixed-step ode3.

    Between samples the interval is split into equal steps no longer than ``max_step``; the
    applied torque is interpolated linearly in (t, tau).
    """
    inv_i = 1.0 / max(inertia, 1e-9)

    def accel(time: float, theta: float, omega: float) -> float:
        applied = 0.0 if tau is None else float(np.interp(time, t, tau))
        drag = damping * omega + friction * math.tanh(tanh_k * omega)
        return (applied - gravity_torque * math.sin(theta) - drag) * inv_i

    theta, omega = float(x0[0]), float(x0[1])
    out = np.empty(len(t))
    out[0] = theta
    for i in range(1, len(t)):
        n = max(1, math.ceil((t[i] - t[i - 1]) / max_step - 1e-9))
        h = (t[i] - t[i - 1]) / n
        time = float(t[i - 1])
        for _ in range(n):
            k1x, k1v = omega, accel(time, theta, omega)
            k2x, k2v = omega + 0.5 * h * k1v, accel(time + 0.5 * h, theta + 0.5 * h * k1x, omega + 0.5 * h * k1v)
            k3x, k3v = omega + 0.75 * h * k2v, accel(time + 0.75 * h, theta + 0.75 * h * k2x, omega + 0.75 * h * k2v)
            theta += h * (2 * k1x + 3 * k2x + 4 * k3x) / 9.0
            omega += h * (2 * k1v + 3 * k2v + 4 * k3v) / 9.0
            time += h
        out[i] = theta
    return out


def ode3_simulator(trial, x0: tuple[float, float], tanh_k: float = thesis.TANH_K, max_step: float = STEP):
    """A :data:`thesis.BatchSimulator` that runs :func:`simulate_ode3` row by row."""

    def simulate(rows: np.ndarray) -> np.ndarray:
        return np.array([
            simulate_ode3(trial.t, x0, i, b, f, trial.gravity_torque, trial.tau, tanh_k, max_step)
            for i, b, f in rows
        ])

    return simulate


def fit_dataset(dataset, cycles: int = thesis.CYCLES, x0: str = "rest", progress=None) -> list[thesis.ThesisRow]:
    """The thesis's per-trial alternating fit, all in Python: one row per trial."""
    return thesis.fit_dataset(
        dataset, cycles=cycles, x0=x0, simulator_factory=ode3_simulator,
        batched_jacobian=False, progress=progress,
    )
