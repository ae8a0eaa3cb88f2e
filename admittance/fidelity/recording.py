"""A recording of ``admittance run --record``, read for the fidelity analysis.

A recording is a dataset (datasets.md) whose CSVs carry, besides ``t``, ``theta`` (the present
angle read from the servo) and ``tau``, the cycle's ``theta_model``, ``omega_model``,
``theta_goal`` and, from this version on, ``t_wake``, ``cycle`` and ``held``; its manifest says
where ``theta`` came from and, per segment, what the loop ran (``virtual_*``,
``servo_compensation``). The same session's ``session.mcap`` (a file, or a folder holding one
and no manifest) gives the same segments: its cycles are turned into the CSV's rows by the
recorder's own function (``admittance.formats.recording.recording_segments``), what the loop ran
comes from its ``/params`` messages and the joints' plants from ``/session``.
Everything is checked here, so the analysis never meets a half recording: each problem is one
``DataError`` line that says what is wrong and what to do.
"""

from __future__ import annotations

import csv
import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from admittance.errors import DataError
from admittance.formats.dataset import MANIFEST, MIN_SAMPLES, TrialData, load_dataset
from admittance.formats.mcap_layout import MCAP_NAME
from admittance.formats.paramfile import read_toml

REQUIRED = ("t", "theta", "tau", "theta_model", "omega_model", "theta_goal")
OPTIONAL = ("t_wake", "cycle", "force", "held", "tau_mean")
TARGET_KEYS = ("virtual_inertia", "virtual_damping", "virtual_coulomb")
PRESENT = "present position"
MIN_MOTION_RAD = 0.01  # a model that moved less than this has nothing to render


def moved(theta_model: np.ndarray) -> bool:
    """Whether the model's angle spans at least MIN_MOTION_RAD: anything to render or to fit."""
    return bool(np.ptp(theta_model) >= MIN_MOTION_RAD)
MAX_FILE_BYTES = 512 * 1024 * 1024
MIN_RUN_S = 1.0  # a stretch between two holds or gaps shorter than this is dropped
# Rows further apart than this (failed reads: a stalled bus or loop) cut a segment: across a
# stall the goal the servo really got is unknown (a starved bus applies a backlog of goals at
# once), and a torque interpolated over 0.1 s misses a 3 Hz hand by half its amplitude. Shorter
# gaps are bridged: the goal by the model's own smooth motion, the torque linearly (at 30 ms and
# 3 Hz a straight line is off by 4 % of the amplitude, at 10 ms by 0.4 %).
MAX_GAP_S = 0.03


@dataclass(frozen=True)
class Segment:
    """A stretch of one joint's trial file without a hold: every column, the dataset trial it
    belongs to (its load), and what the loop ran while it was written."""

    name: str
    joint_id: int
    columns: dict[str, np.ndarray]
    trial: TrialData
    target: dict[str, float] = field(default_factory=dict)
    compensation: float | None = None
    params_changed: bool = False

    def __getitem__(self, name: str) -> np.ndarray:
        return self.columns[name]

    @property
    def n(self) -> int:
        return int(self.columns["t"].size)

    def as_trial(self, column: str) -> TrialData:
        """This stretch as a dataset trial for `identify`, with theta := ``column``."""
        return dataclasses.replace(self.trial, name=self.name, t=self["t"], theta=self[column], tau=self.impulse_tau)

    @property
    def impulse_tau(self) -> np.ndarray:
        """The torque per row for a refit that interpolates it linearly between rows: the mean of
        the two intervals' mean torques around the row (``tau_mean`` of the row and of the next),
        so the refit integrates the impulse the model got whatever a step between two rows did,
        and a smooth torque lands at the row's own time (each interval's mean sits at its middle).
        The last row pairs its interval with its own ``tau``. Older recordings: ``tau``."""
        tau = self["tau"]
        if "tau_mean" not in self.columns or tau.size < 2:
            return tau
        mean = self["tau_mean"]
        return 0.5 * (mean + np.concatenate([mean[1:], tau[-1:]]))

    @property
    def t_servo(self) -> np.ndarray:
        """When the goal was written and the present angle read: the cycle's wake-up (older
        recordings have only ``t``)."""
        return self.columns.get("t_wake", self.columns["t"])


@dataclass(frozen=True)
class Recording:
    folder: Path
    segments: tuple[Segment, ...]
    joints: dict[int, dict]  # the manifest's [[joints]] (plant, servo, parameter file), by id
    held_rows: int = 0  # rows left out because the loop held (stale force)
    gaps: int = 0  # places where rows were more than MAX_GAP_S apart (a cut)

    def joint_ids(self) -> list[int]:
        return sorted({s.joint_id for s in self.segments})

    def of_joint(self, joint_id: int) -> list[Segment]:
        return [s for s in self.segments if s.joint_id == joint_id]


def load_recording(path: str | Path) -> Recording:
    """A --record folder (its CSVs and manifest), or a session.mcap (the file, or a folder that
    holds one and no manifest)."""
    path = Path(path)
    if path.suffix == ".mcap" or (path.is_dir() and not (path / MANIFEST).is_file() and (path / MCAP_NAME).is_file()):
        return _from_mcap(path)
    folder = path
    if not folder.is_dir():
        raise DataError(f"{folder}: recording folder not found")
    manifest_path = folder / MANIFEST
    if not manifest_path.is_file():
        raise DataError(f"{folder}: not a recording (no {MANIFEST}); record one with `admittance run --record DIR`")
    manifest = read_toml(manifest_path, DataError, "manifest")
    source = manifest.get("theta_source")
    if source is None:
        raise DataError(f"{manifest_path}: not a recording of `admittance run --record` (no theta_source)")
    if source != PRESENT:
        raise _no_present_positions(folder, repr(source))
    dataset = load_dataset(folder)  # the contract's checks, and each trial's load
    entries = manifest.get("trials")
    whole = [_segment(folder, manifest_path, i, e, trial) for i, (e, trial) in enumerate(zip(entries, dataset.trials))]
    joints = {int(j["id"]): j for j in manifest.get("joints", []) if isinstance(j, dict) and "id" in j}
    return _recording(folder, whole, joints)


def _recording(where: Path, whole: list[Segment], joints: dict[int, dict]) -> Recording:
    """The stretches of the whole segments, checked for motion."""
    segments = tuple(run for segment in whole for run in _runs(segment))
    held = sum(int(s.columns.get("held", np.zeros(0)).sum()) for s in whole)
    gaps = sum(int((np.diff(s["t"]) > MAX_GAP_S).sum()) for s in whole)
    if not segments:
        raise DataError(f"{where}: no stretch of {MIN_RUN_S:g} s without a hold (stale force) or a gap of "
                        f"{1e3 * MAX_GAP_S:g} ms between reads; record again (on a loaded machine, raise "
                        "[loop].stale_timeout_ms)")
    recording = Recording(where, segments, joints, held, gaps)
    for joint_id in recording.joint_ids():
        _check_motion(where, joint_id, recording.of_joint(joint_id))
    return recording


def _no_present_positions(where: Path, source: str) -> DataError:
    return DataError(f"{where}: no present positions recorded (theta is {source}); record with "
                     "[loop].sync_read_divisor > 0 so the loop reads the servo")


def _from_mcap(path: Path) -> Recording:
    """The segments of a session.mcap, as its CSV folder gives them."""
    from admittance.formats.recording import read_recording, recording_dataset, recording_segments

    rec = read_recording(path)  # DataError: not found, not an MCAP of ours
    if not rec.session.get("measured_theta", True):
        raise _no_present_positions(rec.path, "the model angle")
    per_joint = recording_segments(rec)
    trials = iter(recording_dataset(rec).trials)  # the same segments, in the same order, with their load
    t0 = float(rec.session["t0"])
    sets = sorted(rec.params, key=lambda p: p.get("t", 0.0))
    whole = []
    for jid, segments in per_joint.items():
        for k, columns in enumerate(segments):
            _check_finite(f"{rec.path}: joint{jid}_{k:03d}", columns)
            target, compensation, changed = _ran(sets, jid, t0 + columns["t"][0], t0 + columns["t"][-1])
            whole.append(Segment(f"joint{jid}_{k:03d}", jid, columns, next(trials), target, compensation, changed))
    joints = {int(j["id"]): j for j in rec.session.get("joints", []) if isinstance(j, dict) and "id" in j}
    return _recording(rec.path, whole, joints)


def _ran(sets: list[dict], joint_id: int, start: float, end: float) -> tuple[dict[str, float], float | None, bool]:
    """What the loop ran for a joint from ``start`` (monotonic s): the values of the last /params
    message before it (the start's when none is), and whether another changed them by ``end``."""
    def values(message: dict) -> tuple[dict[str, float], float | None]:
        params = message.get("params", {})
        got = {k: _number(params[f"{joint_id}.{k}"], f"/params {joint_id}.{k}")
               for k in (*TARGET_KEYS, "servo_compensation") if f"{joint_id}.{k}" in params}
        return got, got.pop("servo_compensation", None)

    if not sets:
        return {}, None, False
    before = [m for m in sets if m.get("t", 0.0) <= start] or sets[:1]
    ran = values(before[-1])
    changed = any(values(m) != ran for m in sets if start < m.get("t", 0.0) <= end)
    return ran[0], ran[1], changed


def _segment(folder: Path, manifest_path: Path, index: int, entry: dict, trial: TrialData) -> Segment:
    where = f"{manifest_path}: trials[{index}]"
    path = folder / entry["file"]
    columns = read_columns(path)
    target = {k: _number(entry[k], f"{where}.{k}") for k in TARGET_KEYS if k in entry}
    compensation = _number(entry["servo_compensation"], f"{where}.servo_compensation") \
        if "servo_compensation" in entry else None
    joint_id = entry.get("joint_id", 1)
    if isinstance(joint_id, bool) or not isinstance(joint_id, int):
        raise DataError(f"{where}.joint_id: expected an integer, got {joint_id!r}")
    return Segment(entry["file"], joint_id, columns, trial, target, compensation,
                   bool(entry.get("params_changed", False)))


def _runs(segment: Segment) -> list[Segment]:
    """The stretches of ``segment`` between holds and gaps, each at least ``MIN_RUN_S`` long.
    While the force is stale the model holds instead of following the torque, and across a gap
    (reads failed: a stalled bus or loop) neither the goal the servo got nor the torque is known,
    so neither the admittance fit nor the servo fit may see those rows as dynamics."""
    held = segment.columns.get("held", np.zeros(segment.n)) > 0
    t = segment["t"]
    cut = held | np.concatenate([[False], np.diff(t) > MAX_GAP_S])

    def long_enough(rows: np.ndarray) -> bool:
        return rows.size >= MIN_SAMPLES and t[rows[-1]] - t[rows[0]] >= MIN_RUN_S

    if not cut.any():  # whole, if it is long enough itself (a segment between two live sets can be 0.1 s)
        return [segment] if long_enough(np.arange(segment.n)) else []
    runs = []
    starts = np.flatnonzero(cut)
    for k, rows in enumerate(np.split(np.arange(segment.n), starts)):
        rows = rows[~held[rows]]
        if long_enough(rows):
            columns = {c: v[rows] for c, v in segment.columns.items()}
            runs.append(dataclasses.replace(segment, name=f"{segment.name}[{k}]", columns=columns))
    return runs


def read_columns(path: Path) -> dict[str, np.ndarray]:
    """Every required (and present optional) column of a recorded CSV, as float arrays."""
    try:
        if path.stat().st_size > MAX_FILE_BYTES:
            raise DataError(f"{path}: larger than {MAX_FILE_BYTES >> 20} MiB; not a recording segment")
        with path.open(newline="", encoding="utf-8-sig") as fh:
            reader = csv.reader(fh)
            header = [h.strip() for h in next(reader, [])]
            rows = [row for row in reader if row and any(c.strip() for c in row)]
    except FileNotFoundError:
        raise DataError(f"{path}: trial file not found (listed in the manifest)") from None
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise DataError(f"{path}: cannot read ({exc})") from None
    missing = [c for c in REQUIRED if c not in header]
    if missing:
        raise DataError(f"{path}: not a recording of `admittance run --record`: no column "
                        f"{', '.join(missing)} (header: {','.join(header)})")
    index = {c: header.index(c) for c in (*REQUIRED, *OPTIONAL) if c in header}
    out = {c: np.empty(len(rows)) for c in index}
    for k, row in enumerate(rows):
        for c, col in index.items():
            try:
                out[c][k] = float(row[col])
            except (ValueError, IndexError):
                raise DataError(f"{path}: line {k + 2}: column {c!r}: not a number") from None
    _check_finite(str(path), out)
    return out


def _check_finite(where: str, columns: dict[str, np.ndarray]) -> None:
    for c, values in columns.items():
        if not np.all(np.isfinite(values)):
            bad = int(np.flatnonzero(~np.isfinite(values))[0])
            raise DataError(f"{where}: column {c!r}: NaN or infinite value at row {bad}")


def _number(value, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise DataError(f"{where}: expected a finite number, got {value!r}")
    return float(value)


def _check_motion(folder: Path, joint_id: int, segments: list[Segment]) -> None:
    model = np.concatenate([s["theta_model"] for s in segments])
    tau = np.concatenate([s["tau"] for s in segments])
    if not np.any(tau != 0.0):
        raise DataError(f"{folder}: joint {joint_id}: no hand torque recorded (tau is 0 throughout): "
                        "nothing drove the model")
    if not moved(model):
        raise DataError(f"{folder}: joint {joint_id}: no motion (the model moved {1e3 * np.ptp(model):.1f} mrad, "
                        f"less than {1e3 * MIN_MOTION_RAD:.0f}); push the joint while recording")
