"""Record a session as a pendulum dataset (../shared/contracts/datasets.md), for `identify`
and `fidelity`.

``admittance run --record DIR`` writes ``DIR/manifest.toml`` and, per joint, CSV segments of
``[record].segment_s`` seconds (``joint1_000.csv``, ``joint1_001.csv``...), one trial each. The
contract's columns are ``t`` (s from the start), ``theta`` (rad) and ``tau`` (N·m, the hand
torque the model saw); extra columns keep the rest of the cycle (force, the model's angle and
velocity, the goal angle, the cycle's wake-up time, the cycle number, ``held`` = 1 where the
model did not follow the torque, and ``fault``, the fault bits) for `fidelity`, plots and replay
checks. ``held`` and ``fault`` cover every cycle since the previous row: a row is written only
on the cycles that read the servo, and a hold or a fault between two reads leaves no row of its
own. ``tau_mean`` keeps the torque's impulse between rows: the mean of the torques the model
stepped with from the previous row's time to this row's, each weighed by the steps taken with it
(``tau`` is one cycle's sample, and a
step in the hand's torque between two rows would otherwise move the refit's impulse by up to a
whole row interval of it); the first row of a recording has its own ``tau``. ``held`` is 1 when the loop was not running (docs/realtime.md, the fault model): it held
because the force was stale, or a fault held a joint. After a stall longer than the loop
catches up (``MAX_CATCH_UP_STEPS`` steps) the model restarted its time at the late deadline and
never integrated the torque over the rest of the stall: a *lapse*, which leaves no column but
starts a new segment.

A trial must be one continuous solution of the model, so a new segment starts after time the
model lost, where a hold begins, and after a hold of two rows or more (:func:`trial_starts`; such
a hold's rows form a segment of their own, so the recording still covers the run): otherwise an open-loop refit integrates
the torque over time the model did not follow it (a loaded machine's stalls biased the refit's
inertia by 7 %).

Two alignments make ``theta_model`` against ``tau`` exactly the dataset contract's simulator
(so `identify` with theta := theta_model returns the configured I, B, F):

- ``t`` is the cycle's *deadline*, the model's own time (the loop integrates one step per
  deadline, a skipped one included), not its wake-up time, which is late by the scheduler's
  jitter; ``t_wake`` keeps the wake-up time, when the goal was written and the servo read.
- ``tau`` on a row is the torque of the *next* cycle: the model's step at cycle k uses that
  cycle's newest torque over the interval that ends at k, while the contract's simulator
  applies τ(t) over the substep that *starts* at t. The recorder therefore holds each batch's
  last cycle back until the next batch (or the close) shows what follows it.

A cycle that took no step (the loop's grid, phase-locked to a sensor on another clock, fell
half a period behind the model: docs/realtime.md) repeats its predecessor's ``t`` and state,
and its torque was never integrated: the predecessor's row is then *superseded* and left out,
so ``t`` stays strictly increasing and each row's ``tau`` is the one the model stepped with.

The same rows are made from a ``session.mcap`` (every cycle) by :func:`recorded_rows`, so both
files of a session give the same dataset (admittance.formats.recording.load_recording).

``theta`` is what a refit needs: the joint's *measured* angle, so a row is written each cycle
the servo's present position was read (every ``[loop].sync_read_divisor`` cycles). With
reading off (divisor 0) the model angle stands in, and the manifest says so
(``theta_source``).

The admittance model has no gravity term, yet the dataset contract calls a dataset without
geometry "lumped" (parameters per unit inertia), which the daemon refuses to load. The manifest
therefore declares a negligible point mass (1 mg at 1 mm: 1e-12 kg·m², 1e-8 N·m) so that
`identify` fits in SI units and its output can be loaded back as a joint's ``params``:
record → identify → reload.

Rows are appended as they are drained from the loop and written through each batch (an
unbuffered file: a batch's bytes reach the OS in one write), so a session cut short (power
loss, SIGKILL) still leaves a readable dataset. A write that fails (a full disk, a quota, a
pulled USB stick) cuts the file back to its last whole row and raises ``OSError``: the
supervisor then stops the recording with one line (:meth:`Recorder.abort`) and the loop runs on;
what was written stays a readable dataset.

Faults: a row needs the servo's measured angle, so while a fault keeps the servo from being
read (the bus unplugged, a servo rebooting or browned out) there are no rows. Such a *gap*
(rows further apart than ``gap_s``) ends the segment, the rows after it open a new one (an
open-loop refit must not integrate across it), and the manifest lists it under ``[[gaps]]``
(joint, ``t_start``, ``t_end``, the ``faults`` seen), also when the run ends inside it. A gap
spans the CSV's stretch without rows: from the last row kept before it to the first row kept
after it (a dropped piece next to it, below, lies inside it, and two gaps with only a dropped
piece between them are one). The
first row after a gap carries the gap's fault bits and ``held`` (gathered since the previous
row), and ``session.mcap`` holds every cycle of the gap, marked. A trial shorter than
``MIN_ROWS`` (between two gaps, or a short hold) is too short to fit and is dropped from the CSV
(not from the MCAP); the manifest lists it under ``[[dropped]]`` (joint, ``t_start``, ``t_end``,
``rows``, the ``faults`` its rows carried), so no fault is lost with its rows.
"""

from __future__ import annotations

import contextlib
import csv
import io
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import tomli_w

from admittance.daemon.telemetry import fault_names
from admittance.errors import ConfigError
from admittance.formats.recording import (  # the rows' format and where trials start
    COLUMNS, DEFAULT_GAP_S, MIN_ROWS, NEGLIGIBLE_BOB, NEGLIGIBLE_BOB_DISTANCE, recorded_rows, trial_starts,
    with_defaults, with_next_cycle,
)

# The per-joint values written into each trial's manifest entry: what the loop ran.
TARGET_KEYS = ("virtual_inertia", "virtual_damping", "virtual_coulomb", "servo_compensation")


class Recorder:
    """Per joint, consecutive CSV segments plus the manifest; ``append`` takes column arrays.

    A session is cut into segments of about ``segment_s`` seconds (one trial each): the refit
    then estimates an initial state per segment and can hold some segments out, instead of
    simulating one long session open-loop from its first sample.
    """

    def __init__(self, folder: Path, joints: list[tuple[int, str]], *, measured_theta: bool, t0: float,
                 segment_s: float = 10.0, joint_info: dict[int, dict] | None = None,
                 gap_s: float = DEFAULT_GAP_S, period_s: float | None = None) -> None:
        self.folder = folder
        self.t0 = t0
        self.measured_theta = measured_theta
        self.segment_s = segment_s
        self.gap_s = gap_s
        self.period_s = period_s  # the loop's period: to see where the model lost time (model_lapses)
        # Per joint: the last written row's t, the last cycle's t (written or not); the gaps.
        self._last_row_t: dict[int, float] = {}
        self._last_cycle_t: dict[int, float] = {}
        self.gaps: list[dict[str, Any]] = []
        # Per joint: the gap that opened the current segment, with its fault bits: if that
        # segment is dropped (fewer than MIN_ROWS rows), the gap's end moves on to the CSV's
        # next kept row. And the t of the last row of a segment that is kept.
        self._open_gap: dict[int, tuple[dict[str, Any], int]] = {}
        self._kept_row_t: dict[int, float] = {}
        self.dropped: list[dict[str, Any]] = []  # trials too short to fit, removed from the CSV
        self.models = dict(joints)
        # Per joint: the parameter file, plant and loop settings (the manifest's [[joints]]).
        self.joint_info = joint_info or {}
        self._targets: dict[int, dict[str, float]] = {jid: {} for jid in self.models}
        self._entries: dict[int, list[dict]] = {jid: [] for jid in self.models}
        self._pending: dict[int, dict[str, np.ndarray]] = {}
        # Per joint: (held, fault, torque sum, cycles) of the cycles after its last written row
        # (see recorded_rows).
        self._carry: dict[int, tuple] = {}
        self._last_rows_held: dict[int, tuple[float, float]] = {}  # held of the last two rows, newest first
        self.rows = {joint_id: 0 for joint_id in self.models}
        self._segments: dict[int, list[str]] = {joint_id: [] for joint_id in self.models}
        self._segment_rows: dict[int, int] = {}
        self._segment_start: dict[int, float] = {}
        self._segment_faults: dict[int, int] = {}
        self._files: dict[int, BinaryIO] = {}
        self.stopped = False  # by abort(): a write failed; nothing more is written
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ConfigError(f"record: cannot create {folder} ({exc.strerror})") from None
        for joint_id in self.models:
            self._open_segment(joint_id, 0.0)

    def _open_segment(self, joint_id: int, t: float) -> None:
        name = f"joint{joint_id}_{len(self._segments[joint_id]):03d}.csv"
        try:
            fh = (self.folder / name).open("wb", buffering=0)
        except OSError as exc:
            raise ConfigError(f"record: cannot write into {self.folder} ({exc.strerror})") from None
        self._files[joint_id] = fh
        self._segments[joint_id].append(name)
        self._entries[joint_id].append(dict(self._targets[joint_id]))
        self._segment_rows[joint_id] = 0
        self._segment_start[joint_id] = t
        self._segment_faults[joint_id] = 0
        self._append_bytes(joint_id, csv_text([COLUMNS]))
        self._write_manifest()

    def _append_bytes(self, joint_id: int, data: bytes) -> None:
        """All of ``data`` at the end of the joint's file, or none of it: a failed write (ENOSPC)
        cuts the file back to where it was, so it ends at a whole row, and raises."""
        fh = self._files[joint_id]
        start = fh.tell()
        view = memoryview(data)
        try:
            while view:
                view = view[fh.write(view):]
        except OSError:
            with contextlib.suppress(OSError):
                fh.truncate(start)
            raise

    def _write_manifest(self) -> None:
        trials = [{"file": name, "bob_distance": NEGLIGIBLE_BOB_DISTANCE, "joint_id": jid, "motor": self.models[jid],
                   **entry}
                  for jid, names in self._segments.items() for name, entry in zip(names, self._entries[jid])]
        doc = {
            "motor": ", ".join(sorted(set(self.models.values()))),
            "source": "admittance run --record",
            "theta_source": "present position" if self.measured_theta else "model angle (no present reads)",
            "bob": NEGLIGIBLE_BOB,
            "trials": trials,
        }
        if self.joint_info:
            doc["joints"] = [{"id": jid, **info} for jid, info in self.joint_info.items()]
        if self.gaps:
            doc["gaps"] = self.gaps
        if self.dropped:
            doc["dropped"] = self.dropped
        tmp = self.folder / "manifest.toml.tmp"
        try:
            tmp.write_text(tomli_w.dumps(doc))
        except OSError:
            tmp.unlink(missing_ok=True)  # the last whole manifest stays
            raise
        tmp.replace(self.folder / "manifest.toml")  # readers never see half a manifest

    def set_targets(self, params: dict[str, float]) -> None:
        """The loop's parameters (its flat ``params()``), recorded with each segment: a segment
        opened after this carries them, one open now is marked ``params_changed``."""
        if self.stopped:
            return
        for joint_id in self.models:
            values = {key: float(params[f"{joint_id}.{key}"]) for key in TARGET_KEYS if f"{joint_id}.{key}" in params}
            if values == self._targets[joint_id]:
                continue
            if self._targets[joint_id] and self._entries[joint_id]:
                self._entries[joint_id][-1]["params_changed"] = True
            self._targets[joint_id] = values
            if self._entries[joint_id] and not self._entries[joint_id][-1]:
                self._entries[joint_id][-1].update(values)  # the first segment, opened before the loop ran
        self._write_manifest()

    def append(self, joint_id: int, columns: dict[str, np.ndarray]) -> int:
        """Append the rows of one joint (every cycle of a drained batch); returns how many were written.

        ``columns`` holds ``t`` (s, the cycle's deadline), ``tau``, ``force``, ``theta_model``,
        ``omega_model``, ``theta_goal``, ``theta_present`` (NaN where not read), ``cycle``, and
        optionally ``t_wake`` (else ``t``), ``mode`` (the loop's mode code) and ``fault`` (that
        joint's fault bits), both 0 when absent. The batch's last cycle waits for the next batch
        (see the module doc).
        """
        if self.stopped:
            return 0
        columns = self._with_next_tau(joint_id, columns)
        return self._write(joint_id, columns) if columns is not None else 0

    def append_all(self, by_joint: dict[int, dict[str, np.ndarray]]) -> None:
        """``append`` for each joint's columns of one drained batch."""
        for joint_id, columns in by_joint.items():
            self.append(joint_id, columns)

    def _with_next_tau(self, joint_id: int, columns: dict[str, np.ndarray]) -> dict[str, np.ndarray] | None:
        """The pending cycle plus this batch, each with the following cycle's torque, minus the new
        last cycle (kept pending)."""
        columns = with_defaults(columns)
        pending = self._pending.pop(joint_id, None)
        if pending is not None:
            columns = {k: np.concatenate([pending[k], v]) for k, v in columns.items() if k in pending}
        if len(columns["t"]) == 0:
            return None
        self._pending[joint_id] = {k: v[-1:] for k, v in columns.items()}
        if len(columns["t"]) == 1:
            return None
        columns = with_next_cycle(columns, self.period_s)
        return {k: v[:-1] for k, v in columns.items()}

    def _write(self, joint_id: int, columns: dict[str, np.ndarray]) -> int:
        previous_cycle = self._last_cycle_t.get(joint_id)
        rows, self._carry[joint_id] = recorded_rows(
            columns, measured_theta=self.measured_theta, t0=self.t0, carry=self._carry.get(joint_id, (0, 0)),
            period_s=self.period_s, previous_t=None if previous_cycle is None else previous_cycle + self.t0)
        if len(columns["t"]):
            self._last_cycle_t[joint_id] = float(columns["t"][-1] - self.t0)
        t = rows["t"]
        if len(t) == 0:
            return 0
        last_held = self._last_rows_held.get(joint_id, (0.0, 0.0))
        gaps, breaks = trial_starts(t, rows["held"], rows["lapse"], self.gap_s, self._last_row_t.get(joint_id),
                                    last_held)
        self._last_rows_held[joint_id] = tuple(np.concatenate([last_held[::-1], rows["held"]])[-1:-3:-1])
        written = 0
        for piece in np.split(np.arange(len(t)), np.union1d(gaps, breaks)):
            if len(piece) == 0:
                continue
            if piece[0] in gaps:
                self._gap(joint_id, self._last_row_t[joint_id], float(t[piece[0]]), int(rows["fault"][piece[0]]))
            elif (piece[0] in breaks and self._segment_rows[joint_id] > 0) or \
                    (t[piece[0]] - self._segment_start[joint_id] >= self.segment_s and self._segment_rows[joint_id] >= MIN_ROWS):
                self._next_segment(joint_id, float(t[piece[0]]))
            written += self._write_rows(joint_id, {c: rows[c][piece] for c in COLUMNS})
        return written

    def _write_rows(self, joint_id: int, rows: dict[str, np.ndarray]) -> int:
        table = np.column_stack([rows[c] for c in COLUMNS])
        self._append_bytes(joint_id, csv_text(table.tolist()))
        self.rows[joint_id] += len(table)
        self._segment_faults[joint_id] |= int(np.bitwise_or.reduce(rows["fault"].astype(np.int64)))
        self._segment_rows[joint_id] += len(table)
        self._last_row_t[joint_id] = float(rows["t"][-1])
        if self._segment_rows[joint_id] >= MIN_ROWS:  # this segment stays in the CSV
            self._kept_row_t[joint_id] = self._last_row_t[joint_id]
        return len(table)

    def _gap(self, joint_id: int, t_start: float, t_end: float, fault: int) -> None:
        """The servo went unread from ``t_start`` to ``t_end``: listed, and a new segment after it.
        A gap lists a stretch of the CSV without rows: when the segment before it is dropped, it
        starts at the last row kept, and it is one with a gap that opened the dropped segment."""
        open_gap = self._open_gap.pop(joint_id, None)
        dropped = self._close_segment(joint_id)
        if dropped and open_gap is not None:
            entry, fault = open_gap[0], open_gap[1] | fault
            entry.update(t_end=t_end, faults=fault_names(fault))
        else:
            if dropped:
                t_start = self._kept_row_t.get(joint_id, 0.0)
            entry = {"joint_id": joint_id, "t_start": t_start, "t_end": t_end, "faults": fault_names(fault)}
            self.gaps.append(entry)
        self._open_gap[joint_id] = (entry, fault)
        self._open_segment(joint_id, t_end)

    def _next_segment(self, joint_id: int, t: float) -> None:
        """Close the segment (dropping it when too short to fit: the MCAP keeps its cycles), open
        the next; a gap that opened the dropped segment then reaches the next one."""
        open_gap = self._open_gap.pop(joint_id, None)
        if self._close_segment(joint_id) and open_gap is not None:
            open_gap[0]["t_end"] = t
            self._open_gap[joint_id] = open_gap
        self._open_segment(joint_id, t)

    def _close_segment(self, joint_id: int) -> bool:
        """Close the joint's segment; drop it when too short to fit. True when dropped."""
        self._files[joint_id].close()
        if self._segment_rows[joint_id] >= MIN_ROWS:
            return False
        self._drop_segment(joint_id)
        return True

    def _drop_segment(self, joint_id: int) -> None:
        """Remove the joint's last segment (file and manifest entry); list it when it had rows."""
        (self.folder / self._segments[joint_id].pop()).unlink()
        self._entries[joint_id].pop()
        if self._segment_rows[joint_id]:  # from its opening to its last row, the joint's last
            t_start, t_end = self._segment_start[joint_id], self._last_row_t[joint_id]
            self.dropped.append({"joint_id": joint_id, "t_start": t_start, "t_end": t_end,
                                 "rows": self._segment_rows[joint_id],
                                 "faults": fault_names(self._segment_faults[joint_id])})

    def close(self) -> None:
        """Write the held-back cycles (with their own torque: nothing follows them), close the
        files; a last segment too short to fit on is dropped (file and manifest entry). A run
        that ended inside a gap lists it up to its last cycle."""
        if self.stopped:
            return
        for joint_id, pending in list(self._pending.items()):
            self._write(joint_id, pending)
        self._pending.clear()
        for joint_id, fh in self._files.items():
            fh.close()
            dropped = self._segment_rows[joint_id] < MIN_ROWS and len(self._segments[joint_id]) > 1
            if dropped:
                self._drop_segment(joint_id)
            self._gap_at_the_end(joint_id, dropped)
        self._write_manifest()

    def _gap_at_the_end(self, joint_id: int, dropped: bool) -> None:
        """A run that ended inside a gap lists it up to its last cycle; so does a gap whose
        segment, the last, was dropped (no row of the CSV follows it)."""
        last_cycle = self._last_cycle_t.get(joint_id)
        if last_cycle is None:
            return
        fault = self._carry.get(joint_id, (0, 0))[1]
        open_gap = self._open_gap.pop(joint_id, None) if dropped else None
        if open_gap is not None:
            entry, bits = open_gap
            entry.update(t_end=max(entry["t_end"], last_cycle), faults=fault_names(bits | fault))
            return
        last_row = self._last_row_t.get(joint_id, 0.0)
        if last_cycle - last_row > self.gap_s:
            t_start = self._kept_row_t.get(joint_id, 0.0) if dropped else last_row
            self.gaps.append({"joint_id": joint_id, "t_start": t_start, "t_end": last_cycle,
                              "faults": fault_names(fault)})

    def abort(self) -> None:
        """Stop after a write failed: close the files (each ends at a whole row) and write what the
        manifest can still say; never raises (the disk may still be full)."""
        self.stopped = True
        self._pending.clear()
        for fh in self._files.values():
            with contextlib.suppress(OSError):
                fh.close()
        with contextlib.suppress(OSError):
            self._write_manifest()


def csv_text(rows: list) -> bytes:
    """Rows as CSV bytes (the csv module's quoting, "\\r\\n" line ends as before)."""
    buffer = io.StringIO(newline="")
    csv.writer(buffer).writerows(rows)
    return buffer.getvalue().encode()
