"""Record a session as a pendulum dataset (../shared/contracts/datasets.md), for `identify`.

``admittance run --record DIR`` writes ``DIR/manifest.toml`` and one CSV per joint. The
contract's columns are ``t`` (s from the start), ``theta`` (rad) and ``tau`` (N·m, the hand
torque the model saw); extra columns keep the rest of the cycle (force, the model's angle and
velocity, the goal angle) for plots and for replay checks.

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

import numpy as np
import tomli_w

from admittance.errors import ConfigError

COLUMNS = ("t", "theta", "tau", "force", "theta_model", "omega_model", "theta_goal")
NEGLIGIBLE_BOB = {"mass": 1e-6}  # kg
NEGLIGIBLE_BOB_DISTANCE = 1e-3  # m


class Recorder:
    """One CSV per joint plus the manifest; ``append`` takes column arrays of one joint."""

    def __init__(self, folder: Path, joints: list[tuple[int, str]], *, measured_theta: bool, t0: float) -> None:
        self.folder = folder
        self.t0 = t0
        self.measured_theta = measured_theta
        self.rows = {joint_id: 0 for joint_id, _ in joints}
        try:
            folder.mkdir(parents=True, exist_ok=True)
            self._files = {jid: (folder / self.file_name(jid)).open("w", newline="") for jid, _ in joints}
        except OSError as exc:
            raise ConfigError(f"record: cannot write into {folder} ({exc.strerror})") from None
        self._writers = {jid: csv.writer(fh) for jid, fh in self._files.items()}
        for writer in self._writers.values():
            writer.writerow(COLUMNS)
        self._write_manifest(joints)

    @staticmethod
    def file_name(joint_id: int) -> str:
        return f"joint{joint_id}.csv"

    def _write_manifest(self, joints: list[tuple[int, str]]) -> None:
        motors = sorted({model for _, model in joints})
        doc = {
            "motor": ", ".join(motors),
            "source": "admittance run --record",
            "theta_source": "present position" if self.measured_theta else "model angle (no present reads)",
            "bob": NEGLIGIBLE_BOB,
            "trials": [{"file": self.file_name(jid), "bob_distance": NEGLIGIBLE_BOB_DISTANCE,
                        "joint_id": jid, "motor": model} for jid, model in joints],
        }
        (self.folder / "manifest.toml").write_text(tomli_w.dumps(doc))

    def append(self, joint_id: int, columns: dict[str, np.ndarray]) -> int:
        """Append the rows of one joint; returns how many were written.

        ``columns`` holds ``t`` (s, monotonic), ``tau``, ``force``, ``theta_model``,
        ``omega_model``, ``theta_goal`` and ``theta_present`` (NaN where not read).
        """
        keep = np.isfinite(columns["theta_present"]) if self.measured_theta else np.ones(len(columns["t"]), bool)
        theta = columns["theta_present"] if self.measured_theta else columns["theta_model"]
        table = np.column_stack([
            columns["t"][keep] - self.t0, theta[keep], columns["tau"][keep], columns["force"][keep],
            columns["theta_model"][keep], columns["omega_model"][keep], columns["theta_goal"][keep],
        ])
        self._writers[joint_id].writerows(table.tolist())
        self._files[joint_id].flush()
        self.rows[joint_id] += len(table)
        return len(table)

    def close(self) -> None:
        for fh in self._files.values():
            fh.close()
