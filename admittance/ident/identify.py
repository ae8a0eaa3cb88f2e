"""``identify``: the whole pipeline from a dataset to fitted parameters, effects and scores.

1. Split (split.py): held-out trials for ``rmse_before``/``rmse_after``; the rest train.
2. Equation error on the training trials gives a start (equation_error.py).
3. Output-error LM of the base model on all training trials (fit.py).
4. Effect search (effects.py) on an inner split of the training trials: a fitting part and a
   validation part, so the held-out trials never influence which effects are chosen and their
   score stays an honest estimate.
5. Refit of the final model on all training trials; both models scored on the held-out trials
   (only their initial states fitted); residual verdict (residual.py).

Every step logs a one-line progress on stderr unless quiet; the result converts to the JSON of
``datasets.md`` (:meth:`IdentifyResult.to_json`) and to a Contract 2 parameter file.
"""

from __future__ import annotations

import datetime as _dt
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from admittance.errors import ConfigError
from admittance.ident import paramfile
from admittance.ident.dataset import Dataset
from admittance.ident.effects import Evidence, SearchOutcome, SearchSettings, candidate_effects, rank_candidates
from admittance.ident.effects import grown, nothing_left, score, search_effects
from admittance.ident.equation_error import fit_equation_error, initial_states
from admittance.ident.fit import FitResult, fit_initial_states, fit_output_error, rmse
from admittance.ident.model import (
    EFFECTS,
    INDEX,
    TAU_SCALE,
    TORQUE_PARAMS,
    Simulator,
    free_params,
    lumped_ratios,
    physical_params,
)
from admittance.ident.paramfile import PARAM_DEFAULTS
from admittance.ident.residual import analyse
from admittance.ident.split import stratified_pick

# s: semi-implicit Euler error is < 0.1 mrad for these pendulums at 1 ms; 2 ms was slower (more LM
# iterations) and less accurate.
FIT_MAX_STEP = 1e-3


@dataclass
class IdentifySettings:
    friction: str = "stick"
    max_effects: int = 4
    min_gain: float = 0.03
    min_sigma: float = 3.0
    max_step: float = FIT_MAX_STEP
    quiet: bool = True

    def __post_init__(self):
        if self.friction not in paramfile.FRICTION_LAWS:
            raise ConfigError(f"friction must be one of {paramfile.FRICTION_LAWS}, got {self.friction!r}")
        if self.max_effects < 0:
            raise ConfigError(f"max_effects must be >= 0, got {self.max_effects}")


@dataclass
class IdentifyResult:
    dataset: Dataset
    settings: IdentifySettings
    heldout: list[int]
    training: list[int]
    validation: list[int]  # indices into the dataset's trials
    base: FitResult  # base model on the training trials
    final: FitResult  # final model on the training trials
    before: FitResult  # held-out scoring of the base model
    after: FitResult  # held-out scoring of the final model
    search: SearchOutcome | None
    remaining: list[Evidence]  # candidates ranked on the final residual (not admitted)
    residual: dict
    timings: dict = field(default_factory=dict)

    @property
    def mode(self) -> str:
        return self.dataset.mode

    @property
    def effects(self) -> list[str]:
        return list(self.search.effects) if self.search else []

    @property
    def params(self) -> dict[str, float]:
        """Every parameter of the final model, Contract 1 names, SI (lumped: per inertia)."""
        return physical_params(self.final.vector, self.mode)

    @property
    def base_params(self) -> dict[str, float]:
        return physical_params(self.base.vector, self.mode)

    def sigma(self, fit: FitResult) -> dict[str, float]:
        """Standard errors in the units of :attr:`params`."""
        if self.mode != "lumped":
            return {k: v for k, v in fit.sigma.items() if k != TAU_SCALE}
        gamma = 1.0 / fit.vector[INDEX["motor_inertia"]]
        return {k: (v * gamma if k in TORQUE_PARAMS else v) for k, v in fit.sigma.items()
                if k not in (TAU_SCALE, "motor_inertia")}

    def lumped(self, fit: FitResult) -> dict[str, float]:
        """The identifiable ratios of a lumped-mode fit (with κ when the trials carry a torque)."""
        return lumped_ratios(fit.vector, fit.tau_scale if self.dataset.has_torque else None)

    def base_summary(self) -> dict[str, float]:
        if self.mode == "lumped":
            return self.lumped(self.base)
        p = self.base_params
        return {k: p[k] for k in ("motor_inertia", "damping", "coulomb")}

    def to_json(self) -> dict:
        trials = self.dataset.trials
        params = self.params
        out = {
            "mode": self.mode,
            "friction": self.settings.friction,
            "motor": self.dataset.motor,
            "base": self.base_summary(),
            "effects": self.effects,
            "params": params,
            "motor_inertia": params["motor_inertia"],
            "damping": params["damping"],
            "coulomb": params["coulomb"],
            "rmse_before": self.before.rmse,
            "rmse_after": self.after.rmse,
            "heldout": [trials[i].name for i in self.heldout],
            "training": [trials[i].name for i in self.training],
            "validation": [trials[i].name for i in self.validation],
            "sigma": self.sigma(self.final),
            "training_rmse": {"base": self.base.rmse, "final": self.final.rmse},
            "heldout_rmse_per_trial": {
                trials[i].name: {"before": rmse([rb]), "after": rmse([ra])}
                for i, rb, ra in zip(self.heldout, self.before.residuals, self.after.residuals)
            },
            "evidence": [[e.as_dict() for e in round_] for round_ in (self.search.rounds if self.search else [])],
            "validation_rmse": self.search.validation_rmse if self.search else [],
            "remaining_candidates": [e.as_dict() for e in self.remaining],
            "residual": self.residual,
            "x0": {trials[i].name: [float(v) for v in x] for i, x in zip(self.training, self.final.x0)},
            "timings": self.timings,
        }
        if self.mode == "lumped":
            out["lumped"] = self.lumped(self.final)
        return out

    def write_params(self, path: str | Path, source: str = "") -> None:
        """The final model as a Contract 2 parameter file."""
        defaults = {k: (v if v is not None else np.nan) for k, v in PARAM_DEFAULTS.items()}
        params = {k: v for k, v in self.params.items() if k == "motor_inertia" or v != defaults[k]}
        model = {"motor": self.dataset.motor, "friction": self.settings.friction, "mode": self.mode,
                 "source": source or f"admittance identify {self.dataset.folder}"}
        if self.mode == "lumped":
            model.update(self.lumped(self.final))
        fit = {"effects": self.effects, "rmse_before": self.before.rmse, "rmse_after": self.after.rmse,
               "heldout": [self.dataset.trials[i].name for i in self.heldout],
               "date": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")}
        paramfile.dump(path, params, model=model, fit=fit)


class _Progress:
    """One self-overwriting line on a terminal; on a pipe or a log file, one line per phase
    (an iteration counter rewritten with carriage returns would be unreadable there)."""

    def __init__(self, quiet: bool):
        self.quiet = quiet
        self.width = 0
        self.tty = sys.stderr.isatty()
        self.phase = ""

    def __call__(self, message: str) -> None:
        if self.quiet:
            return
        line = f"identify: {message}"
        if not self.tty:
            phase = message.split(":")[0]
            if phase != self.phase:
                print(line, file=sys.stderr)
                self.phase = phase
            return
        sys.stderr.write("\r" + line.ljust(self.width))
        sys.stderr.flush()
        self.width = len(line)

    def done(self) -> None:
        if self.tty and not self.quiet and self.width:
            sys.stderr.write("\r" + " " * self.width + "\r")
            sys.stderr.flush()


def identify_dataset(dataset: Dataset, settings: IdentifySettings | None = None) -> IdentifyResult:
    """Fit the base model, search for effects, score on held-out trials."""
    settings = settings or IdentifySettings()
    progress = _Progress(settings.quiet)
    timings: dict[str, float] = {}
    clock = time.perf_counter()
    try:
        result = _run(dataset, settings, progress, timings)
    finally:
        progress.done()
    timings["total"] = time.perf_counter() - clock
    return result


@contextmanager
def _timed(timings: dict, phase: str):
    tick = time.perf_counter()
    yield
    timings[phase] = time.perf_counter() - tick


def _run(dataset: Dataset, settings: IdentifySettings, progress: _Progress, timings: dict) -> IdentifyResult:
    trials = dataset.trials
    heldout, training = stratified_pick(trials)
    if not heldout:  # a single trial: score on it, and say so in the JSON (heldout == training)
        heldout = list(training)
    torque_scale = _torque_scale(dataset)
    with _timed(timings, "equation_error"):
        progress("equation-error start")
        start, tau_scale = fit_equation_error([trials[i] for i in training], dataset.mode)
        x0_all = initial_states(trials)
        sim_all = Simulator(trials, dataset.mode, settings.friction, settings.max_step, tau_scale)
        sim_train, sim_held = sim_all.subset(training), sim_all.subset(heldout)
    with _timed(timings, "base_fit"):
        base = fit_output_error(sim_train, start, free_params(dataset.mode, [], dataset.has_torque),
                                x0_all[training], torque_scale=torque_scale, progress=progress, label="base fit")
    with _timed(timings, "effect_search"):
        search, validation = _search(sim_train, training, base, torque_scale, settings, progress)
    with _timed(timings, "final_fit_and_scoring"):
        final = _final_fit(sim_train, base, search, torque_scale, progress)
        before = score(sim_held, base, x0_all[heldout], progress=progress)
        after = before if final is base else score(sim_held, final, before.x0, progress=progress)
    with _timed(timings, "residual_analysis"):
        progress("residual analysis")
        effects = search.effects if search else []
        # Ranking what is left only matters when something is left (it is the costliest batch).
        remaining = [] if nothing_left(final) else rank_candidates(
            sim_train, final, candidate_effects(effects, dataset.has_torque, dataset.mode), torque_scale)
        residual = analyse(sim_train, final)
    return IdentifyResult(dataset, settings, heldout, training, validation, base, final, before, after, search,
                          remaining, residual, timings)


def _torque_scale(dataset: Dataset) -> float:
    """A typical torque of the problem (N·m; 1 in lumped sim units): sets finite-difference steps."""
    if dataset.mode != "geometry":
        return 1.0
    scale = float(np.mean([tr.gravity_torque for tr in dataset.trials]))
    return scale if scale > 0 else 1.0


def _final_fit(sim_train: Simulator, base: FitResult, search: SearchOutcome | None, torque_scale: float,
               progress) -> FitResult:
    """The model with the admitted effects, refitted on all training trials."""
    if not search or not search.effects:
        return base
    sim = sim_train.with_tau_scale(search.fit.tau_scale)
    best = None
    for start in _restarts(search.fit.vector, search.effects):
        # The initial states belong to the base model; refit them to the new model first (cheap,
        # three simulations per trial and iteration) so the joint fit starts near its optimum.
        x0 = fit_initial_states(sim, start, base.x0, label="final fit").x0
        fit = fit_output_error(sim, start, search.fit.free, x0, torque_scale=torque_scale, progress=progress,
                               label="final fit")
        if best is None or fit.rmse < best.rmse:
            best = fit
    return best


def _restarts(vector: np.ndarray, effects: list[str]) -> list[np.ndarray]:
    """The search's values, and the same with the effects grown (see effects.grown)."""
    names = [n for effect in effects for n in EFFECTS[effect].evidence]
    doubled = vector.copy()
    for name, value in grown({n: vector[INDEX[n]] for n in names}, effects).items():
        doubled[INDEX[name]] = value
    return [vector, doubled]


def _search(sim_train: Simulator, training: list[int], base: FitResult, torque_scale: float,
            settings: IdentifySettings, progress) -> tuple[SearchOutcome | None, list[int]]:
    """The effect search on an inner split of the training trials (None if too few trials).
    A base residual that is already white noise ends it before the inner split is even fitted."""
    if settings.max_effects == 0:
        return None, []
    if nothing_left(base):
        return SearchOutcome([], base, [], []), []
    val_local, fit_local = stratified_pick(sim_train.trials)
    if not val_local or not fit_local:
        return None, []
    fit_sim = sim_train.subset(fit_local)
    val_sim = sim_train.subset(val_local)
    progress("base fit on the search split")
    inner = fit_output_error(fit_sim.with_tau_scale(base.tau_scale), base.vector, base.free, base.x0[fit_local],
                             torque_scale=torque_scale, progress=progress, label="search-split fit")
    search_settings = SearchSettings(settings.max_effects, settings.min_gain, settings.min_sigma)
    outcome = search_effects(fit_sim, val_sim, inner, base.x0[val_local], torque_scale, search_settings,
                             progress)
    return outcome, [training[i] for i in val_local]
