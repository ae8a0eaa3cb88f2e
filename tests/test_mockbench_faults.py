"""Fault commands on the simulated bench: in-process, over `mock-bench --control`, and as a
timed `--faults` script. Each command's effect is checked on the device a client sees."""

from __future__ import annotations

import os
import signal

import pytest

from admittance.drivers.dynamixel import ServoBus
from admittance.drivers.optoforce import OptoForceSerialReader
from admittance.drivers.sensor import SampleBuffer
from admittance.errors import ConfigError
from admittance.mockbench.bench import BenchConfig, MockBench
from admittance.mockbench.control import send
from admittance.mockbench.faults import FaultScript, check_command

from helpers import mock_bench_process, start_mock_bench, wait_until


# The bench runs in another process that a loaded machine may leave unscheduled for a while.
SLACK_MS = 500.0


@pytest.fixture(scope="module")
def bench():
    with MockBench(BenchConfig(profile="still:torque=0.105")) as b:
        yield b


def test_the_bench_offers_stable_links_to_its_ptys(bench):
    links = bench.links
    assert os.path.realpath(links["bus"]) == bench.bus_port
    assert os.path.realpath(links["sensor"]) == bench.sensor_port
    assert bench.ports(links=True)["links"] == links and "links" not in bench.ports()


@pytest.mark.parametrize(("command", "check"), [
    ("servo 1 hardware-error 0x20", lambda b: b.bus.servo_state(1)["hardware_error"] == 0x20),
    ("servo 1 hardware-error 0", lambda b: b.bus.servo_state(1)["hardware_error"] == 0),
    ("servo 1 torque-off", lambda b: not b.bus.servo_state(1)["torque_enabled"]),
    ("servo 1 brown-out 0", lambda b: b.bus.register(1, "Torque Enable") == 0),
    ("servo 1 glitch 2000 3", lambda b: True),  # what a read then answers: dxlsim's own test
    ("sensor saturate on", lambda b: b.sensor.saturated),
    ("sensor saturate off", lambda b: not b.sensor.saturated),
    ("sensor silence on", lambda b: b.sensor.silent),
    ("sensor silence off", lambda b: not b.sensor.silent),
    ("sensor status 0x2000", lambda b: b.sensor.fault_status == 0x2000),
    ("sensor status 0", lambda b: b.sensor.fault_status == 0),
    ("sensor garbage 10", lambda b: True),
    ("sensor corrupt 2", lambda b: True),
])
def test_each_command_reaches_the_bench(bench, command, check):
    assert bench.command(command) == {"ok": True}
    assert check(bench)


@pytest.mark.parametrize(("command", "match"), [
    ("", "empty"),
    ("servo", "takes an ID"),
    ("servo 1 explode", "expected hardware-error"),
    ("servo 300 torque-off", "within 0..252"),
    ("servo 9 torque-off", "no servo with ID 9"),
    ("servo 1 hardware-error 0x100", "within 0..255"),
    ("servo 1 brown-out 1e9", "within 0..60"),
    ("servo 1 glitch 1e3", "must be an integer"),
    ("servo 1 glitch 5 2000", "within 0..1000"),
    ("sensor saturate maybe", "sensor takes"),
    ("bus reboot", "unplug or replug"),
    ("launch missiles", "unknown command 'launch'"),
    ("x" * 2000, "at most 1024"),
])
def test_a_bad_command_is_a_refusal_with_its_reason_never_an_exception(bench, command, match):
    reply = bench.command(command)
    assert reply["ok"] is False and match in reply["error"], reply


def test_a_script_is_checked_whole_before_it_runs(tmp_path):
    good = tmp_path / "faults.txt"
    good.write_text("# a comment\n0.5 bus unplug\n\n0.2 servo 1 torque-off  # first\n")
    assert [(s.at_s, s.command) for s in FaultScript.load(good).steps] == [(0.2, "servo 1 torque-off"), (0.5, "bus unplug")]
    bad = tmp_path / "bad.txt"
    bad.write_text("0.1 bus unplug\nsoon bus replug\n")
    with pytest.raises(ConfigError, match=r"bad.txt:2: a line starts with the time"):
        FaultScript.load(bad)
    bad.write_text("1 sensor explode\n")
    with pytest.raises(ConfigError, match=r"bad.txt:1: .*sensor takes"):
        FaultScript.load(bad)
    with pytest.raises(ConfigError, match="cannot read"):
        FaultScript.load(tmp_path / "absent.txt")
    check_command("stats")


def test_the_control_socket_drives_a_bench_in_another_process(tmp_path):
    sock = str(tmp_path / "bench.sock")
    with mock_bench_process("--profile", "still:torque=0.105", "--control", sock) as (proc, ports):
        assert ports["control"] == sock and set(ports["links"]) == {"bus", "sensor"}
        bus_link, sensor_link = ports["links"]["bus"], ports["links"]["sensor"]
        with ServoBus(bus_link, reply_slack_ms=SLACK_MS) as servos:
            assert wait_until(lambda: servos.ping(1) is not None, timeout=30)  # a bench still starting
            servos.set_torque(1, True)
        assert send(sock, "bus unplug") == [{"ok": True, "changed": True}]
        assert not os.path.exists(bus_link)
        replies = send(sock, "bus replug", "servo 1 state", "sensor unplug", "sensor replug", "nonsense")
        assert [r["ok"] for r in replies] == [True, True, True, True, False]
        assert replies[1]["state"]["torque_enabled"] is True, "the servos kept their power"
        with ServoBus(bus_link, reply_slack_ms=SLACK_MS) as servos:
            assert wait_until(lambda: servos.ping(1) is not None, timeout=30)
        buffer = SampleBuffer()
        with OptoForceSerialReader(sensor_link, 451.89, buffer):
            assert buffer.wait_for(10, timeout=30)
    assert proc.returncode == 0, proc.stderr_text
    assert not os.path.exists(sock), "the socket is removed at exit"


def test_a_timed_script_plays_in_another_process_and_a_bad_one_stops_the_bench_at_once(tmp_path):
    script = tmp_path / "faults.txt"
    script.write_text("0.0 bus unplug\n")
    with mock_bench_process("--profile", "still", "--faults", str(script), stop=signal.SIGINT) as (proc, ports):
        assert wait_until(lambda: not os.path.exists(ports["links"]["bus"]), timeout=30)
    assert proc.returncode == 0, proc.stderr_text
    script.write_text("0.0 bus unplug\n1.0 bus wiggle\n")
    bad = start_mock_bench("--faults", str(script))
    out, err = bad.communicate(timeout=60)
    assert bad.returncode != 0 and out == ""
    assert err.strip().count("\n") == 0 and "faults.txt:2" in err


def test_the_control_socket_never_replaces_a_file_that_is_not_a_socket(bench, tmp_path):
    from admittance.errors import DeviceError
    from admittance.mockbench.control import ControlServer

    precious = tmp_path / "notes.txt"
    precious.write_text("keep me")
    with pytest.raises(DeviceError, match="cannot listen on"):
        ControlServer(bench, str(precious))
    assert precious.read_text() == "keep me"
    server = ControlServer(bench, str(tmp_path / "ok.sock"))
    server.start()
    try:
        assert send(str(tmp_path / "ok.sock"), "stats")[0]["stats"]["bus"]["packets"] >= 0
    finally:
        server.close()
