"""Fault injection on the simulated bench: one small command language, three ways in.

A command is one line of words (docs/mock-bench.md has the table)::

    bus unplug | bus replug
    servo ID hardware-error BITS      (P2 Hardware Error Status layout; 0 clears)
    servo ID torque-off | servo ID brown-out SECONDS | servo ID glitch TICKS [EVERY] | servo ID state
    sensor unplug | sensor replug
    sensor silence on|off | sensor saturate on|off | sensor status BITS
    sensor garbage N_BYTES | sensor corrupt N_FRAMES
    stats

:func:`run_command` executes one on a :class:`~admittance.mockbench.bench.MockBench` and
returns a JSON-able reply, ``{"ok": true, ...}`` or ``{"ok": false, "error": "..."}``; it
never raises for a bad command. In-process tests call it (or the bench's methods) directly;
another process sends commands on the control socket (:mod:`admittance.mockbench.control`);
``admittance mock-bench --faults FILE`` plays a timed script of them (:class:`FaultScript`),
one ``SECONDS COMMAND`` per line, seconds after the bench started, ``#`` for comments.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from admittance.errors import AdmittanceError, ConfigError

MAX_LINE = 1024
MAX_SCRIPT_LINES = 10_000


def run_command(bench: Any, line: str) -> dict[str, Any]:
    """Execute one command on ``bench``; the reply says what happened or why not."""
    try:
        return {"ok": True} | (_dispatch(bench, line.split()) or {})
    except (AdmittanceError, ValueError, KeyError, OSError) as exc:
        return {"ok": False, "error": str(exc) or type(exc).__name__}


def check_command(line: str) -> None:
    """Raise ConfigError unless ``line`` is a command of the language (arguments included)."""
    words = line.split()
    if not words or words[0] not in _PARSERS:
        raise ConfigError(f"unknown fault command {line.strip()!r} (commands start with {', '.join(_PARSERS)})")
    _PARSERS[words[0]](words[1:])


def _dispatch(bench: Any, words: list[str]) -> dict[str, Any] | None:
    if not words:
        raise ConfigError("empty command")
    if len(" ".join(words)) > MAX_LINE:
        raise ConfigError(f"a command is at most {MAX_LINE} characters")
    parser = _PARSERS.get(words[0])
    if parser is None:
        raise ConfigError(f"unknown command {words[0]!r} (known: {', '.join(_PARSERS)})")
    return parser(words[1:])(bench)


Action = Callable[[Any], "dict[str, Any] | None"]


def _bus(args: list[str]) -> Action:
    match args:
        case ["unplug"]:
            return lambda bench: {"changed": bench.bus.unplug()}
        case ["replug"]:
            return lambda bench: {"changed": bench.bus.replug(), "port": bench.bus.port_path}
    raise ConfigError("bus takes unplug or replug")


def _servo(args: list[str]) -> Action:
    if not args:
        raise ConfigError("servo takes an ID, then hardware-error BITS, torque-off, brown-out SECONDS, glitch TICKS [EVERY] "
                          "or state")
    servo_id, rest = _int(args[0], "servo ID", 0, 252), args[1:]
    match rest:
        case ["hardware-error", bits]:
            value = _int(bits, "hardware error bits", 0, 0xFF)
            return lambda bench: bench.bus.set_hardware_error(servo_id, value)
        case ["torque-off"]:
            return lambda bench: bench.bus.torque_off(servo_id)
        case ["brown-out", seconds]:
            value = _seconds(seconds)
            return lambda bench: bench.bus.brown_out(servo_id, value)
        case ["glitch", ticks, *every] if len(every) <= 1:
            offset = _int(ticks, "glitch ticks", -(1 << 20), 1 << 20)
            period = _int(every[0], "glitch every (reads)", 0, 1000) if every else 0
            return lambda bench: bench.bus.glitch_position(servo_id, offset, period)
        case ["state"]:
            return lambda bench: {"state": bench.bus.servo_state(servo_id)}
    raise ConfigError(f"servo {servo_id}: expected hardware-error BITS, torque-off, brown-out SECONDS, "
                      f"glitch TICKS [EVERY] or state, got {' '.join(rest)!r}")


def _sensor(args: list[str]) -> Action:
    match args:
        case ["unplug" | "replug" as what]:
            return lambda bench: {"changed": _pty_sensor(bench, what)()}
        case ["silence" | "saturate" as what, ("on" | "off") as state]:
            return lambda bench: getattr(bench.sensor, what)(state == "on")
        case ["status", bits]:
            value = _int(bits, "status bits", 0, 0xFFFF)
            return lambda bench: bench.sensor.set_status(value)
        case ["garbage", n]:
            count = _int(n, "garbage bytes", 1, 4096)
            return lambda bench: bench.sensor.inject_garbage(count)
        case ["corrupt", n]:
            count = _int(n, "corrupt frames", 1, 100_000)
            return lambda bench: bench.sensor.corrupt(count)
    raise ConfigError("sensor takes unplug, replug, silence on|off, saturate on|off, status BITS, garbage N or corrupt N")


def _stats(args: list[str]) -> Action:
    if args:
        raise ConfigError("stats takes no arguments")
    return lambda bench: {"stats": bench.stats()}


_PARSERS: dict[str, Callable[[list[str]], Action]] = {"bus": _bus, "servo": _servo, "sensor": _sensor, "stats": _stats}


def _pty_sensor(bench: Any, what: str) -> Callable[[], bool]:
    method = getattr(bench.sensor, what, None)
    if method is None:
        raise ConfigError(f"the {bench.config.sensor} sensor has no wire to {what} (the pty sensors do)")
    return method


def _int(text: str, what: str, low: int, high: int) -> int:
    try:
        value = int(text, 0)
    except ValueError:
        raise ConfigError(f"{what} must be an integer, not {text!r}") from None
    if not low <= value <= high:
        raise ConfigError(f"{what} must be within {low}..{high}, got {value}")
    return value


def _seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ConfigError(f"seconds must be a number, not {text!r}") from None
    if not 0.0 <= value <= 60.0:
        raise ConfigError(f"seconds must be within 0..60, got {text}")
    return value


# ---------------------------------------------------------------------------------------------
# Timed scripts


@dataclass(frozen=True)
class Step:
    at_s: float
    command: str


class FaultScript:
    """``SECONDS COMMAND`` lines, checked whole at load (a typo fails before the bench runs)."""

    def __init__(self, steps: list[Step]):
        self.steps = sorted(steps, key=lambda step: step.at_s)
        self.replies: list[tuple[Step, dict[str, Any]]] = []

    @classmethod
    def load(cls, path: str | Path) -> FaultScript:
        try:
            text = Path(path).read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise ConfigError(f"--faults: cannot read {path}: {exc}") from None
        lines = text.splitlines()
        if len(lines) > MAX_SCRIPT_LINES:
            raise ConfigError(f"--faults: {path} has more than {MAX_SCRIPT_LINES} lines")
        return cls([step for number, line in enumerate(lines, 1) if (step := _step(path, number, line))])

    def play(self, bench: Any, stop: Any, t0: float | None = None) -> None:
        """Run each step at its time after ``t0`` (default now) until done or ``stop`` (anything with
        ``wait(timeout) -> bool``: a StopRequest, an Event) is set."""
        t0 = time.monotonic() if t0 is None else t0
        for step in self.steps:
            if stop.wait(max(0.0, t0 + step.at_s - time.monotonic())):
                return
            self.replies.append((step, run_command(bench, step.command)))


def _step(path: str | Path, number: int, line: str) -> Step | None:
    text = line.split("#", 1)[0].strip()
    if not text:
        return None
    where = f"--faults {path}:{number}"
    if len(text) > MAX_LINE:
        raise ConfigError(f"{where}: a line is at most {MAX_LINE} characters")
    at, _, command = text.partition(" ")
    try:
        at_s = float(at)
    except ValueError:
        raise ConfigError(f"{where}: a line starts with the time in seconds, not {at!r}") from None
    if not 0.0 <= at_s < 1e6:
        raise ConfigError(f"{where}: the time must be within 0..1e6 s, got {at}")
    try:
        check_command(command)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    return Step(at_s, command.strip())
