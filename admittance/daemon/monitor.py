"""``admittance monitor``: a live terminal view of the daemons' state, timing and parameters over Zenoh.

``--prefix`` may name one bench (``bench/arm1``) or a level above several (``bench``): every
bench that publishes ``<bench>/state`` under it gets its own block, in key order, so a lab
with a router sees all its benches from one monitor.

What it shows must be true *now*, not when the last message came:

- a bench whose liveliness token (``<bench>/alive``) was withdrawn is marked **gone**, with how
  long ago; a bench whose state stopped arriving (``STATE_STALE_S``) is marked **stale**, and so
  are its timing figures when the stats stopped (``STATS_STALE_S``). Values shown then are the
  last ones received, and say so;
- SI units everywhere (rad, rad/s; the rendering error in mrad), or with ``--degrees`` every
  angle and angular rate in degrees (parameters keep the units ``set`` takes);
- one name per quantity, the same as in the docs, the stats and the stop line: *wake-up
  lateness* (``period_us``), *force-to-write latency* (``latency_us``), *stale-sensor holds*
  (``sensor_stale_events``), *rendering error* (``rendering_rms``);
- the loop's mode and faults (from the state and stats), and the live virtual parameters
  (``<prefix>/**/params`` is read every ``PARAMS_PERIOD_S``: a read, which never sets).

On a terminal it redraws one screen in place with ANSI escapes (no curses: it must work over
ssh and in any terminal, and needs no extra package). When stdout is not a terminal (a pipe,
a log file, a test) it prints plain lines instead: each bench's joints at most every
``PLAIN_PERIOD_S`` when new state came, a loop line per stats message, and one line whenever a
bench goes, comes back, goes stale or its parameters change, so the output stays greppable.

The view only formats dicts fed to it (``View.feed``) against a clock it is given; the
subscriptions come from :mod:`zenoh_iface`, so all of this is unit-tested without a network.
"""

from __future__ import annotations

import math
import textwrap
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TextIO

from admittance.daemon.quantities import NAMES, bus_errors_text
from admittance.errors import DeviceError

REDRAW_PERIOD_S = 0.1
PLAIN_PERIOD_S = 0.5
PARAMS_PERIOD_S = 2.0
STATE_STALE_S = 1.0  # the state comes at ≥ 50 Hz: a second without one is a stalled daemon or link
STATS_STALE_S = 3.0  # the stats come about once a second
CLEAR = "\x1b[H\x1b[2J"
WIDTH = 80  # every line fits an 80-column terminal (a laptop's ssh window beside the bench)
AT_LIMIT_RAD = 0.02  # a joint this close to a position limit is flagged AT MIN / AT MAX
# The parameters the monitor shows (the loop's gains and the compensation's weight); `get` has all.
SHOWN_PARAMS = ("virtual_inertia", "virtual_damping", "virtual_coulomb", "servo_compensation", "passivity_guard")


@dataclass(frozen=True)
class Units:
    """SI (rad) or degrees for every angle and angular rate the view shows."""

    degrees: bool = False

    def angle(self, rad: float) -> str:
        return f"{number(math.degrees(rad), 8, 2)}°" if self.degrees else f"{number(rad, 7, 4)} rad"

    def rate(self, rad_s: float) -> str:
        return f"{number(math.degrees(rad_s), 8, 2)} °/s" if self.degrees else f"{number(rad_s, 7, 3)} rad/s"

    def small_angle(self, rad: float) -> str:
        return f"{math.degrees(rad):.3f}°" if self.degrees else f"{1e3 * rad:.2f} mrad"


def number(value: float, width: int, decimals: int) -> str:
    """``value`` signed in exactly ``width`` characters: fixed-point while it fits, else fewer digits,
    so a wild value never widens a line past the screen (nor wraps it mid-number)."""
    if not math.isfinite(value):
        return f"{value!s:>{width}}"
    text = f"{value:+{width}.{decimals}f}"
    return text if len(text) <= width else f"{value:+{width}.{max(width - 7, 1)}g}"


def at_limit(joint: dict[str, Any], params: dict[str, Any] | None) -> str:
    """``AT MIN``/``AT MAX`` when the joint's angle is within ``AT_LIMIT_RAD`` of a position limit
    (the running loop's, from its ``params``), else ""."""
    if not params:
        return ""
    angle = joint.get("position") if joint.get("position") is not None else joint.get("theta")
    low, high = params.get(f"{joint['id']}.position_min"), params.get(f"{joint['id']}.position_max")
    if not isinstance(angle, (int, float)):
        return ""
    if isinstance(low, (int, float)) and angle <= low + AT_LIMIT_RAD:
        return "AT MIN"
    if isinstance(high, (int, float)) and angle >= high - AT_LIMIT_RAD:
        return "AT MAX"
    return ""


def joint_line(joint: dict[str, Any], units: Units = Units(), params: dict[str, Any] | None = None) -> str:
    """Two lines of at most ``WIDTH`` columns: the forces and flags, then the angles (model, goal,
    measured) and the model's speed, each with its unit."""
    present = joint.get("position")
    goal = joint.get("goal")
    first = f"joint {joint['id']:<3} force {number(joint['force'], 9, 3)} N  torque {number(joint['tau'], 8, 3)} N·m"
    if joint.get("rendering_rms") is not None:
        first += f"  {NAMES['rendering_rms']} {units.small_angle(joint['rendering_rms'])}"
    flags = [flag for flag in (at_limit(joint, params),) if flag]
    if joint.get("passivity_damping"):
        flags.append(f"PASSIVITY GUARD +{joint['passivity_damping']:.3g} N·m·s/rad")
    if joint.get("fault"):
        flags.append("FAULT " + ", ".join(fault_names(joint["fault"])))
    second = (f"  model {units.angle(joint['theta'])} {units.rate(joint['omega'])}"
              f"  goal {units.angle(goal) if goal is not None else '-'}"
              f"  read {units.angle(present) if present is not None else '-'}")
    flagged = first + "  " + "  ".join(flags)
    lines = [flagged] if flags and len(flagged) <= WIDTH else [first, "  " + "  ".join(flags)] if flags else [first]
    return "\n".join(fit(lines + [second]))


def fit(lines: list[str], width: int = 0) -> list[str]:
    """Lines longer than the screen broken between words (never inside a number), indented."""
    width = width or WIDTH
    out = []
    for line in lines:
        out += textwrap.wrap(line, width, subsequent_indent="    ", break_long_words=False,
                             break_on_hyphens=False, drop_whitespace=True) if len(line) > width else [line]
    return out


def fault_names(bits: int) -> list[str]:
    """The fault kinds of a joint's ``fault`` bits (by bit number if the extension is missing)."""
    try:
        from admittance._rtcore import FAULT_KINDS
    except ImportError:  # a monitor on a machine without the loop's build
        FAULT_KINDS = []
    return [FAULT_KINDS[k] if k < len(FAULT_KINDS) else f"bit {k}" for k in range(64) if bits >> k & 1]


def loop_lines(stats: dict[str, Any]) -> list[str]:
    return [f"loop    {stats.get('rate_hz', 0):8.1f} Hz  cycles {stats.get('cycles', 0)}  "
            f"overruns {stats.get('overruns', 0)}", f"bus     {bus_errors_text(stats)}"]


def rendering_line(stats: dict[str, Any], units: Units = Units()) -> list[str]:
    """The horn's distance from the model, per joint (the daemon's running RMS, last ~1 s)."""
    rms = stats.get("rendering_rms") or {}
    if not rms:
        return []
    joints = "  ".join(f"joint {jid} {units.small_angle(value)}" for jid, value in sorted(rms.items()))
    return [f"{NAMES['rendering_rms']} (RMS of present − model angle, ~1 s)  {joints}"]


def fault_line(stats: dict[str, Any]) -> list[str]:
    """The loop's mode and its fault events so far (docs/faults.md), when there is anything to say."""
    counts = {kind: n for kind, n in (stats.get("faults") or {}).items() if n}
    mode = stats.get("mode", "running")
    if not counts and mode == "running":
        return []
    bus = stats.get("bus") or {}
    lost = f"  bus lost for {bus['lost_for_s']:.1f} s" if bus.get("lost_for_s") else ""
    return [f"faults  {mode}  " + "  ".join(f"{kind} {n}" for kind, n in sorted(counts.items())) + lost]


def stats_lines(stats: dict[str, Any], units: Units = Units()) -> list[str]:
    rt = stats.get("rt", {})
    period, latency = stats.get("period_us", {}), stats.get("latency_us", {})
    return [
        *loop_lines(stats),
        f"{NAMES['period_us']:<22}  p50 {period.get('p50', 0):7.1f} µs  p99 {period.get('p99', 0):7.1f}  "
        f"p99.9 {period.get('p999', 0):7.1f}  max {period.get('max', 0):7.1f}",
        f"{NAMES['latency_us']:<22}  p50 {latency.get('p50', 0):7.1f} µs  p99 {latency.get('p99', 0):7.1f}  "
        f"max {latency.get('max', 0):7.1f}",
        f"sensor  samples {stats.get('sensor_samples', 0)}  {NAMES['sensor_stale_events']} {stats.get('sensor_stale_events', 0)}",
        f"rt      {rt.get('policy', '?')} prio {rt.get('priority', 0)}  "
        f"memory locked {'yes' if rt.get('memory_locked') else 'no'}",
        *rendering_line(stats, units),
        *fault_line(stats),
        *passivity_line(stats),
    ]


def passivity_line(stats: dict[str, Any]) -> list[str]:
    """Each joint's passivity guard (docs/fidelity.md): its energy balance, the damping it adds
    now and how often it acted, once there is anything to say."""
    guards = [g for g in stats.get("passivity") or [] if g.get("episodes") or g.get("damping")]
    if not guards:
        return []
    return ["passivity  " + "  ".join(f"joint {g['id']} {1e3 * g.get('energy', 0.0):+.1f} mJ "
                                     f"+{g.get('damping', 0.0):.3g} N·m·s/rad {g.get('episodes', 0)}×"
                                     for g in guards)]


def params_lines(params: dict[str, Any]) -> list[str]:
    """The live virtual parameters, one line per joint, with the units ``set`` takes."""
    from admittance.daemon.config import JOINT_LIVE

    joints: dict[str, list[str]] = {}
    for name, value in params.items():
        jid, _, key = name.partition(".")
        if key in SHOWN_PARAMS and isinstance(value, (int, float)):
            unit = JOINT_LIVE[key][1].get("unit", "")
            joints.setdefault(jid, []).append(f"{key} {value:.4g}{' ' + unit if unit else ''}")
    return [f"params  joint {jid}: " + "  ".join(items) for jid, items in sorted(joints.items())]


@dataclass
class BenchSeen:
    """What the monitor knows about one bench, and when it learnt it (the view's clock)."""

    state: dict[str, Any] | None = None
    state_at: float | None = None
    stats: dict[str, Any] | None = None
    stats_at: float | None = None
    params: dict[str, Any] | None = None
    alive: bool | None = None  # None: no liveliness token seen (yet)
    alive_at: float | None = None

    def status(self, now: float) -> str:
        """``alive``, ``GONE ...`` or ``STALE ...``: what is true of the bench now."""
        if self.alive is False:
            return f"GONE {now - (self.alive_at or now):.1f} s ago (its liveliness token was withdrawn)"
        if self.state_at is not None and now - self.state_at > STATE_STALE_S:
            return f"STALE: no state for {now - self.state_at:.1f} s"
        return "alive" if self.alive else "no liveliness token yet"

    def stale(self, now: float) -> bool:
        return self.alive is False or (self.state_at is not None and now - self.state_at > STATE_STALE_S)

    def stats_stale(self, now: float) -> bool:
        return self.alive is False or (self.stats_at is not None and now - self.stats_at > STATS_STALE_S)


def bench_block(name: str, seen: BenchSeen, now: float, units: Units) -> list[str]:
    """One bench: a header with its status, mode and faults; its joints, parameters and timing."""
    state, stats = seen.state, seen.stats
    mode = (state or {}).get("mode") or (stats or {}).get("mode") or "?"
    if seen.stale(now):  # a daemon that is gone or silent is not running: say what it last said
        mode = f"unknown (last: {mode})"
    events = {k: n for k, n in ((stats or {}).get("faults") or {}).items() if n}
    faults = ", ".join(f"{k} ×{n}" for k, n in events.items()) or "none"
    lines = [f"== {name}  {seen.status(now)}", f"mode {mode}  fault events {faults}"]
    if seen.stale(now) and seen.state_at:
        lines.append(f"values below: last received {now - seen.state_at:.1f} s ago")
    lines += [joint_line(j, units, seen.params) for j in state.get("joints", [])] if state else ["waiting for state ..."]
    lines += params_lines(seen.params) if seen.params else []
    if stats:
        timing = stats_lines(stats, units)
        if seen.stats_stale(now) and seen.stats_at is not None:
            timing[0] += f"  [stale: stats {now - seen.stats_at:.1f} s old]"
        lines += timing
    else:
        lines.append("waiting for stats ...")
    return fit("\n".join(lines).split("\n"))


def screen_many(prefix: str, benches: dict[str, BenchSeen], now: float, units: Units = Units()) -> str:
    lines = [f"admittance monitor  {prefix}" + (f"/**  ({len(benches)} benches)" if len(benches) > 1 else "")]
    if not benches:
        lines += ["", f"waiting for {prefix}/state ..."]
    for name in sorted(benches):
        lines += ["", *bench_block(name, benches[name], now, units)]
    return "\n".join(lines)


class View:
    """Keeps what each bench sent and writes it to ``out`` (a redraw, or plain lines)."""

    def __init__(self, prefix: str, out: TextIO, tty: bool, degrees: bool = False,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.prefix = prefix
        self.out = out
        self.tty = tty
        self.units = Units(degrees)
        self.clock = clock
        self.benches: dict[str, BenchSeen] = {}
        self.received = 0
        self._next_plain = 0.0
        self._printed: dict[str, dict[str, Any]] = {}  # plain mode: what each bench's lines last said

    @property
    def state(self) -> dict[str, Any] | None:
        seen = self.benches.get(self.prefix)
        return seen.state if seen else None

    def feed(self, kind: str, message: dict[str, Any], bench: str | None = None) -> None:
        """``state``, ``stats`` or ``params`` (the reply's ``params``) messages, or ``alive``
        (``{"alive": bool}``, from the liveliness subscriber)."""
        bench = bench or self.prefix
        now = self.clock()
        seen = self.benches.setdefault(bench, BenchSeen())
        if kind == "alive":
            seen.alive, seen.alive_at = bool(message.get("alive")), now
        elif kind == "params":
            seen.params = message.get("params", message)
        elif kind in ("state", "stats"):
            self.received += 1
            setattr(seen, kind, message)
            setattr(seen, f"{kind}_at", now)
            if kind == "stats" and not self.tty:
                self.out.write("".join(f"{self._label(bench)}{line}\n" for line in
                                       [*loop_lines(message), *rendering_line(message, self.units),
                                        *fault_line(message)]))

    def _label(self, bench: str) -> str:
        return "" if bench == self.prefix else f"{bench}  "

    def render(self, now: float | None = None) -> None:
        now = self.clock() if now is None else now
        if self.tty:
            self.out.write(CLEAR + screen_many(self.prefix, self.benches, now, self.units) + "\n")
        elif now >= self._next_plain:
            self._next_plain = now + PLAIN_PERIOD_S
            for bench in sorted(self.benches):
                self.out.write("".join(self._label(bench) + line + "\n" for line in self._plain_news(bench, now)))
        self.out.flush()

    def _plain_news(self, bench: str, now: float) -> list[str]:
        """What changed for ``bench`` since the last plain lines: its status, its parameters, new state."""
        seen, printed = self.benches[bench], self._printed.setdefault(bench, {})
        lines = []
        status = seen.status(now).split(" ")[0]  # the word, not the growing age
        if status != printed.get("status") and (seen.alive is not None or status != "no"):
            lines.append(seen.status(now) if status != "no" else "no liveliness token yet")
            printed["status"] = status
        shown = params_lines(seen.params) if seen.params else []
        if shown and shown != printed.get("params"):
            lines += shown
            printed["params"] = shown
        if seen.state is not None and seen.state_at != printed.get("state_at") and not seen.stale(now):
            lines += [line for j in seen.state.get("joints", []) for line in joint_line(j, self.units, seen.params).split("\n")]
            printed["state_at"] = seen.state_at
        return lines


def run_monitor(subscription: Any, view: View, duration: float | None) -> int:
    """Feed and render until ``duration`` passes (or forever); DeviceError if nothing ever came.
    ``subscription.drain()`` gives ``(kind, message[, bench])``; its ``request_params()``, if it
    has one, asks every bench for its parameters (the replies come through ``drain``)."""
    start = time.monotonic()
    next_params = start
    request_params = getattr(subscription, "request_params", None)
    try:
        while duration is None or time.monotonic() - start < duration:
            if request_params is not None and time.monotonic() >= next_params:
                request_params()
                next_params = time.monotonic() + PARAMS_PERIOD_S
            for item in subscription.drain():
                view.feed(*item)
            view.render()
            time.sleep(REDRAW_PERIOD_S)
    except KeyboardInterrupt:
        pass
    if view.received == 0:
        raise DeviceError(f"no state or stats received on {view.prefix}/* "
                          f"(is `admittance run` up, with the same prefix and endpoint?)")
    return 0
