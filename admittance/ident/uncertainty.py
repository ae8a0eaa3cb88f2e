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
resampling sees). One such bias is measured: the fit's own integration (semi-implicit Euler at
1 ms). The final model is refitted at half the step; by Richardson, the error at step h is about
twice the change from h to h/2 (residual.discretisation_error does the same for the angle). On
clean synthetic drops it was most of the gap: I moved 0.0146546 → 0.0146752 → 0.0146791 at 1,
0.5 and 0.25 ms for a true 0.0147, with a fit σ of 0.00001.

The reported σ is √(max(fit σ, jackknife σ)² + (2·(θ_h − θ_h/2))²), and the 95 % interval is
the estimate ± t(0.975, g − 1) · σ: with few groups the jackknife's σ is itself uncertain.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from statistics import NormalDist
from typing import Sequence

import numpy as np

from admittance.ident.fit import FitResult, end_point_of, fit_output_error
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

    sigma: dict[str, float]  # the reported σ (module doc)
    sigma_jackknife: dict[str, float] = field(default_factory=dict)
    integration: dict[str, float] = field(default_factory=dict)  # 2·(θ_h − θ_h/2): the step's bias
    groups: int = 0  # trial groups left out in turn (0: no jackknife)
    multiplier: float = NormalDist().inv_cdf(0.5 + LEVEL / 2)  # half-width of the interval in σ

    def describe(self) -> dict:
        return {"method": ("jackknife over trial groups" if self.groups else "fit σ (too few trials for a jackknife)")
                + " and the integration step's bias",
                "groups": self.groups, "level": LEVEL, "multiplier": self.multiplier}


def trial_groups(trials: Sequence[TrialData], max_groups: int = MAX_GROUPS) -> list[list[int]]:
    """Indices of ``trials`` in at most ``max_groups`` groups, each spread over loads and
    directions (dealt round robin in stratified order, split.py)."""
    order = stratum_order(trials)
    count = min(max_groups, len(order))
    return [sorted(order[k::count]) for k in range(count)]


def reported_uncertainty(sim: Simulator, fit: FitResult, torque_scale: float,
                         max_groups: int = MAX_GROUPS) -> Uncertainty:
    """The reported uncertainty of ``fit`` (fitted on every trial of ``sim``)."""
    if not fit.free:
        return Uncertainty({})
    sim = sim.with_tau_scale(fit.tau_scale)
    integration = integration_bias(sim, fit, torque_scale)
    spread = jackknife(sim, fit, torque_scale, max_groups)
    groups = len(trial_groups(sim.trials, max_groups)) if spread else 0
    sigma = {name: math.hypot(max(fit.sigma.get(name, 0.0), spread.get(name, 0.0)), integration[name])
             for name in fit.free}
    multiplier = student_t_quantile(0.5 + LEVEL / 2, groups - 1) if groups else NormalDist().inv_cdf(0.5 + LEVEL / 2)
    return Uncertainty(sigma, spread, integration, groups, multiplier)


def integration_bias(sim: Simulator, fit: FitResult, torque_scale: float) -> dict[str, float]:
    """Per free parameter, twice its change when the model is refitted at half the step."""
    finer = Simulator(sim.trials, sim.mode, sim.friction, sim.max_step / 2, fit.tau_scale)
    refit = fit_output_error(finer, fit.vector, fit.free, fit.x0, torque_scale=torque_scale,
                             max_iter=REFIT_ITERATIONS, label="half-step refit")
    return {name: 2.0 * abs(refit.value(name) - fit.value(name)) for name in fit.free}


def jackknife(sim: Simulator, fit: FitResult, torque_scale: float, max_groups: int = MAX_GROUPS) -> dict[str, float]:
    """Per free parameter, the delete-a-group jackknife σ ({} with fewer than MIN_GROUPS groups)."""
    groups = trial_groups(sim.trials, max_groups)
    if len(groups) < MIN_GROUPS:
        return {}
    known = end_point_of(sim, fit, torque_scale)  # every replicate starts there: one Jacobian for all
    replicates = []
    for left_out in groups:
        keep = [i for i in range(len(sim.trials)) if i not in left_out]
        refit = fit_output_error(sim.subset(keep), fit.vector, fit.free, fit.x0[keep], torque_scale=torque_scale,
                                 max_iter=REFIT_ITERATIONS, label="jackknife", known=known)
        replicates.append([refit.value(name) for name in fit.free])
    values = np.array(replicates)
    g = len(groups)
    spread = np.sqrt((g - 1) / g * np.sum((values - values.mean(axis=0)) ** 2, axis=0))
    return {name: float(s) for name, s in zip(fit.free, spread)}


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
