"""The rules that make identify's phases other than the effect search cheaper (issue 19 item 2).

- fit.EndPoint: a fit handed the end point of another (``known=``) that starts exactly there,
  on those trials or a subset (a cross-validation fold, a jackknife replicate), takes the
  residuals and Jacobian blocks from it instead of simulating them again. Exact: the tests
  check the result is the same bit for bit, that the simulations are saved, and that a start
  that differs in one trial's initial state or in a fixed parameter reuses nothing.
- fit.end_point_of, called by uncertainty.jackknife and search.cross_validate: the full
  fit's Jacobian simulated once for every replicate and fold. Exact: the same spread and
  held-out residuals bit for bit, and exactly the simulations counted saved.
- fit_output_error(..., residuals=): the residuals at a start the caller simulated already
  (a fit carried on, a regime half's fit after its initial states, fit.closest_starts' pick)
  are not simulated again: the same fit bit for bit, one simulation per trial fewer; ignored
  when the bounds move the start.

Each was removed by mutation and these tests failed.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from admittance.formats.dataset import load_dataset
from admittance.ident import fit as fitmod
from admittance.ident.equation_error import initial_states
from admittance.ident.fit import _Problem, fit_output_error
from admittance.ident.model import Simulator, free_params, vector_from
from admittance.ident.synthetic import MX64, SynthSpec, generate

FREE = ("motor_inertia", "damping", "coulomb")


@pytest.fixture(scope="module")
def drops(tmp_path_factory):
    ds = load_dataset(generate(tmp_path_factory.mktemp("reuse"), SynthSpec(n_trials=6, duration=3.0, seed=3)))
    return Simulator(ds.trials, ds.mode), initial_states(ds.trials)


def _end_point(sim, vector, x0):
    """``vector``/``x0`` on every trial of ``sim`` as a fit's end point."""
    problem = _Problem(sim, vector, FREE, True, 0.3)
    z = np.concatenate([vector[:3], x0.ravel()])
    r = problem.residuals(z)
    return fitmod.EndPoint(problem, z, r, problem.jacobian(z, r, np.full(z.size, np.inf)))


def _refit(sim, vector, x0, known=None):
    return fit_output_error(sim, vector, FREE, x0, torque_scale=0.3, max_iter=2, known=known)


def test_a_fit_started_at_a_remembered_end_point_reuses_its_jacobian_exactly(drops):
    sim, x0 = drops
    vector = vector_from({**MX64, "damping": 1.1 * MX64["damping"]})
    keep = [0, 2, 3, 5]
    fresh = _refit(sim.subset(keep), vector, x0[keep])
    reused = _refit(sim.subset(keep), vector, x0[keep], _end_point(sim, vector, x0))
    # One residual and one Jacobian (1 + 3 + 2 rows) per trial of the subset were not simulated.
    assert fresh.simulations - reused.simulations == (1 + len(FREE) + 2) * len(keep)
    np.testing.assert_array_equal(reused.vector, fresh.vector)
    np.testing.assert_array_equal(reused.x0, fresh.x0)
    for a, b in zip(reused.residuals, fresh.residuals):
        np.testing.assert_array_equal(a, b)


def test_a_start_that_differs_in_one_state_or_a_fixed_parameter_reuses_nothing(drops):
    sim, x0 = drops
    vector = vector_from({**MX64, "damping": 1.1 * MX64["damping"]})
    fresh = _refit(sim, vector, x0)
    known = _end_point(sim, vector, x0)
    moved = x0.copy()
    moved[4, 0] += 1e-4
    assert _refit(sim, vector, moved, known).simulations == fresh.simulations
    other = vector_from({**MX64, "damping": 1.1 * MX64["damping"], "torque_bias": 1e-3})
    assert _refit(sim, other, x0, known).simulations == fresh.simulations


def _with_and_without(monkeypatch, module, call):
    """``call()`` twice: without the rule (``module.end_point_of``: no end point handed to the
    refits), then with it. Returns ((result, simulations) without, (result, simulations) with)."""
    counted = []
    run = Simulator.run
    monkeypatch.setattr(Simulator, "run", lambda self, rows, *a, **k: counted.append(rows.shape[0] * len(self.trials))
                        or run(self, rows, *a, **k))
    out = []
    for reuse in (False, True):
        counted.clear()
        with monkeypatch.context() as m:
            if not reuse:  # every refit simulates its own start
                m.setattr(module, "end_point_of", lambda *a: None)
            out.append((call(), sum(counted)))
    return out


def test_the_jackknife_simulates_the_full_fits_jacobian_once_for_every_replicate(drops, monkeypatch):
    """uncertainty.jackknife linearises the full fit once (fit.end_point_of); each replicate
    then starts from it. The spread is the same to the last bit, with fewer simulations."""
    from admittance.ident import uncertainty

    sim, x0 = drops
    full = replace(fit_output_error(sim, vector_from(MX64), FREE, x0, torque_scale=0.3), end_point=None)
    (plain, plain_sims), (reused, reused_sims) = _with_and_without(
        monkeypatch, uncertainty, lambda: uncertainty.jackknife(sim, full, 0.3, max_groups=3))
    assert reused == plain
    # Three replicates of four trials each: 3 × 4 × (1 + 3 + 2) rows saved, 6 × (3 + 2) spent once.
    assert plain_sims - reused_sims == 3 * 4 * (1 + len(FREE) + 2) - len(sim.trials) * (len(FREE) + 2)


def test_cross_validation_simulates_the_full_fits_jacobian_once_for_every_fold(drops, monkeypatch):
    """search.cross_validate linearises the model fitted on all units once; each fold's refit then
    starts from it. The held-out residuals are the same to the last bit, with fewer simulations."""
    from admittance.ident import search
    from admittance.ident.angle_sensor import Sensor
    from admittance.ident.base import search_context

    sim, x0 = drops
    full = replace(fit_output_error(sim, vector_from(MX64), FREE, x0, torque_scale=0.3), end_point=None)
    ctx, _ = search_context(sim, full, Sensor(), 0.3, search.SearchSettings(1, 0.03, 3.0))
    (plain, plain_sims), (reused, reused_sims) = _with_and_without(
        monkeypatch, search, lambda: search.cross_validate(ctx, full).residuals)
    for a, b in zip(reused, plain):
        np.testing.assert_array_equal(a, b)
    folds = ctx.folds
    trained = sum(len(folds.train(k)) for k in range(folds.n_folds))
    assert plain_sims - reused_sims == trained * (1 + len(FREE) + 2) - len(sim.trials) * (len(FREE) + 2)


def test_a_fit_handed_the_residuals_at_its_start_is_the_same_with_one_simulation_fewer(drops):
    """fit_output_error(..., residuals=): a fit carried on from where another ended (the short
    refits, a regime half's own fit after its initial-state fit) or from the start a batch of
    candidate states picked (fit.closest_starts) takes the residuals there instead of
    simulating them again: bit for bit the same fit, one simulation per trial fewer."""
    sim, x0 = drops
    vector = vector_from({**MX64, "damping": 1.1 * MX64["damping"]})
    picked, residuals = fitmod.closest_starts(sim, vector, [x0, x0 + np.array([1e-3, 0.0])])
    plain = _refit(sim, vector, picked)
    handed = fit_output_error(sim, vector, FREE, picked, torque_scale=0.3, max_iter=2, residuals=residuals)
    assert plain.simulations - handed.simulations == len(sim.trials)
    np.testing.assert_array_equal(handed.vector, plain.vector)
    np.testing.assert_array_equal(handed.x0, plain.x0)
    for a, b in zip(handed.residuals, plain.residuals):
        np.testing.assert_array_equal(a, b)


def test_residuals_handed_to_a_start_the_bounds_move_are_not_used(drops):
    """A start outside the bounds is clipped before the fit: residuals simulated at the
    unclipped start are not the clipped start's, and are ignored (simulated again)."""
    sim, x0 = drops
    outside = vector_from({**MX64, "damping": -0.01})  # damping's lower bound is 0
    plain = _refit(sim, outside, x0)
    wrong = [np.zeros_like(m) for m in sim.measured]
    handed = fit_output_error(sim, outside, FREE, x0, torque_scale=0.3, max_iter=2, residuals=wrong)
    assert handed.simulations == plain.simulations
    np.testing.assert_array_equal(handed.vector, plain.vector)


def test_a_fit_that_ends_on_a_failed_step_carries_its_end_point_and_a_fit_from_there_reuses_it(drops):
    """A converged fit stops when no damped step lowers the cost: the Jacobian it took last is at
    its end point, and it carries it (FitResult.end_point). end_point_of hands that on without
    simulating it again, and a fit carried on from there (effects.explore_further, _settle)
    starts with it: the same fit, 1 + P + 2 simulations per trial fewer."""
    sim, x0 = drops
    converged = fit_output_error(sim, vector_from(MX64), FREE, x0, torque_scale=0.3)
    # From its optimum, with a coarser tolerance, the first step predicts too little: it stops there.
    full = fit_output_error(sim, converged.vector, FREE, converged.x0, torque_scale=0.3, tol=1e-2)
    assert full.iterations == 1 and full.end_point is not None
    assert fitmod.end_point_of(sim, full, 0.3) is full.end_point
    again = fit_output_error(sim, full.vector, FREE, full.x0, torque_scale=0.3, max_iter=2)
    reused = fit_output_error(sim, full.vector, FREE, full.x0, torque_scale=0.3, max_iter=2, known=full.end_point)
    assert again.simulations - reused.simulations == (1 + len(FREE) + 2) * len(sim.trials)
    np.testing.assert_array_equal(reused.vector, again.vector)
    for a, b in zip(reused.residuals, again.residuals):
        np.testing.assert_array_equal(a, b)
