"""Residual verdict pieces: whiteness, noise estimate, binning; and the stratified split."""

from __future__ import annotations

import numpy as np
import pytest

from admittance.formats.dataset import TrialData
from admittance.ident.fit import autocorrelation_time
from admittance.ident.residual import binned_rms, ljung_box, noise_estimate
from admittance.ident.split import stratified_pick


def test_white_noise_is_white_and_a_smooth_error_is_not():
    rng = np.random.default_rng(0)
    white = [rng.normal(0, 0.002, 700) for _ in range(4)]
    _, p_white = ljung_box(white)
    assert p_white > 0.01
    t = np.linspace(0, 6, 700)
    smooth = [0.003 * np.sin(3 * t) + rng.normal(0, 0.002, t.size) for _ in range(4)]
    _, p_smooth = ljung_box(smooth)
    assert p_smooth < 1e-6
    assert autocorrelation_time(smooth) > 5 * autocorrelation_time(white)


def test_noise_estimate_ignores_slow_model_error():
    rng = np.random.default_rng(2)
    t = np.linspace(0, 8, 1000)
    residual = 0.02 * np.sin(2 * t) + rng.normal(0, 0.002, t.size)
    assert abs(noise_estimate([residual]) - 0.002) < 0.0003


def test_binned_rms_finds_the_bad_region():
    speed = np.linspace(0, 5, 1000)
    residual = np.where(speed < 1, 0.01, 0.001)
    bins = binned_rms(speed, residual)
    assert bins[0]["rms"] > 5 * bins[-1]["rms"]


def _trial(name, distance, direction):
    t = np.arange(20) * 0.01
    return TrialData(name, t, t, None, 0.0, 1.0, {"bob_distance": distance, "direction": direction})


def test_stratified_pick_spreads_over_distances_and_directions():
    trials = [_trial(f"{d}_{s}_{k}", d, s) for d in (0.2, 0.3, 0.4) for s in ("cw", "ccw") for k in range(3)]
    picked, rest = stratified_pick(trials)
    assert sorted(picked + rest) == list(range(len(trials)))
    assert len(picked) == 6
    assert {trials[i].meta["bob_distance"] for i in picked} == {0.2, 0.3, 0.4}
    assert {trials[i].meta["direction"] for i in picked} == {"cw", "ccw"}
    assert stratified_pick(trials) == (picked, rest)  # deterministic


def test_stratified_pick_small():
    assert stratified_pick([_trial("a", 0.2, "cw")]) == ([], [0])
    picked, rest = stratified_pick([_trial("a", 0.2, "cw"), _trial("b", 0.3, "cw")])
    assert len(picked) == 1 and len(rest) == 1


def test_an_empty_piece_adds_nothing_to_the_autocorrelation_time():
    """A trial cut to nothing (a fidelity segment with no held-in sample) is skipped, not an
    FFT of length 0."""
    t = np.linspace(0, 6, 700)
    smooth = [0.003 * np.sin(3 * t)]
    assert autocorrelation_time([*smooth, np.empty(0), np.zeros(1)]) == autocorrelation_time(smooth)


def test_ljung_box_ignores_an_empty_segment():
    """A segment with no samples (a cut recording) changes nothing and warns of nothing."""
    import warnings

    rng = np.random.default_rng(3)
    segments = [rng.normal(size=400), rng.normal(size=300)]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with_empty = ljung_box([segments[0], np.array([]), segments[1]])
    assert with_empty == ljung_box(segments)


def _fitted_drops(tmp_path):
    """Four synthetic drops, the base model fitted to them, and their angle sensor."""
    from admittance.formats.dataset import load_dataset
    from admittance.ident.angle_sensor import sensor_for
    from admittance.ident.equation_error import fit_equation_error, initial_states
    from admittance.ident.fit import fit_output_error
    from admittance.ident.model import Simulator, free_params
    from admittance.ident.synthetic import SynthSpec, generate

    ds = load_dataset(generate(tmp_path, SynthSpec(n_trials=4, duration=3.0, seed=3)))
    start, tau = fit_equation_error(ds.trials, ds.mode)
    sim = Simulator(ds.trials, ds.mode, "stick", 1e-3, tau)
    fit = fit_output_error(sim, start, free_params(ds.mode, [], False), initial_states(ds.trials), max_iter=5)
    return sim, fit, sensor_for(ds.trials, None)


def test_a_fits_noise_verdict_is_computed_once_per_simulator_and_sensor(tmp_path, monkeypatch):
    from dataclasses import replace

    from admittance.ident.residual import noise_of

    sim, fit, sensor = _fitted_drops(tmp_path)
    runs = []
    real_run = type(sim).run
    monkeypatch.setattr(type(sim), "run", lambda self, *a, **k: runs.append(1) or real_run(self, *a, **k))
    first = noise_of(sim, fit, sensor)
    simulated = len(runs)
    assert simulated > 0 and noise_of(sim, fit, sensor) is first and len(runs) == simulated
    # Another simulator (even of the same trials), or a fit made from this one, is asked again.
    other = sim.subset(range(len(sim.trials)))
    assert noise_of(other, fit, sensor) == first and len(runs) == 2 * simulated
    moved = replace(fit, residuals=[2.0 * r for r in fit.residuals])
    assert noise_of(sim, moved, sensor).rmse == pytest.approx(2.0 * first.rmse)
