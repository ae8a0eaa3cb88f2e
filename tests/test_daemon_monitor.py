"""`admittance monitor`'s view, fed dicts against a fake clock: units, names, mode and faults,
parameters, a daemon gone (liveliness withdrawn) or stale, in redraw and plain modes; no data =
error. Also the `set` command's NAME=VALUE parsing and the words of `get`/`set`/`tare`."""

from __future__ import annotations

import io

import pytest

from admittance.daemon import monitor
from admittance.daemon.cli import parse_assignments
from admittance.daemon.monitor import CLEAR, BenchSeen, View, run_monitor, screen_many
from admittance.daemon.replies import params_table, set_reply_text, tare_reply_text
from admittance.errors import ConfigError, DeviceError

STATE = {"cycle": 3, "mode": "running",
         "joints": [{"id": 1, "t": 1.0, "force": 1.5, "tau": 0.16, "theta": 0.5, "omega": -0.2, "goal_tick": 2374}]}
STATS = {"cycles": 1000, "overruns": 2, "rate_hz": 999.7, "bus_errors": 3, "sensor_samples": 990,
         "bus_error_kinds": {"write": 0, "read_timeout": 2, "read_corrupt": 1},
         "sensor_stale_events": 1, "period_us": {"p50": 10.0, "p99": 40.0, "p999": 100.0, "max": 500.0},
         "latency_us": {"p50": 600.0, "p99": 900.0, "p999": 950.0, "max": 990.0}, "mode": "running",
         "faults": {"model_state_invalid": 0},
         "rt": {"policy": "SCHED_OTHER", "priority": 0, "memory_locked": False}}
PARAMS = {"params": {"1.virtual_inertia": 0.0147, "1.virtual_damping": 0.035, "1.virtual_coulomb": 0.084,
                     "1.position_max": 3.1, "deadband": 0.0, "ramp_time_s": 0.5}}


class Clock:
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


class Feed:
    def __init__(self, batches):
        self.batches = list(batches)

    def drain(self):
        return self.batches.pop(0) if self.batches else []


def fed_view(tty=False, degrees=False, bench="bench/arm1", prefix="bench/arm1"):
    clock = Clock()
    out = io.StringIO()
    view = View(prefix, out, tty, degrees=degrees, clock=clock)
    view.feed("alive", {"alive": True}, bench)
    view.feed("state", STATE, bench)
    view.feed("stats", STATS, bench)
    view.feed("params", PARAMS, bench)
    return view, clock, out


def test_the_screen_shows_si_units_one_name_per_quantity_mode_faults_and_params():
    view, clock, _ = fed_view()
    text = screen_many("bench/arm1", view.benches, clock.now)
    assert "model +0.5000 rad  -0.200 rad/s" in text and "°" not in text
    assert "wake-up lateness" in text and "force-to-write latency" in text and "stale-sensor holds 1" in text
    assert "jitter" not in text
    assert "3 bus errors (2 read timeouts, 1 corrupt replies)" in text
    assert "== bench/arm1  alive\nmode running  fault events none" in text
    assert "params  joint 1: virtual_inertia 0.0147 kg·m²  virtual_damping 0.035 N·m·s/rad" in text
    assert "position_max" not in text, "the virtual parameters only; `get` has them all"
    assert "waiting for bench/arm1/state" in screen_many("bench/arm1", {}, 0.0)


def test_every_line_fits_80_columns_even_with_wild_values_and_long_names():
    view, clock, _ = fed_view(bench="lab/bench/arm1", prefix="lab")
    wild = {**STATE, "mode": "faulted", "joints": [
        {"id": 253, "t": 1.0, "force": -12345.678, "tau": 9876.5, "theta": -3.14159, "omega": 123.456,
         "goal_tick": 4095, "goal": -3.1, "position": -3.14, "present_tick": 0, "rendering_rms": 0.25, "fault": 3}]}
    view.feed("state", wild, "lab/bench/arm1")
    view.feed("stats", {**STATS, "rendering_rms": {"253": 0.25}, "faults": {"model_state_invalid": 12345},
                        "period_us": {"p50": 12345.6, "p99": 99999.9, "p999": 123456.7, "max": 999999.9}},
              "lab/bench/arm1")
    view.feed("params", {"params": {**PARAMS["params"], "253.virtual_inertia": 0.0147,
                                    "253.virtual_damping": 0.035, "253.virtual_coulomb": 0.084,
                                    "253.servo_compensation": 1.0, "253.position_min": -3.1}}, "lab/bench/arm1")
    for degrees in (False, True):
        text = screen_many("lab", view.benches, clock.now, monitor.Units(degrees))
        long = [line for line in text.splitlines() if len(line) > monitor.WIDTH]
        assert long == [], long
        assert "-12345.678" not in text.replace("\n", " ") or "-12345.678 N" in text  # never split mid-number
    clock.now += 5.0
    view.feed("alive", {"alive": False}, "lab/bench/arm1")
    assert max(len(line) for line in screen_many("lab", view.benches, clock.now).splitlines()) <= monitor.WIDTH


def test_goal_and_read_angles_are_shown_in_radians_not_ticks():
    view, clock, _ = fed_view()
    view.feed("state", {**STATE, "joints": [{**STATE["joints"][0], "goal": 0.4987, "position": 0.4901,
                                             "present_tick": 2367}]}, "bench/arm1")
    text = screen_many("bench/arm1", view.benches, clock.now)
    assert "goal +0.4987 rad" in text and "read +0.4901 rad" in text
    assert "2374" not in text and "2367" not in text


@pytest.mark.parametrize("angle, flag", [(3.095, "AT MAX"), (-3.099, "AT MIN"), (3.0, None), (-3.0, None)])
def test_a_joint_at_its_position_limit_is_flagged(angle, flag):
    view, clock, _ = fed_view()
    view.feed("params", {"params": {**PARAMS["params"], "1.position_min": -3.1}}, "bench/arm1")
    view.feed("state", {**STATE, "joints": [{**STATE["joints"][0], "theta": angle, "position": angle}]},
              "bench/arm1")
    text = screen_many("bench/arm1", view.benches, clock.now)
    assert ("AT MAX" in text, "AT MIN" in text) == (flag == "AT MAX", flag == "AT MIN"), text


def test_degrees_everywhere_with_the_flag():
    view, clock, _ = fed_view(degrees=True)
    stats = {**STATS, "rendering_rms": {"1": 0.001}}
    view.feed("stats", stats, "bench/arm1")
    text = screen_many("bench/arm1", view.benches, clock.now, view.units)
    assert "+28.65°" in text and "-11.46 °/s" in text and "joint 1 0.057°" in text
    assert " rad " not in text.replace("N·m·s/rad", "")


def test_faults_and_the_mode_are_shown():
    view, clock, _ = fed_view()
    faulted = {**STATE, "mode": "faulted", "joints": [{**STATE["joints"][0], "fault": 1}]}
    view.feed("state", faulted, "bench/arm1")
    view.feed("stats", {**STATS, "faults": {"model_state_invalid": 2}}, "bench/arm1")
    text = screen_many("bench/arm1", view.benches, clock.now)
    assert "mode faulted  fault events model_state_invalid ×2" in text
    assert "FAULT model_state_invalid" in text


def test_a_daemon_whose_token_is_withdrawn_is_gone_and_its_values_are_marked_old():
    view, clock, _ = fed_view()
    clock.now += 0.2
    view.feed("alive", {"alive": False}, "bench/arm1")
    clock.now += 3.0
    text = screen_many("bench/arm1", view.benches, clock.now)
    assert "GONE 3.0 s ago (its liveliness token was withdrawn)" in text
    assert "values below: last received 3.2 s ago" in text and "[stale: stats 3.2 s old]" in text
    assert "mode unknown (last: running)" in text and "mode running" not in text
    view.feed("alive", {"alive": True}, "bench/arm1")
    view.feed("state", STATE, "bench/arm1")
    assert "== bench/arm1  alive" in screen_many("bench/arm1", view.benches, clock.now)


def test_values_that_stop_coming_are_stale_even_while_the_token_stays():
    view, clock, _ = fed_view()
    clock.now += monitor.STATE_STALE_S + 0.5
    text = screen_many("bench/arm1", view.benches, clock.now)
    assert "STALE: no state for 1.5 s" in text and "values below: last received 1.5 s ago" in text
    assert "[stale: stats" not in text, "the stats are not 3 s old yet"
    clock.now += 2.0
    assert "[stale: stats 3.5 s old]" in screen_many("bench/arm1", view.benches, clock.now)
    fresh = BenchSeen(state=STATE, state_at=clock.now, alive=True)
    assert fresh.status(clock.now) == "alive" and not fresh.stale(clock.now)


def test_plain_mode_prints_news_only_status_changes_params_and_new_state():
    view, clock, out = fed_view(tty=False)
    view.render()
    first = out.getvalue()
    assert first.count("joint 1 ") == 1 and "999.7 Hz" in first and "alive" in first
    assert "params  joint 1: virtual_inertia" in first
    clock.now += monitor.PLAIN_PERIOD_S
    view.render()
    assert out.getvalue() == first, "nothing new: nothing printed"
    view.feed("alive", {"alive": False}, "bench/arm1")
    clock.now += monitor.PLAIN_PERIOD_S
    view.render()
    news = out.getvalue()[len(first):]
    assert news.startswith("GONE") and "joint" not in news


def test_tty_mode_redraws_and_several_benches_are_labelled():
    tty = io.StringIO()
    clock = Clock()
    view = View("bench", tty, True, clock=clock)
    for bench in ("bench/arm2", "bench/arm1"):
        view.feed("state", STATE, bench)
        view.feed("stats", STATS, bench)
    view.render()
    view.render()
    assert tty.getvalue().count(CLEAR) == 2
    screen = tty.getvalue().split(CLEAR)[-1]
    assert "(2 benches)" in screen and screen.index("== bench/arm1") < screen.index("== bench/arm2")
    plain = io.StringIO()
    view = View("bench", plain, False, clock=clock)
    view.feed("state", STATE, "bench/arm2")
    view.render()
    assert "bench/arm2  joint 1 " in plain.getvalue()


def test_run_monitor_fails_clearly_when_nothing_arrives_and_asks_for_params():
    with pytest.raises(DeviceError, match="no state or stats received on p/"):
        run_monitor(Feed([]), View("p", io.StringIO(), False), duration=0.2)
    out = io.StringIO()
    feed = Feed([[("state", STATE)]])
    asked = []
    feed.request_params = lambda: asked.append(1)
    assert run_monitor(feed, View("p", out, False), duration=0.2) == 0
    assert "joint 1 " in out.getvalue() and asked == [1]


def test_set_assignments_parse_numbers_and_lists():
    assert parse_assignments(["virtual_damping=0.1", "1.virtual_inertia=2e-2", "bias=0,0,0,0,0,1"]) == {
        "virtual_damping": 0.1, "1.virtual_inertia": 0.02, "bias": [0.0, 0.0, 0.0, 0.0, 0.0, 1.0]}
    for bad in ("virtual_damping", "=1", "virtual_damping=soft"):
        with pytest.raises(ConfigError):
            parse_assignments([bad])


def test_set_and_tare_reply_in_words():
    before = {"1.virtual_damping": 0.05, "2.virtual_damping": 0.05, "1.position_max": 3.1,
              "1.servo_compensation": 0.0, "ramp_time_s": 0.5, "bias": [0.0] * 6}
    after = {**before, "1.virtual_damping": 0.08, "2.virtual_damping": 0.08, "1.position_max": 2.0,
             "1.servo_compensation": 1.0}
    text = set_reply_text({"virtual_damping": 0.08, "1.limits.position_max": 2.0, "1.servo_compensation": 1},
                          {"accepted": True}, before, after)
    assert text.splitlines() == [
        "accepted: 1.virtual_damping 0.05 → 0.08 N·m·s/rad, ramping over 0.5 s",
        "accepted: 2.virtual_damping 0.05 → 0.08 N·m·s/rad, ramping over 0.5 s",
        "accepted: 1.position_max 3.1 → 2 rad, at once",
        "accepted: 1.servo_compensation 0 → 1, blending in over 0.5 s"]
    assert set_reply_text({"deadband": 1}, {"accepted": False, "reason": "deadband: must be >= 0"}, {}, {}) == \
        "refused: deadband: must be >= 0"
    assert tare_reply_text(50, {"accepted": True}).startswith("accepted: the next 50 force samples")
    assert tare_reply_text(50, {"accepted": False, "reason": "busy"}) == "refused: busy"


def test_get_prints_joints_first_then_loop_wide_keys_with_units():
    table = params_table({"deadband": 0.5, "2.virtual_inertia": 0.02, "1.virtual_inertia": 0.0147,
                          "bias": [0.0, 1.5, 0, 0, 0, 0]}).splitlines()
    assert [line.split()[0] for line in table] == ["1.virtual_inertia", "2.virtual_inertia", "bias", "deadband"]
    assert table[0].endswith("kg·m²") and table[3].endswith("N") and "[0, 1.5, 0, 0, 0, 0]" in table[2]


def test_faults_have_their_line_in_both_modes_once_there_is_one():
    """docs/faults.md: the mode, the counts of each fault kind seen, how long the bus is lost."""
    quiet = {**STATS, "mode": "running", "faults": {"servo_error": 0, "bus_lost": 0}}
    assert not any(line.startswith("faults") for line in monitor.stats_lines(quiet))
    sick = {**STATS, "mode": "faulted", "faults": {"servo_error": 2, "bus_lost": 1, "torque_off": 0},
            "bus": {"state": "lost", "lost_for_s": 1.25}}
    line = next(line for line in monitor.stats_lines(sick) if line.startswith("faults"))
    assert line == "faults  faulted  bus_lost 1  servo_error 2  bus lost for 1.2 s"
    plain = io.StringIO()
    View("p", plain, False).feed("stats", sick)
    assert "faults  faulted  bus_lost 1  servo_error 2" in plain.getvalue()
