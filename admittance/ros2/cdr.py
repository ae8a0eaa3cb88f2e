"""A little-endian CDR (XCDR1, as rmw_zenoh/Fast CDR write it) encoder for the few types we publish.

A serialized ROS 2 message is a 4-byte encapsulation header (``00 01 00 00``: plain CDR, little
endian) and the fields in order, each aligned to its own size (at most 8) counted from the end
of the header. Strings are a uint32 length that counts the terminating NUL, the UTF-8 bytes and
the NUL; sequences a uint32 element count, then the elements.

Only the encoder lives here: tests decode with rosbags' CDR deserializer, never with this code.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Sequence

ENCAPSULATION_CDR_LE = b"\x00\x01\x00\x00"


class CdrWriter:
    """Appends CDR fields; ``bytes(writer)`` is the payload with its encapsulation header."""

    def __init__(self) -> None:
        self._buf = bytearray(ENCAPSULATION_CDR_LE)

    def _align(self, size: int) -> None:
        pad = -(len(self._buf) - len(ENCAPSULATION_CDR_LE)) % size
        self._buf.extend(b"\x00" * pad)

    def int32(self, value: int) -> None:
        self._align(4)
        self._buf += struct.pack("<i", value)

    def uint32(self, value: int) -> None:
        self._align(4)
        self._buf += struct.pack("<I", value)

    def float64(self, value: float) -> None:
        self._align(8)
        self._buf += struct.pack("<d", value)

    def string(self, value: str) -> None:
        data = value.encode("utf-8")
        self.uint32(len(data) + 1)
        self._buf += data + b"\x00"

    def float64_sequence(self, values: Sequence[float]) -> None:
        self.uint32(len(values))
        if values:
            self._align(8)
            self._buf += struct.pack(f"<{len(values)}d", *values)

    def string_sequence(self, values: Iterable[str]) -> None:
        values = list(values)
        self.uint32(len(values))
        for value in values:
            self.string(value)

    def __bytes__(self) -> bytes:
        return bytes(self._buf)
