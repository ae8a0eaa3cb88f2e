"""The effect search: greedy forward selection judged by cross-validation, with a backward step.

Each round ranks the candidates on the current residual (effects.py), refits every one of
them, and admits at most one. A candidate is admitted only when all of these hold:

1. **It makes physical sense** (``effects.physical_problems``): no effect parameter on a bound,
   no inertia collapsed onto its bound, no friction that pushes, a periodic term's period a
   whole number per revolution and not at an end of the searched grid.
2. **Its parameter is significant**: one evidence parameter ≥ ``min_sigma`` standard errors
   from its "off" value, σ corrected for the residual's autocorrelation (fit.py) and raised for
   effects whose shape was searched on a grid (``effects.required_sigma``).
3. **It lowers the cross-validated error** by more than ``min_gain`` *and* by a margin its
   uncertainty supports (crossval.py: a one-sided Student-t bound on the paired per-unit
   gain). Folds are whole trials, or time segments when the trials are few.
4. **It is the same effect in every fold**: its evidence parameter keeps its sign in every
   fold's fit and no fold's value strays from their mean by more than the mean itself (a
   cogging phase by more than π/3). An "effect" whose value swings from fold to fold is
   fitting something else.
5. **It is the effect at work, not a stand-in** (regime.py): the model is
   refitted (every parameter) on the first and the second half of the motion of every unit
   (large, fast swings against small, slow ones: the unit is cut where half its travel is
   done), and on the light and on the heavy loads. A physical law holds in every operating
   regime: the effect's own value must agree between the halves, and with it the model must
   be stable across them, or at least much more stable than without it. A library term
   standing in for an effect the library lacks (an angle offset for a cable's spring, a
   ripple for breakaway friction) must change its value with the regime to follow the true
   shape, or leaves the model as regime-dependent as before. Such a candidate is a
   **stand-in**: it may well lower the error, so it stays in the model (its predictions are
   better with it), but it is not named in ``effects``; the ``unexplained`` object lists it.
   Prediction being its only claim, a stand-in must improve *every* fold, not a majority, and
   carry over between regimes (:func:`transfer_loss`: fitted on one half of each split, predict
   the other half better than the model without it). Before that verdict, a flagged fit is
   refitted from the halves' own optima (``regime.restart_from_halves``): one that then fits
   materially better was stuck, not a stand-in, and is judged again from there (a few times at most).
   A periodic term (cogging, a friction ripple: a shape chosen among 31 periods, with a free
   phase) can fit part of almost anything that varies with the angle, so it is claimed only
   when the model with it (or with the effects admitted after it) leaves nothing but sensor
   noise; until then it is a stand-in too. And an effect admitted while the model carries a
   stand-in is judged in a model that is itself wrong: it is a stand-in as well, unless the
   final model turns out to leave nothing but noise with only such stand-ins in it.

Significance alone follows from having thousands of samples; a cross-validated gain alone can
be luck on few units; each guards against what the other misses, and tests switch each off
(tests/test_ident_admission.py).

**Ties are settled by evidence.** Among the admissible candidates the one with the largest
cross-validated gain leads; another is only "tied" when the paired comparison of the two,
unit by unit, cannot tell them apart. A tie goes to the candidate that keeps the model stable
across regimes over a stand-in, then to the one that fits the training data materially better
(by more than a tenth of the sensor's noise variance), then, among equal fits, to the one with
fewer parameters; when even that is level, the data cannot choose: the leader stays in the
model (it predicts as well as the others) but no name is claimed for it, and the JSON lists
the equivalent effects. No fixed preference order decides anything.

**Backward step.** After each admission every earlier effect must still earn its place
against the model without it, by the same cross-validated rule; one that no longer does is
removed (an effect can stand in for a later, better one).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from admittance.ident.candidate_screen import FAR_BEHIND, Screened, behind, carry_on, explore_round, judging_order
from admittance.ident.crossval import Folds, PairedGain, paired_gain
from admittance.ident.effects import (
    FREED_SHAPES,
    PERIODIC,
    SHAPE_PARAMS,
    StandIn,
    Evidence,
    candidate_effects,
    physical_problems,
    rank_candidates,
    refit_candidate,
    required_sigma,
    significance,
    switched_off,
    variants,
    without_weak_optional,
)
from admittance.ident.fit import FitResult, Progress, end_point_of, fit_initial_states_multi, fit_output_error
from admittance.ident.model import EFFECTS, INDEX, Simulator, default_vector
from admittance.ident.regime import regime_inconsistency, restart_from_halves, transfer_loss
from admittance.ident.residual import noise_of
from admittance.ident.angle_sensor import Sensor

PHASE_SPREAD = math.pi / 3  # rad: how far a fold's cogging phase may stray from the others'
# Training fits closer than this fraction of the noise variance fit equally well.
MATERIAL_FIT = 0.1
# A flagged fit restarted from the regime halves' optima at most this many times, each restart
# materially better than the last: on 30 synth drops with Stribeck at 1.5× Coulomb the first
# restart went 10.7 → 2.6 mrad (still stuck at one turning point), the second to 1.99 (the noise).
MAX_RESTARTS = 3
# FAR_BEHIND (candidate_screen.py): a candidate whose short refits still fit this many noise
# variances worse than one that leaves nothing but sensor noise is not carried on (_behind_the_floor).
BESIDE_REASON = "it was judged in a model that carries a stand-in, itself not one model across regimes"
FLEXIBLE_REASON = "a periodic term chosen among 31 periods is claimed only when it leaves nothing but sensor noise"


@dataclass
class AtFloor:
    """The first admissible model of a round that leaves nothing but sensor noise: the
    candidates judged after it can at best tie with it (search._judge_round)."""

    fit: FitResult
    screened: Screened | None  # its short refits (candidate_screen.py)
    floor: float  # the sensor's noise level (rad) in its noise verdict, computed once (residual.noise_of)
    params: int = 0  # the effect's own fitted parameters (own_params); 0: none counts as simpler


@dataclass
class SearchSettings:
    max_effects: int = 4
    min_gain: float = 0.03  # relative cross-validated RMSE improvement
    min_sigma: float = 3.0


@dataclass
class Scored:
    """A model fitted on all search units, refitted per fold, and scored on each fold's held-out units."""

    full: FitResult
    folds: list[FitResult]
    residuals: list[np.ndarray]  # per unit, held-out

    @property
    def sse(self) -> float:
        return float(sum(r @ r for r in self.residuals))

    @property
    def rmse(self) -> float:
        return float(math.sqrt(self.sse / sum(r.size for r in self.residuals)))


@dataclass
class Step:
    """One line of the search's ladder: the model after an admission or a removal."""

    effects: list[str]
    crossval_rmse: float
    training_rmse: float
    change: str = ""  # "+effect" or "-effect"
    support: dict | None = None  # PairedGain.as_dict() of this change

    def as_dict(self) -> dict:
        return {"effects": list(self.effects), "rmse": self.crossval_rmse, "training_rmse": self.training_rmse,
                "change": self.change, "support": self.support}


@dataclass
class SearchOutcome:
    effects: list[str]  # every effect in the model, in the order admitted (stand-ins included)
    fit: FitResult  # the fit on all search units with the admitted effects; fit.free says what is free
    rounds: list[list[Evidence]]
    steps: list[Step]
    folds: Folds | None
    removed: list[str] = field(default_factory=list)  # admitted, then made redundant by a later one
    equivalents: dict[str, list[str]] = field(default_factory=dict)  # admitted → indistinguishable alternatives
    stopped: str = ""  # why the search ended
    stand_ins: list[str] = field(default_factory=list)  # in the model, but not claimed (see module doc, test 5)

    @property
    def claimed(self) -> list[str]:
        """The effects named alone as the physics at work: admitted, not stand-ins, and not one
        of a group the data cannot tell apart (those are named as the group: :meth:`groups`)."""
        return [e for e in self.effects if e not in self.stand_ins and e not in self.equivalents]

    def groups(self) -> list[dict]:
        """Each group of effects the data cannot tell apart: which one the model keeps, and
        what experiment would separate them."""
        return [{"effects": [kept, *others], "kept": kept, "separate_by": separating_experiment([kept, *others])}
                for kept, others in self.equivalents.items() if kept in self.effects]

    @property
    def validation_rmse(self) -> list[float]:
        return [s.crossval_rmse for s in self.steps]


@dataclass
class SearchContext:
    """Everything a round needs: the units, their folds and starting states, the sensor."""

    sim: Simulator  # over the units (pseudo-trials)
    folds: Folds
    x0_starts: list[np.ndarray]  # candidate initial states per unit, for scoring
    sensor: Sensor
    torque_scale: float
    settings: SearchSettings
    progress: Progress | None = None
    whole_trials: Sequence | None = None  # the trials the units were cut from (for equation-error starts)

    def say(self, message: str) -> None:
        if self.progress:
            self.progress(message)


# What data would tell two effects apart that fit some data equally well (by pair; any order).
SEPARATING = {
    frozenset({"torque_bias", "asymmetric_coulomb"}): (
        "add undriven drops: a torque bias also acts at rest and moves where the joint settles, "
        "an asymmetric Coulomb level does not"),
    frozenset({"torque_bias", "angle_offset"}): (
        "add trials at another load: an angle offset is the same angle at every load, the rest angle "
        "a torque bias gives shrinks as the gravity torque grows"),
    frozenset({"quadratic_drag", "stribeck"}): "add small, slow swings: Stribeck acts near rest, drag at speed",
    frozenset({"load_dependent_coulomb", "asymmetric_coulomb"}): "add trials at a second load",
}
GENERIC_SEPARATION = "add trials that differ from these in load, swing amplitude or drive"


def separating_experiment(effects: Sequence[str]) -> str:
    """The experiment that tells a group of equivalent effects apart (see :data:`SEPARATING`)."""
    for i, a in enumerate(effects):
        for b in effects[i + 1 :]:
            found = SEPARATING.get(frozenset({a, b}))
            if found:
                return found
    return GENERIC_SEPARATION


def nothing_left(sim: Simulator, fit: FitResult, sensor: Sensor) -> bool:
    """True when the residual is what the sensor alone would leave: there is nothing to explain,
    and any effect "found" would be fitted noise (sensor.py)."""
    return noise_of(sim, fit, sensor).nothing_left


def cross_validate(ctx: SearchContext, full: FitResult) -> Scored:
    """``full``'s model refitted without each fold (from ``full``'s values: a warm start; every
    parameter is refitted) and scored on the fold's units, their initial states fitted alone."""
    sim = ctx.sim.with_tau_scale(full.tau_scale)
    known = end_point_of(sim, full, ctx.torque_scale)  # every fold starts there: one Jacobian for all (exact)
    residuals: list[np.ndarray] = [np.empty(0)] * len(ctx.folds.units)
    fold_fits = []
    for k in range(ctx.folds.n_folds):
        train, held = ctx.folds.train(k), ctx.folds.held(k)
        fit = fit_output_error(sim.subset(train), full.vector, full.free, full.x0[train],
                               torque_scale=ctx.torque_scale, label=f"fold {k + 1}", known=known)
        fold_fits.append(fit)
        # The fit on all units already holds a good initial state for each held-out unit (its
        # parameters barely differ); the data's own start is the second, independent one.
        starts = [full.x0[held], ctx.x0_starts[0][held]]
        scored = fit_initial_states_multi(sim.with_tau_scale(fit.tau_scale).subset(held), fit.vector, starts)
        for j, r in zip(held, scored.residuals):
            residuals[j] = r
    return Scored(full, fold_fits, residuals)


def compare(ctx: SearchContext, current: Scored, candidate: Scored) -> PairedGain:
    return paired_gain(current.residuals, candidate.residuals, [u.fold for u in ctx.folds.units])


def search_effects(ctx: SearchContext, base: FitResult) -> SearchOutcome:
    """Greedy forward selection with a backward step, every decision cross-validated."""
    with_tau = any(tr.tau is not None for tr in ctx.sim.trials)
    effects: list[str] = []
    removed: list[str] = []
    stand_ins: list[str] = []
    equivalents: dict[str, list[str]] = {}
    current = cross_validate(ctx, base)
    steps = [Step([], current.rmse, current.full.rmse)]
    rounds: list[list[Evidence]] = []
    stopped = "max_effects reached"
    while len(effects) < ctx.settings.max_effects:
        if nothing_left(ctx.sim, current.full, ctx.sensor):
            stopped = "nothing left: the residual is at the sensor's noise"
            break
        candidates = candidate_effects(effects + removed, with_tau, ctx.sim.mode)
        ranking = rank_candidates(ctx.sim, current.full, candidates, ctx.torque_scale)
        rounds.append(ranking)
        explored = explore_round(ctx, current.full, ranking)  # judged best first (candidate_screen.py)
        admissible = _judge_round(ctx, current, ranking, explored, bool(stand_ins), len(rounds))
        if not admissible:
            stopped = "no candidate passed every test"
            break
        chosen, current, ties = _choose(ctx, current, admissible)
        effects.append(chosen.effect)
        if chosen.stand_in:
            stand_ins.append(chosen.effect)
        if ties:
            equivalents[chosen.effect] = ties
        steps.append(Step(list(effects), current.rmse, current.full.rmse, f"+{chosen.effect}", chosen.crossval))
        dropped = _redundant(ctx, current, effects)
        if dropped:
            note, current = dropped
            rounds[-1].append(note)
            effects.remove(note.effect)
            removed.append(note.effect)
            if note.effect in stand_ins:
                stand_ins.remove(note.effect)
            steps.append(Step(list(effects), current.rmse, current.full.rmse, f"-{note.effect}", note.crossval))
    promoted = [e for r in rounds for e in r if e.accepted and e.stand_in and e.effect in stand_ins
                and e.stand_in_why in (StandIn.FLEXIBLE, StandIn.BESIDE)]
    if promoted and len(promoted) == len(stand_ins) and nothing_left(ctx.sim, current.full, ctx.sensor):
        # A periodic term kept only because structure remained, or an effect judged beside such a
        # term, is claimed once the final model leaves nothing but sensor noise; never while a
        # stand-in that failed a regime test helps it get there.
        for evidence in promoted:
            if evidence.effect in stand_ins:
                stand_ins.remove(evidence.effect)
                evidence.stand_in = False
                evidence.reason += "; claimed: with the later effects nothing but sensor noise is left"
    return SearchOutcome(effects, current.full, rounds, steps, ctx.folds, removed, equivalents, stopped, stand_ins)


def _judge_round(ctx: SearchContext, current: Scored, ranking: list[Evidence], explored: list[Screened],
                 stand_ins: bool, round_number: int = 1) -> list[tuple[Evidence, Scored]]:
    """Every candidate of a round refitted, in the order of its short refits' error
    (candidate_screen.judging_order), and put through the admission tests (:func:`assess`);
    returns the admissible ones with their cross-validated models.

    **A refit that leaves nothing but sensor noise is assessed first.** The short refits' order
    is a guess at which candidate will reach the floor, and a poor one when the right effect
    needs a fallback start to get there: on 30 drops with a Stribeck term (the base fit landed
    a little differently with the plant's sine from the libm crate, tried and not landed:
    docs/identification-speed-log.md) a cogging term and a
    friction ripple led after twelve iterations (6.1 and 5.0 mrad) while Stribeck reached the
    2 mrad floor only from its equation-error start; each was then cross-validated and put
    through the regime and transfer tests before Stribeck was judged, and the search took
    343,000 trial simulations instead of 128,000. So a refit whose model still leaves
    structure, while no candidate of the round has reached the floor, is assessed only after
    every candidate has been refitted. Once one has reached the floor and is admitted, the
    candidates assessed later face the ``at_floor`` rule the judging order already gave the
    ones refitted after it (a fit materially worse than that model can at best tie and is
    refused without cross-validation, :func:`assess`). The refits themselves run in the same
    order, with the same starts, as before. (tests/test_ident_speed_gates.py)"""
    admissible: list[tuple[Evidence, Scored]] = []
    at_floor: AtFloor | None = None  # the first admissible refit that leaves only sensor noise
    deferred: list[tuple[Evidence, FitResult, Screened]] = []
    for number, index in enumerate(judging_order([s.entries for s in explored]), 1):
        evidence = ranking[index]
        ctx.say(f"effect search round {round_number}: candidate {number}/{len(ranking)} "
                f"{evidence.effect} ({evidence.variant})")
        refit = _refit_judged(ctx, current, evidence, at_floor, explored[index])
        if refit is None:
            continue
        if at_floor is None and not nothing_left(ctx.sim, refit, ctx.sensor):
            deferred.append((evidence, refit, explored[index]))
            continue
        at_floor = _admit(ctx, current, evidence, refit, stand_ins, at_floor, explored[index], admissible)
    for evidence, refit, screened in deferred:
        at_floor = _admit(ctx, current, evidence, refit, stand_ins, at_floor, screened, admissible)
    return admissible


def _refit_judged(ctx: SearchContext, current: Scored, evidence: Evidence,
                  at_floor: AtFloor | None = None, screened: Screened | None = None) -> FitResult | None:
    """Refit one candidate for judging (:func:`assess` puts it through the tests); None when
    it is refused before that (the reason on ``evidence``).

    ``at_floor``: an earlier candidate of the round whose model leaves nothing but sensor noise.
    This one can then at best tie with it: it gets only the starts its linear test suggests
    (and :func:`assess` refuses it without cross-validation when it fits the training data
    materially worse, by more than a tenth of the noise variance). ``screened``: its
    linearised starts already run (candidate_screen.py); carried on to the full short refit
    here unless out of reach of ``at_floor``."""
    # A candidate with fewer parameters than the model at the floor wins a tie with it (_choose),
    # so how far its short refits trail says nothing about the verdict: it is refitted.
    rival = None if at_floor is not None and own_params(evidence) < at_floor.params else at_floor
    if screened is not None and not screened.complete:
        out_of_reach = _behind_the_floor(rival, screened)
        if out_of_reach:
            return _refuse(evidence, out_of_reach)
        carry_on(ctx, evidence, screened)
    behind_floor = _behind_the_floor(rival, screened)
    if behind_floor:
        return _refuse(evidence, behind_floor)
    explored = None if screened is None else screened.entries
    refit = refit_effect(ctx, current.full, evidence, fallbacks=at_floor is None, explored=explored)
    if refit is None:
        return _refuse(evidence, "not refitted: its linear test gave the wrong sign, and another candidate "
                                 "already leaves nothing but sensor noise")
    return refit


def _admit(ctx: SearchContext, current: Scored, evidence: Evidence, refit: FitResult, stand_ins: bool,
           at_floor: AtFloor | None, screened: Screened | None, admissible: list) -> AtFloor | None:
    """``assess`` one refitted candidate; an admissible one joins ``admissible``, and the first
    whose model leaves nothing but sensor noise becomes the round's floor (returned)."""
    scored = assess(ctx, current, evidence, refit, stand_ins, at_floor)
    if scored is None:
        return at_floor
    admissible.append((evidence, scored))
    if at_floor is None:
        verdict = noise_of(ctx.sim, scored.full, ctx.sensor)
        if verdict.nothing_left:
            return AtFloor(scored.full, screened, verdict.floor, own_params(evidence))
    return at_floor


def own_params(evidence: Evidence) -> int:
    """How many parameters the effect adds to the model (a shape held on its grid not counted)."""
    held = [n for n in SHAPE_PARAMS.get(evidence.effect, ()) if n not in FREED_SHAPES]
    return len([n for n in evidence.params if n not in held])


def _behind_the_floor(at_floor: AtFloor | None, screened: Screened | None) -> str:
    """Why a candidate's short refits are not carried further ("" when they are): another
    candidate (``at_floor``) already leaves nothing but sensor noise, and this one trails it by
    more than :data:`FAR_BEHIND` noise variances, so it could at best tie (a tie is within
    ``MATERIAL_FIT``, a thirtieth of that).

    After only the first :data:`candidate_screen.SCREEN_ITERATIONS` LM iterations
    (``screened`` not complete) it must trail on two counts: even the undamped Gauss–Newton
    step of its best start would leave it that far behind the model at the floor, *and* after
    the same first iterations it stood that far behind where the other stood then (like with
    like: on driven trials a torque bias and an asymmetric Coulomb level are one equation and
    take the same steps, 16.405 against 16.403 mrad after three, while their linearisations'
    reach differed, 7 against under 3 noise variances; candidate_screen.py). After
    :data:`effects.EXPLORE_ITERATIONS` from every start, its best error is what counts:
    carrying such starts to convergence was a sixth of a search's simulations on 30 drops with
    a Stribeck term, and none of them came near the floor."""
    if at_floor is None or screened is None or not screened.entries:
        return ""
    model = at_floor.fit.rmse**2
    if not screened.complete:
        if at_floor.screened is None:
            return ""
        far = behind(screened.reach, model, at_floor.floor)
        trailing = behind(screened.first, at_floor.screened.first, at_floor.floor)
        if far <= FAR_BEHIND or trailing <= FAR_BEHIND:
            return ""
        return (f"after its first short refits it trailed a candidate that now leaves nothing but sensor noise by "
                f"{trailing:.0f}× the noise variance, and even its linearised step would fit the training data "
                f"{far:.0f}× worse than that one (a tie needs {MATERIAL_FIT:g}×): not refitted further")
    reached = min(entry[0].rmse for entry in screened.entries)
    far = behind(reached**2, model, at_floor.floor)
    if far <= FAR_BEHIND:
        return ""
    return (f"after its short refits it fits the training data {far:.0f}× the noise variance worse than a "
            f"candidate that leaves nothing but sensor noise (a tie needs {MATERIAL_FIT:g}×): not refitted further")


def refit_effect(ctx: SearchContext, current: FitResult, evidence: Evidence, fallbacks: bool = True,
                 explored: list[list] | None = None) -> FitResult | None:
    """The current model plus ``evidence``'s effect, fitted on all units from its best start."""
    sim = ctx.sim
    refit = refit_candidate(sim, current, evidence, ctx.torque_scale, _scales(ctx, current),
                            lambda fit: nothing_left(sim, fit, ctx.sensor), ctx.whole_trials, fallbacks, ctx.x0_starts,
                            explored)
    if refit is None:
        return None
    return without_weak_optional(sim, current, refit, evidence, ctx.settings.min_sigma, ctx.torque_scale)


def assess(ctx: SearchContext, current: Scored, evidence: Evidence, refit: FitResult,
           stand_ins: bool = False, at_floor: AtFloor | None = None, restarted: int = 0) -> Scored | None:
    """The admission tests of the module doc on a refitted candidate (``refit``: the current
    model plus the effect, fitted on all units; ``stand_ins``: the current model carries some).
    Records everything on ``evidence``; returns the candidate's cross-validated model when it is
    admitted (``evidence.stand_in`` says how). A candidate the regime test flags is judged
    again from the regime halves' own optima when they fit all the data materially better,
    up to :data:`MAX_RESTARTS` times (``restarted``: how many so far; regime.restart_from_halves)."""
    settings = ctx.settings
    evidence.values = {n: (refit.value(n), refit.sigma.get(n, math.nan)) for n in evidence.params}
    evidence.training_gain = float(1.0 - refit.rmse / current.full.rmse)
    main = [n for n in EFFECTS[evidence.effect].evidence if n in evidence.params]
    evidence.significance = significance(refit, main)
    evidence.required_sigma = required_sigma(settings.min_sigma, len(variants(evidence.effect, ctx.torque_scale)))
    evidence.problems = physical_problems(evidence, refit, current.full, ctx.sim.mode)
    if evidence.problems:
        return _refuse(evidence, "not physical: " + "; ".join(evidence.problems))
    if evidence.significance < evidence.required_sigma:
        return _refuse(evidence, f"parameter only {evidence.significance:.1f} σ from its off value "
                                 f"(needs {evidence.required_sigma:.1f} σ)")
    if evidence.training_gain <= settings.min_gain:
        return _refuse(evidence, f"training gain {100 * evidence.training_gain:.1f} % ≤ {100 * settings.min_gain:.0f} %")
    if at_floor is not None:
        if refit.rmse**2 - at_floor.fit.rmse**2 > MATERIAL_FIT * at_floor.floor**2:
            return _refuse(evidence, "fits the training data materially worse than a candidate that leaves "
                                     "nothing but sensor noise")
    scored = cross_validate(ctx, refit)
    gain = compare(ctx, current, scored)
    evidence.crossval = gain.as_dict()
    evidence.fold_values = [{n: f.value(n) for n in evidence.params} for f in scored.folds]
    if not gain.supported(settings.min_gain):
        return _refuse(evidence, _unsupported_reason(gain, settings.min_gain))
    unstable = fold_instability(evidence, scored.folds)
    if unstable:
        return _refuse(evidence, f"not the same effect in every fold: {unstable}")
    halves: list[FitResult] = []
    regimes, evidence.regimes = regime_inconsistency(ctx, evidence, refit, current.full, halves)
    if regimes and restarted < MAX_RESTARTS:
        better = restart_from_halves(ctx, refit, halves)
        if better is not None:
            moved = f"refitted from a regime half's optimum ({1e3 * refit.rmse:.3f} → {1e3 * better.rmse:.3f} mrad)"
            ctx.say(f"{evidence.effect}: {moved}, judged again")
            scored = assess(ctx, current, evidence, better, stand_ins, at_floor, restarted=restarted + 1)
            evidence.reason = f"{moved}; {evidence.reason}"
            return scored
    why = StandIn.REGIMES if regimes else None
    if not regimes and stand_ins:
        regimes, why = BESIDE_REASON, StandIn.BESIDE
    if not regimes and evidence.effect in PERIODIC and not nothing_left(ctx.sim, refit, ctx.sensor):
        regimes, why = FLEXIBLE_REASON, StandIn.FLEXIBLE
    if regimes and gain.folds_supporting < gain.n_folds:
        evidence.stand_in = True
        return _refuse(evidence, f"a stand-in ({regimes}) is kept for its predictions only, and only when every "
                                 f"fold improves: {gain.folds_supporting} of {gain.n_folds} do")
    if regimes:
        worse = transfer_loss(ctx, current.full, refit)
        if worse:
            evidence.stand_in = True
            return _refuse(evidence, f"a stand-in ({regimes}) is kept for its predictions only, and only when they "
                                     f"carry over between regimes: {worse}")
    evidence.accepted = True
    evidence.stand_in = bool(regimes)
    evidence.stand_in_why = why
    evidence.reason = ("admitted as a stand-in, not claimed: " + regimes + "; " if regimes else "") + (
                       f"cross-validated gain {100 * gain.pooled_gain:.1f} % (lower bound "
                       f"{100 * gain.gain_lower_bound:.1f} %), {gain.folds_supporting} of "
                       f"{gain.n_folds} folds, {evidence.significance:.1f} σ")
    return scored


def _refuse(evidence: Evidence, reason: str) -> None:
    evidence.accepted = False
    evidence.reason = reason
    return None


def _unsupported_reason(gain: PairedGain, min_gain: float) -> str:
    folds = f"{gain.folds_supporting} of {gain.n_folds} folds improve"
    if gain.pooled_gain <= min_gain:
        return f"cross-validated gain {100 * gain.pooled_gain:.1f} % ≤ {100 * min_gain:.0f} % ({folds})"
    if gain.gain_lower_bound <= 0:
        return (f"cross-validated gain {100 * gain.pooled_gain:.1f} % is within its uncertainty "
                f"(z = {gain.z:.1f}; {folds})")
    return f"cross-validated gain {100 * gain.pooled_gain:.1f} % comes from a minority of folds ({folds})"


def fold_instability(evidence: Evidence, fold_fits: Sequence[FitResult]) -> str:
    """Why the effect's evidence parameters are not one value across folds ("" when they are)."""
    defaults = default_vector()
    for name in EFFECTS[evidence.effect].evidence:
        if name not in evidence.params:
            continue
        off = defaults[INDEX[name]]
        values = np.array([f.value(name) for f in fold_fits]) - off
        mean = float(values.mean())
        if np.any(np.sign(values) != np.sign(mean)):
            return f"{name} changes sign across folds ({_listed(values + off)})"
        if np.max(np.abs(values - mean)) > abs(mean):
            return f"{name} varies more than its own size across folds ({_listed(values + off)})"
    if evidence.effect in PERIODIC:
        phase_name = PERIODIC[evidence.effect][1]
        phases = np.array([f.value(phase_name) for f in fold_fits])
        centre = math.atan2(np.sin(phases).mean(), np.cos(phases).mean())
        spread = np.abs(np.angle(np.exp(1j * (phases - centre))))
        if spread.max() > PHASE_SPREAD:
            return f"{phase_name} differs across folds ({_listed(phases)})"
    return ""


def _listed(values: np.ndarray) -> str:
    return ", ".join(f"{v:.4g}" for v in values)


def _choose(ctx: SearchContext, current: Scored, admissible: list[tuple[Evidence, Scored]]):
    """The admissible candidate with the best cross-validated error, unless the data cannot tell
    it from another (see the module doc). Returns (evidence, its model, equivalent effects).

    Among candidates the paired comparison cannot separate, evidence decides in this order:
    one that keeps the model stable across regimes beats a stand-in; one that fits the training
    data materially better (by more than a tenth of the sensor's noise variance) wins; among
    equal fits the fewer parameters win; what is left is indistinguishable: kept in the model,
    but not named."""
    admissible.sort(key=lambda pair: pair[1].sse)
    leader, leader_model = admissible[0]
    tied = []
    for evidence, model in admissible[1:]:
        head_to_head = compare(ctx, model, leader_model)  # does the leader beat it, unit by unit?
        if head_to_head.lower_bound > 0 and head_to_head.pooled_gain > ctx.settings.min_gain:
            evidence.reason = f"qualified, but {leader.effect} predicts better (paired, unit by unit)"
            evidence.accepted = False
        else:
            tied.append((evidence, model))
    if not tied:
        return leader, leader_model, []
    contenders = [(leader, leader_model), *tied]
    pool = [pair for pair in contenders if not pair[0].stand_in] or contenders
    # Fits that differ by less than a tenth of the sensor's noise variance fit equally well (with
    # thousands of samples an information criterion would make a winner of rounding); among
    # those the fewer parameters win; what is still level cannot be told apart.
    floor = noise_of(ctx.sim, leader_model.full, ctx.sensor).floor
    best_mse = min(m.full.rmse**2 for _, m in pool)
    level = [pair for pair in pool if pair[1].full.rmse**2 - best_mse <= MATERIAL_FIT * floor**2]
    fewest = min(len(m.full.free) for _, m in level)
    simplest = sorted([pair for pair in level if len(pair[1].full.free) == fewest], key=lambda pair: pair[1].sse)
    leader, leader_model = simplest[0]
    equivalent = [e.effect for e, _ in simplest[1:]]
    for evidence, model in contenders:
        if evidence is leader:
            continue
        evidence.accepted = False
        if evidence.effect in equivalent:
            evidence.reason = f"indistinguishable from {leader.effect} on these data"
        elif evidence.stand_in and not leader.stand_in:
            evidence.reason = f"tied with {leader.effect} on prediction, and a stand-in where it is not"
        elif (evidence, model) in level:
            evidence.reason = f"tied with {leader.effect} on prediction and on the training fit, with more parameters"
        else:
            evidence.reason = f"tied with {leader.effect} on prediction, but fits the training data materially worse"
    if equivalent:
        # Nothing in the data tells them apart (on driven trials a torque bias b and an
        # asymmetric Coulomb level a = b are the same equation under the stick law). The term
        # stays in the model, which predicts as well either way, and the group is named, with
        # the experiment that would separate it: not a stand-in, not one name either.
        group = " or ".join([leader.effect, *equivalent])
        leader.reason = (f"named as a group: {group} (equal prediction, equal fit, as many parameters on these "
                         f"data); {separating_experiment([leader.effect, *equivalent])}; " + leader.reason)
    leader.accepted = True
    return leader, leader_model, equivalent


def _redundant(ctx: SearchContext, current: Scored, effects: list[str]):
    """Backward step: the first earlier effect that no longer earns its place against the model
    without it (None when all do). Returns (note, the model without it)."""
    if len(effects) < 2:
        return None
    for effect in effects[:-1]:
        ctx.say(f"checking {effect} is still needed")
        params = EFFECTS[effect].params
        free = tuple(n for n in current.full.free if n not in params)
        start = switched_off(current.full.vector, params)
        without = fit_output_error(ctx.sim.with_tau_scale(current.full.tau_scale), start, free, current.full.x0,
                                   torque_scale=ctx.torque_scale, label=f"fit -{effect}")
        scored = cross_validate(ctx, without)
        gain = compare(ctx, scored, current)  # what keeping the effect gains over dropping it
        if not gain.supported(ctx.settings.min_gain):
            note = Evidence(effect, variant="removed", accepted=False, crossval=gain.as_dict(),
                            reason=f"removed: with {effects[-1]} it no longer earns its place "
                                   f"({_unsupported_reason(gain, ctx.settings.min_gain)})")
            return note, scored
    return None


def _scales(ctx: SearchContext, fit: FitResult) -> dict[str, float]:
    """Typical sizes for fallback starts: the load torque and the speed while moving."""
    states = ctx.sim.with_tau_scale(fit.tau_scale).run(fit.vector[None, :], fit.x0[None, :, :], velocity=True)
    speeds = np.concatenate([np.abs(s[0][:, 1]) for s in states])
    moving = speeds[speeds > 0.05 * max(float(speeds.max()), 1e-9)]
    speed = float(np.sqrt(np.mean(moving**2))) if moving.size else 1.0
    return {"gravity": ctx.torque_scale, "speed": speed}


__all__ = ["FREED_SHAPES", "SHAPE_PARAMS", "SearchContext", "SearchOutcome", "SearchSettings", "Scored", "Step",
           "assess", "cross_validate", "fold_instability", "nothing_left", "refit_effect", "search_effects"]
