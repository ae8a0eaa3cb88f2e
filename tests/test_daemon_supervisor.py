"""The supervisor's start order, undo on failure, stop on signal or duration, and its outputs,
with fakes standing in for the bench, the servos, the sensor, the RT loop and Zenoh."""

from __future__ import annotations

import contextlib
import json
import logging
import os
import signal
import threading
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import tomli_w

from admittance.daemon import config
from admittance.daemon import supervisor as supervisor_module
from admittance.daemon.messages import STATS_KEYS, State
from admittance.daemon.supervisor import Backends, GatedSink, RunOptions, Supervisor
from admittance.errors import DeviceError

REPO = Path(__file__).resolve().parents[1]
RECORD_DTYPE = np.dtype([(name, "<u8" if name in ("cycle", "t_ns", "deadline_ns", "fault") else "<f8" if name in
                          ("force", "torque", "theta", "omega") else "<i8")
                         for name in ("cycle", "t_ns", "deadline_ns", "id", "force", "torque", "theta", "omega", "goal_tick",
                                      "present_tick", "period_error_ns", "latency_ns", "fault", "mode")])
PCT = {"p50": 1.0, "p99": 2.0, "p999": 3.0, "max": 4.0}


class FakeLoop:
    def __init__(self, events, ids):
        self.events, self.ids = events, ids
        self.cycle = 0
        self.stopped_with = None
        self.samples = []
        self.values = {"1.virtual_damping": 0.05}
        self.lifetime = None
        self.request = None  # the loop's stop request (a fault its policy gives up on)
        self.sensor_faults = []  # every set_sensor_faults call
        self.bus = {"state": "up", "lost_for_s": None, "losses": 0, "reconnects": 0, "read": "fast_sync_read"}
        self.servos = [{"id": jid, "phase": "ok", "hardware_error": 0, "last_error": 0, "errors": 0, "recoveries": 0}
                       for jid in ids]

    def force_sink(self):
        return SimpleNamespace(push=lambda t, f: self.samples.append((t, f)) or True)

    def start(self):
        self.events.append("loop.start")

    def drain_telemetry(self):
        n = 10
        rec = np.zeros(n * len(self.ids), RECORD_DTYPE)
        for k in range(n):
            self.cycle += 1
            for j, jid in enumerate(self.ids):
                r = rec[k * len(self.ids) + j]
                r["cycle"], r["deadline_ns"], r["id"] = self.cycle, 10**9 + self.cycle * 10**6, jid
                r["t_ns"] = r["deadline_ns"] + 30_000  # woke 30 µs after the deadline
                r["torque"], r["theta"], r["goal_tick"] = 0.1, 0.001 * self.cycle, 2048 + self.cycle
                r["present_tick"] = 2048 + self.cycle if self.cycle % 5 == 0 else -1
        return rec

    def stats(self):
        return {"cycles": self.cycle, "overruns": 0, "rate_hz": 1000.0, "period_us": PCT, "latency_us": PCT,
                "bus_errors": 0, "sensor_samples": len(self.samples), "sensor_stale_events": 0,
                "rt": {"policy": "SCHED_OTHER", "priority": 0, "memory_locked": False},
                "faults": {"servo_error": sum(s["errors"] for s in self.servos)}, "bus": dict(self.bus),
                "servos": [dict(s) for s in self.servos]}

    def stop_request(self):
        return self.request

    def set_sensor_faults(self, names):
        self.sensor_faults.append(list(names))

    def warnings(self):
        return ["SCHED_FIFO refused"]

    def heartbeat(self):
        return self.cycle

    def running(self):
        """True for ``lifetime`` checks (None: forever), then the thread "dies"."""
        if self.lifetime is not None:
            self.lifetime -= 1
        return self.lifetime is None or self.lifetime >= 0


    def params(self):
        return dict(self.values)

    def set_params(self, request):
        self.values.update(request)
        return True, ""

    def tare(self, samples):
        self.events.append(f"loop.tare:{samples}")

    def stop(self, torque_policy="hold"):
        self.events.append(f"loop.stop:{torque_policy}")
        self.stopped_with = torque_policy


class FakeSensor:
    def __init__(self, events, sink, tare_ok=True):
        self.events, self.sink, self.tare_ok = events, sink, tare_ok
        self.error = None
        self.hook = None
        self.stale_after_s = 0.2
        self.state, self.last_sample_ns, self.event_counts = "streaming", 0, {}

    def set_event_hook(self, hook, repeat_s=5.0):
        self.hook = hook

    def start(self):
        self.events.append("sensor.start")
        self.sink.push(1, [0.0] * 6)  # before the loop runs: must not reach it

    def tare(self, n, timeout):
        self.events.append(f"sensor.tare:{n}")
        return SimpleNamespace(accepted=self.tare_ok, reason="the sensor is not still")

    def stop(self):
        self.events.append("sensor.stop")

    def stats(self):
        import time

        # A fresh sample at every look, unless the test silenced it (last_sample_ns set).
        last = self.last_sample_ns or time.monotonic_ns()
        return {"kind": "fake", "state": self.state, "last_sample_ns": last, "events": dict(self.event_counts)}


class FakeNotifier:
    def __init__(self, events):
        self.events = events
        self.enabled = False
        self.watchdog_usec = 0

    def status(self, text):
        return True

    def ready(self, status=""):
        self.events.append("READY")
        return True

    def stopping(self, status=""):
        self.events.append("STOPPING")
        return True

    def send(self, *lines):
        return True


HARNESS_LIMIT_S = 20.0


class Harness:
    def __init__(self, tmp_path, *, fail_at=None, tare_ok=True, policy="hold", record=None, stop_after=None,
                 zenoh=None):
        doc = {"bus": {"port": "/dev/fake"},
               "joints": [{"id": 1, "model": "MX-64"}, {"id": 2, "model": "MX-28"}],
               "sensor": {"kind": "optoforce", "port": "/dev/fakesensor", "lever_arm": 0.1},
               "stop": {"torque_policy": policy}, "zenoh": zenoh or {}}
        if record:
            doc["record"] = {"path": record}
        path = tmp_path / "daemon.toml"
        path.write_text(tomli_w.dumps(doc))
        self.cfg = config.load_config(path)
        self.events: list[str] = []
        self.fail_at = fail_at
        self.tare_ok = tare_ok
        self.loop = None
        self.published = []

        @contextlib.contextmanager
        def bench(cfg):
            self.events.append("bench")
            self._maybe_fail("bench")
            try:
                yield "/dev/fake", "/dev/fakesensor", lambda: self.events.append("hand")
            finally:
                self.events.append("bench.stop")

        def check(cfg, port):
            self.events.append("servos")
            self._maybe_fail("servos")
            return ["latency timer is 16 ms"]

        def make_loop(cfg, port):
            self._maybe_fail("loop")
            self.loop = FakeLoop(self.events, [j.id for j in cfg.joints])
            return self.loop

        def make_sensor(cfg, port, sink):
            self._maybe_fail("sensor")
            return FakeSensor(self.events, sink, self.tare_ok)

        def make_interface(zcfg, codec, handler):
            self.events.append("zenoh")
            self._maybe_fail("zenoh")
            return SimpleNamespace(publish_state=self.published.append, publish_stats=self.published.append,
                                   poll=lambda: 0, close=lambda: self.events.append("zenoh.close"), queries=0,
                                   serve=lambda: self.events.append("zenoh.serve"))

        @contextlib.contextmanager
        def claim(cfg):
            self.events.append("claim")
            self._maybe_fail("claim")
            try:
                yield
            finally:
                self.events.append("release-claim")

        self.backends = Backends(start_bench=bench, check_servos=check,
                                 release_servos=lambda cfg, port: self.events.append("release"),
                                 make_sensor=make_sensor, make_loop=make_loop, make_interface=make_interface,
                                 claim_devices=claim)
        self.stats_path = tmp_path / "stats.json"
        # Always bounded: a run meant to end on a fault ends after HARNESS_LIMIT_S anyway (and the
        # test's assertions then fail) instead of hanging when the fault's stop does not come.
        options = RunOptions(duration=HARNESS_LIMIT_S if stop_after is None else stop_after, stats_json=self.stats_path)
        self.supervisor = Supervisor(self.cfg, self.backends, options, FakeNotifier(self.events))

    def _maybe_fail(self, step):
        if self.fail_at == step:
            raise DeviceError(f"{step} failed")


def test_start_order_then_a_duration_stop_writes_every_stats_key(tmp_path, caplog):
    caplog.set_level(logging.INFO, "admittance")
    h = Harness(tmp_path, stop_after=0.2)
    assert h.supervisor.run() == 0
    start = h.events[: h.events.index("READY") + 1]
    # The simulated hand starts once the loop runs, and its delay counts from there (the
    # recording's t = 0), not from the end of the slower interface start.
    assert start == ["claim", "bench", "zenoh", "sensor.start", "servos", "sensor.tare:100", "loop.start",
                     "hand", "zenoh.serve", "READY"]
    assert h.events[-6:] == ["STOPPING", "loop.stop:hold", "sensor.stop", "zenoh.close", "bench.stop",
                             "release-claim"]
    stats = json.loads(h.stats_path.read_text())
    assert set(STATS_KEYS) <= set(stats) and "daemon" in stats
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert any("latency timer" in line for line in warnings) and any("SCHED_FIFO" in line for line in warnings)
    assert caplog.records[-1].levelno == logging.INFO and caplog.messages[-1].startswith("stopped (hold) after")
    assert h.published, "state and stats are published while running"


def test_the_rendering_error_reaches_the_state_the_stats_and_the_stats_file(tmp_path):
    """The fake's horn reads 2048 + n ticks while its model is at 0.001·n rad: a growing gap."""
    from admittance.daemon.messages import State

    h = Harness(tmp_path, stop_after=0.2)
    h.supervisor.run()
    states = [m for m in h.published if isinstance(m, State)]
    last = states[-1].joints[0]
    gap = (last.present_tick - 2048) * 2 * np.pi / 4096 - last.theta  # the largest gap so far
    assert last.rendering_rms is not None and 0 < last.rendering_rms <= gap
    stats = json.loads(h.stats_path.read_text())
    assert set(stats["rendering_rms"]) == {"1", "2"}
    assert any("rendering_rms" in m for m in h.published if isinstance(m, dict))


def test_the_running_rendering_error_is_an_rms_over_about_a_second_of_reads():
    from admittance.daemon.telemetry import RAD_PER_TICK, RenderingError

    cfg = SimpleNamespace(joints=[SimpleNamespace(id=1, zero_tick=2048, direction=1)])
    tracker = RenderingError(cfg, window_s=1.0)
    assert tracker.rms(1) is None
    rec = np.zeros(3000, RECORD_DTYPE)
    rec["id"], rec["t_ns"], rec["cycle"] = 1, 10**9 + np.arange(3000) * 10**6, np.arange(3000)
    rec["present_tick"] = np.where(np.arange(3000) % 10 == 0, 2050, -1)  # 2 ticks off, read every 10th cycle
    tracker.update(rec)
    assert tracker.rms(1) == pytest.approx(2 * RAD_PER_TICK)
    rec["t_ns"] += 3 * 10**9
    rec["theta"] = 2 * RAD_PER_TICK  # the horn now sits on the model
    tracker.update(rec[:1001])
    assert tracker.rms(1) ** 2 == pytest.approx((2 * RAD_PER_TICK) ** 2 * np.exp(-1.0), rel=0.02)


def test_the_gate_keeps_pre_tare_samples_from_the_loop(tmp_path):
    h = Harness(tmp_path, stop_after=0.05)
    h.supervisor.run()
    assert h.loop.samples == []  # the sample pushed at sensor start was dropped by the gate
    target = []
    gate = GatedSink(SimpleNamespace(push=lambda t, f: target.append(t) or True))
    assert gate.push(1, [0] * 6) and gate.dropped_before_open == 1
    gate.open()
    gate.push(2, [0] * 6)
    assert target == [2]


@pytest.mark.parametrize("step, undone", [
    ("claim", []),
    ("bench", ["release-claim"]),
    ("zenoh", ["bench.stop", "release-claim"]),
    ("loop", ["zenoh.close", "bench.stop", "release-claim"]),
    ("sensor", ["zenoh.close", "bench.stop", "release-claim"]),
    ("servos", ["sensor.stop", "zenoh.close", "bench.stop", "release-claim"]),
])
def test_a_failing_step_raises_its_device_error_undoes_the_earlier_ones_and_writes_stats(tmp_path, step, undone):
    h = Harness(tmp_path, fail_at=step, stop_after=1.0)
    with pytest.raises(DeviceError, match=f"{step} failed"):
        h.supervisor.run()
    undo = ("release-claim", "bench.stop", "zenoh.close", "sensor.stop", "loop.stop:hold")
    assert [e for e in h.events if e in undo] == undone
    assert "READY" not in h.events
    stats = json.loads(h.stats_path.read_text())
    assert stats["error"] == f"{step} failed" and stats["exit_status"] == 3 and "daemon" in stats


def test_every_resource_is_claimed_before_the_first_write_to_a_servo(tmp_path):
    """The ports (hook), the bench, the Zenoh endpoint, the recording folder and the sensor's device:
    a daemon that cannot have one of them fails before torque goes on."""
    h = Harness(tmp_path, record="rec", stop_after=0.05)
    folder_existed = []
    check = h.backends.check_servos
    h.backends.check_servos = lambda cfg, port: folder_existed.append((tmp_path / "rec").is_dir()) or check(cfg, port)
    h.supervisor.run()
    servos = h.events.index("servos")
    assert {"claim", "bench", "zenoh", "sensor.start"} <= set(h.events[:servos]) and folder_existed == [True]
    assert "zenoh.serve" not in h.events[:servos], "queries are only served once the loop runs"


def test_a_listen_endpoint_beyond_loopback_is_warned_about_at_start(tmp_path, caplog):
    h = Harness(tmp_path, stop_after=0.05, zenoh={"listen": ["tcp/0.0.0.0:7447"]})
    h.supervisor.run()
    assert any(r.levelno == logging.WARNING and r.getMessage().startswith(
        "[zenoh].listen tcp/0.0.0.0:7447 is reachable from every interface") for r in caplog.records)
    caplog.clear()
    h = Harness(tmp_path, stop_after=0.05)
    h.supervisor.run()
    assert not any("[zenoh].listen" in line for line in caplog.messages), "loopback: no warning"


def test_an_unexpected_exception_still_writes_stats_with_the_error(tmp_path):
    h = Harness(tmp_path)
    make_loop = h.backends.make_loop

    def loop_with_a_bug(cfg, port):
        loop = make_loop(cfg, port)
        loop.drain_telemetry = lambda: 1 / 0
        return loop

    h.backends.make_loop = loop_with_a_bug
    with pytest.raises(ZeroDivisionError):
        h.supervisor.run()
    stats = json.loads(h.stats_path.read_text())
    assert stats["error"].startswith("internal error: ZeroDivisionError") and stats["exit_status"] == 1
    assert stats["cycles"] == 0 and "loop.stop:hold" in h.events


def test_a_refused_tare_stops_the_start(tmp_path):
    h = Harness(tmp_path, tare_ok=False)
    with pytest.raises(DeviceError, match="tare refused: the sensor is not still"):
        h.supervisor.run()
    assert "loop.start" not in h.events and "sensor.stop" in h.events


def test_torque_off_policy_releases_the_servos_when_the_start_fails_before_the_loop(tmp_path):
    h = Harness(tmp_path, tare_ok=False, policy="torque_off")
    with pytest.raises(DeviceError):
        h.supervisor.run()
    assert "release" in h.events
    h = Harness(tmp_path, fail_at="sensor", policy="torque_off")  # before the servos: nothing to release
    with pytest.raises(DeviceError):
        h.supervisor.run()
    assert "release" not in h.events
    h = Harness(tmp_path, policy="torque_off", stop_after=0.05)
    h.supervisor.run()
    assert "release" not in h.events and "loop.stop:torque_off" in h.events


def test_sigterm_stops_cleanly_with_the_torque_policy(tmp_path):
    h = Harness(tmp_path, policy="torque_off")
    previous = signal.getsignal(signal.SIGTERM)
    timer = threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGTERM))
    timer.start()
    try:
        assert h.supervisor.run() == 0
    finally:
        timer.cancel()
    assert h.loop.stopped_with == "torque_off"
    assert json.loads(h.stats_path.read_text())["cycles"] > 0
    assert signal.getsignal(signal.SIGTERM) is not h.supervisor.request_stop  # handlers restored
    assert signal.getsignal(signal.SIGTERM) is previous


def test_recording_writes_a_dataset_of_the_rows_with_a_present_position(tmp_path):
    from admittance.formats.dataset import load_dataset

    h = Harness(tmp_path, record="rec", stop_after=0.2)
    h.supervisor.run()
    dataset = load_dataset(tmp_path / "rec")
    assert dataset.mode == "geometry" and len(dataset.trials) == 2
    trial = dataset.trials[0]
    assert trial.tau is not None and np.all(trial.tau == 0.1)
    # only every 5th fake cycle read the present position
    assert trial.n_samples == h.loop.cycle // 5
    assert trial.load_inertia < 1e-9 and trial.gravity_torque < 1e-6


def test_params_are_flattened_and_sets_are_forwarded(tmp_path):
    h = Harness(tmp_path, stop_after=0.05)
    h.supervisor.run()
    assert h.supervisor.set_params({"virtual_damping": 0.1}) == (True, "")
    assert h.supervisor.get_params()["virtual_damping"] == 0.1
    assert h.supervisor.tare(50) == (True, "") and "loop.tare:50" in h.events


def test_ready_status_and_watchdog_reach_a_real_notify_socket(tmp_path):
    """READY=1 once running, WATCHDOG=1 while the loop's heartbeat advances, STOPPING=1 at the end.
    The supervisor runs in a thread so that this one reads the socket as systemd would."""
    import socket

    from admittance.daemon.notify import Notifier

    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(tmp_path / "notify"))
    sock.settimeout(10.0)
    h = Harness(tmp_path, stop_after=0.6)
    h.supervisor.notifier = Notifier({"NOTIFY_SOCKET": str(tmp_path / "notify"), "WATCHDOG_USEC": "200000"})
    runner = threading.Thread(target=h.supervisor.run)
    runner.start()
    messages: list[str] = []
    try:
        while not messages or not messages[-1].startswith("STOPPING=1"):
            messages.append(sock.recv(4096).decode())
    finally:
        runner.join()
        sock.close()
    ready = next(i for i, m in enumerate(messages) if m.startswith("READY=1"))
    assert "STATUS=running MX-64#1, MX-28#2 at 1000 Hz (SCHED_OTHER); bus read fast_sync_read" in messages[ready]
    pings = [i for i, m in enumerate(messages) if m == "WATCHDOG=1"]
    assert len(pings) >= 2 and min(pings) > ready  # one per 0.1 s while running, after READY


def test_a_loop_that_dies_stops_the_daemon_with_a_device_error(tmp_path):
    h = Harness(tmp_path)
    make_loop = h.backends.make_loop

    def short_lived(cfg, port):
        loop = make_loop(cfg, port)
        loop.lifetime = 1  # alive at the first stats check, dead at the second
        return loop

    h.backends.make_loop = short_lived
    with pytest.raises(DeviceError, match="RT loop thread ended"):
        h.supervisor.run()
    assert "loop.stop:hold" in h.events  # the undo path still holds the joints


def test_the_claim_comes_before_any_device_and_a_refused_claim_touches_none(tmp_path):
    h = Harness(tmp_path, stop_after=0.2)

    @contextlib.contextmanager
    def claim(cfg):
        h.events.append("claim")
        try:
            yield
        finally:
            h.events.append("claim.release")

    h.backends.claim_devices = claim
    assert h.supervisor.run() == 0
    assert h.events[:2] == ["claim", "bench"] and h.events[-1] == "claim.release"

    refused = Harness(tmp_path, stop_after=0.2)

    def busy(cfg):
        raise DeviceError("cannot claim /dev/fake: another admittance daemon has it (pid 1)")

    refused.backends.claim_devices = busy
    with pytest.raises(DeviceError, match="cannot claim"):
        refused.supervisor.run()
    assert refused.events == [], "no bench, no servo check, no sensor: nothing was opened"


def _stats(errors: int, simulated: bool, stalls: int = 0) -> dict:
    timing = {"rt": {"policy": "SCHED_FIFO", "priority": 80}, "stalls": stalls,
              "reply_late_us": {"max": 3400.0}, "wake_late_us": {"max": 900.0}}
    return {"cycles": 10_000, "overruns": 0, "bus_errors": errors,
            "bus_error_kinds": {"write": 0, "read_timeout": errors, "read_corrupt": 0},
            "sensor_stale_events": 0, "period_us": {"p99": 40.0},
            "bench": {"simulated": simulated, "simulated_sensor": simulated,
                      **({"bus": {"timing": timing}} if simulated else {})}}


def test_the_stop_line_says_the_bench_is_simulated_and_where_its_errors_came_from():
    from admittance.daemon.supervisor import summary_line

    clean = summary_line(_stats(0, simulated=True), "hold")
    assert clean.startswith("stopped (hold) after 10000 cycles on the simulated bench: 0 overruns, 0 bus errors, ")
    assert "thread" not in clean, "no errors: nothing to explain"
    starved = summary_line(_stats(3, simulated=True, stalls=2), "hold")
    assert "3 bus errors (3 read timeouts)" in starved
    assert "(SCHED_FIFO 80) ran late 2 times (> 0.25 ms, longest 3.4 ms): the simulation answered late through its " \
        "pseudo-terminals" in starved
    assert "which a real servo would not" in starved
    punctual = summary_line(_stats(3, simulated=True, stalls=0), "hold")
    assert "was never more than 0.25 ms late: these errors are not the simulation's lateness" in punctual
    real = summary_line(_stats(3, simulated=False), "torque_off")
    assert "simulated" not in real and real.startswith("stopped (torque_off) after 10000 cycles: ")
    direct = summary_line({**_stats(3, simulated=True, stalls=2), "bus": {"link": "in-process"}}, "hold")
    assert "in-process, on the wire's own time" in direct and "pseudo-terminals" not in direct, \
        "the embedded bench's loop does not read through the pty: its thread's lateness is not the cause"


# -- faults (docs/faults.md): told, marked, stopped on with their exit status ----------------------


def test_a_stop_request_of_the_loop_stops_cleanly_then_exits_with_its_status(tmp_path, caplog):
    """The loop gave a servo up: the daemon holds, applies its torque policy, writes the stats
    (the cause, the status, the fault counts) and raises the FaultStop the CLI exits with."""
    from admittance.errors import FaultStop

    h = Harness(tmp_path, policy="torque_off")
    make_loop = h.backends.make_loop

    def failing(cfg, port):
        loop = make_loop(cfg, port)
        loop.servos[0].update(errors=1, hardware_error=0x10, last_error=0x10)
        loop.request = {"cause": "unsafe_hardware_error", "joint": 1, "hardware_error": 0x10}
        return loop

    h.backends.make_loop = failing
    with pytest.raises(FaultStop) as caught:
        h.supervisor.run()
    assert caught.value.exit_code == 69 and caught.value.cause == "unsafe_hardware_error"
    assert "servo 1 reports electrical shock" in str(caught.value)
    assert h.events[-6:] == ["STOPPING", "loop.stop:torque_off", "sensor.stop", "zenoh.close", "bench.stop",
                             "release-claim"], "the same clean stop as a signal's"
    stats = json.loads(h.stats_path.read_text())
    assert stats["exit_status"] == 69 and stats["fault_stop"]["cause"] == "unsafe_hardware_error"
    assert stats["faults"]["servo_error"] == 1 and "servo 1 reports" in stats["error"]
    assert any("servo 1 shut down (electrical shock)" in line for line in caplog.messages), caplog.messages


def test_a_shutdown_recovered_between_two_ticks_is_told_with_its_cause(tmp_path):
    """The loop rebooted and re-enabled the servo faster than the supervisor's tick: its
    hardware_error is 0 again, and the line names the cause from last_error."""
    from admittance.daemon.faults import FaultWatch

    h = Harness(tmp_path)
    told: list[str] = []
    watch = FaultWatch(h.cfg, told.append)
    loop = FakeLoop([], [1])
    watch.poll(loop.stats(), {}, loop)
    loop.servos[0].update(errors=1, recoveries=1, hardware_error=0, last_error=0x20)
    watch.poll(loop.stats(), {}, loop)
    assert told[0].startswith("servo 1 shut down (overload); rebooting it"), told


def test_a_bus_that_stays_lost_exits_75_and_a_torque_off_it_cannot_carry_does_not_change_that(tmp_path, caplog):
    from admittance.errors import FaultStop

    h = Harness(tmp_path, policy="torque_off")
    make_loop = h.backends.make_loop

    def lost(cfg, port):
        loop = make_loop(cfg, port)
        loop.bus.update(state="lost", lost_for_s=5.0, losses=1, loss_errno=5)
        loop.request = {"cause": "bus_lost", "joint": None, "hardware_error": 0}

        def stop(torque_policy="hold"):
            loop.events.append(f"loop.stop:{torque_policy}")
            raise DeviceError("torque off failed on '/dev/fake': serial I/O failed")

        loop.stop = stop
        return loop

    h.backends.make_loop = lost
    with pytest.raises(FaultStop) as caught:
        h.supervisor.run()
    assert caught.value.exit_code == 75 and "did not come back within 5 s" in str(caught.value)
    assert any("the Dynamixel bus /dev/fake failed (Input/output error)" in line for line in caplog.messages), caplog.messages
    assert any("torque off failed" in line for line in caplog.messages)
    assert json.loads(h.stats_path.read_text())["exit_status"] == 75


def test_sensor_events_are_told_rate_limited_and_mark_the_loops_cycles(tmp_path, caplog):
    import time

    h = Harness(tmp_path, stop_after=0.5)
    make_sensor = h.backends.make_sensor

    def unplugged(cfg, port, sink):
        sensor = make_sensor(cfg, port, sink)
        sensor.state = "reconnecting"

        def start():
            sensor.events.append("sensor.start")
            for _ in range(50):  # a stream failing fast: told once, then counted
                sensor.hook("disconnected", "optoforce sensor on /dev/fakesensor failed (EIO)")
            sensor.last_sample_ns = time.monotonic_ns()

        sensor.start = start
        return sensor

    h.backends.make_sensor = unplugged
    h.supervisor.run()
    told = [line for line in caplog.messages if "failed (EIO)" in line]
    assert len(told) == 1 and told[0].startswith("sensor: ")
    assert ["sensor_lost"] in h.loop.sensor_faults
    assert h.supervisor.sensor.stale_after_s == h.cfg.loop.stale_timeout_ms / 1000
    stats = json.loads(h.stats_path.read_text())
    assert stats["daemon"]["faults_told"]["sensor.disconnected"] == 50


def test_a_sensor_silent_beyond_its_timeout_exits_75_and_holds_forever_without_one(tmp_path):
    import time

    from admittance.errors import FaultStop

    def silent(h):
        make_sensor = h.backends.make_sensor

        def make(cfg, port, sink):
            sensor = make_sensor(cfg, port, sink)
            sensor.last_sample_ns = time.monotonic_ns()  # its last sample, never another
            return sensor

        h.backends.make_sensor = make

    h = Harness(tmp_path, stop_after=0.6)
    silent(h)
    assert h.supervisor.run() == 0, "[faults].sensor_lost_timeout_s = 0: hold forever"
    h = Harness(tmp_path)
    h.cfg = config.load_config(_with_faults(tmp_path, {"sensor_lost_timeout_s": 0.3}))
    h.supervisor = Supervisor(h.cfg, h.backends, h.supervisor.options, FakeNotifier(h.events))
    silent(h)
    with pytest.raises(FaultStop, match="no usable sample") as caught:
        h.supervisor.run()
    assert caught.value.exit_code == 75


def _with_faults(tmp_path, faults):
    import tomllib

    path = tmp_path / "daemon.toml"
    doc = tomllib.loads(path.read_text())
    doc["faults"] = faults
    path.write_text(tomli_w.dumps(doc))
    return path


def test_the_watchdog_stops_pinging_a_loop_that_cycles_on_a_lost_bus(tmp_path):
    """The loop's heartbeat still advances, but the bus has been gone longer than the policy
    allows: no WATCHDOG=1 from then on (systemd restarts a sick daemon), and the counts say so."""
    from admittance.daemon.notify import Notifier

    h = Harness(tmp_path, stop_after=1.0)
    h.supervisor.notifier = Notifier({"NOTIFY_SOCKET": str(tmp_path / "absent"), "WATCHDOG_USEC": "100000"})
    sent = []
    h.supervisor.notifier.send = lambda *lines: sent.extend(lines) or True
    make_loop = h.backends.make_loop

    def lost(cfg, port):
        loop = make_loop(cfg, port)
        loop.bus.update(state="lost", lost_for_s=h.cfg.faults.bus_lost_timeout_s)
        return loop

    h.backends.make_loop = lost
    h.supervisor.run()
    assert "WATCHDOG=1" not in sent
    watchdog = json.loads(h.stats_path.read_text())["daemon"]["watchdog"]
    assert watchdog["pings"] == 0 and watchdog["unhealthy"] >= 3


def test_a_flood_of_sets_is_counted_in_the_log_not_written_line_by_line(tmp_path, caplog):
    h = Harness(tmp_path, stop_after=0.05)
    h.supervisor.run()
    with caplog.at_level(logging.INFO, logger="admittance.daemon.supervisor"):
        for k in range(200):
            assert h.supervisor.set_params({"virtual_damping": 0.1 + k * 1e-4})[0]
    lines = [r.getMessage() for r in caplog.records if r.getMessage().startswith("params set")]
    assert len(lines) == supervisor_module.PARAMS_LOG_BURST, "the rest of the flood held back"


def test_queries_are_answered_between_chunks_of_a_drained_backlog_and_a_set_recorded_after_it(tmp_path):
    """A main thread starved by a loaded machine drains many seconds of cycles in one tick (the
    telemetry ring holds 65 s): the queries pending meanwhile are answered, and the state published,
    after each chunk of DRAIN_CHUNK_CYCLES, not after the whole backlog; a set answered in the
    middle reaches the recording after every cycle of the batch (the loop applies it after all)."""
    chunk = supervisor_module.DRAIN_CHUNK_CYCLES
    h = Harness(tmp_path, record="rec", stop_after=0.3)
    rows_at_poll: list[int] = []
    rows_at_set_targets: list[int] = []
    states_at_poll: list[int] = []
    make_loop = h.backends.make_loop

    def backlogged_loop(cfg, port):
        loop = make_loop(cfg, port)
        steady, first = loop.drain_telemetry, [True]

        def drain():  # the first drain: 20 chunks' worth of cycles at once
            if first.pop() if first else False:
                return np.concatenate([steady() for _ in range(20 * chunk // 10)])
            return steady()
        loop.drain_telemetry = drain
        return loop

    def make_interface(zcfg, codec, handler):
        def poll():
            recorder = h.supervisor.recorder
            rows_at_poll.append(sum(recorder.rows.values()))
            states_at_poll.append(sum(isinstance(m, State) for m in h.published))
            if len(rows_at_poll) == 3:  # a set arrives while the backlog is recorded
                set_targets = recorder.set_targets
                recorder.set_targets = lambda p: (rows_at_set_targets.append(sum(recorder.rows.values())),
                                                  set_targets(p))
                assert handler.set_params({"virtual_damping": 0.2}) == (True, "")
            return 0
        return SimpleNamespace(publish_state=h.published.append, publish_stats=h.published.append, poll=poll,
                               close=lambda: None, queries=0, serve=lambda: None)

    h.backends.make_loop, h.backends.make_interface = backlogged_loop, make_interface
    assert h.supervisor.run() == 0
    # Each joint's recorded rows are its cycles with a present read (every 5th fake cycle).
    per_chunk = 2 * (chunk // 5 + 1)
    backlog_rows = 2 * (20 * chunk // 5)
    during = [rows for rows in rows_at_poll if rows < backlog_rows - per_chunk]
    assert len(during) >= 15, f"the backlog's queries waited for all of it: polls saw {rows_at_poll[:5]} rows"
    assert max(np.diff([0, *rows_at_poll[:len(during) + 1]])) <= per_chunk
    assert states_at_poll[:len(during)] == list(range(1, len(during) + 1)), "no state published in the backlog"
    assert rows_at_set_targets and rows_at_set_targets[0] >= backlog_rows - 2, \
        f"the set reached the recording before the backlog's cycles: at {rows_at_set_targets} of {backlog_rows} rows"
