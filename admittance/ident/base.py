"""The base model's fit, and the cross-validation set-up the effect search and the ladder share.

**The base fit** (:func:`fit_base`) starts from the equation error and, unless that already
leaves nothing but sensor noise, from a small grid over friction (:data:`FRICTION_GRID`):
each grid start runs a few LM iterations, the best end point is carried on. The equation error
cannot see a term the base model lacks and puts it somewhere: on a quadratic-drag set it put
the drag into damping and left the Coulomb level ten times too low, a local minimum the
output-error LM never left (training error 10 mrad; from the truth, 4.8).

**The search context** (:func:`search_context`) turns the fitting trials into cross-validation
units (crossval.py: whole trials, or time segments of a few long ones) and fits the base model
on them; ``identify`` and ``admittance ladder`` both start from it, so they judge effects on
the same units by the same rules.
"""

from __future__ import annotations

import numpy as np

from admittance.ident.crossval import Folds, make_folds, small_oscillation_period
from admittance.ident.equation_error import initial_state_starts
from admittance.ident.fit import FitResult, fit_initial_states_multi, fit_output_error, screen_starts
from admittance.ident.model import INDEX, Simulator
from admittance.ident.search import SearchContext, SearchSettings, nothing_left
from admittance.ident.angle_sensor import Sensor

# (Coulomb, damping) multipliers of the equation-error start.
FRICTION_GRID = ((3.0, 1.0), (10.0, 0.25), (0.3, 1.0), (3.0, 0.25))
GRID_ITERATIONS = 12  # LM iterations per grid start before the best one is finished


def fit_base(sim: Simulator, start: np.ndarray, free: tuple[str, ...], x0_starts: list[np.ndarray],
             sensor: Sensor, torque_scale: float, progress=None) -> tuple[FitResult, list[dict]]:
    """The base model on ``sim``'s trials; returns the fit and what each start reached."""
    # The starting states: the data's candidates scored under the equation-error model in one
    # batch, each trial taking its best, then refined (the joint LM refits them anyway).
    x0 = fit_initial_states_multi(sim, start, [screen_starts(sim, start, x0_starts)], tau_scale=sim.tau_scale,
                                  label="base fit").x0
    fit = fit_output_error(sim, start, free, x0, torque_scale=torque_scale, progress=progress, label="base fit")
    record = [{"start": "equation error", "rmse": fit.rmse}]
    if nothing_left(sim, fit, sensor):
        return fit, record
    level = max(start[INDEX["coulomb"]], 0.02 * torque_scale)
    best = fit
    for f_mult, b_mult in FRICTION_GRID:
        vector = start.copy()
        vector[INDEX["coulomb"]] = level * f_mult
        vector[INDEX["damping"]] = start[INDEX["damping"]] * b_mult
        trial = fit_output_error(sim, vector, free, x0, torque_scale=torque_scale, max_iter=GRID_ITERATIONS,
                                 progress=progress, label="base fit (friction grid)")
        record.append({"start": f"coulomb ×{f_mult:g}, damping ×{b_mult:g}", "rmse": trial.rmse})
        if trial.rmse < best.rmse * (1 - 1e-6):
            best = trial
    if best is not fit:
        best = fit_output_error(sim, best.vector, free, best.x0, torque_scale=torque_scale, progress=progress,
                                label="base fit")
        record.append({"start": "best grid start, finished", "rmse": best.rmse})
    return best, record


def search_context(sim: Simulator, base: FitResult, sensor: Sensor, torque_scale: float, settings: SearchSettings,
                   progress=None) -> tuple[SearchContext, FitResult] | None:
    """Units and folds over ``sim``'s trials, and the base model fitted on the units (None when
    no fold can be formed)."""
    folds = make_folds(sim.trials, base_period(sim, base))
    if folds is None:
        return None
    if folds.kind == "trials":
        units, base_units = sim, base
        x0_starts = initial_state_starts(folds.data)
    else:
        units = Simulator(folds.data, sim.mode, sim.friction, sim.max_step, base.tau_scale)
        x0_base = states_at_unit_starts(sim, base, folds)
        if progress:
            progress("base fit on the time segments")
        base_units = fit_output_error(units, base.vector, base.free, x0_base, torque_scale=torque_scale,
                                      progress=progress, label="base fit (segments)")
        x0_starts = [*initial_state_starts(folds.data), x0_base]
    ctx = SearchContext(units, folds, x0_starts, sensor, torque_scale, settings, progress, sim.trials)
    return ctx, base_units


def base_period(sim: Simulator, fit: FitResult) -> float:
    """The longest small-oscillation period of the fitted model over ``sim``'s trials (s)."""
    inertia = fit.vector[INDEX["motor_inertia"]]
    if sim.mode == "lumped":
        return small_oscillation_period([inertia], [1.0])
    return small_oscillation_period([inertia + tr.load_inertia for tr in sim.trials],
                                    [tr.gravity_torque for tr in sim.trials])


def states_at_unit_starts(sim: Simulator, fit: FitResult, folds: Folds) -> np.ndarray:
    """Each segment's initial state from the whole-trial fit (where the fit says the joint was)."""
    states = [o[0] for o in sim.with_tau_scale(fit.tau_scale).run(fit.vector[None, :], fit.x0[None, :, :],
                                                                  velocity=True)]
    return np.array([states[u.trial][u.start] for u in folds.units], dtype=float).reshape(-1, 2)


def torque_scale_of(dataset) -> float:
    """A typical torque of the problem (N·m; 1 in lumped sim units): sets finite-difference steps."""
    if dataset.mode != "geometry":
        return 1.0
    scale = float(np.mean([tr.gravity_torque for tr in dataset.trials]))
    return scale if scale > 0 else 1.0
