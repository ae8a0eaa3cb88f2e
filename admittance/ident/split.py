"""Deterministic, stratified trial splits: held-out trials for the report, validation trials for
the effect search.

Trials are ordered by (bob distance, direction, name) and every third one is taken, starting
with the second: the pick then walks across the distances and alternates the directions, so a
held-out set never lacks a whole load or a whole direction the way a random or contiguous
split can. Deterministic on purpose: the same dataset always gives the same numbers.
"""

from __future__ import annotations

from typing import Sequence

from admittance.formats.dataset import TrialData

STRIDE = 3


def stratified_pick(trials: Sequence[TrialData], stride: int = STRIDE) -> tuple[list[int], list[int]]:
    """(picked, rest) indices into ``trials``: every ``stride``-th in stratified order.

    With fewer than two trials nothing is picked (there would be nothing left to fit on)."""
    if len(trials) < 2:
        return [], list(range(len(trials)))
    order = stratum_order(trials)
    picked = sorted(order[1::stride]) or [order[-1]]
    rest = [i for i in range(len(trials)) if i not in picked]
    return picked, rest


def stratum_order(trials: Sequence[TrialData]) -> list[int]:
    """Indices of ``trials`` sorted by (bob distance, direction, name)."""
    return sorted(range(len(trials)), key=lambda i: _stratum(trials[i]))


def _stratum(trial: TrialData) -> tuple:
    distance = trial.meta.get("bob_distance")
    distance = float(distance) if isinstance(distance, (int, float)) else 0.0
    return (distance, str(trial.meta.get("direction", "")), trial.name)
