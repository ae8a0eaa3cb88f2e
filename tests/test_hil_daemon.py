"""Hardware-in-loop: the real daemon (`.venv/bin/admittance run`) as a subprocess against the
mock bench over pseudo-terminals, checked from outside (recording, stats, Zenoh, exit status).

Two bench set-ups are used on purpose: the embedded one (`[bus].port = "mock"`, the bench runs
inside the daemon) and an external one (a MockBench in this test process, the daemon opening
its ptys as it would real devices), so both paths of `admittance run` are exercised.

Tolerances are stated where they are used; no assertion depends on timing beyond "the run
lasted long enough for the motion to happen". Waits are on the daemon's own state (liveliness,
the model's speed, its cycle count) with generous deadlines, so a loaded machine that starts the
daemon slowly or starves its loop makes a test slower, not red.
"""

from __future__ import annotations

import json
import math
import signal
import socket
import subprocess
import tomllib
from pathlib import Path

import numpy as np
import pytest
import tomli_w

from admittance import data
from admittance._rtcore import CATCH_UP_STEPS_PER_CYCLE, MAX_CATCH_UP_STEPS
from admittance.daemon.messages import STATS_KEYS

from daemon_process import (ADMITTANCE, QUERY_TIMEOUT_S, START_TIMEOUT_S, read_recording, run_daemon, running_daemon,
                            wait_alive, wait_for_cycles, wait_for_state)
from helpers import free_endpoint, wait_until
from oracles import virtual_joint

pytestmark = pytest.mark.hil

PREFIX = "hil/arm"
MX64 = data.params_file("MX-64")
RATE_HZ = 1000.0
TICK_RAD = 2 * math.pi / 4096


def daemon_config(tmp_path: Path, *, bus: str = "mock", sensor: str = "mock", joint: dict | None = None,
                  bench: dict | None = None, loop: dict | None = None, stop: str = "hold") -> tuple[Path, str]:
    endpoint = free_endpoint()
    doc = {
        "bus": {"port": bus},
        "joints": [{"id": 1, "model": "MX-64", "params": str(MX64), **(joint or {})}],
        "sensor": {"kind": "optoforce", "port": sensor, "lever_arm": 0.105, "tare_samples": 100},
        "loop": {"rate_hz": RATE_HZ, "sync_read_divisor": 1, **(loop or {})},
        "stop": {"torque_policy": stop},
        "zenoh": {"prefix": PREFIX, "listen": [endpoint]},
    }
    if bench is not None:
        doc["bench"] = bench
    path = tmp_path / "daemon.toml"
    path.write_text(tomli_w.dumps(doc))
    return path, endpoint


def replay_runs(rec: dict[str, np.ndarray], inertia: float, damping: float, coulomb: float) -> np.ndarray:
    """Replay the recorded torque through the virtual joint over every run of consecutive cycles
    (rows are missing where a present-position read failed), each run started from its first
    recorded state; returns the replayed angle at every row (NaN at run starts). As recordings
    define it (docs/daemon.md): a row's ``tau`` is the torque the model integrates from that row's
    time ``t`` (a deadline) on. How many steps a cycle takes is the loop's catch-up rule, replayed
    here as a test oracle of `cycle.rs` `steps_due`: the steps due since the model's time, at most
    CATCH_UP_STEPS_PER_CYCLE a cycle, and a stall that leaves more than MAX_CATCH_UP_STEPS due
    loses its time (the model's time restarts at that deadline). A run starts with none due."""
    out = np.full(len(rec["t"]), np.nan)
    theta = omega = model_t = 0.0
    period = 1.0 / RATE_HZ
    for i in range(1, len(out)):
        if rec["cycle"][i] - rec["cycle"][i - 1] != 1:
            continue
        deadline = rec["t"][i - 1]
        if np.isnan(out[i - 1]):
            theta, omega = rec["theta_model"][i - 1], rec["omega_model"][i - 1]
            model_t = deadline - period
        due = math.floor((deadline - model_t) / period + 0.5)
        steps = min(max(due, 0), CATCH_UP_STEPS_PER_CYCLE)
        model_t = deadline if due > MAX_CATCH_UP_STEPS else model_t + steps * period
        for _ in range(steps):
            theta, omega = virtual_joint.step(theta, omega, rec["tau"][i - 1], inertia, damping, coulomb, period)
        out[i] = theta
    return out


def test_goal_positions_follow_the_admittance_model(tmp_path):
    """A scripted hand torque goes in; replaying the recorded torque through the virtual model
    offline reproduces the goal angles within 2 ticks (plus the half tick of quantisation), and
    the servo's measured angle follows the goal within 0.1 rad. Runs are re-anchored where a
    row is missing. The stale timeout is raised to 0.5 s (the most allowed): on a loaded CI machine the sensor's
    reader thread can stall past the default 50 ms, and the loop would rightly hold, which a
    torque-only replay does not model."""
    from admittance.daemon.zenoh_iface import Client

    inertia, damping, coulomb = 0.02, 0.1, 0.02
    config, endpoint = daemon_config(tmp_path, joint={"virtual_inertia": inertia, "virtual_damping": damping,
                                                      "virtual_coulomb": coulomb},
                                     bench={"profile": "sine:amplitude=0.15,frequency=1", "hand_delay_s": 0.5},
                                     loop={"stale_timeout_ms": 500.0})
    with running_daemon(config, "--record", str(tmp_path / "rec")) as daemon:
        wait_alive(endpoint, PREFIX)
        with Client([endpoint]) as client:
            pushed = wait_for_state(client, PREFIX, lambda m: abs(m["joints"][0]["tau"]) > 0.05, "the hand pushing")
            wait_for_cycles(client, PREFIX, 2 * int(RATE_HZ), after=pushed)  # two periods of the hand's sine
    assert daemon.returncode == 0, daemon.stderr
    rec = read_recording(tmp_path / "rec")
    assert (np.abs(rec["tau"]) > 0.05).sum() > 300, "the hand pushed"
    assert np.ptp(rec["theta_goal"]) > 0.1, "the joint moved"
    replay = replay_runs(rec, inertia, damping, coulomb)
    replayed = ~np.isnan(replay)
    assert replayed.sum() > len(replay) / 4, "enough consecutive cycles to replay"
    assert np.max(np.abs(replay - rec["theta_goal"])[replayed]) < 2.5 * TICK_RAD
    assert np.max(np.abs(rec["theta"] - rec["theta_goal"])) < 0.1


def wait_for_speed(client, speed: float) -> dict:
    """Watch the state until the model's speed reaches ``speed``."""
    return wait_for_state(client, PREFIX, lambda m: m["joints"][0]["omega"] >= speed, f"a speed of {speed} rad/s")


def test_a_parameter_change_over_zenoh_takes_effect_without_a_jump(tmp_path):
    """A constant push drives the joint at its terminal speed (τ − F)/B; raising B over Zenoh
    slows it to the new terminal speed (within 10 %), and no cycle moves the model by more than
    the speed allows (the change is ramped, not stepped). A set with one bad value changes nothing."""
    from admittance.daemon.zenoh_iface import Client

    # The push is gentle (0.2 rad/s, then 0.067): the joint runs on while the queries below go
    # back and forth, which took seconds on a loaded machine, and at 0.4 rad/s it reached its
    # position limit (3.1 rad, where the model stops dead) before the last 200 cycles were judged.
    tau, b1, b2, coulomb = 0.04, 0.1, 0.3, 0.02
    config, endpoint = daemon_config(
        tmp_path, joint={"virtual_inertia": 0.02, "virtual_damping": b1, "virtual_coulomb": coulomb},
        bench={"profile": f"still:torque={tau}", "hand_delay_s": 0.5},
        loop={"stale_timeout_ms": 500.0})  # a stalled reader would hold (ω = 0 at once): not under test here
    with running_daemon(config, "--record", str(tmp_path / "rec")) as daemon:
        wait_alive(endpoint, PREFIX)
        with Client([endpoint]) as client:
            wait_for_speed(client, 0.95 * (tau - coulomb) / b1)
            assert client.query_params(PREFIX, {"virtual_damping": b2}, QUERY_TIMEOUT_S) == {"accepted": True}
            assert client.query_params(PREFIX, timeout=QUERY_TIMEOUT_S)["params"]["1.virtual_damping"] == b2
            rejected = client.query_params(PREFIX, {"virtual_damping": 0.2, "virtual_inertia": -1.0}, QUERY_TIMEOUT_S)
            assert rejected["accepted"] is False and "inertia" in rejected["reason"]
            # all or nothing
            assert client.query_params(PREFIX, timeout=QUERY_TIMEOUT_S)["params"]["1.virtual_damping"] == b2
            # mx64.toml has no [servo] model: compensation cannot be turned on, and nothing else changes
            rejected = client.query_params(PREFIX, {"virtual_damping": 0.2, "servo_compensation": 1}, QUERY_TIMEOUT_S)
            assert rejected["accepted"] is False and "servo model" in rejected["reason"]
            assert client.query_params(PREFIX, timeout=QUERY_TIMEOUT_S)["params"]["1.servo_compensation"] == 0.0
            assert client.query_params(PREFIX, timeout=QUERY_TIMEOUT_S)["params"]["1.virtual_damping"] == b2
            wait_for_cycles(client, PREFIX, int(RATE_HZ))  # the 0.5 s ramp, then several I/B
    assert daemon.returncode == 0, daemon.stderr
    rec = read_recording(tmp_path / "rec")
    tau_model = rec["tau"][-1]
    assert abs(tau_model - tau) < 0.01
    v1, v2 = (tau_model - coulomb) / b1, (tau_model - coulomb) / b2
    omega = rec["omega_model"]
    assert rec["theta_model"].max() < 3.0, "the joint reached its position limit: no terminal speed to judge"
    assert abs(omega.max() - v1) < 0.1 * v1
    assert abs(np.median(omega[rec["cycle"] > rec["cycle"][-1] - 200]) - v2) < 0.1 * v2
    # Per interval of model time: ``t`` is the cycle's deadline, and the loop integrates one step
    # of h per deadline (a skipped one included), so the model's time is ``t``; the wake-up time
    # ``t_wake`` would add the scheduler's jitter and fake a jump.
    model_dt = np.diff(rec["t"])
    speeds = np.abs(np.diff(rec["theta_model"])) / model_dt
    assert speeds.max() < 1.5 * v1, "no cycle jumped"
    assert np.all(np.abs(np.diff(omega)) <= 200.0 * model_dt + 1e-9), "within acceleration_max"


def test_sensor_silence_holds_the_joint(tmp_path):
    """The external bench's sensor goes silent while the hand pushes: the loop counts a stale
    event and holds, the model stops dead and stays, and the servo stays at its goal."""
    from admittance.daemon.zenoh_iface import Client
    from admittance.mockbench.bench import BenchConfig, MockBench
    from admittance.mockbench.hand import make_profile

    with MockBench(BenchConfig(profile="still")) as bench:
        config, endpoint = daemon_config(tmp_path, bus=bench.bus_port, sensor=bench.sensor_port,
                                         joint={"virtual_inertia": 0.02, "virtual_damping": 0.1,
                                                "virtual_coulomb": 0.02})
        with running_daemon(config, "--record", str(tmp_path / "rec"), "--stats-json", str(tmp_path / "s.json"),
                            stop=signal.SIGTERM) as daemon:
            wait_alive(endpoint, PREFIX)
            bench.profile = make_profile("still:torque=0.1")  # the hand pushes once the loop runs
            with Client([endpoint]) as client:
                wait_for_speed(client, 0.4)  # terminal speed (0.1 − 0.02)/0.1 = 0.8 rad/s
                bench.sensor.stop()
                wait_for_cycles(client, PREFIX, int(RATE_HZ))
    assert daemon.returncode == 0, daemon.stderr
    stats = json.loads((tmp_path / "s.json").read_text())
    assert stats["sensor_stale_events"] >= 1
    rec = read_recording(tmp_path / "rec")
    assert rec["omega_model"].max() > 0.3, "the joint was moving before the silence"
    last = rec["cycle"] > rec["cycle"][-1] - RATE_HZ / 2  # the last 500 cycles: well after the silence began
    assert np.all(rec["omega_model"][last] == 0.0)
    assert np.ptp(rec["theta_model"][last]) == 0.0
    assert np.max(np.abs(rec["theta"][last] - rec["theta_goal"][last])) < 3 * TICK_RAD


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_clean_stop_exits_0_with_every_stats_key(tmp_path, sig):
    """(A tare over Zenoh on the way, from the `admittance tare` command.)"""
    config, endpoint = daemon_config(tmp_path, stop="torque_off", bench={"profile": "still"})
    stats_path = tmp_path / "stats.json"
    with running_daemon(config, "--stats-json", str(stats_path), stop=sig) as daemon:
        wait_alive(endpoint, PREFIX)
        assert subprocess.run([str(ADMITTANCE), "tare", "--samples", "50", "--prefix", PREFIX, "--connect",
                               endpoint], capture_output=True, text=True, timeout=START_TIMEOUT_S).returncode == 0
    assert daemon.returncode == 0, daemon.stderr
    stats = json.loads(stats_path.read_text())
    assert set(STATS_KEYS) <= set(stats)
    for key in ("period_us", "latency_us"):
        assert set(stats[key]) >= {"p50", "p99", "p999", "max"}
    assert set(stats["rt"]) >= {"policy", "priority", "memory_locked"}
    assert stats["cycles"] > 0 and stats["rate_hz"] > 0
    # `admittance run` settled its interpreter for the sensor reader before its loop started (docs/realtime.md)
    settled = stats["daemon"]["interpreter"]
    assert settled["switch_interval_s"] == pytest.approx(0.0005) and settled["frozen_objects"] > 10_000


def one_error_line(result: subprocess.CompletedProcess) -> str:
    """The one line of a failed run's error; what comes before it may only be warnings (the sensor
    is opened before the servo checks, and its reader may report a gap in its samples)."""
    assert result.returncode != 0
    lines = result.stderr.strip().splitlines()
    errors = [line for line in lines if "error:" in line]
    assert len(errors) == 1 and lines[-1] == errors[0], result.stderr
    assert all("warning" in line or "no samples" in line for line in lines[:-1]), result.stderr
    assert "Traceback" not in result.stderr
    return errors[0]


def test_a_config_error_is_one_line_and_a_non_zero_exit(tmp_path):
    config, _ = daemon_config(tmp_path)
    config.write_text(config.read_text().replace("rate_hz", "rate_hzz"))
    line = one_error_line(run_daemon(config, "--duration", "1", "--stats-json", str(tmp_path / "s.json")))
    assert "rate_hzz" in line and "did you mean 'rate_hz'" in line
    stats = json.loads((tmp_path / "s.json").read_text())
    assert "rate_hzz" in stats["error"] and stats["exit_status"] == 2


def test_a_missing_device_is_one_line_and_a_non_zero_exit(tmp_path):
    """Each missing device is one line and exit 3, and the stats file says why (--stats-json is
    written on every exit path). The sensor's device is opened before the servos are touched."""
    from admittance.mockbench.bench import BenchConfig, MockBench

    config, _ = daemon_config(tmp_path, bus="/dev/ttyUSB_absent_admittance", sensor="/dev/ttyACM_absent")
    result = run_daemon(config, "--duration", "1", "--stats-json", str(tmp_path / "s.json"))
    assert "/dev/ttyACM_absent" in one_error_line(result)
    assert result.returncode == 3
    stats = json.loads((tmp_path / "s.json").read_text())
    assert "/dev/ttyACM_absent" in stats["error"] and stats["exit_status"] == 3
    with MockBench(BenchConfig(profile="still")) as bench:
        config, _ = daemon_config(tmp_path, bus="/dev/ttyUSB_absent_admittance", sensor=bench.sensor_port)
        result = run_daemon(config, "--duration", "1")
    assert "/dev/ttyUSB_absent_admittance" in one_error_line(result)
    assert result.returncode == 3


def test_a_servo_that_does_not_answer_is_one_line_and_still_writes_stats(tmp_path):
    """A failing start (the servo check) exits 3 with one line, and --stats-json is written anyway,
    with the error and what is known."""
    from admittance.mockbench.bench import BenchConfig, MockBench

    with MockBench(BenchConfig(profile="still")) as bench:
        config, _ = daemon_config(tmp_path, bus=bench.bus_port, sensor=bench.sensor_port, joint={"id": 7})
        result = run_daemon(config, "--duration", "1", "--stats-json", str(tmp_path / "s.json"))
    assert "servo 7" in one_error_line(result) and result.returncode == 3
    stats = json.loads((tmp_path / "s.json").read_text())
    assert "servo 7" in stats["error"] and stats["exit_status"] == 3
    assert "sensor" in stats["daemon"], "what is known: the sensor had been opened"


def test_no_config_runs_the_embedded_bench(tmp_path):
    """`admittance run` alone: the default simulated bench, end to end (the README's `make run`)."""
    with socket.socket() as probe:
        if probe.connect_ex(("127.0.0.1", 7447)) == 0:
            pytest.skip("another process listens on 127.0.0.1:7447, the default configuration's endpoint")
    result = subprocess.run([str(ADMITTANCE), "run", "--duration", "3.5", "--stats-json", str(tmp_path / "s.json")],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    stats = json.loads((tmp_path / "s.json").read_text())
    assert stats["cycles"] > 500 and stats["sensor_samples"] > 200  # of ~3500 each: room for a loaded machine
    assert stats["bus"]["link"] == "in-process", "the loop reaches the embedded bench's servos in-process"


@pytest.mark.slow
@pytest.mark.parametrize("bus, sensor", [({"protocol": 1}, {}), ({}, {"kind": "can", "interface": "virtual"})],
                         ids=["protocol1", "can-sensor"])
def test_protocol_1_servos_and_the_can_sensor_run_end_to_end(tmp_path, bus, sensor):
    """The other firmware protocol (BULK_READ instead of SYNC_READ) and the CAN reader, on the
    embedded bench: the loop reads the servo and the sensor's samples reach it."""
    config, _ = daemon_config(tmp_path, bench={"profile": "still"})
    doc = tomllib.loads(config.read_text())
    doc["bus"].update(bus)
    doc["sensor"].update(sensor)
    config.write_text(tomli_w.dumps(doc))
    result = run_daemon(config, "--duration", "1.5", "--stats-json", str(tmp_path / "s.json"))
    assert result.returncode == 0, result.stderr
    stats = json.loads((tmp_path / "s.json").read_text())
    assert stats["sync_reads"] > 100 and stats["sensor_samples"] > 200  # of ~1500 each: room for a loaded machine
    assert stats["bus"]["link"] == "in-process"


@pytest.mark.parametrize("when", ["at once", "after the stop began", "after the stats were written"])
def test_a_second_signal_during_teardown_finishes_the_teardown(tmp_path, when):
    """SIGINT, then SIGTERM while the daemon tears down (right behind the first, once it has
    logged its stop, or once its stats file is there and only the interpreter's exit is left):
    the teardown completes, exit 0, the stats are written. (The last case used to end the
    process with -15: the default action was back in place while zenoh's session closed.)"""
    config, endpoint = daemon_config(tmp_path, bench={"profile": "still"})
    stats_path = tmp_path / "stats.json"
    proc = subprocess.Popen([str(ADMITTANCE), "run", "--config", str(config), "--stats-json", str(stats_path)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        wait_alive(endpoint, PREFIX)
        proc.send_signal(signal.SIGINT)
        if when == "after the stop began":
            lines = iter(proc.stderr.readline, "")
            assert any(line.startswith("admittance run: stopped (") for line in lines), "no stop line"
        if when == "after the stats were written":
            assert wait_until(stats_path.exists, timeout=START_TIMEOUT_S)
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=START_TIMEOUT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.communicate()
    assert proc.returncode == 0
    stats = json.loads(stats_path.read_text())
    assert stats["cycles"] > 0 and "error" not in stats


def test_a_busy_zenoh_endpoint_fails_before_anything_is_written_to_a_servo(tmp_path):
    """A second daemon on the first one's Zenoh endpoint: one line, exit 3, and its servos never
    saw a packet (the endpoint is claimed before the servo checks; it used to fail only after
    torque was on and a goal written)."""
    from admittance.mockbench.bench import BenchConfig, MockBench

    config, endpoint = daemon_config(tmp_path, bench={"profile": "still"})
    with running_daemon(config) as first, MockBench(BenchConfig(profile="still")) as bench:
        wait_alive(endpoint, PREFIX)
        second = tmp_path / "second"
        second.mkdir()
        config2, _ = daemon_config(second, bus=bench.bus_port, sensor=bench.sensor_port)
        doc = tomllib.loads(config2.read_text())
        doc["zenoh"]["listen"] = [endpoint]
        config2.write_text(tomli_w.dumps(doc))
        result = run_daemon(config2, "--duration", "1")
        assert "address already in use" in one_error_line(result) and result.returncode == 3
        assert bench.bus.stats()["packets"] == 0
        assert bench.bus.register(1, "Torque Enable") == 0
    assert first.returncode == 0, first.stderr


def test_a_second_daemon_on_the_same_devices_stops_before_touching_them(tmp_path, monkeypatch):
    """Two daemons configured on one bus and one sensor: the second stops with one line at the
    claim, and, should it not share the first's lock directory, at its first exclusive open;
    the first runs on undisturbed."""
    from admittance.daemon.zenoh_iface import Client
    from admittance.mockbench.bench import BenchConfig, MockBench

    monkeypatch.setenv("ADMITTANCE_LOCK_DIR", str(tmp_path))
    (tmp_path / "a").mkdir(), (tmp_path / "b").mkdir(), (tmp_path / "other").mkdir()
    with MockBench(BenchConfig(profile="still")) as bench:
        first, endpoint = daemon_config(tmp_path / "a", bus=bench.bus_port, sensor=bench.sensor_port)
        second, _ = daemon_config(tmp_path / "b", bus=bench.bus_port, sensor=bench.sensor_port)
        stats_path = tmp_path / "first.json"
        with running_daemon(first, "--stats-json", str(stats_path)) as daemon:
            wait_alive(endpoint, PREFIX)
            claimed = run_daemon(second, "--duration", "1")
            monkeypatch.setenv("ADMITTANCE_LOCK_DIR", str(tmp_path / "other"))
            opened = run_daemon(second, "--duration", "1")
            with Client([endpoint]) as client:
                wait_for_cycles(client, PREFIX, 200)
    holder = f"pid {daemon.proc.pid}"
    line = one_error_line(claimed)
    assert claimed.returncode == 3 and line.startswith(f"admittance run: error: cannot claim {bench.bus_port}:") and holder in line
    line = one_error_line(opened)
    # The bus's Python open says "busy"; the sensor's Rust reader says "in use by another process".
    assert opened.returncode == 3 and ("the device is busy" in line or "in use by another process" in line) and holder in line
    assert daemon.returncode == 0, daemon.stderr
    sensor = json.loads(stats_path.read_text())["daemon"]["sensor"]
    assert sensor["disconnects"] == 0 and sensor["state"] == "stopped"


@pytest.mark.parametrize("sig", [signal.SIGHUP, signal.SIGUSR1, signal.SIGUSR2])
def test_an_unexpected_signal_is_a_clean_stop_told_and_restartable(tmp_path, sig):
    """SIGHUP and SIGUSR1/2 killed the daemon at once (no stop line, no stats, an unfinished
    MCAP, no torque policy, and a death systemd counted as clean). They stop it cleanly, with
    the stop line and a readable session.mcap, and exit 75 so that systemd restarts it."""
    from mcap.reader import make_reader

    config, endpoint = daemon_config(tmp_path, stop="torque_off")
    stats_path, record = tmp_path / "stats.json", tmp_path / "rec"
    with running_daemon(config, "--stats-json", str(stats_path), "--record", str(record), stop=sig) as daemon:
        wait_alive(endpoint, PREFIX)
    assert daemon.returncode == 75, daemon.stderr
    name = signal.Signals(sig).name
    assert f"stopped by {name}, which is not a stop signal" in daemon.stderr
    assert "stopped (torque_off) after" in daemon.stderr, "the stop line, with the torque policy applied"
    assert "Traceback" not in daemon.stderr
    stats = json.loads(stats_path.read_text())
    assert stats["fault_stop"] == {"cause": f"signal_{name.lower()}", "exit_status": 75}
    with (record / "session.mcap").open("rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None and summary.statistics.message_count > 0, "the MCAP was finished"


def test_a_full_disk_stops_the_recording_with_a_line_and_the_loop_runs_on(tmp_path):
    """Every file the daemon writes may grow to 400 kB (RLIMIT_FSIZE: past it a write fails with
    EFBIG, as on a full disk it fails with ENOSPC). The CSV and then session.mcap hit it while
    recording: each stops with one line, the loop runs on, the run ends cleanly, and what was
    written is read by the project's own loaders (the CSV cut at a whole row, the MCAP read up
    to its cut)."""
    import resource
    import threading

    from admittance.formats.dataset import load_dataset
    from admittance.formats.recording import read_recording

    limit = 400 * 1024

    def small_disk() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails instead of killing
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    config, endpoint = daemon_config(tmp_path)
    doc = tomllib.loads(config.read_text())
    doc["record"] = {"path": str(tmp_path / "rec"), "segment_s": 600.0}
    config.write_text(tomli_w.dumps(doc))
    proc = subprocess.Popen([str(ADMITTANCE), "run", "--config", str(config)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, preexec_fn=small_disk)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stderr), daemon=True)
    reader.start()
    try:
        told = wait_until(lambda: any("recording stopped" in line for line in lines)
                          and any("session.mcap stopped" in line for line in lines), timeout=60.0)
        wait_alive(endpoint, PREFIX)  # still serving after both
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=30)
        reader.join(timeout=10)
    stderr = "".join(lines)
    assert told, stderr
    assert proc.returncode == 0, stderr
    assert "Traceback" not in stderr
    assert sum("recording stopped" in line for line in lines) == 1, "one line"
    folder = tmp_path / "rec"
    for csv_file in folder.glob("joint1_*.csv"):  # a loaded machine's stalls may start new trials
        text = csv_file.read_text()
        assert text.endswith("\n") and len(text.encode()) <= limit
    assert sum(trial.n_samples for trial in load_dataset(folder).trials) > 1000
    recording = read_recording(folder / "session.mcap")
    assert recording.truncated and len(recording.joints[1]["t"]) > 1000
