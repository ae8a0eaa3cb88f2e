"""The RT loop (`_rtcore.AdmittanceLoop`) against the simulated Dynamixel bus (`MockBus`).

The loop runs for real here: its own thread, a pseudo-terminal, the mock servo's control
table. The checks are on *what* it did (goals against the model, holds, counters), never on
how fast: waits poll the loop's heartbeat with a generous limit and fail with a message.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from admittance import _rtcore
from admittance.errors import DeviceError
from oracles import virtual_joint

RATE_HZ = 500.0
INERTIA, DAMPING = 0.02, 0.01
LEVER = 0.1
HOLDING = _rtcore.LOOP_MODES.index("holding")  # a record's mode
CATCH_UP_STEPS_PER_CYCLE = 2  # rtcore/rt/src/cycle.rs: the model steps one cycle may take after a stall


def wait_for(condition, what: str, limit_s: float = 20.0, push=None) -> None:
    """Polls `condition` (calling `push` between polls) until true; fails after `limit_s`."""
    end = time.monotonic() + limit_s
    while not condition():
        if time.monotonic() > end:
            pytest.fail(f"gave up waiting for {what}")
        if push is not None:
            push()
        time.sleep(0.001)


@pytest.fixture
def bus():
    servos = [{"id": 1, "model": "MX-64", "protocol": 2, "params": {"motor_inertia": 0.0147}}]
    mock = _rtcore.MockBus(servos=servos, baudrate=1_000_000, wire_delay=False)
    mock.start()
    yield mock
    mock.stop()


def config(port: str, **overrides) -> dict:
    joint = {"id": 1, "model": "MX-64", "virtual_inertia": INERTIA, "virtual_damping": DAMPING,
             "virtual_coulomb": 0.0, "axis": "x", "lever_arm": LEVER}
    cfg = {"port": port, "rate_hz": RATE_HZ, "rt_priority": 0, "lock_memory": False,
           "sync_read_divisor": 5, "stale_timeout_ms": 1000.0, "joints": [joint],
           # The simulated bus answers from a thread of its own, which a loaded machine can starve
           # past the default 100 ms: the recovery's hold (servo_silent) is not under test here.
           "faults": {"servo_silent_ms": 2000.0}}
    cfg.update(overrides)
    return cfg


def run_with_force(loop, fx: float, cycles: int) -> None:
    sink = loop.force_sink()
    start = loop.heartbeat()
    wait_for(lambda: loop.heartbeat() >= start + cycles, f"{cycles} cycles",
             push=lambda: sink.push(time.monotonic_ns(), [fx, 0, 0, 0, 0, 0]))


def test_goal_positions_follow_the_model_for_a_pushed_force(bus):
    loop = _rtcore.AdmittanceLoop(config(bus.port_path))
    loop.start()
    run_with_force(loop, 1.5, 200)
    loop.stop("hold")
    rec = loop.drain_telemetry()
    assert len(rec) >= 200 and np.all(np.diff(rec["cycle"]) == 1)
    assert np.all(rec["fault"] == 0), f"the state guard held the joint (fault bits {set(rec['fault'].tolist())})"
    assert np.all(rec["mode"] == 0), "the loop held: no force sample for stale_timeout_ms (the pusher stalled)"
    h = 1.0 / RATE_HZ
    # plant::admittance with F = 0, on the torque each cycle used: the velocity first (damping
    # implicit, ω' = (ω + h·τ/I)/(1 + h·B/I)), then θ += h·ω'; one step per deadline since the
    # last cycle, whatever started the cycle: `deadline_ns` is the model's time. After an overrun
    # the skipped deadlines are caught up at most CATCH_UP_STEPS_PER_CYCLE a cycle, and a stall of
    # more than MAX_CATCH_UP_STEPS loses its time: the model's time jumps to the deadline after
    # that cycle's (two) steps (docs/realtime.md). So a cycle took min(its model-time steps, 2).
    # A cycle that held on a stale force (mode holding: this test's pushing thread stalled on a
    # loaded machine) stops the model instead.
    deadline = rec["deadline_ns"].astype(np.int64)
    steps = np.minimum(np.round(np.diff(deadline) / (1e9 / RATE_HZ)).astype(int), CATCH_UP_STEPS_PER_CYCLE)
    omega_want, theta_want = rec["omega"][:-1].copy(), rec["theta"][:-1].copy()
    for i, n in enumerate(steps):
        for _ in range(n):
            theta_want[i], omega_want[i] = virtual_joint.step(theta_want[i], omega_want[i], rec["torque"][i + 1],
                                                              INERTIA, DAMPING, 0.0, h)
    held = rec["mode"][1:] != 0
    omega_want[held], theta_want[held] = 0.0, rec["theta"][:-1][held]
    np.testing.assert_allclose(rec["omega"][1:], omega_want, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(rec["theta"][1:], theta_want, rtol=1e-9, atol=1e-12)
    assert rec["torque"].max() == pytest.approx(1.5 * LEVER)
    assert rec["omega"][-1] > 0.1, "the pushed joint moves"
    want_ticks = np.clip(2048 + np.round(rec["theta"] * 4096 / (2 * math.pi)), 0, 4095)
    np.testing.assert_array_equal(rec["goal_tick"], want_ticks)
    # The last SyncWrite reaches the servo's control table (the mock decodes it on its own thread).
    wait_for(lambda: bus.servo_state(1)["goal_tick"] == rec["goal_tick"][-1], "the last goal on the servo")
    read = rec["present_tick"][rec["present_tick"] != -1]
    assert len(read) > 0 and np.all((read >= 0) & (read <= 4095))
    stats = loop.stats()
    # Every reply the simulated bus sent parsed and every write went out: no corrupt, error-status,
    # I/O or write failure. A reply can miss its cycle when a loaded machine starves the bus's
    # thread (a timeout, counted, retried next cycle: at load 30 more than half did), so timeouts
    # are not counted against the loop; that reads work at all is the positions read above.
    kinds = stats["bus_error_kinds"]
    assert {k: n for k, n in kinds.items() if k != "read_timeout" and n} == {}, stats
    assert stats["sync_reads"] > 0 and stats["sensor_stale_events"] == 0, stats
    assert stats["latency_us"]["count"] > 0


def test_stale_force_holds_the_position(bus):
    loop = _rtcore.AdmittanceLoop(config(bus.port_path, stale_timeout_ms=20.0))
    loop.start()
    run_with_force(loop, 3.0, 30)
    # No more samples: the data goes stale, the joint holds. A loaded machine can also pause this
    # test's pushing thread past 20 ms while it pushes: a real hold that the next sample ended, so
    # the hold under test is the one the loop is in now, and every hold is one stale event.
    wait_for(lambda: loop.stats()["mode"] == "holding", "the hold on stale force")
    held_from, events = loop.heartbeat(), loop.stats()["sensor_stale_events"]
    wait_for(lambda: loop.heartbeat() >= held_from + 30, "30 held cycles")
    loop.stop("hold")
    rec = loop.drain_telemetry()
    held = rec[rec["cycle"] >= held_from]
    assert len(held) >= 30 and np.all(held["mode"] == HOLDING)
    assert np.all(held["omega"] == 0.0)
    assert np.all(held["theta"] == held["theta"][0])
    assert np.all(held["goal_tick"] == held["goal_tick"][0])
    holding = (rec["mode"] == HOLDING).astype(int)
    holds = int(holding[0]) + int(np.count_nonzero(np.diff(holding) == 1))
    stats = loop.stats()
    assert stats["telemetry_drops"] == 0 and events >= 1
    assert stats["sensor_stale_events"] == events == holds, "one stale event per hold, none while it lasts"


def test_stats_has_every_key_of_the_daemon_contract(bus):
    loop = _rtcore.AdmittanceLoop(config(bus.port_path))
    loop.start()
    run_with_force(loop, 0.5, 20)
    stats = loop.stats()
    loop.stop()
    for key in ("cycles", "overruns", "rate_hz", "period_us", "latency_us", "bus_errors",
                "sensor_samples", "sensor_stale_events", "rt"):
        assert key in stats, key
    for key in ("period_us", "latency_us"):
        assert set(stats[key]) >= {"p50", "p99", "p999", "max"}
        assert stats[key]["p50"] <= stats[key]["p99"] <= stats[key]["p999"] <= stats[key]["max"]
    assert stats["rt"] == {"policy": "SCHED_OTHER", "priority": 0, "memory_locked": False, "cpu": None}
    assert stats["rate_hz"] == RATE_HZ and stats["cycles"] >= 20 and stats["sensor_samples"] > 0


@pytest.mark.parametrize("trigger", ["sample", "schedule"])
def test_a_sample_starts_the_cycle_unless_the_loop_keeps_to_its_schedule(bus, trigger):
    loop = _rtcore.AdmittanceLoop(config(bus.port_path, trigger=trigger))
    loop.start()
    run_with_force(loop, 0.5, 100)
    loop.stop()
    stats = loop.stats()
    t = stats["trigger"]
    assert t["mode"] == trigger and t["phase_lock"] == (trigger == "sample")
    assert sum(t["starts"].values()) == stats["cycles"]
    if trigger == "schedule":
        assert t["starts"]["schedule"] == stats["cycles"]
    else:
        # The pushes (about one a millisecond; 500 Hz loop) wake the loop: cycles start on a
        # sample's arrival, and the sensor's period is known.
        assert t["starts"]["schedule"] == 0 and t["starts"]["arrival"] > 0
        assert t["sensor_interval_us"] > 0


def test_fifo_is_obtained_or_refused_with_a_warning(bus):
    loop = _rtcore.AdmittanceLoop(config(bus.port_path, rt_priority=10))
    loop.start()
    rt, warnings = loop.stats()["rt"], loop.warnings()
    loop.stop()
    if rt["policy"] == "SCHED_FIFO":
        assert rt["priority"] == 10
    else:
        assert any("SCHED_FIFO" in w for w in warnings), warnings


def test_stop_policies_hold_or_disable_torque(bus):
    loop = _rtcore.AdmittanceLoop(config(bus.port_path))
    loop.start()
    wait_for(lambda: bus.servo_state(1)["torque_enabled"], "torque on after goal = present")
    loop.stop("hold")
    assert bus.servo_state(1)["torque_enabled"]
    again = _rtcore.AdmittanceLoop(config(bus.port_path))
    again.start()
    again.stop("torque_off")
    wait_for(lambda: not bus.servo_state(1)["torque_enabled"], "torque off on the servo")
    assert not again.running()


def test_tare_measures_the_bias_the_loop_then_removes(bus):
    loop = _rtcore.AdmittanceLoop(config(bus.port_path))
    loop.start()
    loop.tare(samples=20)
    sink = loop.force_sink()
    wait_for(lambda: loop.params()["bias"][0] != 0.0, "the tare",
             push=lambda: sink.push(time.monotonic_ns(), [2.5, -1.0]))
    run_with_force(loop, 2.5, 10)
    loop.stop()
    assert loop.params()["bias"][:3] == [2.5, -1.0, 0.0]
    assert loop.drain_telemetry()["force"][-1] == 0.0


def test_a_silent_bus_is_a_device_error_and_start_can_be_retried(bus):
    cfg = config(bus.port_path, start_timeout_ms=50.0)
    cfg["joints"][0]["id"] = 9
    loop = _rtcore.AdmittanceLoop(cfg)
    with pytest.raises(DeviceError, match=r"id\(s\) \[9\]"):
        loop.start()
    assert not loop.running()
