"""The OptoForce serial reader over a pseudo-terminal, against the simulated sensor."""

from __future__ import annotations

import os
import time
import tty

import pytest

from admittance.drivers import optoforce as of
from admittance.drivers.force_reader import SampleBuffer
from admittance.errors import DeviceError
from admittance.mockbench.hand import make_profile
from admittance.mockbench.simulated_sensor import ForceModel, SimulatedOptoForce

from helpers import wait_until

CPN = (400.0, 500.0, 250.0)



@pytest.fixture
def simulated():
    sim = SimulatedOptoForce(make_profile("still:torque=0.21"), ForceModel(lever_arm=0.105, axis="y", counts_per_newton=CPN), rate_hz=1000)
    sim.start()
    yield sim
    sim.stop()


def test_reader_converts_counts_to_newtons_per_axis(simulated):
    buffer = SampleBuffer()
    with of.OptoForceSerialReader(simulated.port_path, CPN, buffer) as reader:
        assert buffer.wait_for(50, timeout=10)
    samples = buffer.snapshot()
    # 0.21 N·m / 0.105 m = 2 N on y: 1000 counts at 500 counts/N.
    assert all(forces == [0.0, 2.0, 0.0, 0.0, 0.0, 0.0] for _, forces in samples)
    t = [t_ns for t_ns, _ in samples]
    assert t == sorted(t) and abs(t[-1] - time.monotonic_ns()) < 60e9
    stats = reader.stats()
    assert stats["checksum_errors"] == 0 and stats["samples_pushed"] == len(samples)


def test_the_config_packet_sets_the_rate_and_is_acknowledged(simulated):
    buffer = SampleBuffer()
    reader = of.OptoForceSerialReader(simulated.port_path, CPN, buffer, settings=of.DaqSettings(rate_hz=333, tare=True))
    with reader:
        assert wait_until(lambda: reader.stats()["acks"] == 1)
        # The DAQ's own tare zeroes the 2 N load: the samples after the ack read 0.
        assert wait_until(lambda: buffer.snapshot()[-1][1] == [0.0] * 6)
    assert simulated.stats()["rate_hz"] == pytest.approx(1000 / 3)
    assert reader.stats()["ack_errors"] == 0


def test_speed_zero_stops_the_stream(simulated):
    buffer = SampleBuffer()
    with of.OptoForceSerialReader(simulated.port_path, CPN, buffer, settings=of.DaqSettings(rate_hz=0)) as reader:
        assert wait_until(lambda: reader.stats()["acks"] == 1)
    assert not simulated.stats()["streaming"]


def test_a_missing_port_is_a_device_error_naming_it():
    reader = of.OptoForceSerialReader("/dev/ttyACM_absent", 100.0, SampleBuffer())
    with pytest.raises(DeviceError, match="/dev/ttyACM_absent"):
        reader.start()
    assert not reader.running


def test_a_full_pty_drops_whole_samples_never_half_frames():
    sim = SimulatedOptoForce(make_profile("sine:amplitude=0.1,frequency=3"), ForceModel(), rate_hz=1000)
    with sim:
        # Nobody reads: the pty fills up (a few KiB) and the mock drops samples.
        assert wait_until(lambda: sim.stats()["samples_dropped"] > 0)
        # The mock set the pty raw already (setting it again here would flush the input).
        with os.fdopen(os.open(sim.port_path, os.O_RDONLY | os.O_NOCTTY), "rb", buffering=0) as raw:
            data = bytearray()
            while len(data) < 4000:
                data += raw.read(4096)
    parser = of.OptoForceParser()
    records = parser.feed(bytes(data))
    assert len(records) > 100
    assert parser.stats()["checksum_errors"] == 0 and parser.stats()["skipped_bytes"] == 0


def test_the_reader_survives_garbage_on_the_line():
    master, slave = os.openpty()
    tty.setraw(slave)
    buffer = SampleBuffer()
    reader = of.OptoForceSerialReader(os.ttyname(slave), 100.0, buffer)
    try:
        with reader:
            os.write(master, b"\x00\xaa\x13garbage" + of.encode_sample(7, 0, (100, 200, -300)) + b"\xaa\x07\x08\x0a" + of.encode_sample(8, 0, (1, 2, 3)))
            assert buffer.wait_for(2, timeout=10)
    finally:
        os.close(master)
        os.close(slave)
    assert [f for _, f in buffer.snapshot()] == [[1.0, 2.0, -3.0, 0.0, 0.0, 0.0], [0.01, 0.02, 0.03, 0.0, 0.0, 0.0]]
    stats = reader.stats()
    assert stats["resyncs"] >= 1 and stats["checksum_errors"] >= 1


def test_a_vanished_device_is_reported_and_reopened_with_backoff(tmp_path):
    # Read through the link: a freed /dev/pts number is soon another program's pty, which a
    # reopening reader must not open instead.
    sim = SimulatedOptoForce(make_profile("still"), ForceModel(), rate_hz=333, link=str(tmp_path / "ttyACM"))
    sim.start()
    buffer = SampleBuffer()
    reader = of.OptoForceSerialReader(sim.link_path, 100.0, buffer)
    reader.start()
    try:
        assert buffer.wait_for(3, timeout=10)
        sim.stop()  # closes the pty for good: the "USB cable" is pulled and lost
        assert wait_until(lambda: reader.stats()["reopen_failures"] >= 2)
        stats = reader.stats()
        assert reader.running and stats["state"] == "reconnecting" and stats["disconnects"] == 1
        # pyserial wraps a failed read (SerialException); a failed in_waiting ioctl raises the OSError itself.
        assert stats["error"] == reader.error and reader.error.startswith(("SerialException", "OSError"))
        assert "no such device" in stats["last_error"], "a reopen names why it failed"
    finally:
        reader.stop()
    assert reader.stats()["state"] == "stopped"
