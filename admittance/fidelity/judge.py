"""Is a servo fit good enough to compensate with? The gate between `fidelity`'s servo model and
the loop's ``servo_compensation``.

A compensation is the fitted model inverted (``plant::servo::lead``): it helps exactly as much as
the model predicts the horn. So the fit passes only when, on the segments it never saw:

- **it predicts the horn much better than the two baselines** `fidelity` already computes
  ("the horn is at its goal", "the horn is at the model's angle"): held-out error at most
  1/``MIN_HELDOUT_GAIN`` of the smaller one. A model that predicts the horn only 2× better than
  "no lag at all" leaves half the lag and adds its own errors;
- **its residual says the form describes the servo**: at most ``MAX_OVER_NOISE`` times the
  noise floor. Whiteness alone is no reason: the tick quantisation of both the goal and the
  read leaves a coloured residual even on a servo the form describes (BAM oracle: Ljung–Box
  p ≈ 1e-31 at 1.1× the floor, compensation 14×; the simulated bench's MX-64, whose duty cap
  the form lacks: 1.45× and not white, compensation 21×). A residual that is not white and
  above ``MISFIT_OVER_NOISE`` is told in `notes` (``misfit_note``) whatever the verdict: the
  form misses an effect, small enough here or not;
- **its parameters are pinned down**: every free parameter's σ finite, the lag's within
  ``MAX_REL_SIGMA_LAG`` of its value (a lag the data do not pin is a lead of unknown size).

A fit that fails is still reported and still written (a parameter file with the model and
``servo_compensation = 0`` in its ``[fit]``, so a joint can turn it on by hand), never used by
default. The thresholds are measured, not guessed: docs/fidelity.md, "when the servo model is
used", gives the figures of the forms the fit describes and of those it does not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

MIN_HELDOUT_GAIN = 4.0
MAX_OVER_NOISE = 2.0
MAX_REL_SIGMA_LAG = 0.2
# Not white and this far above the noise floor: the form misses an effect (a note, not a reason).
MISFIT_OVER_NOISE = 1.2


@dataclass(frozen=True)
class ServoVerdict:
    passed: bool
    reasons: tuple[str, ...]  # why it failed (empty when it passed)
    heldout_gain: float  # the smaller baseline over the held-out error

    def to_json(self) -> dict:
        return {"passed": self.passed, "reasons": list(self.reasons), "heldout_gain": self.heldout_gain,
                "thresholds": {"min_heldout_gain": MIN_HELDOUT_GAIN, "max_over_noise": MAX_OVER_NOISE,
                               "max_rel_sigma_time_constant": MAX_REL_SIGMA_LAG}}


def verdict_line(verdict: dict) -> str:
    """One line for the summary and the parameter file, from ``ServoVerdict.to_json()``."""
    if verdict["passed"]:
        return f"passes (held-out error {verdict['heldout_gain']:.1f}× below the baselines): compensation on"
    return "refused, compensation off: " + "; ".join(verdict["reasons"])


def judge(rmse_heldout: float, baseline: dict[str, float], residual: dict, params: dict[str, float],
          sigma: dict[str, float]) -> ServoVerdict:
    """The verdict on one servo fit (the values of ``ServoFit.to_json``)."""
    reasons = []
    floor = min(baseline.values())
    # No held-out row scored gives an error of exactly 0 (an empty mean), not a perfect model: a
    # fit that was never tested on unseen data is refused, never passed with an infinite gain.
    gain = floor / rmse_heldout if rmse_heldout > 0 and floor > 0 else math.nan
    if not (rmse_heldout > 0 and floor > 0):
        reasons.append("no held-out error measured (no held-out row was scored): nothing shows the model predicts "
                       "the horn on data it did not see")
    elif not gain >= MIN_HELDOUT_GAIN:  # NaN fails
        reasons.append(f"held-out error {1e3 * rmse_heldout:.2f} mrad is only {gain:.1f}× below the baselines' "
                       f"{1e3 * floor:.2f} (needs {MIN_HELDOUT_GAIN:g}×)")
    over = residual.get("rmse_over_noise", math.inf)
    if not over <= MAX_OVER_NOISE:
        reasons.append(f"residual {over:.2f}× the noise floor (at most {MAX_OVER_NOISE:g}×): the form does not "
                       "describe this servo")
    unknown = [name for name, s in sigma.items() if not math.isfinite(s)]
    if unknown:
        reasons.append(f"σ of {', '.join(unknown)} not computable")
    lag, lag_sigma = params["time_constant"], sigma.get("time_constant", math.inf)
    if math.isfinite(lag_sigma) and not lag_sigma <= MAX_REL_SIGMA_LAG * lag:
        reasons.append(f"time_constant {1e3 * lag:.1f} ± {1e3 * lag_sigma:.1f} ms not pinned down "
                       f"(σ at most {100 * MAX_REL_SIGMA_LAG:g} %)")
    return ServoVerdict(not reasons, tuple(reasons), gain)


def misfit_note(residual: dict) -> str | None:
    """A note when the residual says the form misses an effect: not white and above the floor."""
    over = residual.get("rmse_over_noise", 0.0)
    if residual.get("white", True) or not over > MISFIT_OVER_NOISE:
        return None
    largest = residual.get("largest") or {}
    where = f", largest at {largest['by']} {largest['low']:.3g}–{largest['high']:.3g}" \
        if largest.get("by") and largest.get("ratio", 0) > 1.3 else ""
    return (f"the residual is not white (Ljung–Box p = {residual.get('ljung_box_p', float('nan')):.2g}) and "
            f"{over:.2f}× the noise floor{where}: the servo form misses an effect (a geared servo's backlash, "
            "a speed limit...)")
