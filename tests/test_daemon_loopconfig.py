"""The RT loop's configuration dict: addresses from the model table, limits the servo can reach,
and a dict the real `_rtcore.AdmittanceLoop` accepts (constructed only: no I/O)."""

from __future__ import annotations

from pathlib import Path

import pytest
import tomli_w

from admittance import _rtcore
from admittance.daemon import config
from admittance.daemon.loopconfig import loop_config
from admittance.errors import ConfigError

REPO = Path(__file__).resolve().parents[1]


def cfg_for(tmp_path: Path, protocol: int, **joint) -> config.DaemonConfig:
    doc = {"bus": {"port": "/dev/ttyUSB0", "protocol": protocol},
           "joints": [{"id": 1, "model": "MX-64", **joint}, {"id": 2, "model": "MX-28"}],
           "sensor": {"kind": "optoforce", "port": "/dev/ttyACM0", "lever_arm": -0.1, "axis": "y"}}
    path = tmp_path / "d.toml"
    path.write_text(tomli_w.dumps(doc))
    return config.load_config(path)


@pytest.mark.parametrize("protocol, goal, present, torque", [(2, 116, 132, 64), (1, 30, 36, 24)])
def test_addresses_come_from_the_model_table(tmp_path, protocol, goal, present, torque):
    d = loop_config(cfg_for(tmp_path, protocol), "/dev/pts/9")
    assert d["port"] == "/dev/pts/9" and d["protocol"] == protocol
    for j in d["joints"]:
        assert (j["goal_address"], j["present_address"], j["torque_enable_address"]) == (goal, present, torque)
        assert j["axis"] == "y" and j["lever_arm"] == -0.1
    assert d["joints"][0]["virtual_inertia"] == pytest.approx(0.01467)


def test_default_position_limits_are_clipped_to_what_the_goal_range_reaches(tmp_path):
    cfg = cfg_for(tmp_path, 2, zero_tick=3500, limits={"position_min": -1.0})
    limits = loop_config(cfg, "/dev/x")["joints"][0]["limits"]
    assert limits["position_min"] == -1.0
    assert limits["position_max"] == pytest.approx((4095 - 3500) * 2 * 3.141592653589793 / 4096)
    assert loop_config(cfg, "/dev/x")["joints"][1]["limits"]["position_max"] == 3.1  # zero tick 2048: ±3.1


def test_an_explicit_position_limit_beyond_the_reach_is_refused(tmp_path):
    with pytest.raises(ConfigError, match=r"limits\.position_max: must be within \[-5\.3689, 0\.9127\] rad"):
        cfg_for(tmp_path, 2, zero_tick=3500, limits={"position_max": 3.0})


def test_the_real_loop_accepts_the_dict(tmp_path):
    loop = _rtcore.AdmittanceLoop(loop_config(cfg_for(tmp_path, 2, direction=-1), "/dev/null"))
    assert list(loop.ids) == [1, 2]
    params = loop.params()
    assert params["1.virtual_damping"] == pytest.approx(0.03471) and params["2.lever_arm"] == -0.1


def test_a_zero_tick_outside_the_goal_range_is_a_config_error(tmp_path):
    cfg = cfg_for(tmp_path, 2)
    bad = config.dataclasses.replace(cfg, joints=(config.dataclasses.replace(cfg.joints[0], zero_tick=5000),))
    with pytest.raises(ConfigError, match="zero_tick: 5000 is outside"):
        loop_config(bad, "/dev/x")


@pytest.mark.parametrize("loop, mode, locked", [({}, "sample", True), ({"phase_lock": False}, "sample", False),
                                                ({"trigger": "schedule"}, "schedule", False)])
def test_the_loops_trigger_comes_from_the_loop_table(tmp_path, loop, mode, locked):
    cfg = cfg_for(tmp_path, 2)
    cfg = config.dataclasses.replace(cfg, loop=config.dataclasses.replace(cfg.loop, **loop))
    trigger = _rtcore.AdmittanceLoop(loop_config(cfg, "/dev/null")).stats()["trigger"]
    assert (trigger["mode"], trigger["phase_lock"]) == (mode, locked)


def test_an_unknown_trigger_is_a_config_error(tmp_path):
    path = tmp_path / "d.toml"
    path.write_text(tomli_w.dumps({"bus": {"port": "/dev/ttyUSB0"}, "joints": [{"id": 1, "model": "MX-64"}],
                                   "sensor": {"kind": "optoforce", "port": "/dev/x", "lever_arm": 0.1},
                                   "loop": {"trigger": "sometimes"}}))
    with pytest.raises(ConfigError, match=r"loop.*trigger"):
        config.load_config(path)


def test_the_typed_configuration_and_its_dict_make_the_same_loop(tmp_path):
    """The daemon hands the core the typed object (backends.make_loop); the core converts it at
    that call. Its dict (the benches' and tests' form) builds the very same loop."""
    from admittance.daemon.loopconfig import rt_loop_config

    cfg = cfg_for(tmp_path, 2, direction=-1)
    typed = _rtcore.AdmittanceLoop(rt_loop_config(cfg, "/dev/null"))
    plain = _rtcore.AdmittanceLoop(loop_config(cfg, "/dev/null"))
    assert typed.params() == plain.params() and typed.stats()["trigger"] == plain.stats()["trigger"]


def test_an_unset_field_takes_the_loops_own_default():
    from admittance.loop_config import RtJoint, RtLoopConfig

    loop = _rtcore.AdmittanceLoop(RtLoopConfig(port="/dev/null", joints=(RtJoint(id=3),)))
    assert list(loop.ids) == [3]
    assert loop.params()["3.velocity_max"] == _rtcore.LOOP_DEFAULTS["velocity_max"]
    assert loop.params()["ramp_time_s"] == _rtcore.LOOP_DEFAULTS["ramp_time_s"]


def test_the_typed_configuration_is_frozen_and_names_its_fields(tmp_path):
    from admittance.daemon.loopconfig import rt_loop_config
    from admittance.loop_config import RtJoint

    built = rt_loop_config(cfg_for(tmp_path, 2), "/dev/null")
    with pytest.raises(AttributeError):
        built.rate_hz = 1.0  # type: ignore[misc]
    with pytest.raises(TypeError):
        RtJoint(id=1, velocity_max=6.0)  # type: ignore[call-arg]  # a limit, not a joint key
    with pytest.raises(ConfigError, match="expected a LoopConfig or a dict"):
        _rtcore.AdmittanceLoop([("port", "/dev/null")])  # type: ignore[arg-type]
