"""Exclusive ports: a second opener of a servo bus or a sensor tty fails with one line, naming
the holder, before it writes a byte; the first keeps working.

Every opener the daemon uses is covered (the SDK setup, the Rust serial port of the RT loop
and of DxlClient, the OptoForce reader), each against each other where the daemon could meet
them. "Before it writes" is checked on the simulated bus's own counters of bytes received.
"""

from __future__ import annotations

import os

import pytest

from admittance import _rtcore
from admittance.drivers.dynamixel import ServoBus
from admittance.drivers.optoforce import OptoForceSerialReader
from admittance.drivers.force_reader import SampleBuffer
from admittance.errors import DeviceError
from admittance.mockbench.hand import make_profile
from admittance.mockbench.simulated_sensor import ForceModel, SimulatedOptoForce

from helpers import MX64_PLANT

PID = f"pid {os.getpid()}"


@pytest.fixture
def bus():
    mock = _rtcore.MockBus(servos=[{"id": 1, "params": dict(MX64_PLANT)}], wire_delay=False)
    mock.start()
    yield mock
    mock.stop()


def one_line(exc: pytest.ExceptionInfo) -> str:
    text = str(exc.value)
    assert "\n" not in text, text
    return text


def test_a_second_sdk_setup_on_the_bus_fails_before_writing(bus):
    with ServoBus(bus.port_path, reply_slack_ms=200.0) as first:
        assert first.ping(1) is not None
        received = bus.stats()["bytes_in"]
        with pytest.raises(DeviceError) as err:
            ServoBus(bus.port_path, reply_slack_ms=200.0)
        assert bus.stats()["bytes_in"] == received, "the second opener wrote nothing"
        assert first.ping(1) is not None, "the first one still owns the bus"
    message = one_line(err)
    assert message.startswith(f"cannot open the Dynamixel port {bus.port_path}: the device is busy") and PID in message
    with ServoBus(bus.port_path, reply_slack_ms=200.0) as again:  # free once the first closed
        assert again.ping(1) is not None


def test_the_rust_port_and_the_sdk_exclude_each_other(bus):
    client = _rtcore.DxlClient(bus.port_path, 1_000_000, 2, 0.2)
    try:
        assert client.ping(1)["model_number"] == 311
        received = bus.stats()["bytes_in"]
        with pytest.raises(DeviceError) as err:
            ServoBus(bus.port_path)
        assert PID in one_line(err)
        with pytest.raises(DeviceError) as err:
            _rtcore.DxlClient(bus.port_path, 1_000_000, 2, 0.2)
        assert "in use by another process" in one_line(err) and PID in str(err.value)
        assert bus.stats()["bytes_in"] == received
    finally:
        client.close()
    with ServoBus(bus.port_path, reply_slack_ms=200.0) as servos:
        assert servos.ping(1) is not None


def test_the_rt_loop_does_not_start_on_a_bus_in_use(bus):
    joint = {"id": 1, "model": "MX-64", "virtual_inertia": 0.02, "virtual_damping": 0.01, "virtual_coulomb": 0.0,
             "axis": "x", "lever_arm": 0.1}
    loop = _rtcore.AdmittanceLoop({"port": bus.port_path, "rate_hz": 500.0, "rt_priority": 0, "lock_memory": False,
                                   "joints": [joint]})
    with ServoBus(bus.port_path, reply_slack_ms=200.0):
        packets = bus.stats()["packets"]
        with pytest.raises((DeviceError, OSError, RuntimeError)) as err:
            loop.start()
        assert bus.stats()["packets"] == packets, "no goal, no torque-on: nothing was sent"
    assert "in use by another process" in one_line(err) and PID in str(err.value)
    loop.start()  # the bus is free again
    try:
        assert loop.running()
    finally:
        loop.stop("hold")


def test_a_second_reader_on_the_sensor_fails_and_the_first_keeps_its_samples():
    sim = SimulatedOptoForce(make_profile("still:torque=0.1"), ForceModel(), rate_hz=1000)
    with sim:
        first_buffer = SampleBuffer()
        with OptoForceSerialReader(sim.port_path, 451.89, first_buffer) as first:
            assert first_buffer.wait_for(10, timeout=10)
            second = OptoForceSerialReader(sim.port_path, 451.89, SampleBuffer())
            with pytest.raises(DeviceError) as err:
                second.start()
            assert not second.running
            got = first_buffer.total
            assert first_buffer.wait_for(got + 50, timeout=10), "the first reader still gets every sample"
            assert first.stats()["checksum_errors"] == 0 and first.stats()["disconnects"] == 0
    message = one_line(err)
    assert message.startswith(f"cannot open the OptoForce sensor port {sim.port_path}: the device is busy")
    assert PID in message
