"""`AdmittanceLoop` configuration and live parameters, without starting the loop."""

from __future__ import annotations

import time

import pytest
from hypothesis import given
from hypothesis import strategies as st

from admittance import _rtcore
from admittance.errors import ConfigError, DeviceError


SERVO = {"time_constant": 0.02, "inertial_time": 0.0, "dead_time": 0.001, "compliance": 0.02, "deadband": 0.0}


def config(**overrides) -> dict:
    joints = [{"id": 1, "virtual_inertia": 0.02, "virtual_damping": 0.05},
              {"id": 2, "virtual_inertia": 0.03, "virtual_damping": 0.05, "axis": "ty"}]
    cfg = {"port": "/dev/null-admittance-test", "rate_hz": 1000, "rt_priority": 0, "joints": joints}
    cfg.update(overrides)
    return cfg


@pytest.mark.parametrize("overrides, message", [
    ({"rate_hz_typo": 1}, "unknown key \"rate_hz_typo\""),
    ({"joints": []}, "at least one joint"),
    ({"joints": [{"virtual_inertia": 1.0}]}, "\"id\" is required"),
    ({"joints": [{"id": 1, "axis": "w"}]}, "axis"),
    ({"joints": [{"id": 1, "direction": 2}]}, "direction"),
    ({"joints": [{"id": 1, "limits": {"position_max": -4.0}}]}, "position_max"),
    ({"joints": [{"id": 1, "limits": {"position_min": 1.0, "position_max": 0.5}}]}, "position_min"),
    ({"joints": [{"id": 1, "limits": {"velocity_max": 1e300}}]}, "velocity_max"),
    ({"joints": [{"id": 1, "virtual_damping": 100.0}]}, "h·B/I"),
    ({"joints": [{"id": 1}, {"id": 2, "goal_address": 30}]}, "must be equal"),
    ({"protocol": 3}, "protocol"),
    ({"rt_policy": "rr"}, "rt_policy"),
    ({"lowpass_hz": 600.0}, "lowpass_hz"),
    ({"trigger": "sometimes"}, "config.trigger"),
    ({"phase_lock": "yes"}, "phase_lock"),
    ({"joints": [{"id": 1, "servo_compensation": 1.0}]}, "needs a servo model"),
    ({"joints": [{"id": 1, "servo": {"time_constant": 0.02}}]}, "inertial_time\" is required"),
    ({"joints": [{"id": 1, "servo": {**SERVO, "time_constant": -1.0}}]}, "time_constant"),
    ({"joints": [{"id": 1, "servo": {**SERVO, "backlash": 0.04}}]}, "backlash must be within"),
    ({"joints": [{"id": 1, "servo": {**SERVO, "backlash_torque": -0.1}}]}, "backlash_torque must be within"),
    ({"joints": [{"id": 1, "servo": SERVO, "servo_compensation": 2.0}]}, "servo_compensation"),
])
def test_bad_configurations_name_the_key(overrides, message):
    with pytest.raises(ConfigError, match=message):
        _rtcore.AdmittanceLoop(config(**overrides))


def test_a_missing_port_is_a_device_error_at_start():
    loop = _rtcore.AdmittanceLoop(config())
    with pytest.raises(DeviceError, match="cannot open"):
        loop.start()
    assert not loop.running() and loop.heartbeat() == 0


def test_params_are_flat_and_set_all_or_nothing():
    loop = _rtcore.AdmittanceLoop(config())
    before = loop.params()
    assert before["1.virtual_inertia"] == 0.02 and before["2.virtual_inertia"] == 0.03
    assert before["bias"] == [0.0] * 6
    accepted, reason = loop.set_params({"1.virtual_damping": 0.1, "deadband": 2.0, "2.virtual_inertia": 0.0})
    assert not accepted and "joint 2" in reason and "inertia" in reason
    assert loop.params() == before
    accepted, reason = loop.set_params({"virtual_damping": 25.0})  # h·B/I ≥ 1 for joint 1
    assert not accepted and "h·B/I" in reason
    accepted, reason = loop.set_params({"nonsense": 1.0})
    assert not accepted and "unknown parameter" in reason
    accepted, reason = loop.set_params({"1.virtual_damping": 0.1, "deadband": 2.0,
                                        "2.limits.velocity_max": 1.0, "bias": [1, 2, 3, 4, 5, 6]})
    assert (accepted, reason) == (True, "")
    after = loop.params()
    assert after["1.virtual_damping"] == 0.1 and after["2.virtual_damping"] == 0.05
    assert after["2.velocity_max"] == 1.0 and after["deadband"] == 2.0
    assert after["bias"] == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]


def test_the_sink_takes_up_to_six_components():
    sink = _rtcore.AdmittanceLoop(config(force_capacity=2)).force_sink()
    assert sink.push(1, [1.0, 2.0, 3.0])
    assert sink.push(2, [1.0] * 6)
    assert not sink.push(3, [0.0]), "a full ring drops the sample"
    with pytest.raises(ValueError):
        sink.push(4, [0.0] * 7)
    with pytest.raises(ValueError, match="finite"):
        sink.push(5, [float("nan")])
    with pytest.raises(ValueError, match="monotonic_ns"):
        sink.push(time.time_ns(), [0.0])


def test_a_servo_model_turns_compensation_on_and_a_live_set_may_turn_it_off():
    loop = _rtcore.AdmittanceLoop(config(joints=[{"id": 1, "servo": SERVO}, {"id": 2}]))
    assert loop.params()["1.servo_compensation"] == 1.0 and loop.params()["2.servo_compensation"] == 0.0
    assert loop.set_params({"1.servo_compensation": 0.0}) == (True, "")
    before = loop.params()
    accepted, reason = loop.set_params({"servo_compensation": 1.0, "1.virtual_damping": 0.2})
    assert not accepted and "joint 2" in reason and "servo model" in reason
    assert loop.params() == before, "all or nothing"


def test_telemetry_dtype_is_the_documented_record():
    names = _rtcore.AdmittanceLoop.telemetry_dtype().names
    assert names == ("cycle", "t_ns", "deadline_ns", "id", "force", "torque", "theta", "omega", "goal_tick",
                     "present_tick", "period_error_ns", "latency_ns", "fault", "mode", "passivity_energy",
                     "passivity_damping")
    assert len(_rtcore.AdmittanceLoop(config()).drain_telemetry()) == 0


@given(inertia=st.floats(1e-4, 1.0), damping=st.floats(0.0, 2000.0))
def test_acceptance_matches_the_stability_bound(inertia, damping):
    loop = _rtcore.AdmittanceLoop(config())
    accepted, reason = loop.set_params({"1.virtual_inertia": inertia, "1.virtual_damping": damping})
    assert accepted == (damping / 1000.0 / inertia < 1.0), reason
