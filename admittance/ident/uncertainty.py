"""The reported parameter uncertainty: a delete-a-group jackknife over whole trials.

The fit's own σ (fit.py: (JᵀJ)⁻¹ times the residual variance times its autocorrelation time)
is what the *admission* tests use: it decides whether an effect's parameter is significant,
and the honesty tests are tuned to it. It is a local, within-model estimate: it assumes the
model is right and the residual's correlation is one number. Neither holds when the model
misses something: a Stribeck set fitted slightly wrong moves I, B and F by 5-9 such σ.

The interval reported to the user is built here, apart from every admission decision. The
final model is refitted with each group of training trials left out (warm-started from the
final fit, so a refit costs a few LM iterations); the spread of those refits is the jackknife
variance (g − 1)/g · Σ(θ_k − θ̄)². Trials are independent drops, so whatever makes the
estimate move from trial to trial (correlated residuals, model error that differs with load
or release) shows in it; model error that is the same in every trial does not (a bias no
resampling sees). The reported σ is the larger of the two estimates, and the 95 % interval is
the estimate ± t(0.975, g − 1) · σ: with few groups the jackknife's σ is itself uncertain.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from statistics import NormalDist
from typing import Sequence

import numpy as np

from admittance.ident.fit import FitResult, fit_output_error
from admittance.ident.model import Simulator
from admittance.formats.dataset import TrialData
from admittance.ident.split import stratum_order

MAX_GROUPS = 10  # at most this many refits: trials beyond it are grouped (stratified, round robin)
MIN_GROUPS = 3  # below this a jackknife says nothing: the fit's σ is reported alone
REFIT_ITERATIONS = 20  # a warm-started refit on most of the data converges in a few
LEVEL = 0.95


@dataclass
class Uncertainty:
    """σ of each free parameter (sim units) and how it was obtained."""

    sigma: dict[str, float]  # the reported σ: max(fit σ, jackknife σ)
    sigma_jackknife: dict[str, float] = field(default_factory=dict)
    groups: int = 0  # trial groups left out in turn (0: no jackknife)
    multiplier: float = NormalDist().inv_cdf(0.5 + LEVEL / 2)  # half-width of the interval in σ

    def describe(self) -> dict:
        return {"method": "jackknife over trial groups" if self.groups else "fit σ only (too few trials)",
                "groups": self.groups, "level": LEVEL, "multiplier": self.multiplier}


def trial_groups(trials: Sequence[TrialData], max_groups: int = MAX_GROUPS) -> list[list[int]]:
    """Indices of ``trials`` in at most ``max_groups`` groups, each spread over loads and
    directions (dealt round robin in stratified order, split.py)."""
    order = stratum_order(trials)
    count = min(max_groups, len(order))
    return [sorted(order[k::count]) for k in range(count)]


def jackknife(sim: Simulator, fit: FitResult, torque_scale: float, max_groups: int = MAX_GROUPS) -> Uncertainty:
    """The reported uncertainty of ``fit`` (fitted on every trial of ``sim``)."""
    groups = trial_groups(sim.trials, max_groups)
    if len(groups) < MIN_GROUPS or not fit.free:
        return Uncertainty(dict(fit.sigma))
    sim = sim.with_tau_scale(fit.tau_scale)
    replicates = []
    for left_out in groups:
        keep = [i for i in range(len(sim.trials)) if i not in left_out]
        refit = fit_output_error(sim.subset(keep), fit.vector, fit.free, fit.x0[keep], torque_scale=torque_scale,
                                 max_iter=REFIT_ITERATIONS, label="jackknife")
        replicates.append([refit.value(name) for name in fit.free])
    values = np.array(replicates)
    g = len(groups)
    spread = np.sqrt((g - 1) / g * np.sum((values - values.mean(axis=0)) ** 2, axis=0))
    jack = {name: float(s) for name, s in zip(fit.free, spread)}
    sigma = {name: max(fit.sigma.get(name, 0.0), jack[name]) for name in fit.free}
    return Uncertainty(sigma, jack, g, student_t_quantile(0.5 + LEVEL / 2, g - 1))


def student_t_quantile(p: float, dof: int) -> float:
    """Student-t quantile: exact for 1 and 2 degrees of freedom, else the Cornish–Fisher
    expansion in the normal quantile (within 0.2 % at p = 0.975 for dof ≥ 3)."""
    if dof <= 1:
        return math.tan(math.pi * (p - 0.5))
    if dof == 2:
        return (2 * p - 1) * math.sqrt(2.0 / (4 * p * (1 - p)))
    z, n = NormalDist().inv_cdf(p), float(dof)
    return (z + (z**3 + z) / (4 * n) + (5 * z**5 + 16 * z**3 + 3 * z) / (96 * n**2)
            + (3 * z**7 + 19 * z**5 + 17 * z**3 - 15 * z) / (384 * n**3)
            + (79 * z**9 + 776 * z**7 + 1482 * z**5 - 1920 * z**3 - 945 * z) / (92160 * n**4))
