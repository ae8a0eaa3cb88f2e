"""Each candidate effect, injected alone and undeclared at a meaningful size, is found, named,
with I/B/F within 5/10/15 %, and lowers the held-out error; the data come from the TEST ORACLE
(tests/oracles/ivp.py: solve_ivp with stick events), an integrator independent of the fit. The
ranking's linear algebra, the torque-sensor conventions and the backward step are checked on
their own."""

from __future__ import annotations

import numpy as np
import pytest

from oracles import ivp as oracle
from admittance.formats.dataset import load_dataset
from admittance.ident.effects import _explained, candidate_effects, grown, significance
from admittance.ident.identify import identify_dataset
from admittance.ident.synthetic import SynthSpec, generate

# Sizes: each is a fraction of what the thesis setup shows (F = 0.084 N·m, G ≈ 0.3–0.5 N·m).
CASES = [
    ("stribeck", 0.04, False),  # N·m of breakaway above Coulomb
    ("asymmetric_coulomb", 0.02, False),  # N·m
    ("load_dependent_coulomb", 0.1, False),  # 10 % of the load torque
    ("angle_offset", 0.03, False),  # rad (1.7°)
    ("quadratic_drag", 0.002, False),  # N·m·s²/rad²: 0.05 N·m at 5 rad/s
    ("cogging", 0.01, False),  # N·m ripple, 8 per revolution
    ("time_delay", 0.03, True),  # s
    ("torque_bias", 0.02, "mixed"),  # N·m (with free swings in the set: see the test below)
    ("torque_gain", 0.85, True),  # the sensor reads 1/0.85 = 18 % high
    ("spring", 0.05, False),  # N·m/rad towards 0.2 rad (a cable)
    ("friction_ripple", 0.03, False),  # N·m on the Coulomb level, 6 per revolution
]


@pytest.mark.parametrize("effect, size, with_torque", CASES, ids=[c[0] for c in CASES])
def test_injected_effect_is_found_and_named(tmp_path, effect, size, with_torque):
    folder = oracle.generate(tmp_path, oracle.OracleSpec(n_trials=6, duration=5.0, seed=1, effect=effect, size=size,
                                                         with_torque=bool(with_torque), mixed=with_torque == "mixed"))
    j = identify_dataset(load_dataset(folder)).to_json()
    assert j["effects"] == [effect] and j["stand_ins"] == []
    assert j["rmse_after"] < 0.8 * j["rmse_before"]
    assert j["rmse_after"] < 0.0025  # back at the 2 mrad noise floor
    for name, tolerance in (("motor_inertia", 0.05), ("damping", 0.10), ("coulomb", 0.15)):
        assert j[name] == pytest.approx(oracle.MX64[name], rel=tolerance)


def test_torque_gain_is_measured_and_recorded_as_a_sensor_would(tmp_path):
    """The generator writes the *measured* torque (true / gain); identify gets the gain back and
    the inertia stays right: with the geometry known, gravity fixes the scale of the torque."""
    plain = generate(tmp_path / "plain", SynthSpec(n_trials=6, duration=5.0, seed=4, with_torque=True))
    scaled = generate(tmp_path / "scaled", SynthSpec(n_trials=6, duration=5.0, seed=4, with_torque=True,
                                                     effects={"torque_gain": 0.85}))
    a, b = load_dataset(plain).trials[0], load_dataset(scaled).trials[0]
    np.testing.assert_allclose(b.tau, a.tau / 0.85, rtol=1e-6)
    np.testing.assert_allclose(b.theta, a.theta, atol=1e-6)  # the same motion
    j = identify_dataset(load_dataset(scaled)).to_json()
    assert j["effects"] == ["torque_gain"]
    assert j["params"]["torque_gain"] == pytest.approx(0.85, abs=0.01)
    assert j["sigma"]["torque_gain"] < 0.01
    assert j["motor_inertia"] == pytest.approx(0.0147, rel=0.03)


def test_torque_gain_is_a_candidate_only_with_torque_and_geometry():
    assert "torque_gain" in candidate_effects([], with_tau=True, mode="geometry")
    assert "torque_gain" not in candidate_effects([], with_tau=False, mode="geometry")
    assert "torque_gain" not in candidate_effects([], with_tau=True, mode="lumped")  # κ is fitted already
    assert "torque_bias" in candidate_effects([], with_tau=True, mode="lumped")


def test_significance_is_counted_from_the_off_value():
    """A gain's "zero" is 1: a fitted 0.9 ± 0.02 is 5 σ from off, not 45 σ from 0."""
    from admittance.ident.fit import FitResult
    from admittance.ident.model import vector_from

    fit = FitResult(vector_from({"motor_inertia": 0.01, "torque_gain": 0.9, "torque_bias": 0.03}), 1.0,
                    ("torque_gain", "torque_bias"), {"torque_gain": 0.02, "torque_bias": 0.01}, np.zeros((0, 2)),
                    [], 0, 0, 0.0)
    assert significance(fit, ["torque_gain"]) == pytest.approx(5.0)
    assert significance(fit, ["torque_bias"]) == pytest.approx(3.0)
    assert grown({"torque_gain": 0.9}, ["torque_gain"])["torque_gain"] == pytest.approx(0.8)


def test_clean_torque_driven_data_gets_nothing(tmp_path):
    folder = generate(tmp_path, SynthSpec(n_trials=6, duration=5.0, seed=2, with_torque=True))
    j = identify_dataset(load_dataset(folder)).to_json()
    assert j["effects"] == []


def test_correlated_noise_on_driven_trials_is_not_a_torque_gain(tmp_path):
    """Driven trials never rest, so their coloured noise cannot be recognised as the sensor's:
    the search runs, and no candidate passes every test (a torque gain refit was once 11 %
    better on validation at about 1 σ from 1)."""
    folder = generate(tmp_path, SynthSpec(n_trials=7, duration=5.0, jitter=0.2, noise=0.002, noise_correlation=0.9,
                                          seed=300, with_torque=True))
    j = identify_dataset(load_dataset(folder)).to_json()
    assert not j["residual"]["white"]
    assert j["effects"] == []
    assert j["params"]["torque_gain"] == 1.0


@pytest.mark.parametrize("seed", [0, 1])
def test_correlated_noise_is_not_an_effect(tmp_path, seed):
    """Filtered (AR(1)) sensor noise: second differences see a quarter of it and Ljung–Box calls
    it structure. Where the model sticks the residual is the noise alone; an AR(1) whitens it
    there, so it is recognised as the sensor's, and nothing is added."""
    folder = generate(tmp_path, SynthSpec(n_trials=7, duration=5.0, jitter=0.2, noise=0.002,
                                          noise_correlation=0.9, seed=300 + seed))
    j = identify_dataset(load_dataset(folder)).to_json()
    assert j["residual"]["nothing_left"] and j["residual"]["noise_correlation"] > 0.7
    assert j["effects"] == [] and j["model_effects"] == []


def test_explained_fraction_of_a_column_that_is_the_residual():
    """A candidate column equal to the residual explains all of it; an orthogonal one nothing."""
    rng = np.random.default_rng(0)
    n = 200
    r = [rng.normal(size=n)]
    jac = [rng.normal(size=(3, n))]
    r[0] -= jac[0].T @ np.linalg.lstsq(jac[0].T, r[0], rcond=None)[0]  # residual ⟂ current model
    base, _, _ = _explained(jac, [], r, 1)
    full, coef, change = _explained(jac, [r[0][None, :]], r, 1)
    assert base == pytest.approx(0.0, abs=1e-9)
    assert full == pytest.approx(float(r[0] @ r[0]))
    assert coef[0] == pytest.approx(-1.0)
    np.testing.assert_allclose(change[0], -r[0], atol=1e-9)  # the step cancels the residual
    orth = jac[0][1][None, :]  # inside the current span: nothing new
    assert _explained(jac, [orth], r, 1)[0] == pytest.approx(0.0, abs=1e-8)


def test_backward_step_drops_an_effect_a_later_one_explains(tmp_path):
    """Data with an asymmetric Coulomb level only; a model that also carries an angle offset
    loses it in the backward step (without it the cross-validated error is no worse)."""
    from admittance.ident.base import fit_base, search_context
    from admittance.ident.equation_error import fit_equation_error, initial_state_starts
    from admittance.ident.fit import fit_output_error
    from admittance.ident.model import Simulator, free_params, vector_from
    from admittance.ident.search import SearchSettings, _redundant, cross_validate
    from admittance.ident.angle_sensor import Sensor

    folder = oracle.generate(tmp_path, oracle.OracleSpec(n_trials=4, duration=4.0, seed=5, effect="asymmetric_coulomb",
                                                         size=0.02))
    ds = load_dataset(folder)
    start, _ = fit_equation_error(ds.trials, ds.mode)
    sim = Simulator(ds.trials, ds.mode)
    base, _ = fit_base(sim, start, free_params("geometry", [], False), initial_state_starts(ds.trials), Sensor(), 0.4)
    ctx, base_units = search_context(sim, base, Sensor(), 0.4, SearchSettings())
    effects = ["angle_offset", "asymmetric_coulomb"]
    both = fit_output_error(ctx.sim, vector_from({**oracle.MX64, "coulomb_asym": 0.01, "angle_offset": 0.005}),
                            free_params("geometry", effects, False), base_units.x0, torque_scale=0.4)
    note, without = _redundant(ctx, cross_validate(ctx, both), effects)
    assert note.effect == "angle_offset" and "no longer earns its place" in note.reason
    assert "angle_offset" not in without.full.free


def test_a_torque_bias_on_driven_trials_only_is_named_as_a_group_with_the_separating_experiment(tmp_path):
    """On driven trials a constant torque bias b and an asymmetric Coulomb level a = b are the
    same equation under the stick law: the data cannot tell them apart, so the term is kept in
    the model (it predicts as well either way), neither is named alone, and the group is named
    with the experiment that separates them (undriven drops). With free swings in the set (the
    test above) the asymmetric level acts there and the bias does not: torque_bias is named."""
    folder = oracle.generate(tmp_path, oracle.OracleSpec(n_trials=6, duration=5.0, seed=3, effect="torque_bias",
                                                         size=0.02, with_torque=True))
    j = identify_dataset(load_dataset(folder)).to_json()
    assert j["effects"] == [] and j["stand_ins"] == []
    (group,) = j["groups"]
    assert set(group["effects"]) == {"torque_bias", "asymmetric_coulomb"}
    assert j["model_effects"] == [group["kept"]]
    assert "undriven drops" in group["separate_by"]
    assert j["rmse_after"] < 0.0025  # predicted as well as by the truth


def test_large_torque_bias_is_not_lost_to_a_compensating_drift(tmp_path):
    """A bias of 0.05 N·m: fitted with a drift, the two cancel (bias 0.75, drift not
    significant); without the drift the refit must restart from the model before the effect,
    or it stalls there. On driven trials only, the bias and an asymmetric Coulomb level are the
    same equation (previous test): whichever the model carries must be 0.05."""
    folder = generate(tmp_path, SynthSpec(n_trials=6, duration=5.0, seed=7, jitter=0.1, with_torque=True,
                                          effects={"torque_bias": 0.05}))
    j = identify_dataset(load_dataset(folder)).to_json()
    assert len(j["model_effects"]) == 1 and j["effects"] == []
    value = j["params"]["torque_bias"] if j["model_effects"] == ["torque_bias"] else j["params"]["coulomb_asym"]
    assert value == pytest.approx(0.05, rel=0.05)
    assert j["params"]["torque_drift"] == 0.0
    assert j["rmse_after"] < 0.0025


def test_physical_sense_refuses_bounds_free_periods_grid_ends_and_pushing_friction():
    """effects.physical_problems: what no refit may do, whatever it does to the error."""
    from admittance.ident.effects import Evidence, physical_problems
    from admittance.ident.fit import FitResult
    from admittance.ident.model import vector_from

    def problems(effect, params, **values):
        fit = FitResult(vector_from({"motor_inertia": 0.01, "coulomb": 0.05, **values}), 1.0, (), {},
                        np.zeros((0, 2)), [], 0, 0, 0.0)
        return physical_problems(Evidence(effect, params=params), fit)

    cog = ("cogging_amplitude", "cogging_phase")
    assert problems("cogging", cog, cogging_amplitude=0.01, cogging_period=8.0) == []
    assert "whole number" in problems("cogging", cog, cogging_amplitude=0.01, cogging_period=6.26)[0]
    assert "end of the searched grid" in problems("cogging", cog, cogging_amplitude=0.01, cogging_period=2.0)[0]
    assert "end of the searched grid" in problems("cogging", cog, cogging_amplitude=0.01, cogging_period=32.0)[0]
    assert "lower bound" in problems("cogging", cog, cogging_amplitude=0.0, cogging_period=8.0)[0]
    ripple = ("friction_ripple_amplitude", "friction_ripple_phase")
    assert "above the Coulomb level" in problems("friction_ripple", ripple, friction_ripple_amplitude=0.08,
                                                 friction_ripple_period=6.0)[0]
    assert "above the Coulomb level" in problems("asymmetric_coulomb", ("coulomb_asym",), coulomb_asym=-0.06)[0]
    assert "upper bound" in problems("stribeck", ("stribeck_torque", "stribeck_velocity"), stribeck_torque=0.01,
                                     stribeck_velocity=20.0)[0]
    assert "collapsed" in problems("time_delay", ("time_delay",), time_delay=0.01, motor_inertia=1e-9)[-1]


def test_stribeck_is_refitted_from_the_sliding_friction_of_the_equation_error(tmp_path, monkeypatch):
    """Drops with Stribeck at 1.5× the Coulomb level on a 4096-tick encoder (the families bench's
    regime row, seed 4): the base fit holds the drops at rest with Coulomb 0.168 and damping ~0;
    the fallback start (30 % of that level into Stribeck, the damping kept) stalled and Stribeck
    was refused (0.1 σ). From the equation error's sliding friction with the surplus as breakaway
    it is named, I/B/F within the bench's 5/10/15 %. Fails with those starts removed."""
    from admittance.ident import effects

    spec = oracle.OracleSpec(effect="stribeck", size=1.5 * 0.084, noise=0.0, ticks=4096, declare_ticks=True, seed=4)
    dataset = load_dataset(oracle.generate(tmp_path, spec))
    j = identify_dataset(dataset).to_json()
    assert j["effects"] == ["stribeck"]
    for name, tolerance in (("motor_inertia", 0.05), ("damping", 0.10), ("coulomb", 0.15)):
        assert j[name] == pytest.approx(oracle.MX64[name], rel=tolerance)
    monkeypatch.setattr(effects, "sliding_starts", lambda *args: [])
    assert identify_dataset(dataset).to_json()["effects"] != ["stribeck"]


def test_a_shaped_level_is_tested_with_its_shape_held():
    """The Stribeck level's σ for the significance test is the one with the velocity held (the
    look-elsewhere share over the velocity grid pays for the shape): Σ_SS − Σ_Sv²/Σ_vv."""
    from types import SimpleNamespace

    from admittance.ident.effects import conditional_sigma
    from admittance.ident.fit import FitResult
    from admittance.ident.model import vector_from

    free = ("motor_inertia", "damping", "coulomb", "stribeck_torque", "stribeck_velocity")
    cov = np.diag([1e-8, 1e-6, 1e-6, 0.04**2, 0.07**2])
    cov[3, 4] = cov[4, 3] = 0.98 * 0.04 * 0.07  # the level/velocity ridge
    fit = FitResult(vector=vector_from({"stribeck_torque": 0.085, "stribeck_velocity": 0.3}), tau_scale=1.0,
                    free=free, sigma={n: float(np.sqrt(cov[i, i])) for i, n in enumerate(free)},
                    x0=np.zeros((1, 2)), residuals=[], iterations=0, simulations=0, seconds=0.0,
                    uncertainty=SimpleNamespace(globals=lambda: cov))
    held = 0.04 * np.sqrt(1 - 0.98**2)
    assert conditional_sigma(fit, "stribeck_torque") == pytest.approx(held)
    assert significance(fit, ["stribeck_torque"]) == pytest.approx(0.085 / held)
    assert conditional_sigma(fit, "coulomb") == pytest.approx(1e-3)  # uncorrelated with the shape


def test_stribeck_on_the_level_velocity_ridge_is_named(tmp_path, monkeypatch):
    """Seed 5 of the same regime row: the refit reaches 0.3 mrad (the encoder's floor 0.44) at a
    level 0.085 N·m, velocity 0.3 rad/s (truth 0.126 at 0.15: a ridge). With the velocity free
    the level's σ is 0.040 (2.1 σ < 3.4 σ: refused, and a spring admitted as a stand-in); with
    it held, 11 σ: named. Fails with the marginal σ put back."""
    from admittance.ident import effects

    spec = oracle.OracleSpec(effect="stribeck", size=1.5 * 0.084, noise=0.0, ticks=4096, declare_ticks=True, seed=5)
    dataset = load_dataset(oracle.generate(tmp_path, spec))
    j = identify_dataset(dataset).to_json()
    assert j["effects"] == ["stribeck"] and j["stand_ins"] == []
    monkeypatch.setattr(effects, "conditional_sigma", lambda fit, name: fit.sigma.get(name, np.inf))
    assert identify_dataset(dataset).to_json()["effects"] != ["stribeck"]


def _freed_refits(monkeypatch, rmse_by_velocity: dict[float, float]):
    """effects.fit_output_error replaced by a fit that ends where it starts, with the training
    error ``rmse_by_velocity`` gives its Stribeck velocity; returns the starts it was given."""
    from types import SimpleNamespace

    from admittance.ident import effects
    from admittance.ident.model import INDEX

    starts = []

    def fake_fit(sim, vector, free, x0, **kwargs):
        velocity = float(vector[INDEX["stribeck_velocity"]])
        starts.append(velocity)
        return SimpleNamespace(vector=vector.copy(), rmse=rmse_by_velocity[velocity], x0=x0, free=free,
                               value=lambda name, v=vector.copy(): float(v[INDEX[name]]))

    monkeypatch.setattr(effects, "fit_output_error", fake_fit)
    return starts


def test_a_freed_stribeck_velocity_short_of_the_floor_is_restarted_from_its_grid(monkeypatch):
    """The refit freed from the best grid start ended stuck (2.4 mrad); restarted with the
    velocity at each other grid value, the best end is kept (0.3 rad/s: 2.0 mrad)."""
    from admittance.ident import effects
    from admittance.ident.model import vector_from

    rmse = {0.03: 3.1e-3, 0.1: 2.4e-3, 0.3: 2.0e-3, 1.0: 2.7e-3}
    starts = _freed_refits(monkeypatch, rmse)
    stuck = effects.fit_output_error(None, vector_from({"stribeck_velocity": 0.1}), ("stribeck_velocity",), None)
    best = effects._freed_from_the_grid(None, stuck, effects.Evidence("stribeck"), ("stribeck_velocity",), 1.0)
    assert starts[1:] == [0.03, 0.3, 1.0]  # every other grid value, not the one it ended at
    assert best.rmse == 2.0e-3 and best.value("stribeck_velocity") == 0.3


@pytest.mark.parametrize("fallbacks, at_floor, restarted", [(True, False, True), (True, True, False),
                                                            (False, False, False)])
def test_the_grid_restarts_run_only_for_a_freed_refit_short_of_the_floor(monkeypatch, fallbacks, at_floor, restarted):
    """refit_candidate restarts a freed Stribeck velocity from its grid only when the freed refit
    leaves more than sensor noise and fallback starts are wanted (no other candidate of the
    round leaves nothing but noise)."""
    from types import SimpleNamespace

    from admittance.ident import effects
    from admittance.ident.model import vector_from

    _freed_refits(monkeypatch, {0.1: 2.4e-3})
    grid = []
    monkeypatch.setattr(effects, "_freed_from_the_grid", lambda sim, fit, *a: grid.append(fit) or fit)
    settled = SimpleNamespace(vector=vector_from({"stribeck_velocity": 0.1}), x0=None, rmse=2.4e-3)
    monkeypatch.setattr(effects, "_settle", lambda *a, **k: (settled, "linearised"))
    for name in ("fallback_starts", "sliding_starts", "_equation_error_starts", "_explore"):
        monkeypatch.setattr(effects, name, lambda *a, **k: [])
    current = SimpleNamespace(tau_scale=1.0, free=("motor_inertia", "damping", "coulomb"))
    sim = SimpleNamespace(with_tau_scale=lambda scale: sim, trials=[], mode="lumped")
    evidence = effects.Evidence("stribeck", params=("stribeck_torque", "stribeck_velocity"))
    effects.refit_candidate(sim, current, evidence, 1.0, {}, lambda fit: at_floor, fallbacks=fallbacks,
                            explored=[[settled, "linearised", True]])
    assert bool(grid) == restarted


def test_a_refit_short_of_the_floor_has_its_initial_states_fitted_again(monkeypatch):
    """effects._initial_states_again: the units' states refitted under the refit's parameters,
    from its own and from the data's screened starts, then the joint fit carried on from
    there and kept only when it fits better; nothing to do without the data's starts."""
    from types import SimpleNamespace

    from admittance.ident import effects

    stuck = SimpleNamespace(vector=np.zeros(3), x0=np.array([[0.1, 0.0], [0.5, 0.0]]), free=("damping",), rmse=4.0e-3)
    moved = np.array([[0.1, 0.0], [0.7, 0.0]])  # the second unit's state from the data's start
    # The data's starts lead the second unit elsewhere (fit.states_again: each unit its best).
    monkeypatch.setattr(effects, "states_again", lambda sim, vector, own, starts, **k:
                        moved if any(np.array_equal(s, moved) for s in starts) else own)
    joint = []

    def fake_fit(sim, vector, free, x0, **kwargs):
        joint.append(x0)
        return SimpleNamespace(rmse=2.0e-3 if np.array_equal(x0, moved) else 5.0e-3, x0=x0)

    monkeypatch.setattr(effects, "fit_output_error", fake_fit)
    evidence = effects.Evidence("quadratic_drag")
    assert effects._initial_states_again(None, stuck, evidence, [moved], 1.0).rmse == 2.0e-3
    assert np.array_equal(joint[-1], moved)
    assert effects._initial_states_again(None, stuck, evidence, [], 1.0) is stuck  # no data starts
    moved = stuck.x0  # the states stay where they were: no joint refit
    joint.clear()
    assert effects._initial_states_again(None, stuck, evidence, [stuck.x0], 1.0) is stuck and not joint


def test_the_initial_states_are_fitted_again_only_for_a_refit_short_of_the_floor(monkeypatch):
    from types import SimpleNamespace

    from admittance.ident import effects

    calls = []
    monkeypatch.setattr(effects, "_initial_states_again", lambda sim, fit, *a: calls.append(fit) or fit)
    settled = SimpleNamespace(vector=np.zeros(3), x0=None, rmse=3e-3, free=("damping",))
    monkeypatch.setattr(effects, "_settle", lambda *a, **k: (settled, "linearised"))
    for name in ("fallback_starts", "sliding_starts", "_equation_error_starts", "_explore"):
        monkeypatch.setattr(effects, name, lambda *a, **k: [])
    current = SimpleNamespace(tau_scale=1.0, free=("motor_inertia", "damping", "coulomb"))
    sim = SimpleNamespace(with_tau_scale=lambda scale: sim, trials=[], mode="lumped")
    for fallbacks, at_floor, expected in [(True, False, 1), (True, True, 0), (False, False, 0)]:
        calls.clear()
        effects.refit_candidate(sim, current, effects.Evidence("quadratic_drag", params=("quadratic_drag",)), 1.0, {},
                                lambda fit: at_floor, fallbacks=fallbacks, explored=[[settled, "linearised", True]])
        assert len(calls) == expected, (fallbacks, at_floor)
