"""``admittance monitor``: a live terminal view of the daemons' state and timing over Zenoh.

``--prefix`` may name one bench (``bench/arm1``) or a level above several (``bench``): every
bench that publishes ``<bench>/state`` under it gets its own block, in key order, so a lab
with a router sees all its benches from one monitor.

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
    line = (f"joint {joint['id']:>3}  force {joint['force']:+8.3f} N  tau {joint['tau']:+7.3f} N·m  "
            f"theta {math.degrees(joint['theta']):+8.2f}°  omega {joint['omega']:+7.3f} rad/s  "
            f"goal {joint['goal_tick']:>5}  present {present if present is not None else '-':>5}")
    if joint.get("position") is not None:  # newer daemons: the rendering error, measured − model
        line += f"  error {math.degrees(joint['position'] - joint['theta']):+6.2f}°"
    return line


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


def screen_many(prefix: str, benches: dict[str, dict[str, Any]]) -> str:
    """One block per bench (its state and stats), or the single-bench screen when only one is there."""
    if len(benches) <= 1:
        bench, seen = next(iter(benches.items()), (prefix, {}))
        return screen(bench, seen.get("state"), seen.get("stats"))
    blocks = [f"admittance monitor  {prefix}/**  ({len(benches)} benches)"]
    for bench in sorted(benches):
        seen = benches[bench]
        blocks += ["", f"== {bench}"]
        state, stats = seen.get("state"), seen.get("stats")
        blocks += [joint_line(j) for j in state.get("joints", [])] if state else ["waiting for state ..."]
        blocks += stats_lines(stats)[:1] if stats else []
    return "\n".join(blocks)


class View:
    """Keeps the latest state and stats of each bench and writes them to ``out`` (redraw or plain lines)."""

    def __init__(self, prefix: str, out: TextIO, tty: bool) -> None:
        self.prefix = prefix
        self.out = out
        self.tty = tty
        self.benches: dict[str, dict[str, Any]] = {}
        self._next_plain = 0.0
        self.received = 0

    @property
    def state(self) -> dict[str, Any] | None:
        return self.benches.get(self.prefix, {}).get("state")

    def feed(self, kind: str, message: dict[str, Any], bench: str | None = None) -> None:
        self.received += 1
        bench = bench or self.prefix
        self.benches.setdefault(bench, {})[kind] = message
        if kind == "stats" and not self.tty:
            label = self._label(bench)
            self.out.write("\n".join(label + line for line in [stats_lines(message)[0], *rendering_line(message)])
                           + "\n")

    def _label(self, bench: str) -> str:
        return "" if bench == self.prefix else f"{bench}  "

    def render(self, now: float) -> None:
        if self.tty:
            self.out.write(CLEAR + screen_many(self.prefix, self.benches) + "\n")
        elif now >= self._next_plain and any("state" in seen for seen in self.benches.values()):
            self._next_plain = now + PLAIN_PERIOD_S
            for bench in sorted(self.benches):
                for joint in self.benches[bench].get("state", {}).get("joints", []):
                    self.out.write(self._label(bench) + joint_line(joint) + "\n")
        self.out.flush()


def run_monitor(subscription: Any, view: View, duration: float | None) -> int:
    """Feed and render until ``duration`` passes (or forever); DeviceError if nothing ever came."""
    start = time.monotonic()
    try:
        while duration is None or time.monotonic() - start < duration:
            for item in subscription.drain():
                view.feed(*item)
            view.render(time.monotonic())
            time.sleep(REDRAW_PERIOD_S)
    except KeyboardInterrupt:
        pass
    if view.received == 0:
        raise DeviceError(f"no state or stats received on {view.prefix}/* "
                          f"(is `admittance run` up, with the same prefix and endpoint?)")
    return 0
