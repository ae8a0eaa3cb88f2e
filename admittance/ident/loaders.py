"""Trial loaders for foreign recording formats, and converters to contract datasets.

A contract dataset (../shared/contracts/datasets.md) holds plain ``t, theta[, tau]`` CSVs. The
recordings we meet are not in that form: the thesis's OptiTrack Motive exports (two markers;
the angle is the direction of the line between them), Dynamixel encoder logs (Rhoban BAM's
JSON, or a CSV of present-position ticks) and the DFKI pendulum's driver log. Each format gets
one parser here that returns ``(t, theta, tau | None)`` in SI units; the dataset loader
dispatches ``[[trials]] format = "..."`` entries to :func:`load_trial`, and
:func:`write_dataset` turns parsed trials into a contract folder so ``admittance identify``
(and anything else that reads datasets) runs on them unchanged.

Design choices:
- Time is taken from the file, never rebuilt from a nominal rate: BAM and DFKI logs are not
  uniformly sampled, and Motive drops frames where a marker is occluded.
- Missing marker cells are dropped frame by frame rather than interpolated: an invented angle
  would enter the fit as if it were measured, whereas a gap is handled exactly by the
  simulator (it integrates to the next sample time).
- Angles are unwrapped so a swing through ±π is not a 2π jump.
- Every check raises :class:`~admittance.errors.DataError` naming the file, so a bad file is a
  one-line CLI error and nothing is half written.
"""

from __future__ import annotations

import csv
import inspect
import json
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from admittance.errors import DataError
from admittance.ident.dataset import MIN_SAMPLES as DATASET_MIN_SAMPLES
from admittance.ident.dataset import TrialArrays, check_series


TICKS_PER_REV = 4096
MIN_SAMPLES = 3  # a converted recording may be short; identify asks for more (dataset.MIN_SAMPLES)
MOTIVE_AXES = {"x": 0, "y": 1, "z": 2}


def load_trial(
    path: str | Path,
    format: str,
    t_start: float | None = None,
    t_stop: float | None = None,
    every: int = 1,
    **options: Any,
) -> TrialArrays:
    """Parse one recording; ``options`` are the format's keyword options (see each loader).

    Every format also takes a window on the file's own time axis (``t_start <= t <= t_stop``)
    and ``every`` (keep every k-th sample), to cut a long log down to the part worth fitting.
    """
    loader = LOADERS.get(format)
    if loader is None:
        raise DataError(f"{path}: unknown trial format {format!r} (known: {', '.join(sorted(LOADERS))})")
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: trial file not found")
    try:
        inspect.signature(loader).bind(path, **options)
    except TypeError as exc:  # an unknown or misspelt option
        raise DataError(f"{path}: bad option for format {format!r}: {exc}") from None
    t, theta, tau = loader(path, **options)
    return check_series(path, *_window(path, t, theta, tau, t_start, t_stop, every), min_samples=MIN_SAMPLES)


def _window(path: Path, t, theta, tau, t_start, t_stop, every) -> TrialArrays:
    if not isinstance(every, int) or every < 1:
        raise DataError(f"{path}: every must be a positive integer, got {every!r}")
    t = np.asarray(t, dtype=float)
    keep = np.ones(t.size, dtype=bool)
    if t_start is not None:
        keep &= t >= t_start
    if t_stop is not None:
        keep &= t <= t_stop
    index = np.flatnonzero(keep)[::every]
    pick = lambda a: None if a is None else np.asarray(a, dtype=float)[index]  # noqa: E731
    return t[index], pick(theta), pick(tau)


# --------------------------------------------------------------------------- OptiTrack Motive


@dataclass
class MotiveTake:
    """The position triples of a Motive CSV export: one (n, 3) array per labelled point."""

    labels: list[str]
    types: list[str]
    frame: np.ndarray
    time: np.ndarray
    points: list[np.ndarray] = field(default_factory=list)


def parse_motive(path: Path) -> MotiveTake:
    """Parse the Motive 1.2x CSV layout.

    Line 1 is ``Format Version,...`` metadata; then (after an optional blank line) the rows
    ``,Type,...``, ``,Name,...``, ``,ID,...`` (and ``,Parent,...`` in newer versions), a row
    naming the component of each column (``Position``, ``Rotation``, ``Mean Marker Error``),
    and the axis row ``Frame,Time (Seconds),X,Y,Z,...``. Columns line up across these rows,
    so each position triple is found by index, whatever objects precede it.
    """
    rows = _read_rows(path)
    meta = _motive_metadata(rows[0]) if rows else {}
    axis_at = next((i for i, r in enumerate(rows) if r and r[0].strip().lower() == "frame"), None)
    if axis_at is None:
        raise DataError(f"{path}: not a Motive CSV export (no 'Frame,Time (Seconds),X,Y,Z' header row)")
    header = {_row_label(r): r for r in rows[1:axis_at] if _row_label(r)}
    component = rows[axis_at - 1] if axis_at > 1 else []
    axis_row = [c.strip().upper() for c in rows[axis_at]]
    starts = _position_triples(axis_row, component)
    if len(starts) < 2:
        raise DataError(f"{path}: the export holds {len(starts)} marker position(s); two are needed")
    wanted = [0, 1] + [j + k for j in starts for k in range(3)]
    data = _numeric_block(path, rows[axis_at + 1 :], len(axis_row), wanted)
    time = _motive_time(path, data, axis_row, meta)
    names, types = header.get("name", []), header.get("type", [])
    return MotiveTake(
        labels=[_cell(names, j) or f"point {k}" for k, j in enumerate(starts)],
        types=[_cell(types, j) for j in starts],
        frame=data[:, 0],
        time=time,
        points=[data[:, j : j + 3] for j in starts],
    )


def load_motive(
    path: Path,
    markers: Sequence[str | int] | None = None,
    axes: Sequence[str] = ("x", "z"),
    sign: float = 1.0,
    offset: float = 0.0,
) -> TrialArrays:
    """Angle of the line from marker A (the axis) to marker B (the bob), as appendix C does.

    ``theta = sign·atan2(d[axes[1]], d[axes[0]]) − offset`` with ``d = B − A``; the thesis's
    script uses the x and z columns (its Motive calibration put x along the hanging rod).
    ``markers`` names or indexes the two points (default: the first two of type ``Marker``,
    else the first two position triples). Frames where either marker is blank are dropped.
    """
    take = parse_motive(path)
    a, b = _pick_markers(path, take, markers)
    ia, ib = _motive_axes(path, axes)
    d = take.points[b] - take.points[a]
    ok = np.isfinite(d[:, ia]) & np.isfinite(d[:, ib]) & np.isfinite(take.time)
    if ok.sum() < 3:
        raise DataError(f"{path}: fewer than 3 frames where both markers are visible")
    theta = sign * np.unwrap(np.arctan2(d[ok, ib], d[ok, ia])) - offset
    return take.time[ok], theta, None


def _read_rows(path: Path) -> list[list[str]]:
    try:
        with path.open(newline="", encoding="utf-8-sig") as fh:
            return [row for row in csv.reader(fh)]
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise DataError(f"{path}: cannot read ({exc})") from None


def _motive_metadata(first: list[str]) -> dict[str, str]:
    return {first[i].strip().lower(): first[i + 1].strip() for i in range(0, len(first) - 1, 2)}


def _row_label(row: list[str]) -> str:
    """'type', 'name', 'id' or 'parent' for the header rows Motive labels in cell 0 or 1."""
    for cell in row[:2]:
        label = cell.strip().lower()
        if label in ("type", "name", "id", "parent"):
            return label
    return ""


def _cell(row: list[str], j: int) -> str:
    return row[j].strip() if j < len(row) else ""


def _position_triples(axis_row: list[str], component: list[str]) -> list[int]:
    """Column indices where an X,Y,Z position triple starts (rotations and errors skipped)."""
    starts = []
    j = 2
    while j + 2 < len(axis_row):
        is_xyz = axis_row[j : j + 3] == ["X", "Y", "Z"]
        comp = _cell(component, j).lower()
        if is_xyz and comp in ("position", "") and not _is_rotation(axis_row, j):
            starts.append(j)
            j += 3
        else:
            j += 1
    return starts


def _is_rotation(axis_row: list[str], j: int) -> bool:
    """A quaternion X,Y,Z,W block without a component row must not pass for a position."""
    return j + 3 < len(axis_row) and axis_row[j + 3] == "W"


def _numeric_block(path: Path, rows: list[list[str]], width: int, columns: list[int]) -> np.ndarray:
    """The frame rows as floats; only ``columns`` are parsed (TimeCode and the like are not)."""
    rows = [r for r in rows if any(c.strip() for c in r)]
    if not rows:
        raise DataError(f"{path}: the export has a header but no frames")
    out = np.full((len(rows), width), np.nan)
    for i, row in enumerate(rows):
        for j in columns:
            cell = _cell(row, j)
            if not cell:
                continue  # an occluded marker: Motive leaves the cell blank
            try:
                out[i, j] = float(cell)
            except ValueError:
                raise DataError(f"{path}: frame row {i + 1}, column {j + 1}: not a number: {cell!r}") from None
    return out


def _motive_time(path: Path, data: np.ndarray, axis_row: list[str], meta: dict[str, str]) -> np.ndarray:
    if len(axis_row) > 1 and axis_row[1].startswith("TIME") and np.all(np.isfinite(data[:, 1])):
        return data[:, 1]
    rate = meta.get("export frame rate") or meta.get("capture frame rate")
    try:
        fps = float(rate)
    except (TypeError, ValueError):
        raise DataError(f"{path}: no time column and no frame rate in the metadata row") from None
    return data[:, 0] / fps


def _pick_markers(path: Path, take: MotiveTake, markers) -> tuple[int, int]:
    if markers is None:
        plain = [k for k, kind in enumerate(take.types) if kind.lower() == "marker"]
        chosen = plain[:2] if len(plain) >= 2 else [0, 1]
        return chosen[0], chosen[1]
    if len(markers) != 2:
        raise DataError(f"{path}: markers must name two points (axis, bob), got {markers!r}")
    return tuple(_marker_index(path, take, m) for m in markers)  # type: ignore[return-value]


def _marker_index(path: Path, take: MotiveTake, marker: str | int) -> int:
    if isinstance(marker, int) and not isinstance(marker, bool):
        if 0 <= marker < len(take.points):
            return marker
    elif marker in take.labels:
        return take.labels.index(marker)
    raise DataError(f"{path}: no marker {marker!r} (points: {', '.join(take.labels)})")


def _motive_axes(path: Path, axes: Sequence[str]) -> tuple[int, int]:
    if len(axes) != 2 or any(str(a).lower() not in MOTIVE_AXES for a in axes) or axes[0] == axes[1]:
        raise DataError(f"{path}: axes must be two distinct names of x, y, z, got {axes!r}")
    return MOTIVE_AXES[str(axes[0]).lower()], MOTIVE_AXES[str(axes[1]).lower()]


# --------------------------------------------------------------------------- Dynamixel logs


def load_dynamixel(
    path: Path,
    segment: str = "torque_off",
    zero_tick: float = 2048.0,
    sign: float = 1.0,
) -> TrialArrays:
    """An encoder log: BAM's JSON (``.json``) or a CSV of time and present-position ticks.

    BAM JSON: ``segment="torque_off"`` keeps the free swing after the torque is disabled
    (time restarts at 0 at the release); ``"all"`` keeps everything (no torque is returned:
    while the torque is on the servo drives itself, which this log does not measure).
    CSV: columns ``t``/``time`` (s) and ``present_position``/``position``/``ticks``
    (4096 per revolution); ``theta = sign·(ticks − zero_tick)·2π/4096``. An optional
    ``tau`` column (N·m) is passed through.
    """
    if path.suffix.lower() == ".json":
        return _load_bam_json(path, segment)
    return _load_tick_csv(path, zero_tick, sign)


def _load_bam_json(path: Path, segment: str) -> TrialArrays:
    if segment not in ("torque_off", "all"):
        raise DataError(f"{path}: segment must be 'torque_off' or 'all', got {segment!r}")
    try:
        entries = json.loads(path.read_text())["entries"]
        t = np.array([float(e["timestamp"]) for e in entries])
        theta = np.array([float(e["position"]) for e in entries])
        enabled = np.array([bool(e.get("torque_enable", True)) for e in entries])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise DataError(f"{path}: not a BAM log (entries with timestamp, position): {exc}") from None
    if segment == "all":
        return t, theta, None
    off = np.flatnonzero(~enabled)
    if off.size == 0:
        raise DataError(f"{path}: the torque is never disabled: there is no free swing")
    start = int(off[0])
    if np.any(enabled[start:]):
        raise DataError(f"{path}: the torque is re-enabled after the release; the swing is not free")
    return t[start:] - t[start], theta[start:], None


def _load_tick_csv(path: Path, zero_tick: float, sign: float) -> TrialArrays:
    cols = _csv_columns(path)
    t = _column(path, cols, ("t", "time", "timestamp"))
    ticks = _column(path, cols, ("present_position", "position", "ticks"))
    tau = _column(path, cols, ("tau",), required=False)
    return t, sign * (ticks - zero_tick) * (2.0 * math.pi / TICKS_PER_REV), tau


# --------------------------------------------------------------------------- DFKI pendulum


def load_dfki(path: Path, torque: bool = True) -> TrialArrays:
    """The DFKI driver log ``time,position,velocity,torque`` (rad, 0 = hanging down, N·m).

    The torque is the driver's current-based estimate at the shaft; ``torque=False`` drops it.
    """
    cols = _csv_columns(path)
    t = _column(path, cols, ("time",))
    theta = _column(path, cols, ("position",))
    tau = _column(path, cols, ("torque",)) if torque else None
    return t, theta, tau


def _csv_columns(path: Path) -> dict[str, np.ndarray]:
    rows = _read_rows(path)
    if len(rows) < 2:
        raise DataError(f"{path}: a header row and data rows are needed")
    names = [c.strip().lower() for c in rows[0]]
    body = [r for r in rows[1:] if any(c.strip() for c in r)]
    short = next((i for i, r in enumerate(body) if len(r) != len(names)), None)
    if short is not None:
        raise DataError(f"{path}: data row {short + 1} has {len(body[short])} cells, the header {len(names)}")
    try:
        table = np.array([[float(c) if c.strip() else np.nan for c in r] for r in body], dtype=float)
    except ValueError as exc:
        raise DataError(f"{path}: non-numeric cell ({exc})") from None
    if table.ndim != 2:
        raise DataError(f"{path}: no data rows")
    return {name: table[:, j] for j, name in enumerate(names)}


def _column(path: Path, cols: dict[str, np.ndarray], names: Iterable[str], required: bool = True):
    for name in names:
        if name in cols:
            return cols[name]
    if required:
        raise DataError(f"{path}: missing column (one of {', '.join(names)}); found {', '.join(cols)}")
    return None


LOADERS = {"motive": load_motive, "dynamixel": load_dynamixel, "dfki": load_dfki}


# --------------------------------------------------------------------------- converters


@dataclass
class ConvertedTrial:
    """One trial to write into a contract dataset; ``extra`` goes into its [[trials]] entry."""

    name: str
    t: np.ndarray
    theta: np.ndarray
    tau: np.ndarray | None = None
    extra: dict[str, Any] = field(default_factory=dict)


def write_dataset(out_dir: str | Path, trials: Sequence[ConvertedTrial], header: dict[str, Any] | None = None) -> Path:
    """Write ``manifest.toml`` and one ``t,theta[,tau]`` CSV per trial into ``out_dir``.

    ``header`` holds the manifest's top-level keys and tables (``motor``, ``rod``, ``bob``).
    """
    import tomli_w

    if not trials:
        raise DataError("no trials to write")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    entries = []
    for trial in trials:
        t, theta, tau = check_series(Path(trial.name), trial.t, trial.theta, trial.tau, min_samples=MIN_SAMPLES)
        file = f"{trial.name}.csv"
        _write_csv(out / file, t, theta, tau)
        entries.append({"file": file, **trial.extra})
    manifest = dict(header or {})
    manifest["trials"] = entries
    (out / "manifest.toml").write_text(tomli_w.dumps(manifest))
    return out


def _write_csv(path: Path, t: np.ndarray, theta: np.ndarray, tau: np.ndarray | None) -> None:
    cols = [t, theta] if tau is None else [t, theta, tau]
    head = "t,theta" if tau is None else "t,theta,tau"
    np.savetxt(path, np.column_stack(cols), delimiter=",", header=head, comments="", fmt="%.9g")


def convert_files(
    files: Sequence[str | Path],
    format: str,
    out_dir: str | Path,
    header: dict[str, Any] | None = None,
    extra: dict[str, Any] | None = None,
    **options: Any,
) -> Path:
    """Parse each file with :func:`load_trial` and write them as one contract dataset."""
    trials = []
    for f, name in zip(files, trial_names(files)):
        t, theta, tau = load_trial(f, format, **options)
        trials.append(ConvertedTrial(name, t, theta, tau, dict(extra or {})))
    return write_dataset(out_dir, trials, header)


def trial_names(files: Sequence[str | Path]) -> list[str]:
    """File stems, prefixed by their folder names where stems repeat (``data_measured``)."""
    paths = [Path(f) for f in files]
    stems = [p.stem for p in paths]
    names = [s if stems.count(s) == 1 else f"{p.parent.name}_{s}" for p, s in zip(paths, stems)]
    if len(set(names)) != len(names):
        raise DataError(f"two input files would get the same trial name: {', '.join(names)}")
    return names


# --------------------------------------------------------------------------- MCAP recordings
#
# ``admittance run --record DIR`` writes DIR/session.mcap (admittance.daemon.mcap_recording):
# every cycle of every joint on ``/joint<ID>/cycle``. Two entry points:
#
# - :func:`read_recording` gives every column of every cycle (for `fidelity` and plots);
# - :func:`load_recording` gives the same Dataset object the CSV folder of the same session gives
#   (load_dataset): per joint, trials of ``segment_s`` seconds, theta = the measured angle on the
#   cycles that read it (the model angle when the session read none), tau = the hand torque.
#
# Files are read with the streaming reader, message by message, so a file cut short (SIGKILL,
# power loss: no summary at its end) reads back up to its last complete chunk.

MCAP_CYCLE_COLUMNS = ("t", "t_wake", "wall", "cycle", "force", "tau", "theta_model", "omega_model", "theta_goal",
                      "theta_present", "rendering_error", "fault", "mode")


@dataclass
class Recording:
    """A session.mcap read back: per joint ID, every cycle's columns as float arrays (NaN = not read,
    or absent from an older file). Each ``params`` entry carries ``t``: its monotonic time (s)."""

    path: Path
    session: dict[str, Any]
    joints: dict[int, dict[str, np.ndarray]]
    params: list[dict[str, Any]]
    stats: list[dict[str, Any]]
    events: list[str]
    truncated: bool  # True when the file ends without its summary (the session was cut short)


def _mcap_path(path: str | Path) -> Path:
    path = Path(path)
    if path.is_dir():
        path = path / "session.mcap"
    if not path.is_file():
        raise DataError(f"{path}: MCAP recording not found")
    return path


def read_recording(path: str | Path) -> Recording:
    """Every message of a session.mcap (a file, or a --record folder holding one)."""
    import msgspec
    from mcap.reader import NonSeekingReader

    path = _mcap_path(path)
    rows: dict[int, list[dict]] = {}
    session: dict[str, Any] | None = None
    params, stats, events, truncated = [], [], [], False
    decode = msgspec.json.Decoder().decode
    with path.open("rb") as fh:
        try:
            for _schema, channel, message in NonSeekingReader(fh).iter_messages(log_time_order=False):
                topic, body = channel.topic, decode(message.data)
                if topic.endswith("/cycle") and topic.startswith("/joint"):
                    rows.setdefault(int(topic[len("/joint"):-len("/cycle")]), []).append(body)
                elif topic == "/session":
                    session = body
                elif topic == "/params":
                    params.append({**body, "t": message.publish_time * 1e-9})
                elif topic == "/stats":
                    stats.append(body)
                elif topic == "/events":
                    events.append(body.get("text", ""))
        except Exception as exc:  # noqa: BLE001 - a cut file fails anywhere (McapError, zstd, struct, msgspec)
            truncated = True
            if session is None:
                raise DataError(f"{path}: not a readable admittance MCAP recording ({type(exc).__name__})") from None
    if session is None:
        raise DataError(f"{path}: no /session message (not written by admittance run --record)")
    joints = {jid: {c: np.array([np.nan if r.get(c) is None else r[c] for r in body], dtype=float)
                    for c in MCAP_CYCLE_COLUMNS} for jid, body in rows.items()}
    return Recording(path, session, joints, params, stats, events, truncated)


def _segments(t: np.ndarray, starts: np.ndarray, segment_s: float) -> list[np.ndarray]:
    """Row indices per segment: a new one at each of ``starts`` (a gap, or where the model did not
    follow the torque: recording.trial_starts) and every ``segment_s`` seconds after; a piece
    too short to fit is dropped (the CSV recorder drops it too), the last only if not alone."""
    out = []
    for piece in np.split(np.arange(len(t)), starts):
        if len(piece):
            index = np.floor((t[piece] - t[piece[0]]) / segment_s).astype(int)
            out += [piece[index == k] for k in np.unique(index)]
    if len(out) > 1:
        out = [seg for seg in out[:-1] if len(seg) >= DATASET_MIN_SAMPLES] + \
              ([out[-1]] if len(out[-1]) >= DATASET_MIN_SAMPLES else [])
    return out


def recording_segments(rec: Recording) -> dict[int, list[dict[str, np.ndarray]]]:
    """Per joint, the rows the session's CSV dataset has (recording.recorded_rows: one per cycle
    that read the servo, the next cycle's torque, held and fault since the previous row, times
    from t0), cut as the recorder cuts them: at gaps, where the model did not follow the torque,
    and into segments of ``segment_s`` seconds."""
    from admittance.daemon.recording import gap_seconds, recorded_rows, trial_starts, with_next_cycle

    measured = bool(rec.session.get("measured_theta", True))
    t0, segment_s = float(rec.session["t0"]), float(rec.session.get("segment_s", 10.0))
    rate_hz = rec.session.get("rate_hz")
    divisors = {int(j["id"]): int(j.get("sync_read_divisor", 1)) for j in rec.session.get("joints", []) if "id" in j}
    out = {}
    for jid in sorted(rec.joints):
        cols = with_next_cycle(dict(rec.joints[jid]))
        if not np.isfinite(cols["t_wake"]).all():
            cols["t_wake"] = cols["t"]  # an older file
        rows, _ = recorded_rows(cols, measured_theta=measured, t0=t0, period_s=1.0 / rate_hz if rate_hz else None)
        if not rows["t"].size:
            out[jid] = []
            continue
        gap_s = gap_seconds(rate_hz, divisors.get(jid, 1)) if rate_hz else float("inf")
        starts = np.union1d(*trial_starts(rows["t"], rows["held"], rows["lapse"], gap_s))
        out[jid] = [{k: v[index] for k, v in rows.items()} for index in _segments(rows["t"], starts, segment_s)]
    return out


def load_recording(path: str | Path):
    """A session.mcap as the Dataset that ``load_dataset`` gives for the session's CSV folder.

    ``path`` is the .mcap file or the --record folder. This is the entry point `identify`
    (through load_dataset) and `fidelity` use; see docs/identification.md.
    """
    return recording_dataset(read_recording(path))


def recording_dataset(rec: Recording):
    """The Dataset of a read recording: one trial per segment of :func:`recording_segments`, in
    its order (joints by id)."""
    from admittance.daemon.recording import NEGLIGIBLE_BOB, NEGLIGIBLE_BOB_DISTANCE
    from admittance.ident.dataset import Dataset, TrialData, load_geometry

    measured = bool(rec.session.get("measured_theta", True))
    models = {int(j["id"]): j.get("model", "") for j in rec.session.get("joints", [])}
    inertia, gravity = load_geometry(None, NEGLIGIBLE_BOB, NEGLIGIBLE_BOB_DISTANCE)
    trials = []
    for jid, segments in recording_segments(rec).items():
        for k, rows in enumerate(segments):
            name = f"joint{jid}_{k:03d}"
            ts, th, ta = check_series(Path(f"{rec.path}:{name}"), rows["t"], rows["theta"], rows["tau"])
            trials.append(TrialData(name=name, t=ts, theta=th, tau=ta, load_inertia=inertia, gravity_torque=gravity,
                                    meta={"format": "mcap", "joint_id": jid, "motor": models.get(jid, ""),
                                          "source": str(rec.path)}))
    if not trials:
        raise DataError(f"{rec.path}: no cycle with a {'measured' if measured else 'model'} angle recorded")
    motors = ", ".join(sorted({m for m in models.values() if m}))
    return Dataset(mode="geometry", trials=tuple(trials), motor=motors, folder=rec.path.parent,
                   geometry={"rod": None, "bob": dict(NEGLIGIBLE_BOB)})


def convert_recording(files: Sequence[str | Path], out_dir: str | Path) -> Path:
    """``admittance convert mcap session.mcap --out DIR``: the contract's CSV dataset of a recording."""
    from admittance.daemon.recording import NEGLIGIBLE_BOB, NEGLIGIBLE_BOB_DISTANCE

    trials = []
    for f in files:
        dataset = load_recording(f)
        prefix = "" if len(files) == 1 else f"{Path(f).parent.name}_"
        trials += [ConvertedTrial(prefix + tr.name, tr.t, tr.theta, tr.tau,
                                  {"bob_distance": NEGLIGIBLE_BOB_DISTANCE, "joint_id": tr.meta["joint_id"],
                                   "motor": tr.meta["motor"]}) for tr in dataset.trials]
    header = {"motor": dataset.motor, "source": "admittance convert mcap", "bob": dict(NEGLIGIBLE_BOB)}
    return write_dataset(out_dir, trials, header)
