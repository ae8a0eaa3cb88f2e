"""The rules that make the effect search cheaper without changing a verdict (issue 19 item 2).

Each rule decides what is computed, so each is a gate: these tests fail when it is removed
(the work is done again) or loosened (a verdict changes), tried by mutation.

- regime.regime_inconsistency measures the model's own floor (the parametric bootstrap) only
  when a split's gain exceeds the allowance's fixed part: below it the verdict is "one model"
  whatever the floor is.
- search._refit_judged carries a candidate's short refits to convergence unless another candidate
  already leaves nothing but sensor noise and this one's short refits fit the training data
  worse by more than search.FAR_BEHIND noise variances.
- candidate_screen.explore_round carries a candidate's first short refits (SCREEN_ITERATIONS LM
  iterations) on at once only when their linearised reach is within FAR_BEHIND noise variances
  of the floor; search._refit_judged carries the others on when their turn comes, unless a candidate of
  the round already leaves nothing but sensor noise and their reach is that far behind it.
- search._refit_judged does not refuse, however far its short refits trail, a candidate with
  fewer parameters than the model at the floor: it would win a tie with that model.
- search._judge_round assesses a refit that leaves nothing but sensor noise before the refits
  judged earlier that do not, so those face the model at the floor (refused without
  cross-validation when materially worse) instead of going through every test first.
- effects._settle carries its two best starts best first and stops once one leaves nothing but
  sensor noise (the second could at best tie).
- effects.refit_candidate carries the linearised starts only EXPLORE_ITERATIONS further while
  fallback starts may follow; the best of all is then carried to convergence.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from admittance.ident import candidate_screen, regime, search
from admittance.ident.candidate_screen import Screened
from admittance.ident.effects import Evidence, linearised_reach
from admittance.ident.fit import FitResult

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
    """search._refit_judged on a candidate whose best short refit fits ``behind_over_floor`` noise
    variances worse than a model at the floor (None: no model at the floor yet). Returns
    (whether it was refitted further, the reason it was refused)."""
    at_floor = search.AtFloor(SimpleNamespace(rmse=FLOOR), None, FLOOR)
    reached = FLOOR * np.sqrt(1.0 + (behind_over_floor or 0.0))
    explored = [[SimpleNamespace(rmse=reached), "linearised", False],
                [SimpleNamespace(rmse=2 * reached), "grown", False]]
    refits = []
    monkeypatch.setattr(search, "refit_effect", lambda *a, **k: refits.append(a) or None)
    evidence = Evidence("quadratic_drag")
    ctx = SimpleNamespace(sim=None, sensor=None)
    floor_model = at_floor if behind_over_floor is not None else None
    screened = Screened(explored, reach=reached**2, complete=True)
    search._refit_judged(ctx, SimpleNamespace(full=None), evidence, floor_model, screened)
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


def _screened_judge(monkeypatch, reach_over_floor: float, at_floor: bool,
                    trailing_over_floor: float = 100.0) -> tuple[bool, bool, str]:
    """search._refit_judged on a candidate that ran only its first short refits, whose linearised reach
    is ``reach_over_floor`` noise variances above a model at the floor (``at_floor``: whether
    the round has one), and whose first short refits trailed that model's first ones by
    ``trailing_over_floor`` noise variances. Returns (carried on, refitted, the reason it was refused)."""
    reach = FLOOR**2 * (1.0 + reach_over_floor)
    leader_first = 3.0 * FLOOR
    leader = Screened([[SimpleNamespace(rmse=leader_first), "linearised", True]], reach=FLOOR**2, complete=True)
    floor_model = search.AtFloor(SimpleNamespace(rmse=FLOOR), leader, FLOOR)
    first = np.sqrt(leader_first**2 + trailing_over_floor * FLOOR**2)
    entries = [[SimpleNamespace(rmse=first), "linearised", False]]
    carried, refits = [], []
    monkeypatch.setattr(search, "carry_on", lambda ctx, evidence, screened: carried.append(screened))
    monkeypatch.setattr(search, "refit_effect", lambda *a, **k: refits.append(a) or None)
    evidence = Evidence("cogging")
    search._refit_judged(SimpleNamespace(sim=None, sensor=None), SimpleNamespace(full=None), evidence,
                         floor_model if at_floor else None, Screened(entries, reach))
    return bool(carried), bool(refits), evidence.reason


def test_a_screened_candidate_out_of_reach_of_a_model_at_the_floor_is_refused_there(monkeypatch):
    carried, refitted, reason = _screened_judge(monkeypatch, 10.0, at_floor=True)
    assert not carried and not refitted
    assert "linearised step" in reason and "not refitted further" in reason


def test_a_screened_candidate_level_with_the_leader_after_the_same_iterations_is_carried_on(monkeypatch):
    """Like with like: one that stood within FAR_BEHIND of the model at the floor after the same
    first iterations is carried on whatever its linearisation says (on driven trials a torque
    bias and an asymmetric Coulomb level take the same steps; their reaches differed)."""
    carried, refitted, _ = _screened_judge(monkeypatch, 10.0, at_floor=True, trailing_over_floor=0.001)
    assert carried and refitted


def test_a_screened_candidate_within_reach_or_without_a_floor_is_carried_on_and_refitted(monkeypatch):
    carried, refitted, _ = _screened_judge(monkeypatch, 2.0, at_floor=True)  # within FAR_BEHIND = 3
    assert carried and refitted
    carried, refitted, _ = _screened_judge(monkeypatch, 1000.0, at_floor=False)
    assert carried and refitted


def test_the_round_carries_on_at_once_only_the_candidates_within_reach_of_the_floor(monkeypatch):
    """explore_round: the first short refits of every candidate, carried on at once only when
    their linearised reach is within FAR_BEHIND noise variances of the sensor's floor."""
    reaches = {"stribeck": 1.5, "cogging": 40.0, "quadratic_drag": 2.9}  # noise variances above the floor
    monkeypatch.setattr(candidate_screen, "noise_of", lambda *a, **k: SimpleNamespace(floor=FLOOR))
    monkeypatch.setattr(candidate_screen, "explore_linearised",
                        lambda sim, current, evidence, *a, **k: [[SimpleNamespace(rmse=FLOOR, name=evidence.effect),
                                                                  "linearised", False]])
    monkeypatch.setattr(candidate_screen, "linearised_reach",
                        lambda entries: FLOOR**2 * (1.0 + reaches[entries[0][0].name]))
    carried = []
    monkeypatch.setattr(candidate_screen, "explore_further",
                        lambda sim, entries, *a: carried.append(entries[0][0].name))
    ctx = SimpleNamespace(sim=None, sensor=None, torque_scale=1.0, x0_starts=[], say=lambda m: None)
    out = candidate_screen.explore_round(ctx, None, [Evidence(name) for name in reaches])
    assert carried == ["stribeck", "quadratic_drag"]
    assert [s.complete for s in out] == [True, False, True]


def test_the_linearised_reach_is_the_gauss_newton_minimum_of_the_best_start():
    """On a linear problem the Gauss–Newton step lands on the least-squares minimum: the reach is
    that minimum's mean square, whatever the start; the best of two starts counts."""
    rng = np.random.default_rng(3)
    n_g, n_k = 2, 200
    jac = [rng.normal(size=(n_g + 2, n_k)) for _ in range(3)]
    target = [rng.normal(size=n_k) for _ in range(3)]

    def at(z: np.ndarray) -> FitResult:
        g, x0 = z[:n_g], z[n_g:].reshape(3, 2)
        residuals = [j[:n_g].T @ g + j[n_g:].T @ x - y for j, x, y in zip(jac, x0, target)]
        return FitResult(np.zeros(1), 1.0, ("a", "b"), {}, x0, residuals, 3, 0, 0.0, jacobian=jac)

    stacked = np.zeros((3 * n_k, n_g + 6))
    for k, j in enumerate(jac):
        stacked[k * n_k:(k + 1) * n_k, :n_g] = j[:n_g].T
        stacked[k * n_k:(k + 1) * n_k, n_g + 2 * k:n_g + 2 * k + 2] = j[n_g:].T
    optimum = np.linalg.lstsq(stacked, np.concatenate(target), rcond=None)[0]
    minimum = at(optimum).rmse ** 2
    far = at(optimum + rng.normal(size=optimum.size))
    assert far.rmse**2 > 1.5 * minimum
    assert abs(linearised_reach([[far, "linearised", False]]) - minimum) < 1e-9 * minimum
    worse = FitResult(np.zeros(1), 1.0, ("a", "b"), {}, far.x0, [3.0 * r for r in far.residuals], 3, 0, 0.0)
    assert linearised_reach([[worse, "grown", False], [far, "linearised", False]]) == pytest.approx(minimum)


def test_short_refits_carried_on_take_the_steps_of_one_longer_fit(tmp_path):
    """effects.explore_further continues an LM fit from its values and its damping: three
    iterations and then nine more end where twelve in one go do (the screen changes which
    candidates are carried on, not what a carried-on refit finds)."""
    from admittance.formats.dataset import load_dataset
    from admittance.ident.effects import explore_further
    from admittance.ident.equation_error import fit_equation_error, initial_states
    from admittance.ident.fit import fit_output_error
    from admittance.ident.model import Simulator, free_params
    from admittance.ident.synthetic import SynthSpec, generate

    folder = generate(tmp_path / "set", SynthSpec(n_trials=3, duration=3.0, seed=4, effects={"stribeck": 0.04}))
    dataset = load_dataset(folder)
    start, tau_scale = fit_equation_error(dataset.trials, dataset.mode)
    sim = Simulator(dataset.trials, dataset.mode, tau_scale=tau_scale)
    free = free_params(dataset.mode, [], dataset.has_torque)
    x0 = initial_states(dataset.trials)
    whole = fit_output_error(sim, start, free, x0, max_iter=12)
    first = fit_output_error(sim, start, free, x0, max_iter=3)
    assert first.iterations == 3 and whole.iterations > 3
    entries = [[first, "linearised", False]]
    explore_further(sim, entries, 1.0, 9, "fit")
    assert np.array_equal(entries[0][0].vector, whole.vector)
    assert np.array_equal(entries[0][0].x0, whole.x0)


def _round(monkeypatch, at_the_floor: set[str]):
    """search._judge_round on three candidates judged in the order given, each refit leaving
    nothing but noise when named in ``at_the_floor``. Returns [(effect, whether a model at the
    floor was known when it was assessed)] in the order of assessment, and the admissible effects."""
    names = ["cogging", "stribeck", "friction_ripple"]
    assessed = []
    monkeypatch.setattr(search, "judging_order", lambda entries: [0, 1, 2])
    monkeypatch.setattr(search, "_refit_judged", lambda ctx, current, evidence, at_floor, screened:
                        SimpleNamespace(effect=evidence.effect, rmse=FLOOR))
    monkeypatch.setattr(search, "nothing_left", lambda sim, fit, sensor: fit.effect in at_the_floor)
    monkeypatch.setattr(search, "noise_of", lambda sim, fit, sensor: SimpleNamespace(
        nothing_left=fit.effect in at_the_floor, floor=FLOOR))

    def assess(ctx, current, evidence, refit, stand_ins, at_floor):
        assessed.append((evidence.effect, at_floor is not None))
        # What assess does with a model at the floor: a fit short of it is materially worse.
        if at_floor is not None and refit.effect not in at_the_floor:
            return None
        return SimpleNamespace(full=refit)

    monkeypatch.setattr(search, "assess", assess)
    ctx = SimpleNamespace(sim=None, sensor=None, say=lambda m: None)
    explored = [Screened([], reach=0.0) for _ in names]
    admissible = search._judge_round(ctx, SimpleNamespace(full=None), [Evidence(n) for n in names], explored, False)
    return assessed, [e.effect for e, _ in admissible]


def test_a_refit_at_the_floor_is_assessed_before_earlier_refits_short_of_it(monkeypatch):
    assessed, admissible = _round(monkeypatch, {"stribeck"})
    assert assessed == [("stribeck", False), ("friction_ripple", True), ("cogging", True)]
    assert admissible == ["stribeck"]


def test_without_a_refit_at_the_floor_every_candidate_is_assessed_in_the_judging_order(monkeypatch):
    assessed, admissible = _round(monkeypatch, set())
    assert assessed == [("cogging", False), ("stribeck", False), ("friction_ripple", False)]
    assert admissible == ["cogging", "stribeck", "friction_ripple"]


def test_a_simpler_candidate_far_behind_a_model_at_the_floor_is_refitted(monkeypatch):
    """A spring (2 parameters) reached the floor on driven drops with a torque bias; the bias
    (1 parameter) trailed it by 34 noise variances after three iterations and was refused, so
    the spring was named. Fewer parameters win a tie: such a candidate is refitted whatever its
    short refits say. Fails with the exemption removed."""
    entries = [[SimpleNamespace(rmse=FLOOR * np.sqrt(1.0 + 100.0)), "linearised", True]]
    refits = []
    monkeypatch.setattr(search, "refit_effect", lambda *a, **k: refits.append(a) or None)
    ctx = SimpleNamespace(sim=None, sensor=None)
    for own, floor_params, refitted in [(1, 2, True), (2, 2, False), (1, 1, False)]:
        refits.clear()
        at_floor = search.AtFloor(SimpleNamespace(rmse=FLOOR), None, FLOOR, floor_params)
        evidence = Evidence("torque_bias", params=("torque_bias",) if own == 1 else ("spring_stiffness", "spring_neutral"))
        search._refit_judged(ctx, SimpleNamespace(full=None), evidence, at_floor, Screened(entries, reach=0.0, complete=True))
        assert bool(refits) == refitted, (own, floor_params)


def test_own_params_counts_what_an_effect_adds():
    assert search.own_params(Evidence("torque_bias", params=("torque_bias",))) == 1
    assert search.own_params(Evidence("stribeck", params=("stribeck_torque", "stribeck_velocity"))) == 2
    cogging = Evidence("cogging", params=("cogging_amplitude", "cogging_phase", "cogging_period"))
    assert search.own_params(cogging) == 2  # the period is held on its grid


def _carries(monkeypatch, rmse_after):
    """effects.fit_output_error replaced: each call logged as (start rmse, max_iter, damping) and
    answered with ``rmse_after(start rmse)`` after max_iter iterations (a crawl)."""
    from admittance.ident import effects

    calls = []

    def fake_fit(sim, vector, free, x0, *, max_iter=60, damping=1e-3, **kwargs):
        start = float(vector[0])
        calls.append((start, max_iter, damping))
        after = rmse_after(start)
        return SimpleNamespace(vector=np.array([after]), free=free, x0=x0, rmse=after, iterations=max_iter,
                               residuals=None, end_point=None, tau_scale=1.0, damping=damping)

    monkeypatch.setattr(effects, "fit_output_error", fake_fit)
    return calls


def _entry(rmse):
    fit = SimpleNamespace(vector=np.array([rmse]), free=("damping",), x0=None, rmse=rmse, residuals=None,
                          end_point=None, tau_scale=1.0, damping=0.5)
    return [fit, f"start at {rmse}", False]


def test_settling_stops_once_a_start_leaves_nothing_but_sensor_noise(monkeypatch):
    """effects._settle carries the best starts best first; once one is at the floor the next
    could at best tie with it and is not carried (without a floor both are)."""
    from admittance.ident import effects

    calls = _carries(monkeypatch, lambda start: start - 0.1e-3)
    sim = SimpleNamespace(tau_scale=1.0)
    explored = [_entry(2.6e-3), _entry(2.1e-3)]
    best, label = effects._settle(sim, explored, 1.0, Evidence("stribeck"), lambda fit: fit.rmse < 2.05e-3)
    assert [c[0] for c in calls] == [2.1e-3] and label == "start at 0.0021"
    assert explored[1][2] is False  # the second start left where its short refits ended
    calls.clear()
    effects._settle(sim, [_entry(2.6e-3), _entry(2.1e-3)], 1.0, Evidence("stribeck"), lambda fit: False)
    assert [c[0] for c in calls] == [2.1e-3, 2.6e-3]


def test_with_fallbacks_to_come_the_linearised_starts_are_carried_only_a_bounded_way(monkeypatch):
    """effects.refit_candidate: while fallback starts may follow, the linearised starts are
    carried EXPLORE_ITERATIONS further (from their own damping), not to convergence; the
    fallbacks are then explored and the best of all is carried to convergence. Without
    fallbacks (another candidate is at the floor) they are carried to convergence at once."""
    from admittance.ident import effects

    calls = _carries(monkeypatch, lambda start: start if start > 5e-3 else 1.9e-3)  # the linearised start crawls
    explored_fallbacks = []

    def explore(sim, current, evidence, starts, *a, **k):
        explored_fallbacks.append(len(calls))
        return [_entry(2.3e-3)]

    monkeypatch.setattr(effects, "_explore", explore)
    for name in ("sliding_starts", "_equation_error_starts"):
        monkeypatch.setattr(effects, name, lambda *a, **k: [])
    monkeypatch.setattr(effects, "fallback_starts", lambda *a, **k: [{"quadratic_drag": 1.0}])
    current = SimpleNamespace(tau_scale=1.0, free=("damping",))
    sim = SimpleNamespace(with_tau_scale=lambda scale: sim, trials=[], mode="lumped", tau_scale=1.0)
    evidence = Evidence("quadratic_drag", params=("quadratic_drag",))
    done = lambda fit: fit.rmse < 2.0e-3  # noqa: E731
    best = effects.refit_candidate(sim, current, evidence, 1.0, {}, done, fallbacks=True,
                                   explored=[_entry(14e-3)])
    assert calls[0] == (14e-3, effects.EXPLORE_ITERATIONS, 0.5)
    assert explored_fallbacks == [1]  # explored right after the bounded carry
    assert calls[1][0] == 2.3e-3 and calls[1][1] > effects.EXPLORE_ITERATIONS and best.rmse == 1.9e-3
    calls.clear()
    effects.refit_candidate(sim, current, evidence, 1.0, {}, done, fallbacks=False, explored=[_entry(14e-3)])
    assert calls[0][1] > effects.EXPLORE_ITERATIONS
