"""Held-out scoring (identify._scores): each held-out trial's initial state is fitted under the
model from the data's starts and from the starts nearby (fit.nearby_starts), screened in one
batch. With stick friction the error is a landscape of basins in the initial state, and LM
from the data's starts alone can stay in the wrong one: the score would then blame the model
for the scorer. The test fails with the nearby starts removed (tried by mutation)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from oracles import ivp as oracle
from admittance.formats.dataset import load_dataset
from admittance.ident.angle_sensor import sensor_for
from admittance.ident.equation_error import initial_state_starts
from admittance.ident.fit import FitResult, NEARBY_ANGLES, NEARBY_RATES, fit_initial_states_multi, nearby_starts, screen_starts
from admittance.ident.identify import _scores
from admittance.ident.model import INDEX, Simulator, default_vector

# The Stribeck model identify fitted on the four training trials of this set (2026-11-28):
# the breakaway 2.4x too high and narrower than the truth's, a model that fits its own trials
# to 0.28 mrad and makes the held-out trial's release a narrow target.
FITTED = {"motor_inertia": 0.014655335, "damping": 0.035525488, "coulomb": 0.082688148,
          "stribeck_torque": 0.296914909, "stribeck_velocity": 0.119438895}


@pytest.fixture(scope="module")
def held_out(tmp_path_factory):
    """Trial 00 of the families' regime row (Stribeck at 1.5x Coulomb, 4096-tick encoder, seed 1),
    the model above, and the data's candidate starts."""
    spec = oracle.OracleSpec(effect="stribeck", size=1.5 * 0.084, noise=0.0, ticks=4096, declare_ticks=True, seed=1)
    dataset = load_dataset(oracle.generate(tmp_path_factory.mktemp("stribeck_encoder"), spec))
    trials = dataset.trials
    vector = default_vector()
    for name, value in FITTED.items():
        vector[INDEX[name]] = value
    sim = Simulator(trials, dataset.mode, "stick", 1e-3, 1.0)
    starts = initial_state_starts(trials)
    # The model as identify handed it over: its training error (0.28 mrad, the joint fit's) sets
    # the nearby starts' angle step, with the encoder's grid when coarser (it is here: 1.5 mrad).
    model = FitResult(vector, 1.0, (), {}, np.zeros((5, 2)), [np.full(100, 0.28e-3)], 0, 0, 0.0)
    return sim.subset([0]), model, [s[[0]] for s in starts], sensor_for(trials, dataset.encoder_ticks)


def _mrad(fit) -> float:
    return 1e3 * fit.rmse


def test_the_nearby_starts_find_the_basin_the_data_starts_miss(held_out):
    sim, model, data_starts, sensor = held_out
    alone = fit_initial_states_multi(sim, model.vector, [screen_starts(sim, model.vector, data_starts)])
    assert _mrad(alone) > 4.0, "the trap this test is about: from the data's starts the trial sticks a swing off"
    before, after = _scores(sim, model, model, data_starts, sensor, lambda *a, **k: None)
    assert after is before
    assert _mrad(after) < 2.0, f"scored {_mrad(after):.2f} mrad; from the data's starts alone {_mrad(alone):.2f}"


def test_the_score_is_never_worse_than_from_the_data_starts_alone(held_out):
    sim, model, data_starts, sensor = held_out
    alone = fit_initial_states_multi(sim, model.vector, [screen_starts(sim, model.vector, data_starts)])
    # A sensor grid 50x coarser widens the nearby starts far past the basin: the data's pick still counts.
    wide = type(sensor)(sensor.quantum * 50, sensor.phase, sensor.source)
    _, after = _scores(sim, model, model, data_starts, wide, lambda *a, **k: None)
    assert after.rmse <= alone.rmse


def test_nearby_starts_span_the_grid_around_each_trial():
    x0 = np.array([[1.0, 0.0], [-0.5, 0.2]])
    starts = nearby_starts(x0, 0.01, 0.1)
    assert len(starts) == len(NEARBY_ANGLES) * len(NEARBY_RATES) - 1
    moves = {(round(float(s[0, 0] - 1.0) / 0.01), round(float(s[0, 1]) / 0.1)) for s in starts}
    assert (0, 0) not in moves and len(moves) == len(starts)
    assert all(np.allclose(s[1] - x0[1], s[0] - x0[0]) for s in starts)  # every trial moved alike
    assert len(nearby_starts(x0, 0.01, 0.0)) == len(NEARBY_ANGLES) - 1  # a step of 0 moves nothing


def test_a_trial_scored_as_well_as_the_training_trials_gets_no_nearby_starts(held_out, monkeypatch):
    """The nearby starts cost a batch of 153 simulations per trial: paid only where a trial is
    scored NEARBY_TRIGGER times worse than the model fits its own (3–6 % more trial simulations
    of identify on 30 drops otherwise)."""
    sim, model, data_starts, sensor = held_out
    from admittance.ident import identify

    def refuse(*args):
        raise AssertionError("nearby starts screened for a trial the model already fits")

    good = replace(model, residuals=[np.full(100, 5e-3)])  # a model that fits its training trials to 5 mrad
    monkeypatch.setattr(identify, "nearby_starts", refuse)
    before, _ = _scores(sim, good, good, data_starts, sensor, lambda *a, **k: None)
    assert _mrad(before) < 2 * 5.0
