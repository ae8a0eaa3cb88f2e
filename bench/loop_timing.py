"""Timing of the Rust RT loop against an equivalent pure-Python loop, side by side in one run.

Three loops run the same virtual joints (plant::admittance: implicit damping, stick friction),
build one Protocol 2.0 SyncWrite per cycle for every joint and write it to the same kind of
pseudo-terminal: a MockBus (its servos decode every packet in Rust threads, so the bus side
costs every loop the same).

- ``rust``: ``_rtcore.AdmittanceLoop`` as the daemon runs it: a force sample's push starts the
  cycle (``trigger = "sample"``, one cycle per period, phase lock on; docs/realtime.md);
- ``rust_sched``: the same loop on the fixed schedule (``trigger = "schedule"``): every cycle at
  ``start + k·period``, the loop as it was before the sample trigger;
- ``python``: a thread running the loop in Python on the fixed schedule (``time.sleep`` to each
  absolute deadline, overruns skipped), the SyncWrite bytes (CRC, byte stuffing) built in
  Python and written with pyserial.

Each runs at SCHED_OTHER and at SCHED_FIFO 50 (``_fifo``; the Python thread switches itself with
``os.sched_setscheduler``, so each pair has equal privileges), every thread with 1 ns timer slack.

Two loads, the same for all three loops:

- ``bench``: a sensor thread pushes a sample about every millisecond (``time.sleep(0.001)``,
  so about 0.9-1 kHz and drifting against the loop), and a thread drains the telemetry and
  JSON-encodes the newest rows at 100 Hz;
- ``daemon``: the daemon's own process around the loop. The real supervisor
  (``admittance.daemon.supervisor.Supervisor``) runs the loop: it drains the telemetry at
  100 Hz, records every cycle to CSV (``Recorder``), publishes state and stats over a real Zenoh
  session to a subscriber in the same process; the same sensor thread pushes through the
  supervisor's gate, and the interpreter is settled as ``admittance run`` settles it
  (admittance.daemon.interpreter); a thread allocates 500 small dicts with reference cycles every
  millisecond (allocation and cyclic-GC pressure); and two processes burn a CPU each.
  With ``--sensor rust`` the sensor is a real one's stand-in instead: a separate process writes
  1 kHz OptoForce frames on a pty at absolute deadlines (SCHED_FIFO 60 when allowed), read by the
  daemon's Rust reader (SCHED_FIFO 40 beside the FIFO loops), and each row also shows the
  reader's longest gap, split at its frame counters into the time between the source's writes
  of the frames on either side and how long after its write the frame that ended it was read
  (the DAQ logs each write time by counter), beside the source's own longest write gap; only
  the Rust loops run (the reader pushes into their ring).

Figures, p50/p99/p99.9/max in µs: the wake-up lateness behind the moment the cycle was due
("period error": a deadline, or a sample's push), the force-to-write latency (a sample's
arrival → the end of the first SyncWrite that used it), the cycle's own cost (wake-up → end of
its SyncWrite), and ratios of one run. A last section shows the phase lock at work on a sensor
paced at the loop's own rate. With the daemon load each row also shows the p99 tail: the
cycles at or above the p99 latency, their median wake-up lateness and the rest (the wait for a
sample in the window, the work, the write). Each point runs at least ``--min-cycles`` cycles
(2000), so that a p99 is not the few worst cycles. The machine is shared and noisy: read the
ratios, not the absolutes. ``--help`` lists the options; the default run takes about ten minutes.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import ctypes
import gc
import json
import logging
import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import serial

from admittance import _rtcore
from admittance.drivers.force_reader import ForceSensor
from admittance.logs import ROOT

RATES_HZ = (250, 500, 1000, 2000)
JOINT_COUNTS = (1, 6, 12)
POINT_S = 2.0
# A p99 of a few hundred cycles is the few worst cycles, one VM hiccup apart: each point runs
# long enough for at least this many cycles (3 s at 250 Hz is 750: its p99 is the 8th-worst).
MIN_CYCLES = 2000
FORCE_N = 2.0
INERTIA, DAMPING, COULOMB, LEVER = 0.02, 0.05, 0.01, 0.1
GOAL_ADDRESS, GOAL_SIZE = 116, 4
QUANTILES = (50, 99, 99.9, 100)
LOOPS = ("python", "rust_sched", "rust")
PR_SET_TIMERSLACK = 29  # <linux/prctl.h>


# -- the Python loop --------------------------------------------------------------------------

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


def set_minimal_timer_slack() -> None:
    """The calling thread's timer slack to 1 ns, as the Rust loop thread sets its own."""
    ctypes.CDLL(None, use_errno=True).prctl(PR_SET_TIMERSLACK, ctypes.c_ulong(1), 0, 0, 0)


def percentiles_us(values_ns: list[int]) -> dict:
    if not values_ns:
        return {"p50": math.nan, "p99": math.nan, "p999": math.nan, "max": math.nan}
    p = np.percentile(values_ns, QUANTILES) / 1e3
    return {"p50": float(p[0]), "p99": float(p[1]), "p999": float(p[2]), "max": float(p[3])}


class PythonLoop:
    """The loop in Python, paced like the Rust schedule (absolute deadlines, overruns skipped).

    It offers the part of ``AdmittanceLoop``'s API the supervisor uses (start, stop, force_sink,
    drain_telemetry as the same numpy array, stats, heartbeat...), so both loops run under the
    same supervisor.
    """

    def __init__(self, port: str, rate_hz: float, ids: list[int], fifo: bool):
        self.port, self.period_ns, self.ids, self.fifo = port, int(1e9 / rate_hz), ids, fifo
        self.rate_hz = rate_hz
        self.policy = "SCHED_OTHER"
        self.sample = (0, 0.0)  # (arrival t_ns, force): what the sensor thread hands over
        self.samples = 0
        self.telemetry: collections.deque = collections.deque(maxlen=1 << 16)
        self.costs: list[int] = []
        self.period_errors: list[int] = []
        self.latencies: list[int] = []
        self.overruns = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    # the sink
    def force_sink(self) -> PythonLoop:
        return self

    def push(self, t_ns: int, forces: list[float]) -> bool:
        self.sample = (t_ns, forces[0])
        self.samples += 1
        return True

    # the loop
    def start(self) -> None:
        self._thread.start()

    def stop(self, torque_policy: str = "hold") -> None:
        self._stop.set()
        self._thread.join()

    def _become_fifo(self) -> None:
        if become_fifo(50):
            self.policy = "SCHED_FIFO"

    def _run(self) -> None:
        set_minimal_timer_slack()
        if self.fifo:
            self._become_fifo()
        port = serial.Serial(self.port, 1_000_000, timeout=0)
        h = self.period_ns / 1e9
        state = [(0.0, 0.0)] * len(self.ids)
        used_t = 0
        next_ns = time.monotonic_ns() + self.period_ns
        cycle = 0
        while not self._stop.is_set():
            time.sleep(max(0.0, (next_ns - time.monotonic_ns()) / 1e9))
            wake = time.monotonic_ns()
            self.period_errors.append(wake - next_ns)
            t_ns, force = self.sample
            state = [joint_step(th, om, force * LEVER, h) for th, om in state]
            ticks = [2048 + round(th * 4096 / (2 * math.pi)) for th, _ in state]
            port.write(sync_write_p2(self.ids, ticks))
            end = time.monotonic_ns()
            self.costs.append(end - wake)
            latency = -1
            if t_ns != used_t:
                used_t = t_ns
                latency = end - t_ns
                self.latencies.append(latency)
            self.telemetry.append((cycle, wake, force, state, ticks, wake - next_ns, latency))
            cycle += 1
            next_ns += self.period_ns
            now = time.monotonic_ns()
            if now > next_ns:
                missed = (now - next_ns) // self.period_ns + 1
                self.overruns += missed
                next_ns += missed * self.period_ns
        port.close()

    def drain_telemetry(self) -> np.ndarray:
        rows = []
        while self.telemetry:
            rows.append(self.telemetry.popleft())
        n = len(self.ids)
        out = np.zeros(len(rows) * n, _rtcore.AdmittanceLoop.telemetry_dtype())
        for k, (cycle, wake, force, state, ticks, period_error, latency) in enumerate(rows):
            r = out[k * n:(k + 1) * n]
            r["cycle"], r["t_ns"], r["deadline_ns"], r["id"], r["force"] = cycle, wake, wake - period_error, self.ids, force
            r["torque"], r["period_error_ns"], r["latency_ns"] = force * LEVER, period_error, latency
            r["theta"], r["omega"] = [s[0] for s in state], [s[1] for s in state]
            r["goal_tick"], r["present_tick"] = ticks, -1
        return out

    def stats(self) -> dict:
        return {"cycles": len(self.period_errors), "overruns": self.overruns, "rate_hz": self.rate_hz,
                "period_us": percentiles_us(self.period_errors), "latency_us": percentiles_us(self.latencies),
                "work_us": percentiles_us(self.costs), "bus_errors": 0, "sensor_samples": self.samples,
                "sensor_stale_events": 0, "rt": {"policy": self.policy, "priority": 50 if self.fifo else 0,
                                                 "memory_locked": False}}

    def heartbeat(self) -> int:
        return len(self.period_errors)

    def running(self) -> bool:
        return self._thread.is_alive()

    def warnings(self) -> list[str]:
        return []

    def params(self) -> dict:
        return {}

    def set_params(self, request: dict) -> tuple[bool, str]:
        return False, "the benchmark's Python loop has no live parameters"

    def tare(self, samples: int) -> None:
        pass

    def set_sensor_faults(self, names: list[str]) -> None:
        pass  # the Python loop has no fault marks; the bench's sensor raises none

    def stop_request(self) -> dict | None:
        return None  # nor a fault policy: it never asks to be stopped


# -- the loops under test ---------------------------------------------------------------------

def mock_bus(n_joints: int):
    servos = [{"id": i, "model": "MX-64", "protocol": 2, "params": {"motor_inertia": 0.0147}}
              for i in range(1, n_joints + 1)]
    bus = _rtcore.MockBus(servos=servos, baudrate=1_000_000, wire_delay=False)
    bus.start()
    return bus


def rust_loop(port: str, rate_hz: int, n_joints: int, priority: int, trigger: str, phase_lock: bool = True):
    joints = [{"id": i, "virtual_inertia": INERTIA, "virtual_damping": DAMPING, "virtual_coulomb": COULOMB,
               # The goal range's angles (the default) and the envelope's speed bounds.
               "lever_arm": LEVER, "limits": {"velocity_max": 100.0, "acceleration_max": 1e5}}
              for i in range(1, n_joints + 1)]
    return _rtcore.AdmittanceLoop({"port": port, "rate_hz": rate_hz, "rt_priority": priority,
                                   "lock_memory": False, "sync_read_divisor": 0, "stale_timeout_ms": 1000.0,
                                   "start_timeout_ms": 2000.0,
                                   "trigger": trigger, "phase_lock": phase_lock, "joints": joints})


def make_loop(name: str, port: str, rate_hz: int, n_joints: int):
    fifo = name.endswith("_fifo")
    base = name.removesuffix("_fifo")
    if base == "python":
        return PythonLoop(port, rate_hz, list(range(1, n_joints + 1)), fifo)
    return rust_loop(port, rate_hz, n_joints, 50 if fifo else 0, "schedule" if base == "rust_sched" else "sample")


def summary(stats: dict) -> dict:
    pick = lambda d: [d["p50"], d["p99"], d["p999"], d["max"]]  # noqa: E731
    return {"period": pick(stats["period_us"]), "latency": pick(stats["latency_us"]),
            "cost": pick(stats["work_us"])[:2], "overruns": stats["overruns"], "cycles": stats["cycles"],
            "policy": stats["rt"]["policy"]}


# -- the loads --------------------------------------------------------------------------------

class DriftingSensor(ForceSensor):
    """The daemon's sensor reader (its thread, bias, staleness watch) on a source that yields
    one sample about every millisecond (a relative sleep: it drifts against the loop)."""

    kind = "drifting"

    def _open(self) -> None:
        pass

    def _poll(self) -> None:
        time.sleep(0.001)
        self._emit_all([[FORCE_N, 0.0, 0.0, 0.0, 0.0, 0.0]])

    def _close(self) -> None:
        pass


# A DAQ in its own process: OptoForce frames on a pty at absolute deadlines (its own clock, as a
# real DAQ has; clock_nanosleep(TIMER_ABSTIME), so a late wake-up does not shift the next ones),
# at SCHED_FIFO when allowed: hardware is not delayed by the host's load. Each frame's write time
# (CLOCK_MONOTONIC ns, 0: dropped) goes into a shared log indexed by the frame's 16-bit counter,
# so the bench can tell the source's own gaps from the reader's (WriteLog).
# Its absolute sleep is bench/_rt_sleep.py, whose source goes in front of the script.
PTY_DAQ = (Path(__file__).with_name("_rt_sleep.py").read_text() + r"""
import mmap, os, struct, sys, time, tty
from admittance.drivers.optoforce import encode_sample
rate, priority, counts, log_path = float(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
master, slave = os.openpty()
tty.setraw(slave)
os.set_blocking(master, False)
with open(log_path, "r+b") as f:
    log = mmap.mmap(f.fileno(), 0)
print(os.ttyname(slave), flush=True)
try:
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
except OSError:
    pass
period, t0, k = 1e9 / rate, time.monotonic_ns(), 0
while True:
    sleep_until(t0 + int(k * period))
    try:
        os.write(master, encode_sample(k & 0xFFFF, 0, [counts, 0, 0]))
        written = time.monotonic_ns()
    except BlockingIOError:
        written = 0  # nobody reads: the DAQ drops the frame
    struct.pack_into("<q", log, (k & 0xFFFF) * 8, written)
    k += 1
""")
DAQ_RATE_HZ = 1000
DAQ_PRIORITY = 60
COUNTS_PER_N = 451.89


class PtyDaq:
    """The PTY_DAQ process; ``port`` is the pty a reader opens, ``log`` its write times."""

    def __init__(self, rate_hz: float = DAQ_RATE_HZ) -> None:
        self.log_path = Path(tempfile.mkstemp(prefix="pty-daq-writes-")[1])
        self.log_path.write_bytes(bytes(8 * COUNTER_SPAN))
        self.proc = subprocess.Popen([sys.executable, "-c", PTY_DAQ, str(rate_hz), str(DAQ_PRIORITY),
                                      str(round(FORCE_N * COUNTS_PER_N)), str(self.log_path)],
                                     stdout=subprocess.PIPE, text=True, preexec_fn=die_with_parent)
        self.port = self.proc.stdout.readline().strip()
        self.period_ns = int(1e9 / rate_hz)

    def writes(self) -> np.ndarray:
        """The write time of the last frame with each counter value (0: none or dropped)."""
        return np.fromfile(self.log_path, dtype="<i8")

    def close(self) -> None:
        self.proc.kill()
        self.proc.wait()
        self.log_path.unlink(missing_ok=True)


COUNTER_SPAN = 1 << 16  # the OptoForce frame counter is 16 bits: 65 s of frames at 1 kHz


def source_and_reader(writes: np.ndarray, reader: dict, t0_ns: int, t1_ns: int) -> dict:
    """Whose gap it was. The source's own gaps are the times between its consecutive writes in the
    run [t0, t1]; the reader's longest gap (between two reads that brought samples) is split at its
    frame counters: ``source_ns`` is the time between the writes of the frames on either side (the
    source wrote nothing else), ``reader_late_ns`` how long after its write the frame that ended
    it was read (the pty's hand-over and the reader's wake-up: what the reader side added)."""
    times = np.sort(writes[(writes >= t0_ns) & (writes <= t1_ns)])
    gaps = np.diff(times)
    out = {"source_writes": int(len(times)),
           "source_max_gap_ns": int(gaps.max()) if len(gaps) else 0,
           "source_p999_gap_ns": float(np.percentile(gaps, 99.9)) if len(gaps) else 0.0}
    before, after = writes[reader["max_gap_counter_before"]], writes[reader["max_gap_counter_after"]]
    end = reader["max_gap_end_ns"]
    if reader["max_gap_ns"] and t0_ns - 1_000_000_000 <= before <= after <= end:
        out["gap_source_ns"] = int(after - before)
        out["gap_reader_late_ns"] = int(end - after)
    return out


def rust_reader(port: str, sink, priority: int):
    """The daemon's Rust reader (native_sensor.py) on the pty DAQ."""
    from admittance.drivers.native_sensor import NativeForceReader
    return NativeForceReader.from_config({"kind": "optoforce", "port": port, "counts_per_newton": [COUNTS_PER_N] * 3},
                                         sink, rt_priority=priority)


class BenchLoad:
    """The sensor thread and a JSON "supervisor" thread, as the first version of this bench had."""

    name = "bench"

    def run(self, loop, duration_s: float) -> dict:
        stop = threading.Event()
        sensor = DriftingSensor(loop.force_sink())
        supervisor = threading.Thread(target=self._supervise, args=(loop, stop), daemon=True)
        loop.start()
        sensor.start()
        supervisor.start()
        time.sleep(duration_s)
        stats = loop.stats()
        loop.stop("hold")
        stop.set()
        sensor.stop()
        supervisor.join()
        return stats

    @staticmethod
    def _supervise(loop, stop: threading.Event) -> None:
        while not stop.is_set():
            rows = loop.drain_telemetry()
            if len(rows):
                json.dumps({"state": rows[-12:].tolist(), "n": len(rows)})
            time.sleep(0.01)

    def close(self) -> None:
        pass


def gc_pressure(stop: threading.Event) -> None:
    """500 small dicts with reference cycles every millisecond: only the cyclic GC frees them."""
    while not stop.is_set():
        junk = []
        for i in range(500):
            d = {"i": i, "s": str(i), "l": [i, i, i]}
            d["self"] = d
            junk.append(d)
        del junk
        time.sleep(0.001)


def become_fifo(priority: int) -> bool:
    """The calling thread at SCHED_FIFO ``priority``; False without the privilege."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))  # 0 = this thread
        return True
    except PermissionError:
        return False


def cpu_burners(n: int) -> list[subprocess.Popen]:
    """``n`` processes busy-looping a CPU each, killed with the bench however it dies."""
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"], preexec_fn=die_with_parent)
            for _ in range(n)]


def die_with_parent() -> None:
    """In a burner, before exec: SIGKILL when the bench dies, however it dies (PR_SET_PDEATHSIG)."""
    ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL, 0, 0, 0)


def free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class DaemonLoad:
    """The daemon's supervisor around the loop, GC pressure and two CPU burners (see the docstring)."""

    name = "daemon"
    PREFIX = "bench/loop-timing"

    def __init__(self, sensor: str = "python") -> None:
        import zenoh
        self.sensor = sensor  # python: DriftingSensor (a Python reader thread); rust: PtyDaq + Rust reader
        self.daq = PtyDaq() if sensor == "rust" else None
        self.fifo = False
        self.reader_stats: list[dict] = []

        from admittance.daemon.zenoh_iface import make_config, open_session
        self.workdir = Path(tempfile.mkdtemp(prefix="loop-timing-"))
        self.endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
        self.monitor = open_session(make_config(listen=[self.endpoint]), "for the bench's subscriber")
        self.subscriber = self.monitor.declare_subscriber(f"{self.PREFIX}/**", zenoh.handlers.RingChannel(64))
        self.burners = cpu_burners(2)
        self._gc_stop = threading.Event()
        self._gc = threading.Thread(target=gc_pressure, args=(self._gc_stop,), daemon=True)
        self._gc.start()
        self.runs = 0
        # The supervisor's own lines (a stale sensor under the burners, say) would break up the
        # tables; its errors still show.
        logging.getLogger(ROOT).setLevel(logging.ERROR)

    def config(self, rate_hz: int, n_joints: int):
        from admittance.daemon.config import load_config
        folder = self.workdir / f"run{self.runs}"
        folder.mkdir()
        joints = "".join(f'[[joints]]\nid = {i}\nmodel = "MX-64"\n\n' for i in range(1, n_joints + 1))
        (folder / "daemon.toml").write_text(
            f'[bus]\nport = "{folder}/bus"\n\n{joints}'
            '[sensor]\nkind = "mock"\nlever_arm = 0.1\ntare_samples = 0\n\n'
            f"[loop]\nrate_hz = {rate_hz}\nsync_read_divisor = 0\nlock_memory = false\n\n"
            f'[zenoh]\nprefix = "{self.PREFIX}"\nlisten = ["tcp/127.0.0.1:0"]\nconnect = ["{self.endpoint}"]\n'
            'state_rate_hz = 100\n\n'
            f'[record]\npath = "{folder}/record"\n')
        return load_config(folder / "daemon.toml")

    def run(self, loop, duration_s: float, rate_hz: int, n_joints: int) -> dict:
        from admittance.daemon.interpreter import settle_for_the_reader, unsettle
        from admittance.daemon.notify import Notifier
        from admittance.daemon.supervisor import Backends, RunOptions, Supervisor
        from admittance.daemon.zenoh_iface import DaemonInterface
        self.runs += 1
        cfg = self.config(rate_hz, n_joints)
        readers = []
        tee = TelemetryTee(loop)

        def make_sensor(cfg, port, sink):
            if self.daq is None:
                return DriftingSensor(sink)
            readers.append(rust_reader(self.daq.port, sink, 40 if self.fifo else 0))  # below the loop's 50
            return readers[-1]

        backends = Backends(start_bench=lambda cfg: contextlib.nullcontext((cfg.bus.port, "", lambda: None)),
                            check_servos=lambda cfg, port: [], release_servos=lambda cfg, port: None,
                            make_sensor=make_sensor,
                            make_loop=lambda cfg, port: tee, make_interface=DaemonInterface)
        supervisor = Supervisor(cfg, backends, RunOptions(duration=duration_s, before_loop=settle_for_the_reader),
                                notifier=Notifier(environ={}))
        switch_interval_s = sys.getswitchinterval()
        t0_ns = time.monotonic_ns()
        try:
            supervisor.run()
        finally:  # settled for this run only: the next point, the phase-lock section start as they were
            unsettle(switch_interval_s)
        shutil.rmtree(cfg.record.path, ignore_errors=True)
        stats = dict(supervisor.final_stats)
        stats["tail"] = tee.tail()
        if readers:
            stats["reader"] = readers[-1].stats()
            stats["reader"].update(source_and_reader(self.daq.writes(), stats["reader"], t0_ns, time.monotonic_ns()))
        return stats

    def close(self) -> None:
        if self.daq is not None:
            self.daq.close()
        for p in self.burners:
            p.kill()
            p.wait()
        self._gc_stop.set()
        self._gc.join()
        self.subscriber.undeclare()
        self.monitor.close()
        shutil.rmtree(self.workdir, ignore_errors=True)


class TelemetryTee:
    """The loop as the supervisor sees it, keeping a copy of the rows it drains: the bench's view
    of what the slowest cycles waited on (``tail``)."""

    def __init__(self, loop) -> None:
        self._loop = loop
        self._rows: list[np.ndarray] = []

    def __getattr__(self, name):
        return getattr(self._loop, name)

    def drain_telemetry(self) -> np.ndarray:
        rows = self._loop.drain_telemetry()
        self._rows.append(rows[["cycle", "period_error_ns", "latency_ns"]].copy())
        return rows

    def tail(self) -> dict:
        """The cycles at or above the p99 force→write latency: how many, and the medians of their
        wake-up lateness (the start rule's due time → the thread's wake-up: the scheduler) and of
        the rest (the wait for a sample inside the window, the cycle's own work and write)."""
        if not self._rows:
            return {}
        rows = np.concatenate(self._rows)
        _, first = np.unique(rows["cycle"], return_index=True)  # one row per cycle, not per joint
        rows = rows[first]
        rows = rows[rows["latency_ns"] >= 0]
        if len(rows) == 0:
            return {}
        slow = rows[rows["latency_ns"] >= np.percentile(rows["latency_ns"], 99)]
        late = slow["period_error_ns"].astype(float)
        return {"cycles": int(len(rows)), "slow": int(len(slow)), "wake_late_us": float(np.median(late)) / 1e3,
                "rest_us": float(np.median(slow["latency_ns"] - late)) / 1e3}


# -- one point: every loop, both policies, one load -------------------------------------------

def loops_of(load) -> tuple[str, ...]:
    """The Rust reader pushes into the Rust loop's ring only: no Python loop with it."""
    return LOOPS if getattr(load, "sensor", "python") == "python" else tuple(x for x in LOOPS if x != "python")


def run_point(load, rate: int, n: int, point_s: float) -> dict:
    point_s = max(point_s, MIN_CYCLES / rate)
    bus = mock_bus(n)
    results = {}
    loops = loops_of(load)
    try:
        for name in (*loops, *(f"{loop}_fifo" for loop in loops)):
            loop = make_loop(name, bus.port_path, rate, n)
            load.fifo = name.endswith("_fifo")
            stats = load.run(loop, point_s) if isinstance(load, BenchLoad) else load.run(loop, point_s, rate, n)
            results[name] = summary(stats)
            if "reader" in stats:
                results[name]["reader"] = stats["reader"]
            if stats.get("tail"):
                results[name]["tail"] = stats["tail"]
    finally:
        bus.stop()
    return results


def fmt(values: list[float]) -> str:
    return " ".join(f"{v:7.0f}" for v in values)


def ratio(a: dict, b: dict, key: str, k: int) -> float:
    return a[key][k] / max(b[key][k], 1e-3)


def print_point(rate: int, n: int, results: dict) -> None:
    for name, r in results.items():
        reader = r.get("reader")
        gap = (f" | reader {reader['reader']} {reader['thread_policy']}: longest gap {reader['max_gap_ns'] / 1e3:.0f} µs"
               f"{split_of(reader)}, stale {reader['stale_events']}; source's longest write gap "
               f"{reader.get('source_max_gap_ns', 0) / 1e3:.0f} µs" if reader else "")
        tail = r.get("tail")
        if tail:
            gap += (f" | p99 tail: {tail['slow']} of {tail['cycles']} cycles, median wake-up late "
                    f"{tail['wake_late_us']:.0f} µs + rest {tail['rest_us']:.0f} µs")
        print(f"{rate:5d} {n:3d} {name:<15} {r['policy']:<11} | {fmt(r['period'])} | {fmt(r['latency'])} "
              f"| {fmt(r['cost'])} | {r['overruns']}/{r['cycles']}{gap}", flush=True)


def split_of(reader: dict) -> str:
    if "gap_source_ns" not in reader:
        return " (its frames' writes not in the log)"
    return (f" = source {reader['gap_source_ns'] / 1e3:.0f} µs between its writes, "
            f"then read {reader['gap_reader_late_ns'] / 1e3:.0f} µs after the write")


def print_latency_table(rows: list[tuple]) -> None:
    print("\nForce→write latency, before (rust_sched: the fixed schedule) and after (rust: the sample starts "
          "the cycle), µs:")
    print(f"{'rate':>5} {'jnt':>3} | OTHER p50 before→after  p99 before→after  p99 after/before | "
          f"FIFO p50 before→after  p99 before→after  p99 after/before")
    ratios = {"SCHED_OTHER": [], "SCHED_FIFO": []}
    for rate, n, results in rows:
        cells = []
        for suffix, policy in (("", "SCHED_OTHER"), ("_fifo", "SCHED_FIFO")):
            before, after = results[f"rust_sched{suffix}"]["latency"], results[f"rust{suffix}"]["latency"]
            r = after[1] / max(before[1], 1e-3)
            ratios[policy].append(r)
            cells.append(f"{before[0]:6.0f} → {after[0]:5.0f}   {before[1]:6.0f} → {after[1]:5.0f}   {r:16.2f}")
        print(f"{rate:5d} {n:3d} |      " + " |     ".join(cells))
    for policy, values in ratios.items():
        print(f"median p99 latency after/before at {policy}: {np.median(values):.2f} "
              f"(max {max(values):.2f}; target ≤ 0.25 at every point: {'met' if max(values) <= 0.25 else 'not met'})")


def print_ratio_table(rows: list[tuple]) -> None:
    print("\nPython / Rust (rust: the daemon's loop, sample-triggered), same run, same policy:")
    print(f"{'rate':>5} {'jnt':>3} | OTHER: p99 period err  p99 latency  p50 cycle cost || "
          f"FIFO: p99 period err  p99 latency  p50 cycle cost")
    table = []
    for rate, n, results in rows:
        row = []
        for suffix in ("", "_fifo"):
            py, rs = results[f"python{suffix}"], results[f"rust{suffix}"]
            row += [ratio(py, rs, "period", 1), ratio(py, rs, "latency", 1), ratio(py, rs, "cost", 0)]
        table.append(row)
        print(f"{rate:5d} {n:3d} |        {row[0]:14.1f} {row[1]:12.1f} {row[2]:15.1f} ||        "
              f"{row[3]:14.1f} {row[4]:12.1f} {row[5]:15.1f}")
    med = np.median(table, axis=0)
    for label, k in (("SCHED_OTHER", 0), ("SCHED_FIFO", 3)):
        print(f"median Python/Rust at {label}: p99 period error {med[k]:.1f}x, p99 latency {med[k + 1]:.1f}x, "
              f"cycle cost {med[k + 2]:.1f}x")


def run_load(load, rates, joints, point_s: float) -> None:
    print(f"\n== load: {load.name}, sensor reader: {getattr(load, 'sensor', 'python')}; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
    print(f"{'rate':>5} {'jnt':>3} {'loop':<15} {'policy':<11} | period error µs: p50 p99 p99.9 max "
          f"| latency µs: p50 p99 p99.9 max | cost µs: p50 p99 | overruns/cycles")
    rows = []
    for rate in rates:
        for n in joints:
            results = run_point(load, rate, n, point_s)
            print_point(rate, n, results)
            rows.append((rate, n, results))
    print_latency_table(rows)
    if "python" in loops_of(load):
        print_ratio_table(rows)
    print(f"load average after the {load.name} load: {os.getloadavg()[0]:.1f}")


# -- the phase lock on a sensor paced at the loop's rate --------------------------------------

class PacedSensor:
    """A thread pushing at absolute deadlines ``phase + k·period`` (a sensor with its own clock)."""

    def __init__(self, sink, first_ns: int, period_ns: int) -> None:
        self.sink, self.next_ns, self.period_ns = sink, first_ns, period_ns
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        set_minimal_timer_slack()
        while not self._stop.is_set():
            time.sleep(max(0.0, (self.next_ns - time.monotonic_ns()) / 1e9))
            self.sink.push(time.monotonic_ns(), [FORCE_N, 0.0, 0.0, 0.0, 0.0, 0.0])
            self.next_ns += self.period_ns

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()


def grid_opening(loop) -> int:
    """A window opening of the running loop's grid, from its telemetry: a cycle's deadline (the
    model's time, the grid point itself while no sensor has moved the grid)."""
    deadline = time.monotonic() + 5.0
    rows = loop.drain_telemetry()
    while len(rows) == 0 and time.monotonic() < deadline:
        time.sleep(0.02)
        rows = loop.drain_telemetry()
    return int(rows["deadline_ns"][-1])


def paced_run(port: str, rate: int, trigger: str, phase_lock: bool, phase: float, point_s: float) -> dict:
    """One loop, the sensor at `phase` of a period after each window opening; latency of the last second."""
    period = int(1e9 / rate)
    loop = rust_loop(port, rate, 1, 50, trigger, phase_lock)
    loop.start()
    time.sleep(0.05)  # a few cycles on the schedule (no sensor yet) give the grid
    opening = grid_opening(loop)
    first = opening + int(phase * period) + period * ((time.monotonic_ns() - opening) // period + 2)
    sensor = PacedSensor(loop.force_sink(), first, period)
    time.sleep(point_s)
    loop.drain_telemetry()  # the pull-in: the lock may move the grid by up to half a period
    time.sleep(1.0)
    rows = loop.drain_telemetry()
    sensor.stop()
    stats = loop.stats()
    loop.stop("hold")
    lat = rows["latency_ns"][rows["latency_ns"] >= 0] / 1e3
    starts = stats["trigger"]["starts"]
    return {"p50": float(np.percentile(lat, 50)), "p99": float(np.percentile(lat, 99)), "n": len(lat),
            "starts": starts, "phase_error_us": stats["trigger"]["phase_error_us"]}


def run_phase_lock(rate: int, point_s: float) -> None:
    print(f"\n== the phase lock: a sensor paced at the loop's rate ({rate} Hz), one joint, SCHED_FIFO, "
          f"bench load none; load average {os.getloadavg()[0]:.1f}")
    print("Pushes aimed at a phase of the period after each window opening; latency µs over the last second "
          "(after a pull-in of {:.1f} s):".format(point_s))
    print(f"{'phase':>6} | {'schedule p50/p99':>17} | {'sample, no lock p50/p99':>24} | "
          f"{'sample + lock p50/p99':>22} | lock's last phase error µs")
    bus = mock_bus(1)
    try:
        for phase in (0.3, 0.6, 0.93):
            cells, last = [], None
            for trigger, lock in (("schedule", False), ("sample", False), ("sample", True)):
                r = paced_run(bus.port_path, rate, trigger, lock, phase, point_s)
                cells.append(f"{r['p50']:7.0f} / {r['p99']:6.0f}")
                last = r
            print(f"{phase:6.2f} | {cells[0]:>17} | {cells[1]:>24} | {cells[2]:>22} | {last['phase_error_us']:.0f}",
                  flush=True)
    finally:
        bus.stop()


def main() -> None:
    global MIN_CYCLES
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--load", choices=("bench", "daemon", "both", "none"), default="both",
                        help="which load the loops run under (none: only the phase-lock section; default both)")
    parser.add_argument("--rates", type=int, nargs="+", default=list(RATES_HZ), metavar="HZ",
                        help=f"loop rates, Hz (default {' '.join(map(str, RATES_HZ))})")
    parser.add_argument("--joints", type=int, nargs="+", default=list(JOINT_COUNTS), metavar="N",
                        help=f"joint counts (default {' '.join(map(str, JOINT_COUNTS))})")
    parser.add_argument("--point-s", type=float, default=POINT_S, metavar="S",
                        help=f"seconds per loop and point (default {POINT_S}), at least {MIN_CYCLES} cycles "
                             f"(--min-cycles) so that a p99 is not the few worst cycles")
    parser.add_argument("--min-cycles", type=int, default=MIN_CYCLES, metavar="N",
                        help=f"cycles per loop and point at least (default {MIN_CYCLES}: a p99 over 20 cycles)")
    parser.add_argument("--sensor", choices=("python", "rust"), default="python",
                        help="the daemon load's sensor: python (a Python reader thread pushing ~1 kHz) or rust "
                             "(a 1 kHz DAQ process on a pty read by the Rust reader; Rust loops only)")
    parser.add_argument("--no-phase-lock-section", action="store_true",
                        help="skip the last section (a sensor paced at the loop's rate)")
    args = parser.parse_args()
    MIN_CYCLES = max(1, args.min_cycles)
    print(__doc__.split("\n\n")[0])
    print(f"command: {' '.join(sys.argv)}")
    print(f"uptime: {subprocess.run(['uptime'], capture_output=True, text=True).stdout.strip()}")
    started = time.monotonic()
    daemon_load = lambda: DaemonLoad(args.sensor)  # noqa: E731
    loads = {"bench": [BenchLoad], "daemon": [daemon_load], "both": [BenchLoad, daemon_load], "none": []}[args.load]
    for make in loads:
        load = make()
        try:
            run_load(load, args.rates, args.joints, args.point_s)
        finally:
            load.close()
    if not args.no_phase_lock_section:
        run_phase_lock(1000, max(args.point_s, 1.0))
    gc.collect()
    print(f"\nbench took {time.monotonic() - started:.0f} s; "
          f"uptime after: {subprocess.run(['uptime'], capture_output=True, text=True).stdout.strip()}")


if __name__ == "__main__":
    main()
