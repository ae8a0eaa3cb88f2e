"""The rules that make the effect search cheaper without changing a verdict (issue 19 item 2).

Each rule decides what is computed, so each is a gate: these tests fail when it is removed
(the work is done again) or loosened (a verdict changes), tried by mutation.

- regime.regime_inconsistency measures the model's own floor (the parametric bootstrap) only
  when a split's gain exceeds the allowance's fixed part: below it the verdict is "one model"
  whatever the floor is.
- search._judge carries a candidate's short refits to convergence unless another candidate
  already leaves nothing but sensor noise and this one's short refits fit the training data
  worse by more than search.FAR_BEHIND noise variances.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from admittance.ident import regime, search
from admittance.ident.effects import Evidence

FLOOR = 2e-3  # rad: the sensor's noise level the fake verdict reports


def _split(gain_over_floor: float):
    """One regime split whose separate fits gain ``gain_over_floor`` × the noise variance, with
    a stability statistic far above its limit (the test would otherwise stop before the floor)."""
    joint = 2.1e-3
    apart = np.sqrt(joint**2 - gain_over_floor * FLOOR**2)
    record = {"split": ["large-swing", "small-swing"], "statistic": 500.0, "limit": 20.0,
              "rmse_joint": joint, "rmse_apart": float(apart), "effect": [], "effect_wald": 0.0,
              "effect_limit": 10.0, "effect_relative": 0.0, "params": {"damping": {
                  "large-swing": [1.0, 0.1], "small-swing": [1.0, 0.1]}}}
    return record


def _judge(monkeypatch, gain_over_floor: float, own_floor_over_floor: float):
    """regime_inconsistency on one fake split; returns (verdict, bootstrap calls)."""
    calls = []
    labels = ("large-swing", "small-swing")
    monkeypatch.setattr(regime, "noise_of", lambda *a, **k: SimpleNamespace(floor=FLOOR))
    monkeypatch.setattr(regime, "_regimes", lambda ctx, fit: [(labels, None)])
    monkeypatch.setattr(regime, "_stability", lambda *a, **k: (_split(gain_over_floor), []))

    def model_floor(ctx, fit, evidence):
        calls.append(evidence)
        return {labels: own_floor_over_floor * FLOOR**2}

    monkeypatch.setattr(regime, "model_floor", model_floor)
    fit = SimpleNamespace(rmse=2.1e-3)
    current = SimpleNamespace(rmse=10e-3)
    why, _ = regime.regime_inconsistency(SimpleNamespace(sim=None, sensor=None), Evidence("stribeck"), fit, current)
    return why, len(calls)


def test_a_split_gain_within_the_fixed_allowance_needs_no_bootstrap(monkeypatch):
    why, calls = _judge(monkeypatch, gain_over_floor=0.5 * regime.REGIME_MATERIAL, own_floor_over_floor=0.0)
    assert why == ""
    assert calls == 0


def test_a_split_gain_above_the_fixed_allowance_is_judged_on_the_models_own_floor(monkeypatch):
    # Just above the fixed part: with no floor of its own the model is not one model ...
    why, calls = _judge(monkeypatch, gain_over_floor=1.5 * regime.REGIME_MATERIAL, own_floor_over_floor=0.0)
    assert calls == 1
    assert "not one model" in why
    # ... and with a floor of its own that covers the gain it is (the bootstrap decides).
    why, calls = _judge(monkeypatch, gain_over_floor=1.5 * regime.REGIME_MATERIAL,
                        own_floor_over_floor=0.5 * regime.REGIME_MATERIAL)
    assert calls == 1
    assert why == ""


def _carried_on(monkeypatch, behind_over_floor: float | None) -> tuple[bool, str]:
    """search._judge on a candidate whose best short refit fits ``behind_over_floor`` noise
    variances worse than a model at the floor (None: no model at the floor yet). Returns
    (whether it was refitted further, the reason it was refused)."""
    at_floor = SimpleNamespace(rmse=FLOOR)
    reached = FLOOR * np.sqrt(1.0 + (behind_over_floor or 0.0))
    explored = [[SimpleNamespace(rmse=reached), "linearised", False],
                [SimpleNamespace(rmse=2 * reached), "grown", False]]
    refits = []
    monkeypatch.setattr(search, "noise_of", lambda *a, **k: SimpleNamespace(floor=FLOOR))
    monkeypatch.setattr(search, "refit_effect", lambda *a, **k: refits.append(a) or None)
    evidence = Evidence("quadratic_drag")
    ctx = SimpleNamespace(sim=None, sensor=None)
    floor_model = at_floor if behind_over_floor is not None else None
    search._judge(ctx, SimpleNamespace(full=None), evidence, False, floor_model, explored)
    return bool(refits), evidence.reason


def test_a_candidate_far_behind_a_model_at_the_floor_is_not_refitted_further(monkeypatch):
    refitted, reason = _carried_on(monkeypatch, 10.0)
    assert not refitted
    assert "not refitted further" in reason


def test_a_candidate_within_reach_of_the_floor_or_without_one_is_refitted(monkeypatch):
    # One noise variance behind (ten times what a tie allows) is within reach of convergence: refitted.
    refitted, _ = _carried_on(monkeypatch, 1.0)
    assert refitted
    # However far behind, when no candidate has reached the floor yet: refitted.
    refitted, _ = _carried_on(monkeypatch, None)
    assert refitted
