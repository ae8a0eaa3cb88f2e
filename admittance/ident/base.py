"""The base model's fit, and the cross-validation set-up the effect search and the ladder share.

**The base fit** (:func:`fit_base`) starts from the equation error and, unless that already
leaves nothing but sensor noise, from a small grid over friction (:data:`FRICTION_GRID`):
each grid start runs a few LM iterations, the best end point is carried on. The equation error
cannot see a term the base model lacks and puts it somewhere: on a quadratic-drag set it put
the drag into damping and left the Coulomb level ten times too low, a local minimum the
output-error LM never left (training error 10 mrad; from the truth, 4.8).

**Held at rest.** The equation error leaves out the samples near zero speed, so it never sees
what holds a drop where it comes to rest. A trial resting at θ_r needs a static level of at
least |G·sin θ_r − τ| (:func:`rest_level`); the base model's only static level is its Coulomb
level. When the breakaway exceeds the sliding friction (Stribeck at 1.5× the Coulomb level) the
equation-error level cannot hold the trials that rest furthest out, the grid's LM runs let them
swing on, and each whether-it-sticks decision is a cliff the finite-difference LM does not
climb: on the test oracle's 4 training drops (4096-tick encoder, seed 1) every start above ended
at 52–488 mrad (two trials swinging a second too long) against 8.2 mrad for the base model's
optimum (Coulomb 0.170 N·m, the largest rest torque 0.167). So when some trial rests beyond
what the equation-error level holds, two more starts put the Coulomb level at that rest torque
and keep it there (a floor, :data:`REST_DAMPINGS`) for their grid iterations; the best start is
then finished free, as any other.

**The search context** (:func:`search_context`) turns the fitting trials into cross-validation
units (crossval.py: whole trials, or time segments of a few long ones) and fits the base model
on them; ``identify`` and ``admittance ladder`` both start from it, so they judge effects on
the same units by the same rules.
"""

from __future__ import annotations

import numpy as np

from admittance.ident.crossval import Folds, make_folds, small_oscillation_period
from admittance.ident.equation_error import MIN_SPEED_FRACTION, derivatives, initial_state_starts
from admittance.ident.fit import FitResult, fit_initial_states_multi, fit_output_error, screen_starts
from admittance.ident.model import INDEX, Simulator
from admittance.ident.search import SearchContext, SearchSettings, nothing_left
from admittance.ident.angle_sensor import Sensor

# (Coulomb, damping) multipliers of the equation-error start.
FRICTION_GRID = ((3.0, 1.0), (10.0, 0.25), (0.3, 1.0), (3.0, 0.25))
GRID_ITERATIONS = 12  # LM iterations per grid start before the best one is finished
# Damping multipliers of the starts held at rest (the grid's two).
REST_DAMPINGS = (1.0, 0.25)
REST_TAIL_S = 0.25  # s: a trial rests when its smoothed speed stays this long near zero at its end


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
    for label, vector, floors in _grid_starts(sim, start, level):
        trial = fit_output_error(sim, vector, free, x0, torque_scale=torque_scale, max_iter=GRID_ITERATIONS,
                                 progress=progress, label="base fit (friction grid)", floors=floors)
        record.append({"start": label, "rmse": trial.rmse})
        if trial.rmse < best.rmse * (1 - 1e-6):
            best = trial
    if best is not fit:
        best = fit_output_error(sim, best.vector, free, best.x0, torque_scale=torque_scale, progress=progress,
                                label="base fit")
        record.append({"start": "best grid start, finished", "rmse": best.rmse})
    return best, record


def _grid_starts(sim: Simulator, start: np.ndarray, level: float):
    """(label, start vector, floors) of each friction-grid start: :data:`FRICTION_GRID` around
    the equation error's levels, then the starts held at rest when a trial rests beyond ``level``."""
    for f_mult, b_mult in FRICTION_GRID:
        vector = start.copy()
        vector[INDEX["coulomb"]] = level * f_mult
        vector[INDEX["damping"]] = start[INDEX["damping"]] * b_mult
        yield f"coulomb ×{f_mult:g}, damping ×{b_mult:g}", vector, None
    rest = rest_level(sim)
    if rest <= level:
        return
    for b_mult in REST_DAMPINGS:
        vector = start.copy()
        vector[INDEX["coulomb"]] = rest
        vector[INDEX["damping"]] = start[INDEX["damping"]] * b_mult
        yield f"coulomb held at rest ({rest:.4g}), damping ×{b_mult:g}", vector, {"coulomb": rest}


def rest_level(sim: Simulator) -> float:
    """The largest torque (sim units) that holds a trial where it rests at its end: |G·sin θ − τ|
    over the trials whose smoothed speed stays near zero for their last :data:`REST_TAIL_S`
    (near zero: the equation error's own threshold); 0 when none rests."""
    out = 0.0
    for trial in sim.trials:
        d = derivatives(trial)
        speed = np.abs(d.omega)
        tail = d.t >= d.t[-1] - REST_TAIL_S
        if tail.sum() < 2 or speed[tail].max() > MIN_SPEED_FRACTION * max(speed.max(), 1e-9):
            continue
        # The simulator's units: lumped mode has gravity 1 and the torque scaled (model.py).
        gravity = 1.0 if sim.mode == "lumped" else trial.gravity_torque
        scale = sim.tau_scale if sim.mode == "lumped" else 1.0
        tau = 0.0 if d.tau is None else float(np.mean(d.tau[tail])) * scale
        out = max(out, abs(gravity * float(np.sin(np.mean(d.theta[tail]))) - tau))
    return out


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
