"""Contract 2 parameter files: round trip, validation with file and key named."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from admittance import data
from admittance.errors import ConfigError
from admittance.formats import paramfile

from helpers import examples

MX64 = data.params_file("MX-64")


def test_round_trip(tmp_path):
    path = tmp_path / "mx64.toml"
    params = {"motor_inertia": 0.0147, "damping": 0.0347, "coulomb": 0.0843, "angle_offset": -0.01}
    paramfile.dump(path, params, model={"motor": "MX-64", "friction": "stick"}, fit={"effects": ["angle_offset"]})
    doc = paramfile.load(path)
    assert doc["params"] == params
    assert doc["model"]["motor"] == "MX-64"
    assert doc["fit"]["effects"] == ["angle_offset"]


def test_a_servo_table_round_trips_and_its_names_agree_with_the_rust_model(tmp_path):
    from admittance import _rtcore

    assert paramfile.SERVO_PARAM_NAMES == tuple(_rtcore.SERVO_PARAM_NAMES)
    assert tuple(paramfile.SERVO_BOUNDS.values()) == tuple(tuple(b) for b in _rtcore.SERVO_DOMAIN)
    assert tuple(k.default for k in paramfile.SERVO_KEYS.values()) == tuple(_rtcore.SERVO_PARAM_DEFAULTS)
    servo = {"time_constant": 0.017, "inertial_time": 0.02, "dead_time": 0.001, "compliance": 0.024, "deadband": 0.002,
             "backlash": 0.0087, "backlash_torque": 0.02}
    path = tmp_path / "with_servo.toml"
    paramfile.dump(path, {"motor_inertia": 0.0147}, servo=servo)
    assert paramfile.load(path)["servo"] == servo
    assert "servo" not in paramfile.load(MX64)


def test_a_servo_table_without_the_gear_play_means_none_and_a_play_out_of_its_domain_is_refused(tmp_path):
    lag_form = {"time_constant": 0.017, "inertial_time": 0.02, "dead_time": 0.001, "compliance": 0.024,
                "deadband": 0.002}
    path = tmp_path / "old.toml"
    path.write_text("[params]\nmotor_inertia = 0.0147\n[servo]\n" + "".join(f"{k} = {v}\n" for k, v in lag_form.items()))
    assert paramfile.load(path)["servo"] == {**lag_form, "backlash": 0.0, "backlash_torque": 0.0}
    for key, bad in [("backlash", -1e-3), ("backlash", 0.04), ("backlash", 1e300), ("backlash_torque", -0.1),
                     ("backlash_torque", 3.0)]:
        with pytest.raises(ConfigError, match=key):
            paramfile.validate_servo({**lag_form, key: bad}, where="t")
    with pytest.raises(ConfigError, match="time_constant: required"):
        paramfile.validate_servo({k: v for k, v in lag_form.items() if k != "time_constant"}, where="t")


def test_names_agree_with_the_simulator():
    from admittance import _rtcore

    assert paramfile.PARAM_NAMES == tuple(_rtcore.PARAM_NAMES)
    defaults = [0.0 if v is None else v for v in paramfile.PARAM_DEFAULTS.values()]
    assert defaults[1:] == list(_rtcore.PARAM_DEFAULTS)[1:]


@pytest.mark.parametrize(
    "body, fragment",
    [
        ("[params]\nmotor_inertia = 0.01\ndampin = 0.1\n", "dampin: unknown parameter"),
        ("[params]\nmotor_inertia = nan\n", "motor_inertia: value must be finite"),
        ("[params]\ncoulomb = inf\n", "coulomb: value must be finite"),
        ("[params]\ncoulomb = \"high\"\n", "coulomb: expected a number"),
        ("[model]\nfriction = \"viscous\"\n", "friction"),
        ("[model]\nmode = \"other\"\n", "mode"),
        ("params = 3\n", "[params] must be a table"),
        ("[params\n", "not valid TOML"),
        ("[servo]\ntime_constant = 0.02\n", "inertial_time: required"),
        ("[servo]\ntime_constant = 0.0\ninertial_time = 0\ndead_time = 0\ncompliance = 0\ndeadband = 0\n",
         "time_constant: must be in (0"),
        ("[servo]\ntime_constant = 0.02\ninertial_time = 0\ndead_time = 0\ncompliance = 0\ndeadband = -1\n",
         "deadband: must be in [0"),
        ("[servo]\ntime_constnt = 0.02\n", "time_constnt: unknown servo parameter"),
        # Absurd values a hand edit (or a bad fit) could leave: each refused with its key.
        ("[servo]\ntime_constant = 0.02\ninertial_time = 0\ndead_time = 0\ncompliance = 1e300\ndeadband = 0\n",
         "compliance: must be in [-0.5, 0.5]"),
        ("[servo]\ntime_constant = 0.02\ninertial_time = 0\ndead_time = 0\ncompliance = -1e6\ndeadband = 0\n",
         "compliance: must be in"),
        ("[servo]\ntime_constant = 0.02\ninertial_time = 0\ndead_time = 1.0\ncompliance = 0\ndeadband = 1e300\n",
         "dead_time: must be in [-0.02, 0.2]"),
        ("[params]\nmotor_inertia = 1e300\n", "motor_inertia: 1e+300 is outside its physical range"),
        ("[params]\nmotor_inertia = 0.01\ndamping = -1.0\n", "damping: -1.0 is outside its physical range"),
        ("[params]\nmotor_inertia = 0.01\ntorque_gain = 0\n", "torque_gain: 0 is outside"),
    ],
)
def test_bad_files_name_file_and_key(tmp_path, body, fragment):
    path = tmp_path / "bad.toml"
    path.write_text(body)
    with pytest.raises(ConfigError) as err:
        paramfile.load(path)
    assert str(path) in str(err.value)
    assert fragment in str(err.value)
    assert "\n" not in str(err.value)


def test_a_binary_or_huge_file_is_one_line_not_a_traceback(tmp_path):
    binary = tmp_path / "params.toml"
    binary.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(ConfigError, match="not a text file") as err:
        paramfile.load(binary)
    assert "\n" not in str(err.value)
    huge = tmp_path / "huge.toml"
    huge.write_bytes(b"# padding\n" * (paramfile.MAX_TOML_BYTES // 10 + 1))
    with pytest.raises(ConfigError, match="larger than"):
        paramfile.load(huge)


def test_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        paramfile.load(tmp_path / "absent.toml")


def test_dump_refuses_bad_values_before_writing(tmp_path):
    path = tmp_path / "out.toml"
    with pytest.raises(ConfigError, match="damping"):
        paramfile.dump(path, {"motor_inertia": 0.01, "damping": math.nan})
    assert not path.exists()


def params_within_bounds():
    """A dict of some parameters, each value inside its physical range."""
    names = st.sets(st.sampled_from(paramfile.PARAM_NAMES), min_size=1)
    return names.flatmap(lambda chosen: st.fixed_dictionaries(
        {name: st.floats(*paramfile.PARAM_BOUNDS[name], allow_nan=False) for name in chosen}))


@settings(max_examples=examples(50))
@given(params_within_bounds())
def test_round_trip_property(tmp_path_factory, params):
    path = tmp_path_factory.mktemp("pf") / "p.toml"
    paramfile.dump(path, params)
    assert paramfile.load(path)["params"] == {k: float(v) for k, v in params.items()}
