"""Stalls of the daemon's Python force-sensor reader under the daemon's load, and what the
interpreter's own remedies do to them, side by side in one run.

Why: at 250 and 500 Hz under the daemon's load the loop's force-to-write p99 stays about one
period (bench/loop_timing.py, docs/realtime.md): the reader thread hands samples over late,
and no start rule of the loop can make it deliver. This bench measures the reader alone and
tries what could be done without leaving Python:

- ``default``: CPython as the daemon runs it (a 5 ms GIL switch interval);
- ``switch``: ``sys.setswitchinterval(0.0005)``, so a thread waiting for the GIL asks for it
  after 0.5 ms, not 5;
- ``freeze``: ``gc.collect(); gc.freeze()`` after the daemon's imports, so a full collection no
  longer walks the long-lived heap;
- ``switch+freeze``, and ``switch+freeze+fifo`` (the reader thread at SCHED_FIFO 40, below
  the RT loop's 50; without the privilege it stays SCHED_OTHER, and the table says so).

Each mode runs in its own process (the settings are process-wide): the daemon's imports, the
reader (``ForceSensor``'s own thread on a source that yields a sample after a 1 ms sleep), a
thread allocating 500 small dicts with reference cycles every millisecond, and two processes
burning a CPU each: the daemon load of bench/loop_timing.py without the loop. Figures: the gap
between two consecutive samples handed to the sink, ms (1 ms plus the sleep's overshoot when
nothing stalls).
"""

from __future__ import annotations

import argparse
import gc
import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from loop_timing import DriftingSensor, become_fifo, cpu_burners, gc_pressure  # noqa: E402

from admittance.daemon.interpreter import SWITCH_INTERVAL_S  # noqa: E402

MODES = ("default", "switch", "freeze", "switch+freeze", "switch+freeze+fifo")
READER_FIFO_PRIORITY = 40
STALL_MS = 3.0
WINDOW_S = 5.0
BURNERS = 2


class GapSink:
    """Arrival times of the samples the reader hands over."""

    def __init__(self) -> None:
        self.t_ns: list[int] = []

    def push(self, t_ns: int, forces) -> bool:
        self.t_ns.append(t_ns)
        return True


class FifoDriftingSensor(DriftingSensor):
    """The same reader, its thread switched to SCHED_FIFO on its first poll."""

    policy = "SCHED_OTHER"

    def _poll(self) -> None:
        if self.policy == "SCHED_OTHER":
            self.policy = "SCHED_FIFO" if become_fifo(READER_FIFO_PRIORITY) else "SCHED_OTHER (no privilege)"
        super()._poll()


def measure(mode: str, window_s: float, n_burners: int) -> dict:
    """In this process: apply ``mode``, load it as the daemon would be, time the reader."""
    import zenoh  # noqa: F401 - the daemon's heap: what a full collection walks
    import admittance.daemon.supervisor  # noqa: F401
    if "switch" in mode:
        sys.setswitchinterval(SWITCH_INTERVAL_S)
    if "freeze" in mode:
        gc.collect()
        gc.freeze()
    burners = cpu_burners(n_burners)
    stop = threading.Event()
    garbage = threading.Thread(target=gc_pressure, args=(stop,), daemon=True)
    garbage.start()
    sink = GapSink()
    reader = (FifoDriftingSensor if "fifo" in mode else DriftingSensor)(sink)
    try:
        with reader:
            time.sleep(window_s)
    finally:
        stop.set()
        for p in burners:
            p.kill()
            p.wait()
    gaps = np.diff(np.asarray(sink.t_ns, dtype=np.int64)) / 1e6
    p50, p99, p999 = np.percentile(gaps, [50, 99, 99.9])
    return {"mode": mode, "policy": getattr(reader, "policy", "SCHED_OTHER"), "samples": len(sink.t_ns),
            "p50": p50, "p99": p99, "p999": p999, "max": float(gaps.max()),
            "stalls": int((gaps > STALL_MS).sum())}


def run_mode(mode: str, window_s: float, n_burners: int) -> dict:
    out = subprocess.run([sys.executable, __file__, "--child", mode, "--window", str(window_s),
                          "--burners", str(n_burners)],
                         capture_output=True, text=True, check=False)
    if out.returncode != 0:
        raise SystemExit(f"reader_stalls: the {mode!r} run failed (exit {out.returncode}):\n{out.stderr.strip()}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--window", type=float, default=WINDOW_S, metavar="S",
                        help=f"seconds each mode's reader is timed (default {WINDOW_S:g})")
    parser.add_argument("--burners", type=int, default=BURNERS, metavar="N",
                        help=f"CPU burners beside each mode's reader (default {BURNERS}, as the daemon load)")
    parser.add_argument("--child", choices=MODES, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if not 0 < args.window < 3600:
        parser.error("--window must be between 0 and 3600 s")
    if not 0 <= args.burners <= 64:
        parser.error("--burners must be between 0 and 64")
    if args.child:
        print(json.dumps(measure(args.child, args.window, args.burners)))
        return
    print(__doc__.split("\n\n")[0])
    print(f"command: {' '.join(sys.argv)}")
    print(f"uptime: {subprocess.run(['uptime'], capture_output=True, text=True).stdout.strip()}")
    print(f"\n{'mode':20s} {'reader policy':26s} | gap between samples ms: p50   p99  p99.9    max "
          f"| gaps > {STALL_MS:g} ms | samples")
    print(f"{args.burners} CPU burners beside each reader")
    rows = [run_mode(mode, args.window, args.burners) for mode in MODES]
    for r in rows:
        print(f"{r['mode']:20s} {r['policy']:26s} | {r['p50']:27.2f} {r['p99']:5.2f} {r['p999']:6.2f} "
              f"{r['max']:6.1f} | {r['stalls']:12d} | {r['samples']}")
    base = rows[0]
    for r in rows[1:]:
        print(f"{r['mode']} / default: p99 {r['p99'] / base['p99']:.2f}, p99.9 {r['p999'] / base['p999']:.2f}, "
              f"stalls {r['stalls'] / max(base['stalls'], 1):.2f}")
    print(f"uptime after: {subprocess.run(['uptime'], capture_output=True, text=True).stdout.strip()}")


if __name__ == "__main__":
    main()
