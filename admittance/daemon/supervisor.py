"""The supervisor: bring the joint up in a safe order, serve it, and bring it down cleanly.

Start order, each step with its own clear error (a DeviceError/ConfigError becomes one stderr
line and a non-zero exit in the CLI; everything already started is undone in reverse):

1. the bench (only for ``[bus].port = "mock"``: the simulated bus and sensor on ptys);
2. bus and servo checks with the Python SDK (ping, model, RDT 0, position mode, latency timer,
   torque on), then the SDK port is closed so the RT loop owns the tty alone;
3. the force sensor: open, then tare while nothing moves yet;
4. the RT loop (``_rtcore.AdmittanceLoop``), and only then is the sensor's stream let through
   to it (a gate), so the loop never starts on samples taken before the tare;
5. the Zenoh interface, the recorder, and ``READY=1`` to systemd.

The main thread then ticks at ``[zenoh].state_rate_hz``: it drains the loop's telemetry
(recording every cycle, publishing the latest), answers params queries, publishes stats about
once a second and relays the loop's warnings. SIGINT/SIGTERM only set an event; the stop
itself (hold, then the torque policy) happens on the main thread, and exits 0.

Every dependency on another part of the project comes in through :class:`Backends`, so the
whole sequence is unit-tested with fakes and run for real by the HIL tests.
"""

from __future__ import annotations

import contextlib
import json
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from admittance.daemon import telemetry
from admittance.daemon.config import DaemonConfig, record_dir
from admittance.daemon.ecosystem import Ecosystem
from admittance.daemon.messages import Codec, stats_message
from admittance.daemon.notify import Notifier, Watchdog
from admittance.daemon.recording import Recorder
from admittance.daemon.stopsignals import stop_signals_call
from admittance.errors import DeviceError

STATS_PERIOD_S = 1.0
TARE_MIN_RATE_HZ = 30.0


@dataclass
class RunOptions:
    duration: float | None = None
    stats_json: Path | None = None
    log: Callable[[str], None] = field(default=lambda line: print(f"admittance run: {line}", file=sys.stderr))
    # Set to stop the run (the CLI's own SIGINT/SIGTERM handler sets it; see stopsignals).
    stop: threading.Event = field(default_factory=threading.Event)


@dataclass
class Backends:
    """Factories for the other parts of the project (the real ones are in admittance.daemon.backends)."""

    start_bench: Callable[[DaemonConfig], Any]  # -> context manager of (bus, sensor, start_hand)
    check_servos: Callable[[DaemonConfig, str], list[str]]  # -> warnings
    release_servos: Callable[[DaemonConfig, str], None]  # torque off (failed start, torque_off policy)
    make_sensor: Callable[[DaemonConfig, str, Any], Any]  # (cfg, port, sink) -> ForceSensor
    make_loop: Callable[[DaemonConfig, str], Any]  # (cfg, bus_port) -> AdmittanceLoop
    make_interface: Callable[..., Any] | None  # (zenoh cfg, codec, handler) -> DaemonInterface
    claim_devices: Callable[[DaemonConfig], Any] = lambda cfg: contextlib.nullcontext()  # -> context manager held for the run


class GatedSink:
    """Drops samples until opened, then forwards them to the loop's sink.

    The sensor streams from the moment it is opened (the tare needs samples), but the loop
    must only see tared samples taken after it started.
    """

    def __init__(self, target: Any) -> None:
        self._target = target
        self._push = None
        self.dropped_before_open = 0

    def open(self) -> None:
        self._push = self._target.push

    def push(self, t_ns: int, forces) -> bool:
        push = self._push
        if push is None:
            self.dropped_before_open += 1
            return True  # consumed on purpose, not a full ring
        return push(t_ns, forces)


class Supervisor:
    def __init__(self, cfg: DaemonConfig, backends: Backends, options: RunOptions | None = None,
                 notifier: Notifier | None = None) -> None:
        self.cfg = cfg
        self.backends = backends
        self.options = options or RunOptions()
        self.notifier = notifier or Notifier()
        self.stop_event = self.options.stop
        self.loop: Any = None
        self.sensor: Any = None
        self.interface: Any = None
        self.recorder: Recorder | None = None
        self.ecosystem = Ecosystem()  # session.mcap, ROS 2 bridge, Foxglove view: all optional
        self.final_stats: dict[str, Any] | None = None
        self._codec = Codec(cfg.zenoh.encoding)
        self._t0 = 0.0
        self._warned: set[str] = set()
        self.watchdog: Watchdog | None = None

    # -- lifecycle ---------------------------------------------------------------------------

    def run(self) -> int:
        with stop_signals_call(self.request_stop), contextlib.ExitStack() as stack:
            self._start(stack)
            self._serve()
            self._stop()
        self._write_stats()
        return 0

    def request_stop(self, *_args: Any) -> None:
        self.stop_event.set()

    def _start(self, stack: contextlib.ExitStack) -> None:
        stack.enter_context(self.backends.claim_devices(self.cfg))  # before any device is opened
        self.notifier.status("starting: bus")
        ports = stack.enter_context(self.backends.start_bench(self.cfg))
        bus_port, sensor_port, start_hand = ports
        self._check_servos(stack, bus_port)
        self.loop = self.backends.make_loop(self.cfg, bus_port)
        gate = GatedSink(self.loop.force_sink())
        self._start_sensor(stack, sensor_port, gate)
        self._start_loop(stack, bus_port)
        gate.open()
        self._start_recorder(stack)
        self._start_interface(stack)
        self.watchdog = Watchdog(self.notifier, self.loop.heartbeat)
        status = self._status_line()
        self.notifier.ready(status)
        z = self.cfg.zenoh
        self.options.log(f"{status}; zenoh {z.prefix}/* on {', '.join(z.listen) or 'zenoh defaults'}; "
                         "stop with Ctrl-C or SIGTERM")
        start_hand()

    def _check_servos(self, stack: contextlib.ExitStack, bus_port: str) -> None:
        for warning in self.backends.check_servos(self.cfg, bus_port):
            self._warn(warning)
        if self.cfg.stop.torque_policy == "torque_off":
            stack.callback(self._release_unless_loop_ran, bus_port)

    def _start_sensor(self, stack: contextlib.ExitStack, port: str, sink: GatedSink) -> None:
        self.notifier.status("starting: sensor")
        self.sensor = self.backends.make_sensor(self.cfg, port, sink)
        self.sensor.start()
        stack.callback(self.sensor.stop)
        self._tare()

    def _start_loop(self, stack: contextlib.ExitStack, bus_port: str) -> None:
        self.notifier.status("starting: loop")
        self._t0 = time.monotonic()  # the recording's t = 0: the loop's first cycle follows
        try:
            self.loop.start()
        except (OSError, RuntimeError, ValueError) as exc:  # the port, the servos' first read, threads
            raise DeviceError(f"RT loop: cannot start on {bus_port}: {exc}") from None
        stack.callback(self._stop_loop)

    def _tare(self) -> None:
        n = self.cfg.sensor.tare_samples
        if n == 0:
            return
        # The daemon does not set the DAQ's rate, so the sensor may stream as slowly as 30 Hz
        # (OptoForce's slower settings); a start-up tare is not time-critical, so wait for that.
        result = self.sensor.tare(n, timeout=max(5.0, n / TARE_MIN_RATE_HZ))
        if not result.accepted:
            raise DeviceError(f"sensor: tare refused: {result.reason}")

    def _start_recorder(self, stack: contextlib.ExitStack) -> None:
        folder = record_dir(self.cfg)
        if folder is None:
            return
        joints = [(j.id, j.model) for j in self.cfg.joints]
        self.recorder = Recorder(folder, joints, measured_theta=self.cfg.loop.sync_read_divisor > 0,
                                 t0=self._t0, segment_s=self.cfg.record.segment_s)
        stack.callback(self.recorder.close)
        self.ecosystem.start_mcap(stack, folder, self.cfg, self._t0, self.get_params())

    def _start_interface(self, stack: contextlib.ExitStack) -> None:
        if self.backends.make_interface is None:
            return
        self.interface = self.backends.make_interface(self.cfg.zenoh, self._codec, self)
        stack.callback(self.interface.close)
        self.ecosystem.start_views(stack, self.cfg, self.interface)

    def _release_unless_loop_ran(self, bus_port: str) -> None:
        """A start that failed after torque-on: the loop cannot apply the policy, so do it here."""
        if self.final_stats is None:
            self.backends.release_servos(self.cfg, bus_port)

    def _stop_loop(self) -> None:
        """Undo path for a failed start or an exception: hold, apply the policy, keep the stats."""
        if self.loop is not None and self.final_stats is None:
            self.final_stats = self.loop.stats()
            self.loop.stop(torque_policy=self.cfg.stop.torque_policy)

    def _stop(self) -> None:
        self.notifier.stopping(f"stopping: {self.cfg.stop.torque_policy}")
        self._drain()
        self.final_stats = self.loop.stats()
        self.loop.stop(torque_policy=self.cfg.stop.torque_policy)
        self.final_stats = self.loop.stats() or self.final_stats  # final counts, if still reported
        self._drain()
        self.options.log(self._summary_line(self.final_stats))

    def _summary_line(self, stats: dict[str, Any]) -> str:
        """What a user wants to see at the end of a run: how many cycles, how well timed."""
        period = stats.get("period_us", {})
        return (f"stopped ({self.cfg.stop.torque_policy}) after {stats.get('cycles', 0)} cycles: "
                f"{stats.get('overruns', 0)} overruns, {stats.get('bus_errors', 0)} bus errors, "
                f"{stats.get('sensor_stale_events', 0)} stale-sensor events; "
                f"wake-up lateness p99 {period.get('p99', float('nan')):.0f} µs")

    # -- the main thread's tick --------------------------------------------------------------

    def _serve(self) -> None:
        period = 1.0 / self.cfg.zenoh.state_rate_hz
        deadline = None if self.options.duration is None else self._t0 + self.options.duration
        next_tick = next_stats = time.monotonic()
        while not self.stop_event.is_set():
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                break
            self._tick()
            if now >= next_stats:
                self._publish_stats()
                next_stats = now + STATS_PERIOD_S
            next_tick = max(next_tick + period, time.monotonic())
            wait = next_tick - time.monotonic()
            if deadline is not None:
                wait = min(wait, max(deadline - time.monotonic(), 0.0))
            self.stop_event.wait(max(wait, 0.0))

    def _tick(self) -> None:
        self.watchdog.poll()
        latest = self._drain()
        if self.interface is not None:
            if latest is not None:
                self.interface.publish_state(latest)
            self.interface.poll()
        for warning in self.ecosystem.publish(latest):
            self._warn(warning)
        if self.sensor.error:
            self._warn(f"force sensor stopped: {self.sensor.error} (the joints hold)")

    def _drain(self):
        """Drain the loop's telemetry into the recorder; return the latest State message."""
        records = self.loop.drain_telemetry()
        if len(records) == 0:
            return None
        if self.recorder is not None:
            by_joint = telemetry.columns_by_joint(records, self.cfg)
            for joint_id, columns in by_joint.items():
                self.recorder.append(joint_id, columns)
            self.ecosystem.record_cycles(by_joint)
        return telemetry.latest_state(records, self.cfg)

    def _publish_stats(self) -> None:
        for warning in self.loop.warnings():
            self._warn(warning)
        if not self.loop.running():
            raise DeviceError("the RT loop thread ended on its own (see the warnings above); stopping")
        stats = self.loop.stats()
        self.notifier.status(f"{self._status_line(stats)}: {stats['cycles']} cycles, {stats['overruns']} overruns, "
                             f"{stats['sensor_stale_events']} stale-sensor holds")
        if self.interface is not None:
            self.interface.publish_stats(stats_message(stats))
        self.ecosystem.record("stats", stats)

    def _warn(self, text: str) -> None:
        if text not in self._warned:
            self._warned.add(text)
            self.options.log(f"warning: {text}")
            self.ecosystem.record("event", f"warning: {text}")

    # -- the Zenoh handler: parameters and tare (called from the main thread's poll) ---------

    def get_params(self) -> dict[str, float | list[float]]:
        return telemetry.params_values(self.loop.params())

    def set_params(self, request: dict[str, float]) -> tuple[bool, str]:
        accepted, reason = self.loop.set_params(request)
        if accepted:
            self.options.log(f"params set: {json.dumps(request, sort_keys=True)}")
            self.ecosystem.record("params", self.get_params(), request)
        return accepted, reason

    def tare(self, samples: int) -> tuple[bool, str]:
        """Re-zero the force on the loop's side: the next ``samples`` samples become the bias."""
        self.loop.tare(samples)
        self.options.log(f"tare requested over the next {samples} samples")
        self.ecosystem.record("event", f"tare over the next {samples} samples")
        return True, ""

    # -- exit ----------------------------------------------------------------------------------

    def _status_line(self, stats: dict[str, Any] | None = None) -> str:
        rt = (stats or self.loop.stats()).get("rt", {})
        joints = ", ".join(f"{j.model}#{j.id}" for j in self.cfg.joints)
        return f"running {joints} at {self.cfg.loop.rate_hz:g} Hz ({rt.get('policy', '?')})"

    def _write_stats(self) -> None:
        path = self.options.stats_json
        if path is None or self.final_stats is None:
            return
        stats = dict(self.final_stats)
        stats["daemon"] = {
            "queries": getattr(self.interface, "queries", 0),
            "recorded_rows": dict(self.recorder.rows) if self.recorder else {},
            "sensor": self.sensor.stats() if self.sensor is not None else {},
        }
        try:
            Path(path).write_text(json.dumps(stats, indent=2, default=str) + "\n")
        except OSError as exc:
            raise DeviceError(f"--stats-json: cannot write {path} ({exc.strerror})") from None

