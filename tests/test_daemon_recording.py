"""Recordings are datasets: the contract's loader reads them, segments roll over, short tails are
dropped; and a real session goes record → identify → fidelity → compensate → reload (the `hil`
test at the end)."""

from __future__ import annotations

import errno
import json
import tomllib
from pathlib import Path

import numpy as np
import pytest
import tomli_w

from admittance import data
from admittance.daemon.recording import Recorder
from admittance.formats.recording import COLUMNS
from admittance.formats import paramfile
from admittance.formats.dataset import load_dataset

BENCH = data.bench_config()
MX64 = data.params_file("MX-64")


def batch(t0: float, n: int, read_every: int = 1) -> dict[str, np.ndarray]:
    t = t0 + np.arange(n) * 1e-3
    present = np.sin(t)
    present[np.arange(n) % read_every != 0] = np.nan
    return {"t": t, "t_wake": t + 1e-5, "tau": 0.1 * np.cos(t), "force": np.cos(t), "theta_model": np.sin(t),
            "omega_model": np.cos(t), "theta_goal": np.sin(t), "theta_present": present,
            "cycle": np.round(t * 1e3), "mode": np.zeros(n), "fault": np.zeros(n)}


def test_a_recording_loads_as_a_geometry_dataset_with_measured_theta(tmp_path):
    rec = Recorder(tmp_path, [(1, "MX-64"), (3, "MX-28")], measured_theta=True, t0=100.0)
    for k in range(10):
        for joint in (1, 3):
            rec.append(joint, batch(100.0 + k * 0.05, 50, read_every=5))
    rec.close()
    dataset = load_dataset(tmp_path)
    assert dataset.mode == "geometry" and [tr.name for tr in dataset.trials] == ["joint1_000.csv", "joint3_000.csv"]
    trial = dataset.trials[0]
    assert trial.n_samples == 100 and trial.t[0] == pytest.approx(0.0)
    assert np.allclose(trial.theta, np.sin(trial.t + 100.0))
    assert trial.load_inertia < 1e-9 and trial.gravity_torque < 1e-6
    assert tomllib.loads((tmp_path / "manifest.toml").read_text())["theta_source"] == "present position"


def test_a_row_carries_the_next_cycles_torque_across_batches(tmp_path):
    """The model's step at cycle k+1 uses τ_(k+1) over the interval that starts at row k; the
    contract's simulator applies τ(t_k) there. So row k carries τ_(k+1), the batch's last cycle
    waits for the next batch, and the very last one keeps its own torque."""
    rec = Recorder(tmp_path, [(1, "MX-64")], measured_theta=True, t0=0.0)
    first, second = batch(0.0, 20), batch(0.02, 20)
    rec.append(1, first)
    rec.append(1, second)
    rec.close()
    trial = load_dataset(tmp_path).trials[0]
    tau = np.concatenate([first["tau"], second["tau"]])
    assert trial.n_samples == 40
    assert np.allclose(trial.tau[:-1], tau[1:]) and trial.tau[-1] == tau[-1]
    assert np.allclose(trial.t, np.arange(40) * 1e-3), "t is the cycle's deadline, not its wake-up"


def test_a_cycle_that_took_no_step_supersedes_the_row_before_it(tmp_path):
    """A phase-locked grid that fell half a period behind the model gives a cycle of no step: it
    repeats its predecessor's deadline and state, and the predecessor's next torque was never
    integrated. The predecessor's row goes (here across a batch's end, held back), so t stays
    strictly increasing and the next row carries the torque of the cycle that did step."""
    rec = Recorder(tmp_path, [(1, "MX-64")], measured_theta=True, t0=0.0)
    first, second = batch(0.0, 20), batch(0.02, 20)
    for cols in (first, second):
        cols["t"][cols["cycle"] >= 20] -= 1e-3  # cycle 20 took no step: its deadline is cycle 19's
    first["fault"][19] = 1  # the superseded row's fault carries on to the next row kept
    rec.append(1, first)
    rec.append(1, second)
    rec.close()
    trial = load_dataset(tmp_path).trials[0]
    t = np.concatenate([first["t"], second["t"]])
    tau = np.concatenate([first["tau"], second["tau"]])
    kept = np.arange(40) != 19
    assert trial.n_samples == 39 and np.all(np.diff(trial.t) > 0)
    assert np.allclose(trial.t, t[kept]) and np.allclose(trial.tau[:-1], tau[1:][kept[:-1]])
    rows = np.genfromtxt(tmp_path / "joint1_000.csv", delimiter=",", names=True)
    assert rows["fault"][19] == 1 and rows["cycle"][19] == 20


def all_rows(folder: Path) -> np.ndarray:
    return np.vstack([np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2) for path in sorted(folder.glob("joint1_*.csv"))])


def test_a_hold_or_a_fault_between_two_reads_marks_the_next_row(tmp_path):
    """Reads every 2nd cycle; cycle 37 held (stale force: mode holding), cycle 79 faulted (the
    state guard, fault bit 1): rows 38 and 80 say so, even the one whose fault fell after the
    batch's last read (carried into the next batch)."""
    rec = Recorder(tmp_path, [(1, "MX-64")], measured_theta=True, t0=0.0)
    first, second = batch(0.0, 80, read_every=2), batch(0.08, 80, read_every=2)
    first["mode"][37] = 1.0
    first["mode"][79], first["fault"][79] = 2.0, 1.0
    rec.append(1, first)
    rec.append(1, second)
    rec.close()
    rows = all_rows(tmp_path)
    cycles, held = rows[:, COLUMNS.index("cycle")], rows[:, COLUMNS.index("held")]
    assert list(cycles[held == 1]) == [38.0, 80.0]
    assert list(cycles[rows[:, COLUMNS.index("fault")] == 1]) == [80.0]


def test_where_the_model_did_not_follow_the_torque_a_new_trial_starts(tmp_path):
    """A trial is one continuous solution of the model. A stall longer than the loop catches up
    (the model lost that time) starts a new trial, a stall the loop caught up does not; a hold's
    rows form a trial of their own (the recording covers the run), and the rows after it the
    next. The session.mcap's dataset is cut by the same rule."""
    from admittance._rtcore import MAX_CATCH_UP_STEPS
    from admittance.formats.recording import trial_starts
    from admittance.formats.recording import _segments

    period = 1e-3
    rec = Recorder(tmp_path, [(1, "MX-64")], measured_theta=True, t0=0.0, period_s=period)
    caught_up = (MAX_CATCH_UP_STEPS - 1) * period  # a stall the model integrates through
    lost = (MAX_CATCH_UP_STEPS + 5) * period  # a stall whose time the model restarts after
    a, b = batch(0.0, 100), batch(0.1 + caught_up, 100)
    c = batch(b["t"][-1] + period + lost, 100)
    c["mode"][50:70] = 1.0  # a hold inside the last stretch
    for part in (a, b, c):
        rec.append(1, part)
    rec.close()
    trials = load_dataset(tmp_path).trials
    assert [t.n_samples for t in trials] == [200, 50, 20, 30], "cut at the lost time, the hold's start and end"
    rows = all_rows(tmp_path)
    assert list(rows[rows[:, COLUMNS.index("held")] == 1, COLUMNS.index("cycle")]) == list(c["cycle"][50:70])
    # The MCAP's reader cuts by the same rule (trial_starts).
    t = np.concatenate([a["t"], b["t"], c["t"]])
    held, lapse = np.zeros(len(t)), np.zeros(len(t))
    held[250:270], lapse[200] = 1, 1
    assert [len(s) for s in _segments(t, np.union1d(*trial_starts(t, held, lapse, 0.25)), 10.0)] == [200, 50, 20, 30]


def test_targets_go_into_each_segments_manifest_entry(tmp_path):
    rec = Recorder(tmp_path, [(1, "MX-64")], measured_theta=False, t0=0.0, segment_s=1.0,
                   joint_info={1: {"params_file": "p.toml", "rate_hz": 1000.0}})
    rec.set_targets({"1.virtual_inertia": 0.02, "1.virtual_damping": 0.1, "1.virtual_coulomb": 0.0,
                     "1.servo_compensation": 0.0, "deadband": 0.0})
    rec.append(1, batch(0.0, 1000))
    rec.set_targets({"1.virtual_inertia": 0.02, "1.virtual_damping": 0.1, "1.virtual_coulomb": 0.0,
                     "1.servo_compensation": 1.0})
    rec.append(1, batch(1.0, 1000))
    rec.append(1, batch(2.0, 1000))  # opens the second segment
    rec.close()
    manifest = tomllib.loads((tmp_path / "manifest.toml").read_text())
    first, second = manifest["trials"]
    assert first["servo_compensation"] == 0.0 and first["params_changed"] is True
    assert second["servo_compensation"] == 1.0 and "params_changed" not in second
    assert manifest["joints"] == [{"id": 1, "params_file": "p.toml", "rate_hz": 1000.0}]


def test_segments_roll_over_and_a_short_tail_is_dropped(tmp_path):
    rec = Recorder(tmp_path, [(1, "MX-64")], measured_theta=False, t0=0.0, segment_s=1.0)
    for k in range(25):  # 2.5 s in 0.1 s batches: segments [0, 1), [1, 2), [2, 2.5)
        rec.append(1, batch(k * 0.1, 100))
    rec.append(1, batch(3.0, 3))  # opens a fourth segment of 3 rows: too short, dropped at close
    rec.close()
    names = [tr.name for tr in load_dataset(tmp_path).trials]
    assert names == ["joint1_000.csv", "joint1_001.csv", "joint1_002.csv"]
    assert not (tmp_path / "joint1_003.csv").exists()
    assert rec.rows[1] == 2503
    dropped = tomllib.loads((tmp_path / "manifest.toml").read_text())["dropped"]
    assert dropped == [{"joint_id": 1, "t_start": 3.0, "t_end": pytest.approx(3.002), "rows": 3, "faults": []}]


def test_a_short_hold_dropped_from_the_csv_is_listed_with_its_faults(tmp_path):
    """A hold of a few rows (a torque found off and re-enabled) is a trial of its own, too short
    to fit: its file goes, and the manifest lists it with the faults its rows carried."""
    from admittance.daemon.telemetry import fault_names

    torque_off = 1 << fault_names(0xFF).index("torque_off")
    rec = Recorder(tmp_path, [(1, "MX-64")], measured_theta=True, t0=0.0)
    cols = batch(0.0, 300)
    cols["mode"][100:107], cols["fault"][100:107] = 2.0, torque_off
    rec.append(1, cols)
    rec.close()
    manifest = tomllib.loads((tmp_path / "manifest.toml").read_text())
    assert [t.n_samples for t in load_dataset(tmp_path).trials] == [100, 193]
    assert manifest["dropped"] == [{"joint_id": 1, "t_start": pytest.approx(0.1), "t_end": pytest.approx(0.106),
                                    "rows": 7, "faults": ["torque_off"]}]
    assert not np.any(all_rows(tmp_path)[:, COLUMNS.index("fault")]), "no kept row carries the hold's fault"


def test_an_unwritable_folder_is_a_config_error(tmp_path):
    from admittance.errors import ConfigError

    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(ConfigError, match="record: cannot create"):
        Recorder(blocker / "sub", [(1, "MX-64")], measured_theta=True, t0=0.0)


def bench_session(tmp_path, name: str, params: str | Path, *, cycles: int,
                  joint: dict | None = None) -> tuple[Path, dict]:
    """A session of the embedded bench's default (MX-64 with its thesis values as the virtual
    joint, a 0.5 Hz hand, reads every 10th cycle), recorded until ``cycles`` cycles after the
    hand first pushes; returns the recording folder and the --stats-json object. The stale
    timeout is raised: a loaded CI machine can stall the sensor reader past 50 ms, and the hold
    that follows is not under test here."""
    from daemon_process import running_daemon, wait_alive, wait_for_cycles, wait_for_state
    from helpers import free_endpoint

    from admittance.daemon.zenoh_iface import Client

    endpoint, prefix = free_endpoint(), f"hil/{name}"
    cfg = tomllib.loads(BENCH.read_text())
    cfg["joints"][0]["params"] = str(params)
    cfg["joints"][0].update(joint or {})
    cfg["loop"]["stale_timeout_ms"] = 500.0  # no hold when CI stalls the reader (the most allowed)
    cfg["zenoh"] = {"prefix": prefix, "listen": [endpoint]}
    cfg["record"] = {"path": name, "segment_s": 2.0}
    path = tmp_path / f"{name}.toml"
    path.write_text(tomli_w.dumps(cfg))
    with running_daemon(path, "--stats-json", str(tmp_path / f"{name}.json")) as daemon:
        wait_alive(endpoint, prefix)
        with Client([endpoint]) as client:
            pushed = wait_for_state(client, prefix, lambda m: abs(m["joints"][0]["tau"]) > 0.05, "the hand pushing")
            wait_for_cycles(client, prefix, cycles, after=pushed)
    assert daemon.returncode == 0, daemon.stderr
    return tmp_path / name, json.loads((tmp_path / f"{name}.json").read_text())


def with_model_angle(folder: Path, out: Path) -> Path:
    """The recording with theta := theta_model, as an outside check would make it."""
    out.mkdir()
    (out / "manifest.toml").write_text((folder / "manifest.toml").read_text())
    for path in folder.glob("joint*.csv"):
        lines = path.read_text().splitlines()
        header = lines[0].split(",")
        i, j = header.index("theta"), header.index("theta_model")
        rows = [line.split(",") for line in lines[1:]]
        for row in rows:
            row[i] = row[j]
        (out / path.name).write_text("\n".join([lines[0], *(",".join(r) for r in rows)]) + "\n")
    return out


@pytest.mark.hil
@pytest.mark.slow
def test_record_identify_fidelity_compensate_reload(tmp_path):
    """The chain on the embedded bench default (MX-64, large Coulomb, 0.5 Hz hand):

    1. the recording is honest: `identify` with theta := theta_model returns the configured
       I, B, F within 3/3/5 % (it was 18/28/12 % off when rows carried the wake-up time and the
       cycle's own torque);
    2. `fidelity` identifies the servo and writes the plant with its [servo] model (and reads
       the session's session.mcap to the same figures);
    3. a session with that file compensates: the rendering error is ≥ 3× lower, and `identify`
       on the *measured* angle (what the user felt) is within 10 % (I, B) and 10 % + 5 mN·m (F)
       of the configured joint (without compensation it was 13 %, 54 % and 16 % off);
    4. reloaded as a joint's params, the refit's values are the virtual defaults."""
    from admittance.cli import main
    from admittance.daemon import config
    from admittance.fidelity.judge import MIN_HELDOUT_GAIN
    from admittance.ident.identify import IdentifySettings, identify_dataset

    plant = paramfile.load(MX64)["params"]
    target = {"motor_inertia": plant["motor_inertia"], "damping": plant["damping"], "coulomb": plant["coulomb"]}
    plain, _ = bench_session(tmp_path, "plain", MX64, cycles=6000)
    honest = identify_dataset(load_dataset(with_model_angle(plain, tmp_path / "model_angle")),
                              IdentifySettings(max_effects=0)).params
    for name, tolerance in (("motor_inertia", 0.03), ("damping", 0.03), ("coulomb", 0.05)):
        assert honest[name] == pytest.approx(target[name], rel=tolerance), (name, honest[name])

    servo_params = tmp_path / "mx64_servo.toml"
    assert main(["fidelity", str(plain), "--json", str(tmp_path / "plain_fidelity.json"),
                 "--params-out", str(servo_params), "--quiet"]) == 0
    before = json.loads((tmp_path / "plain_fidelity.json").read_text())["rendering_rmse"]
    # The daemon's session.mcap carries what fidelity needs (the same rows, targets and plant).
    assert main(["fidelity", str(plain / "session.mcap"), "--json", str(tmp_path / "mcap.json"), "--quiet"]) == 0
    from_mcap = json.loads((tmp_path / "mcap.json").read_text())
    assert from_mcap["rendering_rmse"] == pytest.approx(before, rel=0.02)
    assert from_mcap["target"] == json.loads((tmp_path / "plain_fidelity.json").read_text())["target"]
    # Step 3 judges the fitted model's effect, so the compensated session turns it on by hand
    # (judge.py: a refused fit is still written for that) rather than through the verdict: the
    # verdict's residual test sits at 1.2-1.5x the noise floor here (at most 2x) on a quiet
    # machine, and the stalls of a loaded one move it past (2.23x with 100 loop overruns and 266
    # simulated-bus stalls, against 1.18x with 18 and 26), which left nothing to judge (a
    # compensated session without compensation: 0.0100 against 0.0098 = before / 3). The model
    # still predicts the horn: its held-out gain (11.6x then, 23x quiet) keeps the verdict's 4x.
    verdict = json.loads((tmp_path / "plain_fidelity.json").read_text())["servo_verdict"]
    assert verdict["heldout_gain"] >= MIN_HELDOUT_GAIN, verdict
    compensated, stats = bench_session(tmp_path, "compensated", servo_params, cycles=4500,
                                       joint={"servo_compensation": 1.0})
    assert stats["rendering_rms"]["1"] > 0, "the live figure is in the stats file"
    assert stats["compensation_fallbacks"] == 0, ("the loop's watch blended the compensation out", stats["overruns"],
                                                  stats["bench"]["bus"]["timing"])
    assert main(["fidelity", str(compensated), "--json", str(tmp_path / "comp.json"), "--quiet"]) == 0
    after = json.loads((tmp_path / "comp.json").read_text())
    assert after["servo_compensation"] == 1.0 and after["rendering_rmse"] < before / 3, (before, after["rendering_rmse"])

    felt = identify_dataset(load_dataset(compensated), IdentifySettings(max_effects=0))
    assert felt.params["motor_inertia"] == pytest.approx(target["motor_inertia"], rel=0.1)
    assert felt.params["damping"] == pytest.approx(target["damping"], rel=0.1)
    assert felt.params["coulomb"] == pytest.approx(target["coulomb"], abs=0.1 * target["coulomb"] + 0.005)
    fitted = tmp_path / "felt.toml"
    felt.write_params(fitted, source="test round trip")
    doc = tomllib.loads((tmp_path / "compensated.toml").read_text())
    doc["joints"][0] = {"id": 1, "model": "MX-64", "params": str(fitted)}
    (tmp_path / "reload.toml").write_text(tomli_w.dumps(doc))
    joint = config.load_config(tmp_path / "reload.toml").joints[0]  # virtual_* default to the refit
    assert joint.virtual_inertia == felt.params["motor_inertia"] and joint.servo_compensation == 0.0


def test_a_fault_that_stops_the_reads_is_a_listed_gap_that_splits_the_trials(tmp_path):
    """docs/faults.md: no rows while the servo is unread (the bus unplugged); the gap ends the
    trial, is listed in the manifest with its faults, marks the first row after it, and a run
    that ends inside a gap lists that one too."""
    from admittance.daemon.telemetry import fault_names

    lost = 1 << fault_names(0xFF).index("bus_lost")
    rec = Recorder(tmp_path, [(1, "MX-64")], measured_theta=True, t0=0.0)
    before, during, after, end = batch(0.0, 200), batch(0.2, 400), batch(0.6, 200), batch(0.8, 400)
    for unread in (during, end):
        unread["theta_present"][:] = np.nan
        unread["fault"][:] = lost
    for part in (before, during, after, end):
        rec.append(1, part)
    rec.close()
    manifest = tomllib.loads((tmp_path / "manifest.toml").read_text())
    assert [g["faults"] for g in manifest["gaps"]] == [["bus_lost"], ["bus_lost"]]
    first, last = manifest["gaps"]
    assert first["t_start"] == pytest.approx(0.199) and first["t_end"] == pytest.approx(0.6)
    assert last["t_start"] == pytest.approx(0.799) and last["t_end"] == pytest.approx(1.199)
    trials = load_dataset(tmp_path).trials
    assert [t.n_samples for t in trials] == [200, 200], "one trial each side of the gap"
    with (tmp_path / trials[1].name).open() as fh:
        rows = fh.read().splitlines()
    header = rows[0].split(",")
    assert int(float(rows[1].split(",")[header.index("fault")])) & lost, "the first row after the gap is marked"


class FillingDisk:
    """A recording file on a disk with ``room`` bytes left: a write past it writes what fits and
    fails with ENOSPC, as a full file system does."""

    def __init__(self, fh, room: int) -> None:
        self.fh, self.room = fh, room

    def write(self, data) -> int:
        if self.room <= 0:
            raise OSError(errno.ENOSPC, "No space left on device")
        written = self.fh.write(bytes(data[:self.room]))
        self.room -= written
        return written

    def __getattr__(self, name):
        return getattr(self.fh, name)


def test_a_full_disk_cuts_the_csv_at_its_last_whole_row_and_the_dataset_stays_readable(tmp_path):
    rec = Recorder(tmp_path, [(1, "MX-64")], measured_theta=True, t0=100.0)
    rec.append(1, batch(100.0, 200))
    rec._files[1] = FillingDisk(rec._files[1], room=3000)  # the disk fills during the next batches
    with pytest.raises(OSError) as err:
        for k in range(1, 50):
            rec.append(1, batch(100.0 + k * 0.2, 200))
    assert err.value.errno == errno.ENOSPC
    rec.abort()
    assert rec.stopped and rec.append(1, batch(200.0, 50)) == 0, "nothing more is written"
    rec.close()  # the supervisor's exit path: a no-op now
    text = (tmp_path / "joint1_000.csv").read_text()
    assert text.endswith("\n") and all(len(line.split(",")) == len(COLUMNS) for line in text.splitlines())
    trial = load_dataset(tmp_path).trials[0]
    # The first batch's rows (its last cycle waits for the next); the batch that did not fit is cut
    # back whole, not left half a row long.
    assert trial.n_samples == len(text.splitlines()) - 1 == 199


def rowless_stretches(t: np.ndarray, longer_than: float) -> list[tuple[float, float]]:
    """(last row before, first row after) of each stretch of the CSV without rows."""
    wide = np.diff(t) > longer_than
    return list(zip(t[:-1][wide].tolist(), t[1:][wide].tolist()))


def replug_after_a_lost_bus(period: float = 1e-3) -> dict[str, np.ndarray]:
    """CI's failed replug (tests/test_hil_faults.py), cycle by cycle: rows to 0.518 s, the bus
    lost (no reads) to 2.080 s, one read there, then a stall the loop did not catch up (the model
    lost its time: a new trial), the rows resuming at 2.206 s."""
    from admittance.daemon.telemetry import fault_names

    lost = 1 << fault_names(0xFF).index("bus_lost")
    up, down, first_read, resumed = batch(0.0, 519), batch(0.519, 1561), batch(2.080, 1), batch(2.206, 400)
    down["theta_present"][:], down["fault"][:], down["mode"][:] = np.nan, lost, 2.0
    cols = {k: np.concatenate([p[k] for p in (up, down, first_read, resumed)]) for k in up}
    cols["cycle"] = np.arange(len(cols["t"]), dtype=float)  # one cycle after another, the stall's included
    return cols


@pytest.mark.parametrize("chunk", [None, 100, 7])
def test_a_gap_spans_every_row_the_csv_lacks_when_the_trial_after_it_is_too_short(tmp_path, chunk):
    """After a gap, the first rows may form a trial too short to fit (a stall or a hold cut it
    after one row) and be dropped: the gap then reaches the first row the CSV kept, as its
    manifest entry says ("stretches with no rows"); the dropped row is still listed. The same
    whether the drain arrives in one batch or in the supervisor's chunks."""
    cols = replug_after_a_lost_bus()
    rec = Recorder(tmp_path, [(1, "MX-64")], measured_theta=True, t0=0.0, period_s=1e-3)
    step = chunk or len(cols["t"])
    for start in range(0, len(cols["t"]), step):
        rec.append(1, {k: v[start:start + step] for k, v in cols.items()})
    rec.close()
    manifest = tomllib.loads((tmp_path / "manifest.toml").read_text())
    t = all_rows(tmp_path)[:, COLUMNS.index("t")]
    gaps = manifest["gaps"]
    for before, after in rowless_stretches(t, 0.25):
        assert any(g["t_start"] <= before and g["t_end"] >= after for g in gaps), \
            f"rows stop at {before:.3f} s, resume at {after:.3f} s, and no gap says why: {gaps}"
    assert [g["faults"] for g in gaps] == [["bus_lost"]]
    assert gaps[0]["t_start"] == pytest.approx(0.518) and gaps[0]["t_end"] == pytest.approx(2.206)
    assert manifest["dropped"] == [{"joint_id": 1, "t_start": pytest.approx(2.080), "t_end": pytest.approx(2.080),
                                    "rows": 1, "faults": ["bus_lost"]}]


def test_gaps_around_dropped_pieces_say_where_the_csv_has_no_rows(tmp_path):
    """A short hold just before a gap, a piece of 3 rows between two gaps, and a run that ends
    unread after a gap and 5 rows: every dropped piece lies inside a gap, the two gaps around
    the 3 rows are one (with the faults of both), and the last gap reaches the run's last cycle."""
    from admittance.daemon.telemetry import fault_names

    bit = {name: 1 << fault_names(0xFF).index(name) for name in ("bus_lost", "servo_silent")}
    starts = [0.0, 0.3, 0.303, 0.703, 0.706, 1.106, 1.406, 1.806, 1.811, 2.211]
    parts = [batch(t, round((end - t) * 1e3)) for t, end in zip(starts, starts[1:])]
    parts[1]["mode"][:] = 1.0  # a hold of 3 rows, then the bus lost
    for k, fault in ((2, "bus_lost"), (4, "servo_silent"), (6, "bus_lost"), (8, "bus_lost")):
        parts[k]["theta_present"][:], parts[k]["fault"][:] = np.nan, bit[fault]
    rec = Recorder(tmp_path, [(1, "MX-64")], measured_theta=True, t0=0.0, period_s=1e-3)
    for part in parts:
        rec.append(1, part)
    rec.close()
    manifest = tomllib.loads((tmp_path / "manifest.toml").read_text())
    assert [(g["t_start"], g["t_end"], g["faults"]) for g in manifest["gaps"]] == [
        (pytest.approx(0.299), pytest.approx(1.106), ["servo_silent", "bus_lost"]),
        (pytest.approx(1.405), pytest.approx(2.210), ["bus_lost"])]
    assert [(d["t_start"], d["rows"]) for d in manifest["dropped"]] == [
        (pytest.approx(0.3), 3), (pytest.approx(0.703), 3), (pytest.approx(1.806), 5)]
    t = all_rows(tmp_path)[:, COLUMNS.index("t")]
    assert rowless_stretches(t, 0.25) == [(pytest.approx(0.299), pytest.approx(1.106))]
