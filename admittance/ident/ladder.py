"""An effect ladder scored by leave-one-trial-out: which effects a small real dataset supports.

``identify`` chooses effects greedily on one inner split, which is the right tool for a
thesis-sized set (30 trials). A real dataset may hold three or four trials; a single split then
leaves one trial to judge every choice, and an effect with a free shape (cogging's period, a
Stribeck velocity) can fit that trial's quirks. The ladder asks a narrower question of
hand-picked models: fit each on all trials but one, predict the one left out (only its initial
state fitted), and pool the held-out errors over every fold. Each rung is the base model plus
a list of effects, so "before" and "after" for one effect are two rows of the same table.

It reuses the core's pieces unchanged (equation-error start, the batch ``Simulator``, the
output-error LM, held-out scoring), so its numbers are comparable with ``identify``'s.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from admittance.errors import ConfigError
from admittance.ident.equation_error import fit_equation_error, initial_states
from admittance.ident.fit import fit_initial_states_multi, fit_output_error
from admittance.ident.model import EFFECTS, INDEX, Simulator, free_params, lumped_ratios, physical_params


@dataclass
class Rung:
    """One model of the ladder and its held-out errors."""

    effects: tuple[str, ...]
    heldout_rmse: list[float]  # rad, one per left-out trial
    pooled_rmse: float  # rad, RMS over every held-out sample
    params: dict[str, float]  # fitted on all trials (SI units; per inertia in lumped mode)
    # Per fold, each effect parameter's value and σ as fitted on the other trials (geometry
    # mode; σ is None in lumped mode, where the fit's σ is in sim units): how stable it is.
    fold_values: list[dict[str, tuple[float, float | None]]] = field(default_factory=list)

    @property
    def label(self) -> str:
        return "base" if not self.effects else "base + " + " + ".join(self.effects)


def effect_ladder(dataset, rungs: Sequence[Sequence[str]], friction: str = "stick",
                  start: dict[str, float] | None = None, max_step: float = 1e-3) -> list[Rung]:
    """Score each rung (a list of effect names) by leave-one-trial-out on ``dataset``.

    ``start`` sets starting values of effect parameters whose zero is a dead point of the fit
    (``cogging_period``, ``stribeck_velocity``); it applies only to the rungs that free them.
    """
    trials = dataset.trials
    if len(trials) < 2:
        raise ConfigError("the ladder leaves one trial out: it needs at least two trials")
    for effects in rungs:
        unknown = [e for e in effects if e not in EFFECTS]
        if unknown:
            raise ConfigError(f"unknown effect(s) {', '.join(unknown)} (known: {', '.join(EFFECTS)})")
        geometry_only = [e for e in effects if EFFECTS[e].geometry_only]
        if dataset.mode == "lumped" and geometry_only:
            raise ConfigError(f"{', '.join(geometry_only)} needs geometry: in lumped mode the fit already "
                              "frees the torque's scale (the inverse inertia)")
    with_tau = dataset.has_torque
    torque_scale = 1.0
    if dataset.mode == "geometry":
        torque_scale = float(np.mean([tr.gravity_torque for tr in trials])) or 1.0
    x0_all = initial_states(trials)
    out = []
    for effects in rungs:
        free = free_params(dataset.mode, effects, with_tau)
        folds = [_fold(dataset, k, free, start, x0_all, friction, max_step, torque_scale) for k in range(len(trials))]
        residuals = np.concatenate([r for _, r, _ in folds])
        everything = _fit(dataset, list(range(len(trials))), free, start, x0_all, friction, max_step, torque_scale)
        out.append(Rung(
            effects=tuple(effects),
            heldout_rmse=[float(np.sqrt(np.mean(r**2))) for _, r, _ in folds],
            pooled_rmse=float(np.sqrt(np.mean(residuals**2))),
            params=_reported(everything, dataset.mode, with_tau),
            fold_values=[_effect_values(fit, effects, dataset.mode) for _, _, fit in folds],
        ))
    return out


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


def _fit(dataset, indices, free, start, x0_all, friction, max_step, torque_scale):
    chosen = [dataset.trials[i] for i in indices]
    vector, tau_scale = fit_equation_error(chosen, dataset.mode)
    for name, value in (start or {}).items():
        if name not in INDEX:
            raise ConfigError(f"--start {name}: not a parameter name")
        if name in free:  # a rung without the effect keeps the parameter at its default
            vector[INDEX[name]] = value
    sim = Simulator(chosen, dataset.mode, friction, max_step, tau_scale)
    return fit_output_error(sim, vector, free, x0_all[indices], torque_scale=torque_scale)


def _fold(dataset, k, free, start, x0_all, friction, max_step, torque_scale):
    training = [i for i in range(len(dataset.trials)) if i != k]
    fit = _fit(dataset, training, free, start, x0_all, friction, max_step, torque_scale)
    held = Simulator([dataset.trials[k]], dataset.mode, friction, max_step, fit.tau_scale)
    scored = fit_initial_states_multi(held, fit.vector, [x0_all[[k]]], tau_scale=fit.tau_scale)
    return scored, scored.residuals[0], fit


def to_markdown(rungs: Sequence[Rung], names: Sequence[str]) -> str:
    """One row per rung: the held-out RMSE per left-out trial, pooled, and the key parameters."""
    params = sorted({p for r in rungs for e in r.effects for p in EFFECTS[e].params})
    base = ["motor_inertia", "damping", "coulomb"]
    if "gravity_per_inertia" in rungs[0].params:  # lumped: the per-inertia ratios
        base = [k for k in ("gravity_per_inertia", "inverse_inertia", "damping", "coulomb") if k in rungs[0].params]
    shown = [*base, *params]
    head = ["Model", *[f"left out: {n}" for n in names], "pooled (mrad)", *shown]
    lines = ["| " + " | ".join(head) + " |", "|---" * len(head) + "|"]
    for r in rungs:
        cells = [r.label, *[f"{1e3 * v:.2f}" for v in r.heldout_rmse], f"**{1e3 * r.pooled_rmse:.2f}**"]
        active = set(base) | {p for e in r.effects for p in EFFECTS[e].params}
        cells += [f"{r.params[p]:.5g}" if p in active else "–" for p in shown]
        lines.append("| " + " | ".join(cells) + " |")
    folds = [_fold_line(r) for r in rungs if r.effects]
    if folds:
        lines += ["", "Effect parameters per fold (fitted without the left-out trial, value ± σ):", *folds]
    return "\n".join(lines) + "\n"


def _fold_line(rung: Rung) -> str:
    def shown(value: float, sigma: float | None) -> str:
        return f"{value:.5g}" if sigma is None else f"{value:.5g} ± {sigma:.2g}"

    names = list(rung.fold_values[0]) if rung.fold_values else []
    cells = [f"{n} " + " | ".join(shown(*fold[n]) for fold in rung.fold_values) for n in names]
    return f"- {rung.label}: " + "; ".join(cells)


def write_params(rungs: Sequence[Rung], dataset, folder, friction: str = "stick") -> list:
    """One Contract 2 file per rung (geometry mode only), named after its effects."""
    from pathlib import Path

    from admittance.ident import paramfile

    if dataset.mode != "geometry":
        raise ConfigError("parameter files are written for geometry-mode datasets only (the daemon refuses lumped)")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for r in rungs:
        path = folder / ("_".join(("base", *r.effects)) + ".toml")
        model = {"motor": dataset.motor, "friction": friction, "mode": "geometry",
                 "source": f"admittance ladder {dataset.folder}: {r.label}, fitted on all trials"}
        paramfile.dump(path, r.params, model=model, fit={"effects": list(r.effects), "heldout_rmse": r.pooled_rmse})
        paths.append(path)
    return paths
