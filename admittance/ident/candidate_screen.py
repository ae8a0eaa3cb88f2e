"""The order in which a search round judges its candidates: by a short refit, not by the linear test.

Every candidate of a round is refitted whatever its rank (effects.py), and the refit starts with
a few LM iterations from the starts its linear test suggests (:func:`effects.explore_linearised`).
That first stage is run for all candidates before any is judged, and the candidates are judged
in the order of the error it reached, lowest first; those without a start (the linear test gave
the wrong sign) keep their rank after the others.

Why the order matters: once a candidate's model leaves nothing but sensor noise, the candidates
judged after it can at best tie with it, so the search gives them only their linearised starts
and no cross-validation when they fit the training data materially worse (search._judge's
``at_floor``). The linear test is a poor guide to which candidate that will be: on 30 drops
with a Stribeck term it ranked Stribeck fifth, behind cogging, a friction ripple, a
load-dependent Coulomb level and a drag, each of which then went through its fallback starts,
cross-validation and the regime tests before being refused (105 of 145 s of the search, cProfile
on bench/identify_speed.py's set). After twelve iterations the short refits put Stribeck first.

Nothing is skipped here: every candidate is still judged; the order decides which one sets the
floor the others are measured against, and the first stage's fits are the ones the refit would
have computed anyway (handed on, not repeated). A candidate whose short refits are still far
behind a model at the floor (search.FAR_BEHIND noise variances; a tie needs a thirtieth of that)
is not carried on to convergence (search._far_behind): judged, refused, not refitted further.
"""

from __future__ import annotations

from typing import Sequence

from admittance.ident.effects import Evidence, explore_linearised
from admittance.ident.fit import FitResult


def explore_round(ctx, current: FitResult, ranking: Sequence[Evidence]) -> list[list]:
    """Per candidate of ``ranking``, its linearised starts after a few LM iterations
    (``[fit, label, finished]`` entries, as :func:`effects.refit_candidate` takes them)."""
    out = []
    for number, evidence in enumerate(ranking, 1):
        ctx.say(f"screening candidate {number}/{len(ranking)} {evidence.effect} ({evidence.variant})")
        out.append(explore_linearised(ctx.sim, current, evidence, ctx.torque_scale, ctx.x0_starts))
    return out


def judging_order(explored: Sequence[Sequence[list]]) -> list[int]:
    """Indices of the candidates, lowest short-refit error first; those without a start last,
    in their ranking order (a stable sort keeps the ranking among equals)."""
    def reached(i: int) -> float:
        return min((entry[0].rmse for entry in explored[i]), default=float("inf"))

    return sorted(range(len(explored)), key=reached)
