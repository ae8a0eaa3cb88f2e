"""A pseudo-terminal that captures every byte a Dynamixel host writes and answers like servos.

Shared by the dxl tests and the SyncWrite bench: the host (dynamixel-sdk or our DxlClient)
opens the slave path; a thread reads the master, records the raw bytes, decodes instructions
with the Rust decoder and replies with the Rust status encoder.
"""

from __future__ import annotations

import os
import select
import threading
import tty

from admittance import _rtcore

PING, READ, WRITE, REBOOT, SYNC_READ, BULK_READ = 0x01, 0x02, 0x03, 0x08, 0x82, 0x92
MODEL_NUMBER = {1: 310, 2: 311}  # MX-64 on each firmware
FIRMWARE = 45


class PtyServos:
    """Servos with IDs ``ids`` behind a pty; ``captured`` holds everything the host wrote."""

    def __init__(self, protocol: int, ids=(1, 2, 3, 7), memory_value: int = 0x5A):
        self.protocol = protocol
        self.ids = set(ids)
        self.memory_value = memory_value
        self.master, self._slave = os.openpty()
        tty.setraw(self._slave)  # the line discipline sits on the slave: raw, or binary breaks
        self.path = os.ttyname(self._slave)
        self.captured = bytearray()
        self._arrived = threading.Condition()
        self._decoder = _rtcore.Decoder(protocol, expect="instruction")
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def take(self, n: int, timeout_s: float = 5.0) -> bytes:
        """Wait until at least ``n`` bytes were captured (or ``timeout_s``), return them all
        and forget them. Waiting for a count, not for quiet, keeps it independent of load."""
        with self._arrived:
            self._arrived.wait_for(lambda: len(self.captured) >= n, timeout_s)
            data = bytes(self.captured)
            self.captured.clear()
        return data

    def clear(self) -> None:
        with self._arrived:
            self.captured.clear()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1)
        os.close(self.master)
        os.close(self._slave)

    def _serve(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([self.master], [], [], 0.02)
            if not ready:
                continue
            try:
                data = os.read(self.master, 4096)
            except OSError:
                return
            with self._arrived:
                self.captured += data
                self._arrived.notify_all()
            for packet in self._decoder.push(data):
                if packet["kind"] == "instruction":
                    self._answer(packet)

    def _status(self, id_: int, params: bytes = b"") -> None:
        os.write(self.master, _rtcore.encode_status(id_, 0, params, protocol=self.protocol))

    def _data(self, length: int) -> bytes:
        return bytes([self.memory_value]) * length

    def _answer(self, p: dict) -> None:
        instr, params, id_ = p["instruction"], p["params"], p["id"]
        wide = self.protocol == 2
        if instr == PING and id_ in self.ids:
            body = MODEL_NUMBER[self.protocol].to_bytes(2, "little") + bytes([FIRMWARE]) if wide else b""
            self._status(id_, body)
        elif instr == READ and id_ in self.ids:
            address = int.from_bytes(params[:2], "little") if wide else params[0]
            length = int.from_bytes(params[2:4], "little") if wide else params[1]
            if address == 0:
                self._status(id_, MODEL_NUMBER[self.protocol].to_bytes(2, "little")[:length])
            else:
                self._status(id_, self._data(length))
        elif instr in (WRITE, REBOOT) and id_ in self.ids:
            self._status(id_)
        elif instr == SYNC_READ:
            length = int.from_bytes(params[2:4], "little")
            for target in params[4:]:
                if target in self.ids:
                    self._status(target, self._data(length))
        elif instr == BULK_READ:
            entries = (
                [(params[i], int.from_bytes(params[i + 3 : i + 5], "little")) for i in range(0, len(params), 5)]
                if wide
                else [(params[i + 1], params[i]) for i in range(1, len(params), 3)]
            )
            for target, length in entries:
                if target in self.ids:
                    self._status(target, self._data(length))
