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
