"""Pendulum datasets (``shared/contracts/datasets.md``): a folder with ``manifest.toml`` and one
file per trial.

Everything is validated on load, so the fit never meets a NaN or a time series that goes
backwards: each problem raises :class:`DataError` with one line naming the file (and the key or
row) at fault. The load's inertia and gravity torque are worked out here from the geometry, so the
rest of the pipeline sees only numbers per trial.

Trial files are CSV by default. A ``[[trials]]`` entry may carry ``format = "..."`` (an extension
of the contract) for the recorders' own formats; those are read by
``admittance.formats.converters.load_trial``, imported only when needed so a plain CSV dataset never
pays for the loaders.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

import numpy as np

from admittance.errors import DataError
from admittance.formats.paramfile import read_toml
from admittance.formats.trial import (  # noqa: F401  (a dataset's types, read with it)
    GRAVITY, MIN_SAMPLES, Dataset, TrialArrays, TrialData, check_series, load_geometry,
)

MANIFEST = "manifest.toml"

def load_dataset(folder: str | Path) -> Dataset:
    """Read ``folder/manifest.toml`` and every trial it lists (or a session.mcap: recording.load_recording)."""
    folder = Path(folder)
    if folder.suffix == ".mcap" and folder.is_file():
        from admittance.formats.recording import load_recording

        return load_recording(folder)
    if not folder.is_dir():
        raise DataError(f"{folder}: dataset folder not found")
    manifest_path = folder / MANIFEST
    manifest = read_toml(manifest_path, DataError, "manifest")
    rod = _geometry_table(manifest, "rod", ("mass", "length"), manifest_path)
    bob = _geometry_table(manifest, "bob", ("mass",), manifest_path)
    entries = manifest.get("trials")
    if not isinstance(entries, list) or not entries:
        raise DataError(f"{manifest_path}: no [[trials]] listed")
    mode = "geometry" if (rod or bob) else "lumped"
    trials = []
    seen: set[str] = set()
    for index, entry in enumerate(entries):
        trial = _load_entry(folder, manifest_path, index, entry, rod, bob)
        if trial.name in seen:
            raise DataError(f"{manifest_path}: trials[{index}]: file {trial.name!r} listed twice")
        seen.add(trial.name)
        trials.append(trial)
    motor = manifest.get("motor", "")
    return Dataset(
        mode=mode,
        trials=tuple(trials),
        motor=str(motor),
        folder=folder,
        geometry={"rod": rod, "bob": bob},
        encoder_ticks=_encoder_ticks(manifest.get("encoder_ticks"), manifest_path),
    )


MAX_ENCODER_TICKS = 1 << 24


def _encoder_ticks(value: Any, path: Path) -> int | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or not 2 <= value <= MAX_ENCODER_TICKS:
        raise DataError(f"{path}: encoder_ticks must be a whole number of ticks per revolution "
                        f"(2 to {MAX_ENCODER_TICKS}), got {value!r}")
    return value


def _geometry_table(manifest: dict, name: str, keys: tuple[str, ...], path: Path) -> dict | None:
    table = manifest.get(name)
    if table is None:
        return None
    if not isinstance(table, dict):
        raise DataError(f"{path}: [{name}] must be a table")
    out = {}
    for key in keys:
        out[key] = _positive_number(table.get(key), f"{path}: [{name}] {key}")
    return out


def _positive_number(value: Any, where: str) -> float:
    if value is None:
        raise DataError(f"{where}: missing")
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise DataError(f"{where}: expected a number, got {value!r}")
    if not math.isfinite(value) or value <= 0:
        raise DataError(f"{where}: must be a positive finite number, got {value!r}")
    return float(value)


def _load_entry(folder: Path, manifest_path: Path, index: int, entry: Any, rod, bob) -> TrialData:
    where = f"{manifest_path}: trials[{index}]"
    if not isinstance(entry, dict):
        raise DataError(f"{where}: must be a table")
    name = entry.get("file")
    if not isinstance(name, str) or not name:
        raise DataError(f"{where}: missing 'file'")
    distance = None
    if bob:
        distance = _positive_number(entry.get("bob_distance"), f"{where} ({name}): bob_distance")
    fmt = entry.get("format", "csv")
    if not isinstance(fmt, str):
        raise DataError(f"{where} ({name}): format must be a string, got {fmt!r}")
    path = folder / name
    if not path.is_file():
        raise DataError(f"{path}: trial file not found (listed in {manifest_path.name})")
    t, theta, tau = check_series(path, *_read_series(path, fmt))
    inertia, gravity = load_geometry(rod, bob, distance)
    meta = {k: v for k, v in entry.items() if k != "file"}
    meta.setdefault("format", fmt)
    return TrialData(name=name, t=t, theta=theta, tau=tau, load_inertia=inertia, gravity_torque=gravity, meta=meta)


def _read_series(path: Path, fmt: str) -> TrialArrays:
    if fmt == "csv":
        return read_csv_trial(path)
    from admittance.formats import converters  # only datasets in recorder formats need it

    return converters.load_trial(path, fmt)


def read_csv_trial(path: Path) -> TrialArrays:
    """Columns ``t``, ``theta`` and optional ``tau``, by header name, in any order."""
    try:
        # utf-8-sig: spreadsheet programs put a byte-order mark before the first header name.
        with path.open(newline="", encoding="utf-8-sig") as fh:
            rows = list(csv.reader(fh))
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: cannot read ({exc})") from None
    if not rows:
        raise DataError(f"{path}: empty file (no header row)")
    header = [h.strip() for h in rows[0]]
    for required in ("t", "theta"):
        if required not in header:
            raise DataError(f"{path}: missing column {required!r} (header: {','.join(header)})")
    for name in ("t", "theta", "tau"):
        if header.count(name) > 1:  # which one is meant cannot be guessed
            raise DataError(f"{path}: column {name!r} appears {header.count(name)} times in the header")
    wanted = {name: header.index(name) for name in ("t", "theta", "tau") if name in header}
    columns: dict[str, list[float]] = {name: [] for name in wanted}
    for line_no, row in enumerate(rows[1:], start=2):
        if not row or all(not cell.strip() for cell in row):
            continue
        for name, col in wanted.items():
            columns[name].append(_cell(path, line_no, name, row, col))
    arrays = {name: np.asarray(values, dtype=float) for name, values in columns.items()}
    return arrays["t"], arrays["theta"], arrays.get("tau")


def _cell(path: Path, line_no: int, name: str, row: list[str], col: int) -> float:
    if col >= len(row):
        raise DataError(f"{path}: line {line_no}: missing value in column {name!r}")
    text = row[col].strip()
    try:
        return float(text)
    except ValueError:
        raise DataError(f"{path}: line {line_no}: column {name!r}: not a number: {text!r}") from None


