"""The Rust force-sensor readers (``_rtcore.ForceReader``) behind the reader interface the
daemon uses (start, stop, tare, stats, events), and the choice between them and the Python ones.

Why: a Python reader hands every sample across the GIL before the loop sees it, and under load
its gaps reach several sensor periods (issue 18, docs/realtime.md). The Rust reader parses the
OptoForce stream (serial, slcan or SocketCAN) on its own thread at a real-time priority below
the loop's and pushes each sample straight into the loop's ring: no sample touches Python.
Python keeps what is not time-critical: the tare's statistics (``estimate_bias``), the
rate-limited event log (the same ``EventLog``), and the fault marks, which the daemon's fault
watch reads from ``stats()`` every 0.1 s (events are drained there).

Which reader runs (``[sensor] reader``, docs/daemon.md):
- ``auto`` (default): Rust for ``kind = "optoforce"``, for CAN on ``socketcan`` and on ``slcan``
  (with no interface options the Rust reader does not know); python-can for every other CAN
  interface (PCAN, Kvaser, virtual...);
- ``rust``: Rust, or a ConfigError where it cannot;
- ``python``: the Python readers (admittance/drivers/optoforce.py, can_sensor.py).
The start line and ``stats()["reader"]`` say which one runs.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from admittance.drivers.force_reader import (
    DEFAULT_TARE_MAX_STD,
    DEFAULT_TARE_SAMPLES,
    EVENT_REPEAT_S,
    EventLog,
    TareResult,
    counts_per_unit,
    estimate_bias,
)
from admittance.errors import ConfigError, DeviceError

READER_CHOICES = ("auto", "rust", "python")
SLCAN_OPTIONS = {"tty_baudrate", "sleep_after_open"}
DEFAULT_SLCAN_TTY_BAUD = 115_200
PTY_DIR = "/dev/pts/"
# Below the loop's priority: a flood of sensor frames must not delay a cycle; above every
# ordinary thread: the interpreter and the burners must not delay a sample.
PRIORITY_BELOW_LOOP = 10


def reader_priority(loop_priority: int) -> int:
    """SCHED_FIFO priority of the reader thread for a loop at ``loop_priority`` (0 = none)."""
    return max(loop_priority - PRIORITY_BELOW_LOOP, 1) if loop_priority > 0 else 0


def rust_transport(section: Mapping[str, Any]) -> dict[str, Any] | None:
    """The Rust reader's device keys for a [sensor] table, or None when only Python can read it."""
    kind = section.get("kind")
    if kind == "optoforce":
        return {"transport": "serial", "port": str(section.get("port", "")),
                "baudrate": int(section.get("baudrate", 1_000_000))}
    if kind != "can":
        return None
    interface = section.get("interface") or ("socketcan" if section.get("channel") or section.get("port") else None)
    channel = str(section.get("channel") or section.get("port") or "")
    options = dict(section.get("can_options") or {})
    can = {"can_id": int(section.get("can_id", 0x100))}
    if interface == "socketcan" and not options and channel:
        return can | {"transport": "socketcan", "interface": channel}
    if interface == "slcan" and set(options) <= SLCAN_OPTIONS and channel:
        port, _, suffix = channel.partition("@")  # python-can's "port@tty_baudrate"
        baud = options.get("tty_baudrate") or (int(suffix) if suffix.isdigit() else DEFAULT_SLCAN_TTY_BAUD)
        delay = options.get("sleep_after_open")
        if delay is None:  # python-can's 2 s for adapters that reset at open; a pty has nothing to reset
            delay = 0.0 if os.path.realpath(port).startswith(PTY_DIR) else 2.0
        bitrate = section.get("bitrate")
        return can | {"transport": "slcan", "port": port, "baudrate": int(baud), "open_delay_s": float(delay),
                      "bitrate": None if bitrate is None else int(bitrate)}
    return None


def choose_reader(section: Mapping[str, Any]) -> str:
    """``"rust"`` or ``"python"`` for a [sensor] table (``reader`` key, see the module doc)."""
    wanted = section.get("reader", "auto") or "auto"
    if wanted not in READER_CHOICES:
        raise ConfigError(f"[sensor].reader must be one of {', '.join(READER_CHOICES)}, not {wanted!r}")
    if wanted == "python":
        return "python"
    if rust_transport(section) is not None:
        return "rust"
    if wanted == "rust":
        raise ConfigError(f"[sensor].reader = \"rust\" reads kind = \"optoforce\" and CAN on socketcan or slcan, "
                          f"not kind = {section.get('kind')!r} interface = {section.get('interface')!r}; "
                          f"use reader = \"python\" (python-can)")
    return "python"


class NativeForceReader:
    """A Rust reader with the ``ForceSensor`` interface (start, stop, tare, stats, events).

    ``sink``: the loop's ``_rtcore.ForceSink``, the daemon's gate in front of it (the reader
    then keeps its own gate, opened with the daemon's), or None to capture the samples for
    ``take_captured()`` (tests and tools).
    """

    def __init__(self, device: Mapping[str, Any], section: Mapping[str, Any], sink: Any, *, rt_priority: int = 0):
        from admittance import _rtcore

        self.kind = str(section.get("kind"))
        self.saturation = str(section.get("saturation", "hold"))
        axes = int(section.get("axes", 3))
        config = dict(device) | {
            "counts_per_newton": list(counts_per_unit(section.get("counts_per_newton", 451.89), axes)),
            "axes": axes, "sensor_index": int(section.get("sensor_index", 0)),
            "saturation": self.saturation, "rt_priority": int(rt_priority),
        }
        for key in ("rate_hz", "filter_hz", "tare_on_start"):
            if key in section:
                config[key] = section[key]
        target, self._gate_opened_by = _loop_sink(sink)
        self._reader = _rtcore.ForceReader(config, target)
        if target is not None and self._gate_opened_by is None:
            self._reader.open_gate()
        elif self._gate_opened_by is not None:
            self._gate_opened_by(self._reader.open_gate)
        self.events = EventLog()
        self._stale_after_s = 0.2

    @classmethod
    def from_config(cls, section: Mapping[str, Any], sink: Any, *, rt_priority: int = 0) -> NativeForceReader:
        device = rust_transport(section)
        if device is None:
            raise ConfigError(f"the Rust reader cannot read kind = {section.get('kind')!r} "
                              f"interface = {section.get('interface')!r}")
        return cls(device, section, sink, rt_priority=rt_priority)

    # -- lifecycle -------------------------------------------------------------------------------

    def start(self) -> None:
        self._reader.start()

    def stop(self) -> None:
        self._reader.stop()
        self._drain_events()

    @property
    def running(self) -> bool:
        return self._reader.running

    @property
    def reader_path(self) -> str:
        return self._reader.path

    def describe(self) -> str:
        return self._reader.describe()

    def __enter__(self) -> NativeForceReader:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def stale_after_s(self) -> float:
        return self._stale_after_s

    @stale_after_s.setter
    def stale_after_s(self, seconds: float) -> None:
        self._reader.set_stale_after(float(seconds))
        self._stale_after_s = float(seconds)

    def set_event_hook(self, hook: Callable[[str, str], None] | None, repeat_s: float = EVENT_REPEAT_S) -> None:
        counts = self.events.counts
        self.events = EventLog(hook, repeat_s)
        self.events.counts = counts

    def _drain_events(self) -> None:
        for kind, message in self._reader.take_events():
            self.events(kind, message)

    # -- bias and tare ---------------------------------------------------------------------------

    @property
    def bias(self) -> tuple[float, ...]:
        return tuple(self._reader.bias)

    def set_bias(self, bias: Sequence[float]) -> None:
        values = [float(b) for b in bias]
        if len(values) != 6:
            raise ConfigError(f"a bias has 6 finite values, got {bias!r}")
        self._reader.set_bias(values)

    def tare(self, n_samples: int = DEFAULT_TARE_SAMPLES, *, max_std: float | Sequence[float] = DEFAULT_TARE_MAX_STD,
             timeout: float = 2.0) -> TareResult:
        """The bias from the next ``n_samples`` raw samples, applied when the sensor was still."""
        if not self.running:
            raise DeviceError(f"cannot tare the {self.kind} sensor: it is not running")
        rows = self._reader.collect_raw(int(n_samples), float(timeout))
        if len(rows) < n_samples:
            return TareResult(False, None, (), len(rows), f"only {len(rows)} of {n_samples} samples arrived in {timeout:g} s")
        result = estimate_bias(rows, max_std=max_std)
        if result.accepted:
            self._reader.set_bias(list(result.bias))
        return result

    # -- counters ----------------------------------------------------------------------------------

    def stats(self) -> dict[str, Any]:
        """The Python readers' keys (kind, state, samples_pushed, ... events) plus the Rust
        reader's own (``reader``, ``max_gap_ns``, ``thread_policy``...). Tells queued events."""
        self._drain_events()
        return self._reader.stats() | {"kind": self.kind, "running": self.running,
                                       "events": dict(self.events.counts)}

    def take_captured(self) -> list[tuple[int, list[float]]]:
        return self._reader.take_captured()


def _loop_sink(sink: Any) -> tuple[Any, Callable[[Callable[[], None]], None] | None]:
    """(the loop's ForceSink or None, how to follow the daemon's gate or None)."""
    if sink is None:
        return None, None
    native = getattr(sink, "native_target", None)
    if callable(native):
        return native(), sink.on_open
    from admittance import _rtcore

    if isinstance(sink, _rtcore.ForceSink):
        return sink, None
    raise ConfigError("the Rust force reader pushes into the loop's ForceSink only "
                      "(use reader = \"python\" for other sinks)")
