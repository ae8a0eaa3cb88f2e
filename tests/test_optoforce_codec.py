"""The OptoForce DAQ codec and streaming parser: documented vectors and properties."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from admittance.drivers import optoforce as of
from admittance.errors import ConfigError

from helpers import examples

# A real captured frame and ack (shared protocols.md §5.1, checksums verified there).
CAPTURED_FRAME = bytes.fromhex("AA 07 08 0A 2D 6A 00 00 FF F7 FF FB 00 07 05 51")
CAPTURED_ACK = bytes.fromhex("AA 00 50 01 00 00 FB")
CONFIG_100HZ_15HZ = bytes.fromhex("AA 00 32 03 0A 04 00 00 ED")

i16 = st.integers(-32768, 32767)
u16 = st.integers(0, 0xFFFF)
u8 = st.integers(0, 255)


@st.composite
def records(draw):
    """Any record the parser knows, with its encoding."""
    choice = draw(st.sampled_from(["sample", "ack", "config", "serial"]))
    if choice == "sample":
        n = draw(st.sampled_from([3, 6, 12]))
        counts = draw(st.lists(i16, min_size=n, max_size=n))
        record = of.Sample(draw(u16), draw(u16), tuple(counts))
        return record, of.encode_sample(*record)
    if choice == "ack":
        record = of.Ack(draw(u8))
        return record, of.encode_ack(record.code)
    if choice == "config":
        record = of.Config(draw(u8), draw(u8), draw(u8))
        return record, of.encode_config(*record)
    text = draw(st.text(alphabet="ABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789", min_size=1, max_size=8))
    return of.SerialNumber(text), of.encode_serial_number(text)


def test_captured_frame_decodes_to_the_documented_values():
    parser = of.OptoForceParser()
    assert parser.feed(CAPTURED_FRAME + CAPTURED_ACK) == [of.Sample(11626, 0, (-9, -5, 7)), of.Ack(0)]
    assert parser.stats()["checksum_errors"] == 0


def test_encoders_reproduce_the_documented_bytes():
    assert of.encode_sample(11626, 0, (-9, -5, 7)) == CAPTURED_FRAME
    assert of.encode_ack(0) == CAPTURED_ACK
    assert of.DaqSettings(rate_hz=100, filter_hz=15, tare=False).packet() == CONFIG_100HZ_15HZ


def test_frame_sizes_follow_the_documented_layouts():
    assert [len(of.encode_sample(0, 0, [0] * n)) for n in (3, 6, 12)] == [16, 22, 34]
    assert len(of.encode_ack()) == 7
    assert len(of.encode_config(1, 0, 0)) == 9


def test_settings_refuse_rates_the_daq_does_not_have():
    with pytest.raises(ConfigError, match="rate 500 Hz"):
        of.DaqSettings(rate_hz=500).packet()
    with pytest.raises(ConfigError, match="filter 7 Hz"):
        of.DaqSettings(filter_hz=7).packet()
    assert of.DaqSettings(rate_hz=333, filter_hz=150, tare=True).packet()[4:7] == bytes([3, 2, 255])


def test_status_word_helpers():
    assert not of.status_faults(1 << 9)
    assert of.status_overloads((1 << 9) | (1 << 7)) == ["fx", "fz"]
    assert of.status_faults(0x2000) and of.status_faults(0x0400)


@given(st.lists(records(), max_size=20), st.data())
def test_round_trip_in_any_cut(items, data):
    stream = b"".join(encoded for _, encoded in items)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=8)))
    parser = of.OptoForceParser()
    decoded = []
    for a, b in zip([0, *cuts], [*cuts, len(stream)]):
        decoded += parser.feed(stream[a:b])
    assert decoded == [record for record, _ in items]
    assert parser.stats()["checksum_errors"] == 0 and parser.stats()["skipped_bytes"] == 0


@given(st.binary(max_size=600))
def test_arbitrary_bytes_never_crash_and_the_counts_add_up(blob):
    parser = of.OptoForceParser()
    out = parser.feed(blob[: len(blob) // 2]) + parser.feed(blob[len(blob) // 2 :])
    stats = parser.stats()
    assert stats["frames"] == len(out)
    assert stats["skipped_bytes"] + parser.pending() + sum(_size(r) for r in out) == len(blob)
    assert parser.pending() < of.MAX_FRAME_SIZE


def _size(record) -> int:
    if isinstance(record, of.Sample):
        return of.SAMPLE_KIND_BY_VALUES[len(record.counts)].size
    return {of.Ack: of.ACK, of.Config: of.CONFIG, of.SerialNumber: of.SERIAL_NUMBER}[type(record)].size


@given(st.lists(records(), min_size=1, max_size=10), st.lists(st.binary(max_size=40).map(lambda b: b.replace(b"\xaa", b"")), min_size=1, max_size=11))
def test_garbage_between_frames_is_skipped_and_every_frame_recovered(items, garbage):
    stream = bytearray()
    for i, (_, encoded) in enumerate(items):
        stream += garbage[i % len(garbage)] + encoded
    parser = of.OptoForceParser()
    assert parser.feed(bytes(stream)) == [record for record, _ in items]
    garbage_runs = sum(1 for i in range(len(items)) if garbage[i % len(garbage)])
    assert parser.stats()["resyncs"] == garbage_runs


@given(st.lists(st.lists(i16, min_size=3, max_size=3), min_size=2, max_size=10), st.data())
def test_a_bad_checksum_is_rejected_and_counted(samples, data):
    frames = [bytearray(of.encode_sample(i, 0, s)) for i, s in enumerate(samples)]
    bad = data.draw(st.integers(0, len(frames) - 1))
    byte = data.draw(st.integers(4, 15))  # any byte after the header, checksum included
    frames[bad][byte] ^= data.draw(st.integers(1, 255))
    parser = of.OptoForceParser()
    out = parser.feed(b"".join(frames))
    assert [r.counter for r in out] == [i for i in range(len(samples)) if i != bad]
    assert parser.stats()["checksum_errors"] >= 1


def test_an_ack_mid_stream_is_parsed_between_samples():
    stream = of.encode_sample(1, 0, (1, 2, 3)) + of.encode_ack(0) + of.encode_sample(2, 0, (4, 5, 6))
    parser = of.OptoForceParser()
    out = parser.feed(stream[:20]) + parser.feed(stream[20:])
    assert out == [of.Sample(1, 0, (1, 2, 3)), of.Ack(0), of.Sample(2, 0, (4, 5, 6))]


@settings(max_examples=examples(50))
@given(st.lists(st.lists(i16, min_size=3, max_size=3), min_size=1, max_size=20))
def test_converter_scales_counts_per_axis_and_tracks_the_counter(samples):
    converter = of.SampleConverter([100.0, 200.0, 400.0], axes=3)
    stream = b"".join(of.encode_sample(i, 0, s) for i, s in enumerate(samples))
    vectors = converter.forces(stream)
    # A count at the int16 limit is a clipped reading: held (the default policy), and counted.
    clipped = [s for s in samples if set(s) & {32767, -32767, -32768}]
    expected = [[s[0] / 100.0, s[1] / 200.0, s[2] / 400.0, 0.0, 0.0, 0.0] for s in samples if s not in clipped]
    assert len(vectors) == len(expected) and np.allclose(np.reshape(vectors, (-1, 6)), np.reshape(expected, (-1, 6)))
    assert converter.stats()["counter_gaps"] == 0 and converter.stats()["overloads"] == len(clipped)


@pytest.mark.parametrize(("policy", "kept"), [("hold", [1.0]), ("pass", [1.0, 3.0])])
def test_converter_drops_faulty_samples_and_counts_gaps_and_overloads(policy, kept):
    converter = of.SampleConverter(10.0, axes=3, saturation=policy)
    stream = (
        of.encode_sample(5, 0, (10, 0, 0))
        + of.encode_sample(6, 0x2000, (20, 0, 0))  # DAQ error: dropped
        + of.encode_sample(9, 1 << 9, (30, 0, 0))  # gap 6 -> 9, Fx overload flag: held, or passed
    )
    assert [v[0] for v in converter.forces(stream)] == kept
    stats = converter.stats()
    assert (stats["status_faults"], stats["counter_gaps"], stats["overloads"]) == (1, 1, 1)


def test_converter_picks_one_sensor_of_a_four_channel_daq():
    converter = of.SampleConverter(1.0, axes=3, sensor_index=2)
    counts = list(range(12))
    assert converter.forces(of.encode_sample(0, 0, counts)) == [[6.0, 7.0, 8.0, 0.0, 0.0, 0.0]]


def test_a_six_axis_frame_on_a_three_axis_reader_is_counted_not_used():
    converter = of.SampleConverter(1.0, axes=3)
    assert converter.forces(of.encode_sample(0, 0, [1] * 6)) == []
    assert converter.stats()["unexpected_frames"] == 1
    six = of.SampleConverter([1, 1, 1, 10, 10, 10], axes=6)
    assert six.forces(of.encode_sample(0, 0, [5] * 6)) == [[5.0, 5.0, 5.0, 0.5, 0.5, 0.5]]


@pytest.mark.parametrize(
    ("cpn", "axes", "match"),
    [([1.0, 2.0], 3, "needs 3 values"), ([1.0, 0.0, 1.0], 3, "positive"), ("abc", 3, "numbers"), (1.0, 4, "3 or 6 axes")],
)
def test_converter_rejects_bad_sensitivities(cpn, axes, match):
    with pytest.raises(ConfigError, match=match):
        of.SampleConverter(cpn, axes=axes)
