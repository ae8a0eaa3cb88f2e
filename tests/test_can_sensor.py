"""The CAN force reader on python-can's virtual bus: split frames, bad checksums, foreign IDs."""

from __future__ import annotations

import itertools

import can
import pytest
from hypothesis import given
from hypothesis import strategies as st

from admittance.drivers import optoforce as of
from admittance.drivers.can_sensor import CanForceReader, split_into_can_payloads
from admittance.drivers.force_reader import SampleBuffer
from admittance.errors import DeviceError
from admittance.mockbench.hand import make_profile
from admittance.mockbench.simulated_sensor import ForceModel, SimulatedCanOptoForce

from helpers import wait_until

_channels = itertools.count()


@pytest.fixture
def channel() -> str:
    return f"test-can-{next(_channels)}"


@pytest.fixture
def sender(channel):
    bus = can.Bus(interface="virtual", channel=channel, ignore_config=True)
    yield bus
    bus.shutdown()


def _send(bus, payload: bytes, can_id: int = 0x100) -> None:
    bus.send(can.Message(arbitration_id=can_id, data=payload, is_extended_id=can_id > 0x7FF))


def _send_sample(bus, frame: bytes, can_id: int = 0x100) -> None:
    for payload in split_into_can_payloads(frame):
        _send(bus, payload, can_id)


def test_split_samples_are_reassembled_in_order(channel, sender):
    buffer = SampleBuffer()
    with CanForceReader(channel, 100.0, buffer, interface="virtual") as reader:
        for i in range(20):
            _send_sample(sender, of.encode_sample(i, 0, (i, -i, 2 * i)))
        assert buffer.wait_for(20, timeout=10)
    assert [f[:3] for _, f in buffer.snapshot()] == [[i / 100, -i / 100, 2 * i / 100] for i in range(20)]
    stats = reader.stats()
    assert stats["can_frames"] == 40 and stats["checksum_errors"] == 0


def test_six_axis_and_four_channel_samples_span_three_and_five_frames(channel, sender):
    assert [len(split_into_can_payloads(of.encode_sample(0, 0, [0] * n))) for n in (3, 6, 12)] == [2, 3, 5]
    buffer = SampleBuffer()
    with CanForceReader(channel, [1, 1, 1, 10, 10, 10], buffer, interface="virtual", axes=6):
        _send_sample(sender, of.encode_sample(0, 0, (1, 2, 3, 40, 50, 60)))
        assert buffer.wait_for(1, timeout=10)
    assert buffer.snapshot()[0][1] == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]


def test_bad_checksums_and_lost_frames_cost_only_their_own_sample(channel, sender):
    buffer = SampleBuffer()
    with CanForceReader(channel, 1.0, buffer, interface="virtual") as reader:
        good1 = of.encode_sample(1, 0, (1, 1, 1))
        bad = bytearray(of.encode_sample(2, 0, (2, 2, 2)))
        bad[-1] ^= 0xFF
        lost = of.encode_sample(3, 0, (3, 3, 3))
        good4 = of.encode_sample(4, 0, (4, 4, 4))
        _send_sample(sender, good1)
        _send_sample(sender, bytes(bad))
        _send(sender, lost[:8])  # its second frame never arrives
        _send_sample(sender, good4)
        assert buffer.wait_for(2, timeout=10)
        assert wait_until(lambda: reader.stats()["can_frames"] == 7)
    assert [f[0] for _, f in buffer.snapshot()] == [1.0, 4.0]
    stats = reader.stats()
    assert stats["checksum_errors"] >= 2 and stats["counter_gaps"] == 1


def test_frames_with_other_identifiers_are_ignored(channel, sender):
    buffer = SampleBuffer()
    with CanForceReader(channel, 1.0, buffer, interface="virtual", can_id=0x100):
        for i in range(5):
            frame = of.encode_sample(i, 0, (i, 0, 0))
            _send(sender, frame[:8])
            _send_sample(sender, of.encode_sample(99, 0, (99, 99, 99)), can_id=0x101)  # interleaved foreign traffic
            _send(sender, b"\xaa\x07\x08\x0a", can_id=0x200)
            _send(sender, frame[8:])
        assert buffer.wait_for(5, timeout=10)
    assert [f[0] for _, f in buffer.snapshot()] == [0.0, 1.0, 2.0, 3.0, 4.0]


def test_an_extended_identifier_is_matched_exactly(channel, sender):
    buffer = SampleBuffer()
    with CanForceReader(channel, 1.0, buffer, interface="virtual", can_id=0x18FF0100):
        _send_sample(sender, of.encode_sample(0, 0, (5, 0, 0)), can_id=0x18FF0100)
        assert buffer.wait_for(1, timeout=10)
    assert buffer.snapshot()[0][1][0] == 5.0


@pytest.mark.parametrize(("interface", "channel"), [("socketcan", "can_absent0"), ("no_such_interface", "x"), ("slcan", "/dev/ttyACM_absent")])
def test_a_missing_interface_or_channel_is_a_device_error(interface, channel):
    reader = CanForceReader(channel, 1.0, SampleBuffer(), interface=interface)
    with pytest.raises(DeviceError, match=f"interface '{interface}', channel '{channel}'"):
        reader.start()


def test_the_simulated_can_sensor_streams_and_obeys_a_config_packet(channel):
    sim = SimulatedCanOptoForce(make_profile("still:torque=0.1"), ForceModel(lever_arm=0.1, counts_per_newton=(200.0,) * 3), channel=channel, rate_hz=1000)
    buffer = SampleBuffer()
    host = can.Bus(interface="virtual", channel=channel, ignore_config=True)
    try:
        with sim, CanForceReader(channel, 200.0, buffer, interface="virtual") as reader:
            assert buffer.wait_for(100, timeout=10)
            _send_sample(host, of.DaqSettings(rate_hz=100, tare=True).packet(), can_id=0x101)
            assert wait_until(lambda: reader.stats()["acks"] == 1)
            assert wait_until(lambda: buffer.snapshot()[-1][1][0] == 0.0)
    finally:
        host.shutdown()
    assert all(f[0] == 1.0 for _, f in buffer.snapshot()[:100])  # 0.1 N·m / 0.1 m = 1 N
    assert sim.stats()["rate_hz"] == 100.0
    assert reader.stats()["checksum_errors"] == 0



@given(
    st.lists(st.tuples(st.integers(-32768, 32767), st.integers(-32768, 32767), st.integers(-32768, 32767)), min_size=1, max_size=30),
    st.data(),
)
def test_lost_can_frames_never_yield_a_wrong_force(samples, data):
    """Any CAN frames may be lost: every force vector decoded is one that was sent."""
    payloads = [p for i, counts in enumerate(samples) for p in split_into_can_payloads(of.encode_sample(i, 0, counts))]
    kept = [p for p in payloads if data.draw(st.booleans(), label="kept")]
    parser = of.OptoForceParser()
    decoded = [r.counts for r in parser.feed(b"".join(kept)) if isinstance(r, of.Sample)]
    assert set(decoded) <= set(samples)
    if kept == payloads:
        assert decoded == samples
