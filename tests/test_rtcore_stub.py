"""The typed boundary to the Rust core: the stub ``admittance/_rtcore.pyi`` against the built
module (mypy's stubtest: every name, every signature, nothing missing or extra), the loop's
configuration builder against the stub's ``LoopConfigDict`` (mypy), and the defaults and the
key grammar the daemon takes from the core."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from admittance import _rtcore

REPO = Path(__file__).resolve().parents[1]
pytest.importorskip("mypy")


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", *args], cwd=REPO, capture_output=True, text=True, timeout=300)


def test_the_stub_matches_the_built_module():
    done = _run("mypy.stubtest", "admittance._rtcore")
    assert done.returncode == 0, done.stdout + done.stderr


def test_the_loop_configuration_is_built_to_its_type():
    done = _run("mypy", "--follow-imports=silent", "--ignore-missing-imports", "--no-incremental",
                "admittance/daemon/loopconfig.py", "admittance/loop_config.py")
    assert done.returncode == 0, done.stdout + done.stderr


def test_the_daemon_takes_the_loops_defaults_from_the_core():
    from admittance.daemon import config

    tables = {"baudrate": config.BusConfig, "zero_tick": config.JointConfig, "direction": config.JointConfig,
              "deadband": config.SensorConfig, "lowpass_hz": config.SensorConfig, "rate_hz": config.LoopConfig,
              "sync_read_divisor": config.LoopConfig, "stale_timeout_ms": config.LoopConfig,
              "ramp_time_s": config.LoopConfig, "velocity_max": config.LimitsConfig,
              "acceleration_max": config.LimitsConfig, "max_recoveries": config.FaultsConfig,
              "horn_speed_max": config.FaultsConfig}
    assert set(tables) == set(_rtcore.LOOP_DEFAULTS)
    for name, table in tables.items():
        field = table.__dataclass_fields__[name]
        assert field.default == _rtcore.LOOP_DEFAULTS[name], name


@pytest.mark.parametrize("name, parsed", [
    ("virtual_damping", (None, "virtual_damping")),
    ("3.virtual_damping", (3, "virtual_damping")),
    ("3.limits.velocity_max", (3, "velocity_max")),
    ("limits.velocity_max", (None, "velocity_max")),
    ("252.x", (252, "x")),
    ("x.y", (None, "x.y")),
])
def test_one_parser_of_the_key_grammar(name, parsed):
    assert _rtcore.split_param_name(name) == parsed


@pytest.mark.parametrize("name", ["253.virtual_damping", "999.virtual_damping", "0001000.x"])
def test_an_id_beyond_the_dynamixel_range_is_refused(name):
    with pytest.raises(ValueError, match=f"0..={_rtcore.MAX_JOINT_ID}"):
        _rtcore.split_param_name(name)
