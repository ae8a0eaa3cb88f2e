"""`admittance mock-bench` as a subprocess, and MockBench in-process."""

from __future__ import annotations

import json
import signal

import pytest

from admittance import data
from admittance.drivers.dynamixel import ServoBus
from admittance.drivers.optoforce import OptoForceSerialReader
from admittance.drivers.force_reader import SampleBuffer
from admittance.errors import ConfigError
from admittance.mockbench.bench import MockBench, params_path
from admittance.mockbench.cli import parse_effects

from helpers import first_line, start_mock_bench

CPN = 451.89


def test_print_ports_gives_one_json_line_working_ports_and_a_clean_sigterm():
    proc = start_mock_bench("--profile", "still:torque=0.105")
    try:
        ports = json.loads(first_line(proc))
        assert set(ports) == {"bus", "sensor"}
        assert ports["bus"].startswith("/dev/pts/") and ports["sensor"].startswith("/dev/pts/")
        with ServoBus(ports["bus"], reply_slack_ms=200.0) as servos:
            assert [(s.id, s.model, s.protocol) for s in servos.scan(range(0, 4))] == [(1, "MX-64", 2)]
        buffer = SampleBuffer()
        with OptoForceSerialReader(ports["sensor"], CPN, buffer):
            assert buffer.wait_for(20, timeout=30)
        assert buffer.snapshot()[-1][1][0] == pytest.approx(1.0, abs=0.01)  # 0.105 N·m at 0.105 m
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert out == ""  # nothing after the one JSON line


def test_options_reach_the_bench_and_sigint_also_exits_zero():
    proc = start_mock_bench("--servos", "2", "--model", "MX-28", "--protocol", "1", "--effect", "cogging_amplitude=0.01")
    try:
        ports = json.loads(first_line(proc))
        with ServoBus(ports["bus"], protocol=1, reply_slack_ms=200.0) as servos:
            assert [(s.id, s.model) for s in servos.scan(range(0, 4))] == [(1, "MX-28"), (2, "MX-28")]
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0


def test_a_bad_option_is_one_line_on_stderr_and_a_non_zero_exit():
    proc = start_mock_bench("--profile", "wobble")
    _, err = proc.communicate(timeout=60)
    assert proc.returncode != 0
    assert err.strip().count("\n") == 0 and "unknown hand profile 'wobble'" in err


def test_effects_parse_and_unknown_parameters_are_refused():
    assert parse_effects(["cogging_amplitude=0.02", "cogging_period=32"]) == {"cogging_amplitude": 0.02, "cogging_period": 32.0}
    with pytest.raises(ConfigError, match="NAME=VALUE"):
        parse_effects(["cogging_amplitude"])
    with pytest.raises(ConfigError, match="unknown parameter"):
        MockBench(effects={"wobble": 1.0})


def test_the_hand_pushes_the_horn_and_the_sensor_with_the_same_torque():
    with MockBench(profile="still:torque=0.2", sensor_rate_hz=333) as bench:
        buffer = SampleBuffer()
        with OptoForceSerialReader(bench.sensor_port, CPN, buffer):
            assert buffer.wait_for(10, timeout=30)
        state = bench.bus.servo_state(bench.hand_servo_id)
    assert state["external_torque"] == pytest.approx(0.2)
    assert buffer.snapshot()[-1][1][0] * 0.105 == pytest.approx(0.2, abs=0.005)


def test_the_can_variant_exposes_its_channel_and_no_pty():
    with MockBench(sensor="can", can_channel="bench-can-test") as bench:
        assert bench.sensor_port is None and bench.can_channel == "bench-can-test"
        assert bench.ports()["can"]["channel"] == "bench-can-test"


def test_models_map_to_their_parameter_files(repo_root):
    assert params_path("MX-64") == data.params_file("MX-64") and params_path("MX-64").name == "mx64.toml"
    with pytest.raises(ConfigError, match="no fitted parameters for XM430-W350"):
        MockBench(model="XM430-W350")


def test_servo_tables_choose_model_parameters_and_mockbus_options(repo_root):
    servos = [
        {"id": 1},
        {"id": 3, "model": "XM430-W350", "params_file": str(data.params_file("MX-64")), "kt": 1.2, "resistance": 5.0, "initial_theta": 0.5},
    ]
    with MockBench(servos=servos, profile="still") as bench:
        assert bench.bus.servo_state(3)["theta"] == pytest.approx(0.5)
        with ServoBus(bench.bus_port, reply_slack_ms=200.0) as bus:
            assert [(s.id, s.model) for s in bus.scan()] == [(1, "MX-64"), (3, "XM430-W350")]
