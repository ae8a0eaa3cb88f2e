"""What ``admittance run --record`` writes, and its reading back: the rows, the cuts into trials,
the reader of ``session.mcap``.

A recording's CSV rows (:data:`COLUMNS`) and the ``session.mcap`` of the same session
(``mcap_layout``) give the same dataset: both go through :func:`recorded_rows` (one row per cycle
that read the servo, the next cycle's torque, ``held`` and ``fault`` gathered since the previous
row) and are cut where :func:`trial_starts` says (after a gap, time the model lost, a hold).
The writers are the daemon's (``admittance.daemon.recording`` and ``mcap_recording``, whose module
docs say why each choice); the readers are here, for ``identify``, ``fidelity`` and ``convert``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from admittance._rtcore import CATCH_UP_STEPS_PER_CYCLE, LOOP_MODES, MAX_CATCH_UP_STEPS
from admittance.errors import DataError
from admittance.formats.converters import ConvertedTrial, write_dataset
from admittance.formats.mcap_layout import MCAP_CYCLE_COLUMNS, MCAP_NAME
from admittance.formats.trial import MIN_SAMPLES, Dataset, TrialData, check_series, load_geometry

COLUMNS = ("t", "theta", "tau", "force", "theta_model", "omega_model", "theta_goal", "t_wake", "cycle", "held",
           "fault", "passivity_energy", "passivity_damping", "tau_mean")
MIN_ROWS = 10  # the dataset loader's minimum per trial
NEGLIGIBLE_BOB = {"mass": 1e-6}  # kg
NEGLIGIBLE_BOB_DISTANCE = 1e-3  # m
DEFAULT_GAP_S = 0.25  # s: rows further apart than this are a gap (see the module doc)

MODE_RUNNING = LOOP_MODES.index("running")  # a cycle where every joint followed its model


def with_defaults(columns: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """A batch's columns with the optional ones filled: ``t_wake`` = ``t``, ``mode`` and ``fault``
    0, none ``superseded``."""
    zeros = np.zeros(len(columns["t"]))
    return {"t_wake": columns["t"], "mode": zeros, "fault": zeros, "superseded": zeros, "passivity_energy": zeros,
            "passivity_damping": zeros, **columns}


def with_next_cycle(columns: dict[str, np.ndarray], period_s: float | None = None) -> dict[str, np.ndarray]:
    """Consecutive cycles with what the cycle after each says about it (module doc): ``tau`` the
    following cycle's torque, ``superseded`` where the following cycle took no step, and
    ``steps``, the model steps it took with that torque (with the loop's ``period_s``: ``t`` is
    the model's own time, which a catch-up after a stall advances by up to
    ``CATCH_UP_STEPS_PER_CYCLE`` periods a cycle; 1 where that is unknown)."""
    follows = np.diff(columns["cycle"]) == 1
    dt = np.diff(columns["t"])
    superseded = np.zeros(len(columns["cycle"]))
    superseded[:-1] = follows & (dt <= 0)
    steps = 1.0 - superseded
    if period_s:
        steps[:-1] = np.where(follows, np.clip(np.rint(dt / period_s), 0, CATCH_UP_STEPS_PER_CYCLE), steps[:-1])
    return {**columns, "tau": next_cycle_tau(columns["tau"], columns["cycle"]), "superseded": superseded,
            "steps": steps}


def next_cycle_tau(tau: np.ndarray, cycle: np.ndarray) -> np.ndarray:
    """Each cycle's row with the following cycle's torque (module doc); a cycle whose next record
    is missing (a dropped record, the last one) keeps its own."""
    out = np.array(tau, dtype=float)
    follows = np.diff(cycle) == 1
    out[:-1] = np.where(follows, tau[1:], tau[:-1])
    return out


def held_cycles(mode: np.ndarray) -> np.ndarray:
    """1 on a cycle where the model did not follow the torque: the loop was not running."""
    return (np.isfinite(mode) & (mode != MODE_RUNNING)).astype(np.int64)  # NaN: an older file, running


def since_previous_row(flags: np.ndarray, keep: np.ndarray, carry: int = 0) -> tuple[np.ndarray, int]:
    """Per cycle, the bitwise OR of ``flags`` over the cycles since the previous kept row up to
    its own kept row (``carry``: what the cycles after the last batch's last row had); and the
    carry for the next batch."""
    if not carry and not flags.any():  # the usual batch: nothing held, no fault
        return np.zeros(len(keep), np.int64), 0
    group = np.concatenate([[0], np.cumsum(keep)[:-1]]).astype(np.int64)  # kept rows before each cycle
    acc = np.zeros(int(group[-1]) + 1 if len(group) else 1, np.int64)
    np.bitwise_or.at(acc, group, flags.astype(np.int64))
    acc[0] |= carry
    return acc[group], int(acc[-1]) if len(keep) and not keep[-1] else 0


def gap_seconds(rate_hz: float, sync_read_divisor: int) -> float:
    """Rows further apart than this are a gap: the servo unread for ten read periods (a retried
    read is never that late), at least ``DEFAULT_GAP_S``."""
    return max(DEFAULT_GAP_S, 10.0 * sync_read_divisor / rate_hz)


def trial_starts(t: np.ndarray, held: np.ndarray, lapse: np.ndarray, gap_s: float, previous_t: float | None = None,
                 previous_held: tuple[float, float] = (0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the rows that must start a new trial: after a gap (``t`` more than ``gap_s``
    after the previous row; ``previous_t``: the row before ``t[0]``); after time the model lost
    (``lapse``); where a hold begins (the interval before a held row was not followed, the row's
    state is a good start); and after a hold of two rows or more, whose rows then form a trial of
    their own, so the recording still covers the run (``previous_held``: ``held`` of the row
    before ``t[0]`` and of the one before that). Returns (gaps, breaks), disjoint."""
    previous = t[0] if previous_t is None else previous_t
    after_gap = np.diff(np.concatenate([[previous], t])) > gap_s
    h = np.concatenate([previous_held[::-1], held]) > 0
    begins = h[2:] & ~h[1:-1]
    ends = ~h[2:] & h[1:-1] & h[:-2]
    return np.flatnonzero(after_gap), np.flatnonzero(((lapse > 0) | begins | ends) & ~after_gap)


def model_lapses(t: np.ndarray, period_s: float | None, previous_t: float | None = None) -> np.ndarray:
    """1 on a cycle whose deadline ``t`` (s) came after a stall longer than the loop catches up:
    the model lost that time (docs/realtime.md). ``previous_t``: the cycle before ``t[0]``."""
    if not period_s or len(t) == 0:
        return np.zeros(len(t), np.int64)
    before = np.concatenate([[t[0] if previous_t is None else previous_t], t[:-1]])
    return (t - before > (MAX_CATCH_UP_STEPS + 0.5) * period_s).astype(np.int64)


def mean_since_previous_row(values: np.ndarray, weight: np.ndarray, keep: np.ndarray,
                            carry: tuple[float, float] = (0.0, 0.0)) -> tuple[np.ndarray, tuple[float, float]]:
    """Per cycle, the weighted mean of ``values`` over the cycles from the previous kept row
    (inclusive) to its own kept row (exclusive): on a row, the mean over the interval that ends
    at it (``carry``: (sum, weight) of the cycles after the last batch's last row). NaN where no
    cycle counts (the recording's first row). And the carry for the next batch."""
    group = np.cumsum(keep).astype(np.int64)  # cycle j counts for the first kept row after it
    total = np.zeros(int(group[-1]) + 1 if len(group) else 1)
    count = np.zeros_like(total)
    np.add.at(total, group, values * weight)
    np.add.at(count, group, weight)
    total[0] += carry[0]
    count[0] += carry[1]
    ends = np.concatenate([[0], np.cumsum(keep)[:-1]]).astype(np.int64)  # kept rows before each cycle
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count[ends] > 0, total[ends] / np.where(count[ends] > 0, count[ends], 1.0), np.nan)
    return mean, (float(total[-1]), float(count[-1]))


def recorded_rows(columns: dict[str, np.ndarray], *, measured_theta: bool, t0: float,
                  carry: tuple = (0, 0), period_s: float | None = None,
                  previous_t: float | None = None) -> tuple[dict[str, np.ndarray], tuple]:
    """The CSV rows (``COLUMNS``) of consecutive cycles whose ``tau`` is already the next
    cycle's (:func:`with_next_cycle`): one row per cycle that read the servo (every cycle without
    reads) and was not superseded, times from ``t0``, ``held`` and ``fault`` gathered since the
    previous row, ``tau_mean`` the mean torque since it (each cycle's weighed by its model
    ``steps``). Also the (held, fault, torque sum, cycles)
    carry. With the loop's ``period_s``, a cycle where the
    model lost time counts as held (``previous_t``: the absolute deadline before ``columns``')."""
    columns = with_defaults(columns)
    n = len(columns["t"])
    keep = np.isfinite(columns["theta_present"]) if measured_theta else np.ones(n, bool)
    keep &= columns["superseded"] == 0
    # Bit 0: held; bit 1: the model lost time. Both gathered since the previous row.
    flags = held_cycles(columns["mode"]) | (model_lapses(columns["t"], period_s, previous_t) << 1)
    flags, held_carry = since_previous_row(flags, keep, carry[0])
    held, lapse = flags & 1, flags >> 1
    faults = columns["fault"]
    faults = np.where(np.isfinite(faults), faults, 0).astype(np.int64)  # NaN: an older file, none
    fault, fault_carry = since_previous_row(faults, keep, carry[1])
    steps = columns["steps"] if "steps" in columns else (columns["superseded"] == 0).astype(float)
    tau_mean, tau_carry = mean_since_previous_row(columns["tau"], steps, keep, tuple(carry[2:4]) or (0.0, 0.0))
    tau_mean = np.where(np.isfinite(tau_mean), tau_mean, columns["tau"])
    theta = columns["theta_present"] if measured_theta else columns["theta_model"]
    rows = {"t": columns["t"] - t0, "theta": theta, "tau": columns["tau"], "force": columns["force"],
            "theta_model": columns["theta_model"], "omega_model": columns["omega_model"],
            "theta_goal": columns["theta_goal"], "t_wake": columns["t_wake"] - t0, "cycle": columns["cycle"],
            "held": held.astype(float), "fault": fault.astype(float), "lapse": lapse.astype(float),
            "passivity_energy": columns["passivity_energy"], "passivity_damping": columns["passivity_damping"],
            "tau_mean": tau_mean}
    return {k: np.asarray(v, dtype=float)[keep] for k, v in rows.items()}, (held_carry, fault_carry, *tau_carry)


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
        path = path / MCAP_NAME
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
        out = [seg for seg in out[:-1] if len(seg) >= MIN_SAMPLES] + \
              ([out[-1]] if len(out[-1]) >= MIN_SAMPLES else [])
    return out


def recording_segments(rec: Recording) -> dict[int, list[dict[str, np.ndarray]]]:
    """Per joint, the rows the session's CSV dataset has (recording.recorded_rows: one per cycle
    that read the servo, the next cycle's torque, held and fault since the previous row, times
    from t0), cut as the recorder cuts them: at gaps, where the model did not follow the torque,
    and into segments of ``segment_s`` seconds."""
    measured = bool(rec.session.get("measured_theta", True))
    t0, segment_s = float(rec.session["t0"]), float(rec.session.get("segment_s", 10.0))
    rate_hz = rec.session.get("rate_hz")
    period_s = 1.0 / rate_hz if rate_hz else None
    divisors = {int(j["id"]): int(j.get("sync_read_divisor", 1)) for j in rec.session.get("joints", []) if "id" in j}
    out = {}
    for jid in sorted(rec.joints):
        cols = with_next_cycle(dict(rec.joints[jid]), period_s)
        if not np.isfinite(cols["t_wake"]).all():
            cols["t_wake"] = cols["t"]  # an older file
        rows, _ = recorded_rows(cols, measured_theta=measured, t0=t0, period_s=period_s)
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
    trials = []
    for f in files:
        dataset = load_recording(f)
        prefix = "" if len(files) == 1 else f"{Path(f).parent.name}_"
        trials += [ConvertedTrial(prefix + tr.name, tr.t, tr.theta, tr.tau,
                                  {"bob_distance": NEGLIGIBLE_BOB_DISTANCE, "joint_id": tr.meta["joint_id"],
                                   "motor": tr.meta["motor"]}) for tr in dataset.trials]
    header = {"motor": dataset.motor, "source": "admittance convert mcap", "bob": dict(NEGLIGIBLE_BOB)}
    return write_dataset(out_dir, trials, header)
