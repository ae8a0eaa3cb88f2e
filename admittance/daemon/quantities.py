"""One name per quantity of the loop's statistics, shared by the monitor, the stop line, the
systemd status and the docs (docs/daemon.md, docs/realtime.md; a test holds the docs to them).

The stats keys are the contract's and stay as they are; these are what a person reads.
"""

from __future__ import annotations

from typing import Any

NAMES = {
    "period_us": "wake-up lateness",  # how late each cycle woke behind its absolute deadline
    "latency_us": "force-to-write latency",  # a force sample's arrival → the end of the SyncWrite that used it
    "sensor_stale_events": "stale-sensor holds",  # the force went stale, so the joints held
    "rendering_rms": "rendering error",  # RMS of present − model angle over ~1 s
    "bus_errors": "bus errors",
}
# `bus_error_kinds`, in words.
BUS_ERROR_WORDS = {"write": "write failures", "read_timeout": "read timeouts", "read_corrupt": "corrupt replies",
                   "read_servo_error": "servo error replies", "read_io": "read I/O failures"}


def bus_errors_text(stats: dict[str, Any]) -> str:
    """``3 bus errors (2 read timeouts, 1 corrupt replies)``: the kinds only when there are errors."""
    total = stats.get("bus_errors", 0)
    kinds = [f"{n} {BUS_ERROR_WORDS.get(kind, kind)}" for kind, n in (stats.get("bus_error_kinds") or {}).items() if n]
    return f"{total} bus errors" + (f" ({', '.join(kinds)})" if total and kinds else "")
