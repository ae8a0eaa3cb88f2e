"""Record a session as a pendulum dataset (../shared/contracts/datasets.md), for `identify`.

``admittance run --record DIR`` writes ``DIR/manifest.toml`` and, per joint, CSV segments of
``[record].segment_s`` seconds (``joint1_000.csv``, ``joint1_001.csv``...), one trial each. The
contract's columns are ``t`` (s from the start), ``theta`` (rad) and ``tau`` (N·m, the hand
torque the model saw); extra columns keep the rest of the cycle (force, the model's angle and
velocity, the goal angle, the cycle number, the fault bits) for plots and for replay checks.

``theta`` is what a refit needs: the joint's *measured* angle, so a row is written each cycle
the servo's present position was read (every ``[loop].sync_read_divisor`` cycles). With
reading off (divisor 0) the model angle stands in, and the manifest says so
(``theta_source``).

The admittance model has no gravity term, yet the dataset contract calls a dataset without
geometry "lumped" (parameters per unit inertia), which the daemon refuses to load. The manifest
therefore declares a negligible point mass (1 mg at 1 mm: 1e-12 kg·m², 1e-8 N·m) so that
`identify` fits in SI units and its output can be loaded back as a joint's ``params``:
record → identify → reload.

Rows are appended as they are drained from the loop and flushed each batch, so a session cut
short (power loss, SIGKILL) still leaves a readable dataset.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any, TextIO

import numpy as np
import tomli_w

from admittance.errors import ConfigError

COLUMNS = ("t", "theta", "tau", "force", "theta_model", "omega_model", "theta_goal", "cycle", "fault")
MIN_ROWS = 10  # the dataset loader's minimum per trial
NEGLIGIBLE_BOB = {"mass": 1e-6}  # kg
NEGLIGIBLE_BOB_DISTANCE = 1e-3  # m


class Recorder:
    """Per joint, consecutive CSV segments plus the manifest; ``append`` takes column arrays.

    A session is cut into segments of about ``segment_s`` seconds (one trial each): the refit
    then estimates an initial state per segment and can hold some segments out, instead of
    simulating one long session open-loop from its first sample.
    """

    def __init__(self, folder: Path, joints: list[tuple[int, str]], *, measured_theta: bool, t0: float,
                 segment_s: float = 10.0) -> None:
        self.folder = folder
        self.t0 = t0
        self.measured_theta = measured_theta
        self.segment_s = segment_s
        self.models = dict(joints)
        self.rows = {joint_id: 0 for joint_id in self.models}
        self._segments: dict[int, list[str]] = {joint_id: [] for joint_id in self.models}
        self._segment_rows: dict[int, int] = {}
        self._segment_start: dict[int, float] = {}
        self._files: dict[int, TextIO] = {}
        self._writers: dict[int, Any] = {}
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ConfigError(f"record: cannot create {folder} ({exc.strerror})") from None
        for joint_id in self.models:
            self._open_segment(joint_id, 0.0)

    def _open_segment(self, joint_id: int, t: float) -> None:
        name = f"joint{joint_id}_{len(self._segments[joint_id]):03d}.csv"
        try:
            fh = (self.folder / name).open("w", newline="")
        except OSError as exc:
            raise ConfigError(f"record: cannot write into {self.folder} ({exc.strerror})") from None
        self._files[joint_id] = fh
        self._writers[joint_id] = csv.writer(fh)
        self._writers[joint_id].writerow(COLUMNS)
        self._segments[joint_id].append(name)
        self._segment_rows[joint_id] = 0
        self._segment_start[joint_id] = t
        self._write_manifest()

    def _write_manifest(self) -> None:
        trials = [{"file": name, "bob_distance": NEGLIGIBLE_BOB_DISTANCE, "joint_id": jid, "motor": self.models[jid]}
                  for jid, names in self._segments.items() for name in names]
        doc = {
            "motor": ", ".join(sorted(set(self.models.values()))),
            "source": "admittance run --record",
            "theta_source": "present position" if self.measured_theta else "model angle (no present reads)",
            "bob": NEGLIGIBLE_BOB,
            "trials": trials,
        }
        tmp = self.folder / "manifest.toml.tmp"
        tmp.write_text(tomli_w.dumps(doc))
        tmp.replace(self.folder / "manifest.toml")  # readers never see half a manifest

    def append(self, joint_id: int, columns: dict[str, np.ndarray]) -> int:
        """Append the rows of one joint; returns how many were written.

        ``columns`` holds ``t`` (s, monotonic), ``tau``, ``force``, ``theta_model``,
        ``omega_model``, ``theta_goal``, ``theta_present`` (NaN where not read), ``cycle`` and
        ``fault`` (the loop's fault bits of that joint; 0, or absent, when none).
        """
        fault = columns.get("fault", np.zeros(len(columns["t"])))
        keep = np.isfinite(columns["theta_present"]) if self.measured_theta else np.ones(len(columns["t"]), bool)
        if not keep.any():
            return 0
        theta = columns["theta_present"] if self.measured_theta else columns["theta_model"]
        t = columns["t"][keep] - self.t0
        if t[0] - self._segment_start[joint_id] >= self.segment_s and self._segment_rows[joint_id] >= MIN_ROWS:
            self._files[joint_id].close()
            self._open_segment(joint_id, float(t[0]))
        table = np.column_stack([
            t, theta[keep], columns["tau"][keep], columns["force"][keep],
            columns["theta_model"][keep], columns["omega_model"][keep], columns["theta_goal"][keep],
            columns["cycle"][keep], fault[keep],
        ])
        self._writers[joint_id].writerows(table.tolist())
        self._files[joint_id].flush()
        self.rows[joint_id] += len(table)
        self._segment_rows[joint_id] += len(table)
        return len(table)

    def close(self) -> None:
        """Close the files; a last segment too short to fit on is dropped (file and manifest entry)."""
        for joint_id, fh in self._files.items():
            fh.close()
            names = self._segments[joint_id]
            if self._segment_rows[joint_id] < MIN_ROWS and len(names) > 1:
                (self.folder / names.pop()).unlink()
        self._write_manifest()
