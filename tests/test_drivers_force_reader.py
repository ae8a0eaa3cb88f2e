"""The force-sensor base: bias estimation, tare on a running reader, sinks, and the registry."""

from __future__ import annotations

import sys

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from admittance.drivers import force_reader as fs
from admittance.errors import ConfigError, DataError, DeviceError
from admittance.mockbench.hand import make_profile
from admittance.mockbench.simulated_sensor import ForceModel, ScriptedForceSensor

from helpers import wait_until


def test_bias_is_the_mean_of_still_samples():
    rng = np.random.default_rng(1)
    samples = np.array([1.0, -2.0, 0.5, 0.0, 0.01, 0.0]) + rng.normal(0.0, 0.01, size=(200, 6))
    result = fs.estimate_bias(samples.tolist())
    assert result.accepted and result.reason == ""
    assert np.allclose(result.bias, samples.mean(axis=0))
    assert result.n_samples == 200


def test_samples_must_be_rows_of_six():
    with pytest.raises(DataError, match="rows of 6"):
        fs.estimate_bias([[0.0, 0.0, 0.0]] * 20)


def test_a_moving_sensor_is_refused_with_the_axis_and_its_spread():
    samples = [[0.0, 0.1 * i, 0.0, 0.0, 0.0, 0.0] for i in range(50)]
    result = fs.estimate_bias(samples, max_std=0.25)
    assert not result.accepted and result.bias is None
    assert "fy" in result.reason and "not still" in result.reason


@pytest.mark.parametrize(
    ("samples", "match"),
    [([], "too few"), ([[0.0] * 6] * 3, "too few"), ([[float("nan")] * 6] * 20, "NaN")],
)
def test_unusable_sample_sets_are_refused(samples, match):
    result = fs.estimate_bias(samples)
    assert not result.accepted and match in result.reason


@given(st.lists(st.floats(-1e3, 1e3), min_size=6, max_size=6), st.floats(0.0, 0.2))
def test_constant_offsets_are_recovered_exactly_when_the_noise_is_below_the_bound(offset, spread):
    noise = np.tile([[-1.0], [1.0]], (10, 6)) * spread
    result = fs.estimate_bias((np.array(offset) + noise).tolist(), max_std=1.0)
    assert result.accepted
    assert np.allclose(result.bias, offset, atol=1e-9)


def _mock_sensor(sink, profile: str, rate_hz: float = 1000.0) -> ScriptedForceSensor:
    return ScriptedForceSensor(sink, make_profile(profile), ForceModel(lever_arm=0.1, bias_n=0.0), rate_hz=rate_hz)


def test_tare_on_a_still_sensor_removes_the_offset_from_later_samples():
    buffer = fs.SampleBuffer()
    with _mock_sensor(buffer, "still:torque=0.05") as sensor:  # 0.5 N on x, held
        assert buffer.wait_for(5, timeout=10)
        result = sensor.tare(50, timeout=10)
        assert result.accepted, result.reason
        assert result.bias[0] == pytest.approx(0.5, abs=0.01)
        n = buffer.total
        assert buffer.wait_for(n + 20, timeout=10)
    after = buffer.snapshot()[-10:]
    assert all(abs(forces[0]) < 0.01 for _, forces in after)
    assert sensor.bias == result.bias


def test_tare_refuses_while_the_hand_pushes_and_keeps_the_old_bias():
    buffer = fs.SampleBuffer()
    with _mock_sensor(buffer, "sine:amplitude=0.2,frequency=20") as sensor:
        sensor.set_bias([0.1, 0, 0, 0, 0, 0])
        result = sensor.tare(100, timeout=10)
    assert not result.accepted and "fx" in result.reason
    assert sensor.bias == (0.1, 0, 0, 0, 0, 0)


def test_tare_needs_a_running_sensor():
    with pytest.raises(DeviceError, match="not running"):
        _mock_sensor(fs.SampleBuffer(), "still").tare()


class _FullSink:
    def push(self, t_ns, forces):
        return False


def test_a_full_sink_drops_samples_and_counts_them():
    with _mock_sensor(_FullSink(), "still", rate_hz=1000) as sensor:
        assert wait_until(lambda: sensor.samples_dropped >= 5)
    assert sensor.stats()["samples_pushed"] == 0



def test_start_and_stop_are_idempotent_and_restartable():
    buffer = fs.SampleBuffer()
    sensor = _mock_sensor(buffer, "still")
    sensor.stop()
    sensor.start()
    sensor.start()
    assert sensor.running
    sensor.stop()
    sensor.stop()
    assert not sensor.running
    with sensor:
        assert sensor.running


def test_registry_imports_kinds_lazily_and_names_unknown_ones():
    sys.modules.pop("admittance.drivers.can_sensor", None)
    assert fs.sensor_class("can").__name__ == "CanForceReader"
    with pytest.raises(ConfigError, match="unknown sensor kind 'ati'"):
        fs.sensor_class("ati")
    with pytest.raises(ConfigError, match="needs kind"):
        fs.create_sensor({}, fs.SampleBuffer())


def test_create_sensor_builds_each_kind_from_a_sensor_table():
    buffer = fs.SampleBuffer()
    opto = fs.create_sensor({"kind": "optoforce", "port": "/dev/null", "counts_per_newton": [1, 2, 3]}, buffer)
    can = fs.create_sensor({"kind": "can", "port": "vcan0", "interface": "virtual", "can_id": 0x120, "counts_per_newton": 100}, buffer)
    mock = fs.create_sensor({"kind": "mock", "profile": "sine", "lever_arm": 0.2}, buffer)
    assert (opto.kind, opto.port) == ("optoforce", "/dev/null")
    assert (can.kind, can.can_id, can.interface) == ("can", 0x120, "virtual")
    assert mock.kind == "mock"
    with pytest.raises(ConfigError, match="needs 'port'"):
        fs.create_sensor({"kind": "optoforce", "counts_per_newton": 1}, buffer)


def test_a_sink_without_push_is_a_config_error():
    with pytest.raises(ConfigError, match="sink"):
        _mock_sensor(object(), "still")
