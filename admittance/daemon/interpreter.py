"""The daemon's Python interpreter, settled for its sensor reader once the run is open.

Why: the force-sensor reader is a Python thread; a sample it reads waits for the GIL before it
reaches the loop. Under the daemon's load (publishing, recording, allocation, busy CPUs) two
things in CPython make that wait long:
- the GIL switch interval: a waiting thread asks the holder for the GIL only after 5 ms;
- full cyclic collections that walk the whole long-lived heap (zenoh, numpy, the daemon's
  modules) with the GIL held.
Asking after 0.5 ms, and freezing the heap that exists once everything is open (it lives as
long as the process), cuts the reader's long stalls; it does not bring the loop's 250/500 Hz
latency under a period. The measurements: bench/reader_stalls.py, docs/realtime.md.

Process-wide, so only `admittance run` calls it, never a library user's process; a bench that
settles one run of several undoes it with `unsettle`.
"""

from __future__ import annotations

import gc
import sys

SWITCH_INTERVAL_S = 0.0005


def settle_for_the_reader() -> None:
    """Ask for the GIL after 0.5 ms, and leave the heap as it is now out of collections."""
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    gc.collect()  # what the start left behind goes now, not frozen forever
    gc.freeze()


def unsettle(switch_interval_s: float) -> None:
    """Undo :func:`settle_for_the_reader`: the frozen heap collectable again, the interval back."""
    gc.unfreeze()
    sys.setswitchinterval(switch_interval_s)


def report() -> dict[str, float | int]:
    """What the stats tell of it: the switch interval and how many objects are frozen."""
    return {"switch_interval_s": sys.getswitchinterval(), "frozen_objects": gc.get_freeze_count()}
