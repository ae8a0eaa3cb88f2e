"""The passivity guard's keys, its live changes and its telemetry (docs/fidelity.md, "The passivity
guard"; the guard itself is tested in rtcore/rt/src/passivity_tests.rs and cycle_passivity_tests.rs).

- its three keys are in the configuration (defaults: on, 2 mJ, 1 N·m·s/rad), in the loop's
  configuration and in ``params()``, and a bad value is refused by the loop with the key named;
- a live set that changes them is all or nothing;
- its energy and damping are in every telemetry row, the state message, the recording's rows, the
  stats (``passivity``), the monitor, and an episode is told once in one line.
"""

from __future__ import annotations

import numpy as np
import pytest

from admittance import _rtcore
from admittance.daemon import config
from admittance.daemon.faults import FaultWatch
from admittance.daemon.loopconfig import loop_config
from admittance.daemon.monitor import joint_line, passivity_line
from admittance.daemon.recording import COLUMNS, Recorder
from admittance.daemon.telemetry import columns_by_joint, latest_state
from admittance.errors import ConfigError

KEYS = ("passivity_guard", "passivity_margin", "passivity_damping_max")


def loop_dict(**joint) -> dict:
    return {"port": "/dev/null-admittance-test", "rate_hz": 1000, "rt_priority": 0,
            "joints": [{"id": 1, "virtual_inertia": 0.02, "virtual_damping": 0.05, **joint}]}


def test_the_defaults_are_on_and_reach_the_loop():
    cfg = config.load_default()
    joint = cfg.joints[0]
    assert (joint.passivity_guard, joint.passivity_margin, joint.passivity_damping_max) == (1, 0.002, 1.0)
    params = _rtcore.AdmittanceLoop(loop_config(cfg, "/dev/null-admittance-test")).params()
    assert [params[f"{joint.id}.{k}"] for k in KEYS] == [1.0, 0.002, 1.0]


@pytest.mark.parametrize(("joint", "key"), [
    ({"passivity_guard": 0.5}, "passivity_guard"),
    ({"passivity_guard": float("nan")}, "passivity_guard"),
    ({"passivity_margin": 0.0}, "passivity_margin"),
    ({"passivity_margin": float("inf")}, "passivity_margin"),
    ({"passivity_damping_max": -1.0}, "passivity_damping_max"),
])
def test_the_loop_refuses_a_bad_guard_setting_naming_the_key(joint, key):
    with pytest.raises(ConfigError, match=key):
        _rtcore.AdmittanceLoop(loop_dict(**joint))


def test_a_live_set_of_the_guard_is_all_or_nothing():
    loop = _rtcore.AdmittanceLoop(loop_dict())
    before = loop.params()
    accepted, reason = loop.set_params({"1.passivity_margin": 0.05, "passivity_guard": 3.0})
    assert not accepted and "passivity_guard" in reason
    assert loop.params() == before
    assert loop.set_params({"1.passivity_margin": 0.05, "passivity_guard": 0, "passivity_damping_max": 2.0}) \
        == (True, "")
    after = loop.params()
    assert (after["1.passivity_margin"], after["1.passivity_guard"], after["1.passivity_damping_max"]) == (0.05, 0, 2)


def test_a_bad_value_in_the_file_names_the_key(tmp_path):
    text = config.data.bench_config().read_text().replace("[[joints]]", "[[joints]]\npassivity_margin = 0.0", 1)
    path = tmp_path / "bench.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match="passivity_margin"):
        config.load_config(path)


def records(n: int = 4) -> np.ndarray:
    rows = np.zeros(n, dtype=_rtcore.AdmittanceLoop.telemetry_dtype())
    rows["id"] = 1
    rows["cycle"] = np.arange(n)
    rows["deadline_ns"] = rows["t_ns"] = 1_000_000_000 + np.arange(n) * 1_000_000
    rows["goal_tick"] = rows["present_tick"] = 2048
    rows["passivity_energy"] = [0.0, -0.001, -0.003, -0.004]
    rows["passivity_damping"] = [0.0, 0.0, 0.001, 0.0011]
    return rows


def test_every_row_state_and_recording_carry_the_guard(tmp_path):
    cfg = config.load_default()
    rows = records()
    columns = columns_by_joint(rows, cfg)[1]
    assert columns["passivity_damping"].tolist() == [0.0, 0.0, 0.001, 0.0011]
    state = latest_state(rows, cfg)
    assert (state.joints[0].passivity_energy, state.joints[0].passivity_damping) == (-0.004, 0.0011)
    assert {"passivity_energy", "passivity_damping"} <= set(COLUMNS)
    rec = Recorder(tmp_path, [(1, "MX-64")], measured_theta=True, t0=0.0)
    rec.append(1, columns)
    rec.close()
    table = np.genfromtxt(next(tmp_path.glob("joint1_*.csv")), delimiter=",", names=True)
    assert table["passivity_damping"].tolist() == [0.0, 0.0, 0.001, 0.0011]


class QuietLoop:
    def set_sensor_faults(self, names):
        pass

    def stop_request(self):
        return None


def test_an_episode_is_told_once_in_one_line_and_shown_by_the_monitor():
    cfg = config.load_default()
    told: list[str] = []
    watch = FaultWatch(cfg, told.append)
    guard = {"id": 1, "energy": -0.004, "port_energy": -0.01, "model_dissipated": 0.0, "damping": 0.0, "episodes": 0}
    watch.poll({"passivity": [guard]}, {}, QuietLoop())
    assert told == []
    for _ in range(3):  # the same episode over several ticks
        watch.poll({"passivity": [{**guard, "episodes": 1, "damping": 0.2}]}, {}, QuietLoop())
    assert len(told) == 1 and "\n" not in told[0], told
    assert told[0].startswith("joint 1: passivity guard acting") and "0.004 J" in told[0] and "0.002 J" in told[0]
    assert passivity_line({"passivity": [{**guard, "episodes": 1, "damping": 0.2}]}) == \
        ["passivity  joint 1 -4.0 mJ +0.2 N·m·s/rad 1×"]
    assert passivity_line({"passivity": [guard]}) == [], "nothing to say while it never acted"
    line = joint_line({"id": 1, "force": 0.0, "tau": 0.0, "theta": 0.0, "omega": 0.0, "goal_tick": 2048,
                       "passivity_damping": 0.2})
    assert "PASSIVITY GUARD +0.2 N·m·s/rad" in line


def test_the_stats_carry_each_joints_guard():
    stats = _rtcore.AdmittanceLoop(loop_dict()).stats()
    assert [sorted(g) for g in stats["passivity"]] == \
        [sorted(["id", "energy", "port_energy", "model_dissipated", "damping", "episodes"])]
    assert stats["passivity"][0]["id"] == 1 and stats["passivity"][0]["damping"] == 0.0
