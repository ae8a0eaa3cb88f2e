"""Our encoders against ROBOTIS's dynamixel-sdk, byte for byte.

The SDK writes through a pseudo-terminal whose master a test thread reads (tests/dxl_pty.py);
the captured bytes must equal what our Rust encoders produce for the same request. Requests
the SDK waits on (PING, READ, SYNC_READ...) are answered with our status encoder, so the SDK
also checks that our status packets parse.
"""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from admittance import _rtcore
from tests.dxl_pty import FIRMWARE, MODEL_NUMBER, PtyServos

from helpers import examples, patient

sdk = pytest.importorskip("dynamixel_sdk")


@pytest.fixture(scope="module", params=[1, 2], ids=["P1", "P2"])
def bus(request):
    servos = PtyServos(request.param)
    # Patient: the servos are a Python thread here, which a loaded machine can keep from
    # answering within the SDK's own 34 ms (test_ping[P2] failed so at load 25-30).
    port = patient(sdk.PortHandler(servos.path))
    assert port.openPort() and port.setBaudRate(1_000_000)
    handler = sdk.PacketHandler(float(request.param))
    yield servos, port, handler
    port.closePort()
    servos.close()


def enc(servos, name, *args):
    return getattr(_rtcore, name)(*args, protocol=servos.protocol)


def assert_sent(servos, expected: bytes) -> None:
    assert servos.take(len(expected)) == expected


def test_ping(bus):
    servos, port, ph = bus
    servos.clear()
    model, result, error = ph.ping(port, 1)
    assert (result, error, model) == (sdk.COMM_SUCCESS, 0, MODEL_NUMBER[servos.protocol])
    expected = enc(servos, "encode_ping", 1)
    if servos.protocol == 1:  # the SDK reads the model number after a P1 ping
        expected += enc(servos, "encode_read", 1, 0, 2)
    assert_sent(servos, expected)


def test_read_tx_rx(bus):
    servos, port, ph = bus
    servos.clear()
    data, result, _ = ph.readTxRx(port, 3, 36, 2)
    assert result == sdk.COMM_SUCCESS and bytes(data) == b"\x5a\x5a"
    assert_sent(servos, enc(servos, "encode_read", 3, 36, 2))


def test_write_tx_rx(bus):
    servos, port, ph = bus
    servos.clear()
    result, _ = ph.writeTxRx(port, 2, 30, 2, [0x00, 0x02])
    assert result == sdk.COMM_SUCCESS
    assert_sent(servos, enc(servos, "encode_write", 2, 30, bytes([0x00, 0x02])))


HEADER_RUN = b"\xff\xff\xfd"


@settings(max_examples=examples(40), suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(id_=st.integers(0, 252), address=st.integers(0, 255), data=st.binary(min_size=1, max_size=40))
def test_write_tx_only_any_data(bus, id_, address, data):
    servos, port, ph = bus
    # The SDK's txPacket discards addStuffing's result (see the test below), so its wire
    # bytes are only the reference for payloads that need no stuffing.
    payload = data.replace(HEADER_RUN, b"\xff\xfe\xfd")
    servos.clear()
    ph.writeTxOnly(port, id_, address, len(payload), list(payload))
    assert_sent(servos, enc(servos, "encode_write", id_, address, payload))


@settings(max_examples=examples(200))
@given(data=st.lists(st.sampled_from([b"\xff", b"\xfd", b"\x00", HEADER_RUN, b"\x42"]), max_size=20).map(b"".join))
def test_stuffing_matches_the_sdk_stuffer(data):
    """dynamixel-sdk 4.x's Protocol2PacketHandler.txPacket calls addStuffing but ignores the
    list it returns, so payloads containing FF FF FD go out unstuffed. Its addStuffing and
    updateCRC are still the vendor's definition of the wire bytes: ours must equal them."""
    ph = sdk.PacketHandler(2.0)
    params = [0x74, 0x00, *data]
    raw = [0xFF, 0xFF, 0xFD, 0x00, 1, *(len(params) + 3).to_bytes(2, "little"), 0x03, *params, 0, 0]
    stuffed = ph.addStuffing(raw)
    n = int.from_bytes(bytes(stuffed[5:7]), "little") + 7
    crc = ph.updateCRC(0, stuffed, n - 2)
    wire = bytes(stuffed[: n - 2]) + crc.to_bytes(2, "little")
    assert _rtcore.encode_write(1, 0x74, data) == wire


def test_sync_write(bus):
    servos, port, ph = bus
    servos.clear()
    records = [(1, b"\x10\x00"), (2, b"\xff\xff"), (7, b"\xfd\x00")]
    group = sdk.GroupSyncWrite(port, ph, 30, 2)
    for id_, data in records:
        assert group.addParam(id_, list(data))
    assert group.txPacket() == sdk.COMM_SUCCESS
    assert_sent(servos, enc(servos, "encode_sync_write", 30, 2, records))


def test_sync_read(bus):
    servos, port, ph = bus
    if servos.protocol == 1:
        pytest.skip("SYNC_READ does not exist in Protocol 1.0")
    servos.clear()
    group = sdk.GroupSyncRead(port, ph, 132, 4)
    for id_ in (3, 1, 2):
        assert group.addParam(id_)
    assert group.txRxPacket() == sdk.COMM_SUCCESS
    assert group.getData(2, 132, 4) == 0x5A5A5A5A
    assert_sent(servos, enc(servos, "encode_sync_read", 132, 4, [3, 1, 2]))


def test_bulk_read(bus):
    servos, port, ph = bus
    servos.clear()
    group = sdk.GroupBulkRead(port, ph)
    entries = [(1, 36, 2), (7, 43, 1)]
    for id_, address, length in entries:
        assert group.addParam(id_, address, length)
    if servos.protocol == 1:
        # dynamixel-sdk 4.x's GroupBulkRead passes P1's bulkReadTx one argument too many:
        # build the same parameters with the group and transmit through the handler.
        group.makeParam()
        assert ph.bulkReadTx(port, group.param, len(entries) * 3) == sdk.COMM_SUCCESS
        port.is_using = False  # released by the reply read we skip
    else:
        assert group.txRxPacket() == sdk.COMM_SUCCESS
        assert group.getData(7, 43, 1) == 0x5A
    assert_sent(servos, enc(servos, "encode_bulk_read", entries))


def test_reboot(bus):
    servos, port, ph = bus
    if servos.protocol == 1:
        pytest.skip("REBOOT does not exist in Protocol 1.0")
    servos.clear()
    result, _ = ph.reboot(port, 1)
    assert result == sdk.COMM_SUCCESS
    assert_sent(servos, enc(servos, "encode_reboot", 1))


def test_reg_write_action_factory_reset(bus):
    servos, port, ph = bus
    servos.clear()
    ph.regWriteTxOnly(port, 1, 30, 2, [0x34, 0x12])
    assert_sent(servos, enc(servos, "encode_reg_write", 1, 30, b"\x34\x12"))
    ph.action(port, 0xFE)
    assert_sent(servos, enc(servos, "encode_action", 0xFE))
    if servos.protocol == 1:  # P1's FACTORY_RESET has no option byte
        ph.factoryReset(port, 0xFE)
        assert_sent(servos, enc(servos, "encode_factory_reset", 0xFE))
    else:
        ph.factoryReset(port, 0xFE, 0x01)
        assert_sent(servos, enc(servos, "encode_factory_reset", 0xFE, 0x01))


def test_ping_firmware_is_read_by_our_client(bus):
    """The same pty servos answer our DxlClient (Rust serial port + client)."""
    servos, _, _ = bus
    client = _rtcore.DxlClient(servos.path, 1_000_000, servos.protocol, 0.2)
    try:
        info = client.ping(7)
        assert info["model_number"] == MODEL_NUMBER[servos.protocol]
        assert info["firmware"] == (FIRMWARE if servos.protocol == 2 else None)
    finally:
        client.close()


class _RecordingPort:
    """Just enough of a PortHandler for the SDK's transmit path: it records what is written."""

    def __init__(self):
        self.is_using = False
        self.sent = b""

    def clearPort(self):  # noqa: N802 (the SDK's name)
        pass

    def writePort(self, packet):  # noqa: N802
        self.sent += bytes(packet)
        return len(packet)

    def setPacketTimeout(self, _length):  # noqa: N802
        pass


@pytest.mark.skipif(not hasattr(sdk.GroupSyncRead, "fastSyncRead"),
                    reason="the installed dynamixel-sdk has no GroupSyncRead.fastSyncRead (added in 3.8.1/4.x)")
@settings(max_examples=examples(30))
@given(address=st.integers(0, 300), length=st.integers(1, 8),
       ids=st.lists(st.integers(0, 252), min_size=1, max_size=12, unique=True))
def test_fast_sync_read_instruction_matches_the_sdk(address, length, ids):
    port, ph = _RecordingPort(), sdk.PacketHandler(2.0)
    group = sdk.GroupSyncRead(port, ph, address, length)
    for id_ in ids:
        assert group.addParam(id_)
    assert group.fastSyncReadTxPacket() == sdk.COMM_SUCCESS
    assert port.sent == _rtcore.encode_fast_sync_read(address, length, ids)


@pytest.mark.skipif(not hasattr(sdk.GroupSyncRead, "fastSyncRead"),
                    reason="the installed dynamixel-sdk has no GroupSyncRead.fastSyncRead (added in 3.8.1/4.x)")
def test_the_sdks_fast_sync_read_reads_the_mock_bus():
    """The SDK's own Fast Sync Read on the simulated bus: its instruction parses, our combined
    reply (the codec's segments and running CRCs) passes the SDK's CRC check, and the positions
    are the servos' own, in the SDK's listed order; a missing servo fails the SDK's read."""
    from helpers import MX64_PLANT, sdk_on_mock_bus

    with sdk_on_mock_bus() as open_bus:
        servos = [{"id": i, "model": "MX-64", "protocol": 2, "params": dict(MX64_PLANT),
                   "initial_theta": 0.3 * i} for i in (1, 2, 5)]
        bus, port, ph = open_bus(servos)
        group = sdk.GroupSyncRead(port, ph, 132, 4)
        for id_ in (5, 1, 2):
            assert group.addParam(id_)
        assert group.fastSyncRead() == sdk.COMM_SUCCESS, ph.getTxRxResult(group.fastSyncRead())
        fast = {i: group.getData(i, 132, 4) for i in (5, 1, 2)}
        assert fast == {i: bus.register(i, "Present Position") for i in (5, 1, 2)}
        assert len(set(fast.values())) == 3, "three different horns"
        # The plain Sync Read agrees (the horns rest).
        assert group.txRxPacket() == sdk.COMM_SUCCESS
        assert {i: group.getData(i, 132, 4) for i in (5, 1, 2)} == fast
        # ID 9 is not on the bus: the combined reply ends before its segment.
        assert group.addParam(9)
        assert group.fastSyncRead() != sdk.COMM_SUCCESS
