"""The daemon's Python interpreter, settled once the run has started, for its sensor reader.

Why: the force-sensor reader is a Python thread; a sample it reads waits for the GIL before it
reaches the loop. Under the daemon's load (publishing, recording, allocation, busy CPUs) two
things in CPython make that wait long (bench/reader_stalls.py, docs/realtime.md):
- the GIL switch interval: a waiting thread asks the holder for the GIL only after 5 ms;
- full cyclic collections that walk the whole long-lived heap (zenoh, numpy, the daemon's
  modules), tens of milliseconds with the GIL held.
Asking after 0.5 ms and freezing the heap that exists once the run has started (it lives as
long as the process) measured, in two runs, the reader's p99.9 gap 3-4x lower (22-24 -> 6-7 ms),
its longest stall 28-32 -> 8 ms and about half the stalls over 3 ms: a wide margin inside the
sensor's stale timeout (50 ms by default). It does not bring the loop's force-to-write p99 at
250/500 Hz under a period: that needs a reader outside the GIL.

Process-wide, so only `admittance run` calls it, never a library user's process.
"""

from __future__ import annotations

import gc
import sys

SWITCH_INTERVAL_S = 0.0005


def settle_for_the_reader() -> None:
    """Ask for the GIL after 0.5 ms, and leave the started run's heap out of collections."""
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    gc.collect()  # what the start left behind goes now, not frozen forever
    gc.freeze()


def report() -> dict[str, float | int]:
    """What the stats tell of it: the switch interval and how many objects are frozen."""
    return {"switch_interval_s": sys.getswitchinterval(), "frozen_objects": gc.get_freeze_count()}
