"""DxlClient (Rust serial port + client) against pty servos (tests/dxl_pty.py)."""

from __future__ import annotations

import pytest

from admittance import _rtcore
from admittance.errors import DeviceError
from tests.dxl_pty import FIRMWARE, MODEL_NUMBER, PtyServos


@pytest.fixture(params=[1, 2], ids=["P1", "P2"])
def servos(request):
    s = PtyServos(request.param, ids=(1, 2, 3))
    yield s
    s.close()


@pytest.fixture
def client(servos):
    c = _rtcore.DxlClient(servos.path, 1_000_000, servos.protocol, 0.2)
    yield c
    c.close()


def test_open_report_on_a_pty(client):
    report = client.open_report()
    assert report["low_latency"] is False and report["low_latency_error"]


def test_ping_read_write(servos, client):
    info = client.ping(2)
    assert info["model_number"] == MODEL_NUMBER[servos.protocol]
    assert info["firmware"] == (FIRMWARE if servos.protocol == 2 else None)
    assert client.read(3, 36, 2) == b"\x5a\x5a"
    assert client.write(1, 30, b"\x00\x02") is False
    servos.clear()
    assert client.write(0xFE, 25, b"\x01") is None  # broadcast: no reply awaited
    assert servos.take(1) == _rtcore.encode_write(0xFE, 25, b"\x01", protocol=servos.protocol)


def test_sync_write_sends_the_encoder_bytes(servos, client):
    records = [(1, b"\x01\x02"), (3, b"\xff\xff")]
    servos.clear()
    client.sync_write(30, 2, records)
    expected = _rtcore.encode_sync_write(30, 2, records, protocol=servos.protocol)
    assert servos.take(len(expected)) == expected


def test_sync_read_marks_a_missing_servo(servos, client):
    if servos.protocol == 1:
        with pytest.raises(ValueError, match="SYNC_READ does not exist"):
            client.sync_read(132, 4, [1, 2])
        return
    got = client.sync_read(132, 4, [3, 9, 1])
    assert list(got) == [3, 9, 1]
    assert got == {3: b"\x5a" * 4, 9: None, 1: b"\x5a" * 4}


def test_bulk_read(client):
    assert client.bulk_read([(1, 36, 2), (2, 43, 1)]) == {1: b"\x5a\x5a", 2: b"\x5a"}


def test_reboot(servos, client):
    if servos.protocol == 1:
        with pytest.raises(ValueError, match="REBOOT does not exist"):
            client.reboot(1)
    else:
        client.reboot(1)


def test_silence_raises_device_error_naming_the_servo(servos):
    c = _rtcore.DxlClient(servos.path, 1_000_000, servos.protocol, 0.01)
    with pytest.raises(DeviceError, match="no reply from servo 42"):
        c.ping(42)
    c.close()
    with pytest.raises(DeviceError, match="closed"):
        c.ping(1)


def test_missing_port_is_a_device_error():
    with pytest.raises(DeviceError, match="/dev/ttyDXL-missing"):
        _rtcore.DxlClient("/dev/ttyDXL-missing", 1_000_000, 2, 0.01)


def test_bad_timeout_is_a_value_error(servos):
    with pytest.raises(ValueError, match="timeout_s"):
        _rtcore.DxlClient(servos.path, 1_000_000, 2, 0.0)
