"""The Lawicel ("slcan") ASCII protocol, from the adapter's side, for the simulated USB-CAN adapter.

A USB-CAN adapter in slcan mode (CANable, CANUSB and the like) is a serial port that speaks
lines ending in CR: the host sends commands (``C`` close, ``O`` open, ``S0``..``S8`` bit rate,
``tIIILDD..`` transmit) and the adapter answers each with CR, or BEL for a refused one, and,
while the channel is open, writes every received CAN frame as a ``t``/``T`` line (optionally
followed by a 4-digit millisecond timestamp after ``Z1``).

:class:`SlcanAdapter` is only that command state machine and line codec; it owns no port. The
simulated sensor (:mod:`admittance.mockbench.simulated_sensor`) moves its bytes on a pty, so the same
machine could sit behind any byte pipe. The refusals follow the Lawicel rules (a bit rate only
while closed, no second ``O``) rather than being lenient, so that the reader is tested against
the BEL answers a real adapter gives; python-can ignores them.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from admittance.errors import DataError

OK = b"\r"
ERROR = b"\a"
STANDARD_ID_MAX = 0x7FF
EXTENDED_ID_MAX = 0x1FFFFFFF
TIMESTAMP_WRAP_MS = 60_000  # the Lawicel timestamp counts milliseconds and wraps each minute
BITRATE_CODES = {
    "0": 10_000, "1": 20_000, "2": 50_000, "3": 100_000, "4": 125_000,
    "5": 250_000, "6": 500_000, "7": 750_000, "8": 1_000_000, "9": 83_300,
}
MAX_COMMAND_LENGTH = 64  # longer than any command: a host that never sends CR cannot grow the buffer
VERSION_REPLY = b"V1013\r"
SERIAL_NUMBER_REPLY = b"NA123\r"


@dataclass(frozen=True)
class CanFrame:
    can_id: int
    extended: bool
    data: bytes


def encode_frame(can_id: int, data: bytes, *, timestamp_ms: int | None = None) -> bytes:
    """One received data frame as the adapter reports it: ``t1008AA07...\\r`` (``T`` + 8 digits when extended)."""
    if not 0 <= can_id <= EXTENDED_ID_MAX or len(data) > 8:
        raise DataError(f"a CAN data frame has an identifier ≤ 0x1FFFFFFF and ≤ 8 bytes, got {can_id:#x} and {len(data)}")
    head = f"T{can_id:08X}" if can_id > STANDARD_ID_MAX else f"t{can_id:03X}"
    stamp = "" if timestamp_ms is None else f"{timestamp_ms % TIMESTAMP_WRAP_MS:04X}"
    return f"{head}{len(data)}{data.hex().upper()}{stamp}\r".encode("ascii")


def decode_frame(line: bytes) -> CanFrame:
    """A ``t``/``T`` line (without its CR) as the host sends it for transmission."""
    id_digits = {ord("t"): 3, ord("T"): 8}.get(line[0]) if line else None
    if id_digits is None:
        raise DataError(f"not an slcan data frame: {line!r}")
    try:
        can_id = int(line[1 : 1 + id_digits], 16)
        dlc = int(line[1 + id_digits : 2 + id_digits])
        hex_data = line[2 + id_digits :]
        if not 0 <= dlc <= 8 or len(hex_data) != 2 * dlc:
            raise ValueError
        data = bytes.fromhex(hex_data.decode("ascii"))
    except ValueError:
        raise DataError(f"malformed slcan data frame: {line!r}") from None
    return CanFrame(can_id, id_digits == 8, data)


class SlcanAdapter:
    """The adapter's command state: open or closed, bit rate, timestamps; answers every command."""

    def __init__(self) -> None:
        self.is_open = False
        self.bitrate: int | None = None
        self.timestamps = False
        self.commands = 0
        self.refused_commands = 0
        self._pending = bytearray()

    def feed(self, data: bytes) -> tuple[bytes, list[CanFrame]]:
        """Take host bytes in any cut; return (the answers to write back, the frames to transmit)."""
        self._pending += data
        *lines, rest = self._pending.split(b"\r")
        self._pending = bytearray(rest[-MAX_COMMAND_LENGTH:])
        replies = bytearray()
        frames: list[CanFrame] = []
        for line in lines:
            reply, frame = self._command(bytes(line).strip(b"\n"))
            self.commands += 1
            self.refused_commands += reply == ERROR
            replies += reply
            if frame is not None:
                frames.append(frame)
        return bytes(replies), frames

    def _command(self, line: bytes) -> tuple[bytes, CanFrame | None]:
        op, arg = line[:1], line[1:]
        if op == b"":
            return OK, None  # a bare CR: how hosts flush a half-sent command
        if op in (b"O", b"L"):
            return self._set_open(True)
        if op == b"C":
            return self._set_open(False)
        if op == b"S" and arg.decode("ascii", "replace") in BITRATE_CODES and not self.is_open:
            self.bitrate = BITRATE_CODES[arg.decode("ascii")]
            return OK, None
        if op == b"s" and len(arg) == 4 and not self.is_open:
            return OK, None  # BTR0/BTR1 register values: accepted, the simulated bus has no timing
        if op == b"Z" and arg in (b"0", b"1"):
            self.timestamps = arg == b"1"
            return OK, None
        if op == b"V":
            return VERSION_REPLY, None
        if op == b"N":
            return SERIAL_NUMBER_REPLY, None
        if op == b"F":
            return b"F00\r", None
        if op in (b"t", b"T") and self.is_open:
            try:
                frame = decode_frame(line)
            except DataError:
                return ERROR, None
            return (b"z\r" if op == b"t" else b"Z\r"), frame
        return ERROR, None

    def _set_open(self, wanted: bool) -> tuple[bytes, None]:
        # Lawicel refuses O on an open channel; C is always accepted (hosts send it blindly first).
        if wanted and self.is_open:
            return ERROR, None
        self.is_open = wanted
        return OK, None

    def frame_lines(self, can_id: int, payloads: Iterable[bytes], now_ms: int) -> bytes:
        """The lines for consecutive received frames with one identifier."""
        stamp = now_ms if self.timestamps else None
        return b"".join(encode_frame(can_id, p, timestamp_ms=stamp) for p in payloads)

    def stats(self) -> dict[str, object]:
        return {
            "slcan_open": self.is_open,
            "slcan_bitrate": self.bitrate,
            "slcan_commands": self.commands,
            "slcan_refused_commands": self.refused_commands,
        }
