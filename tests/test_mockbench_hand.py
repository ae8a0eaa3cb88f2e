"""Scripted hand-torque profiles and the simulated sensor's force model."""

from __future__ import annotations

import math
import random

import pytest
from hypothesis import given
from hypothesis import strategies as st

from admittance.drivers import optoforce as of
from admittance.errors import ConfigError, DataError
from admittance.mockbench import hand
from admittance.mockbench.simulated_sensor import ForceModel

times = st.floats(0.0, 1e4, allow_nan=False)


@pytest.mark.parametrize("name", sorted(hand.BUILTIN_PROFILES))
@given(t=times)
def test_builtins_are_deterministic_and_bounded_by_their_amplitude(name, t):
    a, b = hand.make_profile(f"{name}"), hand.make_profile(f"{name}")
    bound = getattr(a, "amplitude", 0.0) + abs(getattr(a, "offset", 0.0)) + abs(getattr(a, "torque", 0.0))
    assert a(t) == b(t)
    assert abs(a(t)) <= bound + 1e-12


def test_push_release_pushes_holds_and_lets_go():
    p = hand.make_profile("push-release:amplitude=0.5,period=4,rise=0.5,hold=1,fall=0.1")
    assert p(0.0) == 0.0
    assert p(0.25) == pytest.approx(0.25)
    assert p(1.0) == 0.5
    assert p(1.7) == 0.0
    assert p(4.0 + 1.0) == 0.5  # it repeats


def test_sine_ramp_and_steps_have_their_shapes():
    assert hand.make_profile("sine:amplitude=2,frequency=1")(0.25) == pytest.approx(2.0)
    ramp = hand.make_profile("ramp:amplitude=1,period=2,rest=1")
    assert (ramp(0.0), ramp(1.0), ramp(2.5)) == (0.0, 1.0, 0.0)
    steps = hand.make_profile("steps:amplitude=1,step=0.5")
    assert [steps(0.5 * k + 0.1) for k in range(6)] == [0.0, 0.5, 1.0, -0.5, -1.0, 0.0]


@pytest.mark.parametrize(
    ("spec", "match"),
    [("wave", "unknown hand profile"), ("sine:speed=2", "takes amplitude"), ("sine:amplitude=x", "must be a number"), ("steps:step=0", "positive")],
)
def test_bad_profile_specs_are_config_errors(spec, match):
    with pytest.raises(ConfigError, match=match):
        hand.make_profile(spec)


def test_csv_profiles_are_interpolated_and_held_at_the_ends(tmp_path):
    path = tmp_path / "hand.csv"
    path.write_text("t,tau\n0.0,0.0\n1.0,0.4\n# a comment\n2.0,-0.2\n")
    p = hand.make_profile(str(path))
    assert (p(-1.0), p(0.5), p(1.5), p(10.0)) == (0.0, pytest.approx(0.2), pytest.approx(0.1), -0.2)


@pytest.mark.parametrize(("text", "match"), [("t,tau\n", "no rows"), ("0,1\n0,2\n", "increase"), ("0,a\n", "two numbers")])
def test_bad_csv_profiles_are_data_errors(tmp_path, text, match):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(DataError, match=match):
        hand.load_csv_profile(path)


def test_a_missing_csv_is_a_data_error(tmp_path):
    with pytest.raises(DataError, match="cannot read"):
        hand.make_profile(str(tmp_path / "absent.csv"))


@given(st.floats(-50.0, 50.0), st.sampled_from("xyz"))
def test_force_model_puts_tau_over_the_lever_arm_on_its_axis(tau, axis):
    model = ForceModel(lever_arm=0.1, axis=axis, counts_per_newton=(100.0, 200.0, 300.0))
    counts, status = model.counts(tau, random.Random(0))
    i = "xyz".index(axis)
    expected = round(tau / 0.1 * model.counts_per_newton[i])
    if abs(expected) <= 32767:
        assert counts[i] == expected and status == 0
    else:
        assert abs(counts[i]) == 32767 and of.status_overloads(status) == ["f" + axis]
    assert all(c == 0 for j, c in enumerate(counts) if j != i)


def test_force_model_noise_is_seeded():
    model = ForceModel(noise_std_n=0.5)
    a = [model.counts(0.0, random.Random(3))[0] for _ in range(2)]
    assert a[0] == a[1] and any(a[0])


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [({"lever_arm": 0.0}, "lever_arm"), ({"axis": "tx"}, "force axis"), ({"counts_per_newton": (1.0, 2.0)}, "3 values|3 \\(3-axis\\)"), ({"noise_std_n": -1}, "noise")],
)
def test_force_model_rejects_bad_settings(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        ForceModel(**kwargs)


def test_profiles_are_plain_functions_of_time():
    assert math.isclose(hand.Sine(amplitude=1, frequency=0.5)(1.0), 0.0, abs_tol=1e-12)
