"""The loop's present-position read on the simulated bus: Fast Sync Read where the servos answer
it, Sync Read where they do not (docs/realtime.md, "Fast Sync Read")."""

from __future__ import annotations

import time

import pytest

from admittance import _rtcore
from admittance.errors import ConfigError
from helpers import MX64_PLANT


def servos(n: int, **extra) -> list[dict]:
    return [{"id": i, "model": "MX-64", "protocol": 2, "params": dict(MX64_PLANT), "initial_theta": 0.1 * i,
             "registers": {"Return Delay Time": 0}, **extra} for i in range(1, n + 1)]


def config(n: int, read: str, protocol: int = 2) -> dict:
    joints = [{"id": i, "model": "MX-64", "virtual_inertia": 0.02, "virtual_damping": 0.05, "virtual_coulomb": 0.0,
               "axis": "x", "lever_arm": 0.1} for i in range(1, n + 1)]
    return {"port": "in-process", "protocol": protocol, "rate_hz": 250.0, "rt_priority": 0, "lock_memory": False,
            "trigger": "schedule", "sync_read_divisor": 1, "stale_timeout_ms": 1e4, "bus_read": read,
            "joints": joints, "start_timeout_ms": 2000.0}


def run(bus_servos: list[dict], read: str, seconds: float = 0.3) -> tuple[dict, list[str]]:
    bus = _rtcore.MockBus(servos=bus_servos, baudrate=4_000_000, wire_delay=True)
    bus.start()
    try:
        loop = _rtcore.AdmittanceLoop(config(len(bus_servos), read))
        loop.start(simulated_bus=bus)
        try:
            time.sleep(seconds)
            return loop.stats(), loop.warnings()
        finally:
            loop.stop("hold")
    finally:
        bus.stop()


@pytest.mark.parametrize("read, expected", [("auto", "fast_sync_read"), ("fast", "fast_sync_read"),
                                             ("sync", "sync_read")])
def test_the_loop_reads_as_configured_and_says_so(read, expected):
    stats, warnings = run(servos(3), read)
    assert stats["bus"]["read"] == expected
    assert stats["sync_reads"] > 10, "positions arrive"
    assert not any("Fast Sync Read" in w for w in warnings)


def test_auto_falls_back_to_sync_read_where_a_firmware_lacks_fast_sync_read():
    bus_servos = servos(3)
    bus_servos[1]["fast_sync_read"] = False  # one servo's firmware without it
    stats, warnings = run(bus_servos, "auto")
    assert stats["bus"]["read"] == "sync_read"
    assert stats["sync_reads"] > 10, "positions arrive"
    assert any("Fast Sync Read went unanswered at start" in w for w in warnings), warnings


def test_fast_without_fallback_refuses_to_start_where_it_goes_unanswered():
    bus = _rtcore.MockBus(servos=servos(2, fast_sync_read=False), baudrate=4_000_000, wire_delay=True)
    bus.start()
    try:
        loop = _rtcore.AdmittanceLoop({**config(2, "fast"), "start_timeout_ms": 100.0})
        with pytest.raises(Exception, match="answer"):
            loop.start(simulated_bus=bus)
    finally:
        bus.stop()


def test_fast_needs_protocol_2_and_a_known_choice():
    with pytest.raises(ConfigError, match="Fast Sync Read"):
        _rtcore.AdmittanceLoop(config(1, "fast", protocol=1))
    with pytest.raises(ConfigError, match="bus_read"):
        _rtcore.AdmittanceLoop(config(1, "fastest"))
