"""The regime test's floor (ident/regime.py): measured on data the fitted model itself makes.

A right model fitted on a driven and free encoder set (test-oracle data) gains more than the
old fixed allowance (0.1× the noise variance) from separate light- and heavy-load fits, and
about as much on its own simulated data: it is one model. A model that lacks the effect at
work is not, whatever its own floor. Each test fails with its half of the gate removed (the
measured floor; the gate itself), tried by mutation."""

from __future__ import annotations

import pytest

from oracles import ivp as oracle
from admittance.formats.dataset import load_dataset
from admittance.ident.angle_sensor import sensor_for
from admittance.ident.base import fit_base, search_context, torque_scale_of
from admittance.ident.effects import Evidence
from admittance.ident.equation_error import fit_equation_error, initial_state_starts
from admittance.ident.fit import fit_output_error
from admittance.ident.model import EFFECTS, INDEX, Simulator, free_params
from admittance.ident.regime import REGIME_MATERIAL, regime_inconsistency
from admittance.ident.search import SearchSettings


def _context(folder):
    """The search context identify builds, on every trial (no held-out pick: the test is the
    regime test alone)."""
    dataset = load_dataset(folder)
    trials = dataset.trials
    scale = torque_scale_of(dataset)
    sensor = sensor_for(trials, dataset.encoder_ticks)
    start, tau = fit_equation_error(trials, dataset.mode)
    sim = Simulator(trials, dataset.mode, "stick", 1e-3, tau)
    base, _ = fit_base(sim, start, free_params(dataset.mode, [], dataset.has_torque), initial_state_starts(trials),
                       sensor, scale, None)
    ctx, base_units = search_context(sim, base, sensor, scale, SearchSettings(), None)
    return ctx, base_units


def _with(ctx, base, effect: str, values: dict):
    """The base model plus ``effect`` (started at ``values``), fitted on every unit."""
    params = EFFECTS[effect].params
    vector = base.vector.copy()
    for name in params:
        vector[INDEX[name]] = values.get(name, vector[INDEX[name]])
    sim = ctx.sim.with_tau_scale(base.tau_scale)
    return fit_output_error(sim, vector, tuple(base.free) + tuple(params), base.x0, torque_scale=ctx.torque_scale)


@pytest.fixture(scope="module")
def torque_bias_on_an_encoder(tmp_path_factory):
    spec = oracle.OracleSpec(effect="torque_bias", size=0.02, noise=0.0, ticks=4096, declare_ticks=True,
                             with_torque=True, mixed=True, seed=1)
    return spec, _context(oracle.generate(tmp_path_factory.mktemp("tb"), spec))


def test_a_right_model_on_encoder_data_is_one_model_across_regimes(torque_bias_on_an_encoder):
    spec, (ctx, base) = torque_bias_on_an_encoder
    fit = _with(ctx, base, "torque_bias", oracle.library_params(spec))
    why, records = regime_inconsistency(ctx, Evidence("torque_bias", params=("torque_bias",)), fit, base)
    assert why == ""
    loads = next(r for r in records if r["split"] == ["light-load", "heavy-load"])
    # The old fixed allowance would have called it a stand-in; its own floor is of that size.
    assert loads["gain_over_floor"] > REGIME_MATERIAL
    assert loads["model_floor_over_floor"] > 0.3 * loads["gain_over_floor"]


def test_a_model_without_the_effect_at_work_is_not_one_model(torque_bias_on_an_encoder):
    """The model without the torque bias its data hold: the light and the heavy loads want
    other parameters, by far more than the model's own floor (the stability gate: no effect
    parameter is there for the value test to catch)."""
    _, (ctx, base) = torque_bias_on_an_encoder
    why, records = regime_inconsistency(ctx, Evidence("torque_bias", params=("torque_bias",)), base, base)
    assert "not one model" in why, records
    worst = max(records, key=lambda r: r["gain_over_floor"])
    assert worst["gain_over_floor"] > 10 * max(worst["model_floor_over_floor"], REGIME_MATERIAL)


def _value_split(monkeypatch, gain_over_floor: float):
    """regime_inconsistency on one fake split whose halves put the effect's value far apart (a
    Wald statistic far above its limit, 98 % of its size) while the whole model passes the
    stability test; the halves' own parameters gain ``gain_over_floor`` × the noise variance."""
    from types import SimpleNamespace

    import numpy as np

    from admittance.ident import regime

    floor, joint = 2e-3, 2.1e-3
    labels = ("large-swing", "small-swing")
    record = {"split": list(labels), "statistic": 0.0, "limit": 20.0, "rmse_joint": joint,
              "rmse_apart": float(np.sqrt(joint**2 - gain_over_floor * floor**2)), "effect": ["stribeck_torque"],
              "effect_wald": 1.4e4, "effect_limit": 11.2, "effect_relative": 0.98,
              "params": {"stribeck_torque": {"large-swing": [0.114, 0.06], "small-swing": [7.27, 2.6e-6]}}}
    monkeypatch.setattr(regime, "noise_of", lambda *a, **k: SimpleNamespace(floor=floor))
    monkeypatch.setattr(regime, "_regimes", lambda ctx, fit: [(labels, None)])
    monkeypatch.setattr(regime, "_stability", lambda *a, **k: (dict(record), []))
    monkeypatch.setattr(regime, "model_floor", lambda *a, **k: {labels: 0.0})
    why, _ = regime.regime_inconsistency(SimpleNamespace(sim=None, sensor=None), Evidence("stribeck"),
                                         SimpleNamespace(rmse=joint), SimpleNamespace(rmse=10e-3))
    return why


def test_an_effect_value_the_halves_move_and_the_data_support_is_a_stand_in(monkeypatch):
    """The value test itself: separate values that fit materially better (twice the fixed
    allowance) say the effect follows the regime. Fails with the value test removed."""
    assert "its value differs" in _value_split(monkeypatch, 2 * REGIME_MATERIAL)


def test_an_effect_value_moved_along_a_flat_direction_is_no_regime(monkeypatch):
    """Stribeck on the small swings of 6 encoder drops (families' regime row, seed 1): one half
    put the level at 7.3 N·m and 0.057 rad/s for 0.07× the noise variance; one value fits both
    halves as well, so the effect is one law across them. Fails without the materiality rule."""
    assert _value_split(monkeypatch, 0.5 * REGIME_MATERIAL) == ""
