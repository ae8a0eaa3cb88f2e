"""An effect ladder: chosen models scored by cross-validation, with identify's admission verdict.

``identify`` chooses effects greedily; the ladder asks a narrower question of hand-picked
models. Each rung is the base model plus a list of effects, built up one effect at a time in
the order given; every model is fitted on all but one fold and scored on the fold left out
(only the initial states of its units fitted), and the held-out errors are pooled.

It uses identify's own pieces, so the two cannot disagree by construction: the same base fit
(base.py), the same units and folds (crossval.py: whole trials, or time segments of a few
long trials), the same refit of an added effect from the same starts, and the same admission
tests (search.assess: physical sense, significance, cross-validated gain with its margin and
a majority of folds, the same value in every fold, regime stability). Each rung that adds one
effect to an earlier one says how many folds support it and whether ``identify`` would admit
it, claim it, or keep it only as a stand-in. The difference from ``identify``: the ladder folds
*all* the trials (it reports no separate held-out trial), while ``identify`` keeps its
held-out trials out of the search.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from admittance.errors import ConfigError
from admittance.ident.base import fit_base, search_context, torque_scale_of
from admittance.ident.effects import Evidence, rank_candidates
from admittance.ident.equation_error import fit_equation_error, initial_state_starts
from admittance.ident.fit import fit_initial_states_multi, fit_output_error
from admittance.ident.model import EFFECTS, INDEX, Simulator, free_params, lumped_ratios, physical_params
from admittance.ident.search import Scored, SearchSettings, assess, cross_validate, refit_effect
from admittance.ident.angle_sensor import sensor_for


@dataclass
class Rung:
    """One model of the ladder and its cross-validated errors."""

    effects: tuple[str, ...]
    heldout_rmse: list[float]  # rad, one per fold (pooled over the fold's held-out units)
    pooled_rmse: float  # rad, RMS over every held-out sample
    params: dict[str, float]  # fitted on all trials (SI units; per inertia in lumped mode)
    # Per fold, each effect parameter's value and σ as fitted without the fold (geometry mode;
    # σ is None in lumped mode, where the fit's σ is in sim units): how stable it is.
    fold_values: list[dict[str, tuple[float, float | None]]] = field(default_factory=list)
    fold_names: list[str] = field(default_factory=list)  # what each fold holds out
    support: dict | None = None  # the last effect against the rung without it (crossval.PairedGain)
    verdict: str = ""  # "claimed", "stand-in" or "refused", for the last effect added
    reason: str = ""

    @property
    def label(self) -> str:
        return "base" if not self.effects else "base + " + " + ".join(self.effects)


def effect_ladder(dataset, rungs: Sequence[Sequence[str]], friction: str = "stick",
                  start: dict[str, float] | None = None, max_step: float = 1e-3,
                  min_gain: float = 0.03, min_sigma: float = 3.0) -> list[Rung]:
    """Score each rung (a list of effect names) by cross-validation on ``dataset``.

    ``start`` overrides the starting value of effect parameters (a cogging period the user
    knows, a Stribeck velocity); it applies only to the rungs that free them.
    """
    trials = dataset.trials
    if len(trials) < 2:
        raise ConfigError("the ladder leaves data out: it needs at least two trials")
    _check_rungs(dataset, rungs, start or {})
    torque_scale = torque_scale_of(dataset)
    sensor = sensor_for(trials, dataset.encoder_ticks)
    vector, tau_scale = fit_equation_error(trials, dataset.mode)
    sim = Simulator(trials, dataset.mode, friction, max_step, tau_scale)
    starts = initial_state_starts(trials)
    base, _ = fit_base(sim, vector, free_params(dataset.mode, [], dataset.has_torque), starts, sensor, torque_scale)
    context = search_context(sim, base, sensor, torque_scale, SearchSettings(min_gain=min_gain, min_sigma=min_sigma))
    if context is None:
        raise ConfigError("too few trials (or too short) to form cross-validation folds")
    ctx, base_units = context
    models: dict[tuple[str, ...], tuple[Scored, Evidence | None]] = {(): (cross_validate(ctx, base_units), None)}
    out = []
    for rung in rungs:
        rung = tuple(rung)
        for n in range(1, len(rung) + 1):
            if rung[:n] not in models:
                stand_ins = any(models[rung[:k]][1] is not None and models[rung[:k]][1].stand_in for k in range(1, n))
                models[rung[:n]] = _add(ctx, models[rung[:n - 1]][0], rung[n - 1], start or {}, stand_ins)
        scored, evidence = models[rung]
        out.append(_rung(rung, scored, evidence, ctx, sim, base, dataset))
    return out


def _check_rungs(dataset, rungs, start: dict[str, float]) -> None:
    for name in start:
        if name not in INDEX:
            raise ConfigError(f"--start {name}: not a parameter name")
    for effects in rungs:
        unknown = [e for e in effects if e not in EFFECTS]
        if unknown:
            raise ConfigError(f"unknown effect(s) {', '.join(unknown)} (known: {', '.join(EFFECTS)})")
        geometry_only = [e for e in effects if EFFECTS[e].geometry_only]
        if dataset.mode == "lumped" and geometry_only:
            raise ConfigError(f"{', '.join(geometry_only)} needs geometry: in lumped mode the fit already "
                              "frees the torque's scale (the inverse inertia)")
        needs_torque = [e for e in effects if EFFECTS[e].needs_torque]
        if needs_torque and not dataset.has_torque:
            raise ConfigError(f"{', '.join(needs_torque)} needs trials with a measured torque")


def _add(ctx, current: Scored, effect: str, start: dict[str, float], stand_ins: bool) -> tuple[Scored, Evidence]:
    """``current`` plus ``effect``, refitted as identify refits it, and judged as identify judges it."""
    ranked = rank_candidates(ctx.sim, current.full, [effect], ctx.torque_scale)
    evidence = ranked[0] if ranked else Evidence(effect, params=EFFECTS[effect].params)
    chosen = {k: v for k, v in start.items() if k in EFFECTS[effect].params}
    if chosen:
        evidence.start.update(chosen)
        evidence.plausible = True
        evidence.variant = "start " + ", ".join(f"{k}={v:g}" for k, v in chosen.items())
    refit = refit_effect(ctx, current.full, evidence)
    scored = assess(ctx, current, evidence, refit, stand_ins)
    return (scored if scored is not None else cross_validate(ctx, refit)), evidence


def _rung(effects, scored: Scored, evidence: Evidence | None, ctx, sim: Simulator, base, dataset) -> Rung:
    folds = ctx.folds
    per_fold, names = [], []
    for k in range(folds.n_folds):
        held = folds.held(k)
        res = np.concatenate([scored.residuals[j] for j in held])
        per_fold.append(float(np.sqrt(np.mean(res**2))))
        names.append(" + ".join(folds.data[j].name for j in held))
    everything = _fit_whole(sim, scored.full, base)
    return Rung(
        effects=tuple(effects),
        heldout_rmse=per_fold,
        pooled_rmse=scored.rmse,
        params=_reported(everything, dataset.mode, dataset.has_torque),
        fold_values=[_effect_values(f, effects, dataset.mode) for f in scored.folds],
        fold_names=names,
        support=evidence.crossval if evidence else None,
        verdict=_verdict(evidence),
        reason=evidence.reason if evidence else "",
    )


def _verdict(evidence: Evidence | None) -> str:
    if evidence is None:
        return ""
    if not evidence.accepted:
        return "refused"
    return "stand-in" if evidence.stand_in else "claimed"


def _fit_whole(sim: Simulator, fit, base):
    """The rung's model refitted on the whole trials (its parameters as reported)."""
    sim = sim.with_tau_scale(fit.tau_scale)
    x0 = fit_initial_states_multi(sim, fit.vector, [base.x0]).x0
    return fit_output_error(sim, fit.vector, fit.free, x0, torque_scale=1.0 if sim.mode == "lumped" else
                            float(np.mean([tr.gravity_torque for tr in sim.trials])))


def _reported(fit, mode: str, with_tau: bool) -> dict[str, float]:
    """SI parameters; in lumped mode also the ratios (Γ, and 1/I when a torque is measured)."""
    params = physical_params(fit.vector, mode)
    if mode == "lumped":
        params.update(lumped_ratios(fit.vector, fit.tau_scale if with_tau else None))
    return params


def _effect_values(fit, effects: Sequence[str], mode: str) -> dict[str, tuple[float, float | None]]:
    params = physical_params(fit.vector, mode)
    names = [p for e in effects for p in EFFECTS[e].params]
    return {n: (params[n], fit.sigma.get(n) if mode == "geometry" else None) for n in names}


def to_markdown(rungs: Sequence[Rung], names: Sequence[str] | None = None) -> str:
    """One row per rung: the held-out RMSE per fold, pooled, the verdict, and the key parameters."""
    params = sorted({p for r in rungs for e in r.effects for p in EFFECTS[e].params})
    base = ["motor_inertia", "damping", "coulomb"]
    if "gravity_per_inertia" in rungs[0].params:  # lumped: the per-inertia ratios
        base = [k for k in ("gravity_per_inertia", "inverse_inertia", "damping", "coulomb") if k in rungs[0].params]
    shown = [*base, *params]
    folds = names or [f"fold {k + 1}" for k in range(len(rungs[0].heldout_rmse))]
    head = ["Model", *[f"left out: {n}" for n in folds], "pooled (mrad)", "last effect", *shown]
    lines = ["| " + " | ".join(head) + " |", "|---" * len(head) + "|"]
    for r in rungs:
        cells = [r.label, *[f"{1e3 * v:.2f}" for v in r.heldout_rmse], f"**{1e3 * r.pooled_rmse:.2f}**",
                 _support_cell(r)]
        active = set(base) | {p for e in r.effects for p in EFFECTS[e].params}
        cells += [f"{r.params[p]:.5g}" if p in active else "–" for p in shown]
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "Folds: " + "; ".join(f"{k + 1}: {n}" for k, n in enumerate(rungs[0].fold_names))]
    verdicts = [f"- {r.label}: {r.verdict} ({r.reason})" for r in rungs if r.verdict]
    if verdicts:
        lines += ["", "Verdict on the last effect of each rung (identify's admission tests):", *verdicts]
    per_fold = [_fold_line(r) for r in rungs if r.effects]
    if per_fold:
        lines += ["", "Effect parameters per fold (fitted without the fold, value ± σ):", *per_fold]
    return "\n".join(lines) + "\n"


def _support_cell(rung: Rung) -> str:
    if not rung.support:
        return rung.verdict or "–"
    s = rung.support
    return f"{rung.verdict}, {100 * s['pooled_gain']:.0f} %, {s['folds_supporting']}/{s['folds']} folds"


def _fold_line(rung: Rung) -> str:
    def shown(value: float, sigma: float | None) -> str:
        return f"{value:.5g}" if sigma is None else f"{value:.5g} ± {sigma:.2g}"

    names = list(rung.fold_values[0]) if rung.fold_values else []
    cells = [f"{n} " + " | ".join(shown(*fold[n]) for fold in rung.fold_values) for n in names]
    return f"- {rung.label}: " + "; ".join(cells)


def write_params(rungs: Sequence[Rung], dataset, folder, friction: str = "stick") -> list:
    """One Contract 2 file per rung (geometry mode only), named after its effects."""
    from pathlib import Path

    from admittance.formats import paramfile

    if dataset.mode != "geometry":
        raise ConfigError("parameter files are written for geometry-mode datasets only (the daemon refuses lumped)")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for r in rungs:
        path = folder / ("_".join(("base", *r.effects)) + ".toml")
        model = {"motor": dataset.motor, "friction": friction, "mode": "geometry",
                 "source": f"admittance ladder {dataset.folder}: {r.label}, fitted on all trials"}
        paramfile.dump(path, r.params, model=model, fit={"effects": list(r.effects), "heldout_rmse": r.pooled_rmse,
                                                          "verdict": r.verdict})
        paths.append(path)
    return paths
