"""The short refits of a search round: which candidates are carried on, and in which order they are judged.

Every candidate of a round is refitted whatever its rank (effects.py), and the refit starts with
a few LM iterations from the starts its linear test suggests (:func:`effects.explore_linearised`).
That first stage is run for all candidates before any is judged, and the candidates are judged
in the order of the error it reached, lowest first; those without a start (the linear test gave
the wrong sign) keep their rank after the others.

Why the order matters: once a candidate's model leaves nothing but sensor noise, the candidates
judged after it can at best tie with it, so the search gives them only their linearised starts
and no cross-validation when they fit the training data materially worse (search._judge_round's
``at_floor``). The linear test is a poor guide to which candidate that will be: on 30 drops
with a Stribeck term it ranked Stribeck fifth, behind cogging, a friction ripple, a
load-dependent Coulomb level and a drag, each of which then went through its fallback starts,
cross-validation and the regime tests before being refused (105 of 145 s of the search, cProfile
on bench/identify_speed.py's set). After twelve iterations the short refits put Stribeck first.

**Two stages** (issue 19 item 2, speed). Every start first runs :data:`SCREEN_ITERATIONS` LM
iterations. Where it then stands, the undamped Gauss–Newton step of its own Jacobian predicts
the lowest error the local linear model can reach (:func:`effects.linearised_reach`). A
candidate whose reach is within :data:`FAR_BEHIND` noise variances of the sensor's floor could
set the floor or tie with the one that does: its starts are carried on to
:data:`effects.EXPLORE_ITERATIONS` at once, before any candidate is judged, so the candidates
that matter are judged in the order of their twelve-iteration error as before. The others are
carried on when their turn comes (search._refit_judged), unless a candidate of the round already
leaves nothing but sensor noise and this one is out of its reach (search._behind_the_floor): its
reach more than :data:`FAR_BEHIND` noise variances worse than that model, *and* after the same
first iterations it stood that far behind where that one stood then. On 30 drops with a
Stribeck term the six other candidates were refused so after three iterations instead of
twelve. The reach alone is an estimate, not a bound (with stick friction the linearisation
sees neither the kinks nor what later steps find), hence the second, like-with-like condition:
on driven trials a torque bias and an asymmetric Coulomb level are one equation and took the
same steps (16.405 and 16.403 mrad after three), while their reaches differed (7 and under 3
noise variances); refused on the reach alone, the torque bias lost its group. Not exact: a start
that trails by that much after three iterations and then ends within a tie would be lost
(docs/identification-speed-log.md, *A two-stage screen of the short refits*, for the family rows
run on it).

Nothing else is skipped here: every candidate still gets a verdict; the order decides which one
sets the floor the others are measured against, and the first stage's fits are the ones the
refit continues from (handed on, not repeated). A candidate whose twelve-iteration refits are
still far behind a model at the floor (:data:`FAR_BEHIND` noise variances; a tie needs a
thirtieth of that) is not carried on to convergence either (search._behind_the_floor).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

from admittance.ident.effects import EXPLORE_ITERATIONS, Evidence, explore_further, explore_linearised, linearised_reach
from admittance.ident.fit import FitResult
from admittance.ident.residual import noise_of

# LM iterations every start of every candidate gets before the round decides which to carry on.
# On the three speed sets (bench/identify_speed.py) the candidate that reached the floor was within
# reach after three (Stribeck 2.07 mrad, a drag 2.27 mrad against 2 mrad of noise).
SCREEN_ITERATIONS = 3
# Noise variances of training fit: a candidate this far behind the floor (or a model at it) is not
# carried on. A tie is within search.MATERIAL_FIT = 0.1, a thirtieth of this.
FAR_BEHIND = 3.0


@dataclass
class Screened:
    """One candidate's short refits: ``[fit, label, finished]`` per start (as
    :func:`effects.refit_candidate` takes them), how low their linearisation reaches after the
    first :data:`SCREEN_ITERATIONS` (mean square, rad²), the lowest mean square those reached
    (``first``), and whether they ran the full :data:`effects.EXPLORE_ITERATIONS`."""

    entries: list[list]
    reach: float
    first: float = float("inf")
    complete: bool = False

    def __post_init__(self):
        if self.entries and self.first == float("inf"):
            self.first = min(entry[0].rmse ** 2 for entry in self.entries)


def explore_round(ctx, current: FitResult, ranking: Sequence[Evidence]) -> list[Screened]:
    """Per candidate of ``ranking``, its linearised starts after :data:`SCREEN_ITERATIONS` LM
    iterations, carried on to :data:`effects.EXPLORE_ITERATIONS` when within reach of the floor."""
    floor = noise_of(ctx.sim, current, ctx.sensor).floor
    out = []
    for number, evidence in enumerate(ranking, 1):
        ctx.say(f"screening candidate {number}/{len(ranking)} {evidence.effect} ({evidence.variant})")
        entries = explore_linearised(ctx.sim, current, evidence, ctx.torque_scale, ctx.x0_starts,
                                     iterations=SCREEN_ITERATIONS)
        screened = Screened(entries, linearised_reach(entries))
        if behind(screened.reach, floor**2, floor) <= FAR_BEHIND:
            carry_on(ctx, evidence, screened)
        out.append(screened)
    return out


def carry_on(ctx, evidence: Evidence, screened: Screened) -> None:
    """Run ``screened``'s unfinished starts on to :data:`effects.EXPLORE_ITERATIONS` iterations."""
    if not screened.complete:
        explore_further(ctx.sim, screened.entries, ctx.torque_scale, EXPLORE_ITERATIONS - SCREEN_ITERATIONS,
                        f"fit +{evidence.effect}")
        screened.complete = True


def behind(mean_square: float, reference: float, floor: float) -> float:
    """How many noise variances (``floor``²) ``mean_square`` is above ``reference`` (both rad²)."""
    return (mean_square - reference) / max(floor**2, 1e-300)


def judging_order(explored: Sequence[Sequence[list]]) -> list[int]:
    """Indices of the candidates, lowest short-refit error first; those without a start last,
    in their ranking order (a stable sort keeps the ranking among equals)."""
    def reached(i: int) -> float:
        return min((entry[0].rmse for entry in explored[i]), default=float("inf"))

    return sorted(range(len(explored)), key=reached)
