"""Which effect is missing: rank the candidates by how much of the residual each explains, then
admit one only when held-back trials clearly improve.

**Ranking (a score test).** At the current fit, each candidate's parameter sits at its "off"
value (0). The linearised effect of switching it on is the sensitivity column ∂θ/∂p, by finite
difference. Least squares of the residual on [current Jacobian | candidate columns] tells how
much of the residual's sum of squares the candidate could remove *beyond what refitting the
current parameters and initial states already can*: the explained fraction. Every candidate's
columns come from ONE batch simulation at the current fit. Nonlinear shape parameters get a
small grid of variants (Stribeck velocity; cogging period, whose amplitude and phase become
two linear columns, the sin and cos of period·θ); the best variant represents the effect and
seeds its refit. A coefficient of the wrong sign (negative drag, a Stribeck dip below Coulomb)
means "not this effect" and scores zero.

**Admission.** The ranking only orders the work. An effect is added only when (1) refitting
with it lowers the output error on *validation* trials (held back from this fit, and distinct
from the reported held-out trials) by more than ``min_gain`` relative, and (2) one of its
evidence parameters is at least ``min_sigma`` standard errors from zero, with σ corrected for
the residual's autocorrelation (fit.py). Both are needed: a better validation score alone can
be luck on few trials, and significance alone follows from having thousands of samples. On
data without the effect neither holds, so nothing is claimed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from admittance.ident.fit import FitResult, Progress, fit_initial_states, fit_output_error, normal_equations, rmse
from admittance.ident.model import EFFECTS, INDEX, Simulator, free_params

STRIBECK_VELOCITIES = (0.03, 0.1, 0.3, 1.0)  # rad/s
COGGING_PERIODS = tuple(range(2, 33))  # cycles/rev: 1 would be gravity itself
MIN_EXPLAINED = 0.002  # below this fraction of the residual a refit is not worth its time


@dataclass(frozen=True)
class Column:
    """One sensitivity column: with ``settings`` applied, perturb ``param`` by ``step``."""

    settings: tuple[tuple[str, float], ...]
    param: str
    step: float


@dataclass(frozen=True)
class Variant:
    effect: str
    label: str
    columns: tuple[Column, ...]
    shape: tuple[tuple[str, float], ...] = ()  # shape values that seed the refit


@dataclass
class Evidence:
    """What the ranking and the admission test found for one candidate effect."""

    effect: str
    variant: str = ""
    explained: float = 0.0  # fraction of the residual sum of squares
    plausible: bool = True
    start: dict[str, float] = field(default_factory=dict)
    validation_gain: float | None = None  # relative drop of validation RMSE
    significance: float | None = None  # |value| / σ of the best evidence parameter
    values: dict[str, tuple[float, float]] = field(default_factory=dict)  # name -> (value, σ)
    accepted: bool = False
    reason: str = ""

    def as_dict(self) -> dict:
        return {
            "effect": self.effect,
            "variant": self.variant,
            "explained_fraction": self.explained,
            "plausible": self.plausible,
            "validation_gain": self.validation_gain,
            "significance_sigma": self.significance,
            "params": {k: {"value": v, "sigma": s} for k, (v, s) in self.values.items()},
            "accepted": self.accepted,
            "reason": self.reason,
        }


def variants(effect: str, torque_scale: float) -> list[Variant]:
    """The probes of one effect, with finite-difference steps in each parameter's units."""
    torque_step = 1e-3 * torque_scale
    if effect == "stribeck":
        return [
            Variant(effect, f"v_s = {v} rad/s", (Column((("stribeck_velocity", v),), "stribeck_torque", torque_step),),
                    (("stribeck_velocity", v),))
            for v in STRIBECK_VELOCITIES
        ]
    if effect == "cogging":
        out = []
        for period in COGGING_PERIODS:
            sin_col = Column((("cogging_period", period), ("cogging_phase", 0.0)), "cogging_amplitude", torque_step)
            cos_col = Column((("cogging_period", period), ("cogging_phase", math.pi / 2)), "cogging_amplitude",
                             torque_step)
            out.append(Variant(effect, f"period {period}/rev", (sin_col, cos_col), (("cogging_period", period),)))
        return out
    steps = {
        "asymmetric_coulomb": ("coulomb_asym", torque_step),
        "load_dependent_coulomb": ("load_coulomb", 1e-2),
        "angle_offset": ("angle_offset", 2e-3),
        "quadratic_drag": ("quadratic_drag", 1e-4 * torque_scale),
        "time_delay": ("time_delay", 5e-3),
    }
    if effect == "torque_bias":
        cols = (Column((), "torque_bias", torque_step), Column((), "torque_drift", 1e-4 * torque_scale))
        return [Variant(effect, "bias and drift", cols)]
    param, step = steps[effect]
    return [Variant(effect, param, (Column((), param, step),))]


def candidate_effects(present: Sequence[str], with_tau: bool) -> list[str]:
    return [name for name, e in EFFECTS.items() if name not in present and (with_tau or not e.needs_torque)]


def rank_candidates(sim: Simulator, fit: FitResult, candidates: Sequence[str], torque_scale: float) -> list[Evidence]:
    """Explained fraction of each candidate (best variant), highest first, from one batch."""
    sim = sim.with_tau_scale(fit.tau_scale)
    probes = [v for name in candidates for v in variants(name, torque_scale)]
    columns = [c for v in probes for c in v.columns]
    if not columns or not fit.jacobian:
        return []
    sens = _sensitivities(sim, fit, columns)
    total = sum(float(r @ r) for r in fit.residuals)
    base_explained = _explained(fit.jacobian, [], fit.residuals, len(fit.free))[0]
    best: dict[str, Evidence] = {}
    offset = 0
    for variant in probes:
        n_c = len(variant.columns)
        cols = [s[offset : offset + n_c] for s in sens]
        offset += n_c
        explained, coef = _explained(fit.jacobian, cols, fit.residuals, len(fit.free))
        evidence = _evidence(variant, coef, (explained - base_explained) / max(total, 1e-300))
        if variant.effect not in best or evidence.explained > best[variant.effect].explained:
            best[variant.effect] = evidence
    return sorted(best.values(), key=lambda e: e.explained, reverse=True)


def _sensitivities(sim: Simulator, fit: FitResult, columns: Sequence[Column]) -> list[np.ndarray]:
    """Per trial, (n_columns, n_k) of ∂θ/∂p at the current fit, from one batch call."""
    rows = np.repeat(fit.vector[None, :], len(columns), axis=0)
    for i, col in enumerate(columns):
        for name, value in col.settings:
            rows[i, INDEX[name]] = value
        rows[i, INDEX[col.param]] += col.step
    x0 = np.repeat(fit.x0[None, :, :], len(columns), axis=0)
    steps = np.array([c.step for c in columns])
    sims = sim.run(rows, x0)
    return [(s - (r + m)[None, :]) / steps[:, None] for s, r, m in zip(sims, fit.residuals, sim.measured)]


def _explained(jac: list[np.ndarray], extra: list[np.ndarray], residuals: list[np.ndarray], n_g: int):
    """Sum of squares a Gauss–Newton step over [globals, extra, x0] removes; extra's coefficients."""
    n_x = 0 if not extra else extra[0].shape[0]
    blocks = [np.vstack([jk[:n_g], ek, jk[n_g:]]) if n_x else jk for jk, ek in zip(jac, extra or [None] * len(jac))]
    a, b = normal_equations(blocks, residuals, n_g + n_x, fit_x0=blocks[0].shape[0] > n_g + n_x)
    scale = np.sqrt(np.maximum(np.diag(a), 1e-300))
    delta = -np.linalg.lstsq(a / np.outer(scale, scale), b / scale, rcond=1e-10)[0] / scale
    return float(-b @ delta), delta[n_g : n_g + n_x]


def _evidence(variant: Variant, coef: np.ndarray, explained: float) -> Evidence:
    start = dict(variant.shape)
    plausible = True
    if variant.effect == "cogging":
        a, b = coef
        start.update(cogging_amplitude=float(math.hypot(a, b)), cogging_phase=float(math.atan2(b, a)))
    else:
        for col, value in zip(variant.columns, coef):
            start[col.param] = float(value)
        nonneg = {"stribeck_torque", "load_coulomb", "quadratic_drag", "time_delay"}
        plausible = all(start[c.param] > 0 for c in variant.columns if c.param in nonneg)
    return Evidence(
        effect=variant.effect,
        variant=variant.label,
        explained=max(explained, 0.0) if plausible else 0.0,
        plausible=plausible,
        start=start,
    )


@dataclass
class SearchSettings:
    max_effects: int = 4
    min_gain: float = 0.05  # relative validation-RMSE improvement
    min_sigma: float = 3.0
    top_k: int = 3  # candidates refitted per round


@dataclass
class SearchOutcome:
    effects: list[str]
    fit: FitResult  # the fit (on the fitting split) with the admitted effects
    rounds: list[list[Evidence]]
    validation_rmse: list[float]  # before any effect, then after each admitted one


def score(sim: Simulator, fit: FitResult, x0: np.ndarray, progress: Progress | None = None) -> FitResult:
    """Output error of trials the model was not fitted on: only their initial states are fitted."""
    return fit_initial_states(sim, fit.vector, x0, tau_scale=fit.tau_scale, progress=progress, label="scoring")


def search_effects(
    fit_sim: Simulator,
    val_sim: Simulator,
    base: FitResult,
    val_x0: np.ndarray,
    mode: str,
    torque_scale: float,
    settings: SearchSettings,
    progress: Progress | None = None,
) -> SearchOutcome:
    """Greedy forward selection on the fitting split, judged on the validation split."""
    with_tau = any(tr.tau is not None for tr in fit_sim.trials)
    effects: list[str] = []
    current = base
    val_rmse = [score(val_sim, current, val_x0).rmse]
    rounds: list[list[Evidence]] = []
    while len(effects) < settings.max_effects:
        ranking = rank_candidates(fit_sim, current, candidate_effects(effects, with_tau), torque_scale)
        rounds.append(ranking)
        tried = [e for e in ranking if e.plausible and e.explained >= MIN_EXPLAINED][: settings.top_k]
        for evidence in ranking:
            if evidence not in tried:
                evidence.reason = "explains too little of the residual" if evidence.plausible else "wrong sign"
        best: tuple[Evidence, FitResult, float] | None = None
        for evidence in tried:
            if progress:
                progress(f"trying {evidence.effect} ({evidence.variant})")
            trial_fit, trial_rmse = _try_effect(fit_sim, val_sim, current, effects, evidence, val_x0, mode,
                                                with_tau, torque_scale, val_rmse[-1], settings)
            if evidence.accepted and (best is None or trial_rmse < best[2]):
                best = (evidence, trial_fit, trial_rmse)
        if best is None:
            break
        for evidence in tried:
            if evidence is not best[0] and evidence.accepted:
                evidence.accepted = False
                evidence.reason = f"qualified, but {best[0].effect} improved validation more"
        effects.append(best[0].effect)
        current = best[1]
        val_rmse.append(best[2])
    return SearchOutcome(effects, current, rounds, val_rmse)


def _try_effect(fit_sim, val_sim, current, effects, evidence, val_x0, mode, with_tau, torque_scale, val_before,
                settings: SearchSettings) -> tuple[FitResult, float]:
    vector = current.vector.copy()
    for name, value in evidence.start.items():
        vector[INDEX[name]] = value
    free = free_params(mode, [*effects, evidence.effect], with_tau)
    sim = fit_sim.with_tau_scale(current.tau_scale)
    refit = fit_output_error(sim, _clip_start(vector, free), free, current.x0, torque_scale=torque_scale,
                             label=f"fit +{evidence.effect}")
    val = score(val_sim, refit, val_x0).rmse
    evidence.validation_gain = float(1.0 - val / val_before) if val_before > 0 else 0.0
    main = EFFECTS[evidence.effect].evidence
    evidence.values = {n: (refit.value(n), refit.sigma.get(n, math.nan)) for n in EFFECTS[evidence.effect].params}
    evidence.significance = float(max(abs(refit.value(n)) / max(refit.sigma.get(n, math.inf), 1e-300) for n in main))
    gain_ok = evidence.validation_gain > settings.min_gain
    sig_ok = evidence.significance >= settings.min_sigma
    evidence.accepted = gain_ok and sig_ok
    if evidence.accepted:
        evidence.reason = "validation improved and the parameter is significant"
    elif not gain_ok:
        evidence.reason = f"validation gain {100 * evidence.validation_gain:.1f} % ≤ {100 * settings.min_gain:.0f} %"
    else:
        evidence.reason = f"parameter only {evidence.significance:.1f} σ from zero"
    return refit, val


def _clip_start(vector: np.ndarray, free: Sequence[str]) -> np.ndarray:
    from admittance.ident.model import LOWER, UPPER

    out = vector.copy()
    for name in free:
        if name in INDEX:
            out[INDEX[name]] = min(max(out[INDEX[name]], LOWER.get(name, -np.inf)), UPPER.get(name, np.inf))
    return out


__all__ = ["Evidence", "SearchSettings", "SearchOutcome", "rank_candidates", "search_effects", "score", "rmse"]
