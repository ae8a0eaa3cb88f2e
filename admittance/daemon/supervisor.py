"""The supervisor: bring the joint up in a safe order, serve it, and bring it down cleanly.

Start order, each step with its own clear error (a DeviceError/ConfigError becomes one stderr
line and a non-zero exit in the CLI; everything already started is undone in reverse). Every
resource is claimed before the first write to a servo, so a daemon that cannot have them all
fails without touching the joint:

0. ``Backends.claim_devices``: the exclusive claim of the ttys (backends.claim_devices);
1. the bench (only for ``[bus].port = "mock"``: the simulated bus and sensor on ptys);
2. the Zenoh session (its endpoint) and the views on it (ROS 2, Foxglove's port), then the
   recording folder, then the RT loop object (its configuration checked; no I/O yet), then
   the force sensor's device (it streams into a closed gate);
3. bus and servo checks with the Python SDK (ping, model, RDT 0, position mode, latency timer,
   torque on): the first write to a servo; then the SDK port is closed so the RT loop owns
   the tty alone;
4. the tare, while the joint holds still;
5. the RT loop starts, and only then is the sensor's stream let through to it (the gate), so
   the loop never acts on a sample taken before the tare;
6. the MCAP session file (it starts with the loop's parameters), the Zenoh queryables and
   liveliness token, then ``READY=1`` to systemd.

The main thread then ticks at ``[zenoh].state_rate_hz``: it drains the loop's telemetry
(recording every cycle, publishing the latest), answers params queries, publishes stats about
once a second and relays the loop's warnings. SIGINT/SIGTERM only set an event; the stop
itself (hold, then the torque policy) happens on the main thread, and exits 0.

Faults (docs/faults.md): the loop recovers servos and the bus by itself, the sensor's reader
its device; every ``FAULT_PERIOD_S`` the supervisor tells what changed, marks the sensor's
faults on the loop's cycles and, when the policy gives up (the loop's stop request, a sensor
gone too long), stops the same clean way and exits with the fault's status (69 or 75). The
systemd watchdog pings only while the loop cycles *and* is healthy (``FaultWatch.health``).

Everything it says goes through ``logging`` (``admittance.logs`` sets the handler up): the
start line, parameter changes and the one-line summary at stop at info, each warning once
(and at most a few a second from one source), the start order's steps and the status every
second at debug.

``--stats-json`` is written on every way out: a clean stop, and an error too (with an
``error`` field, the exit status, and whatever the loop had counted), before the error goes on
to the CLI's one line and non-zero status.

Every dependency on another part of the project comes in through :class:`Backends`, so the
whole sequence is unit-tested with fakes and run for real by the HIL tests.
"""

from __future__ import annotations

import contextlib
import json
import logging
import time
from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Any, NamedTuple

from admittance.daemon import endpoints, interpreter, telemetry
from admittance.daemon.config import DaemonConfig, record_dir
from admittance.daemon.ecosystem import Ecosystem
from admittance.daemon.faults import FaultWatch
from admittance.daemon.liveparams import LiveParams
from admittance.daemon.messages import Codec, stats_message
from admittance.daemon.notify import Notifier, Watchdog
from admittance.daemon.quantities import NAMES, bus_errors_text
from admittance.daemon.recording import Recorder
from admittance.formats.recording import gap_seconds
from admittance.daemon.schema import clip
from admittance.daemon.stopsignals import StopRequest, stop_signals_call
from admittance.errors import EXIT_TEMPFAIL, AdmittanceError, DeviceError, FaultStop
from admittance.logs import RateLimitedLog

if TYPE_CHECKING:
    import numpy as np

    from admittance._rtcore import AdmittanceLoop, ForceSink, MockBus
    from admittance.daemon.messages import State
    from admittance.daemon.zenoh_iface import DaemonInterface
    from admittance.drivers.force_reader import ForceStream

STATS_PERIOD_S = 1.0
FAULT_PERIOD_S = 0.1  # faults told, sensor marks set and stops judged this often
TARE_MIN_RATE_HZ = 30.0
WARNING_BURST = 5  # distinct warnings from one source (the loop, the bench) per 10 s, then held back
PARAMS_LOG_BURST = 10  # "params set" lines per 10 s; a flood of sets is then counted, not logged each
# A drained backlog is recorded this many cycles at a time, with the pending queries answered in
# between: a main thread starved by a loaded machine drains up to the telemetry ring's 65 s of
# cycles at once (~0.1 ms of CPU each), and a query must not wait behind all of them.
DRAIN_CHUNK_CYCLES = 100
STALL_MS = 0.25  # the simulated bus thread's stall threshold (rtcore/dxlsim/src/server.rs, STALL)

log = logging.getLogger(__name__)


@dataclass
class RunOptions:
    duration: float | None = None
    stats_json: Path | None = None
    # Set to stop the run (the CLI's own SIGINT/SIGTERM handler sets it; see stopsignals). Anything
    # with set/is_set/wait; a StopRequest because signal handlers set it (a threading.Event can deadlock).
    stop: StopRequest = field(default_factory=StopRequest)
    # Called once everything is open, just before the loop starts (its full collection then
    # delays nothing live): `admittance run` settles its interpreter there
    # (admittance.daemon.interpreter); process-wide, so never by default.
    before_loop: Callable[[], None] | None = None


class BenchPorts(NamedTuple):
    """What ``Backends.start_bench`` yields: the devices' ports, and the simulated bench's parts."""

    bus: str
    sensor: str
    start_hand: Callable[[], None]  # called once the loop runs (a no-op on real hardware)
    stats: Callable[[], dict[str, Any]] | None = None  # the simulated bench's counters (None on hardware)
    # The embedded bench's servos: the loop reaches them in-process, not through the pty
    # (which the start-up checks use), so the simulation answers on the wire model's time.
    simulated_bus: MockBus | None = None


@dataclass
class Backends:
    """Factories for the other parts of the project (the real ones are in admittance.daemon.backends)."""

    start_bench: Callable[[DaemonConfig], AbstractContextManager[BenchPorts]]
    check_servos: Callable[[DaemonConfig, str], list[str]]  # -> warnings
    release_servos: Callable[[DaemonConfig, str], None]  # torque off (failed start, torque_off policy)
    make_sensor: Callable[[DaemonConfig, str, GatedSink], ForceStream]  # (cfg, port, sink)
    make_loop: Callable[[DaemonConfig, str], AdmittanceLoop]  # (cfg, bus_port)
    make_interface: Callable[..., DaemonInterface] | None  # (zenoh cfg, codec, handler)
    # -> context manager holding the devices (ttys) for the whole run: step 0 of the start order
    claim_devices: Callable[[DaemonConfig], AbstractContextManager[object]] = lambda cfg: contextlib.nullcontext()


class GatedSink:
    """Drops samples until opened, then forwards them to the loop's sink.

    The sensor streams from the moment it is opened (the tare needs samples), but the loop
    must only see tared samples taken after it started.
    """

    def __init__(self, target: ForceSink) -> None:
        self._target = target
        self._push: Callable[[int, Sequence[float]], bool] | None = None
        self._on_open: list[Callable[[], None]] = []
        self.dropped_before_open = 0

    def open(self) -> None:
        self._push = self._target.push
        for opened in self._on_open:
            opened()

    def native_target(self) -> ForceSink:
        """The loop's own sink, for a Rust reader that pushes past Python; it keeps its own
        gate and opens it with this one (``on_open``)."""
        return self._target

    def on_open(self, opened: Callable[[], None]) -> None:
        self._on_open.append(opened)

    def push(self, t_ns: int, forces: Sequence[float]) -> bool:
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
        self.loop: AdmittanceLoop | None = None
        self.sensor: ForceStream | None = None
        self.interface: DaemonInterface | None = None
        self.recorder: Recorder | None = None
        self.ecosystem = Ecosystem()  # session.mcap, ROS 2 bridge, Foxglove view: all optional
        self.final_stats: dict[str, Any] | None = None
        self.live = LiveParams(cfg)
        self._codec = Codec(cfg.zenoh.encoding)
        self.rendering = telemetry.RenderingError(cfg)
        self._t0 = 0.0
        self._warned: set[str] = set()
        self._warn_limit = RateLimitedLog(log, burst=WARNING_BURST)
        self._params_log = RateLimitedLog(log, burst=PARAMS_LOG_BURST)
        self.watchdog: Watchdog | None = None
        self.faults = FaultWatch(cfg, self._event)
        self.fault_stop: FaultStop | None = None
        self._healthy = True
        self._bench_stats: Callable[[], dict[str, Any]] | None = None  # the simulated bench's, if any
        self._simulated_bus: MockBus | None = None  # the embedded bench's servos, reached in-process
        self._after_batch: list[Callable[[], object]] | None = None  # while a drained batch is recorded

    # -- lifecycle ---------------------------------------------------------------------------

    def run(self) -> int:
        """Start, serve until stopped, stop; 0 after a clean stop. Every way out writes
        ``--stats-json`` (an error with its ``error`` field) before the error propagates."""
        try:
            with stop_signals_call(self.request_stop), contextlib.ExitStack() as stack:
                self._start(stack)
                self._serve()
                self._note_unexpected_signal()
                self._stop()
            if self.fault_stop is not None:
                raise self.fault_stop  # after the same clean stop: its exit status
        except BaseException as exc:
            self._write_stats(error=exc)
            raise
        self._write_stats()
        return 0

    def request_stop(self, signum: int | None = None, _frame: FrameType | None = None) -> None:
        self.stop_event.set(signum)

    def _made_loop(self) -> AdmittanceLoop:
        """The RT loop, which ``_start`` makes before any step that uses it."""
        if self.loop is None:
            raise RuntimeError("the RT loop is not made yet")
        return self.loop

    def _opened_sensor(self) -> ForceStream:
        """The force sensor, which ``_start`` opens before any step that uses it."""
        if self.sensor is None:
            raise RuntimeError("the force sensor is not open yet")
        return self.sensor

    def _note_unexpected_signal(self) -> None:
        """A stop by SIGHUP or SIGUSR1/2 is clean, but nobody asked for it: exit 75, so that
        systemd restarts a service that a stray signal stopped (stopsignals.py)."""
        name = getattr(self.stop_event, "unexpected", lambda: None)()
        if name is not None and self.fault_stop is None:
            self.fault_stop = FaultStop(f"stopped by {name}, which is not a stop signal (SIGINT, SIGTERM): "
                                        f"a clean stop, exit {EXIT_TEMPFAIL} so that systemd restarts it",
                                        EXIT_TEMPFAIL, f"signal_{name.lower()}")
            self._event(str(self.fault_stop))

    def _start(self, stack: contextlib.ExitStack) -> None:
        self._step("starting: devices")
        stack.enter_context(self.backends.claim_devices(self.cfg))  # before any device is opened
        # BenchPorts(*...): a fake bench (tests, bench/loop_timing.py) may yield its first fields as a tuple.
        ports = BenchPorts(*stack.enter_context(self.backends.start_bench(self.cfg)))
        bus_port, sensor_port, start_hand = ports.bus, ports.sensor, ports.start_hand
        self._bench_stats, self._simulated_bus = ports.stats, ports.simulated_bus
        for warning in endpoints.exposure_warnings(self.cfg.zenoh):
            self._warn(warning)
        self._open_interface(stack)
        self._open_recorder(stack)
        self.loop = self.backends.make_loop(self.cfg, bus_port)
        gate = GatedSink(self.loop.force_sink())
        self._open_sensor(stack, sensor_port, gate)
        self._step("starting: bus")
        self._check_servos(stack, bus_port)  # the first write to a servo
        self._tare()
        if self.options.before_loop is not None:
            self.options.before_loop()
        self._start_loop(stack, bus_port)
        gate.open()
        # The simulated hand's delay counts from the loop's start (the recording's t = 0), not
        # from the end of the slower steps below: on a loaded machine those took seconds, and a
        # recording's first seconds were then still (the wheel smoke's fidelity step).
        start_hand()
        self._start_mcap(stack)
        if self.interface is not None:
            self.interface.serve()
        self.watchdog = Watchdog(self.notifier, self.loop.heartbeat, healthy=lambda: self._healthy)
        status = self._status_line()
        self.notifier.ready(status)
        z = self.cfg.zenoh
        where = getattr(self.interface, "where", None)
        log.info("%s; zenoh %s/* %s; stop with Ctrl-C or SIGTERM", status, z.prefix,
                 where() if where is not None else "on " + (", ".join(z.listen) or "zenoh defaults"))

    def _step(self, text: str) -> None:
        """A start-order step: systemd's STATUS, and a debug line."""
        self.notifier.status(text)
        log.debug("%s", text)

    def _check_servos(self, stack: contextlib.ExitStack, bus_port: str) -> None:
        for warning in self.backends.check_servos(self.cfg, bus_port):
            self._warn(warning)
        if self.cfg.stop.torque_policy == "torque_off":
            stack.callback(self._release_unless_loop_ran, bus_port)

    def _open_sensor(self, stack: contextlib.ExitStack, port: str, sink: GatedSink) -> None:
        """Open the sensor's device; it streams into the closed gate until the loop runs."""
        self._step("starting: sensor")
        self.sensor = self.backends.make_sensor(self.cfg, port, sink)
        # Its events (unplugged, back, stale, saturated) are told and marked by the fault watch;
        # it calls a silence "stale" at the loop's own threshold.
        self.sensor.set_event_hook(self.faults.sensor_event)
        self.sensor.stale_after_s = self.cfg.loop.stale_timeout_ms / 1000.0
        self.sensor.start()
        stack.callback(self.sensor.stop)

    def _start_loop(self, stack: contextlib.ExitStack, bus_port: str) -> None:
        self._step("starting: loop")
        self._t0 = time.monotonic()  # the recording's t = 0: the loop's first cycle follows
        if self.recorder is not None:
            self.recorder.t0 = self._t0
            self._record(lambda recorder: recorder.set_targets(self._made_loop().params()))  # what the first segment runs
        try:
            if self._simulated_bus is not None:
                self._made_loop().start(simulated_bus=self._simulated_bus)
            else:
                self._made_loop().start()
        except (OSError, RuntimeError, ValueError) as exc:  # the port, the servos' first read, threads
            raise DeviceError(f"RT loop: cannot start on {bus_port}: {exc}") from None
        stack.callback(self._stop_loop)

    def _tare(self) -> None:
        self._step("starting: tare")
        n = self.cfg.sensor.tare_samples
        if n == 0:
            return
        # The daemon does not set the DAQ's rate, so the sensor may stream as slowly as 30 Hz
        # (OptoForce's slower settings); a start-up tare is not time-critical, so wait for that.
        result = self._opened_sensor().tare(n, timeout=max(5.0, n / TARE_MIN_RATE_HZ))
        if not result.accepted:
            raise DeviceError(f"sensor: tare refused: {result.reason}")

    def _open_recorder(self, stack: contextlib.ExitStack) -> None:
        """Create the recording folder and its files (t = 0 is set when the loop starts)."""
        folder = record_dir(self.cfg)
        if folder is None:
            return
        joints = [(j.id, j.model) for j in self.cfg.joints]
        lp = self.cfg.loop
        self.recorder = Recorder(folder, joints, measured_theta=lp.sync_read_divisor > 0, t0=0.0,
                                 segment_s=self.cfg.record.segment_s, joint_info=self.joint_info(),
                                 gap_s=gap_seconds(lp.rate_hz, lp.sync_read_divisor), period_s=1.0 / lp.rate_hz)
        stack.callback(self._record, lambda recorder: recorder.close())

    def _record(self, write: Callable[[Recorder], object]) -> None:
        """One write to the CSV recording. A write that fails (a full disk) stops the recording
        with one line; what was written stays readable, and the loop runs on."""
        if self.recorder is None or self.recorder.stopped:
            return
        try:
            write(self.recorder)
        except OSError as exc:
            self.recorder.abort()
            self._event(f"recording stopped: cannot write into {self.recorder.folder} ({exc.strerror or exc}); "
                        "what was written stays readable (each CSV ends at its last whole row); the loop runs on")

    def joint_info(self) -> dict[int, dict]:
        """What a recording needs to be judged later (`admittance fidelity`): each joint's plant
        and servo model, and the loop's timing (the manifest's [[joints]], the MCAP's /session)."""
        info = {}
        for j in self.cfg.joints:
            plant = j.plant or {}
            entry = {"model": j.model, "params_file": j.params, "rate_hz": self.cfg.loop.rate_hz,
                     "sync_read_divisor": self.cfg.loop.sync_read_divisor,
                     "friction": str(plant.get("model", {}).get("friction", "stick")),
                     "plant": dict(plant.get("params", {}))}
            if "servo" in plant:
                entry["servo"] = dict(plant["servo"])
            info[j.id] = entry
        return info

    def _start_mcap(self, stack: contextlib.ExitStack) -> None:
        """The MCAP session file beside the recording: it starts with the loop's first parameters
        and its t = 0, so it opens once the loop runs (the folder itself was claimed before)."""
        folder = record_dir(self.cfg)
        if folder is not None:
            self.ecosystem.start_mcap(stack, folder, self.cfg, self._t0, self.get_params(), self.joint_info())

    def _open_interface(self, stack: contextlib.ExitStack) -> None:
        """Open the Zenoh session (claims the endpoint); it serves queries once the loop runs."""
        if self.backends.make_interface is None:
            return
        self._step("starting: zenoh")
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
        self.final_stats = self._made_loop().stats()
        try:
            self._made_loop().stop(torque_policy=self.cfg.stop.torque_policy)
        except DeviceError as exc:
            if self.fault_stop is None:
                raise
            self._event(f"{exc} (the fault's stop goes on)")  # a torque off the lost bus cannot carry
        self.final_stats = self._made_loop().stats() or self.final_stats  # final counts, if still reported
        self._drain()
        self.final_stats = {**self.final_stats, "rendering_rms": self.rendering.by_joint(),
                            "bench": self.bench_report()}
        log.info("%s", summary_line(self.final_stats, self.cfg.stop.torque_policy))

    def bench_report(self) -> dict[str, Any]:
        """The stats' ``bench``: whether the bus and the sensor are simulated and, on the simulated
        bench, its own counters (the bus thread's lateness and scheduling, the sensor's)."""
        bench_stats = self._bench_stats
        simulated = bench_stats is not None
        report: dict[str, Any] = {"simulated": simulated,
                                  "simulated_sensor": simulated or self.cfg.sensor.kind == "mock"}
        if bench_stats is not None:
            try:
                report.update(bench_stats())
            except Exception as exc:  # the bench's counters must not cost the run its stats
                report["error"] = clip(f"{type(exc).__name__}: {exc}", 200)
        return report

    # -- the main thread's tick --------------------------------------------------------------

    def _serve(self) -> None:
        period = 1.0 / self.cfg.zenoh.state_rate_hz
        deadline = None if self.options.duration is None else self._t0 + self.options.duration
        next_tick = next_stats = next_faults = time.monotonic()
        while not self.stop_event.is_set():
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                break
            if now >= next_faults:  # first: the watchdog's first ping already knows the health
                self._watch_faults()
                next_faults = now + FAULT_PERIOD_S
                if self.fault_stop is not None:
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
        if self.watchdog is not None:  # made by _start, before the first tick
            self.watchdog.poll()
        latest = self._drain(between_chunks=self._serve_between_chunks)
        if self.interface is not None:
            if latest is not None:
                self.interface.publish_state(latest)
            self.interface.poll()
            getattr(self.interface, "watch_link", lambda: None)()  # a client's router coming or going
        for warning in self.ecosystem.publish(latest):
            self._warn(warning)

    def _watch_faults(self) -> None:
        """Tell the faults since the last look, mark the sensor's, judge health and the stop."""
        stats, sensor = self._made_loop().stats(), self._opened_sensor().stats()
        stop = self.faults.poll(stats, sensor, self.loop)
        self._healthy = self.faults.health(stats, sensor, self.loop)
        if stop is not None:
            self.fault_stop = stop
            self._event(f"stopping on a fault: {stop} (exit {stop.exit_code})")

    def _drain(self, between_chunks: Callable[[np.ndarray], object] | None = None) -> State | None:
        """Drain the loop's telemetry into the recorder, DRAIN_CHUNK_CYCLES at a time with
        ``between_chunks(the chunk recorded)`` called in between; return the latest State message."""
        records = self._made_loop().drain_telemetry()
        if len(records) == 0:
            return None
        step = DRAIN_CHUNK_CYCLES * len(self.cfg.joints)
        self._after_batch = []
        try:
            for start in range(0, len(records), step):
                if start and between_chunks is not None:
                    between_chunks(records[start - step:start])
                self._record_cycles(records[start:start + step])
        finally:
            actions, self._after_batch = self._after_batch, None
            for action in actions:
                action()
        return telemetry.latest_state(records, self.cfg, self.rendering)

    def _record_cycles(self, records: np.ndarray) -> None:
        self.rendering.update(records)
        if self.recorder is not None:
            by_joint = telemetry.columns_by_joint(records, self.cfg)
            self._record(lambda recorder: recorder.append_all(by_joint))
            self.ecosystem.record_cycles(by_joint)  # on, whatever became of the CSVs

    def _serve_between_chunks(self, recorded: np.ndarray) -> None:
        """In a backlog: the state of the cycles just recorded, and the pending queries answered."""
        if self.interface is not None:
            self.interface.publish_state(telemetry.latest_state(recorded, self.cfg, self.rendering))
            self.interface.poll()

    def _after_recorded(self, action: Callable[[], object]) -> None:
        """``action`` now, or, for a query answered in the middle of a drained batch, once the
        batch is recorded: the recording then shows the set after every cycle that ran before it."""
        if self._after_batch is None:
            action()
        else:
            self._after_batch.append(action)

    def _publish_stats(self) -> None:
        for warning in self._made_loop().warnings():
            self._warn(warning, source="loop")
        for warning in self._bench_warnings():
            self._warn(warning, source="bench")
        if not self._made_loop().running():
            raise DeviceError("the RT loop thread ended on its own (see the warnings above); stopping")
        stats = {**self._made_loop().stats(), "rendering_rms": self.rendering.by_joint()}
        self._step(f"{self._status_line(stats)}: {stats['cycles']} cycles, {stats['overruns']} overruns, "
                   f"{stats['sensor_stale_events']} {NAMES['sensor_stale_events']}")
        if self.interface is not None:
            self.interface.publish_stats(stats_message({**stats, "daemon": self._query_counts()}))
        self.ecosystem.record("stats", stats)

    def _query_counts(self) -> dict[str, Any]:
        """The queries answered, those a handler failed, and the longest the queryables went unpolled."""
        return {name: getattr(self.interface, name, 0) for name in ("queries", "query_errors", "longest_poll_gap_s")}

    def _bench_warnings(self) -> list[str]:
        """What the simulated bench could not get (its bus thread's SCHED_FIFO), like the loop's."""
        if self._bench_stats is None:
            return []
        with contextlib.suppress(Exception):
            return list(self._bench_stats().get("bus", {}).get("timing", {}).get("warnings", []))
        return []

    def _warn(self, text: str, source: str = "daemon") -> None:
        """Each warning once; at most WARNING_BURST distinct ones per source per 10 s."""
        if text not in self._warned:
            self._warned.add(text)
            self._warn_limit(source, text)
            self.ecosystem.record("event", f"warning: {text}")

    def _event(self, text: str) -> None:
        """A warning each time it happens (the fault watch rate-limits its own, per kind)."""
        log.warning("%s", text)
        self.ecosystem.record("event", f"warning: {text}")

    # -- the Zenoh handler: parameters and tare (called from the main thread's poll) ---------

    def get_params(self) -> dict[str, float | list[float]]:
        return telemetry.params_values(self._made_loop().params())

    def set_params(self, request: dict[str, object]) -> tuple[bool, str]:
        """Check a live set as the configuration would be checked (liveparams), then hand it to
        the loop, whose own gate checks it again; all or nothing."""
        try:
            request = self.live.check(request, self.get_params())
        except AdmittanceError as exc:
            return False, str(exc)
        accepted, reason = self._made_loop().set_params(request)
        if accepted:
            who = getattr(self.interface, "requester", None)  # set while a Zenoh query is answered
            self._params_log("params", f"params set{' by ' + who if who else ''}: "
                                       f"{clip(json.dumps(request, sort_keys=True), 400)}", logging.INFO)
            adopted, values = self._made_loop().params(), self.get_params()
            self._after_recorded(lambda: self._record(lambda recorder: recorder.set_targets(adopted)))
            self._after_recorded(lambda: self.ecosystem.record("params", values, request))
        return accepted, reason

    def tare(self, samples: int) -> tuple[bool, str]:
        """Re-zero the force on the loop's side: the next ``samples`` samples become the bias."""
        self._made_loop().tare(samples)
        log.info("tare requested over the next %d samples", samples)
        self._after_recorded(lambda: self.ecosystem.record("event", f"tare over the next {samples} samples"))
        return True, ""

    # -- exit ----------------------------------------------------------------------------------

    def _status_line(self, stats: dict[str, Any] | None = None) -> str:
        stats = stats or self._made_loop().stats()
        rt = stats.get("rt", {})
        joints = ", ".join(f"{j.model}#{j.id}" for j in self.cfg.joints)
        reader = getattr(self.sensor, "reader_path", None)
        sensor = f"; sensor reader {reader}" if reader else ""
        read = stats.get("bus", {}).get("read")
        bus = f"; bus read {read}" if read else ""
        return f"running {joints} at {self.cfg.loop.rate_hz:g} Hz ({rt.get('policy', '?')}){bus}{sensor}"

    def _write_stats(self, error: BaseException | None = None) -> None:
        """``--stats-json``: the loop's final counts and the daemon's own, plus, after an error,
        ``error`` (its one line) and ``exit_status``. After an error what is known is written
        (possibly no loop counts at all), and a failure to write is logged, not raised over it."""
        path = self.options.stats_json
        if path is None:
            return
        stats = dict(self.final_stats or {})
        if error is None and not stats:
            return
        if stats:  # the loop ran: its rendering error and the bench too, on an error's way out as well
            stats.setdefault("rendering_rms", self.rendering.by_joint())
            stats.setdefault("bench", self.bench_report())
        stats["daemon"] = {
            **self._query_counts(),
            "recorded_rows": dict(self.recorder.rows) if self.recorder else {},
            "sensor": self.sensor.stats() if self.sensor is not None else {},
            "faults_told": dict(self.faults.events.counts),
            "watchdog": {"pings": getattr(self.watchdog, "pings", 0), "missed": getattr(self.watchdog, "missed", 0),
                         "unhealthy": getattr(self.watchdog, "unhealthy", 0)},
            "interpreter": interpreter.report(),
        }
        if self.fault_stop is not None:
            stats["fault_stop"] = {"cause": self.fault_stop.cause, "exit_status": self.fault_stop.exit_code}
        if error is not None:
            stats.update(error_fields(error))
        try:
            write_stats_file(path, stats)
        except DeviceError as exc:
            if error is None:
                raise
            log.warning("%s", exc)


def summary_line(stats: dict[str, Any], policy: str) -> str:
    """What a user wants to see at the end of a run: how many cycles, how well timed, which bus
    errors, and on the simulated bench where they came from: the loop's own lateness (the
    embedded bench's in-process link), or the simulation's thread being late on its pty (which a
    real bus would not be)."""
    period = stats.get("period_us", {})
    bench = stats.get("bench", {})
    where = " on the simulated bench" if bench.get("simulated") else (
        " with a simulated sensor" if bench.get("simulated_sensor") else "")
    line = (f"stopped ({policy}) after {stats.get('cycles', 0)} cycles{where}: "
            f"{stats.get('overruns', 0)} overruns, {bus_errors_text(stats)}, "
            f"{stats.get('sensor_stale_events', 0)} {NAMES['sensor_stale_events']}; "
            f"{NAMES['period_us']} p99 {period.get('p99', float('nan')):.0f} µs")
    if bench.get("simulated") and stats.get("bus_errors", 0):
        if stats.get("bus", {}).get("link") == "in-process":
            line += ("; the loop reaches the simulated servos in-process, on the wire's own time: a reply "
                     "misses its read only when the loop itself is late, as on hardware")
        else:
            line += "; " + bench_lateness_text(bench.get("bus", {}).get("timing", {}))
    return line


def bench_lateness_text(timing: dict[str, Any]) -> str:
    """Whether the simulated bus's own thread was late, by its own counters."""
    if not timing:
        return "the simulated bus reported no timing"
    rt = timing.get("rt", {})
    thread = f"the simulated bus's thread ({rt.get('policy', '?')} {rt.get('priority', 0)})"
    stalls = timing.get("stalls", 0)
    if not stalls:
        return f"{thread} was never more than {STALL_MS:g} ms late: these errors are not the simulation's lateness"
    longest = max(timing.get("reply_late_us", {}).get("max", 0.0), timing.get("wake_late_us", {}).get("max", 0.0))
    # Late even at SCHED_FIFO: on a pty, poll and read wait for the kernel's tty worker (a
    # SCHED_OTHER kworker) to hand the bytes over, and a loaded machine starves that worker.
    return (f"{thread} ran late {stalls} times (> {STALL_MS:g} ms, longest {longest / 1e3:.1f} ms): "
            "the simulation answered late through its pseudo-terminals (their kernel worker is not "
            "real-time, and any load delays it), which a real servo would not")


def error_fields(error: BaseException) -> dict[str, Any]:
    """What a stats file says about the error that ended the run: its line and the exit status."""
    if isinstance(error, AdmittanceError):
        return {"error": str(error), "exit_status": error.exit_code}
    if isinstance(error, KeyboardInterrupt):
        return {"error": "interrupted", "exit_status": 130}
    return {"error": f"internal error: {type(error).__name__}: {clip(str(error), 200)}", "exit_status": 1}


def write_stats_file(path: Path, stats: dict[str, Any]) -> None:
    """Write ``stats`` as JSON, whole or not at all (a reader never sees half a file)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        tmp.write_text(json.dumps(stats, indent=2, default=str) + "\n")
        tmp.replace(path)
    except OSError as exc:
        raise DeviceError(f"--stats-json: cannot write {path} ({exc.strerror})") from None
