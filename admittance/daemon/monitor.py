"""``admittance monitor``: a live terminal view of a daemon's state and timing over Zenoh.

On a terminal it redraws one screen in place with ANSI escapes (no curses: it must work over
ssh and in any terminal, and needs no extra package). When stdout is not a terminal (a pipe,
a log file, a test) it prints plain lines instead, one per joint at most every
``PLAIN_PERIOD_S``, so the output stays greppable.

The view only formats dicts; the subscription comes from :mod:`zenoh_iface`, so the
formatting is unit-tested without a network.
"""

from __future__ import annotations

import math
import time
from typing import Any, TextIO

from admittance.errors import DeviceError

REDRAW_PERIOD_S = 0.1
PLAIN_PERIOD_S = 0.5
CLEAR = "\x1b[H\x1b[2J"


def joint_line(joint: dict[str, Any]) -> str:
    present = joint.get("present_tick")
    return (f"joint {joint['id']:>3}  force {joint['force']:+8.3f} N  tau {joint['tau']:+7.3f} N·m  "
            f"theta {math.degrees(joint['theta']):+8.2f}°  omega {joint['omega']:+7.3f} rad/s  "
            f"goal {joint['goal_tick']:>5}  present {present if present is not None else '-':>5}")


def rendering_line(stats: dict[str, Any]) -> list[str]:
    """The horn's distance from the model, per joint (the daemon's running RMS, last ~1 s)."""
    rms = stats.get("rendering_rms") or {}
    if not rms:
        return []
    joints = "  ".join(f"joint {jid} {1e3 * value:6.2f} mrad" for jid, value in sorted(rms.items()))
    return [f"render  |present − model| RMS  {joints}"]


def stats_lines(stats: dict[str, Any]) -> list[str]:
    rt = stats.get("rt", {})
    period, latency = stats.get("period_us", {}), stats.get("latency_us", {})
    return [
        f"loop   {stats.get('rate_hz', 0):8.1f} Hz  cycles {stats.get('cycles', 0)}  "
        f"overruns {stats.get('overruns', 0)}  bus errors {stats.get('bus_errors', 0)}",
        f"jitter p50 {period.get('p50', 0):7.1f} µs  p99 {period.get('p99', 0):7.1f}  "
        f"p99.9 {period.get('p999', 0):7.1f}  max {period.get('max', 0):7.1f}",
        f"latency p50 {latency.get('p50', 0):6.1f} µs  p99 {latency.get('p99', 0):7.1f}  "
        f"max {latency.get('max', 0):7.1f}",
        f"sensor samples {stats.get('sensor_samples', 0)}  stale events {stats.get('sensor_stale_events', 0)}  "
        f"rt {rt.get('policy', '?')} prio {rt.get('priority', 0)} "
        f"mlock {'yes' if rt.get('memory_locked') else 'no'}",
        *rendering_line(stats),
    ]


def screen(prefix: str, state: dict[str, Any] | None, stats: dict[str, Any] | None) -> str:
    lines = [f"admittance monitor  {prefix}", ""]
    if state is None:
        lines.append(f"waiting for {prefix}/state ...")
    else:
        lines += [joint_line(j) for j in state.get("joints", [])]
    lines.append("")
    lines += stats_lines(stats) if stats else [f"waiting for {prefix}/stats ..."]
    return "\n".join(lines)


class View:
    """Keeps the latest state and stats and writes them to ``out`` (redraw or plain lines)."""

    def __init__(self, prefix: str, out: TextIO, tty: bool) -> None:
        self.prefix = prefix
        self.out = out
        self.tty = tty
        self.state: dict[str, Any] | None = None
        self.stats: dict[str, Any] | None = None
        self._next_plain = 0.0
        self.received = 0

    def feed(self, kind: str, message: dict[str, Any]) -> None:
        self.received += 1
        if kind == "state":
            self.state = message
        else:
            self.stats = message
            if not self.tty:
                self.out.write("\n".join([stats_lines(message)[0], *rendering_line(message)]) + "\n")

    def render(self, now: float) -> None:
        if self.tty:
            self.out.write(CLEAR + screen(self.prefix, self.state, self.stats) + "\n")
        elif self.state is not None and now >= self._next_plain:
            self._next_plain = now + PLAIN_PERIOD_S
            for joint in self.state.get("joints", []):
                self.out.write(joint_line(joint) + "\n")
        self.out.flush()


def run_monitor(subscription: Any, view: View, duration: float | None) -> int:
    """Feed and render until ``duration`` passes (or forever); DeviceError if nothing ever came."""
    start = time.monotonic()
    try:
        while duration is None or time.monotonic() - start < duration:
            for kind, message in subscription.drain():
                view.feed(kind, message)
            view.render(time.monotonic())
            time.sleep(REDRAW_PERIOD_S)
    except KeyboardInterrupt:
        pass
    if view.received == 0:
        raise DeviceError(f"no state or stats received on {view.prefix}/* "
                          f"(is `admittance run` up, with the same prefix and endpoint?)")
    return 0
