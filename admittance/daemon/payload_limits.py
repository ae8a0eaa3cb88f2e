"""Bounds on an untrusted payload, checked on its raw bytes before any parser sees it.

A Zenoh query's payload comes from anyone who reaches the daemon's endpoint. Two things must be
refused before decoding, because the decoder itself is what they attack:

- size: a payload above a few kilobytes is not a request (every live key of 32 joints fits in
  16 KiB), and parsing megabytes on the supervisor's thread would stall it;
- nesting depth: 100 000 ``[`` make msgspec raise RecursionError, which is not a decode error
  and used to end the daemon. A request is an object of numbers or lists of numbers (depth 2).

The depth is measured without decoding: for JSON, brackets outside strings; for MessagePack, by
walking the headers (containers push their item counts, everything else is skipped by its
length). Both walks are linear and allocate nothing per item.
"""

from __future__ import annotations

import re
import struct

from admittance.errors import DataError

_JSON_STRING = re.compile(rb'"(?:[^"\\]|\\.)*"', re.DOTALL)
_NOT_BRACKET = bytes(b for b in range(256) if b not in b"[]{}")


def check(payload: bytes, *, max_bytes: int, max_depth: int | None, is_json: bool) -> None:
    """DataError when ``payload`` is larger than ``max_bytes`` or nests deeper than ``max_depth``
    (None: the depth is not checked)."""
    if len(payload) > max_bytes:
        raise DataError(f"payload of {len(payload)} bytes is larger than the {max_bytes} bytes a request may have")
    if max_depth is None or (is_json and payload.count(b"[") + payload.count(b"{") <= max_depth):
        return  # (fewer brackets than the limit cannot nest deeper than it)
    depth = json_depth(payload, max_depth) if is_json else msgpack_depth(payload, max_depth)
    if depth > max_depth:
        raise DataError(f"payload nests deeper than {max_depth} levels")


def json_depth(payload: bytes, limit: int) -> int:
    """The bracket depth of a JSON text (strings skipped); stops counting past ``limit``.

    An unterminated string leaves its brackets counted: that only refuses a text the decoder
    would refuse anyway.
    """
    brackets = _JSON_STRING.sub(b"", payload).translate(None, _NOT_BRACKET)
    depth = deepest = 0
    for b in brackets:
        depth += 1 if b in b"[{" else -1
        if depth > deepest:
            deepest = depth
            if deepest > limit:
                break
    return deepest


# MessagePack: header byte -> (bytes of the length/count field, fixed payload bytes, kind), where
# kind is "skip" (length field counts payload bytes), "array" or "map" (count of items/pairs).
_LENGTH_FORMATS = {1: ">B", 2: ">H", 4: ">I"}
_VARIABLE = {0xC4: (1, "skip"), 0xC5: (2, "skip"), 0xC6: (4, "skip"),  # bin
             0xD9: (1, "skip"), 0xDA: (2, "skip"), 0xDB: (4, "skip"),  # str
             0xDC: (2, "array"), 0xDD: (4, "array"), 0xDE: (2, "map"), 0xDF: (4, "map")}
_EXT = {0xC7: 1, 0xC8: 2, 0xC9: 4}  # ext 8/16/32: length field, then a type byte, then data
_FIXED = {0xC0: 0, 0xC2: 0, 0xC3: 0, 0xCA: 4, 0xCB: 8, 0xCC: 1, 0xCD: 2, 0xCE: 4, 0xCF: 8,
          0xD0: 1, 0xD1: 2, 0xD2: 4, 0xD3: 8, 0xD4: 2, 0xD5: 3, 0xD6: 5, 0xD7: 9, 0xD8: 17}


def msgpack_depth(payload: bytes, limit: int) -> int:
    """The container depth of one MessagePack object; stops past ``limit``.

    DataError when the headers run past the end (a count larger than what follows) or use the
    reserved byte 0xC1.
    """
    pos, depth, deepest = 0, 0, 0
    pending = [1]  # items still expected at each open level; the top level holds one object
    while pending:
        if pending[-1] == 0:
            pending.pop()
            depth -= 1
            continue
        pending[-1] -= 1
        if pos >= len(payload):
            raise DataError("malformed payload: MessagePack data ends inside a container")
        head = payload[pos]
        pos += 1
        count, pos = _msgpack_item(payload, head, pos)
        if count is not None:
            depth += 1
            deepest = max(deepest, depth)
            if deepest > limit:
                return deepest
            pending.append(count)
    return deepest


def _msgpack_item(payload: bytes, head: int, pos: int) -> tuple[int | None, int]:
    """Skips the item whose header byte is ``head``; returns (items it contains or None, new pos)."""
    if head <= 0x7F or head >= 0xE0:  # positive and negative fixint
        return None, pos
    if 0x80 <= head <= 0x8F:
        return 2 * (head & 0x0F), pos
    if 0x90 <= head <= 0x9F:
        return head & 0x0F, pos
    if 0xA0 <= head <= 0xBF:
        return None, _advance(payload, pos, head & 0x1F)
    if head in _FIXED:
        return None, _advance(payload, pos, _FIXED[head])
    if head in _VARIABLE:
        size, kind = _VARIABLE[head]
        n = _read_length(payload, pos, size)
        pos += size
        if kind == "skip":
            return None, _advance(payload, pos, n)
        return (n if kind == "array" else 2 * n), pos
    if head in _EXT:
        size = _EXT[head]
        n = _read_length(payload, pos, size)
        return None, _advance(payload, pos + size, 1 + n)
    raise DataError(f"malformed payload: byte 0x{head:02x} is not a MessagePack header")


def _read_length(payload: bytes, pos: int, size: int) -> int:
    if pos + size > len(payload):
        raise DataError("malformed payload: MessagePack data ends inside a header")
    return struct.unpack_from(_LENGTH_FORMATS[size], payload, pos)[0]


def _advance(payload: bytes, pos: int, n: int) -> int:
    if pos + n > len(payload):
        raise DataError("malformed payload: MessagePack data ends inside an item")
    return pos + n
