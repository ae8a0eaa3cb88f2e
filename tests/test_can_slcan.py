"""The CAN force reader over python-can's ``slcan`` interface, against a simulated USB-CAN adapter on a pty."""

from __future__ import annotations

import contextlib
import json
import signal
from collections.abc import Iterator

import can
import pytest
from hypothesis import given
from hypothesis import strategies as st

from admittance.drivers import optoforce as of
from admittance.drivers.can_sensor import CanForceReader, split_into_can_payloads
from admittance.drivers.force_reader import SampleBuffer
from admittance.errors import DataError, DeviceError
from admittance.mockbench import slcan
from admittance.mockbench.hand import make_profile
from admittance.mockbench.simulated_sensor import ForceModel, PtyPort, SimulatedSlcanOptoForce

from helpers import first_line, start_mock_bench, wait_until

CPN = 200.0


def _lines(sample: bytes, can_id: int = 0x100) -> bytes:
    return b"".join(slcan.encode_frame(can_id, p) for p in split_into_can_payloads(sample))


@pytest.fixture
def adapter_port():
    """A bare pty the test writes slcan lines to, with the adapter's state machine on its commands."""
    port = PtyPort()
    adapter = slcan.SlcanAdapter()
    yield port, adapter
    port.close()


def _opened(port: PtyPort, adapter: slcan.SlcanAdapter) -> bool:
    adapter.feed(port.receive())
    return adapter.is_open


# -- the Lawicel codec ---------------------------------------------------------------------------


@given(st.integers(0, slcan.EXTENDED_ID_MAX), st.binary(max_size=8))
def test_a_frame_line_decodes_to_the_frame_it_encodes(can_id, data):
    line = slcan.encode_frame(can_id, data)
    assert line.endswith(b"\r") and line[:1] == (b"T" if can_id > 0x7FF else b"t")
    assert slcan.decode_frame(line[:-1]) == slcan.CanFrame(can_id, can_id > 0x7FF, data)


def test_a_timestamp_is_four_hex_digits_of_milliseconds_wrapping_each_minute():
    assert slcan.encode_frame(0x100, b"\x01", timestamp_ms=60_000 + 0x1234) == b"t100101" + b"1234\r"


@pytest.mark.parametrize("line", [b"", b"x1008", b"t1G01AA", b"t1001", b"t1002AA", b"t1009" + b"00" * 9, b"T1001AA"])
def test_a_malformed_frame_line_is_a_data_error(line):
    with pytest.raises(DataError):
        slcan.decode_frame(line)


@given(st.lists(st.integers(1, 12), max_size=10))
def test_the_adapter_answers_the_same_in_any_cut_of_the_commands(cuts):
    script = b"C\rS8\r\rO\rO\rt1012AABB\rV\rZ1\rS4\rC\rt1010\rQ\r"
    whole = slcan.SlcanAdapter().feed(script)
    adapter, replies, frames, at = slcan.SlcanAdapter(), b"", [], 0
    for cut in [*cuts, len(script)]:
        r, f = adapter.feed(script[at : at + cut])
        replies, frames, at = replies + r, frames + f, at + cut
    assert (replies, frames) == whole
    # C S8 CR O ok; second O refused; t ok (z); V; Z1 ok; S4 refused while open; C ok; t refused closed; Q unknown.
    assert replies == b"\r\r\r\r\az\rV1013\r\r\a\r\a\a"
    assert frames == [slcan.CanFrame(0x101, False, b"\xaa\xbb")]
    assert adapter.bitrate == 1_000_000 and adapter.timestamps and not adapter.is_open
    assert adapter.stats()["slcan_refused_commands"] == 4


# -- the reader over a pty -----------------------------------------------------------------------


def test_the_reader_opens_the_adapter_and_reassembles_samples_with_exact_statistics(adapter_port):
    port, adapter = adapter_port
    buffer = SampleBuffer()
    with CanForceReader(port.path, CPN, buffer, interface="slcan", can_id=0x100) as reader:
        assert wait_until(lambda: _opened(port, adapter))
        assert adapter.bitrate == 1_000_000
        for i in range(20):
            assert port.send(_lines(of.encode_sample(i, 0, (2 * i, -i, 0))))
        assert buffer.wait_for(20, timeout=10)
    assert [f[:3] for _, f in buffer.snapshot()] == [[2 * i / CPN, -i / CPN, 0.0] for i in range(20)]
    stats = reader.stats()
    assert (stats["can_frames"], stats["frames"], stats["samples"]) == (40, 20, 20)
    assert stats["checksum_errors"] == stats["counter_gaps"] == stats["undecodable_frames"] == stats["foreign_frames"] == 0
    assert stats["error"] is None
    assert _opened(port, adapter) is False  # stop() closed the channel with C


def test_corrupted_lines_and_bad_checksums_are_counted_and_the_reader_recovers(adapter_port):
    port, adapter = adapter_port
    buffer = SampleBuffer()
    with CanForceReader(port.path, 1.0, buffer, interface="slcan", can_id=0x100) as reader:
        assert wait_until(lambda: _opened(port, adapter))
        bad_checksum = bytearray(of.encode_sample(3, 0, (3, 3, 3)))
        bad_checksum[-1] ^= 0xFF
        half_lost = _lines(of.encode_sample(2, 0, (2, 2, 2)))
        port.send(_lines(of.encode_sample(1, 0, (1, 1, 1))))
        port.send(b"t1G08" + half_lost[5:22])  # its first frame's identifier is not hex
        port.send(half_lost[22:])
        assert wait_until(lambda: reader.stats()["undecodable_frames"] == 1)
        # A non-ASCII byte makes the reader drop python-can's input, so what follows is sent after.
        port.send(b"\xff\xfe\r")
        assert wait_until(lambda: reader.stats()["undecodable_frames"] == 2)
        port.send(_lines(bytes(bad_checksum)))
        port.send(_lines(of.encode_sample(4, 0, (4, 4, 4))))
        assert buffer.wait_for(2, timeout=10)
        assert wait_until(lambda: reader.stats()["can_frames"] == 7)
        assert reader.running
    assert [f[0] for _, f in buffer.snapshot()] == [1.0, 4.0]
    stats = reader.stats()
    assert stats["undecodable_frames"] == 2 and stats["error"] is None
    assert stats["checksum_errors"] >= 1 and stats["counter_gaps"] == 1 and stats["samples"] == 2


def test_a_missing_pty_is_one_device_error_naming_it():
    reader = CanForceReader("/dev/pts/99999", 1.0, SampleBuffer(), interface="slcan")
    with pytest.raises(DeviceError) as caught:
        reader.start()
    message = str(caught.value)
    assert "\n" not in message and "'/dev/pts/99999'" in message and "no such device" in message
    assert not reader.running


def test_python_cans_wait_after_open_is_skipped_on_a_pty_only(adapter_port):
    port, _ = adapter_port
    sink = SampleBuffer()
    assert CanForceReader(port.path, 1.0, sink, interface="slcan")._slcan_options() == {"sleep_after_open": 0.0}
    assert CanForceReader(f"{port.path}@115200", 1.0, sink, interface="slcan")._slcan_options() == {"sleep_after_open": 0.0}
    assert CanForceReader("/dev/ttyACM0", 1.0, sink, interface="slcan")._slcan_options() == {}
    assert CanForceReader("/dev/ttyACM0", 1.0, sink, interface="slcan", open_delay=0.5)._slcan_options() == {"sleep_after_open": 0.5}


# -- the simulated sensor ------------------------------------------------------------------------


def _simulated(**options) -> SimulatedSlcanOptoForce:
    return SimulatedSlcanOptoForce(make_profile("still:torque=0.1"), ForceModel(lever_arm=0.1, counts_per_newton=(CPN,) * 3), rate_hz=200, **options)


def test_the_simulated_adapter_streams_only_while_open_and_the_reader_gets_the_forces():
    with _simulated() as sim:
        assert wait_until(lambda: sim.stats()["samples_dropped"] >= 2)  # closed: nothing reaches the pty
        assert sim.stats()["samples_sent"] == 0
        buffer = SampleBuffer()
        with CanForceReader(sim.port_path, CPN, buffer, interface="slcan") as reader:
            assert buffer.wait_for(20, timeout=10)
        assert wait_until(lambda: not sim.stats()["slcan_open"])
        sent, dropped = sim.stats()["samples_sent"], sim.stats()["samples_dropped"]
        assert wait_until(lambda: sim.stats()["samples_dropped"] >= dropped + 2)
        assert sim.stats()["samples_sent"] == sent  # C stopped the stream
    assert all(f == [1.0, 0.0, 0.0, 0.0, 0.0, 0.0] for _, f in buffer.snapshot())  # 0.1 N·m at 0.1 m
    stats = reader.stats()
    assert stats["checksum_errors"] == stats["undecodable_frames"] == 0 and stats["can_frames"] >= 2 * 20


def test_a_configuration_packet_sent_through_the_adapter_is_acknowledged_and_applied():
    with _simulated(can_id=0x18FF0100) as sim:
        bus = can.Bus(interface="slcan", channel=sim.port_path, bitrate=500_000, sleep_after_open=0, ignore_config=True)
        try:
            for payload in split_into_can_payloads(of.DaqSettings(rate_hz=100, tare=True).packet()):
                bus.send(can.Message(arbitration_id=0x18FF0101, data=payload, is_extended_id=True))
            parser, records = of.OptoForceParser(), []
            while not any(type(r) is of.Ack for r in records):
                msg = bus.recv(5.0)
                assert msg is not None and msg.arbitration_id == 0x18FF0100 and msg.is_extended_id
                records += parser.feed(msg.data)
        finally:
            bus.shutdown()
    assert sim.stats()["rate_hz"] == 100.0 and sim.stats()["slcan_bitrate"] == 500_000
    assert parser.stats()["checksum_errors"] == 0


@contextlib.contextmanager
def _mock_bench(*args: str) -> Iterator[dict]:
    """``admittance mock-bench --print-ports ARGS`` in a subprocess: its ports; on exit, SIGTERM and a clean exit."""
    proc = start_mock_bench(*args)
    try:
        yield json.loads(first_line(proc))
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=30)
        assert (proc.returncode, out) == (0, ""), err  # nothing on stdout after the JSON line
    finally:
        if proc.poll() is None:
            proc.kill()


def test_mock_bench_with_an_slcan_sensor_prints_a_pty_the_reader_opens():
    with _mock_bench("--sensor", "slcan", "--rate", "200", "--profile", "still:torque=0.105", "--can-id", "0x120") as ports:
        assert ports["sensor"].startswith("/dev/pts/")
        assert ports["can"] == {"interface": "slcan", "channel": ports["sensor"], "can_id": 0x120}
        buffer = SampleBuffer()
        with CanForceReader(ports["sensor"], 451.89, buffer, interface="slcan", can_id=0x120) as reader:
            assert buffer.wait_for(10, timeout=30)
    assert buffer.snapshot()[-1][1][0] == pytest.approx(1.0, abs=0.01)  # 0.105 N·m at 0.105 m
    assert reader.stats()["checksum_errors"] == 0
