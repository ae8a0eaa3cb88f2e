"""The NumPy Savitzky–Golay, bounded least squares and χ² tail used instead of SciPy imports."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from admittance.ident.smoothing import chi2_sf, nonneg_lstsq, savgol

from helpers import examples


@pytest.mark.parametrize("deriv", [0, 1, 2])
def test_savgol_is_exact_on_cubics_including_the_edges(deriv):
    dt = 0.01
    t = dt * np.arange(50)
    y = 0.3 - 2 * t + 5 * t**2 - 7 * t**3
    exact = [y, -2 + 10 * t - 21 * t**2, 10 - 42 * t][deriv]
    np.testing.assert_allclose(savgol(y, 11, 3, deriv, dt), exact, atol=1e-8)


def test_savgol_smooths_noise():
    rng = np.random.default_rng(1)
    y = rng.normal(0, 1, 2000)
    assert np.std(savgol(y, 21, 3, 0, 1.0)) < 0.6


@settings(max_examples=examples(40))
@given(st.integers(0, 10_000))
def test_nonneg_lstsq_matches_brute_force(seed):
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(30, 3))
    y = rng.normal(size=30)
    x = nonneg_lstsq(a, y, np.zeros(3))
    assert np.all(x >= 0)
    cost = np.sum((a @ x - y) ** 2)
    for point in itertools.product(np.linspace(0, 2, 9), repeat=3):  # no feasible grid point beats it
        assert cost <= np.sum((a @ np.array(point) - y) ** 2) + 1e-9


def test_chi2_tail():
    assert chi2_sf(0.0, 20) == 1.0
    assert chi2_sf(31.41, 20) == pytest.approx(0.05, abs=0.003)  # the tabulated 95 % point
    assert chi2_sf(37.57, 20) == pytest.approx(0.01, abs=0.002)
