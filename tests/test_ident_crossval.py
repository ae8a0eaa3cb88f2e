"""Cross-validation units and the paired score: folds never overlap, few long trials are cut
into time segments, and a gain counts only when it is larger than its uncertainty and most
folds see it."""

from __future__ import annotations

import numpy as np
import pytest

from admittance.ident.crossval import make_folds, paired_gain
from admittance.formats.dataset import TrialData


def _trial(name: str, seconds: float, rate: float = 100.0, distance: float = 0.2) -> TrialData:
    t = np.arange(int(seconds * rate) + 1) / rate
    return TrialData(name, t, np.sin(t), None, 0.01, 0.3, {"bob_distance": distance})


def _check_partition(folds):
    for k in range(folds.n_folds):
        train, held = set(folds.train(k)), set(folds.held(k))
        assert held and train and not train & held  # the held-out units are never fitted on
        assert train | held == set(range(len(folds.units)))
    assert sorted(j for k in range(folds.n_folds) for j in folds.held(k)) == list(range(len(folds.units)))


def test_many_trials_are_folded_whole():
    trials = [_trial(f"t{i}", 3.0, distance=0.2 + 0.05 * (i // 2)) for i in range(7)]
    folds = make_folds(trials, period=1.0)
    assert folds.kind == "trials" and folds.n_folds == 5 and len(folds.units) == 7
    _check_partition(folds)


def test_few_long_trials_are_cut_into_segments_each_fold_training_on_every_trial():
    trials = [_trial("a", 20.0), _trial("b", 20.0)]
    folds = make_folds(trials, period=1.5)
    assert folds.kind == "segments" and folds.n_folds == 4 and len(folds.units) == 8
    _check_partition(folds)
    for k in range(folds.n_folds):  # every trial keeps data in every fold's training part
        assert {folds.units[j].trial for j in folds.train(k)} == {0, 1}
        # the held-out segments of a fold come from different phases of the two swings
        assert len({folds.units[j].start for j in folds.held(k)}) == 2
    seg = folds.data[1]
    assert seg.t[0] == pytest.approx(5.0) and seg.n_samples == folds.units[1].stop - folds.units[1].start
    np.testing.assert_array_equal(seg.theta, trials[0].theta[folds.units[1].start:folds.units[1].stop])


def test_segments_are_at_least_two_periods_long():
    folds = make_folds([_trial("a", 20.0), _trial("b", 20.0)], period=4.0)  # 8 s minimum
    assert folds.kind == "segments" and folds.n_folds == 2
    assert make_folds([_trial("a", 3.0), _trial("b", 3.0)], period=1.0).kind == "trials"  # too short to cut
    assert make_folds([_trial("a", 3.0)], period=1.0) is None


def _residuals(scale_per_unit, n=400, seed=0):
    rng = np.random.default_rng(seed)
    base = [rng.normal(0, 1.0, n) * 0.01 for _ in scale_per_unit]
    return base, [s * b for s, b in zip(scale_per_unit, base)]


def test_a_gain_on_every_fold_is_supported():
    current, candidate = _residuals([0.5, 0.6, 0.4, 0.5])
    gain = paired_gain(current, candidate, [0, 1, 2, 3])
    assert gain.pooled_gain == pytest.approx(0.5, abs=0.05)
    assert gain.folds_supporting == 4 and gain.supported(0.03)


def test_no_gain_and_a_minority_gain_are_not():
    current, candidate = _residuals([1.0, 1.0, 1.0, 1.0])
    assert not paired_gain(current, candidate, [0, 1, 2, 3]).supported(0.03)
    # One fold improves a lot, three get worse: the pooled gain is positive, the folds say no.
    current, candidate = _residuals([0.05, 1.1, 1.1, 1.1])
    current[0] = current[0] * 6  # the improving fold dominates the pooled sum
    candidate[0] = current[0] * 0.05
    gain = paired_gain(current, candidate, [0, 1, 2, 3])
    assert gain.pooled_gain > 0.03 and gain.folds_supporting == 1 and not gain.supported(0.03)


def test_a_gain_within_its_uncertainty_is_not_supported():
    """A 4 % drop on smooth (correlated) residuals: counted as independent samples it would look
    certain; counted in effective samples it is within the noise."""
    rng = np.random.default_rng(5)
    smooth = [np.convolve(rng.normal(0, 1, 600), np.ones(60) / 60, mode="same") for _ in range(4)]
    noise = [np.convolve(rng.normal(0, 1, 600), np.ones(60) / 60, mode="same") for _ in range(4)]
    candidate = [0.96 * s + 0.3 * e for s, e in zip(smooth, noise)]
    gain = paired_gain(smooth, candidate, [0, 1, 2, 3])
    assert gain.autocorrelation_time > 20
    assert not gain.supported(0.03)
