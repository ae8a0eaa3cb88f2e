"""The fidelity analysis of one joint of a recording: the JSON of ../shared/contracts/fidelity.md
and the parameter file with the servo model.

- ``rendering_rmse``: RMS of present − model angle where the hand acts (``tau ≠ 0``).
- ``target``: what the loop ran (the manifest's per-segment ``virtual_*``). When segments ran
  different values (a live change), the largest group of equal segments is analysed and the
  others are listed as excluded; a recording without them (an older version) falls back to
  `identify` on the model angle, and says so.
- ``rendered``: `identify` (base model, no effect search) on the *measured* angle: the
  admittance the horn really rendered.
- ``target_check``: `identify` on the *model* angle: it must give the target back (3/3/5 %), or
  the recording's timing is wrong (docs/fidelity.md, "record → identify").
- ``servo``: the servo model fitted on the segments (``servo.fit_servo``), with its error on
  held-out segments and the residual verdict.
- ``servo_verdict``: whether that model is good enough to compensate with (``judge``): the
  parameter file's ``[fit] servo_compensation`` is 1 only when it passes.
- ``target_check_verdict``: whether `identify` on the model's angle gives the target back.
"""

from __future__ import annotations

import dataclasses
from collections import Counter
from pathlib import Path

import numpy as np

from admittance.errors import DataError
from admittance.fidelity.recording import MIN_MOTION_RAD, TARGET_KEYS, Recording, Segment, moved
from admittance.fidelity.judge import judge, misfit_note, verdict_line
from admittance.fidelity.servo import fit_servo
from admittance.formats import paramfile

PLANT_NAMES = {"virtual_inertia": "motor_inertia", "virtual_damping": "damping", "virtual_coulomb": "coulomb"}


def analyse(recording: Recording, joint_id: int | None = None) -> dict:
    """The fidelity JSON of one joint (the only one, or ``joint_id``)."""
    joint_id = _pick_joint(recording, joint_id)
    moving, still = _moving(recording, joint_id)
    segments, excluded = _same_target(moving)
    excluded = still + excluded
    rows = [s["tau"] != 0.0 for s in segments]
    rendering = _rms([s["theta"][m] - s["theta_model"][m] for s, m in zip(segments, rows)])
    target, target_source = _target(segments)
    model_fit = _identify(segments, "theta_model")
    if target is None:
        target = model_fit
    rendered = _identify(segments, "theta")
    servo = fit_servo(segments)
    note = misfit_note(servo.residual)
    if note:
        servo.notes.append(note)
    fit = servo.to_json()
    servo_verdict = judge(servo.rmse_heldout, servo.baseline_heldout, servo.residual, servo.model(), fit["sigma"])
    check = {k: _relative(model_fit[k], target[k]) for k in TARGET_KEYS}
    compensation = {s.compensation for s in segments}
    return {
        "joint_id": joint_id,
        "rendering_rmse": rendering,
        "target": target,
        "target_source": target_source,
        "rendered": rendered,
        "rendered_error": {k: _relative(rendered[k], target[k]) for k in TARGET_KEYS},
        "target_check": {**model_fit, "error": check, "verdict": target_check_verdict(check, target_source)},
        "servo": fit,
        "servo_verdict": servo_verdict.to_json(),
        "servo_compensation": compensation.pop() if len(compensation) == 1 else None,
        "segments": [s.name for s in segments],
        "excluded_segments": excluded,
        "held_rows": recording.held_rows,
        "gaps": recording.gaps,
        "rows": int(sum(s.n for s in segments)),
        "motion_rad": float(np.ptp(np.concatenate([s["theta_model"] for s in segments]))),
        "_servo_fit": servo,
    }


# `identify` on the model's own angle must give the target back within these (relative): the
# record → identify round trip (docs/fidelity.md). Coulomb's is wider: it is pinned only by the
# reversals.
TARGET_CHECK_TOLERANCE = {"virtual_inertia": 0.03, "virtual_damping": 0.03, "virtual_coulomb": 0.05}


def target_check_verdict(error: dict[str, float | None], source: str) -> dict:
    """Pass when every relative error is within its tolerance (a zero target is not checked);
    meaningless when the target itself came from that fit (no manifest values)."""
    if source.startswith("identify"):
        return {"passed": None, "reasons": ["the recording does not say what the loop ran: nothing to check against"]}
    reasons = [f"{k} off by {100 * v:+.1f} % (at most ±{100 * TARGET_CHECK_TOLERANCE[k]:g} %)"
               for k, v in error.items() if v is not None and not abs(v) <= TARGET_CHECK_TOLERANCE[k]]
    return {"passed": not reasons, "reasons": reasons, "tolerance": TARGET_CHECK_TOLERANCE}


def _pick_joint(recording: Recording, joint_id: int | None) -> int:
    ids = recording.joint_ids()
    if joint_id is None:
        return ids[0]
    if joint_id not in ids:
        raise DataError(f"{recording.folder}: no joint {joint_id} in the recording (joints: {ids})")
    return joint_id


def _moving(recording: Recording, joint_id: int) -> tuple[list[Segment], list[str]]:
    """The joint's segments in which the model moved, and the names of those in which it did not.

    A stretch before the hand started (or while it kept off) has a constant goal and a still
    model: nothing for the servo fit, and not one row for `identify`'s equation error, which
    refuses "too little motion" when such a stretch is all its training set got (a recording
    cut in two by a hold or a read gap before a late hand: the wheel smoke's 1-in-3 failure)."""
    moving, still = [], []
    for s in recording.of_joint(joint_id):
        (moving if moved(s["theta_model"]) else still).append(s)
    if not moving:
        raise DataError(f"{recording.folder}: joint {joint_id}: the model moved less than "
                        f"{1e3 * MIN_MOTION_RAD:.0f} mrad in every stretch between holds and read gaps "
                        f"({len(still)} stretches; {recording.held_rows} held rows, {recording.gaps} gaps); "
                        "record again, pushing the joint (on a loaded machine, raise [loop].stale_timeout_ms)")
    return moving, [s.name for s in still]


def _same_target(segments: list[Segment]) -> tuple[list[Segment], list[str]]:
    """The segments that ran the most common (target, compensation), without a change inside them."""
    def key(s: Segment):
        return tuple(sorted(s.target.items())), s.compensation

    steady = [s for s in segments if not s.params_changed] or segments
    counts = Counter(key(s) for s in steady)
    best = max(counts, key=lambda k: sum(s.n for s in steady if key(s) == k))
    chosen = [s for s in steady if key(s) == best]
    return chosen, [s.name for s in segments if s not in chosen]


def _target(segments: list[Segment]) -> tuple[dict | None, str]:
    target = segments[0].target
    if all(k in target for k in TARGET_KEYS):
        return {k: target[k] for k in TARGET_KEYS}, "recording manifest (what the loop ran)"
    return None, "identify on theta_model (the recording does not say what the loop ran)"


def _identify(segments: list[Segment], column: str) -> dict:
    """`identify`'s base model (no effect search) on the segments with ``theta := column``."""
    from admittance.formats.dataset import Dataset
    from admittance.ident.identify import IdentifySettings, identify_dataset

    dataset = Dataset(mode="geometry", trials=tuple(s.as_trial(column) for s in segments))
    result = identify_dataset(dataset, IdentifySettings(max_effects=0))
    p, sigma = result.params, result.sigma(result.final)
    return {**{key: p[name] for key, name in PLANT_NAMES.items()},
            "sigma": {key: sigma.get(name) for key, name in PLANT_NAMES.items()},
            "rmse": result.final.rmse, "residual": result.residual["summary"]}


def _relative(value: float, target: float) -> float | None:
    return (value - target) / target if target != 0 else None


def _rms(parts: list[np.ndarray]) -> float:
    joined = np.concatenate(parts)
    if joined.size == 0:
        raise DataError("the hand never acted (tau is 0 on every row)")
    return float(np.sqrt(np.mean(joined**2)))


def write_params(path: str | Path, recording: Recording, result: dict, source: str) -> None:
    """The joint's plant (from the recording's manifest) with the identified servo model added:
    a parameter file whose ``[fit] servo_compensation`` (1 when the fit passed its verdict, else
    0) is the default of a joint whose ``params`` names it."""
    joint = recording.joints.get(result["joint_id"])
    if not joint or not isinstance(joint.get("plant"), dict) or "motor_inertia" not in joint["plant"]:
        raise DataError(f"{recording.folder}: the recording does not say which plant joint {result['joint_id']} "
                        "had (its manifest has no [[joints]] plant); record it again with this version")
    servo = result["_servo_fit"]
    model = {"motor": str(joint.get("model", "")), "friction": str(joint.get("friction", "stick")),
             "mode": "geometry", "source": source}
    verdict = result["servo_verdict"]
    fit = {"servo_source": source, "servo_compensation": 1.0 if verdict["passed"] else 0.0,
           "servo_verdict": verdict_line(verdict), "servo_rmse_heldout": servo.rmse_heldout,
           "servo_rmse_training": servo.rmse_training, "servo_heldout": servo.heldout,
           "plant_file": str(joint.get("params_file", ""))}
    paramfile.dump(path, joint["plant"], model=model, fit=fit, servo=servo.model())

