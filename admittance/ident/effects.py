"""Which effect is missing: rank the candidates by how much of the residual each explains, then
admit one only when held-back trials clearly improve.

**Ranking (a score test).** At the current fit, each candidate's parameter sits at its "off"
value (its Contract 1 default: 0, or 1 for ``torque_gain``). The linearised effect of
switching it on is the sensitivity column ∂θ/∂p, by finite difference. Least squares of the
residual on [current Jacobian | candidate columns] tells how much of the residual's sum of squares the candidate could remove *beyond what refitting the
current parameters and initial states already can*: the explained fraction. Every candidate's
columns come from ONE batch simulation at the current fit. Nonlinear shape parameters get a
small grid of variants (Stribeck velocity; cogging period, whose amplitude and phase become
two linear columns, the sin and cos of period·θ); the best variant represents the effect and
seeds its refit. A coefficient of the wrong sign (negative drag, a Stribeck dip below Coulomb)
means "not this effect" and scores zero.

**Admission.** The ranking only orders the work. An effect is added only when (1) refitting
with it lowers the output error on *validation* trials (held back from this fit, and distinct
from the reported held-out trials) by more than ``min_gain`` relative, and (2) one of its
evidence parameters is at least ``min_sigma`` standard errors from its "off" value, with σ corrected for
the residual's autocorrelation (fit.py) and the threshold raised for effects whose shape was
searched on a grid (:func:`required_sigma`). Both are needed: a better validation score alone can
be luck on few trials, and significance alone follows from having thousands of samples. On
data without the effect neither holds, so nothing is claimed.
"""

from __future__ import annotations

import math
from statistics import NormalDist
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from admittance.ident.fit import FitResult, Progress, fit_initial_states, fit_output_error, normal_equations
from admittance.ident.model import EFFECTS, INDEX, LOWER, UPPER, Simulator, default_vector
from admittance.ident.residual import WHITE_P, ljung_box, noise_estimate

STRIBECK_VELOCITIES = (0.03, 0.1, 0.3, 1.0)  # rad/s
COGGING_PERIODS = tuple(range(2, 33))  # cycles/rev: 1 would be gravity itself
MIN_EXPLAINED = 0.002  # below this fraction of the residual a refit is not worth its time
# Shape parameters are held at their grid values for a first refit, then freed: fitted free
# from the base model's optimum, a Stribeck velocity runs to its bound (a pure breakaway level
# is a nearby local optimum), while with the shape fixed the rest is nearly linear.
SHAPE_PARAMS = {"stribeck": ("stribeck_velocity",), "cogging": ("cogging_period",)}
SHAPE_STARTS = 3  # best variants (by explained fraction) refitted with their shape fixed
NOISE_RATIO = 1.1  # RMSE within this factor of the noise estimate: at the noise floor
TIE = 0.02  # validation RMSEs within 2 % are a tie
PREFERENCE = ("angle_offset", "torque_bias", "torque_gain", "time_delay", "asymmetric_coulomb", "quadratic_drag",
              "load_dependent_coulomb", "stribeck", "cogging")
OPTIONAL_PARAMS = ("torque_drift",)  # kept only when significant on their own
RANK_RESOLUTION = 0.01  # explained fractions closer than this rank as equal


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
    params: tuple[str, ...] = ()  # what the refit frees; empty: all of the effect's parameters


@dataclass
class Evidence:
    """What the ranking and the admission test found for one candidate effect."""

    effect: str
    variant: str = ""
    explained: float = 0.0  # fraction of the residual sum of squares
    plausible: bool = True
    params: tuple[str, ...] = ()  # the parameters this variant frees
    start: dict[str, float] = field(default_factory=dict)
    alternatives: list[dict[str, float]] = field(default_factory=list)  # other variants' starts
    # Per trial, the part of the residual the candidate's linearised columns explain (rad):
    # what the report plots against the residual.
    signature: list[np.ndarray] = field(default_factory=list, repr=False)
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
        "torque_gain": ("torque_gain", 1e-2),
    }
    if effect == "torque_bias":
        bias = Column((), "torque_bias", torque_step)
        drift = Column((), "torque_drift", 1e-4 * torque_scale)
        return [Variant(effect, "offset", (bias,), params=("torque_bias",)),
                Variant(effect, "offset and drift", (bias, drift))]
    param, step = steps[effect]
    return [Variant(effect, param, (Column((), param, step),))]


def candidate_effects(present: Sequence[str], with_tau: bool, mode: str = "geometry") -> list[str]:
    """The effects not yet in the model that the data can show: torque corrections need a
    measured torque, and a torque gain needs geometry (lumped mode fits it as κ)."""
    return [name for name, e in EFFECTS.items() if name not in present and (with_tau or not e.needs_torque)
            and (mode == "geometry" or not e.geometry_only)]


def rank_candidates(sim: Simulator, fit: FitResult, candidates: Sequence[str], torque_scale: float) -> list[Evidence]:
    """Explained fraction of each candidate (best variant), highest first, from one batch."""
    sim = sim.with_tau_scale(fit.tau_scale)
    probes = [v for name in candidates for v in variants(name, torque_scale)]
    columns = [c for v in probes for c in v.columns]
    if not columns or not fit.jacobian:
        return []
    sens = _sensitivities(sim, fit, columns)
    total = sum(float(r @ r) for r in fit.residuals)
    base_explained, _, base_change = _explained(fit.jacobian, [], fit.residuals, len(fit.free))
    found: dict[str, list[Evidence]] = {}
    offset = 0
    for variant in probes:
        n_c = len(variant.columns)
        cols = [s[offset : offset + n_c] for s in sens]
        offset += n_c
        explained, coef, change = _explained(fit.jacobian, cols, fit.residuals, len(fit.free))
        evidence = _evidence(variant, coef, (explained - base_explained) / max(total, 1e-300))
        # What the candidate takes out of the residual beyond a refit of what is already there.
        evidence.signature = [b0 - c for c, b0 in zip(change, base_change)]
        found.setdefault(variant.effect, []).append(evidence)
    best = []
    for options in found.values():
        # The simplest variant unless a richer one explains clearly more (drift beyond offset).
        options.sort(key=lambda e: (round(e.explained / RANK_RESOLUTION), -len(e.params)), reverse=True)
        options[0].alternatives = [e.start for e in options[1:SHAPE_STARTS] if e.plausible]
        best.append(options[0])
    return sorted(best, key=lambda e: e.explained, reverse=True)


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
    """A Gauss–Newton step over [globals, extra, x0]: the sum of squares it removes, the extra
    columns' coefficients, and per trial the predicted change of the simulated angle."""
    n_x = 0 if not extra else extra[0].shape[0]
    blocks = [np.vstack([jk[:n_g], ek, jk[n_g:]]) if n_x else jk for jk, ek in zip(jac, extra or [None] * len(jac))]
    n_shared = n_g + n_x
    with_x0 = blocks[0].shape[0] > n_shared
    a, b = normal_equations(blocks, residuals, n_shared, fit_x0=with_x0)
    scale = np.sqrt(np.maximum(np.diag(a), 1e-300))
    delta = -np.linalg.lstsq(a / np.outer(scale, scale), b / scale, rcond=1e-10)[0] / scale
    change = []
    for k, block in enumerate(blocks):
        own = delta[n_shared + 2 * k : n_shared + 2 * k + 2] if with_x0 else np.zeros(0)
        change.append(block[:n_shared].T @ delta[:n_shared] + block[n_shared:].T @ own)
    return float(-b @ delta), delta[n_g:n_shared], change


def _evidence(variant: Variant, coef: np.ndarray, explained: float) -> Evidence:
    start = dict(variant.shape)
    plausible = True
    if variant.effect == "cogging":
        a, b = coef
        start.update(cogging_amplitude=float(math.hypot(a, b)), cogging_phase=float(math.atan2(b, a)))
    else:
        defaults = default_vector()
        for col, value in zip(variant.columns, coef):
            start[col.param] = float(defaults[INDEX[col.param]] + value)  # the step from "off"
        positive = {"stribeck_torque", "load_coulomb", "quadratic_drag", "time_delay", "torque_gain"}
        plausible = all(start[c.param] > 0 for c in variant.columns if c.param in positive)
    return Evidence(
        effect=variant.effect,
        variant=variant.label,
        explained=max(explained, 0.0) if plausible else 0.0,
        plausible=plausible,
        params=variant.params or EFFECTS[variant.effect].params,
        start=start,
    )


@dataclass
class SearchSettings:
    max_effects: int = 4
    min_gain: float = 0.03  # relative validation-RMSE improvement
    min_sigma: float = 3.0
    top_k: int = 8  # candidates refitted per round (all of them: the linear ranking is only a guide)


@dataclass
class SearchOutcome:
    effects: list[str]
    fit: FitResult  # the fit (on the fitting split) with the admitted effects; fit.free says what is free
    rounds: list[list[Evidence]]
    validation_rmse: list[float]  # before any effect, then after each admitted (or removed) one
    removed: list[str] = field(default_factory=list)  # admitted, then made redundant by a later one


def score(sim: Simulator, fit: FitResult, x0: np.ndarray, progress: Progress | None = None) -> FitResult:
    """Output error of trials the model was not fitted on: only their initial states are fitted."""
    return fit_initial_states(sim, fit.vector, x0, tau_scale=fit.tau_scale, progress=progress, label="scoring")


def search_effects(
    fit_sim: Simulator,
    val_sim: Simulator,
    base: FitResult,
    val_x0: np.ndarray,
    torque_scale: float,
    settings: SearchSettings,
    progress: Progress | None = None,
) -> SearchOutcome:
    """Greedy forward selection on the fitting split, judged on the validation split."""
    with_tau = any(tr.tau is not None for tr in fit_sim.trials)
    effects: list[str] = []
    removed: list[str] = []
    current = base
    val_rmse = [score(val_sim, current, val_x0).rmse]
    rounds: list[list[Evidence]] = []
    while len(effects) < settings.max_effects and not nothing_left(current):
        candidates = candidate_effects(effects + removed, with_tau, fit_sim.mode)
        ranking = rank_candidates(fit_sim, current, candidates, torque_scale)
        rounds.append(ranking)
        results = []
        for evidence in _worth_trying(ranking, current, settings.top_k):
            if progress:
                progress(f"trying {evidence.effect} ({evidence.variant})")
            refit, val = _try_effect(fit_sim, val_sim, current, evidence, val_x0, torque_scale, val_rmse[-1],
                                     settings)
            if evidence.accepted:
                results.append((evidence, refit, val))
        if not results:
            break
        chosen, current, val = _choose(results)
        effects.append(chosen.effect)
        val_rmse.append(val)
        for dropped in _redundant(fit_sim, val_sim, current, effects, val_x0, torque_scale, settings, progress):
            evidence, current, val = dropped
            rounds[-1].append(evidence)
            effects.remove(evidence.effect)
            removed.append(evidence.effect)
            val_rmse.append(val)
    return SearchOutcome(effects, current, rounds, val_rmse, removed)


def _redundant(fit_sim, val_sim, current: FitResult, effects: list[str], val_x0, torque_scale: float,
               settings: SearchSettings, progress):
    """Backward step: an earlier effect the newest one made unnecessary (at most one per round).

    Effects can stand in for each other: a fine cogging ripple near the rest position acts like
    breakaway friction, and on one synthetic Stribeck set it was admitted first; Stribeck came
    next and explained what cogging had. Each earlier effect is dropped in turn; when the model
    without it is no worse on validation than ``min_gain``, it goes (and is not tried again)."""
    if len(effects) < 2:
        return []
    val_now = score(val_sim, current, val_x0).rmse
    for effect in effects[:-1]:
        if progress:
            progress(f"checking {effect} is still needed")
        params = EFFECTS[effect].params
        vector = switched_off(current.vector, params)
        free = tuple(n for n in current.free if n not in params)
        without = fit_output_error(fit_sim.with_tau_scale(current.tau_scale), vector, free, current.x0,
                                   torque_scale=torque_scale, label=f"fit -{effect}")
        val = score(val_sim, without, val_x0).rmse
        if val <= val_now * (1.0 + settings.min_gain):
            note = Evidence(effect, variant="removed", accepted=False, validation_gain=float(1.0 - val / val_now),
                            reason=f"removed: {effects[-1]} explains it (validation without it within "
                                   f"{100 * settings.min_gain:.0f} %)")
            return [(note, without, val)]
    return []


def nothing_left(fit: FitResult) -> bool:
    """True when the residual is white and at the noise level: there is nothing to explain, and
    any effect "found" would be fitted noise."""
    _, p_white = ljung_box(fit.residuals)
    noise = noise_estimate(fit.residuals)
    return p_white > WHITE_P and noise > 0 and fit.rmse < NOISE_RATIO * noise


def _worth_trying(ranking: list[Evidence], current: FitResult, top_k: int) -> list[Evidence]:
    """The top candidates by explained fraction, plus Stribeck when its linear test failed.

    The base fit absorbs breakaway friction into a higher Coulomb level, so at the base optimum
    adding a Stribeck term looks harmful or useless to first order (the "wrong sign", or a tiny
    explained fraction) although the two together fit far better. It is then tried from a start
    that keeps the static level: Coulomb 0.7·F plus Stribeck 0.3·F."""
    tried = [e for e in ranking if e.plausible and e.explained >= MIN_EXPLAINED][:top_k]
    for evidence in ranking:
        if evidence.effect == "stribeck" and all(evidence is not e for e in tried):
            level = current.value("coulomb")
            starts = [{"stribeck_velocity": v, "stribeck_torque": 0.3 * level, "coulomb": 0.7 * level}
                      for v in STRIBECK_VELOCITIES]
            evidence.start, evidence.alternatives = starts[1], [starts[0], starts[2]]
            evidence.variant = "static level kept"
            tried.append(evidence)
    tried_ids = {id(e) for e in tried}
    for evidence in ranking:
        if id(evidence) not in tried_ids:
            evidence.reason = "explains too little of the residual" if evidence.plausible else "wrong sign"
    return tried


def _choose(results: list[tuple[Evidence, FitResult, float]]) -> tuple[Evidence, FitResult, float]:
    """The best validation RMSE; candidates within TIE of it count as equal, and among those the
    one with fewest parameters wins, then the better score. Effects can act alike (a Stribeck
    term with a large velocity and more damping mimics quadratic drag; a torque bias and an
    asymmetric Coulomb level look the same on driven trials), and a flexible effect should not
    win on noise. Some pairs are not just alike but the same equation: on driven trials a
    constant torque bias b and an asymmetric Coulomb level a = b give identical motion under the
    stick law (moving: −F·sgn ω − b either way; at rest: the same breakaway thresholds). Data
    cannot choose there, so PREFERENCE does: measurement errors (offset, bias, delay) first,
    being the commoner cause, then friction terms, the most flexible (cogging) last."""
    best_rmse = min(r[2] for r in results)
    close = [r for r in results if r[2] <= best_rmse * (1.0 + TIE)]
    chosen = min(close, key=lambda r: (len(r[0].params), PREFERENCE.index(r[0].effect), r[2]))
    for evidence, _, val in results:
        if evidence is not chosen[0]:
            evidence.accepted = False
            tied = " (a tie)" if val <= best_rmse * (1.0 + TIE) else ""
            evidence.reason = f"qualified, but {chosen[0].effect} was preferred{tied}"
    return chosen


def refit_with(sim: Simulator, current: FitResult, evidence: Evidence, torque_scale: float) -> FitResult:
    """Fit the current model plus ``evidence``'s parameters from its start values; shape
    parameters go through their grid first (see SHAPE_PARAMS)."""
    free = (*current.free, *[p for p in evidence.params if p not in current.free])
    sim = sim.with_tau_scale(current.tau_scale)
    shape = SHAPE_PARAMS.get(evidence.effect, ())
    starts = [evidence.start, *evidence.alternatives] if shape else [evidence.start, grown(evidence.start,
                                                                                          [evidence.effect])]
    best = None
    for start in starts:
        vector = current.vector.copy()
        for name, value in start.items():
            vector[INDEX[name]] = value
        held = [n for n in free if n not in shape]
        fit = fit_output_error(sim, _clip_start(vector, free), held, current.x0, torque_scale=torque_scale,
                               label=f"fit +{evidence.effect}")
        if best is None or fit.rmse < best.rmse:
            best = fit
    if not shape:
        return best
    return fit_output_error(sim, best.vector, free, best.x0, torque_scale=torque_scale,
                            label=f"fit +{evidence.effect}")


def grown(values: dict[str, float], effects: Sequence[str]) -> dict[str, float]:
    """``values`` with the evidence parameters of ``effects`` doubled (their distance from "off",
    for a gain the distance from 1): a second start.

    With stick friction the cost is piecewise smooth, and a refit can stop where the new effect
    is only half grown while the base parameters still compensate (seen with load-dependent
    Coulomb: the effect at half its size, the inertia 7 % high, the validation gain below the
    bar). A restart from twice the linearised size is cheap insurance; the lower cost wins."""
    out = dict(values)
    defaults = default_vector()
    for effect in effects:
        for name in EFFECTS[effect].evidence:
            if name in out:
                off = defaults[INDEX[name]]
                out[name] = float(off + 2.0 * (out[name] - off))
    return out


def _without_weak_optional(sim: Simulator, current: FitResult, refit: FitResult, evidence: Evidence,
                           min_sigma: float, torque_scale: float) -> FitResult:
    """Refit without an optional parameter (a torque drift beside the bias) that is not
    significant, so the simpler variant competes with its true parameter count."""
    weak = [n for n in evidence.params if n in OPTIONAL_PARAMS
            and abs(refit.value(n)) < min_sigma * refit.sigma.get(n, math.inf)]
    if not weak:
        return refit
    evidence.params = tuple(n for n in evidence.params if n not in weak)
    evidence.variant += f" (without {', '.join(weak)}: not significant)"
    free = tuple(n for n in refit.free if n not in weak)
    sim = sim.with_tau_scale(refit.tau_scale)
    # Two starts: the values found with the optional parameter, and the model before the effect.
    # A weak drift can drag its bias far from the bias's own optimum (the two cancel over a
    # trial), and from there the refit without the drift can stall in a local minimum.
    starts = [(switched_off(refit.vector, weak), refit.x0), (current.vector, current.x0)]
    fits = [fit_output_error(sim, vector, free, x0, torque_scale=torque_scale, label=f"fit +{evidence.effect}")
            for vector, x0 in starts]
    return min(fits, key=lambda fit: fit.rmse)


def switched_off(vector: np.ndarray, names: Sequence[str]) -> np.ndarray:
    """``vector`` with the parameters ``names`` back at their "off" value (their default)."""
    defaults = default_vector()
    out = vector.copy()
    for name in names:
        out[INDEX[name]] = defaults[INDEX[name]]
    return out


def _try_effect(fit_sim, val_sim, current, evidence, val_x0, torque_scale, val_before,
                settings: SearchSettings) -> tuple[FitResult, float]:
    refit = refit_with(fit_sim, current, evidence, torque_scale)
    refit = _without_weak_optional(fit_sim, current, refit, evidence, settings.min_sigma, torque_scale)
    val = score(val_sim, refit, val_x0).rmse
    evidence.validation_gain = float(1.0 - val / val_before) if val_before > 0 else 0.0
    main = EFFECTS[evidence.effect].evidence
    evidence.values = {n: (refit.value(n), refit.sigma.get(n, math.nan)) for n in evidence.params}
    evidence.significance = significance(refit, [n for n in main if n in evidence.params])
    gain_ok = evidence.validation_gain > settings.min_gain
    needed = required_sigma(settings.min_sigma, len(variants(evidence.effect, torque_scale)))
    sig_ok = evidence.significance >= needed
    evidence.accepted = gain_ok and sig_ok
    if evidence.accepted:
        evidence.reason = "validation improved and the parameter is significant"
    elif not gain_ok:
        evidence.reason = f"validation gain {100 * evidence.validation_gain:.1f} % ≤ {100 * settings.min_gain:.0f} %"
    else:
        evidence.reason = f"parameter only {evidence.significance:.1f} σ from its off value (needs {needed:.1f} σ)"
    return refit, val


def significance(fit: FitResult, names: Sequence[str]) -> float:
    """The largest distance, in σ, of any of ``names`` from its "off" value (its default)."""
    defaults = default_vector()
    return float(max(abs(fit.value(n) - defaults[INDEX[n]]) / max(fit.sigma.get(n, math.inf), 1e-300)
                     for n in names))


def required_sigma(min_sigma: float, looks: int) -> float:
    """The significance an effect needs after searching ``looks`` grid variants for it.

    Picking the best of many variants (31 cogging periods) finds a large-looking value in noise
    more easily than a single look does (the look-elsewhere effect), so the two-sided tail
    probability of ``min_sigma`` is shared among the looks (Bonferroni): 3 σ for one look,
    3.4 σ for the 4 Stribeck velocities, 3.9 σ for the 31 cogging periods."""
    normal = NormalDist()
    tail = 2.0 * (1.0 - normal.cdf(min_sigma)) / max(looks, 1)
    return normal.inv_cdf(1.0 - tail / 2.0)


def _clip_start(vector: np.ndarray, free: Sequence[str]) -> np.ndarray:
    out = vector.copy()
    for name in free:
        if name in INDEX:
            out[INDEX[name]] = min(max(out[INDEX[name]], LOWER.get(name, -np.inf)), UPPER.get(name, np.inf))
    return out

