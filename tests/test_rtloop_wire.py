"""The RT loop's bytes on the wire, decoded by a fake bus on a pseudo-terminal.

A test thread owns the pty master: it decodes every packet the loop sends with `_rtcore`'s
own decoder and answers present-position reads (SYNC_READ on Protocol 2.0, BULK_READ on 1.0)
as servos would. This checks what MockBus cannot show: exactly one SyncWrite per cycle,
carrying every joint, and the bumpless start sequence.
"""

from __future__ import annotations

import os
import select
import threading
import time
import tty

import pytest

from admittance import _rtcore

READ, SYNC_READ, SYNC_WRITE, BULK_READ = 0x02, 0x82, 0x83, 0x92
IDS = (1, 2, 3)
REGISTERS = {2: dict(goal=116, size=4, present=132, torque=64), 1: dict(goal=30, size=2, present=36, torque=24)}


class FakeServos(threading.Thread):
    """Decodes the loop's instructions; answers reads with present tick 2048 + id."""

    def __init__(self, protocol: int):
        super().__init__(daemon=True)
        self.protocol = protocol
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)
        self.decoder = _rtcore.Decoder(protocol, expect="instruction")
        self.packets: list[dict] = []
        self.done = threading.Event()

    def run(self) -> None:
        while not self.done.is_set():
            ready, _, _ = select.select([self.master], [], [], 0.02)
            if not ready:
                continue
            for packet in self.decoder.push(os.read(self.master, 4096)):
                self.packets.append(packet)
                if packet.get("instruction") in (SYNC_READ, BULK_READ):
                    self.answer()
                elif packet.get("instruction") == READ and packet.get("id") in IDS:
                    self.answer_read(packet)

    def answer(self) -> None:
        size = REGISTERS[self.protocol]["size"]
        for i in IDS:
            tick = (2048 + i).to_bytes(size, "little")
            os.write(self.master, _rtcore.encode_status(i, 0, tick, protocol=self.protocol))

    def answer_read(self, packet: dict) -> None:
        """The recovery's checks (docs/faults.md): Torque Enable reads 1 (on), anything else
        (Hardware Error Status) 0; one byte each."""
        params = packet["params"]
        address = int.from_bytes(params[:2], "little") if self.protocol == 2 else params[0]
        value = 1 if address == REGISTERS[self.protocol]["torque"] else 0
        os.write(self.master, _rtcore.encode_status(packet["id"], 0, bytes([value]), protocol=self.protocol))

    def close(self) -> None:
        self.done.set()
        self.join()
        os.close(self.master)
        os.close(self.slave)

    def sync_writes(self, address: int) -> list[bytes]:
        """The data part of every SyncWrite to `address`."""
        head = 4 if self.protocol == 2 else 2
        out = []
        for p in self.packets:
            if p.get("instruction") == SYNC_WRITE:
                params = p["params"]
                if int.from_bytes(params[: head // 2], "little") == address:
                    out.append(params[head:])
        return out


def wait_for(condition, what: str, limit_s: float = 20.0) -> None:
    end = time.monotonic() + limit_s
    while not condition():
        if time.monotonic() > end:
            pytest.fail(f"gave up waiting for {what}")
        time.sleep(0.005)


@pytest.mark.parametrize("protocol", [2, 1])
def test_one_sync_write_per_cycle_carries_every_joint(protocol):
    servos = FakeServos(protocol)
    servos.start()
    regs = REGISTERS[protocol]
    joints = [{"id": i, "goal_address": regs["goal"], "goal_size": regs["size"],
               "present_address": regs["present"], "present_size": regs["size"],
               "torque_enable_address": regs["torque"], "virtual_coulomb": 0.0} for i in IDS]
    loop = _rtcore.AdmittanceLoop({"port": servos.path, "protocol": protocol, "rate_hz": 500,
                                   "rt_priority": 0, "lock_memory": False, "sync_read_divisor": 0,
                                   "joints": joints})
    try:
        loop.start()
        sink = loop.force_sink()
        wait_for(lambda: sink.push(time.monotonic_ns(), [1.0]) and loop.heartbeat() >= 100, "100 cycles")
        loop.stop("torque_off")
        cycles = loop.heartbeat()
        goals = lambda: servos.sync_writes(regs["goal"])  # noqa: E731
        wait_for(lambda: len(goals()) == cycles + 1 and len(servos.sync_writes(regs["torque"])) == 2,
                 "every SyncWrite on the wire")
    finally:
        servos.close()
    size = regs["size"]
    record = 1 + size
    first, *per_cycle = goals()
    # Bumpless start: the first goals are the present positions, before torque is enabled.
    assert [int.from_bytes(first[k * record + 1:(k + 1) * record], "little") for k in range(3)] == [2049, 2050, 2051]
    for data in per_cycle:
        assert len(data) == 3 * record
        assert [data[k * record] for k in range(3)] == list(IDS)
    torque_on, torque_off = servos.sync_writes(regs["torque"])
    assert torque_on == bytes([1, 1, 2, 1, 3, 1]) and torque_off == bytes([1, 0, 2, 0, 3, 0])
    # Every reply the fake servos sent parsed: no corrupt, error-status or I/O failure. A reply
    # can still miss its deadline when the machine is loaded (the fake is a Python thread), so
    # timeouts are allowed, but only a few: a malformed read request goes unanswered every cycle.
    stats = loop.stats()
    kinds = stats["bus_error_kinds"]
    assert {k: n for k, n in kinds.items() if k != "read_timeout" and n} == {}, stats
    assert kinds["read_timeout"] <= cycles // 10, stats


def test_a_bus_that_stops_reading_costs_bus_errors_not_a_hang():
    servos = FakeServos(2)
    servos.start()
    joints = [{"id": i} for i in IDS]
    loop = _rtcore.AdmittanceLoop({"port": servos.path, "rate_hz": 2000, "rt_priority": 0,
                                   "lock_memory": False, "sync_read_divisor": 0, "joints": joints})
    try:
        loop.start()
        servos.done.set()  # the far end stops reading: the pty's buffer fills up
        servos.join()
        wait_for(lambda: loop.stats()["bus_errors"] > 0, "a write that times out")
        beat = loop.heartbeat()
        wait_for(lambda: loop.heartbeat() > beat + 10, "the loop going on")
        loop.stop("hold")
    finally:
        servos.close()
    assert not loop.running()
