"""The Zenoh payloads: both encodings round-trip, and malformed requests are DataErrors."""

from __future__ import annotations

import msgspec
import pytest
from hypothesis import example, given
from hypothesis import strategies as st

from admittance.daemon.messages import (
    Codec, JointState, ParamsReply, SetReply, State, Stats, decode, decode_set_request, stats_message,
)
from admittance.errors import DataError

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
joint_states = st.builds(
    JointState, id=st.integers(0, 252), t=finite, force=finite, tau=finite, theta=finite, omega=finite,
    goal_tick=st.integers(0, 4095), present_tick=st.one_of(st.none(), st.integers(0, 4095)))
states = st.builds(State, cycle=st.integers(0, 2**63 - 1), joints=st.lists(joint_states, max_size=4))
names = st.text(st.characters(min_codepoint=33, max_codepoint=126), min_size=1, max_size=20)


@pytest.mark.parametrize("encoding", ["json", "msgpack"])
@given(state=states)
def test_state_round_trips_in_both_encodings(encoding, state):
    assert decode(Codec(encoding).encode(state), State) == state


@pytest.mark.parametrize("encoding", ["json", "msgpack"])
@given(request=st.dictionaries(names, st.one_of(finite, st.lists(finite, min_size=1, max_size=6)), min_size=1))
def test_set_requests_round_trip_in_both_encodings(encoding, request):
    assert decode_set_request(Codec(encoding).encode(request)) == request


@given(payload=st.binary(max_size=64))
@example(payload=b"\x81\xa7\x00\x00\x00\x00\x00\x00\x80")  # MessagePack string with invalid UTF-8
def test_arbitrary_bytes_never_escape_as_anything_but_data_error(payload):
    try:
        decode_set_request(payload)
    except DataError:
        pass


@pytest.mark.parametrize("payload, message", [
    (b"", "empty request"),
    (b"{}", "no parameter"),
    (b'{"virtual_damping": "x"}', "virtual_damping: expected a number"),
    (b'{"virtual_damping": true}', "expected a number"),
    (b'{"bias": [1, "a"]}', r"bias\[1\]: expected a number"),
    (b"[1, 2]", "malformed payload"),
    (b'{"a": ', "malformed payload"),
    (b'{"velocity_max": ' + b"9" * 400 + b"}", r"velocity_max: integer out of range \(beyond ±2\^53\), got an integer of"),
    (b'{"bias": [0, 0, ' + b"9" * 400 + b", 0, 0, 0]}", r"bias\[2\]: integer out of range"),
    (msgspec.msgpack.encode({"deadband": 2**64 - 1}), "deadband: integer out of range"),
    (b'{"deadband": 1e999}', "malformed payload: Number out of range"),
    (b'{"deadband": NaN}', "malformed payload"),
])
def test_bad_set_requests_say_why(payload, message):
    with pytest.raises(DataError, match=message) as refused:
        decode_set_request(payload)
    assert len(str(refused.value)) < 200


def test_set_reply_omits_an_empty_reason():
    assert Codec().encode(SetReply(accepted=True)) == b'{"accepted":true}'
    assert decode(Codec().encode(SetReply(False, "no")), dict) == {"accepted": False, "reason": "no"}
    assert decode(Codec("msgpack").encode(ParamsReply({"1.x": 1.0})), ParamsReply).params == {"1.x": 1.0}


def test_stats_message_keeps_every_key_and_requires_the_contract_ones():
    p = {"p50": 1.0, "p99": 2.0, "p999": 3.0, "max": 4.0}
    stats = {"cycles": 5, "overruns": 0, "rate_hz": 1000.0, "period_us": p, "latency_us": p, "bus_errors": 0,
             "sensor_samples": 3, "sensor_stale_events": 1,
             "rt": {"policy": "SCHED_OTHER", "priority": 0, "memory_locked": False}, "sync_reads": 9}
    message = stats_message(stats)
    assert msgspec.json.decode(Codec().encode(message)) == stats
    assert msgspec.convert(stats, Stats, strict=False).rt.policy == "SCHED_OTHER"
    del stats["rt"]
    with pytest.raises(DataError, match="rt"):
        stats_message(stats)
