"""Where the wire's limit is: the loop's bus time per cycle, Sync Read against Fast Sync Read.

For 1, 6 and 12 servos at 1, 3 and 4 Mbps, on the simulated bus (rtcore/dxlsim, in-process link:
replies readable only when their last byte would have arrived at the baud rate, after the
Return Delay Time) it prints
- the wire's floor per cycle, from the codec's own packet lengths: SyncWrite of Goal Position
  (4 bytes each), then the read's instruction and its replies (Sync Read: one 15-byte status per
  servo, each after the servo's Return Delay Time; Fast Sync Read: one 8 + 8·N-byte reply after
  one Return Delay Time), at 10 bits a byte;
- the measured bus time per cycle (median and p99 of `--cycles` cycles of the loop's own
  JointBus: write, then read until the last byte is in; `MockBus.time_bus_cycles`), its ratio
  to the floor, and Fast Sync Read's gain over Sync Read (sync median / fast median);
- the highest loop rate (of a ladder) at which the real loop (`AdmittanceLoop` on the
  simulated bus, fixed schedule, a read every cycle, SCHED_FIFO where allowed) counts 0 read
  timeouts in `--point-s` seconds, for each read, with how many of the rates tried were clean
  (only rates whose read deadline, 0.9 of a period, the floor leaves room for are tried).

The Return Delay Time is the daemon's (0: `admittance.drivers.dynamixel` sets it) and the
factory's (250 = 500 µs); `--rdt` picks. Everything runs on this host: the measured times carry
its wake-up latency, which a loaded machine lengthens (the load is printed).

Run: nice .venv/bin/python bench/wire_limit.py
"""

from __future__ import annotations

import argparse
import statistics
import time

from admittance import _rtcore

GOAL, PRESENT, SIZE = 116, 132, 4
MX64 = {"motor_inertia": 0.0147, "damping": 0.035, "coulomb": 0.084}
RT_PRIORITY = 80  # SCHED_FIFO where allowed (the daemon's own request); the stats say what it got
SIM_PRIORITY = 70
POLICIES: set[str] = set()  # what the loop's thread got, printed at the end
RATES = (250, 500, 1000, 1500, 2000, 3000, 4000, 5000, 6000, 8000)


def floor_us(n: int, baud: int, rdt: int, read: str) -> float:
    """The wire's own time for one cycle: bytes at 10 bits each plus the Return Delay Time(s)."""
    ids = list(range(1, n + 1))
    write = len(_rtcore.encode_sync_write(GOAL, SIZE, [(i, bytes(SIZE)) for i in ids]))
    status = len(_rtcore.encode_status(1, 0, bytes(SIZE)))
    if read == "fast":
        wire_bytes = write + len(_rtcore.encode_fast_sync_read(PRESENT, SIZE, ids)) + 8 + n * (4 + SIZE)
        delays = 1
    else:
        wire_bytes = write + len(_rtcore.encode_sync_read(PRESENT, SIZE, ids)) + n * status
        delays = n
    return wire_bytes * 10 / baud * 1e6 + delays * 2 * rdt


def mock_bus(n: int, baud: int, rdt: int) -> _rtcore.MockBus:
    servos = [{"id": i, "model": "MX-64", "protocol": 2, "params": dict(MX64), "registers": {"Return Delay Time": rdt}}
              for i in range(1, n + 1)]
    # The simulation's thread at SCHED_FIFO too (below the loop's): the loop takes its lock to
    # answer a packet, and a SCHED_OTHER holder preempted by the load would be measured as wire.
    return _rtcore.MockBus(servos=servos, baudrate=baud, wire_delay=True, rt_priority=SIM_PRIORITY)


def bus_time(bus: _rtcore.MockBus, n: int, read: str, cycles: int) -> tuple[float, float, int]:
    """(median µs, p99 µs, failed reads) of `cycles` SyncWrite + read cycles."""
    ns, failed = bus.time_bus_cycles(list(range(1, n + 1)), read, cycles)
    us = sorted(x / 1e3 for x in ns)
    return statistics.median(us), us[min(len(us) - 1, int(0.99 * len(us)))], failed


def read_timeouts(bus: _rtcore.MockBus, n: int, read: str, rate: float, seconds: float) -> tuple[int, int]:
    """(read timeouts, cycles) of the loop at `rate` on the simulated bus for `seconds`."""
    joints = [{"id": i, "model": "MX-64", "virtual_inertia": 0.02, "virtual_damping": 0.05, "virtual_coulomb": 0.0,
               "axis": "x", "lever_arm": 0.1} for i in range(1, n + 1)]
    config = {"port": "in-process", "rate_hz": rate, "rt_priority": RT_PRIORITY, "lock_memory": False, "trigger": "schedule",
              "sync_read_divisor": 1, "stale_timeout_ms": 1e4, "bus_read": read, "joints": joints,
              "start_timeout_ms": 2000.0}
    loop = _rtcore.AdmittanceLoop(config)
    loop.start(simulated_bus=bus)
    try:
        time.sleep(seconds)
        stats = loop.stats()
    finally:
        loop.stop("hold")
    POLICIES.add(stats["rt"]["policy"])
    assert stats["bus"]["read"] == ("fast_sync_read" if read == "fast" else "sync_read"), stats["bus"]
    return stats["bus_error_kinds"].get("read_timeout", 0), stats["cycles"]


def highest_clean_rate(bus: _rtcore.MockBus, n: int, read: str, rates: list[float], seconds: float,
                       floor: float) -> str:
    """The highest rate of the ladder with 0 read timeouts, of the rates whose read deadline
    (0.9 of the period after the cycle's start) the wire's floor leaves room for (the others
    cannot pass), and how many of those were clean: "2000 (4/5)"."""
    possible = [r for r in rates if floor < 0.9e6 / r]
    clean = [r for r in possible if read_timeouts(bus, n, read, r, seconds)[0] == 0]
    return f"{max(clean):g} ({len(clean)}/{len(possible)})" if clean else f"none (0/{len(possible)})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--servos", type=int, nargs="+", default=[1, 6, 12])
    ap.add_argument("--bauds", type=int, nargs="+", default=[1_000_000, 3_000_000, 4_000_000])
    ap.add_argument("--rdt", type=int, nargs="+", default=[0, 250], help="Return Delay Time (2 µs units)")
    ap.add_argument("--cycles", type=int, default=2000)
    ap.add_argument("--rates", type=float, nargs="*", default=list(RATES),
                    help="loop rates to try (Hz), ascending; none: skip the rate search")
    ap.add_argument("--point-s", type=float, default=1.0, help="seconds the loop runs at each rate")
    args = ap.parse_args()
    with open("/proc/loadavg") as f:
        print(f"load before: {f.read().split()[:3]}")
    print(f"loop: SCHED_FIFO priority {RT_PRIORITY} if allowed (the simulated bus's thread {SIM_PRIORITY}), "
          f"{args.point_s:g} s per rate; "
          f"bus time: {args.cycles} cycles per row and read")
    print("| RDT µs | servos | Mbps | floor sync µs | sync median (p99) µs | ×floor | floor fast µs "
          "| fast median (p99) µs | ×floor | sync/fast | max Hz sync | max Hz fast |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for rdt in args.rdt:
        for n in args.servos:
            for baud in args.bauds:
                bus = mock_bus(n, baud, rdt)
                bus.start()
                try:
                    row = {}
                    for read in ("sync", "fast"):
                        floor = floor_us(n, baud, rdt, read)
                        median, p99, failed = bus_time(bus, n, read, args.cycles)
                        rate = highest_clean_rate(bus, n, read, args.rates, args.point_s, floor) if args.rates else "-"
                        row[read] = (floor, median, p99, failed, rate)
                finally:
                    bus.stop()
                cells = []
                for read in ("sync", "fast"):
                    floor, median, p99, failed, _ = row[read]
                    fails = f", {failed} failed" if failed else ""
                    cells.append(f"{floor:.0f} | {median:.0f} ({p99:.0f}{fails}) | {median / floor:.2f}")
                gain = row["sync"][1] / row["fast"][1]
                print(f"| {2 * rdt} | {n} | {baud / 1e6:g} | {cells[0]} | {cells[1]} | {gain:.2f} "
                      f"| {row['sync'][4]} | {row['fast'][4]} |", flush=True)
    with open("/proc/loadavg") as f:
        print(f"load after: {f.read().split()[:3]}; the loop's scheduling: {', '.join(sorted(POLICIES)) or '-'}")


if __name__ == "__main__":
    main()
