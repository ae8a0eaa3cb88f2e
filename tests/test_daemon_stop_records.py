"""What a stop leaves on disk: the last cycles before a fault stop reach the CSV and the MCAP (the
supervisor drains the loop after ``loop.stop``), every batch written is on disk when the tick
ends (what a SIGKILL leaves), and samples a ``saturation = "pass"`` sensor lets through are
marked ``sensor_saturated`` for as long as they come, and no longer.

The supervisor runs with the fakes of test_daemon_supervisor (no bench, no threads of its own)."""

from __future__ import annotations

import os
import shutil

import numpy as np
import pytest

from test_daemon_supervisor import RECORD_DTYPE, Harness

FINAL_CYCLES = 7  # what the fake loop runs between the supervisor's last tick and its stop


def _fault_stopping(h: Harness) -> None:
    """The loop asks for a stop (a servo given up); the cycles it runs until ``stop`` returns
    are only drained after it."""
    make_loop = h.backends.make_loop

    def loop_of(cfg, port):
        loop = make_loop(cfg, port)
        loop.request = {"cause": "unsafe_hardware_error", "joint": 1, "hardware_error": 0x10}
        loop.final = None
        drain, stop = loop.drain_telemetry, loop.stop

        def stop_then_final(torque_policy="hold"):
            stop(torque_policy)
            loop.final = _cycles(loop, FINAL_CYCLES)

        def drain_final():
            if loop.final is not None:
                final, loop.final = loop.final, np.zeros(0, RECORD_DTYPE)
                return final
            return drain()

        loop.stop, loop.drain_telemetry = stop_then_final, drain_final
        return loop

    h.backends.make_loop = loop_of


def _cycles(loop, n: int, read_every: int = 1) -> np.ndarray:
    """``n`` more cycles of every joint, with a present read every ``read_every`` and the
    servo-error bit."""
    rec = np.zeros(n * len(loop.ids), RECORD_DTYPE)
    for k in range(n):
        loop.cycle += 1
        for j, jid in enumerate(loop.ids):
            r = rec[k * len(loop.ids) + j]
            r["cycle"], r["deadline_ns"], r["id"] = loop.cycle, 10**9 + loop.cycle * 10**6, jid
            r["t_ns"] = r["deadline_ns"] + 30_000
            r["torque"], r["theta"], r["goal_tick"] = 0.1, 0.001 * loop.cycle, 2048
            r["present_tick"] = 2048 if loop.cycle % read_every == 0 else -1
            r["fault"] = 1 << 1  # servo_error
    return rec


def test_the_last_cycles_before_a_fault_stop_reach_the_csv_and_the_mcap(tmp_path):
    from admittance.errors import FaultStop
    from admittance.formats.recording import read_recording

    from daemon_process import read_recording as read_csv

    h = Harness(tmp_path, record=str(tmp_path / "rec"))
    _fault_stopping(h)
    with pytest.raises(FaultStop):
        h.supervisor.run()
    last = h.loop.cycle
    mcap = read_recording(tmp_path / "rec" / "session.mcap").joints[1]["cycle"]
    assert mcap[-1] == last, f"the MCAP ends at cycle {mcap[-1]}, the loop at {last}"
    # The CSV holds each row back until the next cycle's torque is known, the last one until the close.
    csv_cycles = read_csv(tmp_path / "rec")["cycle"]
    assert csv_cycles[-1] == last, f"the CSV ends at cycle {csv_cycles[-1]}, the loop at {last}"
    assert np.all(read_csv(tmp_path / "rec")["fault"][-FINAL_CYCLES + 1:] == 2), "with their fault bits"


def test_every_drained_batch_is_on_disk_when_the_tick_ends(tmp_path, monkeypatch):
    """What a SIGKILL leaves is what reached the OS: after each tick's drain the CSVs and the
    session.mcap on disk hold every byte written so far (the MCAP's open chunk is the writer's,
    not yet written), and a copy of them reads back every row and every completed chunk. Files
    opened with the default buffering get a 1 MiB buffer here, so that what is on disk depends
    on the flushes, not on whether a write happened to exceed Python's 8 KiB buffer."""
    import pathlib

    from admittance.formats.recording import read_recording

    plain_open = pathlib.Path.open

    def big_buffers(self, mode="r", buffering=-1, *args, **kwargs):
        if buffering == -1 and "b" in mode and ("w" in mode or "a" in mode):
            buffering = 1 << 20
        return plain_open(self, mode, buffering, *args, **kwargs)

    monkeypatch.setattr(pathlib.Path, "open", big_buffers)

    h = Harness(tmp_path, record=str(tmp_path / "rec"), stop_after=30.0)
    sizes = []

    def tick_and_look():
        tick()
        recorder, mcap = h.supervisor.recorder, h.supervisor.ecosystem.mcap
        for fh in [*recorder._files.values(), mcap._fh]:
            sizes.append((os.path.getsize(fh.name), fh.tell()))
        if h.loop.cycle >= 6000:
            h.supervisor.request_stop()

    make_loop = h.backends.make_loop

    def busy_loop(cfg, port):  # 200 cycles a tick: the MCAP completes chunks within a few ticks
        loop = make_loop(cfg, port)
        loop.drain_telemetry = lambda: _cycles(loop, 200, read_every=10)
        return loop

    h.backends.make_loop = busy_loop
    tick = h.supervisor._tick
    h.supervisor._tick = tick_and_look
    h.supervisor.run()
    assert sizes and all(on_disk == written for on_disk, written in sizes), \
        [s for s in sizes if s[0] != s[1]][:3]
    assert sizes[-1][1] > 0, "the MCAP has completed chunks by then"
    copy = tmp_path / "killed.mcap"
    shutil.copy(tmp_path / "rec" / "session.mcap", copy)
    assert read_recording(copy).joints[1]["cycle"][-1] == h.loop.cycle


@pytest.mark.parametrize("policy", ["pass", "hold"])
def test_saturated_samples_mark_the_cycles_while_they_come_and_then_no_more(tmp_path, policy):
    """The sensor's saturation events mark the loop's cycles ``sensor_saturated`` (whether the
    samples are passed or held): from the tick that sees a new one until SATURATION_MARK_S after
    the last, then not any more."""
    from admittance.daemon.faults import SATURATION_MARK_S, FaultWatch

    from test_daemon_supervisor import FakeLoop

    h = Harness(tmp_path)
    now = [100.0]
    watch = FaultWatch(h.cfg, lambda line: None, clock=lambda: now[0])
    loop = FakeLoop([], [1])
    sensor = {"state": "streaming", "last_sample_ns": 0, "events": {}}

    def tick(saturated_events: int, dt: float = 0.05) -> list[str]:
        now[0] += dt
        sensor["events"] = {"saturated": saturated_events} if saturated_events else {}
        watch.poll(loop.stats(), sensor, loop)
        return loop.sensor_faults[-1]

    assert tick(0) == []
    assert tick(3) == ["sensor_saturated"]
    assert tick(5) == ["sensor_saturated"]
    assert tick(5, dt=SATURATION_MARK_S / 2) == ["sensor_saturated"], "still within the mark's time"
    assert tick(5, dt=SATURATION_MARK_S) == [], "no new saturated sample: the mark ends"
    assert tick(5) == []
    assert tick(6) == ["sensor_saturated"]
