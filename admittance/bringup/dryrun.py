"""A first admittance session with the servos' output limited: the daemon itself, for a few seconds.

The configuration about to be written runs through the real supervisor (the same start checks,
tare, RT loop and stop as ``admittance run``), with three changes for safety: every servo's
output is capped (Protocol 2.0: PWM Limit, an EEPROM item written with torque off; Protocol
1.0: Torque Limit, in RAM), the joint is released at the end (``torque_policy = "torque_off"``),
and Zenoh listens on a free loopback port so that a daemon already running is not disturbed.
The caps are restored afterwards, whatever happened.
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import json
import socket
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from admittance.drivers.dynamixel import ServoBus
from admittance.errors import ConfigError, DeviceError

CAP_ITEMS = {2: "PWM Limit", 1: "Torque Limit"}
CAP_FULL = {2: 885, 1: 1023}


def dry_run_doc(doc: dict[str, Any]) -> dict[str, Any]:
    """The configuration as the dry run uses it."""
    out = copy.deepcopy(doc)
    out["stop"] = {"torque_policy": "torque_off"}
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        out["zenoh"] = {**out.get("zenoh", {}), "listen": [f"tcp/127.0.0.1:{sock.getsockname()[1]}"], "connect": []}
    out.pop("record", None)
    return out


@contextlib.contextmanager
def output_capped(port: str, baudrate: int, protocol: int, ids: list[int], fraction: float,
                  bus_options: dict | None = None) -> Iterator[None]:
    """Cap each servo's output at ``fraction`` of full scale; restore the old caps on exit."""
    if not 0.0 < fraction <= 1.0:
        raise ConfigError(f"--output-limit must be in (0, 1], got {fraction:g}")
    item, full = CAP_ITEMS[protocol], CAP_FULL[protocol]
    with ServoBus(port, baudrate=baudrate, protocol=protocol, **(bus_options or {})) as bus:
        old = {i: _read_cap(bus, i, item, full) for i in ids}
        _write_caps(bus, {i: max(1, round(min(old[i], full) * fraction)) for i in ids}, item)
    try:
        yield
    finally:
        with ServoBus(port, baudrate=baudrate, protocol=protocol, **(bus_options or {})) as bus:
            _write_caps(bus, old, item)


def _read_cap(bus: ServoBus, servo_id: int, item: str, full: int) -> int:
    """The cap to restore afterwards, read twice: a value restored wrong would outlive the session."""
    first, second = bus.read_raw(servo_id, item), bus.read_raw(servo_id, item)
    if first != second or not 0 <= first <= full:
        raise DeviceError(f"servo {servo_id}: {item} read back {first} then {second} (0..{full} expected): "
                          "the bus is unreliable, check the wiring and the host's load")
    return first


def _write_caps(bus: ServoBus, caps: dict[int, int], item: str) -> None:
    for servo_id, value in caps.items():
        bus.set_torque(servo_id, False)  # PWM Limit is EEPROM: locked while torque is on
        bus.write_raw(servo_id, item, value)


def run_dry(doc: dict[str, Any], where: Path, seconds: float, fraction: float, *,
            start_hand: Callable[[], None] = lambda: None, log: Callable[[str], None] = print,
            bus_options: dict | None = None, bench_stats: Callable[[], dict[str, Any]] | None = None) -> dict[str, Any]:
    """Run the session; returns the loop's statistics (the --stats-json object). The daemon's
    lines (its stop line among them) go to ``log``; ``bench_stats``, on the simulated bench, is
    its counters, so that the stop line says the bench is simulated and where errors came from."""
    from admittance.daemon import config
    from admittance.daemon.backends import BenchPorts, real_backends
    from admittance.daemon.supervisor import RunOptions, Supervisor
    from admittance.logs import forwarded

    cfg = config.parse_config(dry_run_doc(doc), where)

    @contextlib.contextmanager
    def ports(_cfg: Any) -> Iterator[BenchPorts]:
        yield BenchPorts(cfg.bus.port, cfg.sensor.port, start_hand, bench_stats)

    backends = dataclasses.replace(real_backends(), start_bench=ports)
    with tempfile.TemporaryDirectory() as tmp:
        stats_path = Path(tmp) / "stats.json"
        options = RunOptions(duration=seconds, stats_json=stats_path)
        with forwarded(log), output_capped(cfg.bus.port, cfg.bus.baudrate, cfg.bus.protocol,
                                           [j.id for j in cfg.joints], fraction, bus_options):
            Supervisor(cfg, backends, options).run()
        return json.loads(stats_path.read_text())
