"""Each candidate effect, injected alone and undeclared at a meaningful size, is found, named,
and lowers the held-out error; the ranking's linear algebra is checked on its own."""

from __future__ import annotations

import numpy as np
import pytest

from admittance.ident.dataset import load_dataset
from admittance.ident.effects import _explained
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
    ("torque_bias", 0.02, True),  # N·m
]


@pytest.mark.parametrize("effect, size, with_torque", CASES, ids=[c[0] for c in CASES])
def test_injected_effect_is_found_and_named(tmp_path, effect, size, with_torque):
    folder = generate(tmp_path, SynthSpec(n_trials=8, duration=5.0, jitter=0.2, seed=1,
                                          effects={effect: size}, with_torque=with_torque))
    j = identify_dataset(load_dataset(folder)).to_json()
    assert j["effects"] == [effect]
    assert j["rmse_after"] < 0.8 * j["rmse_before"]
    assert j["rmse_after"] < 0.0025  # back at the 2 mrad noise floor
    assert j["motor_inertia"] == pytest.approx(0.0147, rel=0.05)


def test_clean_torque_driven_data_gets_nothing(tmp_path):
    folder = generate(tmp_path, SynthSpec(n_trials=6, duration=5.0, seed=2, with_torque=True))
    j = identify_dataset(load_dataset(folder)).to_json()
    assert j["effects"] == []


@pytest.mark.parametrize("seed", [0, 1])
def test_correlated_noise_is_not_an_effect(tmp_path, seed):
    """Filtered (AR(1)) sensor noise leaves a residual that is not white, so the search runs;
    nothing may pass validation and significance (σ accounts for the correlation)."""
    folder = generate(tmp_path, SynthSpec(n_trials=7, duration=5.0, jitter=0.2, noise=0.002,
                                          noise_correlation=0.9, seed=300 + seed))
    j = identify_dataset(load_dataset(folder)).to_json()
    assert not j["residual"]["white"]
    assert j["effects"] == []


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
