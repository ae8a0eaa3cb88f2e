"""The raw-byte guards in front of the decoders: size and nesting depth of JSON and MessagePack,
measured without decoding, agree with the real depth, and malformed bytes are only DataErrors."""

from __future__ import annotations

import msgspec
import pytest
from hypothesis import given
from hypothesis import strategies as st

from admittance.daemon import payload_limits
from admittance.daemon.messages import MAX_REQUEST_BYTES, MAX_REQUEST_DEPTH, decode_set_request, decode_tare_request
from admittance.errors import DataError

scalars = st.one_of(st.none(), st.booleans(), st.integers(-2**63, 2**64 - 1), st.floats(allow_nan=False),
                    st.text(max_size=300), st.binary(max_size=300))
values = st.recursive(scalars, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                       st.dictionaries(st.text(max_size=5), inner, max_size=4)),
                      max_leaves=30)


def depth(value) -> int:
    """The nesting depth the oracle way: by walking the decoded value."""
    if isinstance(value, list):
        return 1 + max((depth(v) for v in value), default=0)
    if isinstance(value, dict):
        return 1 + max((depth(v) for v in value.values()), default=0)
    return 0


@given(value=values)
def test_the_json_depth_is_the_real_depth(value):
    json_value = value if not isinstance(value, bytes) else None
    encoded = msgspec.json.encode(json_value)
    assert payload_limits.json_depth(encoded, limit=100) == depth(msgspec.json.decode(encoded))


@given(value=values)
def test_the_msgpack_depth_is_the_real_depth(value):
    encoded = msgspec.msgpack.encode(value)
    assert payload_limits.msgpack_depth(encoded, limit=100) == depth(value)


@given(payload=st.binary(max_size=200))
def test_arbitrary_bytes_are_measured_or_refused_as_data_errors(payload):
    for is_json in (True, False):
        try:
            payload_limits.check(payload, max_bytes=1000, max_depth=4, is_json=is_json)
        except DataError:
            pass


@pytest.mark.parametrize("payload", [
    b"[" * 100_000,  # the RecursionError
    b"[" * 2000,  # under the size cap, still far too deep for a request
    b'{"a": ' + b"[" * 3000 + b"]" * 3000 + b"}",  # well-formed, under the cap: RecursionError in msgspec
    b"\x81\xa1a" + b"\x91" * 3000 + b"\x90",  # the same in MessagePack
    b'{"a": [[[[[1]]]]]}',
    b"\x91" * 2000,  # MessagePack: nested one-element arrays
    b"\xdd\xff\xff\xff\xff" * 10,  # MessagePack arrays that claim 4 billion items
    b'{"a": "' + b"x" * 100_000 + b'"}',  # a huge string
    b"\xc1",  # MessagePack's reserved byte
])
def test_deep_huge_or_truncated_payloads_are_refused_before_decoding(payload):
    with pytest.raises(DataError) as refused:
        decode_set_request(payload)
    assert len(str(refused.value)) < 200


def test_the_limits_let_every_real_request_through():
    request = {f"{jid}.{key}": 0.5 for jid in range(32) for key in (
        "virtual_inertia", "virtual_damping", "virtual_coulomb", "lever_arm", "position_min", "position_max",
        "velocity_max", "limits.acceleration_max")}
    request["bias"] = [0.0] * 6
    for encoded in (msgspec.json.encode(request), msgspec.msgpack.encode(request)):
        assert len(encoded) <= MAX_REQUEST_BYTES and decode_set_request(encoded) == request
    assert payload_limits.json_depth(b'{"bias": [1, 2]}', MAX_REQUEST_DEPTH) == 2
    assert payload_limits.json_depth(b'{"a[": "]]]["}', MAX_REQUEST_DEPTH) == 1, "brackets in strings do not count"


@pytest.mark.parametrize("payload", [b'{"samples": ' + b"9" * 400 + b"}", b"[" * 100_000,
                                     b'{"samples": 5, "x": 1}', b"\xff\xfe"])
def test_bad_tare_requests_are_data_errors_with_short_reasons(payload):
    with pytest.raises(DataError) as refused:
        decode_tare_request(payload)
    assert len(str(refused.value)) < 200


def test_a_request_over_the_size_cap_is_refused_for_its_size_whatever_it_holds():
    request = {f"{k}.virtual_damping": 0.05 for k in range(1000)}  # well-formed, shallow, 26 KB
    for payload in (msgspec.json.encode(request), msgspec.msgpack.encode(request)):
        assert len(payload) > MAX_REQUEST_BYTES
        with pytest.raises(DataError, match=f"larger than the {MAX_REQUEST_BYTES} bytes"):
            decode_set_request(payload)
