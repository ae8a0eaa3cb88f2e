"""The common part of the force-sensor readers: lifecycle, sink, tare, and the kind registry.

Modelled on python-can's driver abstraction (shared style-anchors.md §2):

- A tiny backend contract. A reader subclasses :class:`ForceSensor` and writes ``_open``
  (acquire the device, raise DeviceError if it is missing), ``_poll`` (wait a bounded time for
  data and hand any samples to ``_emit_all``) and ``_close``. The base owns the thread, the
  idempotent start/stop, the context manager, the bias, tare and the statistics.
- The registry is data with lazy import (``READER_CLASSES``): importing ``admittance.drivers``
  never loads pyserial or python-can, and a kind whose import fails names itself.
- Readers never import the daemon or the RT loop: they get a *sink* (Contract 5), any object
  with ``push(t_ns, forces) -> bool``. The reader thread only converts and pushes; a sink
  that is full (False) loses that sample and the loss is counted, never waited for.

A device that fails while running (unplugged: EIO, hang-up, a CAN adapter gone) is closed and
reopened with backoff (0.05 s doubling to 2 s) until it answers again, so a replug recovers
without a restart; meanwhile the joint holds on the loop's staleness check. Whatever happens
is counted in ``stats()`` and told once through a rate-limited event hook (``set_event_hook``;
by default the ``logging`` module): a disconnection, a failed reopen, the recovery, a stream
gone stale and fresh again, saturated samples.

Tare is done on the host from the reader's own stream and not with the DAQ's ZERO command,
because the same code then serves every kind of sensor, and because a tare taken while the
user is still touching the handle must be refused: the bias is the mean of N samples, and the
standard deviation of each axis must stay below a bound (a still sensor shows only its noise).
"""

from __future__ import annotations

import abc
import importlib
import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from admittance.errors import ConfigError, DataError, DeviceError

log = logging.getLogger(__name__)

AXES = ("fx", "fy", "fz", "tx", "ty", "tz")
# A still sensor shows a few counts of noise, well below 0.05 N on the OptoForce sensors we
# know; a hand resting on the handle moves by tenths of a newton.
DEFAULT_TARE_MAX_STD = (0.25, 0.25, 0.25, 0.025, 0.025, 0.025)
DEFAULT_TARE_SAMPLES = 200
RECONNECT_FIRST_S = 0.05
RECONNECT_MAX_S = 2.0
DEFAULT_STALE_AFTER_S = 0.2
EVENT_REPEAT_S = 5.0


class EventLog:
    """Tells each kind of event at most once per ``repeat_s``, with the count of those held
    back, to a hook ``(kind, message)``: a stream that fails 1000 times a second must not
    flood the journal, and the first of a kind is never delayed."""

    def __init__(self, hook: Callable[[str, str], None] | None = None, repeat_s: float = EVENT_REPEAT_S,
                 clock: Callable[[], float] = time.monotonic):
        self.hook = hook or _log_event
        self.repeat_s = repeat_s
        self.clock = clock
        self.counts: dict[str, int] = {}
        self._last: dict[str, float] = {}
        self._held: dict[str, int] = {}

    def __call__(self, kind: str, message: str) -> None:
        self.counts[kind] = self.counts.get(kind, 0) + 1
        now = self.clock()
        last = self._last.get(kind)
        if last is not None and now - last < self.repeat_s:
            self._held[kind] = self._held.get(kind, 0) + 1
            return
        held = self._held.pop(kind, 0)
        self._last[kind] = now
        suffix = f" ({held} more since the last report)" if held else ""
        try:
            self.hook(kind, message + suffix)
        except Exception:  # a broken hook must not stop the reader
            log.exception("the force sensor's event hook failed")


def _log_event(kind: str, message: str) -> None:
    level = logging.INFO if kind in ("reconnected", "fresh") else logging.WARNING
    log.log(level, "%s", message)


class Sink(Protocol):
    def push(self, t_ns: int, forces: Sequence[float]) -> bool: ...


class ForceStream(Protocol):
    """What the daemon needs of a force sensor's reader, whichever runs it: a
    :class:`ForceSensor` (a Python thread) or the Rust reader's wrapper
    (native_sensor.NativeForceReader). mypy checks both against it where the daemon makes its
    sensor (daemon/backends.py, ``make test-stub``)."""

    stale_after_s: float

    @property
    def running(self) -> bool: ...

    @property
    def reader_path(self) -> str: ...

    @property
    def bias(self) -> tuple[float, ...]: ...

    def start(self) -> None: ...

    def stop(self) -> None: ...

    def describe(self) -> str: ...

    def set_event_hook(self, hook: Callable[[str, str], None] | None, repeat_s: float = ...) -> None: ...

    def set_bias(self, bias: Sequence[float]) -> None: ...

    def tare(self, n_samples: int = ..., *, max_std: float | Sequence[float] = ...,
             timeout: float = ...) -> TareResult: ...

    def stats(self) -> dict[str, Any]: ...


class SampleBuffer:
    """A bounded sink that keeps the latest samples: for tools, benches and tests.

    ``push`` never blocks and always accepts (the oldest sample falls off the end), which is
    what a monitor wants; the RT loop's own sink is a lock-free ring instead.
    """

    def __init__(self, maxlen: int = 100_000):
        self._samples: deque[tuple[int, list[float]]] = deque(maxlen=maxlen)
        self._cond = threading.Condition()
        self.total = 0

    def push(self, t_ns: int, forces: Sequence[float]) -> bool:
        with self._cond:
            self._samples.append((t_ns, list(forces)))
            self.total += 1
            self._cond.notify_all()
        return True

    def snapshot(self) -> list[tuple[int, list[float]]]:
        with self._cond:
            return list(self._samples)

    def wait_for(self, total: int, timeout: float) -> bool:
        """Wait until ``total`` samples have been pushed in all; False on timeout."""
        with self._cond:
            return self._cond.wait_for(lambda: self.total >= total, timeout)


# ---------------------------------------------------------------------------------------------
# Tare and bias


@dataclass(frozen=True)
class TareResult:
    """The outcome of a bias estimate. When refused, ``bias`` is None and ``reason`` says why."""

    accepted: bool
    bias: tuple[float, ...] | None
    std: tuple[float, ...]
    n_samples: int
    reason: str = ""


def estimate_bias(
    samples: Sequence[Sequence[float]], *, max_std: float | Sequence[float] = DEFAULT_TARE_MAX_STD, min_samples: int = 10
) -> TareResult:
    """The bias is the per-axis mean of ``samples`` (rows of 6); refused when not still.

    ``max_std`` bounds each axis's standard deviation (N for forces, N·m for torques); a
    scalar applies to every axis.
    """
    data = np.asarray(samples, dtype=float) if len(samples) else np.zeros((0, len(AXES)))
    if data.ndim != 2 or data.shape[1] != len(AXES):
        raise DataError(f"a tare needs rows of {len(AXES)} values [fx, fy, fz, tx, ty, tz], got shape {data.shape}")
    n = data.shape[0]
    if n < max(2, min_samples):
        return TareResult(False, None, (), n, f"too few samples for a tare: {n} < {max(2, min_samples)}")
    if not np.all(np.isfinite(data)):
        return TareResult(False, None, (), n, "the samples contain NaN or infinite values")
    bound = np.broadcast_to(np.asarray(max_std, dtype=float), (len(AXES),))
    std = data.std(axis=0, ddof=1)
    stds = tuple(float(s) for s in std)
    moving = [i for i in range(len(AXES)) if std[i] > bound[i]]
    if moving:
        i = moving[0]
        unit = "N" if i < 3 else "N·m"
        reason = (
            f"the sensor is not still: the std of {AXES[i]} is {std[i]:.3g} {unit} "
            f"> {bound[i]:.3g} {unit} over {n} samples (let go of the handle and retry)"
        )
        return TareResult(False, None, stds, n, reason)
    return TareResult(True, tuple(float(m) for m in data.mean(axis=0)), stds, n)


# ---------------------------------------------------------------------------------------------
# The reader base


class ForceSensor(abc.ABC):
    """A force sensor that streams samples to a sink from its own thread.

    ``start()`` opens the device (DeviceError if it is missing) and starts the thread;
    ``stop()`` joins it and closes the device. Both are idempotent; the sensor can be started
    again after a stop. If the device fails while running (unplugged), it is closed and
    reopened with backoff until it works again; meanwhile ``error`` holds the failure (None
    again once samples flow) and ``state`` is ``"reconnecting"``.
    """

    kind: str = ""
    reader_path = "python"  # which reader runs (stats, the start line); the Rust ones say rust-*
    reconnect_first_s = RECONNECT_FIRST_S
    reconnect_max_s = RECONNECT_MAX_S

    def __init__(self, sink: Sink):
        if not callable(getattr(sink, "push", None)):
            raise ConfigError("a force sensor needs a sink with push(t_ns, forces)")
        self._sink = sink
        self._bias = (0.0,) * len(AXES)
        self._thread: threading.Thread | None = None
        self._stop_event = threading.Event()
        self._tare_rows: list[list[float]] | None = None
        self._tare_full = threading.Event()
        self._tare_wanted = 0
        self.error: str | None = None
        self.last_error: str | None = None
        self.state = "stopped"
        self.samples_pushed = 0
        self.samples_dropped = 0
        self.last_sample_ns = 0
        self.disconnects = 0
        self.reconnects = 0
        self.reopen_failures = 0
        self.stale_events = 0
        self.stale_after_s = DEFAULT_STALE_AFTER_S
        self.events = EventLog()
        self._stale = False
        self._last_arrival = 0.0
        # The next reopen's wait: it grows while reopens fail, or succeed without a sample
        # (a device that opens, then fails at once, must not be reopened 20 times a second).
        self._backoff = self.reconnect_first_s

    # -- backend contract --------------------------------------------------------------------

    @abc.abstractmethod
    def _open(self) -> None:
        """Acquire the device; raise DeviceError with the device's name if it is missing."""

    @abc.abstractmethod
    def _poll(self) -> None:
        """Wait a bounded time (≤ ~0.1 s) for data and pass any samples to ``_emit_all``."""

    @abc.abstractmethod
    def _close(self) -> None:
        """Release the device (called once per successful ``_open``)."""

    def describe(self) -> str:
        """The device in words for messages, e.g. ``optoforce sensor on /dev/ttyACM0``."""
        where = getattr(self, "port", None) or getattr(self, "channel", None)
        return f"{self.kind} sensor" + (f" on {where}" if where is not None else "")

    def set_event_hook(self, hook: Callable[[str, str], None] | None, repeat_s: float = EVENT_REPEAT_S) -> None:
        """Where events go, ``hook(kind, message)``, each kind at most once per ``repeat_s``.
        Kinds: disconnected, reopen_failed, reconnected, stale, fresh, saturated, status_fault."""
        counts = self.events.counts
        self.events = EventLog(hook, repeat_s)
        self.events.counts = counts

    @classmethod
    def from_config(cls, section: Mapping[str, Any], sink: Sink) -> ForceSensor:
        """Build the reader from the daemon's [sensor] table."""
        raise ConfigError(f"sensor kind '{cls.kind}' cannot be built from a configuration")

    # -- lifecycle -----------------------------------------------------------------------------

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self) -> None:
        if self._thread is not None:
            return
        self.error = None
        self._open()
        self.state = "streaming"
        self._last_arrival = time.monotonic()
        self._stale = False
        self._stop_event.clear()
        self._thread = threading.Thread(target=self._run, name=f"force-{self.kind}", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        thread, self._thread = self._thread, None
        if thread is None:
            return
        self._stop_event.set()
        thread.join()
        self._close()
        self.state = "stopped"

    def __enter__(self) -> ForceSensor:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _run(self) -> None:
        while not self._stop_event.is_set():
            try:
                while not self._stop_event.is_set():
                    self._poll()
                    self._watch_staleness()
            except Exception as exc:  # the device died under us: reopen it, never kill the process
                self._lost(exc)
                self._reopen()

    def _lost(self, exc: BaseException) -> None:
        self.error = self.last_error = f"{type(exc).__name__}: {exc}"
        self.disconnects += 1
        self.state = "reconnecting"
        self.events("disconnected", f"{self.describe()} failed ({self.error}); reopening it with backoff, the joints hold meanwhile")
        try:
            self._close()
        except Exception as close_exc:  # closing a dead device may fail too; it is closed anyway
            log.debug("closing the failed %s: %s", self.describe(), close_exc)

    def _reopen(self) -> None:
        """Reopen with backoff until it works or the reader is stopped."""
        while not self._stop_event.wait(self._backoff):
            self._backoff = min(2 * self._backoff, self.reconnect_max_s)
            try:
                self._open()
            except Exception as exc:
                self.reopen_failures += 1
                self.last_error = str(exc)
                self.events("reopen_failed", f"{self.describe()} is still gone: {exc}")
                continue
            self.reconnects += 1
            self.error = None
            self.state = "streaming"
            self._last_arrival = time.monotonic()
            self.events("reconnected", f"{self.describe()} is back after {self.disconnects} disconnection(s)")
            return

    def _watch_staleness(self) -> None:
        """Tells when the stream stops for ``stale_after_s`` and when it comes back (the loop
        holds the joint on its own, sooner; this is for the log and the counters)."""
        silent_s = time.monotonic() - self._last_arrival
        if not self._stale and silent_s > self.stale_after_s:
            self._stale = True
            self.stale_events += 1
            self.events("stale", f"{self.describe()}: no samples for {silent_s:.2f} s; the joints hold")

    # -- samples -------------------------------------------------------------------------------

    def _emit_all(self, vectors: Sequence[list[float]]) -> None:
        """Hand a batch of 6-vectors (bias not yet removed) to the sink, stamped now."""
        t_ns = time.monotonic_ns()
        bias = self._bias
        if vectors:
            self._arrived()
        for raw in vectors:
            if self._tare_rows is not None:
                self._collect_for_tare(raw)
            forces = [f - b for f, b in zip(raw, bias)]
            if self._sink.push(t_ns, forces):
                self.samples_pushed += 1
            else:
                self.samples_dropped += 1
            self.last_sample_ns = t_ns

    def _emit_converted(self, converter: Any, data: bytes | bytearray) -> None:
        """Parse ``data`` with an OptoForce ``SampleConverter``, push its forces, and tell
        saturated and faulty samples (rate-limited). A frame that arrived counts as arrival
        even when the policy holds it: the stream is alive, its readings are not usable."""
        samples, overloads, faults = converter.parser.samples, converter.overloads, converter.status_faults
        self._emit_all(converter.forces(data))
        if converter.parser.samples != samples:
            self._arrived()
        if converter.overloads != overloads:
            self.events("saturated", f"{self.describe()}: {converter.saturation_note()}")
        if converter.status_faults != faults:
            self.events("status_fault", f"{self.describe()}: the DAQ reports an error "
                                        f"(status 0x{converter.last_fault_status:04X}); those samples are dropped")

    def _arrived(self) -> None:
        self._last_arrival = time.monotonic()
        self._backoff = self.reconnect_first_s
        if self._stale:
            self._stale = False
            self.events("fresh", f"{self.describe()}: samples flow again")

    def _collect_for_tare(self, raw: list[float]) -> None:
        rows = self._tare_rows
        if rows is not None and len(rows) < self._tare_wanted:
            rows.append(raw)
            if len(rows) >= self._tare_wanted:
                self._tare_full.set()

    # -- bias ----------------------------------------------------------------------------------

    @property
    def bias(self) -> tuple[float, ...]:
        return self._bias

    def set_bias(self, bias: Sequence[float]) -> None:
        values = tuple(float(b) for b in bias)
        if len(values) != len(AXES) or not all(np.isfinite(values)):
            raise ConfigError(f"a bias has {len(AXES)} finite values, got {bias!r}")
        self._bias = values

    def tare(
        self,
        n_samples: int = DEFAULT_TARE_SAMPLES,
        *,
        max_std: float | Sequence[float] = DEFAULT_TARE_MAX_STD,
        timeout: float = 2.0,
    ) -> TareResult:
        """Estimate the bias from the next ``n_samples`` samples and apply it if accepted.

        Blocks up to ``timeout`` seconds; a refused tare leaves the bias unchanged.
        """
        if not self.running:
            raise DeviceError(f"cannot tare the {self.kind} sensor: it is not running")
        self._tare_wanted = n_samples
        self._tare_full.clear()
        self._tare_rows = []
        try:
            self._tare_full.wait(timeout)
            rows = list(self._tare_rows)
        finally:
            self._tare_rows = None
        if len(rows) < n_samples:
            return TareResult(False, None, (), len(rows), f"only {len(rows)} of {n_samples} samples arrived in {timeout:g} s")
        result = estimate_bias(rows, max_std=max_std)
        if result.accepted:
            self._bias = result.bias
        return result

    def stats(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "reader": self.reader_path,
            "running": self.running,
            "state": self.state,
            "error": self.error,
            "last_error": self.last_error,
            "samples_pushed": self.samples_pushed,
            "samples_dropped": self.samples_dropped,
            "last_sample_ns": self.last_sample_ns,
            "disconnects": self.disconnects,
            "reconnects": self.reconnects,
            "reopen_failures": self.reopen_failures,
            "stale_events": self.stale_events,
            "stale": self._stale,
            "events": dict(self.events.counts),
        }


# ---------------------------------------------------------------------------------------------
# Configuration helpers shared by the readers


def counts_per_unit(values: float | Sequence[float], axes: int) -> tuple[float, ...]:
    """Per-axis sensitivities (counts/N, then counts/N·m): a scalar applies to every axis."""
    if isinstance(values, int | float):
        values = [values] * axes
    try:
        out = tuple(float(v) for v in values)
    except (TypeError, ValueError):
        raise ConfigError(f"counts_per_newton must be numbers, got {values!r}") from None
    if len(out) != axes:
        raise ConfigError(f"counts_per_newton needs {axes} values (one per axis), got {len(out)}")
    if not all(np.isfinite(out)) or min(out) <= 0:
        raise ConfigError(f"counts_per_newton must be positive, got {list(out)}")
    return out


def require_key(section: Mapping[str, Any], key: str) -> Any:
    if key not in section:
        raise ConfigError(f"[sensor] needs '{key}' for kind = \"{section.get('kind')}\"")
    return section[key]


# ---------------------------------------------------------------------------------------------
# The registry of kinds

READER_CLASSES: dict[str, tuple[str, str]] = {
    "optoforce": ("admittance.drivers.optoforce", "OptoForceSerialReader"),
    "can": ("admittance.drivers.can_sensor", "CanForceReader"),
    "mock": ("admittance.mockbench.simulated_sensor", "ScriptedForceSensor"),  # lives with the other simulations
}


def sensor_class(kind: str) -> type[ForceSensor]:
    """The reader class of a kind, imported on first use."""
    try:
        module_name, class_name = READER_CLASSES[kind]
    except KeyError:
        raise ConfigError(f"unknown sensor kind '{kind}' (known: {', '.join(READER_CLASSES)})") from None
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ConfigError(f"sensor kind '{kind}' is unavailable: {exc}") from None
    return getattr(module, class_name)


def create_sensor(section: Mapping[str, Any], sink: Sink) -> ForceSensor:
    """The reader described by a [sensor] table (daemon.md), not yet started."""
    kind = section.get("kind")
    if not isinstance(kind, str):
        raise ConfigError("[sensor] needs kind = \"optoforce\", \"can\" or \"mock\"")
    return sensor_class(kind).from_config(section, sink)
