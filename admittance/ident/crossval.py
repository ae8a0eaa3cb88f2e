"""Cross-validation units and folds, and the paired score of one model against another.

An effect is admitted on what it does to data the fit did not see. With many trials the
units are whole trials, dealt into up to five folds in stratified order. With few trials
(a measured set may hold two to four long swings) whole trials are too few a jury: one
validation trial decides everything, and a flexible effect fits its quirks. Long trials are
then cut into **time segments**, each a unit of its own with its own fitted initial state:
fold k holds out one segment of every trial, shifted by the trial's index, so each fold
still trains on every trial and on every phase of a swing (large swings early, small ones
late). Segments are kept at least two small-oscillation periods long: in shorter windows the
fitted initial state absorbs what the parameters should explain.

A held-out unit is scored as a held-out trial is: the model fixed, only its initial state
fitted (from several starts, keeping the best; fit.fit_initial_states_multi).

**The paired score** compares a candidate with the current model on the same held-out
samples: the loss differential δ_t = r_current,t² − r_candidate,t² per sample. Its mean over
every held-out sample is the cross-validated improvement; its standard error is the noise's
share of it, the long-run variance of δ within each unit (the integrated autocorrelation
time, the same correction fit.py applies to parameter σ): output-error residuals are smooth,
and counted as independent samples they would make any gain look certain. This is the
Diebold–Mariano comparison of predictive accuracy. How much the gain varies *between* units
(trials differ in load, release and direction) is the other uncertainty; with three to five
units it cannot be estimated, so it is judged by counting folds. A candidate earns its place when

- the pooled gain 1 − √(Σc²/Σm²) exceeds ``min_gain``,
- the one-sided 95 % lower bound of the mean differential is above zero (the gain is not
  within its uncertainty), and
- a majority of folds improve: a gain that one fold sees and the others contradict is the
  quirk of one fold, however large.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from statistics import NormalDist
from typing import Sequence

import numpy as np

from admittance.formats.dataset import TrialData
from admittance.ident.fit import autocorrelation_time
from admittance.ident.split import stratum_order

MAX_FOLDS = 5
MIN_TRIALS_FOR_TRIAL_FOLDS = 4  # fewer trials: cut them into time segments
MAX_SEGMENTS = 4  # per trial
MIN_SEGMENT_S = 2.0  # s, and at least MIN_SEGMENT_PERIODS small-oscillation periods
MIN_SEGMENT_PERIODS = 2.0
MIN_UNITS = 3  # fewer units than this: whole trials are folded instead of segments
CONFIDENCE = 0.95  # one-sided


@dataclass(frozen=True)
class Unit:
    """A piece of one trial: samples [start, stop) of ``trial`` (an index into the parent list)."""

    trial: int
    start: int
    stop: int
    fold: int


@dataclass
class Folds:
    """Units (with their data as pseudo-trials) and their fold labels."""

    kind: str  # "trials" or "segments"
    units: list[Unit]
    data: list[TrialData]  # one pseudo-trial per unit
    n_folds: int

    def train(self, k: int) -> list[int]:
        return [i for i, u in enumerate(self.units) if u.fold != k]

    def held(self, k: int) -> list[int]:
        return [i for i, u in enumerate(self.units) if u.fold == k]

    def describe(self) -> dict:
        return {"kind": self.kind, "folds": self.n_folds, "units": len(self.units),
                "unit_names": [d.name for d in self.data]}


def make_folds(trials: Sequence[TrialData], period: float) -> Folds | None:
    """Folds over ``trials``: whole trials when there are enough, else time segments.
    ``period`` (s) is the model's small-oscillation period. None when no fold can be formed."""
    n = len(trials)
    if n >= MIN_TRIALS_FOR_TRIAL_FOLDS:
        return _trial_folds(trials, min(n, MAX_FOLDS))
    segments = _segment_folds(trials, max(MIN_SEGMENT_S, MIN_SEGMENT_PERIODS * period))
    if segments is not None:
        return segments
    return _trial_folds(trials, n) if n >= 2 else None


def _trial_folds(trials: Sequence[TrialData], k: int) -> Folds:
    order = stratum_order(trials)
    fold_of = {trial: rank % k for rank, trial in enumerate(order)}
    units = [Unit(i, 0, tr.n_samples, fold_of[i]) for i, tr in enumerate(trials)]
    return Folds("trials", units, list(trials), k)


def _segment_folds(trials: Sequence[TrialData], min_length: float) -> Folds | None:
    counts = [max(1, min(MAX_SEGMENTS, int((tr.t[-1] - tr.t[0]) // min_length))) for tr in trials]
    if sum(counts) < MIN_UNITS or max(counts) < 2:
        return None
    k = max(counts)
    units, data = [], []
    for i, (trial, count) in enumerate(zip(trials, counts)):
        edges = np.searchsorted(trial.t, np.linspace(trial.t[0], trial.t[-1], count + 1))
        edges[-1] = trial.n_samples
        for s in range(count):
            unit = Unit(i, int(edges[s]), int(edges[s + 1]), (s + i) % k)
            units.append(unit)
            data.append(segment(trial, unit.start, unit.stop))
    return Folds("segments", units, data, k)


def segment(trial: TrialData, start: int, stop: int) -> TrialData:
    """Samples [start, stop) of ``trial`` as a trial of its own."""
    pick = slice(start, stop)
    name = f"{trial.name}[{trial.t[start]:.1f}–{trial.t[stop - 1]:.1f} s]"
    tau = None if trial.tau is None else trial.tau[pick]
    return replace(trial, name=name, t=trial.t[pick], theta=trial.theta[pick], tau=tau)


def small_oscillation_period(inertia_total: Sequence[float], gravity: Sequence[float]) -> float:
    """The longest 2π·√(I/G) over the trials (s); 0 without gravity."""
    periods = [2 * math.pi * math.sqrt(i / g) for i, g in zip(inertia_total, gravity) if g > 0 and i > 0]
    return max(periods, default=0.0)


@dataclass
class PairedGain:
    """The cross-validated comparison of a candidate model with the current one."""

    pooled_gain: float  # 1 − √(Σc² / Σm²) over every held-out sample
    gain_lower_bound: float  # the same with the mean differential at its lower confidence bound
    z: float  # mean differential over its standard error
    autocorrelation_time: float  # of the loss differential, in samples
    folds_supporting: int
    n_folds: int
    n_units: int
    current_rmse: float  # pooled over the held-out samples
    candidate_rmse: float

    @property
    def lower_bound(self) -> float:
        return self.gain_lower_bound

    @property
    def majority(self) -> bool:
        return 2 * self.folds_supporting > self.n_folds

    def supported(self, min_gain: float) -> bool:
        return self.pooled_gain > min_gain and self.gain_lower_bound > 0 and self.majority

    def as_dict(self) -> dict:
        return {"pooled_gain": self.pooled_gain, "gain_lower_bound": self.gain_lower_bound, "z": self.z,
                "autocorrelation_time": self.autocorrelation_time, "folds_supporting": self.folds_supporting,
                "folds": self.n_folds, "units": self.n_units, "rmse_current": self.current_rmse,
                "rmse_candidate": self.candidate_rmse}


def paired_gain(current: Sequence[np.ndarray], candidate: Sequence[np.ndarray], folds: Sequence[int]) -> PairedGain:
    """Compare two models' held-out residuals (per unit, the same units in the same order)."""
    deltas = [m**2 - c**2 for m, c in zip(current, candidate)]
    n = sum(d.size for d in deltas)
    total_m = sum(float(m @ m) for m in current)
    total_c = sum(float(c @ c) for c in candidate)
    mean = (total_m - total_c) / n
    centred = [d - d.mean() for d in deltas if d.size]
    tau = autocorrelation_time(centred, max_lag=2000)
    variance = sum(float(d @ d) for d in centred) / n
    std_error = math.sqrt(max(variance, 0.0) * tau / n)
    low = mean - NormalDist().inv_cdf(CONFIDENCE) * std_error
    folds = np.asarray(folds)
    unit_m = np.array([float(m @ m) for m in current])
    unit_c = np.array([float(c @ c) for c in candidate])
    supporting = sum(1 for k in np.unique(folds) if unit_c[folds == k].sum() < unit_m[folds == k].sum())
    return PairedGain(
        pooled_gain=_gain(total_m, total_m - n * mean),
        gain_lower_bound=_gain(total_m, total_m - n * low),
        z=float(mean / std_error) if std_error > 0 else (math.inf if mean > 0 else 0.0),
        autocorrelation_time=tau,
        folds_supporting=int(supporting),
        n_folds=int(np.unique(folds).size),
        n_units=len(deltas),
        current_rmse=float(math.sqrt(total_m / n)),
        candidate_rmse=float(math.sqrt(total_c / n)),
    )


def _gain(before: float, after: float) -> float:
    return float(1.0 - math.sqrt(max(after, 0.0) / before)) if before > 0 else 0.0
