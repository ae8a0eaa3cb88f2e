"""Whose is the sensor reader's gap: the source's, the reader thread's, or the pty's hand-over?

The daemon reads its OptoForce DAQ through a tty (a USB serial adapter; on the benches a pty).
A tty does not hand a writer's bytes straight to the reader: the bytes go into a flip buffer,
and a kernel worker (a SCHED_OTHER `kworker` of the unbound workqueue) moves them to the
reader's side and wakes it. A reader at SCHED_FIFO can still wait for that worker, which queues
behind every busy SCHED_OTHER process (the CPU burners of issue 18's targets). A pipe hands
bytes over in the writer's own system call: the same source and reader on a pipe show what the
pty's hand-over adds.

One run per transport, taking turns, with ``--burners`` busy-looping processes beside them:
a writer process at SCHED_FIFO 60 (absolute deadlines, ``clock_nanosleep(TIMER_ABSTIME)``)
sends its write time (CLOCK_MONOTONIC ns, 8 bytes) every ``1/rate`` s; the reader at SCHED_FIFO
40 (the daemon's reader is below its loop, the DAQ is hardware) waits in ``poll`` and reads all
available bytes, as the Rust reader does, and reads its own ``/proc/thread-self/schedstat`` at
each wake-up. Per run:

- latency: each frame's read time minus its write time (p50, p99, p99.9, max, µs);
- the reader's longest gap between two reads that brought frames, the writer's longest gap
  between two writes (the source's own);
- for the frames at or above the p99 latency (median): the reader's run-queue wait since its
  previous read (woken, but not yet on a CPU: the reader thread's share) and the rest (the
  bytes were not yet readable: the transport's hand-over).

The machine is shared: read the two transports against each other within one run.
"""

from __future__ import annotations

import argparse
import os
import select
import struct
import sys
import time
import tty
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _rt_sleep import sleep_until  # noqa: E402
from loop_timing import become_fifo as fifo, cpu_burners  # noqa: E402

WRITER_PRIORITY, READER_PRIORITY = 60, 40
FRAME = struct.Struct("<q")


def writer(fd: int, rate_hz: float, frames: int) -> None:
    """The source: one frame per period at absolute deadlines; exits after ``frames``."""
    fifo(WRITER_PRIORITY)
    period, t0 = 1e9 / rate_hz, time.monotonic_ns() + 50_000_000
    for k in range(frames):
        sleep_until(t0 + int(k * period))
        os.write(fd, FRAME.pack(time.monotonic_ns()))
    os._exit(0)


def run_queue_ns(fd: int) -> int:
    """This thread's total run-queue wait so far (schedstat's second field)."""
    return int(os.pread(fd, 128, 0).split()[1])


def reader(fd: int, seconds: float) -> dict:
    """Reads frames until the writer is done; per read: its time, the frames' write times, the
    run-queue wait since the previous read."""
    was = os.sched_getscheduler(0), os.sched_getparam(0)
    fifo_ok = fifo(READER_PRIORITY)
    stat = os.open("/proc/thread-self/schedstat", os.O_RDONLY)
    poller = select.poll()
    poller.register(fd, select.POLLIN)
    pending, reads, writes, waits = b"", [], [], []
    rq = run_queue_ns(stat)
    end = time.monotonic() + seconds + 1.0
    try:
        while time.monotonic() < end:
            if not poller.poll(100):
                continue
            data = os.read(fd, 65536)
            t = time.monotonic_ns()
            now_rq = run_queue_ns(stat)
            pending += data
            n = len(pending) // FRAME.size
            if n:
                writes.append([FRAME.unpack_from(pending, i * FRAME.size)[0] for i in range(n)])
                reads.append(t)
                waits.append(now_rq - rq)
                pending = pending[n * FRAME.size:]
            rq = now_rq
    finally:
        os.close(stat)
        os.sched_setscheduler(0, was[0], was[1])
    return {"reads": reads, "writes": writes, "waits": waits, "fifo": fifo_ok}


def open_transport(kind: str) -> tuple[int, int]:
    """(write end, read end) of a pty in raw mode, or of a pipe."""
    if kind == "pipe":
        r, w = os.pipe()
        return w, r
    master, slave = os.openpty()
    tty.setraw(slave)
    return master, slave


def one_run(kind: str, rate_hz: float, seconds: float) -> dict:
    w, r = open_transport(kind)
    os.set_blocking(r, False)
    frames = int(seconds * rate_hz)
    pid = os.fork()
    if pid == 0:
        os.close(r)
        writer(w, rate_hz, frames)
    try:
        got = reader(r, seconds)
    finally:
        os.waitpid(pid, 0)
        os.close(w)
        os.close(r)
    return summarize(got)


def summarize(got: dict) -> dict:
    reads = np.array(got["reads"], dtype=np.int64)
    first = np.array([w[0] for w in got["writes"]], dtype=np.int64)
    every = np.concatenate([np.array(w, dtype=np.int64) for w in got["writes"]])
    per_frame = np.concatenate([t - np.array(w, dtype=np.int64) for t, w in zip(got["reads"], got["writes"])])
    late = reads - first  # the oldest frame of each read: how long the reader side kept it
    waits = np.array(got["waits"], dtype=np.int64)
    slow = late >= np.percentile(late, 99)
    q = lambda v, p: float(np.percentile(v, p)) / 1e3  # noqa: E731
    return {"frames": int(len(every)), "fifo": got["fifo"],
            "latency": [q(per_frame, 50), q(per_frame, 99), q(per_frame, 99.9), float(per_frame.max()) / 1e3],
            "reader_gap": float(np.diff(reads).max()) / 1e3, "writer_gap": float(np.diff(every).max()) / 1e3,
            "slow_reads": int(slow.sum()), "slow_rq": float(np.median(waits[slow])) / 1e3,
            "slow_rest": float(np.median(late[slow] - waits[slow])) / 1e3}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="seconds per run (default 20)")
    parser.add_argument("--rate", type=float, default=1000.0, help="frames per second (default 1000)")
    parser.add_argument("--runs", type=int, default=2, help="runs per transport, taking turns (default 2)")
    parser.add_argument("--burners", type=int, default=2, help="CPU burners beside them (default 2)")
    args = parser.parse_args()
    print(f"{args.rate:g} frames/s, {args.seconds:g} s a run, {args.burners} CPU burners, {os.cpu_count()} CPUs; "
          f"writer SCHED_FIFO {WRITER_PRIORITY}, reader SCHED_FIFO {READER_PRIORITY}")
    print("| transport | load before (1/5/15 min) | frames | latency µs p50 / p99 / p99.9 / max | reader's longest gap µs "
          "| writer's longest gap µs | reads ≥ p99: reader's run-queue wait µs + rest (bytes not yet readable) µs |")
    print("|---|---|---|---|---|---|---|")
    burners = cpu_burners(args.burners)
    rows: dict[str, list[dict]] = {"pty": [], "pipe": []}
    try:
        for _ in range(args.runs):
            for kind in rows:
                load = " ".join(Path("/proc/loadavg").read_text().split()[:3])
                r = one_run(kind, args.rate, args.seconds)
                rows[kind].append(r)
                lat = " / ".join(f"{v:.0f}" for v in r["latency"])
                policy = "" if r["fifo"] else " (reader not FIFO)"
                print(f"| {kind}{policy} | {load} | {r['frames']} | {lat} | {r['reader_gap']:.0f} | {r['writer_gap']:.0f} "
                      f"| {r['slow_reads']} reads: {r['slow_rq']:.0f} + {r['slow_rest']:.0f} |", flush=True)
    finally:
        for p in burners:
            p.kill()
            p.wait()
    p99 = {k: np.median([r["latency"][1] for r in v]) for k, v in rows.items()}
    print(f"median p99 latency: pty {p99['pty']:.0f} µs, pipe {p99['pipe']:.0f} µs "
          f"(pty / pipe {p99['pty'] / max(p99['pipe'], 1e-3):.1f}x)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
