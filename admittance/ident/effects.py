"""The candidate effects: how each is probed, ranked, refitted and checked for physical sense.

**Ranking (a score test).** At the current fit, each candidate's parameter sits at its "off"
value (its Contract 1 default: 0, or 1 for ``torque_gain``). The linearised effect of
switching it on is the sensitivity column ∂θ/∂p, by finite difference. Least squares of the
residual on [current Jacobian | candidate columns] tells how much of the residual's sum of
squares the candidate could remove *beyond what refitting the current parameters and initial
states already can*: the explained fraction. Every candidate's columns come from ONE batch
simulation at the current fit. Nonlinear shape parameters get a small grid of variants
(Stribeck velocity; cogging period, a whole number of cycles per revolution, whose amplitude
and phase become two linear columns, the sin and cos of period·θ).

**The ranking only orders the work.** Every candidate is refitted, whatever its linear test
said: from its linearised size (when that has the right sign), from twice that size, and,
unless those already reach the sensor's noise, from *fallback* starts that do not depend on
the current fit at all: an equation-error fit with the effect's own column beside the base
model's (equation_error.effect_start), and starts of a typical size (the base fit can absorb
an effect so well that, to first order, adding it looks harmful: a quadratic drag set once
ranked drag "wrong sign", and its fit never ran).

**Physical sense** (:func:`physical_problems`): a refit whose effect parameter ran to a bound,
that collapses the inertia onto its bound, or that makes a friction level negative in one
direction is not a physical explanation, whatever it does to the error. The cogging period is
held on its integer grid: a ripple periodic in the joint angle repeats a whole number of times
per revolution, and a free period (6.26, 4.10, 3.21 per revolution…) is a curve fit to
whatever the residual holds; a best period at either end of the grid is a fit running to a
bound, and refused as such. Admission itself (cross-validated gain, significance, stability
across folds) is in search.py.
"""

from __future__ import annotations

import enum
import math
from statistics import NormalDist
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from admittance.errors import DataError
from admittance.ident.equation_error import effect_start, fit_equation_error
from admittance.ident.fit import (
    FitResult,
    chord_slopes,
    closest_starts,
    fit_output_error,
    normal_equations,
    states_again,
)
from admittance.ident.model import EFFECTS, INDEX, LOWER, UPPER, Simulator, default_vector

STRIBECK_VELOCITIES = (0.03, 0.1, 0.3, 1.0)  # rad/s
COGGING_PERIODS = tuple(range(2, 33))  # whole cycles/rev: 1 would be gravity itself
# Shape parameters are held at their grid values for a first refit. A Stribeck velocity is then
# freed (fitted free from the base model's optimum it runs to its bound: a pure breakaway level
# is a nearby local optimum, while with the shape fixed the rest is nearly linear); a cogging
# period never is (a whole number per revolution, see the module doc).
SHAPE_PARAMS = {"stribeck": ("stribeck_velocity",), "cogging": ("cogging_period",),
                "friction_ripple": ("friction_ripple_period",)}
# Effects whose amplitude and phase are two linear columns (sin and cos) at each grid period.
PERIODIC = {"cogging": ("cogging_amplitude", "cogging_phase", "cogging_period"),
            "friction_ripple": ("friction_ripple_amplitude", "friction_ripple_phase", "friction_ripple_period")}
SPRING_PROBE_NEUTRAL = 1.0  # rad: the second spring column (neutral 0 and 1 give k and k·neutral)
FREED_SHAPES = ("stribeck_velocity",)
SHAPE_GRIDS = {"stribeck_velocity": STRIBECK_VELOCITIES}  # a freed shape's grid (_freed_from_the_grid)
SHAPE_STARTS = 3  # best variants (by explained fraction) refitted with their shape fixed
OPTIONAL_PARAMS = ("torque_drift",)  # kept only when significant on their own
RANK_RESOLUTION = 0.01  # explained fractions closer than this rank as equal
BOUND_TOLERANCE = 1e-6  # relative: a value this close to a bound sits on it
EXPLORE_ITERATIONS = 12  # LM iterations per start before the best ones are carried on to convergence
FINISHED_STARTS = 2


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


class StandIn(enum.Enum):
    """Why an admitted effect is a stand-in (helps predict, not claimed as the effect)."""

    REGIMES = "not one model across the operating regimes"  # regime.regime_inconsistency said so
    BESIDE = "judged beside a stand-in"  # search.BESIDE_REASON
    FLEXIBLE = "a periodic term that leaves more than sensor noise"  # search.FLEXIBLE_REASON


@dataclass
class Evidence:
    """What the ranking, the refit and the admission tests found for one candidate effect."""

    effect: str
    variant: str = ""
    explained: float = 0.0  # fraction of the residual sum of squares (linearised)
    plausible: bool = True  # the linearised coefficient has the effect's sign
    params: tuple[str, ...] = ()  # the parameters this variant frees
    start: dict[str, float] = field(default_factory=dict)
    alternatives: list[dict[str, float]] = field(default_factory=list)  # other variants' starts
    # Per trial, the part of the residual the candidate's linearised columns explain (rad):
    # what the report plots against the residual.
    signature: list[np.ndarray] = field(default_factory=list, repr=False)
    start_used: str = ""  # which start the refit kept: linearised, grown or fallback
    training_gain: float | None = None  # relative drop of the training RMSE
    significance: float | None = None  # |value| / σ of the best evidence parameter
    required_sigma: float | None = None
    values: dict[str, tuple[float, float]] = field(default_factory=dict)  # name -> (value, σ)
    problems: list[str] = field(default_factory=list)  # physical inconsistencies of the refit
    crossval: dict | None = None  # search.PairedGain.as_dict() of the cross-validated comparison
    fold_values: list[dict[str, float]] = field(default_factory=list)  # evidence params per fold
    regimes: list[dict] = field(default_factory=list)  # evidence params per operating regime
    stand_in: bool = False  # passed every test but regime consistency: helps, but is not the effect
    stand_in_why: StandIn | None = None  # set with an admitted stand-in: what later evidence may lift
    accepted: bool = False
    reason: str = ""

    @property
    def validation_gain(self) -> float | None:
        """The pooled cross-validated gain (None when the candidate never reached cross-validation)."""
        return None if self.crossval is None else self.crossval["pooled_gain"]

    def as_dict(self) -> dict:
        return {
            "effect": self.effect,
            "variant": self.variant,
            "explained_fraction": self.explained,
            "plausible": self.plausible,
            "start": self.start_used,
            "training_gain": self.training_gain,
            "validation_gain": self.validation_gain,
            "crossval": self.crossval,
            "significance_sigma": self.significance,
            "required_sigma": self.required_sigma,
            "params": {k: {"value": v, "sigma": s} for k, (v, s) in self.values.items()},
            "fold_values": self.fold_values,
            "regimes": self.regimes,
            "stand_in": self.stand_in,
            "problems": self.problems,
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
    if effect in PERIODIC:
        amplitude, phase, period_name = PERIODIC[effect]
        out = []
        for period in COGGING_PERIODS:
            sin_col = Column(((period_name, period), (phase, 0.0)), amplitude, torque_step)
            cos_col = Column(((period_name, period), (phase, math.pi / 2)), amplitude, torque_step)
            out.append(Variant(effect, f"period {period}/rev", (sin_col, cos_col), ((period_name, period),),
                               params=(amplitude, phase)))
        return out
    if effect == "spring":
        step = 1e-2 * torque_scale
        return [Variant(effect, "stiffness and neutral angle",
                        (Column((("spring_neutral", 0.0),), "spring_stiffness", step),
                         Column((("spring_neutral", SPRING_PROBE_NEUTRAL),), "spring_stiffness", step)))]
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
    return [chord_slopes(s, r + m, steps) for s, r, m in zip(sims, fit.residuals, sim.measured)]


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
    if variant.effect in PERIODIC:
        amplitude, phase, _ = PERIODIC[variant.effect]
        a, b = coef
        start.update({amplitude: float(math.hypot(a, b)), phase: float(math.atan2(b, a))})
    elif variant.effect == "spring":
        # −k0·θ and −k1·(θ − N) add up to −(k0 + k1)·(θ − k1·N/(k0 + k1)).
        k0, k1 = coef
        stiffness = float(k0 + k1)
        plausible = stiffness > 0
        start.update(spring_stiffness=stiffness,
                     spring_neutral=float(k1 * SPRING_PROBE_NEUTRAL / stiffness) if plausible else 0.0)
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


def explore_linearised(sim: Simulator, current: FitResult, evidence: Evidence, torque_scale: float,
                       x0_starts: Sequence[np.ndarray] = (), iterations: int = EXPLORE_ITERATIONS) -> list[list]:
    """The first stage of :func:`refit_candidate`: its starts from the linear test (the
    linearised size and twice it, or the next grid variants of a shape effect), each after
    ``iterations`` LM iterations (:func:`explore_further` carries them on to
    :data:`EXPLORE_ITERATIONS`); [] when the linear test gave the wrong sign."""
    sim = sim.with_tau_scale(current.tau_scale)
    starts: list[tuple[str, dict[str, float]]] = []
    if evidence.plausible:
        starts.append(("linearised", evidence.start))
        if SHAPE_PARAMS.get(evidence.effect, ()):
            starts += [("linearised (next grid variant)", alt) for alt in evidence.alternatives]
        else:
            starts.append(("grown", grown(evidence.start, [evidence.effect])))
    return _explore(sim, current, evidence, starts, torque_scale, x0_starts, iterations)


def explore_further(sim: Simulator, explored: list[list], torque_scale: float, iterations: int, label: str) -> None:
    """Carry every unfinished ``[fit, label, finished]`` entry on by ``iterations`` more LM
    iterations, in place: from the entry's values and its LM damping, the same steps one longer
    fit would have taken (its residuals handed on: not simulated again)."""
    for entry in explored:
        if entry[2]:
            continue
        fit = entry[0]
        entry[0] = fit_output_error(sim.with_tau_scale(fit.tau_scale), fit.vector, fit.free, fit.x0,
                                    torque_scale=torque_scale, max_iter=iterations, label=label, damping=fit.damping,
                                    residuals=fit.residuals, known=fit.end_point)
        entry[2] = entry[0].iterations < iterations


def linearised_reach(explored: Sequence[list]) -> float:
    """The lowest training mean square (rad²) that the undamped Gauss–Newton step of any explored
    start predicts from where it stands (inf without a start): the local linear model's own
    minimum, free of bounds, so no higher than what a bounded step of that model can reach."""
    best = math.inf
    for entry in explored:
        fit = entry[0]
        cost = sum(float(r @ r) for r in fit.residuals)
        gain = _explained(fit.jacobian, [], fit.residuals, len(fit.free))[0] if fit.jacobian else 0.0
        best = min(best, max(cost - max(gain, 0.0), 0.0) / max(sum(r.size for r in fit.residuals), 1))
    return best


def refit_candidate(sim: Simulator, current: FitResult, evidence: Evidence, torque_scale: float,
                    scales: dict[str, float], done, whole_trials=None, fallbacks: bool = True,
                    x0_starts: Sequence[np.ndarray] = (), explored: list[list] | None = None) -> FitResult | None:
    """Fit the current model plus ``evidence``'s parameters; keep the best of its starts.

    Starts: the linearised size (and twice it, or the next-best grid variants for a shape
    effect) when the linear test gave the effect's sign; then the fallback starts of
    :func:`fallback_starts`, unless the best refit so far already leaves nothing but sensor
    noise (``done(fit)``). ``whole_trials`` (default: the simulator's) feed the equation error:
    time segments near rest are too short and too still for derivatives. A refit from the linearised size can stop half way, with the base
    parameters still compensating in a wrong basin (a quadratic drag on three long swings
    stopped at 6 mrad that way, against 2 mrad from a start that moved damping into drag).
    ``fallbacks=False`` skips them (another candidate already leaves nothing but noise: this
    one can at best tie, which its linearised refit shows); None when nothing was refitted.
    A refit that still leaves structure (fallbacks wanted) then restarts a freed shape from its
    grid (:func:`_freed_from_the_grid`) and gets its units' initial states fitted again
    (:func:`_initial_states_again`).
    ``explored``: the result of :func:`explore_linearised` when the caller already ran it."""
    sim = sim.with_tau_scale(current.tau_scale)
    shape = SHAPE_PARAMS.get(evidence.effect, ())
    if explored is None:
        explored = explore_linearised(sim, current, evidence, torque_scale, x0_starts)
    # With fallbacks to come, the linearised starts are first carried only EXPLORE_ITERATIONS
    # further: one that crawls far from the floor stays there while the fallbacks are explored,
    # and the best of all is carried on below. (On 30 drops with a Stribeck term the linearised
    # start crawled 60 iterations, 11,800 trial simulations, to 14.4 mrad; a fallback start then
    # reached the 2 mrad floor in 8.)
    best, label = _settle(sim, explored, torque_scale, evidence, done,
                          iterations=EXPLORE_ITERATIONS if fallbacks else None)
    if best is not None and done(best):
        best, label = _settle(sim, explored, torque_scale, evidence, done)
    elif fallbacks:
        fallback = [("fallback", s) for s in fallback_starts(evidence, current, scales)]
        fallback[:0] = [("sliding friction from the equation error", s)
                        for s in sliding_starts(whole_trials or sim.trials, sim.mode, evidence, current)]
        for linear in _equation_error_starts(whole_trials or sim.trials, sim.mode, evidence):
            fallback.insert(0, ("equation error with the effect", linear))
        explored += _explore(sim, current, evidence, fallback, torque_scale, x0_starts)
        best, label = _settle(sim, explored, torque_scale, evidence, done)
    if best is None:
        return None
    evidence.start_used = label
    freed = [n for n in shape if n in FREED_SHAPES]
    if freed:
        best = fit_output_error(sim, best.vector, _free_for(current, evidence, held=()), best.x0,
                                torque_scale=torque_scale, label=f"fit +{evidence.effect}")
    # The shape first, then the units' states: in the other order the states refitted at a stuck
    # velocity moved the start of every velocity restart, and the 30-trial Stribeck row of the
    # families stayed stuck under the libm sine (bench/identify_perturbed.py: 40 of 41 rows,
    # 41 of 41 in this order, under both sines).
    if fallbacks and freed and not done(best):
        best = _freed_from_the_grid(sim, best, evidence, best.free, torque_scale)
    if fallbacks and not done(best):
        best = _initial_states_again(sim, best, evidence, x0_starts, torque_scale)
    return best


def _initial_states_again(sim, fit: FitResult, evidence: Evidence, x0_starts: Sequence[np.ndarray],
                          torque_scale: float) -> FitResult:
    """A refit that still leaves structure, its units' initial states fitted again under its own
    parameters, from its states and from the data's candidates screened under it (each unit
    keeping its best, as the final fit does); the joint fit carried on from there, and kept
    when it fits better.

    A unit whose start the refit carried into a wrong basin (its swing sticking at another
    turning point) stays there: the joint LM moves all parameters together and cannot jump one
    unit's stick event. On 3 long swings with a quadratic drag (tests/test_ident_honest.py's
    set, cut into 12 units) the drag's refit ended at 4.0 mrad, 11 of its units at the 2 mrad
    noise and one at 11.9, with the plant's sine from the libm crate (glibc's reached the
    noise); the regime test then called the drag a stand-in."""
    if not len(x0_starts):
        return fit
    x0 = states_again(sim, fit.vector, fit.x0, x0_starts, label=f"fit +{evidence.effect}")
    if np.array_equal(x0, fit.x0):
        return fit
    again = fit_output_error(sim, fit.vector, fit.free, x0, torque_scale=torque_scale, label=f"fit +{evidence.effect}")
    return again if again.rmse < fit.rmse else fit


def _freed_from_the_grid(sim, fit: FitResult, evidence: Evidence, free, torque_scale: float) -> FitResult:
    """A freed shape's refit that still leaves structure, restarted with the shape at each other
    value of its grid (the rest where it ended); the best of them all.

    With stick friction the error is rough in a Stribeck velocity: each value decides at which
    turning points the drops stick. On 30 test-oracle drops with Stribeck at 1.5× the Coulomb
    level (bench/identify_families.py's regime row, seed 1) the refit freed from 0.1 rad/s ended
    at 0.123 and 2.41 mrad with the plant's sine from the libm crate (tried, not landed:
    docs/identification-speed-log.md) and at the truth's 0.144 and the 2.0 mrad noise with
    glibc's; from the stuck end, 0.3 rad/s reached 0.140 and 2.0 mrad, while 0.055, 0.071, 0.17
    and 0.21 (half steps of the grid) ended at 2.1-2.7 mrad. Only a fit short of the noise floor
    pays for this."""
    best = fit
    for name in (n for n in SHAPE_PARAMS[evidence.effect] if n in FREED_SHAPES):
        for value in SHAPE_GRIDS[name]:
            if value == fit.value(name):
                continue
            vector = fit.vector.copy()
            vector[INDEX[name]] = value
            again = fit_output_error(sim, vector, free, fit.x0, torque_scale=torque_scale,
                                     label=f"fit +{evidence.effect} ({name} from {value:g})")
            if again.rmse < best.rmse:
                best = again
    return best


def _equation_error_starts(trials, mode: str, evidence: Evidence) -> list[dict[str, float]]:
    """Equation-error starts with the effect's columns: one, or for a periodic effect the
    :data:`SHAPE_STARTS` periods whose regression fits best. (The output-error ranking's best
    period is not always the true one: 5/rev for a 6/rev friction ripple; the equation error
    costs a millisecond per period, so every period is tried.)"""
    if evidence.effect not in PERIODIC:
        shape = {k: v for k, v in evidence.start.items() if k in SHAPE_PARAMS.get(evidence.effect, ())}
        start = effect_start(trials, mode, evidence.effect, shape)
        return [start] if start is not None else []
    period_name = PERIODIC[evidence.effect][2]
    scored = [effect_start(trials, mode, evidence.effect, {period_name: float(p)}, with_cost=True)
              for p in COGGING_PERIODS]
    ranked = sorted((cost, i) for i, (start, cost) in enumerate(scored) if start is not None)
    return [scored[i][0] for _, i in ranked[:SHAPE_STARTS]]


def sliding_starts(trials, mode: str, evidence: Evidence, current: FitResult) -> list[dict[str, float]]:
    """Stribeck starts that split the current static level into sliding friction and breakaway.

    The equation error regresses on the sliding samples only (it leaves out those near zero
    speed), so its damping and Coulomb level are the sliding friction; the base fit's Coulomb
    level is what holds the drops where they stick (base.py's starts held at rest). The surplus
    of the second over the first is the breakaway a Stribeck term adds at low speed. The
    fallback start (30 % of the level moved into Stribeck, the damping kept) leaves the base
    fit's damping, which the missing breakaway had pushed to ~0: on the test oracle's drops
    with Stribeck at 1.5× the Coulomb level (4096-tick encoder, seeds 1–6) it stalled at
    4–12 mrad in 3 of 6; from these starts every seed's refit reached 0.2–0.9 mrad. The effect's
    own equation-error column cannot give this: exp(−(ω/v_s)²) vanishes on the sliding samples."""
    if evidence.effect != "stribeck":
        return []
    try:
        sliding, _ = fit_equation_error(trials, mode)
    except DataError:
        return []
    surplus = current.value("coulomb") - sliding[INDEX["coulomb"]]
    if surplus <= 0:
        return []
    return [{"stribeck_velocity": v, "stribeck_torque": surplus, "coulomb": float(sliding[INDEX["coulomb"]]),
             "damping": float(sliding[INDEX["damping"]])} for v in STRIBECK_VELOCITIES[1:]]


def _explore(sim, current, evidence, starts, torque_scale, x0_starts=(), iterations=EXPLORE_ITERATIONS) -> list[list]:
    """[fit, label, finished] per start, each after ``iterations`` LM iterations.

    Each start also gets its own initial states: the current model's, or the data's candidates
    (``x0_starts``), whichever its simulation follows best (one batch). The current model's
    states were fitted to compensate for what it lacks; a model with the effect may need
    another release for one trial, and joint LM from the wrong one stalls (a 6/rev ripple at
    7 mrad instead of the 2 mrad noise)."""
    held = SHAPE_PARAMS.get(evidence.effect, ())
    free = _free_for(current, evidence, held)
    out = []
    for name, start in starts:
        vector = current.vector.copy()
        for key, value in start.items():
            vector[INDEX[key]] = value
        vector = _clip_start(vector, free)
        x0, residuals = closest_starts(sim, vector, [current.x0, *x0_starts]) if len(x0_starts) else (current.x0, None)
        fit = fit_output_error(sim, vector, free, x0, torque_scale=torque_scale,
                               max_iter=iterations, label=f"fit +{evidence.effect}", residuals=residuals)
        out.append([fit, name, fit.iterations < iterations])
    return out


def _settle(sim, explored: list[list], torque_scale: float, evidence: Evidence, done=None,
            iterations: int | None = None):
    """The best explored start once carried to convergence (or ``iterations`` further). The two
    best are carried on, best first, not one: after a dozen iterations the ranking of starts is
    not yet the final one (a 6/rev ripple from the equation error still trailed a 4/rev one from
    the linearisation, then won). Once one leaves nothing but sensor noise (``done``), the next
    could at best tie with it and is not carried: on 30 drops with a Stribeck term that second
    carry was 60 iterations and 10,000 trial simulations, ending behind the first."""
    if not explored:
        return None, ""
    explored.sort(key=lambda entry: entry[0].rmse)
    for entry in explored[:FINISHED_STARTS]:
        if not entry[2]:
            fit = entry[0]
            same_scale = fit.tau_scale == sim.tau_scale  # else the residuals were simulated at another scale
            # A bounded carry goes on with the short refit's damping (explore_further's steps); a
            # carry to convergence starts the LM afresh, as it always did.
            bounded = {} if iterations is None else {"max_iter": iterations, "damping": fit.damping}
            entry[0] = fit_output_error(sim, fit.vector, fit.free, fit.x0, torque_scale=torque_scale,
                                        label=f"fit +{evidence.effect}", residuals=fit.residuals if same_scale else None,
                                        known=fit.end_point, **bounded)
            entry[2] = iterations is None or entry[0].iterations < iterations
        if done is not None and done(entry[0]):
            break
    best = min(explored[:FINISHED_STARTS], key=lambda entry: entry[0].rmse)
    return best[0], best[1]


def _free_for(current: FitResult, evidence: Evidence, held: Sequence[str]) -> tuple[str, ...]:
    return (*current.free, *[p for p in evidence.params if p not in current.free and p not in held])


def fallback_starts(evidence: Evidence, current: FitResult, scales: dict[str, float]) -> list[dict[str, float]]:
    """Starts of a typical size for each effect, independent of the linearisation.

    Each keeps the dissipation the base fit found where it moved it: a friction-like effect
    takes 30 % of the Coulomb level over (as Stribeck always did: the base fit absorbs breakaway
    into a higher Coulomb level), a drag takes half the viscous damping at the typical speed."""
    level = max(current.value("coulomb"), 0.02 * scales["gravity"])
    damping = current.value("damping")
    speed = max(scales["speed"], 1e-3)
    effect = evidence.effect
    if effect == "stribeck":
        return [{"stribeck_velocity": v, "stribeck_torque": 0.3 * level, "coulomb": 0.7 * level}
                for v in STRIBECK_VELOCITIES[1:]]
    if effect == "asymmetric_coulomb":
        return [{"coulomb_asym": 0.3 * level}, {"coulomb_asym": -0.3 * level}]
    if effect == "load_dependent_coulomb":
        return [{"load_coulomb": 0.6 * level / scales["gravity"], "coulomb": 0.7 * level}]
    if effect == "angle_offset":
        return [{"angle_offset": 0.02}, {"angle_offset": -0.02}]
    if effect == "quadratic_drag":
        return [{"quadratic_drag": 0.5 * damping / speed, "damping": 0.5 * damping},
                {"quadratic_drag": 0.3 * level / speed**2, "coulomb": 0.7 * level}]
    if effect in PERIODIC:
        amplitude, phase_name, period_name = PERIODIC[effect]
        period = evidence.start.get(period_name, COGGING_PERIODS[1])
        return [{period_name: period, amplitude: 0.2 * level, phase_name: phase} for phase in (0.0, math.pi)]
    if effect == "spring":
        return [{"spring_stiffness": 0.1 * scales["gravity"], "spring_neutral": 0.0}]
    if effect == "time_delay":
        return [{"time_delay": 0.01}, {"time_delay": 0.03}]
    if effect == "torque_bias":
        return [{"torque_bias": 0.5 * level}, {"torque_bias": -0.5 * level}]
    if effect == "torque_gain":
        return [{"torque_gain": 0.9}, {"torque_gain": 1.1}]
    raise KeyError(f"no fallback start for effect {effect!r}")


def _inertia_on_bound(fit: FitResult) -> bool:
    return fit.value("motor_inertia") <= LOWER["motor_inertia"] * (1 + 1e-3)


# Effects that can take over the swing's period (a delay, a spring, a torque scale, a ripple in
# the angle): when one of them puts the motor inertia on its bound it has replaced the inertia.
PERIOD_EFFECTS = frozenset({"time_delay", "spring", "torque_gain", "cogging"})


def physical_problems(evidence: Evidence, fit: FitResult, before: FitResult | None = None,
                      mode: str = "geometry") -> list[str]:
    """Why a refit is not a physical explanation, whatever it does to the error (empty: none).

    An effect parameter on a bound means the data wanted more than the effect can be (or
    none of it); an inertia collapsed onto its bound means the effect took over the swing's
    period, which no friction or measurement term can (a 14 ms delay on the DFKI runs did);
    an asymmetric level beyond the Coulomb level is a friction that pushes one way. (How far
    the inertia may move is no test: a 0.05 N·m torque bias left out of the base model puts
    its inertia 3× too high, and the true effect moves it back.)

    ``before``: the model without the effect. An inertia that already sat on its bound there is
    a fact about the rig (a passive pendulum has no motor inertia to fit), not something the
    effect did. And in geometry mode a motor inertia of 0 is a rig without a motor (the load's
    inertia remains): only an effect that can take over the period (:data:`PERIOD_EFFECTS`) is
    refused for putting it there. A passive rod pendulum with quadratic drag: the base fit
    absorbs the drag into 0.19 g·m² of motor inertia, the drag takes it back to the true 0.
    In lumped mode the "inertia" is 1/Γ, and 0 is no pendulum at all."""
    out = []
    shape_fixed = [n for n in SHAPE_PARAMS.get(evidence.effect, ()) if n not in FREED_SHAPES]
    for name in evidence.params:
        if name in shape_fixed:
            continue
        value = fit.value(name)
        for bound, kind in ((LOWER.get(name), "lower"), (UPPER.get(name), "upper")):
            if bound is not None and abs(value - bound) <= BOUND_TOLERANCE * max(1.0, abs(bound)):
                out.append(f"{name} ran to its {kind} bound {bound:g}")
    takes_over = mode == "lumped" or evidence.effect in PERIOD_EFFECTS
    if _inertia_on_bound(fit) and takes_over and not (before is not None and _inertia_on_bound(before)):
        out.append("motor_inertia collapsed onto its bound")
    if evidence.effect == "asymmetric_coulomb" and abs(fit.value("coulomb_asym")) > fit.value("coulomb"):
        out.append("|coulomb_asym| above the Coulomb level: friction would push one way")
    if evidence.effect == "friction_ripple" and fit.value("friction_ripple_amplitude") > fit.value("coulomb"):
        out.append("friction ripple above the Coulomb level: friction would vanish or push at some angles")
    if evidence.effect in PERIODIC:
        period = fit.value(PERIODIC[evidence.effect][2])
        if abs(period - round(period)) > 1e-9:
            out.append(f"{evidence.effect} period {period:g}/rev is not a whole number per revolution")
        elif period <= COGGING_PERIODS[0] or period >= COGGING_PERIODS[-1]:
            # The best period at an end of the searched grid is a fit running to a bound: the
            # data want a slower or finer shape than the grid holds (2/rev stands in for an
            # offset or a spring, the top of the grid for whatever is finer still).
            out.append(f"{evidence.effect} period {period:g}/rev sits at the end of the searched grid "
                       f"({COGGING_PERIODS[0]}–{COGGING_PERIODS[-1]}/rev)")
    return out


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


def without_weak_optional(sim: Simulator, current: FitResult, refit: FitResult, evidence: Evidence,
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


def significance(fit: FitResult, names: Sequence[str]) -> float:
    """The largest distance, in σ, of any of ``names`` from its "off" value (its default), each σ
    taken with the freed shape parameters held (:func:`conditional_sigma`)."""
    defaults = default_vector()
    return float(max(abs(fit.value(n) - defaults[INDEX[n]]) / max(conditional_sigma(fit, n), 1e-300)
                     for n in names))


def conditional_sigma(fit: FitResult, name: str) -> float:
    """σ of ``name`` with the freed shape parameters (:data:`FREED_SHAPES`) held at their fitted values.

    The test of an effect's level is a test at each shape of the grid, paid for by
    :func:`required_sigma`'s look-elsewhere share (3.4 σ for the 4 Stribeck velocities). Its
    marginal σ with the shape free counts the shape's uncertainty a second time: along the ridge
    where the Stribeck level and velocity trade, the fit at 0.29 mrad (sensor floor 0.44) on
    the test oracle's encoder drops (seed 5) had a level of 0.085 N·m at σ 0.040 free (2.1 σ,
    refused) and σ 0.0074 with the velocity held (11 σ)."""
    shapes = [n for n in FREED_SHAPES if n in fit.free]
    if name not in fit.free or not shapes or fit.uncertainty is None:
        return fit.sigma.get(name, math.inf)
    cov = fit.covariance
    i = fit.free.index(name)
    j = [fit.free.index(n) for n in shapes]
    variance = cov[i, i] - cov[i, j] @ np.linalg.pinv(cov[np.ix_(j, j)]) @ cov[j, i]
    return float(np.sqrt(max(variance, 0.0)))


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
