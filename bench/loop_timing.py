"""Timing of the Rust RT loop against an equivalent pure-Python loop, side by side in one run.

Both loops run the same virtual joint (plant::admittance: implicit damping, stick friction),
build one Protocol 2.0 SyncWrite per cycle for every joint and write it to the same kind of
pseudo-terminal: a MockBus (its servos decode every packet in Rust threads, so the bus side
costs both loops the same). Both sleep to absolute deadlines and skip missed ones.

- ``rust``: ``_rtcore.AdmittanceLoop`` at SCHED_OTHER (the same scheduling as Python's thread,
  so the ratio compares implementations, not privileges);
- ``rust_fifo``: the same at SCHED_FIFO 50 (what the daemon asks for; falls back if refused);
- ``python``: a thread running the loop in Python, the SyncWrite bytes (CRC, byte stuffing)
  built in Python and written with pyserial, ``time.sleep`` to each absolute deadline;
- ``python_fifo``: the same thread switched to SCHED_FIFO 50 (``os.sched_setscheduler`` on the
  calling thread), so the FIFO pair compares implementations with equal privileges too.
  Both Python variants also set the thread's timer slack to 1 ns (``prctl`` through ctypes),
  as the Rust loop does, so neither sleeps up to 50 µs late by the kernel's default.

Load, identical for all: a sensor thread pushes a force sample every millisecond, and a
supervisor thread drains the telemetry and JSON-encodes the newest state at 100 Hz, as the
daemon does. Figures: the wake-up lateness behind each deadline ("period error"), the
force-to-write latency (a sample's arrival → the end of the first SyncWrite that used it),
p50/p99/p99.9/max in µs, the cycle's own cost (wake-up → end of its SyncWrite, p50/p99) and
the Python/Rust ratios. The cost is the least load-sensitive figure: on a shared machine the
period error at SCHED_OTHER mostly measures the other processes. Each point runs ~1 s; the whole bench
takes about a minute. The machine is shared and noisy: read the ratios, not the absolutes.
"""

from __future__ import annotations

import collections
import ctypes
import json
import math
import os
import threading
import time

import numpy as np
import serial

from admittance import _rtcore

RATES_HZ = (250, 500, 1000, 2000)
JOINT_COUNTS = (1, 6, 12)
POINT_S = 1.0
FORCE_N = 2.0
INERTIA, DAMPING, COULOMB, LEVER = 0.02, 0.05, 0.01, 0.1
GOAL_ADDRESS, GOAL_SIZE = 116, 4
QUANTILES = (50, 99, 99.9, 100)


def crc16_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return table


CRC_TABLE = crc16_table()


def crc16(data: bytes) -> int:
    crc = 0
    for b in data:
        crc = ((crc << 8) ^ CRC_TABLE[((crc >> 8) ^ b) & 0xFF]) & 0xFFFF
    return crc


def sync_write_p2(ids: list[int], ticks: list[int]) -> bytes:
    """SYNC_WRITE of Goal Position in Python: parameters, byte stuffing, length, CRC."""
    params = bytearray(GOAL_ADDRESS.to_bytes(2, "little") + GOAL_SIZE.to_bytes(2, "little"))
    for i, tick in zip(ids, ticks):
        params.append(i)
        params += (tick & 0xFFFFFFFF).to_bytes(4, "little")
    body = bytes([0x83]) + bytes(params).replace(b"\xff\xff\xfd", b"\xff\xff\xfd\xfd")
    packet = b"\xff\xff\xfd\x00\xfe" + (len(body) + 2).to_bytes(2, "little") + body
    return packet + crc16(packet).to_bytes(2, "little")


def joint_step(theta: float, omega: float, tau: float, h: float) -> tuple[float, float]:
    """plant::admittance::step in Python: stick friction, implicit damping."""
    gain = h / INERTIA
    free = omega + gain * tau
    if abs(free) <= gain * COULOMB:
        return theta, 0.0
    omega = (free - math.copysign(gain * COULOMB, free)) / (1.0 + gain * DAMPING)
    return theta + h * omega, omega



PR_SET_TIMERSLACK = 29  # <linux/prctl.h>


def set_minimal_timer_slack() -> None:
    """The calling thread's timer slack to 1 ns, as the Rust loop thread sets its own."""
    ctypes.CDLL(None, use_errno=True).prctl(PR_SET_TIMERSLACK, ctypes.c_ulong(1), 0, 0, 0)

class PythonLoop(threading.Thread):
    """The loop in Python, paced like the Rust one (absolute deadlines, overruns skipped)."""

    def __init__(self, port: str, rate_hz: float, ids: list[int], duration_s: float, fifo: bool):
        super().__init__(daemon=True)
        self.port, self.period_ns, self.ids, self.duration_s = port, int(1e9 / rate_hz), ids, duration_s
        self.fifo = fifo
        self.policy = "SCHED_OTHER"
        self.costs: list[int] = []
        self.sample = (0, 0.0)  # (arrival t_ns, force): what the sensor thread hands over
        self.telemetry: collections.deque = collections.deque(maxlen=1 << 16)
        self.period_errors: list[int] = []
        self.latencies: list[int] = []
        self.overruns = 0

    def push(self, t_ns: int, forces: list[float]) -> bool:
        self.sample = (t_ns, forces[0])
        return True

    def become_fifo(self) -> None:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(50))  # 0 = this thread
            self.policy = "SCHED_FIFO"
        except PermissionError:
            pass

    def run(self) -> None:
        set_minimal_timer_slack()
        if self.fifo:
            self.become_fifo()
        port = serial.Serial(self.port, 1_000_000, timeout=0)
        h = self.period_ns / 1e9
        state = [(0.0, 0.0)] * len(self.ids)
        used_t = 0
        next_ns = time.monotonic_ns() + self.period_ns
        end_ns = next_ns + int(self.duration_s * 1e9)
        while next_ns < end_ns:
            time.sleep(max(0.0, (next_ns - time.monotonic_ns()) / 1e9))
            wake = time.monotonic_ns()
            self.period_errors.append(wake - next_ns)
            t_ns, force = self.sample
            state = [joint_step(th, om, force * LEVER, h) for th, om in state]
            ticks = [2048 + round(th * 4096 / (2 * math.pi)) for th, _ in state]
            port.write(sync_write_p2(self.ids, ticks))
            self.costs.append(time.monotonic_ns() - wake)
            if t_ns != used_t:
                used_t = t_ns
                self.latencies.append(time.monotonic_ns() - t_ns)
            self.telemetry.append((wake, force, state, ticks))
            next_ns += self.period_ns
            now = time.monotonic_ns()
            if now > next_ns:
                missed = (now - next_ns) // self.period_ns + 1
                self.overruns += missed
                next_ns += missed * self.period_ns
        port.close()

    def drain(self) -> list:
        out = []
        while self.telemetry:
            out.append(self.telemetry.popleft())
        return out


def sensor_thread(sink, stop: threading.Event) -> threading.Thread:
    def run():
        while not stop.is_set():
            sink.push(time.monotonic_ns(), [FORCE_N, 0.0, 0.0, 0.0, 0.0, 0.0])
            time.sleep(0.001)
    return threading.Thread(target=run, daemon=True)


def supervisor_thread(drain, stop: threading.Event) -> threading.Thread:
    """Publishes the newest state as JSON at 100 Hz, like the daemon's main loop."""
    def run():
        while not stop.is_set():
            rows = drain()
            if len(rows):
                tail = rows[-12:]  # a numpy structured array (Rust) or a list of tuples (Python)
                json.dumps({"state": tail.tolist() if hasattr(tail, "tolist") else tail, "n": len(rows)})
            time.sleep(0.01)
    return threading.Thread(target=run, daemon=True)


def under_load(sink, drain, body) -> None:
    stop = threading.Event()
    threads = [sensor_thread(sink, stop), supervisor_thread(drain, stop)]
    for t in threads:
        t.start()
    try:
        body()
    finally:
        stop.set()
        for t in threads:
            t.join()


def mock_bus(n_joints: int):
    servos = [{"id": i, "model": "MX-64", "protocol": 2, "params": {"motor_inertia": 0.0147}}
              for i in range(1, n_joints + 1)]
    bus = _rtcore.MockBus(servos=servos, baudrate=1_000_000, wire_delay=False)
    bus.start()
    return bus


def run_rust(port: str, rate_hz: int, n_joints: int, priority: int) -> dict:
    joints = [{"id": i, "virtual_inertia": INERTIA, "virtual_damping": DAMPING, "virtual_coulomb": COULOMB,
               "lever_arm": LEVER, "limits": {"position_min": -1e3, "position_max": 1e3,
                                              "velocity_max": 1e3, "acceleration_max": 1e6}}
              for i in range(1, n_joints + 1)]
    loop = _rtcore.AdmittanceLoop({"port": port, "rate_hz": rate_hz, "rt_priority": priority,
                                   "lock_memory": False, "sync_read_divisor": 0,
                                   "stale_timeout_ms": 1000.0, "joints": joints})
    loop.start()
    under_load(loop.force_sink(), loop.drain_telemetry, lambda: time.sleep(POINT_S))
    stats = loop.stats()
    loop.stop("hold")
    pick = lambda d: [d["p50"], d["p99"], d["p999"], d["max"]]  # noqa: E731
    return {"period": pick(stats["period_us"]), "latency": pick(stats["latency_us"]),
            "cost": pick(stats["work_us"])[:2], "overruns": stats["overruns"], "cycles": stats["cycles"],
            "policy": stats["rt"]["policy"]}


def run_python(port: str, rate_hz: int, n_joints: int, fifo: bool) -> dict:
    loop = PythonLoop(port, rate_hz, list(range(1, n_joints + 1)), POINT_S, fifo)

    def body():
        loop.start()
        loop.join()

    under_load(loop, loop.drain, body)
    pct = lambda xs: [float(v) / 1e3 for v in np.percentile(xs, QUANTILES)] if xs else [math.nan] * 4  # noqa: E731
    return {"period": pct(loop.period_errors), "latency": pct(loop.latencies), "cost": pct(loop.costs)[:2],
            "overruns": loop.overruns, "cycles": len(loop.period_errors), "policy": loop.policy}


def fmt(values: list[float]) -> str:
    return " ".join(f"{v:7.0f}" for v in values)


def ratio(py: dict, rs: dict, key: str, k: int) -> float:
    return py[key][k] / max(rs[key][k], 1e-3)


def run_point(rate: int, n: int) -> dict:
    bus = mock_bus(n)
    try:
        return {"rust": run_rust(bus.port_path, rate, n, 0),
                "python": run_python(bus.port_path, rate, n, fifo=False),
                "rust_fifo": run_rust(bus.port_path, rate, n, 50),
                "python_fifo": run_python(bus.port_path, rate, n, fifo=True)}
    finally:
        bus.stop()


def print_ratios(ratios: list[tuple]) -> None:
    print("\nPython / Rust, same run, same policy (SCHED_OTHER pair | SCHED_FIFO pair):")
    print(f"{'rate':>5} {'jnt':>3} | p99 period err | p99 latency | p50 cycle cost || "
          f"p99 period err | p99 latency | p50 cycle cost")
    widths = (14, 11, 14) * 2
    for rate, n, other, fifo in ratios:
        print(f"{rate:5d} {n:3d} | " + " | ".join(f"{v:{w}.1f}" for v, w in zip(other + fifo, widths)))
    for label, col in (("SCHED_OTHER", 2), ("SCHED_FIFO", 3)):
        med = np.median([[r[col][k] for k in range(3)] for r in ratios], axis=0)
        print(f"median Python/Rust at {label}: p99 period error {med[0]:.1f}x, p99 latency {med[1]:.1f}x, "
              f"cycle cost {med[2]:.1f}x")


def main() -> None:
    print(__doc__.split("\n\n")[0])
    print(f"load average before: {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
    print(f"\n{'rate':>5} {'jnt':>3} {'loop':<11} {'policy':<11} | period error µs: p50 p99 p99.9 max "
          f"| latency µs: p50 p99 p99.9 max | cost µs: p50 p99 | overruns/cycles")
    ratios = []
    started = time.monotonic()
    for rate in RATES_HZ:
        for n in JOINT_COUNTS:
            results = run_point(rate, n)
            for name, r in results.items():
                print(f"{rate:5d} {n:3d} {name:<11} {r['policy']:<11} | {fmt(r['period'])} | {fmt(r['latency'])} "
                      f"| {fmt(r['cost'])} | {r['overruns']}/{r['cycles']}")
            pair = lambda py, rs: [ratio(results[py], results[rs], "period", 1),  # noqa: E731
                                   ratio(results[py], results[rs], "latency", 1),
                                   ratio(results[py], results[rs], "cost", 0)]
            ratios.append((rate, n, pair("python", "rust"), pair("python_fifo", "rust_fifo")))
    print_ratios(ratios)
    print(f"bench took {time.monotonic() - started:.0f} s; load average after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
