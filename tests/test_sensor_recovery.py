"""Force-sensor readers under the simulated sensor's faults: unplug and replug (serial and slcan),
silence, saturation (hold and pass), DAQ status errors, garbage and bad checksums. Each is
counted in stats(), told once through the rate-limited event hook, and never turns into a
wrong force. Every wait is on the readers' own counters, never on a duration.
"""

from __future__ import annotations

import os
import threading

import pytest

from admittance.drivers import optoforce as of
from admittance.drivers.can_sensor import CanForceReader
from admittance.drivers.force_reader import EventLog, ForceSensor, SampleBuffer
from admittance.errors import ConfigError, DeviceError
from admittance.mockbench.hand import make_profile
from admittance.mockbench.simulated_sensor import ForceModel, SimulatedOptoForce, SimulatedSlcanOptoForce

from helpers import wait_until

CPN = 451.89
# 0.21 N·m on a 0.105 m lever: 2 N on x, 904 counts.
STILL = "still:torque=0.21"


class Events:
    """An event hook that keeps what it is told, for the assertions."""

    def __init__(self) -> None:
        self.told: list[tuple[str, str]] = []
        self._lock = threading.Lock()

    def __call__(self, kind: str, message: str) -> None:
        with self._lock:
            self.told.append((kind, message))

    def kinds(self) -> list[str]:
        with self._lock:
            return [kind for kind, _ in self.told]


@pytest.fixture
def sim(tmp_path):
    sensor = SimulatedOptoForce(make_profile(STILL), ForceModel(), rate_hz=1000, link=str(tmp_path / "ttyACM"))
    with sensor:
        yield sensor


def reader_on(sim, **options) -> tuple[of.OptoForceSerialReader, SampleBuffer, Events]:
    buffer, events = SampleBuffer(), Events()
    reader = of.OptoForceSerialReader(sim.link_path, CPN, buffer, **options)
    reader.set_event_hook(events, repeat_s=600.0)  # a slow run still tells each kind once
    return reader, buffer, events


def test_an_unplugged_sensor_is_reopened_with_backoff_and_recovers_on_replug(sim):
    reader, buffer, events = reader_on(sim)
    with reader:
        assert buffer.wait_for(20, timeout=20)
        assert sim.unplug()
        assert wait_until(lambda: reader.stats()["reopen_failures"] >= 2)
        stats = reader.stats()
        assert stats["state"] == "reconnecting" and stats["disconnects"] == 1 and reader.error
        assert "no such device" in stats["last_error"], "the link is gone while unplugged"
        pushed = stats["samples_pushed"]
        assert sim.replug()  # a new pty (the kernel may give it the old number)
        assert os.path.realpath(sim.link_path) == sim.port_path
        assert wait_until(lambda: buffer.total > pushed + 20), "samples flow again from the new pty"
        stats = reader.stats()
        assert stats["state"] == "streaming" and stats["reconnects"] == 1 and reader.error is None
        assert stats["last_error"], "the last failure stays readable"
    assert buffer.snapshot()[-1][1][0] == pytest.approx(2.0, abs=0.01)
    assert events.kinds().count("disconnected") == 1 and events.kinds().count("reconnected") == 1


class _FlakyDevice(ForceSensor):
    """Opens fine at start, fails while polling, then refuses ``refusals`` reopens."""

    kind = "flaky"

    def __init__(self, refusals: int):
        super().__init__(SampleBuffer())
        self.refusals = refusals
        self.opens = 0
        self.delays: list[float] = []

    def _open(self) -> None:
        self.opens += 1
        if self.opens > 1 and self.refusals > 0:
            self.refusals -= 1
            raise DeviceError("cannot open the flaky sensor: no such device")

    def _poll(self) -> None:
        if self.opens == 1:
            raise OSError(5, "Input/output error")
        self._stop_event.wait(0.01)

    def _close(self) -> None:
        pass


def test_the_reopen_backoff_doubles_up_to_its_ceiling():
    sensor = _FlakyDevice(refusals=8)
    wait = sensor._stop_event.wait

    def record(delay=None):
        if delay is not None and delay >= sensor.reconnect_first_s:
            sensor.delays.append(delay)
            return wait(0)  # the schedule is under test, not the clock
        return wait(delay)

    sensor._stop_event.wait = record
    with sensor:
        assert wait_until(lambda: sensor.reconnects == 1)
    assert sensor.delays[:9] == [0.05, 0.1, 0.2, 0.4, 0.8, 1.6, 2.0, 2.0, 2.0]
    assert sensor.reopen_failures == 8 and sensor.disconnects == 1


def test_events_are_rate_limited_per_kind_and_count_what_was_held_back():
    now = [0.0]
    told: list[tuple[str, str]] = []
    events = EventLog(lambda kind, message: told.append((kind, message)), repeat_s=5.0, clock=lambda: now[0])
    for _ in range(100):
        events("saturated", "saturated samples")
    events("stale", "no samples")
    now[0] = 6.0
    events("saturated", "saturated samples")
    assert told == [("saturated", "saturated samples"), ("stale", "no samples"),
                    ("saturated", "saturated samples (99 more since the last report)")]
    assert events.counts == {"saturated": 101, "stale": 1}


def test_a_failing_hook_does_not_stop_the_events():
    def broken(kind: str, message: str) -> None:
        raise RuntimeError("the hook is broken")

    events = EventLog(broken)
    events("stale", "no samples")
    assert events.counts == {"stale": 1}


def test_silence_is_counted_and_told_then_the_stream_is_fresh_again(sim):
    reader, buffer, events = reader_on(sim)
    reader.stale_after_s = 0.1
    with reader:
        assert buffer.wait_for(10, timeout=20)
        assert wait_until(lambda: not reader.stats()["stale"])
        before = reader.stats()["stale_events"]  # a starved machine may have paused the stream already
        sim.silence(True)
        assert wait_until(lambda: reader.stats()["stale"])
        assert reader.stats()["stale_events"] == before + 1 and reader.stats()["disconnects"] == 0
        sim.silence(False)
        assert wait_until(lambda: not reader.stats()["stale"])
    assert events.kinds().count("stale") == 1 and events.kinds().count("fresh") == 1, "each told once"


@pytest.mark.parametrize("policy", ["hold", "pass"])
def test_saturated_samples_are_held_by_default_and_passed_when_asked(sim, policy):
    reader, buffer, events = reader_on(sim, saturation=policy)
    with reader:
        assert buffer.wait_for(10, timeout=20)
        sim.saturate(True)
        assert wait_until(lambda: reader.stats()["overloads"] >= 50)
        sim.saturate(False)
        overloads = reader.stats()["overloads"]
        total = buffer.total
        assert buffer.wait_for(total + 10, timeout=20)
    saturated = [f for _, f in buffer.snapshot() if f[0] > 70.0]
    if policy == "hold":
        assert saturated == [], "a saturated reading never reaches the sink"
        assert reader.stats()["samples_pushed"] + overloads <= reader.stats()["samples"]
    else:
        assert saturated and saturated[0][0] == pytest.approx(32767 / CPN)  # 72.5 N, as read
    told = [message for kind, message in events.told if kind == "saturated"]
    assert len(told) == 1, "told once, not once per sample"
    assert "overload flag on fx" in told[0] and ("held" if policy == "hold" else "passed on") in told[0]


def test_a_count_at_the_int16_limit_is_saturated_even_without_its_flag():
    converter = of.SampleConverter(CPN)
    frames = of.encode_sample(1, 0, (32767, 0, 0)) + of.encode_sample(2, 0, (-32768, 5, 5)) + of.encode_sample(3, 0, (100, 0, 0))
    assert converter.forces(frames) == [pytest.approx([100 / CPN, 0.0, 0.0, 0.0, 0.0, 0.0])]
    assert converter.overloads == 2
    with pytest.raises(ConfigError, match="saturation"):
        of.SampleConverter(CPN, saturation="clip")


def test_daq_errors_garbage_and_bad_checksums_never_become_a_force(sim):
    reader, buffer, events = reader_on(sim)
    with reader:
        assert buffer.wait_for(10, timeout=20)
        sim.set_status(0x2000)  # DAQ error
        assert wait_until(lambda: reader.stats()["status_faults"] >= 20)
        sim.set_status(0)
        sim.inject_garbage(300)
        assert wait_until(lambda: reader.stats()["resyncs"] >= 1)
        sim.corrupt(5)
        assert wait_until(lambda: reader.stats()["checksum_errors"] >= 5)
        total = buffer.total
        assert buffer.wait_for(total + 10, timeout=20)
    assert all(f == pytest.approx([904 / CPN, 0, 0, 0, 0, 0]) for _, f in buffer.snapshot())
    assert "status_fault" in events.kinds() and reader.stats()["disconnects"] == 0


def test_the_slcan_can_reader_recreates_its_bus_after_the_adapter_was_unplugged(tmp_path):
    sim = SimulatedSlcanOptoForce(make_profile(STILL), ForceModel(), rate_hz=500, link=str(tmp_path / "ttyCAN"))
    buffer = SampleBuffer()
    with sim:
        reader = CanForceReader(sim.link_path, CPN, buffer, interface="slcan")
        with reader:
            assert buffer.wait_for(10, timeout=20)
            sim.unplug()
            assert wait_until(lambda: reader.stats()["disconnects"] == 1)
            pushed = buffer.total
            sim.replug()
            assert wait_until(lambda: buffer.total > pushed + 10), "frames flow again through a new python-can bus"
            assert reader.stats()["reconnects"] == 1 and reader.stats()["state"] == "streaming"


class _OpensThenFails(_FlakyDevice):
    """Every reopen succeeds, and the device fails again before a single sample."""

    def _poll(self) -> None:
        raise OSError(5, "Input/output error")


def test_a_device_that_fails_right_after_each_reopen_still_backs_off():
    sensor = _OpensThenFails(refusals=0)
    event = sensor._stop_event

    def record(delay=None):
        sensor.delays.append(delay)
        if len(sensor.delays) == 7:
            event.set()  # seen enough: the reader stops
        return event.is_set()

    event.wait = record
    with sensor:
        assert wait_until(lambda: not sensor.running)
    assert sensor.delays == [0.05, 0.1, 0.2, 0.4, 0.8, 1.6, 2.0], "never back to 0.05 s without a sample"
    assert sensor.reconnects == 6 and sensor.disconnects == 7
