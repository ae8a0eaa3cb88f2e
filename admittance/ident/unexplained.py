"""The honest verdict on what the library does not explain.

When the final residual still holds structure (it is not what the sensor alone leaves), the
JSON says so in an ``unexplained`` object rather than letting a library name soak it up:

- ``where``: the quantities the residual depends on most (angle, speed, direction of motion,
  time since the start, load torque), each with its bins: the signature of the missing effect;
- ``tried``: every candidate the search refitted, and why each was refused (not physical, not
  significant, no cross-validated gain, not the same in every fold, beaten by another);
- ``stand_ins``: effects admitted because they help prediction although the model with them
  is not one model across operating regimes (:func:`stand_ins`); they stay in the model (its
  predictions are better with them) but are not claimed as the effect at work;
- ``remaining``: what each candidate would still explain of the final residual, linearised.
"""

from __future__ import annotations

from typing import Sequence

from admittance.ident.effects import Evidence

CONTRAST_SHOWN = 1.2  # a dimension is listed when its worst bin is this far above the overall RMS


def where(residual: dict) -> list[dict]:
    """Dimensions ordered by how unevenly the residual spreads over their bins."""
    rmse = residual["rmse"]
    out = []
    for by, rows in residual["bins"].items():
        if not rows or rmse <= 0:
            continue
        worst = max(rows, key=lambda r: r["rms"])
        contrast = worst["rms"] / rmse
        spread = max(r["rms"] for r in rows) / max(min(r["rms"] for r in rows), 1e-300)
        label = worst.get("label") or f"{worst['low']:.3g} to {worst['high']:.3g}"
        out.append({"by": by, "contrast": contrast, "spread": spread, "worst_bin": label,
                    "bins": [{k: v for k, v in r.items()} for r in rows]})
    out.sort(key=lambda d: d["contrast"], reverse=True)
    return out


def tried(rounds: Sequence[Sequence[Evidence]]) -> list[dict]:
    """Each refused candidate of every round, with its reason (the last round's verdict wins)."""
    latest: dict[str, Evidence] = {}
    for round_ in rounds:
        for evidence in round_:
            if not evidence.accepted:
                latest[evidence.effect] = evidence
    return [{"effect": e.effect, "variant": e.variant, "reason": e.reason, "stand_in": e.stand_in,
             "validation_gain": e.validation_gain, "significance_sigma": e.significance,
             "problems": e.problems} for e in latest.values()]


def stand_ins(rounds: Sequence[Sequence[Evidence]], in_model: Sequence[str]) -> list[dict]:
    """The stand-ins the model carries: admitted because they predict better, but the model
    with them is not one model across operating regimes (search.py, test 5)."""
    seen: dict[str, Evidence] = {}
    for round_ in rounds:
        for evidence in round_:
            if evidence.stand_in and evidence.accepted:
                seen[evidence.effect] = evidence
    return [{"effect": e.effect, "variant": e.variant, "validation_gain": e.validation_gain,
             "params": {k: v for k, (v, _) in e.values.items()}, "regimes": e.regimes, "reason": e.reason}
            for name, e in seen.items() if name in in_model]


def describe_unexplained(residual: dict, search, remaining: Sequence[Evidence]) -> dict:
    """The ``unexplained`` object of the JSON (call only when the residual is not just noise)."""
    dims = where(residual)
    shown = [d for d in dims if d["contrast"] >= CONTRAST_SHOWN] or dims[:1]
    rounds = search.rounds if search else []
    lines = [f"the final residual ({1e3 * residual['rmse']:.2f} mrad, {residual['rmse_over_noise']:.1f}× the "
             f"sensor's floor) has structure no admitted effect accounts for"]
    if shown:
        lines.append("it lives mostly in " + ", ".join(f"{d['by']} ({d['worst_bin']}: {d['contrast']:.1f}×)"
                                                        for d in shown))
    if search and search.stopped:
        lines.append(f"the search stopped: {search.stopped}")
    return {
        "summary": "; ".join(lines),
        "residual": {"rmse": residual["rmse"], "floor": residual["noise_estimate"],
                     "ratio": residual["rmse_over_noise"], "white": residual["white"]},
        "where": shown,
        "tried": tried(rounds),
        "stand_ins": stand_ins(rounds, search.stand_ins if search else []),
        "remaining": [{"effect": e.effect, "variant": e.variant, "explained_fraction": e.explained}
                      for e in remaining],
    }
