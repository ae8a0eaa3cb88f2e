"""Corrupted, truncated and foreign bytes never kill or wedge the simulated bus.

Bytes are written raw with pyserial; the bus must keep answering the SDK afterwards. A packet
with a bad CRC (checksum on P1) addressed to a present servo is answered with CRC Error (0x03;
P1 bit 0x10), as docs/mock-bench.md decides; to an absent ID or broadcast it stays silent.
"""

from __future__ import annotations

import time

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

sdk = pytest.importorskip("dynamixel_sdk")
serial = pytest.importorskip("serial")
_rtcore = pytest.importorskip("admittance._rtcore")

from helpers import MX64_PLANT, examples, patient  # noqa: E402

MX64 = MX64_PLANT
# Longer than the mock's 1.5 ms inter-byte timeout, so a partial packet has been dropped.
SETTLE_S = 0.01


def p2_packet(servo_id: int, instruction: int, params: bytes = b"", crc_delta: int = 0) -> bytes:
    """A P2 instruction packet, its CRC computed by the SDK (the reference implementation)."""
    body = bytes([0xFF, 0xFF, 0xFD, 0x00, servo_id]) + (len(params) + 3).to_bytes(2, "little")
    body += bytes([instruction]) + params
    crc = (sdk.PacketHandler(2.0).updateCRC(0, list(body), len(body)) + crc_delta) & 0xFFFF
    return body + crc.to_bytes(2, "little")


def p1_packet(servo_id: int, instruction: int, params: bytes = b"", checksum_delta: int = 0) -> bytes:
    body = bytes([servo_id, len(params) + 2, instruction]) + params
    checksum = (~sum(body) + checksum_delta) & 0xFF
    return b"\xff\xff" + body + bytes([checksum])


@pytest.fixture
def bus_and_port(request):
    protocol = getattr(request, "param", 2)
    servos = [{"id": i, "protocol": protocol, "params": dict(MX64)} for i in (1, 2)]
    bus = _rtcore.MockBus(servos=servos, wire_delay=False)
    bus.start()
    raw = serial.Serial(bus.port_path, 1_000_000, timeout=0.2)
    port = patient(sdk.PortHandler(bus.port_path))
    assert port.openPort()
    yield bus, raw, port, sdk.PacketHandler(float(protocol))
    port.closePort()
    raw.close()
    bus.stop()


def still_answers(raw, port, ph) -> None:
    time.sleep(SETTLE_S)
    raw.reset_input_buffer()
    for servo_id in (1, 2):
        model, result, error = ph.ping(port, servo_id)
        assert result == sdk.COMM_SUCCESS and error == 0
        assert model in (310, 311)


def read_status(raw, length: int) -> bytes:
    return raw.read(length)


def test_bad_crc_to_a_present_servo_gets_crc_error(bus_and_port):
    bus, raw, port, ph = bus_and_port
    raw.write(p2_packet(1, 0x01, crc_delta=1))
    reply = read_status(raw, 11)
    assert reply[:5] == bytes([0xFF, 0xFF, 0xFD, 0x00, 1])
    assert reply[7:9] == bytes([0x55, 0x03])
    assert bus.stats()["crc_errors"] == 1
    still_answers(raw, port, ph)


def test_bad_crc_to_absent_or_broadcast_ids_is_silent(bus_and_port):
    _, raw, port, ph = bus_and_port
    raw.write(p2_packet(9, 0x01, crc_delta=1) + p2_packet(0xFE, 0x01, crc_delta=1))
    assert raw.read(11) == b""
    still_answers(raw, port, ph)


@pytest.mark.parametrize("bus_and_port", [1], indirect=True)
def test_p1_bad_checksum_sets_the_checksum_bit(bus_and_port):
    _, raw, port, ph = bus_and_port
    raw.write(p1_packet(2, 0x01, checksum_delta=1))
    reply = raw.read(6)
    assert reply[:3] == bytes([0xFF, 0xFF, 2])
    assert reply[4] & 0x10
    still_answers(raw, port, ph)


def test_a_truncated_packet_is_dropped_after_the_inter_byte_timeout(bus_and_port):
    bus, raw, port, ph = bus_and_port
    read = p2_packet(1, 0x02, bytes([0x84, 0, 4, 0]))
    raw.write(read[:9])
    still_answers(raw, port, ph)
    assert bus.stats()["truncated_packets"] >= 1
    assert bus.stats()["crc_errors"] == 0


def test_foreign_traffic_is_ignored(bus_and_port):
    bus, raw, port, ph = bus_and_port
    other_servo_status = bytes([0xFF, 0xFF, 0xFD, 0x00, 7, 4, 0, 0x55, 0])
    other_servo_status += sdk.PacketHandler(2.0).updateCRC(0, list(other_servo_status), 9).to_bytes(2, "little")
    raw.write(other_servo_status + p1_packet(1, 0x01) + bytes(range(256)) + p2_packet(9, 0x01))
    time.sleep(SETTLE_S)
    assert raw.read(64) == b""
    still_answers(raw, port, ph)
    assert bus.stats()["foreign_status_packets"] == 1


def test_a_length_field_beyond_the_limit_is_skipped(bus_and_port):
    bus, raw, port, ph = bus_and_port
    raw.write(bytes([0xFF, 0xFF, 0xFD, 0x00, 1, 0xFF, 0xFF, 0x02]) + p2_packet(1, 0x01))
    reply = raw.read(14)
    assert reply[:5] == bytes([0xFF, 0xFF, 0xFD, 0x00, 1]) and reply[8] == 0
    assert bus.stats()["framing_errors"] >= 1
    still_answers(raw, port, ph)


@pytest.mark.parametrize("bus_and_port", [1, 2], indirect=True)
@settings(max_examples=examples(20), suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(noise=st.binary(min_size=1, max_size=300))
def test_any_garbage_leaves_the_bus_answering(bus_and_port, noise):
    bus, raw, port, ph = bus_and_port
    raw.write(noise)
    still_answers(raw, port, ph)
    assert bus.running
