"""The Rust force readers (``_rtcore.ForceReader`` via ``NativeForceReader``) over ptys, under the
simulated sensor's faults: unplug and replug (serial and slcan), garbage and bad checksums,
saturation (hold and pass), DAQ status errors, a stale stream, a burst of 1000 frames at once, a
sensor at half its rate, and counters that jump. The same faults the Python readers' tests use
(tests/test_sensor_recovery.py), from the same mock bench. Every wait is on the reader's own
counters (bounded), never on a duration; a SocketCAN test runs where a vcan interface exists.
"""

from __future__ import annotations

import os
import subprocess

import pytest

from admittance.drivers import optoforce as of
from admittance.drivers.native_sensor import NativeForceReader, choose_reader, rust_transport
from admittance.errors import ConfigError, DeviceError
from admittance.mockbench.hand import make_profile
from admittance.mockbench.simulated_sensor import ForceModel, SimulatedOptoForce, SimulatedSlcanOptoForce

from helpers import wait_until
from test_sensor_recovery import Events  # the event hook that keeps what it is told

CPN = 451.89
STILL = "still:torque=0.21"  # 0.21 N·m on a 0.105 m lever: 2 N on x


def rust_reader(port: str, *, kind: str = "optoforce", **section) -> tuple[NativeForceReader, Events]:
    section = {"kind": kind, "port": port, "counts_per_newton": [CPN] * 3} | section
    reader = NativeForceReader.from_config(section, None)
    events = Events()
    reader.set_event_hook(events, repeat_s=600.0)
    return reader, events


def captured_until(reader: NativeForceReader, n: int, timeout: float = 20.0) -> list:
    """Samples captured until there are at least ``n`` (bounded by ``timeout``)."""
    got: list = []

    def enough() -> bool:
        got.extend(reader.take_captured())
        return len(got) >= n

    wait_until(enough, timeout=timeout)
    return got


@pytest.fixture
def sim(tmp_path):
    sensor = SimulatedOptoForce(make_profile(STILL), ForceModel(), rate_hz=1000, link=str(tmp_path / "ttyACM"))
    with sensor:
        yield sensor


def test_the_rust_reader_converts_counts_to_newtons_and_says_which_path_runs(sim):
    reader, _ = rust_reader(sim.link_path)
    with reader:
        samples = captured_until(reader, 50)
        stats = reader.stats()
    assert len(samples) >= 50
    assert samples[-1][1][0] == pytest.approx(2.0, abs=0.01)
    assert stats["reader"] == "rust-serial" and reader.reader_path == "rust-serial"
    assert stats["samples_pushed"] >= 50 and stats["checksum_errors"] == 0 and stats["kind"] == "optoforce"


def test_an_unplugged_sensor_is_reopened_with_backoff_and_recovers_on_replug(sim):
    reader, events = rust_reader(sim.link_path)
    with reader:
        assert len(captured_until(reader, 20)) >= 20
        assert sim.unplug()
        assert wait_until(lambda: reader.stats()["reopen_failures"] >= 2)
        stats = reader.stats()
        assert stats["state"] == "reconnecting" and stats["disconnects"] == 1 and stats["error"]
        pushed = stats["samples_pushed"]
        assert sim.replug()
        assert wait_until(lambda: reader.stats()["samples_pushed"] > pushed + 20), "samples flow again from the new pty"
        stats = reader.stats()
        assert stats["state"] == "streaming" and stats["reconnects"] == 1 and stats["error"] is None
    assert events.kinds().count("disconnected") == 1 and events.kinds().count("reconnected") == 1


def test_garbage_bad_checksums_and_daq_errors_never_become_a_force(sim):
    reader, events = rust_reader(sim.link_path)
    with reader:
        captured_until(reader, 20)
        sim.set_status(0x2000)
        assert wait_until(lambda: reader.stats()["status_faults"] >= 5)
        sim.set_status(0)
        sim.inject_garbage(300)
        sim.corrupt(5)
        assert wait_until(lambda: reader.stats()["checksum_errors"] >= 5 and reader.stats()["skipped_bytes"] >= 300)
        reader.take_captured()
        samples = captured_until(reader, 20)
    assert all(f[0] == pytest.approx(2.0, abs=0.05) for _, f in samples), "only true forces reach the sink"
    assert "status_fault" in events.kinds()


@pytest.mark.parametrize("policy", ["hold", "pass"])
def test_saturated_samples_are_held_by_default_and_passed_when_asked(sim, policy):
    reader, events = rust_reader(sim.link_path, saturation=policy)
    with reader:
        captured_until(reader, 10)
        sim.saturate(True)
        assert wait_until(lambda: reader.stats()["overloads"] >= 20)
        sim.saturate(False)
        pushed_during = reader.take_captured()
    big = [f for _, f in pushed_during if abs(f[0]) > 50]
    assert bool(big) == (policy == "pass")
    assert "saturated" in events.kinds()


def test_a_silent_sensor_is_stale_once_and_fresh_again(sim):
    reader, events = rust_reader(sim.link_path)
    reader.stale_after_s = 0.05
    with reader:
        captured_until(reader, 10)
        assert wait_until(lambda: not reader.stats()["stale"])
        # A loaded machine can starve the simulated DAQ's thread past the stale limit before the
        # silence: a real (counted) stale event, over when it sends again. Count from here.
        before = reader.stats()["stale_events"]
        sim.silence(True)
        assert wait_until(lambda: reader.stats()["stale"])
        sim.silence(False)
        assert wait_until(lambda: not reader.stats()["stale"])
        stats = reader.stats()
    assert stats["stale_events"] == before + 1, "one silence, one stale event"
    assert events.kinds().count("stale") == 1 and events.kinds().count("fresh") == 1


def _pty_pair(tmp_path):
    master, slave = os.openpty()
    return master, os.ttyname(slave), slave


def test_a_burst_of_1000_frames_at_once_is_read_whole(tmp_path):
    master, path, slave = _pty_pair(tmp_path)
    try:
        reader, _ = rust_reader(path)
        with reader:
            burst = b"".join(of.encode_sample(k, 0, [904, 0, 0]) for k in range(1000))
            os.write(master, burst)
            samples = captured_until(reader, 1000)
            stats = reader.stats()
    finally:
        os.close(master)
        os.close(slave)
    assert len(samples) == 1000 and stats["checksum_errors"] == 0 and stats["counter_gaps"] == 0
    assert stats["samples_dropped"] == 0


def test_counters_that_jump_are_counted_and_the_forces_still_flow(tmp_path):
    master, path, slave = _pty_pair(tmp_path)
    try:
        reader, _ = rust_reader(path)
        with reader:
            counters = [0, 1, 2, 500, 501, 65535, 0, 7]  # two jumps, one wrap (no gap), one jump
            os.write(master, b"".join(of.encode_sample(c, 0, [452, 0, 0]) for c in counters))
            samples = captured_until(reader, len(counters))
            stats = reader.stats()
    finally:
        os.close(master)
        os.close(slave)
    assert len(samples) == len(counters) and stats["counter_gaps"] == 3
    assert all(f[0] == pytest.approx(452 / CPN) for _, f in samples)
    assert all(b[0] >= a[0] for a, b in zip(samples, samples[1:])), "stamped on CLOCK_MONOTONIC, never the sensor's"


def test_a_sensor_at_half_its_rate_is_not_stale(tmp_path):
    sim = SimulatedOptoForce(make_profile(STILL), ForceModel(), rate_hz=500, link=str(tmp_path / "ttyACM"))
    with sim:
        reader, events = rust_reader(sim.link_path)
        reader.stale_after_s = 0.2
        with reader:
            samples = captured_until(reader, 200)
            stats = reader.stats()
    assert len(samples) >= 200
    # Stale means a silence longer than stale_after_s, whatever the configured rate. A loaded
    # machine can starve the simulated DAQ's thread that long (the reader's longest gap, or its
    # being stale now, then says so); without such a silence, a 2 ms period is never stale.
    if stats["max_gap_ns"] <= 0.2e9 and not stats["stale"]:
        assert stats["stale_events"] == 0 and "stale" not in events.kinds(), stats


def test_the_config_packet_is_sent_at_start_and_acknowledged(sim):
    reader, _ = rust_reader(sim.link_path, rate_hz=100)
    with reader:
        assert wait_until(lambda: reader.stats()["acks"] >= 1)
        assert wait_until(lambda: sim.rate_hz == pytest.approx(100.0))
        assert reader.stats()["ack_errors"] == 0


def test_the_slcan_reader_reassembles_samples_and_recovers_after_an_unplug(tmp_path):
    sim = SimulatedSlcanOptoForce(make_profile(STILL), ForceModel(), rate_hz=500, link=str(tmp_path / "ttyCAN"))
    with sim:
        reader, events = rust_reader(sim.link_path, kind="can", interface="slcan", channel=sim.link_path)
        with reader:
            samples = captured_until(reader, 20)
            assert samples[-1][1][0] == pytest.approx(2.0, abs=0.01)
            assert reader.stats()["reader"] == "rust-slcan" and reader.stats()["can_frames"] >= 40
            sim.unplug()
            assert wait_until(lambda: reader.stats()["disconnects"] == 1)
            pushed = reader.stats()["samples_pushed"]
            sim.replug()
            assert wait_until(lambda: reader.stats()["samples_pushed"] > pushed + 20)
    assert events.kinds().count("reconnected") == 1


def test_a_missing_port_is_a_device_error_naming_it(tmp_path):
    reader, _ = rust_reader(str(tmp_path / "nothing"))
    with pytest.raises(DeviceError, match="nothing"):
        reader.start()


def test_which_reader_runs_follows_the_configuration():
    assert choose_reader({"kind": "optoforce", "port": "/dev/ttyACM0"}) == "rust"
    assert choose_reader({"kind": "optoforce", "port": "/dev/ttyACM0", "reader": "python"}) == "python"
    assert choose_reader({"kind": "can", "channel": "can0"}) == "rust"
    assert rust_transport({"kind": "can", "channel": "can0"})["transport"] == "socketcan"
    assert choose_reader({"kind": "can", "interface": "pcan", "channel": "PCAN_USBBUS1"}) == "python"
    assert choose_reader({"kind": "can", "interface": "socketcan", "channel": "can0", "can_options": {"fd": True}}) == "python"
    with pytest.raises(ConfigError, match="python-can"):
        choose_reader({"kind": "can", "interface": "kvaser", "channel": "0", "reader": "rust"})
    with pytest.raises(ConfigError):
        choose_reader({"kind": "optoforce", "reader": "fast"})


def _vcan_reason() -> str | None:
    try:
        out = subprocess.run(["ip", "-br", "link", "show", "type", "vcan"], capture_output=True, text=True, timeout=5)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return f"no `ip` tool to look for a vcan interface: {exc}"
    names = [line.split()[0] for line in out.stdout.splitlines() if line.strip()]
    if out.returncode != 0 or not names:
        return ("no vcan interface on this machine (create one as root: `ip link add dev vcan0 type vcan && "
                "ip link set up vcan0`; on a kernel without the vcan module `ip` answers 'Unknown device type')")
    return None


@pytest.mark.skipif(_vcan_reason() is not None, reason=_vcan_reason() or "")
def test_the_socketcan_reader_reads_samples_from_a_vcan_interface():
    can = pytest.importorskip("can")
    name = subprocess.run(["ip", "-br", "link", "show", "type", "vcan"], capture_output=True, text=True,
                          timeout=5).stdout.split()[0]
    reader, _ = rust_reader(name, kind="can", channel=name)
    with can.Bus(interface="socketcan", channel=name) as bus, reader:
        frame = of.encode_sample(1, 0, [904, 0, 0])
        for _ in range(20):
            for k in range(0, len(frame), 8):
                bus.send(can.Message(arbitration_id=0x100, data=frame[k:k + 8], is_extended_id=False))
        samples = captured_until(reader, 20)
    assert len(samples) >= 20 and reader.stats()["reader"] == "rust-socketcan"


def test_the_daemons_gate_holds_the_rust_reader_back_until_the_loop_runs(sim):
    """Before the gate opens, samples only feed the tare (the loop must see only tared samples
    taken after it started); once it opens they go to the loop's own ring, past Python."""
    from admittance import _rtcore
    from admittance.daemon.supervisor import GatedSink

    loop = _rtcore.AdmittanceLoop({"port": "/dev/null", "rate_hz": 1000, "joints": [
        {"id": 1, "virtual_inertia": 0.02, "virtual_damping": 0.05, "lever_arm": 0.1}]})
    gate = GatedSink(loop.force_sink())
    reader = NativeForceReader.from_config({"kind": "optoforce", "port": sim.link_path, "counts_per_newton": [CPN] * 3},
                                           gate)
    with reader:
        assert wait_until(lambda: reader.stats()["dropped_before_open"] >= 20)
        assert reader.stats()["samples_pushed"] == reader.stats()["dropped_before_open"], "none reached the ring"
        gate.open()
        before = reader.stats()["dropped_before_open"]
        assert wait_until(lambda: reader.stats()["samples_pushed"] - reader.stats()["dropped_before_open"] >= 20)
        assert reader.stats()["dropped_before_open"] - before <= 5
