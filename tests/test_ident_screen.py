"""The candidate screen (candidate_screen.py) and the LM's converged exit (fit.py): what makes the
effect search fast must not change what it finds.

- The screen only orders the candidates (lowest short-refit error first); every candidate of a
  round is still judged. A screen that dropped the candidates behind the first one would lose
  the group of two indistinguishable effects (tests/test_ident_effects.py, the torque bias on
  driven trials: tried by mutation) and the check below that every candidate has a verdict.
- The LM ends a fit when even the undamped Gauss–Newton step predicts less than a tenth of its
  stopping tolerance; a fit that is not converged is not stopped by it.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from oracles import ivp as oracle
from admittance.formats.dataset import load_dataset
from admittance.ident.candidate_screen import judging_order
from admittance.ident.fit import _lm_step, _predicted_gain
from admittance.ident.identify import identify_dataset


def _entry(rmse: float) -> list:
    return [SimpleNamespace(rmse=rmse), "linearised", False]


def test_candidates_are_judged_lowest_short_refit_error_first_and_none_is_dropped():
    explored = [[_entry(5.0), _entry(4.0)], [], [_entry(2.0)], [_entry(3.0)], []]
    order = judging_order(explored)
    assert order == [2, 3, 0, 1, 4]  # no start (wrong sign): last, in ranking order
    assert sorted(order) == list(range(len(explored)))


def test_every_candidate_of_a_round_gets_a_verdict(tmp_path):
    """The true effect is named, and every other candidate of the round was judged (a reason),
    whatever the order the screen put it in."""
    folder = oracle.generate(tmp_path, oracle.OracleSpec(n_trials=6, duration=5.0, seed=1, effect="stribeck",
                                                         size=0.04))
    j = identify_dataset(load_dataset(folder)).to_json()
    assert j["effects"] == ["stribeck"]
    first_round = j["evidence"][0]
    assert len(first_round) >= 8
    assert all(c["reason"] for c in first_round)


class _Quadratic:
    """A linear least-squares problem r(z) = J z − y: its Gauss–Newton model is exact."""

    n_trials = 0

    def __init__(self, jac: np.ndarray, y: np.ndarray):
        self.jac, self.y = jac, y
        self.calls = 0

    def residuals(self, z):
        self.calls += 1
        return [self.jac @ z - self.y]

    def residuals_of(self, zs):
        return [self.residuals(z) for z in zs]


def _normal(problem: _Quadratic, z):
    r = problem.residuals(z)[0]
    return problem.jac.T @ problem.jac, problem.jac.T @ r, float(r @ r)


def test_the_lm_stops_without_simulating_at_a_minimum_and_steps_elsewhere():
    rng = np.random.default_rng(0)
    jac, y = rng.normal(size=(50, 3)), rng.normal(size=50)
    problem = _Quadratic(jac, y)
    lo, hi = np.full(3, -np.inf), np.full(3, np.inf)
    optimum = np.linalg.lstsq(jac, y, rcond=None)[0]
    a, b, cost = _normal(problem, optimum)
    problem.calls = 0
    z_new, *_ = _lm_step(problem, optimum, a, b, cost, 1e-3, lo, hi, tol=1e-5)
    assert z_new is None and problem.calls == 0  # converged: no simulation spent on dampings
    a, b, cost = _normal(problem, np.zeros(3))
    z_new, _, cost_new, _ = _lm_step(problem, np.zeros(3), a, b, cost, 1e-3, lo, hi, tol=1e-5)
    assert z_new is not None and cost_new < cost
    assert _predicted_gain(a, b, optimum) == pytest.approx(cost - float(np.sum((jac @ optimum - y) ** 2)))
