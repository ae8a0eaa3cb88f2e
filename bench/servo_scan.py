"""How long a Dynamixel scan takes: ServoBus (the adapter's real latency timer) vs the plain SDK,
and the bring-up wizard's scan (admittance.bringup.scan: every protocol at every usual rate).

dynamixel-sdk waits 2 × 16 ms (an assumed FTDI latency timer) + 2 ms for every missing reply;
ServoBus uses the port's real timer (none on a pty) plus its 20 ms slack. The figures are for
the simulated bus (one MX-64 at ID 1), with a ping on IDs 1..N (N − 1 of them absent), and a
Protocol 2.0 broadcast ping.

Run: .venv/bin/python bench/servo_scan.py [--baud BIT/S ...] (the setup scan's rates, as
``admittance setup --baud``; default: all seven of DEFAULT_BAUDRATES)
"""

from __future__ import annotations

import argparse
import time

from dynamixel_sdk import PacketHandler, PortHandler

from admittance import _rtcore
from admittance.bringup.scan import DEFAULT_BAUDRATES, DEFAULT_PROTOCOLS, scan_bus
from admittance.drivers.dynamixel import ServoBus

IDS = range(1, 21)


def _sdk_scan(port: str) -> tuple[float, int]:
    handler, packet = PortHandler(port), PacketHandler(2.0)
    handler.setBaudRate(1_000_000)
    t0 = time.perf_counter()
    found = sum(1 for i in IDS if packet.ping(handler, i)[1] == 0)
    elapsed = time.perf_counter() - t0
    handler.closePort()
    return elapsed, found


def _servobus_scan(port: str) -> tuple[float, int]:
    with ServoBus(port) as bus:
        t0 = time.perf_counter()
        found = len(bus.scan(IDS))
        return time.perf_counter() - t0, found


def _broadcast(port: str) -> tuple[float, int]:
    with ServoBus(port) as bus:
        t0 = time.perf_counter()
        found = len(bus.scan())
        return time.perf_counter() - t0, found


def _wizard_scan(port: str, baudrates: list[int]) -> tuple[float, int]:
    t0 = time.perf_counter()
    found = scan_bus(port, baudrates=baudrates, protocols=DEFAULT_PROTOCOLS)
    return time.perf_counter() - t0, len(found)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baud", type=int, action="append", metavar="BIT/S", choices=DEFAULT_BAUDRATES,
                        help="a rate for the setup scan (repeatable; default: "
                        f"{', '.join(map(str, DEFAULT_BAUDRATES))})")
    args = parser.parse_args()
    baudrates = args.baud or list(DEFAULT_BAUDRATES)
    bus = _rtcore.MockBus(servos=[{"id": 1, "model": "MX-64", "protocol": 2, "params": {"motor_inertia": 0.0147}}], baudrate=1_000_000, wire_delay=True)
    bus.start()
    try:
        sdk, found_sdk = _sdk_scan(bus.port_path)
        ours, found_ours = _servobus_scan(bus.port_path)
        broadcast, found_bc = _broadcast(bus.port_path)
        wizard, found_wizard = _wizard_scan(bus.port_path, baudrates)
    finally:
        bus.stop()
    n = len(IDS)
    print(f"scan of IDs {IDS.start}..{IDS.stop - 1} on the simulated bus (1 servo present)")
    print(f"  dynamixel-sdk ping per ID          {sdk * 1e3:8.0f} ms  ({sdk / n * 1e3:5.1f} ms/ID, found {found_sdk})")
    print(f"  ServoBus.scan(ids) ping per ID     {ours * 1e3:8.0f} ms  ({ours / n * 1e3:5.1f} ms/ID, found {found_ours})")
    print(f"  ServoBus.scan() broadcast ping     {broadcast * 1e3:8.0f} ms  (whole bus, found {found_bc})")
    rates = f"{len(baudrates)} rate{'s' if len(baudrates) > 1 else ''}"
    print(f"  setup's scan: P2 and P1 (IDs 0-31) at {rates}  {wizard * 1e3:8.0f} ms  "
          f"(found {found_wizard}: a pty answers at every rate, a real bus at one)")
    print(f"  SDK / ServoBus per-ID scan: {sdk / ours:.1f}×")


if __name__ == "__main__":
    main()
