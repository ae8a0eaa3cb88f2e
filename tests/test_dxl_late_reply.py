"""A reply that misses the host's timeout is still the answer to the instruction that is out:
ServoBus waits for it before sending again, so no reply is left on the wire for the next
instruction to take as its own (dynamixel.py, late replies).

The servo here is a pty whose thread stalls, as a simulated bus's thread does on a loaded
machine: its replies go out in order, each held for its scripted delay."""

from __future__ import annotations

import heapq
import os
import threading
import time

import pytest

from admittance.drivers.control_table import table_for_number
from admittance.drivers.dynamixel import ServoBus, decode_hardware_error

from dxl_pty import FIRMWARE, MODEL_NUMBER, PING, READ, PtyServos

FIRMWARE_VERSION, HARDWARE_ERROR_STATUS = 6, 70  # MX(2.0) addresses
SLACK_MS = 500.0  # the host gives up on a reply after about this long
LATE_MS = 5000.0  # and then awaits it this long before it sends again


class StallingServos(PtyServos):
    """MX-64 (2.0) servos whose replies to the n-th instruction of a kind are held
    ``delays[(instruction, address, n)]`` seconds after it arrived, and never overtake an
    earlier reply (one thread answers in order). Every other reply goes out at once."""

    def __init__(self, delays: dict[tuple[int, int, int], float]) -> None:
        self.delays = delays
        self.seen: dict[tuple[int, int], int] = {}
        self._due: list[tuple[float, int, bytes]] = []
        self._last_due = 0.0
        self._wake = threading.Condition()
        super().__init__(protocol=2, ids=(1,))
        self._writer = threading.Thread(target=self._write_due, daemon=True)
        self._writer.start()

    def _answer(self, p: dict) -> None:
        address = int.from_bytes(p["params"][:2], "little") if p["instruction"] == READ else 0
        kind = (p["instruction"], address)
        self.seen[kind] = self.seen.get(kind, 0) + 1
        self._delay = self.delays.get((*kind, self.seen[kind]), 0.0)
        if p["instruction"] == READ and address in (FIRMWARE_VERSION, HARDWARE_ERROR_STATUS):
            self._status(p["id"], bytes([FIRMWARE if address == FIRMWARE_VERSION else 0]))
        else:
            super()._answer(p)

    def _status(self, id_: int, params: bytes = b"") -> None:
        from admittance import _rtcore

        packet = _rtcore.encode_status(id_, 0, params, protocol=2)
        with self._wake:
            self._last_due = max(self._last_due, time.monotonic() + self._delay)
            heapq.heappush(self._due, (self._last_due, len(self._due), packet))
            self._wake.notify()

    def _write_due(self) -> None:
        while not self._stop.is_set():
            with self._wake:
                self._wake.wait_for(lambda: bool(self._due) or self._stop.is_set(), 0.05)
                if not self._due or self._due[0][0] > time.monotonic():
                    if self._due:
                        self._wake.wait(self._due[0][0] - time.monotonic())
                    continue
                _, _, packet = heapq.heappop(self._due)
            try:
                os.write(self.master, packet)
            except OSError:  # closed
                return


@pytest.fixture
def stalling():
    made = []

    def make(delays):
        made.append(StallingServos(delays))
        return made[-1]

    yield make
    for servos in made:
        servos.close()


def test_a_late_reply_is_not_taken_as_the_next_reads(stalling):
    """The start's sequence: Firmware Version (45 = 0x2D), then Hardware Error Status (0). The
    thread stalls on the first read, and again on a copy sent after the timeout: that copy's
    reply, 45, would come after the next read went out and be read as four hardware errors."""
    # 1.5 timeouts: the reply to the first copy comes while the host waits for the second's
    servos = stalling({(READ, FIRMWARE_VERSION, 1): 1.5 * SLACK_MS / 1e3, (READ, FIRMWARE_VERSION, 2): SLACK_MS / 1e3})
    with ServoBus(servos.path, reply_slack_ms=SLACK_MS, late_reply_ms=LATE_MS, auto_recover=False) as bus:
        bus._tables[1] = table_for_number(2, MODEL_NUMBER[2])  # known: no PING, no read before these
        assert bus.read_raw(1, "Firmware Version") == FIRMWARE
        assert bus.hardware_error(1) == [], "a late Firmware Version taken as the alert's causes"
    assert servos.seen[(READ, FIRMWARE_VERSION)] == 1, "sent again although its reply was on its way"
    assert decode_hardware_error(FIRMWARE) == ["input voltage", "overheating", "motor encoder", "overload"]


def test_a_ping_answered_after_the_timeout_finds_the_servo(stalling):
    servos = stalling({(PING, 0, 1): 3 * SLACK_MS / 1e3})  # past both copies' timeouts
    with ServoBus(servos.path, reply_slack_ms=SLACK_MS, late_reply_ms=LATE_MS) as bus:
        info = bus.ping(1)
    assert info is not None and info.model == "MX-64" and info.firmware == FIRMWARE
    assert servos.seen[(PING, 0)] == 1


def test_a_scan_takes_silence_for_an_answer_without_a_late_wait(stalling):
    servos = stalling({})
    with ServoBus(servos.path, protocol=2, reply_slack_ms=SLACK_MS, late_reply_ms=LATE_MS) as bus:
        start = time.monotonic()
        assert [s.id for s in bus.scan(ids=[1, 2, 3])] == [1]
        assert time.monotonic() - start < LATE_MS / 1e3, "absent IDs were awaited late"


def test_the_daemon_never_sends_a_setup_instruction_twice_on_a_pty(stalling):
    """A pty loses no bytes: past its late window the daemon's setup gives up (one clear line)
    rather than send again and leave a second reply for the next instruction (backends.py)."""
    from types import SimpleNamespace

    from admittance.daemon.backends import PTY_REPLY_WAIT_MS, open_setup_bus
    from admittance.drivers.dynamixel import ServoTimeout

    past_the_window_s = PTY_REPLY_WAIT_MS / 1e3 + 0.5
    servos = stalling({(READ, FIRMWARE_VERSION, 1): past_the_window_s})
    cfg = SimpleNamespace(bus=SimpleNamespace(baudrate=1_000_000, protocol=2))
    with open_setup_bus(cfg, servos.path) as bus:
        bus._tables[1] = table_for_number(2, MODEL_NUMBER[2])
        with pytest.raises(ServoTimeout):
            bus.read_raw(1, "Firmware Version")
    assert servos.seen[(READ, FIRMWARE_VERSION)] == 1
