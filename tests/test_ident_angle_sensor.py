"""The sensor model: an encoder's grid is found (or declared), and a residual that is only the
sensor's own error reads as "nothing left", for an encoder and for coloured motion-capture
noise alike; real structure does not."""

from __future__ import annotations

import math

import numpy as np
import pytest

from admittance.errors import DataError
from admittance.formats.dataset import load_dataset
from admittance.ident.angle_sensor import Sensor, infer_quantum, noise_verdict, rest_noise, sensor_for

TICK = 2 * math.pi / 4096


def _swing(n=1200, seed=0):
    """A decaying swing that sticks half way through (a drop test comes to rest)."""
    t = np.arange(n) / 120
    theta = 1.2 * np.exp(-0.6 * t) * np.cos(3.5 * t + 0.1 * seed)
    theta[n // 2 :] = theta[n // 2]
    return theta


def test_an_encoder_grid_is_inferred_and_snapped_to_whole_ticks():
    theta = [TICK * np.round(_swing(seed=s) / TICK) + 17 * TICK for s in range(3)]
    assert infer_quantum(theta) == pytest.approx(TICK, rel=1e-12)
    # Written to a file with 9 significant digits, the grid is still found.
    assert infer_quantum([np.array([float(f"{v:.9g}") for v in th]) for th in theta]) == pytest.approx(TICK)


def test_continuous_angles_have_no_grid():
    rng = np.random.default_rng(1)
    assert infer_quantum([_swing() + rng.normal(0, 0.002, 1200)]) == 0.0
    assert infer_quantum([np.zeros(100)]) == 0.0  # never moves: nothing to infer from


def test_manifest_declares_the_encoder(tmp_path):
    (tmp_path / "a.csv").write_text("t,theta\n" + "\n".join(f"{i / 100},{0.01 * i}" for i in range(20)))
    manifest = 'encoder_ticks = {}\n[[trials]]\nfile = "a.csv"\n'
    (tmp_path / "manifest.toml").write_text(manifest.format(4096))
    ds = load_dataset(tmp_path)
    assert ds.encoder_ticks == 4096
    assert sensor_for(ds.trials, ds.encoder_ticks).source == "manifest"
    for bad in ("0", "-5", "1.5", '"many"', "true"):
        (tmp_path / "manifest.toml").write_text(manifest.format(bad))
        with pytest.raises(DataError, match="encoder_ticks"):
            load_dataset(tmp_path)


def _quantised_residual(model_error: float, seed: int = 0):
    """A true swing read by a 4096-tick encoder; the model is the truth plus ``model_error``·a slow wave."""
    rng = np.random.default_rng(seed)
    true = [_swing(seed=s) for s in range(4)]
    sensor = Sensor(TICK, 0.0, "manifest")
    measured = [sensor.read(th + rng.normal(0, 2e-4, th.size)) for th in true]
    simulated = [th + model_error * np.sin(np.arange(th.size) / 40) for th in true]
    return measured, [s - m for s, m in zip(simulated, measured)], sensor


def test_a_perfect_model_of_encoder_data_leaves_nothing():
    """The rounding error is constant at rest and a sawtooth when slow: as motion-capture noise
    it reads as structure; against the encoder's own replicas it is nothing."""
    measured, residual, sensor = _quantised_residual(0.0)
    assert noise_verdict(measured, residual, sensor).nothing_left
    assert not noise_verdict(measured, residual, Sensor()).nothing_left  # the old, sensor-blind verdict


def test_model_error_above_a_tick_is_not_noise():
    measured, residual, sensor = _quantised_residual(3 * TICK)
    assert not noise_verdict(measured, residual, sensor).nothing_left


def test_coloured_noise_at_rest_is_recognised_and_whitened():
    """AR(1) noise (ρ = 0.9) fools second differences by 4×; where the model sticks, the
    residual is the noise itself, and an AR(1) that whitens it is the noise model."""
    rng = np.random.default_rng(3)
    n, rho, sigma = 3000, 0.9, 0.002
    noise = np.empty(n)
    noise[0] = rng.normal(0, sigma)
    for i in range(1, n):
        noise[i] = rho * noise[i - 1] + rng.normal(0, sigma * math.sqrt(1 - rho**2))
    at_rest = np.ones(n, bool)
    at_rest[:300] = False
    found_sigma, found_rho = rest_noise([noise], [at_rest])
    assert found_sigma == pytest.approx(sigma, rel=0.15) and found_rho == pytest.approx(rho, abs=0.05)
    verdict = noise_verdict([np.zeros(n)], [noise], Sensor(), [at_rest])
    assert verdict.nothing_left and verdict.correlation > 0.8
    moving_error = noise + np.where(at_rest, 0.0, 0.004 * np.sin(np.arange(n) / 20))  # model error in motion
    assert not noise_verdict([np.zeros(n)], [moving_error], Sensor(), [at_rest]).nothing_left
    creeping = noise + 0.004 * np.sin(np.arange(n) / 60)  # the joint still moves where the model sticks
    assert rest_noise([creeping], [at_rest]) is None
    assert not noise_verdict([np.zeros(n)], [creeping], Sensor(), [at_rest]).nothing_left


def test_a_residual_exactly_constant_at_rest_has_no_rest_noise_and_no_crash():
    """A noiseless angle (a recording's model angle where the model sticks) leaves a residual
    that is exactly constant at rest: there is no noise to model there, and the verdict still
    comes (it divided by zero once, in `admittance fidelity` on a compensated session)."""
    n = 2000
    at_rest = np.zeros(n, bool)
    at_rest[500:] = True
    residual = np.where(at_rest, 0.0, 0.001 * np.sin(np.arange(n) / 30))
    assert rest_noise([residual], [at_rest]) is None
    verdict = noise_verdict([np.zeros(n)], [residual], Sensor(), [at_rest])
    assert math.isfinite(verdict.rmse)
