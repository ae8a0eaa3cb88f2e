"""Breakaway detection on force ramps simulated with the plant's stick friction."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from admittance import sim
from admittance.cli import main
from admittance.errors import DataError
from admittance.thesis import breakaway
from admittance.formats.converters import ConvertedTrial, write_dataset

RATE = 0.05  # N·m/s, a slow hand ramp


def ramp_trial(level, sign, noise, seed=0, duration=6.0, inertia=0.002, name="ramp", meta=None):
    """A joint at rest under a torque ramp sign·RATE·t; it breaks away at |τ| = level."""
    t = np.arange(0.0, duration, 1 / 120)
    tau = sign * RATE * t
    rt = sim.make_trial(t, tau, 0.0, 0.0)
    theta = sim.simulate(rt, {"motor_inertia": inertia, "coulomb": level, "damping": 0.01}, 0.0, 0.0)
    theta = theta + np.random.default_rng(seed).normal(0.0, noise, t.size)
    return SimpleNamespace(name=name, t=t, theta=theta, tau=tau, meta=meta or {})


@pytest.mark.parametrize("level", [0.0176, 0.1061, 0.1234])
@pytest.mark.parametrize("sign", [1, -1])
@pytest.mark.parametrize("noise", [0.0, 5e-4, 1e-3])
def test_detected_torque_matches_the_friction_level(level, sign, noise):
    result = breakaway.breakaway_of(ramp_trial(level, sign, noise, seed=int(level * 1e4)))
    assert result.torque == pytest.approx(level, rel=0.05, abs=0.003)
    assert result.direction == ("ccw" if sign > 0 else "cw")
    assert result.onset_time == pytest.approx(level / RATE, abs=0.003 / RATE)


@pytest.mark.parametrize("level", [0.0176, 0.1234])
def test_average_of_noisy_trials_is_unbiased(level):
    """At OptiTrack-like noise (2 mrad) single trials scatter by ~2 mN·m; six average it out,
    as table 3.1 does."""
    results = [breakaway.breakaway_of(ramp_trial(level, s, 2e-3, seed=k)) for k in range(3) for s in (1, -1)]
    summary = breakaway.summarise(results)
    assert summary["average"] == pytest.approx(level, abs=0.002)


def test_onset_fit_beats_the_threshold_crossing():
    """Reading the torque where the angle crosses the band would overstate the breakaway."""
    trial = ramp_trial(0.1, 1, 1e-3, seed=5)
    late = trial.tau[np.argmax(np.abs(trial.theta) > breakaway.K_SIGMA * 1e-3)]
    fitted = breakaway.breakaway_of(trial).torque
    assert abs(fitted - 0.1) < abs(late - 0.1)


def test_direction_label_wins_over_ramp_sign():
    result = breakaway.breakaway_of(ramp_trial(0.05, 1, 0.0, meta={"direction": "cw"}))
    assert result.direction == "cw"


def test_summary_averages_like_table_3_1():
    results = [
        breakaway.Breakaway("a", "ccw", 0.10, 1.0, 1e-4),
        breakaway.Breakaway("b", "ccw", 0.12, 1.0, 1e-4),
        breakaway.Breakaway("c", "cw", 0.14, 1.0, 1e-4),
    ]
    summary = breakaway.summarise(results)
    assert summary["average_by_direction"] == {"ccw": pytest.approx(0.11), "cw": pytest.approx(0.14)}
    assert summary["average"] == pytest.approx(0.12)
    assert "**Overall average**" in breakaway.to_markdown(summary)


def test_no_motion_and_no_torque_are_errors():
    still = ramp_trial(0.5, 1, 1e-4)  # the ramp never reaches the level
    with pytest.raises(DataError, match="never leaves"):
        breakaway.breakaway_of(still)
    free = SimpleNamespace(name="f", t=still.t, theta=still.theta, tau=None, meta={})
    with pytest.raises(DataError, match="no tau"):
        breakaway.breakaway_of(free)
    with pytest.raises(DataError, match="too short"):
        breakaway.detect_onset(still.t[:12], still.theta[:12])


def test_cli_on_a_dataset(tmp_path, capsys):
    trials = []
    for k, (sign, direction) in enumerate([(1, "ccw"), (-1, "cw")]):
        tr = ramp_trial(0.1, sign, 5e-4, seed=k)
        trials.append(ConvertedTrial(f"ramp_{direction}", tr.t, tr.theta, tr.tau, {"direction": direction}))
    folder = write_dataset(tmp_path / "ds", trials, {"motor": "MX-64"})
    out = tmp_path / "res" / "breakaway.json"
    assert main(["breakaway", str(folder), "--json", str(out)]) == 0
    assert "Average for ccw" in capsys.readouterr().out
    summary = json.loads(out.read_text())
    assert summary["average"] == pytest.approx(0.1, rel=0.05)
    assert set(summary["average_by_direction"]) == {"ccw", "cw"}


@pytest.mark.parametrize("shape, reason", [
    (lambda t: 0.3 * np.sin(2 * np.pi * 0.5 * t), "not a straight line"),
    (lambda t: np.where(t < 1.0, 0.0, 0.4), "not a straight line"),
])
def test_a_segment_that_is_not_a_ramp_is_refused_with_its_reason(shape, reason):
    trial = ramp_trial(0.08, 1.0, 0.0)
    trial.tau = shape(trial.t)
    with pytest.raises(DataError, match=f"not a torque ramp.*{reason}"):
        breakaway.breakaway_of(trial)
    assert breakaway.not_a_ramp(trial.t, np.full_like(trial.t, 0.2)) == "tau is constant"
