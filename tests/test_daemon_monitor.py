"""`admittance monitor`'s view: ANSI redraw on a terminal, plain lines otherwise; no data = error.
Also the `set` command's NAME=VALUE parsing."""

from __future__ import annotations

import io

import pytest

from admittance.daemon.cli import parse_assignments
from admittance.daemon.monitor import CLEAR, View, run_monitor, screen
from admittance.errors import ConfigError, DeviceError

STATE = {"cycle": 3, "joints": [{"id": 1, "t": 1.0, "force": 1.5, "tau": 0.16, "theta": 0.5, "omega": -0.2,
                                 "goal_tick": 2374}]}
STATS = {"cycles": 1000, "overruns": 2, "rate_hz": 999.7, "bus_errors": 0, "sensor_samples": 990,
         "sensor_stale_events": 1, "period_us": {"p50": 1000.0, "p99": 1040.0, "p999": 1100.0, "max": 1500.0},
         "latency_us": {"p50": 600.0, "p99": 900.0, "p999": 950.0, "max": 990.0},
         "rt": {"policy": "SCHED_OTHER", "priority": 0, "memory_locked": False}}


class Feed:
    def __init__(self, batches):
        self.batches = list(batches)

    def drain(self):
        return self.batches.pop(0) if self.batches else []


def test_screen_shows_joints_and_timing():
    text = screen("bench/arm1", STATE, STATS)
    assert "joint   1" in text and "+28.65°" in text and "present     -" in text
    assert "999.7 Hz" in text and "overruns 2" in text and "SCHED_OTHER" in text
    assert "waiting for bench/arm1/state" in screen("bench/arm1", None, None)


def test_the_rendering_error_has_its_line_in_both_modes():
    stats = {**STATS, "rendering_rms": {"1": 0.00123, "2": 0.0105}}
    assert "render" in screen("p", STATE, stats) and "joint 1   1.23 mrad" in screen("p", STATE, stats)
    plain = io.StringIO()
    View("p", plain, False).feed("stats", stats)
    assert "joint 2  10.50 mrad" in plain.getvalue()
    assert "render" not in screen("p", STATE, STATS), "no line before the daemon reports one"


def test_tty_mode_redraws_and_plain_mode_prints_lines():
    tty, plain = io.StringIO(), io.StringIO()
    for out, is_tty in ((tty, True), (plain, False)):
        view = View("p", out, is_tty)
        view.feed("state", STATE)
        view.feed("stats", STATS)
        view.render(0.0)
        view.render(0.1)  # plain mode: rate-limited
    assert tty.getvalue().count(CLEAR) == 2
    assert CLEAR not in plain.getvalue()
    assert plain.getvalue().count("joint   1") == 1 and "999.7 Hz" in plain.getvalue()


def test_run_monitor_fails_clearly_when_nothing_arrives():
    with pytest.raises(DeviceError, match="no state or stats received on p/"):
        run_monitor(Feed([]), View("p", io.StringIO(), False), duration=0.2)
    out = io.StringIO()
    assert run_monitor(Feed([[("state", STATE)]]), View("p", out, False), duration=0.2) == 0
    assert "joint   1" in out.getvalue()


def test_set_assignments_parse_numbers_and_lists():
    assert parse_assignments(["virtual_damping=0.1", "1.virtual_inertia=2e-2", "bias=0,0,0,0,0,1"]) == {
        "virtual_damping": 0.1, "1.virtual_inertia": 0.02, "bias": [0.0, 0.0, 0.0, 0.0, 0.0, 1.0]}
    for bad in ("virtual_damping", "=1", "virtual_damping=soft"):
        with pytest.raises(ConfigError):
            parse_assignments([bad])
