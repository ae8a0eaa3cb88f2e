"""Breakaway friction from a slow torque ramp (the thesis's section 2.3 test, table 3.1).

A slowly growing torque is applied to a joint at rest; at the instant the friction gives way
the angle starts to move, and the torque at that instant is the breakaway (static) friction.

Detection, and why this way:
- The rest angle and its noise are measured on the first samples of the trial (the median,
  and a MAD-based σ of the sample-to-sample differences: robust to outliers and to a slow
  drift), with a floor so a noiseless or quantised signal does not give σ = 0. The window is
  short (5 %) because a light joint may break away early in the ramp.
- Motion is declared where the angle stays outside ``k·σ`` of the rest angle for ``hold``
  consecutive samples: one noisy sample cannot trigger it, and a slow creep below the band
  does not count.
- The threshold crossing comes late: after breakaway the angle grows smoothly from zero
  (∝ (t − t₀)³ under a ramp with Coulomb friction, ∝ (t − t₀)² if the friction drops at
  breakaway), and reading the torque there would overstate it by the ramp's growth in
  between. So the onset t₀ is fitted: ``|θ − θ_rest| = a·max(t − t₀, 0)^p`` (p in [1, 4])
  on the samples around the crossing (signed, so the rest noise averages out), starting
  from the last sample inside ``k_onset·σ``.
- The torque is interpolated at t₀; the direction is the trial's ``direction`` label, else
  the sign of the ramp. Like table 3.1, the torque is reported as a magnitude.
"""

from __future__ import annotations

import statistics
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np
from scipy.optimize import least_squares

from admittance.errors import DataError

REST_FRACTION = 0.05  # share of the trial (from the start) taken as at rest
RAMP_MIN_R2 = 0.9  # a ramp's torque is a line in time; a step, hold or sine is not
K_SIGMA = 6.0
K_ONSET = 2.0
K_FIT = 20.0
HOLD = 5
SIGMA_FLOOR = 2e-5  # rad: below a 12-bit encoder's tick, above float noise


@dataclass
class Breakaway:
    trial: str
    direction: str
    torque: float  # |τ| at the onset, N·m
    onset_time: float  # s
    sigma: float  # rad, the rest noise


def detect_onset(t: np.ndarray, theta: np.ndarray, rest_fraction: float = REST_FRACTION,
                 k_sigma: float = K_SIGMA, k_onset: float = K_ONSET, hold: int = HOLD) -> tuple[float, float]:
    """(the time motion starts, the rest-noise σ)."""
    n_rest = max(int(rest_fraction * t.size), 10)
    if t.size < n_rest + hold + 1:
        raise DataError(f"only {t.size} samples: too short to find a rest band and a breakaway")
    centre, sigma = _rest_band(theta[:n_rest])
    outside = np.abs(theta - centre) > k_sigma * sigma
    run = np.convolve(outside.astype(int), np.ones(hold, dtype=int), mode="valid") == hold
    hits = np.flatnonzero(run[n_rest:]) + n_rest
    if hits.size == 0:
        raise DataError("the angle never leaves its rest band: no breakaway in this trial")
    first = int(hits[0])
    inside = np.flatnonzero(np.abs(theta[:first] - centre) <= k_onset * sigma)
    last_rest = int(inside[-1]) if inside.size else first
    # the signed deviation keeps the rest noise zero-mean, so it does not pull t₀ earlier
    signed = (theta - centre) * np.sign(theta[first] - centre)
    # fit up to where the growth is well above the noise (K_FIT·σ), so t₀ is pinned by the
    # curve's shape rather than by the few samples around the crossing
    above = np.flatnonzero(signed[first:] > K_FIT * sigma)
    end = first + (int(above[0]) if above.size else 0) + hold
    return _fit_onset(t, signed, last_rest, min(end, t.size)), sigma


def _rest_band(rest: np.ndarray) -> tuple[float, float]:
    """(rest angle, noise σ): the median, and the MAD of the differences (white noise's have σ·√2)."""
    sigma = 1.4826 * float(np.median(np.abs(np.diff(rest)))) / np.sqrt(2.0)
    return float(np.median(rest)), max(sigma, SIGMA_FLOOR)


def _fit_onset(t: np.ndarray, dev: np.ndarray, last_rest: int, end: int) -> float:
    """t₀ of ``dev = a·max(t − t₀, 0)^p`` on a window around the departure from rest."""
    start = max(0, last_rest - 2 * (end - last_rest))
    tw, dw = t[start:end], dev[start:end]
    scale = max(float(dw[-1]), 1e-12)
    span = float(tw[-1] - tw[0])

    def residual(x):
        t0, a, p = x
        return a * np.maximum(tw - t0, 0.0) ** p - dw / scale

    guess_t0 = float(t[last_rest])
    guess_a = 1.0 / max(float(tw[-1]) - guess_t0, 1e-9) ** 2
    fit = least_squares(residual, [guess_t0, guess_a, 2.0],
                        bounds=([tw[0] - span, 0.0, 1.0], [tw[-1], np.inf, 4.0]))
    return float(fit.x[0]) if fit.success else guess_t0


def breakaway_of(trial) -> Breakaway:
    """The breakaway of one ``TrialData`` (it must carry ``tau``)."""
    if trial.tau is None:
        raise DataError(f"{trial.name}: no tau column; the breakaway test needs the applied torque")
    try:
        onset, sigma = detect_onset(trial.t, trial.theta)
    except DataError as exc:
        raise DataError(f"{trial.name}: {exc}") from None
    torque = float(np.interp(onset, trial.t, trial.tau))
    before = trial.tau[trial.t <= onset]
    reason = not_a_ramp(trial.t[trial.t <= onset], before)
    if reason:
        raise DataError(f"{trial.name}: not a torque ramp before the breakaway ({reason}); "
                        "the breakaway test needs a slow, steady ramp of tau")
    direction = str(trial.meta.get("direction") or ("ccw" if _ramp_sign(before) > 0 else "cw"))
    return Breakaway(trial.name, direction, abs(torque), float(onset - trial.t[0]), float(sigma))


def not_a_ramp(t: np.ndarray, tau: np.ndarray, min_r2: float = RAMP_MIN_R2) -> str:
    """Why the torque up to the onset is not a ramp (a straight line away from zero), or ''."""
    if tau.size < 3:
        return f"only {tau.size} samples before the onset"
    slope, intercept = np.polyfit(t, tau, 1)
    total = float(np.sum((tau - tau.mean()) ** 2))
    if total == 0.0 or slope == 0.0:
        return "tau is constant"
    r2 = 1.0 - float(np.sum((tau - (slope * t + intercept)) ** 2)) / total
    if r2 < min_r2:
        return f"tau is not a straight line in time: R² {r2:.2f} < {min_r2}"
    if abs(tau[-1]) <= abs(tau[0]):
        return "|tau| does not grow"
    return ""


def _ramp_sign(tau: np.ndarray) -> float:
    """The sign of the ramp: of the torque with the largest magnitude before the onset."""
    if tau.size == 0:
        return 0.0
    return float(np.sign(tau[int(np.argmax(np.abs(tau)))]))


def summarise(results: Sequence[Breakaway]) -> dict:
    """Table 3.1's layout: per trial, the average per direction, and the overall average."""
    by_direction: dict[str, list[float]] = {}
    for r in results:
        by_direction.setdefault(r.direction, []).append(r.torque)
    return {
        "trials": [asdict(r) for r in results],
        "average_by_direction": {d: statistics.mean(v) for d, v in sorted(by_direction.items())},
        "average": statistics.mean(r.torque for r in results) if results else None,
    }


def to_markdown(summary: dict) -> str:
    lines = ["| Trial | Direction | Breakaway torque (N·m) | Onset (s) |", "|---|---|---|---|"]
    lines += [f"| {r['trial']} | {r['direction']} | {r['torque']:.5f} | {r['onset_time']:.3f} |"
              for r in summary["trials"]]
    lines += [f"| **Average for {d}** | {d} | {v:.5f} | |" for d, v in summary["average_by_direction"].items()]
    if summary["average"] is not None:
        lines.append(f"| **Overall average** | | {summary['average']:.5f} | |")
    return "\n".join(lines) + "\n"
