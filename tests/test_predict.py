"""Section 3.3's tests: torque → predicted position, position → calculated torque, the lag."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from admittance import sim
from admittance.cli import main
from admittance.errors import ConfigError, DataError
from admittance.formats import paramfile
from admittance.thesis import predict
from admittance.formats.converters import ConvertedTrial, write_dataset

TRUTH = {"motor_inertia": 0.0147, "damping": 0.035, "coulomb": 0.02, "tanh_k": 100.0}
LOAD_INERTIA = 0.005
GRAVITY = 0.2


def driven_trial(params=TRUTH, friction="tanh", delay=0.0, duration=8.0, noise=0.0):
    """A joint pushed through large swings by a smooth hand torque (always moving)."""
    t = np.arange(0.0, duration, 1 / 120)
    tau = 0.4 * np.sin(2 * np.pi * 0.5 * t) + 0.15 * np.sin(2 * np.pi * 1.3 * t + 1.0)
    rt = sim.make_trial(t, tau, LOAD_INERTIA, GRAVITY)
    theta = sim.simulate(rt, {**params, "time_delay": delay}, 0.0, 0.0, max_step=1e-4, friction=friction)
    theta = theta + np.random.default_rng(0).normal(0.0, noise, t.size)
    return SimpleNamespace(name="push.csv", t=t, theta=theta, tau=tau, load_inertia=LOAD_INERTIA,
                           gravity_torque=GRAVITY, meta={})


def full(params):
    return dict(zip(paramfile.PARAM_NAMES, paramfile.full_vector(params)))


def test_true_parameters_predict_position_and_torque():
    trial = driven_trial(noise=5e-4)
    pred = predict.predict_trial(trial, full(TRUTH), "tanh")
    m = pred.metrics
    assert m.position_rmse < 0.02
    assert m.position_corr > 0.99
    amplitude = np.std(trial.tau)
    assert m.torque_rmse_model < 0.15 * amplitude
    assert m.torque_corr_model > 0.98
    assert abs(m.torque_lag) <= 1 / 120 + 1e-9
    # the thesis formula leaves gravity out: it cannot do as well on a gravity-loaded joint
    assert m.torque_rmse_thesis > m.torque_rmse_model


def test_wrong_parameters_predict_worse():
    trial = driven_trial()
    good = predict.predict_trial(trial, full(TRUTH), "tanh").metrics
    bad = predict.predict_trial(trial, full({**TRUTH, "damping": 0.2, "motor_inertia": 0.03}), "tanh").metrics
    assert bad.position_rmse > 3 * good.position_rmse
    assert bad.torque_rmse_model > 3 * good.torque_rmse_model


def test_delay_shows_as_lag_of_measured_torque():
    """Torque that acts 50 ms late: the recorded torque leads the motion it causes, so the
    calculated torque (from the motion) is late by 50 ms; the measured one leads by 50 ms."""
    trial = driven_trial(delay=0.05)
    m = predict.predict_trial(trial, full(TRUTH), "tanh").metrics
    assert m.torque_lag == pytest.approx(-0.05, abs=1.5 / 120)
    corrected = predict.predict_trial(trial, full({**TRUTH, "time_delay": 0.05}), "tanh").metrics
    assert corrected.torque_rmse_model < m.torque_rmse_model


def test_lag_of_a_shifted_signal():
    grid = np.arange(0, 10, 0.01)
    calc = np.sin(2 * np.pi * 0.7 * grid) + 0.3 * np.sin(2 * np.pi * 1.9 * grid)
    measured = np.interp(grid - 0.12, grid, calc)
    assert predict.lag_of(grid, calc, measured) == pytest.approx(0.12, abs=0.011)


def test_filtered_derivatives_of_a_sine_on_non_uniform_time():
    rng = np.random.default_rng(2)
    t = np.cumsum(rng.uniform(0.004, 0.006, 2000))
    theta = 0.5 * np.sin(2 * np.pi * 0.5 * t)
    grid, vel, acc, _ = predict.filtered_derivatives(t, theta)
    inner = slice(50, -50)
    w = 2 * np.pi * 0.5
    np.testing.assert_allclose(vel[inner], 0.5 * w * np.cos(w * grid[inner]), atol=0.02)
    np.testing.assert_allclose(acc[inner], -0.5 * w**2 * np.sin(w * grid[inner]), atol=0.05)


def test_filter_needs_a_fast_enough_rate():
    t = np.arange(0, 10, 0.2)  # 5 Hz sampling: a 5 Hz low-pass is above Nyquist
    with pytest.raises(DataError, match="too slow"):
        predict.filtered_derivatives(t, np.sin(t))


def test_model_torque_stick_sign_and_corrections():
    p = full({"motor_inertia": 0.01, "coulomb": 0.1, "coulomb_asym": 0.02, "torque_bias": 0.05})
    vel = np.array([-1.0, 0.0, 1.0])
    out = predict.model_torque(p, 0.01, 0.0, np.zeros(3), vel, np.zeros(3), "stick")
    np.testing.assert_allclose(out, [-0.08, 0.0, 0.12])
    t = np.arange(5.0)
    np.testing.assert_allclose(predict.corrected_torque(t, np.ones(5), p), 0.95)


def test_lumped_file_is_refused(tmp_path):
    lumped = tmp_path / "lumped.toml"
    paramfile.dump(lumped, {"motor_inertia": 1.0}, {"mode": "lumped"})
    with pytest.raises(ConfigError, match="lumped"):
        predict.load_params(lumped)


def test_free_swing_gets_the_position_check_only():
    trial = driven_trial(duration=3.0)
    free = SimpleNamespace(**{**vars(trial), "tau": None})
    rt = sim.make_trial(free.t, None, LOAD_INERTIA, GRAVITY)
    free.theta = sim.simulate(rt, TRUTH, 1.0, 0.0, max_step=1e-4, friction="tanh")
    pred = predict.predict_trial(free, full(TRUTH), "tanh")
    assert pred.metrics.position_rmse < 0.01
    assert pred.tau is None and pred.metrics.torque_lag is None
    assert "| – |" in predict.metrics_table([pred])


def test_cli_writes_metrics_and_appendix_b_plots(tmp_path, capsys):
    trial = driven_trial(duration=3.0)
    pushed = ConvertedTrial("push", trial.t, trial.theta, trial.tau, {"bob_distance": 0.3})
    folder = write_dataset(tmp_path / "ds", [pushed], {"motor": "MX-64", "bob": {"mass": 0.05}})
    params = tmp_path / "p.toml"
    paramfile.dump(params, TRUTH, {"motor": "MX-64", "friction": "tanh"})
    out = tmp_path / "out"
    assert main(["predict", str(folder), "--params", str(params), "--out", str(out)]) == 0
    assert "push.csv" in capsys.readouterr().out
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics[0]["trial"] == "push.csv" and np.isfinite(metrics[0]["position_rmse"])
    assert sorted(p.name for p in out.glob("*.png")) == [
        "push_position.png", "push_position_torque.png", "push_torque.png"]


@pytest.mark.parametrize("k", ["nan", "-1", "0"])
def test_cli_bad_thesis_k_is_a_one_line_error(tmp_path, capsys, k):
    assert main(["predict", str(tmp_path), "--params", str(tmp_path / "p.toml"), "--thesis-k", k]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--thesis-k" in err
