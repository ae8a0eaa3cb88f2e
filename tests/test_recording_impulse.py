"""Recorded rows keep the torque's impulse between them (``tau_mean``), so a step in the hand's
torque that falls between two rows reaches a refit whole, wherever it falls; the session.mcap
gives the same column; and `fidelity`'s refit torque integrates to the impulse the model got."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from admittance.daemon.recording import COLUMNS, Recorder

READ_EVERY = 10


def stepped(t0: float, n: int, step_at: int) -> dict[str, np.ndarray]:
    """n cycles of 1 ms; the hand's torque steps 0 → 0.3 N·m at cycle ``step_at``; a read every
    READ_EVERY cycles."""
    cycle = np.arange(n, dtype=float)
    t = t0 + cycle * 1e-3
    present = np.where(cycle % READ_EVERY == 0, 0.01 * cycle, np.nan)
    return {"t": t, "t_wake": t, "tau": np.where(cycle >= step_at, 0.3, 0.0), "force": np.zeros(n),
            "theta_model": 0.01 * cycle, "omega_model": np.full(n, 10.0), "theta_goal": 0.01 * cycle,
            "theta_present": present, "cycle": cycle, "mode": np.zeros(n), "fault": np.zeros(n)}


def rows(folder: Path) -> dict[str, np.ndarray]:
    table = np.vstack([np.loadtxt(p, delimiter=",", skiprows=1, ndmin=2) for p in sorted(folder.glob("joint1_*.csv"))])
    return {c: table[:, k] for k, c in enumerate(COLUMNS)}


@pytest.mark.parametrize("step_at", [201, 205, 209])
def test_the_mean_torque_since_the_previous_row_keeps_the_impulse_wherever_the_step_falls(tmp_path, step_at):
    cycles = stepped(0.0, 400, step_at)
    rec = Recorder(tmp_path, [(1, "MX-64")], measured_theta=True, t0=0.0)
    for start in range(0, 400, 37):  # batches that cut the rows' intervals anywhere
        rec.append(1, {k: v[start:start + 37] for k, v in cycles.items()})
    rec.close()
    r = rows(tmp_path)
    # The model stepped cycle k+1 with cycle k+1's torque over [t_k, t_k+1): over the rows' span
    # that is the sum of the torques of cycles 1..last row.
    last = int(r["cycle"][-1])
    impulse = 1e-3 * cycles["tau"][1:last + 1].sum()
    by_means = float(np.sum(r["tau_mean"][1:] * np.diff(r["t"])))
    by_points = float(np.sum(r["tau"][:-1] * np.diff(r["t"])))
    assert by_means == pytest.approx(impulse, abs=1e-12)
    assert abs(by_points - impulse) > 1e-4 or step_at % READ_EVERY == 1, "the point samples miss part of the step"


def record_both(folder: Path, step_at: int, n: int = 3000) -> None:
    """A CSV folder and its session.mcap of ``n`` cycles, the step at ``step_at``, a moving hand."""
    from admittance.daemon.mcap_recording import McapRecorder

    cycles = stepped(0.0, n, step_at)
    cycles["tau"] = cycles["tau"] + 0.05 * np.sin(np.arange(n) * 2e-3)  # the hand moves the model
    rec = Recorder(folder, [(1, "MX-64")], measured_theta=True, t0=0.0, segment_s=100.0)
    info = {"model": "MX-64", "rate_hz": 1000.0, "plant": {"motor_inertia": 0.0147}}
    mcap = McapRecorder(folder / "session.mcap", {"joints": [{**info, "id": 1}], "t0": 0.0, "segment_s": 100.0,
                                                   "measured_theta": True, "rate_hz": 1000.0})
    for start in range(0, n, 97):
        part = {k: v[start:start + 97] for k, v in cycles.items()}
        rec.append(1, part)
        mcap.append(1, part, wall_offset_ns=0)
    rec.close()
    mcap.close()


def test_the_session_mcap_gives_the_same_means(tmp_path):
    from admittance.formats.recording import read_recording, recording_segments

    record_both(tmp_path, 1505)
    from_mcap = recording_segments(read_recording(tmp_path / "session.mcap"))[1]
    np.testing.assert_allclose(np.concatenate([s["tau_mean"] for s in from_mcap]), rows(tmp_path)["tau_mean"],
                               atol=1e-12)


def test_the_refit_sees_where_a_step_fell_between_two_rows(tmp_path):
    """A step early or late between the same two rows: the point samples are the same, the
    impulse is not; `fidelity`'s refit torque (linearly interpolated) integrates the difference."""
    from admittance.fidelity.recording import load_recording

    impulses = []
    for step_at in (1501, 1509):
        folder = tmp_path / str(step_at)
        record_both(folder, step_at)
        segment = load_recording(folder).of_joint(1)[0]
        t, refit = segment["t"], segment.impulse_tau
        impulses.append(float(np.sum(0.5 * (refit[1:] + refit[:-1]) * np.diff(t))))
    assert impulses[0] - impulses[1] == pytest.approx(8 * 0.3 * 1e-3, abs=1e-9)


def test_a_catch_up_cycle_weighs_its_torque_by_the_steps_it_took(tmp_path):
    """After a stall the model catches up at most CATCH_UP_STEPS_PER_CYCLE steps a cycle: the
    records' ``t`` (the model's time) then advances by several periods a cycle, each integrated
    with that cycle's torque. ``tau_mean`` keeps that impulse, a step in the torque falling
    inside the catch-up included."""
    from admittance._rtcore import CATCH_UP_STEPS_PER_CYCLE

    n, stall_at, lost = 400, 203, 7
    cycles = stepped(0.0, n, 206)
    model = np.arange(n, dtype=float)
    due = 0.0
    for k in range(stall_at, n):  # the deadlines jump by `lost` periods at stall_at
        deadline = k + lost
        due = deadline - model[k - 1]
        model[k] = model[k - 1] + min(due, CATCH_UP_STEPS_PER_CYCLE)
    cycles["t"] = cycles["t_wake"] = model * 1e-3
    assert np.diff(model).max() == CATCH_UP_STEPS_PER_CYCLE > 1, "the catch-up ran"
    rec = Recorder(tmp_path, [(1, "MX-64")], measured_theta=True, t0=0.0, period_s=1e-3, segment_s=100.0)
    for start in range(0, n, 37):
        rec.append(1, {k: v[start:start + 37] for k, v in cycles.items()})
    rec.close()
    r = rows(tmp_path)
    last = int(r["cycle"][-1])
    impulse = float(np.sum(cycles["tau"][1:last + 1] * np.diff(cycles["t"][:last + 1])))
    by_means = float(np.sum(r["tau_mean"][1:] * np.diff(r["t"])))
    assert by_means == pytest.approx(impulse, abs=1e-12)
