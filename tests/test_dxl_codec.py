"""The Rust codecs through the binding: e-manual vectors, round trips (hypothesis), arbitrary
byte streams, and the model table's shape."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from admittance import _rtcore

from helpers import examples

STATUS = 0x55
ids2 = st.integers(0, 0xFC)
ids1 = st.integers(0, 0xFD)
# Bytes biased to the header run, so stuffing happens in most examples.
payloads = st.lists(st.sampled_from([0xFF, 0xFD, 0x00, 0x01, 0x55]) | st.integers(0, 255), max_size=120).map(bytes)


def decode(data: bytes, protocol: int = 2, expect: str = "status") -> list[dict]:
    return _rtcore.Decoder(protocol, expect).push(data)


def test_crc_check_value_and_an_emanual_vector():
    assert _rtcore.crc16(b"123456789") == 0xFEE8
    assert _rtcore.encode_ping(1) == bytes.fromhex("FFFFFD0001030001194E")
    restore = bytes.fromhex("FFFFFD0001080020024354524C")  # the e-manual prints 92 F5 for it
    assert _rtcore.crc16(restore).to_bytes(2, "little") == bytes.fromhex("9EF5")


def test_protocol_1_vectors():
    assert _rtcore.encode_read(1, 43, 1, protocol=1) == bytes.fromhex("FFFF0104022B01CC")
    sync = _rtcore.encode_sync_write(30, 4, [(0, bytes.fromhex("10005001")), (1, bytes.fromhex("20026003"))], protocol=1)
    assert sync == bytes.fromhex("FF FF FE 0E 83 1E 04 00 10 00 50 01 01 20 02 60 03 67")
    [status] = decode(bytes.fromhex("FF FF 01 02 24 D8"), protocol=1)
    assert (status["error"], status["failed"], status["alert"]) == (0x24, False, True)


@given(ids2, st.integers(0, 255).filter(lambda i: i != STATUS), payloads)
def test_instruction_round_trip(id_, instruction, params):
    [p] = decode(_rtcore.encode_instruction(id_, instruction, params))
    assert (p["kind"], p["id"], p["instruction"], p["params"]) == ("instruction", id_, instruction, params)


@given(ids2, st.integers(0, 255), payloads)
def test_status_round_trip_keeps_error_and_alert(id_, error, params):
    [p] = decode(_rtcore.encode_status(id_, error, params))
    assert (p["id"], p["error"], p["alert"], p["params"]) == (id_, error, bool(error & 0x80), params)
    assert p["failed"] == bool(error & 0x7F)


@given(st.lists(st.tuples(ids2, st.binary(min_size=4, max_size=4)), max_size=12), st.integers(0, 0xFFFF))
def test_sync_write_round_trip(records, address):
    [p] = decode(_rtcore.encode_sync_write(address, 4, records), expect="instruction")
    body = address.to_bytes(2, "little") + b"\x04\x00" + b"".join(bytes([i]) + d for i, d in records)
    assert (p["id"], p["instruction"], p["params"]) == (0xFE, 0x83, body)


@given(ids1, st.integers(0, 255), st.binary(max_size=100))
def test_protocol_1_round_trip(id_, address, data):
    [p] = decode(_rtcore.encode_write(id_, address, data, protocol=1), protocol=1, expect="instruction")
    assert (p["id"], p["instruction"], p["params"]) == (id_, 0x03, bytes([address]) + data)


@settings(max_examples=examples(200))
@given(st.binary(max_size=3000), st.integers(0, 1))
def test_arbitrary_bytes_never_break_the_decoder(data, protocol_index):
    protocol = (1, 2)[protocol_index]
    dec = _rtcore.Decoder(protocol)
    items = dec.push(data)
    assert all(i["kind"] in ("status", "instruction", "decode_error") for i in items)
    # Whatever came before, a valid packet after it is still found.
    tail = dec.push(b"\x00" + _rtcore.encode_status(7, 0, b"ok", protocol=protocol))
    assert tail and tail[-1]["kind"] == "status" and tail[-1]["params"] == b"ok"


def test_crc_error_carries_expected_and_actual():
    bad = bytearray(_rtcore.encode_ping(1))
    bad[-1] ^= 0xFF
    [err] = decode(bytes(bad))
    assert err["type"] == "crc" and err["actual"] == err["expected"] ^ 0xFF00
    assert "CRC mismatch" in err["message"]


def test_bad_arguments_raise_value_error():
    with pytest.raises(ValueError, match="protocol must be 1 or 2"):
        _rtcore.encode_ping(1, protocol=3)
    with pytest.raises(ValueError, match="does not fit"):
        _rtcore.encode_read(1, 300, 2, protocol=1)
    with pytest.raises(ValueError, match="expected 4"):
        _rtcore.encode_sync_write(116, 4, [(1, b"\x00")])
    with pytest.raises(ValueError, match="invalid Dynamixel ID"):
        _rtcore.encode_ping(0xFD)
    with pytest.raises(ValueError, match="Protocol 1.0"):
        _rtcore.encode_reboot(1, protocol=1)


def test_model_table_covers_every_model_and_key_item():
    models = {(m["name"], m["protocol"]): m for m in _rtcore.model_table()}
    numbers = {key: m["number"] for key, m in models.items()}
    assert numbers == {
        ("MX-28", 1): 29, ("MX-64", 1): 310, ("MX-106", 1): 320,
        ("MX-28", 2): 30, ("MX-64", 2): 311, ("MX-106", 2): 321,
        ("XM430-W350", 2): 1020, ("XL330-M288", 2): 1200,
    }  # fmt: skip
    items = {i["name"]: i for i in models[("MX-64", 2)]["items"]}
    goal = items["Goal Position"]
    assert (goal["address"], goal["size"], goal["access"], goal["signed"]) == (116, 4, "RW", True)
    assert items["Present Position"]["access"] == "R"
    assert items["ID"]["eeprom"] and (items["ID"]["min"], items["ID"]["max"]) == (0, 252)
    runs = [(i["first_number"], i["address"], i["count"]) for i in models[("MX-64", 2)]["items"] if i["name"] == "Indirect Address"]
    assert runs == [(1, 168, 28), (29, 578, 28)]
    keys = {"name", "address", "size", "access", "eeprom", "signed", "default", "min", "max", "unit", "count"}
    assert set(goal) == keys | {"default_step", "first_number"}
