"""Checks of the data before any fit: what would bend the parameters without a word.

The loader (dataset.py) already refuses what is malformed (NaN, time that does not strictly
increase, duplicated times, too few samples). These checks look for data that are well formed
but not one free swing of the model: each finding names the file and the sample, and says what
``identify`` does about it.

- **re-release** (undriven trials): a swing loses energy; a half-swing much larger than the one
  before it means the joint was lifted and let go again, two drops in one file. Five such files
  in 30 moved I, B and F by 29–51 %. The trial is dropped.
- **jump**: the angle steps by more than the motion around it can explain and stays there (a
  splice, a wrapped encoder, a lost count). A single-sample spike that comes back is an outlier
  the fit can live with and is not flagged. The trial is dropped.
- **stuck**: the reading repeats exactly for a stretch the joint enters and leaves at speed (a
  frozen sensor or a repeated buffer). A joint that sticks arrives at rest slowly. Dropped.
- **clipping**: the angle sits at the trial's extreme value after arriving there at speed (a
  swing past the encoder's range reads as a flat top). Dropped.
- **clock** (geometry mode, undriven trials): a pendulum cannot swing faster than its load alone
  lets it: the half-period is at least π·√(I_load/G) (motor inertia, damping and amplitude only
  lengthen it; Coulomb friction leaves it). Swings faster than that by more than
  :data:`CLOCK_TOLERANCE` mean the time stamps run slow (or the geometry is wrong): the dataset
  is refused. A clock running fast lengthens the period, which a larger motor inertia absorbs:
  that direction is not detectable from the swing alone, and is not claimed.

What is dropped is listed in the JSON (``data_checks``) and on stderr; when no trial is left, or
the clock check fails, ``identify`` stops with a :class:`DataError` naming the file and sample.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from admittance.errors import DataError

RISE_FACTOR = 1.5  # a half-swing this much larger than the one before it is a new release
JUMP_RAD = 0.05  # rad: a step in the angle beyond the motion's own, this large, is a jump
JUMP_SIGMAS = 20.0  # ... and this many robust σ of the step-to-step change
STUCK_SAMPLES = 5  # identical readings in a row, entered and left at speed
MOVING_SPEED = 0.5  # rad/s: "at speed" for the stuck and clipping checks
CLIP_SAMPLES = 3
CLOCK_TOLERANCE = 0.015  # the swing may be this much faster than the load alone allows (noise)
MIN_HALF_SWINGS = 4


@dataclass(frozen=True)
class Finding:
    trial: str
    sample: int
    kind: str  # re-release, jump, stuck, clipping, clock
    message: str
    action: str  # "drop" (the trial) or "refuse" (the dataset)

    def line(self) -> str:
        verb = "trial dropped" if self.action == "drop" else "dataset refused"
        return f"{self.trial}: sample {self.sample}: {self.kind}: {self.message} ({verb})"

    def as_dict(self) -> dict:
        return {"trial": self.trial, "sample": self.sample, "kind": self.kind, "message": self.message,
                "action": self.action}


def check_trial(trial, mode: str) -> list[Finding]:
    """Every finding on one trial (TrialData)."""
    t, theta = np.asarray(trial.t, float), np.asarray(trial.theta, float)
    driven = trial.tau is not None and np.any(np.abs(trial.tau) > 0)
    out = []
    for check in (_jump, _stuck, _clipping):
        found = check(t, theta)
        if found:
            out.append(Finding(trial.name, found[0], check.__name__.strip("_"), found[1], "drop"))
    if not driven:
        smooth = _median5(theta)  # a one-sample outlier is no turning point
        turns = turning_points(smooth, _hysteresis(smooth))
        rise = _re_release(smooth, turns)
        if rise:
            out.append(Finding(trial.name, rise[0], "re-release", rise[1], "drop"))
        elif mode == "geometry":
            fast = _clock(t, turns, trial)
            if fast:
                out.append(Finding(trial.name, fast[0], "clock", fast[1], "refuse"))
    return out


def screen(dataset, say=None):
    """The dataset without the trials the checks drop, and the findings. Raises DataError when
    a check refuses the dataset or no trial is left."""
    findings = [f for trial in dataset.trials for f in check_trial(trial, dataset.mode)]
    for f in findings:
        if say:
            say(f.line())
    refused = [f for f in findings if f.action == "refuse"]
    if refused:
        raise DataError(f"{_where(dataset, refused[0])}: {refused[0].line()}")
    dropped = {f.trial for f in findings}
    kept = tuple(tr for tr in dataset.trials if tr.name not in dropped)
    if not kept:
        raise DataError(f"{_where(dataset, findings[0])}: every trial failed a data check; first: {findings[0].line()}")
    return (replace(dataset, trials=kept) if dropped else dataset), findings


def _where(dataset, finding: Finding) -> str:
    return str(dataset.folder / finding.trial) if dataset.folder else finding.trial


def _median5(x: np.ndarray) -> np.ndarray:
    if x.size < 5:
        return x
    padded = np.concatenate([x[:1], x[:1], x, x[-1:], x[-1:]])
    return np.median(np.lib.stride_tricks.sliding_window_view(padded, 5), axis=1)


def _robust_sigma(x: np.ndarray) -> float:
    return float(1.4826 * np.median(np.abs(x - np.median(x)))) if x.size else 0.0


def _hysteresis(theta: np.ndarray) -> float:
    """How far the angle must come back for a turning point: well above the noise, a small
    fraction of the motion."""
    noise = _robust_sigma(np.diff(theta, 2)) / math.sqrt(6.0)
    return max(8.0 * noise, 0.02 * float(np.ptp(theta)), 1e-4)


def turning_points(theta: np.ndarray, h: float) -> list[int]:
    """Sample indices of the swing's turning points: the running extremum, confirmed once the
    angle has come back from it by more than ``h`` (a zigzag filter, robust to noise)."""
    turns, ext, direction = [], 0, 0
    for k in range(1, theta.size):
        if direction == 0:  # not yet moved by more than h from the first sample
            if abs(theta[k] - theta[0]) > h:
                direction, ext = (1 if theta[k] > theta[0] else -1), k
        elif direction * (theta[k] - theta[ext]) > 0:
            ext = k
        elif direction * (theta[ext] - theta[k]) > h:
            turns.append(ext)
            direction, ext = -direction, k
    return turns


def _re_release(theta: np.ndarray, turns: list[int]):
    """A whole half-swing (turning point to turning point) much larger than the one before."""
    swings = [abs(theta[b] - theta[a]) for a, b in zip(turns, turns[1:])]
    for i in range(1, len(swings)):
        if swings[i] > RISE_FACTOR * swings[i - 1] and swings[i] > 0.2 * max(swings):
            return turns[i + 1], (f"the swing grows again ({swings[i - 1]:.3g} → {swings[i]:.3g} rad peak to peak): "
                                  f"two releases in one file")
    return None


def _jump(t: np.ndarray, theta: np.ndarray):
    d = np.diff(theta)
    if d.size < 4:
        return None
    # How far each step departs from its neighbours' mean: smooth motion leaves acceleration·dt².
    excess = d[1:-1] - 0.5 * (d[:-2] + d[2:])
    limit = max(JUMP_RAD, JUMP_SIGMAS * _robust_sigma(excess))
    size = np.abs(excess)
    for k in np.flatnonzero(size > limit):
        if size[k] < size[max(k - 1, 0)] or size[k] < size[min(k + 1, size.size - 1)]:
            continue  # the neighbours of a step depart by half of it: the step is the peak
        i = k + 1  # the step d[i] = θ[i+1] − θ[i]
        step = d[i]
        before, after = d[i - 1], (d[i + 1] if i + 1 < d.size else 0.0)
        # A one-sample outlier goes out and comes back: one step cancels the next.
        if abs(step + after) > 0.5 * abs(step) and abs(step + before) > 0.5 * abs(step):
            return int(i + 1), f"the angle steps by {step:.4g} rad in one sample and stays there"
    return None


def _runs_of_equal(theta: np.ndarray, min_len: int):
    same = np.concatenate([[False], np.diff(theta) == 0.0, [False]])
    edges = np.flatnonzero(np.diff(same.astype(int)))
    for start, stop in zip(edges[::2], edges[1::2]):  # readings start..stop are equal
        if stop - start + 1 >= min_len:
            yield int(start), int(stop)


def _fast_step(t: np.ndarray, theta: np.ndarray, a: int) -> bool:
    """Whether the single step a → a+1 is one of a joint at speed: faster than MOVING_SPEED and
    more than three of the data's smallest steps (an encoder tick is no motion). A joint that
    sticks arrives and leaves at zero speed, so its steps next to the rest are small; a frozen
    reading is entered at speed and left with a jump (the reading catching up)."""
    if a < 0 or a + 1 >= theta.size:
        return False
    steps = np.abs(np.diff(theta))
    quantum = float(steps[steps > 0].min()) if np.any(steps > 0) else 0.0
    change = abs(theta[a + 1] - theta[a])
    return change > 3.0 * quantum and change / max(t[a + 1] - t[a], 1e-12) > MOVING_SPEED


def _stuck(t: np.ndarray, theta: np.ndarray):
    for start, stop in _runs_of_equal(theta, STUCK_SAMPLES):
        if _fast_step(t, theta, start - 1) and _fast_step(t, theta, stop):
            return start, (f"{stop - start + 1} identical readings ({theta[start]:.5g} rad), entered and left "
                           f"at speed: a frozen reading")
    return None


def _clipping(t: np.ndarray, theta: np.ndarray):
    for value in (float(theta.max()), float(theta.min())):
        for start, stop in _runs_of_equal(theta, CLIP_SAMPLES):
            if theta[start] == value and _fast_step(t, theta, start - 1):
                return start, (f"{stop - start + 1} readings at the trial's extreme {value:.5g} rad, "
                               f"arrived at speed: the angle is clipped")
    return None


def _clock(t: np.ndarray, turns: list[int], trial):
    """Half-periods shorter than the load alone allows (see the module doc)."""
    if len(turns) < MIN_HALF_SWINGS + 1 or trial.gravity_torque <= 0 or trial.load_inertia <= 0:
        return None
    half = float(np.median(np.diff(t[turns])))
    shortest = math.pi * math.sqrt(trial.load_inertia / trial.gravity_torque)
    if half < (1.0 - CLOCK_TOLERANCE) * shortest:
        return turns[0], (f"half-swings take {half:.4g} s, but this load cannot swing faster than "
                          f"{shortest:.4g} s: the time stamps run slow (or the geometry is wrong)")
    return None


__all__ = ["Finding", "check_trial", "screen", "turning_points"]
