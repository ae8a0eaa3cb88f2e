"""The daemon's configuration: validation messages, defaults, path resolution, documentation."""

from __future__ import annotations

import dataclasses
import re
import tomllib
from pathlib import Path

import pytest
import tomli_w
from hypothesis import given, settings
from hypothesis import strategies as st

from admittance import data
from admittance.daemon import config
from admittance.daemon.schema import describe
from admittance.errors import ConfigError

from helpers import examples

REPO = Path(__file__).resolve().parents[1]
MX64 = data.params_file("MX-64")


def minimal() -> dict:
    return {
        "bus": {"port": "/dev/ttyUSB0"},
        "joints": [{"id": 1, "model": "MX-64", "params": str(MX64)}],
        "sensor": {"kind": "optoforce", "port": "/dev/ttyACM0", "lever_arm": 0.1},
    }


def write(tmp_path: Path, doc: dict) -> Path:
    path = tmp_path / "daemon.toml"
    path.write_text(tomli_w.dumps(doc))
    return path


def error_of(tmp_path: Path, doc: dict) -> str:
    with pytest.raises(ConfigError) as info:
        config.load_config(write(tmp_path, doc))
    message = str(info.value)
    assert "\n" not in message
    return message


def test_shipped_configurations_load():
    for path in (data.bench_config(), data.example_config()):
        cfg = config.load_config(path)
        assert cfg.joints and cfg.zenoh.prefix


def test_defaults_fill_in_and_virtual_values_come_from_the_fitted_plant(tmp_path):
    cfg = config.load_config(write(tmp_path, minimal()))
    joint = cfg.joints[0]
    fitted = tomllib.loads(MX64.read_text())["params"]
    assert joint.virtual_inertia == fitted["motor_inertia"]
    assert joint.virtual_damping == fitted["damping"]
    assert joint.virtual_coulomb == fitted["coulomb"]
    assert joint.lever_arm == 0.1 and joint.zero_tick == 2048
    assert cfg.zenoh.listen == ["tcp/127.0.0.1:7447"] and cfg.zenoh.scouting is False
    assert cfg.stop.torque_policy == "hold" and cfg.loop.rate_hz == 1000.0


def test_explicit_virtual_values_win(tmp_path):
    doc = minimal()
    doc["joints"][0].update(virtual_inertia=0.03, virtual_damping=0.0, virtual_coulomb=0.01)
    joint = config.load_config(write(tmp_path, doc)).joints[0]
    assert (joint.virtual_inertia, joint.virtual_damping, joint.virtual_coulomb) == (0.03, 0.0, 0.01)


def test_params_path_is_resolved_beside_the_config_then_cwd_then_the_package(tmp_path, monkeypatch):
    doc = minimal()
    doc["joints"][0]["params"] = "mine.toml"
    (tmp_path / "mine.toml").write_text(MX64.read_text().replace("0.01467", "0.02"))
    assert config.load_config(write(tmp_path, doc)).joints[0].virtual_inertia == 0.02
    monkeypatch.chdir(tmp_path / "..")
    doc["joints"][0]["params"] = "params/mx28.toml"  # not beside, not in cwd: the shipped fit
    assert config.load_config(write(tmp_path, doc)).joints[0].params == str(data.params_file("MX-28"))
    doc["joints"][0]["params"] = "config/params/mx28.toml"  # a checkout's former layout still resolves
    assert config.load_config(write(tmp_path, doc)).joints[0].params == str(data.params_file("MX-28"))
    (tmp_path / "cwd" / "params").mkdir(parents=True)  # a user's own file in the working directory wins
    (tmp_path / "cwd" / "params" / "mx28.toml").write_text(MX64.read_text())
    monkeypatch.chdir(tmp_path / "cwd")
    doc["joints"][0]["params"] = "params/mx28.toml"
    assert config.load_config(write(tmp_path, doc)).joints[0].params == str(tmp_path / "cwd/params/mx28.toml")
    doc["joints"][0]["params"] = "../secret.toml"
    assert "not found" in error_of(tmp_path, doc)
    del doc["joints"][0]["params"]  # the model's own file by default
    assert config.load_config(write(tmp_path, doc)).joints[0].params.endswith("mx64.toml")


@pytest.mark.parametrize("mutate, expected", [
    (lambda d: d["bus"].update(baudrat=1), r"\[bus\]: unknown key 'baudrat' \(did you mean 'baudrate'\?\)"),
    (lambda d: d.update(zenho={}), r"unknown table \[zenho\] \(did you mean 'zenoh'\?\)"),
    (lambda d: d["bus"].update(protocol=3), r"\[bus\]\.protocol: expected one of 1, 2, got 3"),
    (lambda d: d["bus"].update(baudrate="fast"), r"\[bus\]\.baudrate: expected a number"),
    (lambda d: d["bus"].pop("port"), r"\[bus\]\.port: required key is missing"),
    (lambda d: d.pop("sensor"), r"\[sensor\] is required"),
    (lambda d: d["joints"][0].update(id=300), r"\[\[joints\]\] #1\.id: must be <= 252"),
    (lambda d: d["joints"][0].update(virtual_damping=-1.0), r"virtual_damping: must be >= 0"),
    (lambda d: d["joints"][0].update(virtual_inertia=0.0), r"virtual_inertia: must be >= 0\.0001 kg·m²"),
    (lambda d: d["joints"].append(dict(d["joints"][0])), r"duplicate joint id 1"),
    (lambda d: d["joints"][0].update(virtual_damping=50.0), r"\[joints\.1\] virtual_\*: h·B/I = .* must be < 1"),
    (lambda d: d["joints"][0].update(params="nowhere.toml"), r"params: file 'nowhere.toml' not found"),
    (lambda d: d["joints"][0].update(limits={"position_min": 1.0, "position_max": 0.5}),
     r"limits\.position_min: must be below position_max"),
    (lambda d: d["joints"][0].update(limits={"velocity_mx": 1.0}), r"did you mean 'velocity_max'"),
    (lambda d: d["joints"][0].update(plant={}), r"unknown key 'plant'"),  # filled in, never read
    (lambda d: d["joints"][0].update(model="MX-65"), r"model: 'MX-65' is not a Protocol 2\.0 model \(did you mean 'MX-64'\?\)"),
    (lambda d: d.update(bus={"port": "/dev/x", "protocol": 1}) or d["joints"][0].update(model="XM430-W350"),
     r"'XM430-W350' is not a Protocol 1\.0 model"),
    (lambda d: d["sensor"].update(kind="laser"), r"\[sensor\]\.kind: expected one of"),
    (lambda d: d["sensor"].update(lever_arm=0.0), r"lever_arm: must be at least 0\.001 m either side of 0"),
    (lambda d: d["sensor"].update(counts_per_newton=[1.0]), r"counts_per_newton: expected 3 values"),
    (lambda d: d["sensor"].update(port="mock"), r"needs the simulated bench"),
    (lambda d: d.update(loop={"rate_hz": 1000, "stale_timeout_ms": 0}), r"stale_timeout_ms: must be > 0"),
    (lambda d: d.update(zenoh={"state_rate_hz": 20}), r"state_rate_hz: must be >= 50"),
    (lambda d: d.update(zenoh={"mode": "client"}), r"\[zenoh\]\.connect: required with mode = \"client\""),
    (lambda d: d.update(zenoh={"encoding": "cbor"}), r"encoding: expected one of 'json', 'msgpack'"),
    (lambda d: d.update(zenoh={"prefix": "a//b"}), r"prefix: 'a//b' is not a valid key expression"),
    (lambda d: d.update(stop={"torque_policy": "float"}), r"torque_policy: expected one of 'hold', 'torque_off'"),
    (lambda d: d.update(joints=[]), r"\[\[joints\]\] must be a non-empty array"),
    (lambda d: d.update(zenoh={"listen": ["tcp/127.0.0.1:99999"]}),
     r"\[zenoh\]\.listen\[0\]: 'tcp/127\.0\.0\.1:99999': the port must be a number 0\.\.65535"),
    (lambda d: d.update(zenoh={"listen": [""]}), r"\[zenoh\]\.listen\[0\]: '' is not an endpoint"),
    (lambda d: d.update(zenoh={"connect": ["foo/bar"]}), r"\[zenoh\]\.connect\[0\]: 'foo/bar': unknown protocol 'foo'"),
    (lambda d: d.update(zenoh={"connect": ["tcp/256.1.1.1:7447"]}), r"'256\.1\.1\.1' is not an IPv4 address"),
    (lambda d: d.update(zenoh={"listen": ["tcp/[::g]:1"]}), r"in brackets is not an IPv6 address"),
])
def test_errors_name_the_key_and_the_problem_in_one_line(tmp_path, mutate, expected):
    doc = minimal()
    mutate(doc)
    assert re.search(expected, error_of(tmp_path, doc))


def test_unreadable_files_give_one_line(tmp_path):
    with pytest.raises(ConfigError, match="configuration file not found"):
        config.load_config(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[bus\nport = 1")
    with pytest.raises(ConfigError, match="not valid TOML"):
        config.load_config(bad)


def test_compensation_needs_a_servo_model_in_the_parameter_file(tmp_path):
    doc = minimal()
    doc["joints"][0]["servo_compensation"] = 1.0
    assert "servo_compensation: 1 needs a servo model" in error_of(tmp_path, doc)
    doc["joints"][0]["servo_compensation"] = 0.0
    assert config.load_config(write(tmp_path, doc)).joints[0].servo_compensation == 0.0
    doc["joints"][0]["servo_compensation"] = 1.5
    assert "servo_compensation: must be <= 1" in error_of(tmp_path, doc)


def test_a_lumped_parameter_file_is_refused(tmp_path):
    lumped = tmp_path / "lumped.toml"
    lumped.write_text('[model]\nmode = "lumped"\n[params]\nmotor_inertia = 1.0\n')
    doc = minimal()
    doc["joints"][0]["params"] = str(lumped)
    assert "lumped fit" in error_of(tmp_path, doc)


@settings(max_examples=examples(60))
@given(table=st.sampled_from(["bus", "sensor", "loop", "stop", "zenoh", "record"]),
       value=st.one_of(st.text(max_size=5), st.lists(st.integers(), max_size=2), st.booleans(),
                       st.floats(allow_nan=True), st.integers()))
def test_any_bad_value_is_a_config_error_naming_its_key(tmp_path_factory, table, value):
    """Fuzz every key of a table with arbitrary values: either accepted, or one ConfigError line."""
    cls = config.TABLES[table]
    for field in dataclasses.fields(cls):
        doc = minimal()
        doc.setdefault(table, {})[field.name] = value
        try:
            config.parse_config(doc, tmp_path_factory.getbasetemp() / "x.toml")
        except ConfigError as exc:
            assert "\n" not in str(exc)


def test_with_overrides_makes_the_record_path_absolute(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cfg = config.with_overrides(config.load_config(write(tmp_path, minimal())), record="rec")
    assert config.record_dir(cfg) == tmp_path / "rec"


def test_every_key_is_documented():
    doc = (REPO / "docs" / "daemon.md").read_text()
    tables = {**config.TABLES, "joints": config.JointConfig, "joints.limits": config.LimitsConfig}
    for table, cls in tables.items():
        for key in describe(cls):
            if key.get("internal"):
                continue
            assert f"`{key['name']}`" in doc, f"[{table}] {key['name']} is not in docs/daemon.md"


def test_run_check_prints_the_resolved_configuration(capsys):
    from admittance.cli import main

    assert main(["run", "--check", "--config", str(data.example_config())]) == 0
    out = capsys.readouterr().out
    assert "joint 1: MX-64" in out and "I=0.02 kg·m²" in out and "zenoh: bench/arm1" in out


@pytest.mark.parametrize("listen, mode, warned", [
    (["tcp/127.0.0.1:7447"], "peer", []),
    (["tcp/[::1]:7447", "tcp/localhost:7448", "unixsock-stream//tmp/z.sock"], "peer", []),
    ([], "peer", ["listen is empty"]),
    (["tcp/0.0.0.0:7447"], "peer", ["tcp/0.0.0.0:7447 is reachable from every interface"]),
    (["tcp/[::]:7447", "tcp/192.168.1.5:7447"], "router", ["every interface", "the network"]),
    ([], "client", []),  # a client listens nowhere
])
def test_listening_beyond_loopback_is_warned_about(listen, mode, warned):
    from admittance.daemon.endpoints import exposure_warnings

    zcfg = config.ZenohConfig(listen=listen, mode=mode, connect=["tcp/10.0.0.1:7447"])
    warnings = exposure_warnings(zcfg)
    assert len(warnings) == len(warned)
    for line, expected in zip(warnings, warned):
        assert expected in line and "can set parameters and tare" in line and "\n" not in line
