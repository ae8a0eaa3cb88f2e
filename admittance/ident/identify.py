"""``identify``: the whole pipeline from a dataset to fitted parameters, effects and scores.

1. Split (split.py): held-out trials for ``rmse_before``/``rmse_after``; the rest train.
   The angle sensor is read from the manifest or the data (sensor.py).
2. Equation error on the training trials gives a start (equation_error.py).
3. Output-error LM of the base model on all training trials (fit.py), from the equation-error
   start and, unless that already leaves nothing but sensor noise, from a small grid over
   friction (:data:`FRICTION_GRID`): the best end point wins.
4. Effect search (search.py) by cross-validation over the training trials only (whole trials,
   or time segments of few long trials: crossval.py), so the held-out trials never influence
   which effects are chosen and their score stays an honest estimate.
5. Refit of the final model on all training trials; both models scored on the held-out trials
   (only their initial states fitted, from several starts, some nearby the data's); residual
   verdict (residual.py) and, when structure is left, what the library could not explain
   (unexplained.py).

Every step logs a one-line progress on stderr unless quiet; the result converts to the JSON of
``datasets.md`` (:meth:`IdentifyResult.to_json`) and to a Contract 2 parameter file.
"""

from __future__ import annotations

import datetime as _dt
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from admittance.errors import ConfigError
from admittance.formats import paramfile
from admittance.ident.base import fit_base, search_context, torque_scale_of
from admittance.ident.crossval import Folds
from admittance.formats.dataset import Dataset
from admittance.ident.datacheck import Finding, screen
from admittance.ident.effects import Evidence, candidate_effects, grown, rank_candidates
from admittance.ident.equation_error import SMOOTH_WINDOW_S, fit_equation_error, initial_state_starts
from admittance.ident.fit import (
    FitResult,
    fit_initial_states_multi,
    fit_output_error,
    nearby_starts,
    rmse,
    screen_starts,
    states_again,
)
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
from admittance.formats.paramfile import PARAM_DEFAULTS
from admittance.ident.residual import analyse
from admittance.ident.search import SearchOutcome, SearchSettings, nothing_left, search_effects
from admittance.ident.angle_sensor import Sensor, sensor_for
from admittance.ident.split import stratified_pick
from admittance.ident.uncertainty import Uncertainty, reported_uncertainty
from admittance.ident.unexplained import describe_unexplained

# s: semi-implicit Euler error is < 0.1 mrad for these pendulums at 1 ms; 2 ms was slower (more LM
# iterations) and less accurate.
FIT_MAX_STEP = 1e-3
# A held-out trial scored this many times worse than the model fits its training trials gets the
# starts nearby its own (_scores).
NEARBY_TRIGGER = 2.0


@dataclass
class IdentifySettings:
    friction: str = "stick"
    max_effects: int = 4
    min_gain: float = 0.03
    min_sigma: float = 3.0
    max_step: float = FIT_MAX_STEP
    quiet: bool = True
    # False: every trial trains and scores (no held-out estimate): for a set too small to spare
    # any, e.g. the halves of a measured set compared in bench/identify_coverage.py.
    hold_out: bool = True

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
    training: list[int]  # indices into the dataset's trials
    base: FitResult  # base model on the training trials
    final: FitResult  # final model on the training trials
    before: FitResult  # held-out scoring of the base model
    after: FitResult  # held-out scoring of the final model
    search: SearchOutcome | None
    remaining: list[Evidence]  # candidates ranked on the final residual (not admitted)
    residual: dict
    sensor: Sensor = field(default_factory=Sensor)
    unexplained: dict | None = None
    base_starts: list[dict] = field(default_factory=list)
    timings: dict = field(default_factory=dict)
    data_checks: list[Finding] = field(default_factory=list)  # what the data checks found (and dropped)
    uncertainty: Uncertainty | None = None  # the reported intervals (uncertainty.py), not the admission σ

    def intervals(self) -> dict | None:
        """The reported uncertainty of the final model: its σ and 95 % intervals, in the units of
        :attr:`params` (``sigma`` in the JSON is the fit's own σ, the one admission tests use)."""
        if self.uncertainty is None:
            return None
        unc = self.uncertainty
        sigma = self.sigma(replace(self.final, sigma=unc.sigma))
        half = unc.multiplier
        params = self.params
        return {**unc.describe(), "sigma": sigma,
                "sigma_jackknife": self.sigma(replace(self.final, sigma=unc.sigma_jackknife)),
                "integration_bias": self.sigma(replace(self.final, sigma=unc.integration)),
                "interval95": {k: [params[k] - half * s, params[k] + half * s] for k, s in sigma.items() if k in params}}

    @property
    def mode(self) -> str:
        return self.dataset.mode

    @property
    def effects(self) -> list[str]:
        """The effects claimed: admitted, and not stand-ins (datasets.md's ``effects``)."""
        return list(self.search.claimed) if self.search else []

    @property
    def model_effects(self) -> list[str]:
        """Every effect in the final model, stand-ins included."""
        return list(self.search.effects) if self.search else []

    @property
    def stand_ins(self) -> list[str]:
        return list(self.search.stand_ins) if self.search else []

    @property
    def folds(self) -> Folds | None:
        return self.search.folds if self.search else None

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

    def crossvalidation(self) -> dict | None:
        """How the search judged effects: its folds and the cross-validated error after each step."""
        if not self.search:
            return None
        folds = self.search.folds
        return {**(folds.describe() if folds else {"kind": None, "folds": 0, "units": 0}),
                "steps": [s.as_dict() for s in self.search.steps], "stopped": self.search.stopped,
                "removed": self.search.removed, "equivalents": self.search.equivalents}

    def to_json(self) -> dict:
        trials = self.dataset.trials
        params = self.params
        search = self.search
        out = {
            "mode": self.mode,
            "friction": self.settings.friction,
            "motor": self.dataset.motor,
            "base": self.base_summary(),
            "effects": self.effects,
            "stand_ins": self.stand_ins,
            "groups": self.search.groups() if self.search else [],
            "model_effects": self.model_effects,
            "params": params,
            "motor_inertia": params["motor_inertia"],
            "damping": params["damping"],
            "coulomb": params["coulomb"],
            "rmse_before": self.before.rmse,
            "rmse_after": self.after.rmse,
            "heldout": [trials[i].name for i in self.heldout],
            "training": [trials[i].name for i in self.training],
            "sensor": self.sensor.as_dict(),
            "sigma": self.sigma(self.final),
            "uncertainty": self.intervals(),
            "training_rmse": {"base": self.base.rmse, "final": self.final.rmse},
            "heldout_rmse_per_trial": {
                trials[i].name: {"before": rmse([rb]), "after": rmse([ra])}
                for i, rb, ra in zip(self.heldout, self.before.residuals, self.after.residuals)
            },
            "base_fit_starts": self.base_starts,
            "crossvalidation": self.crossvalidation(),
            "evidence": [[e.as_dict() for e in round_] for round_ in (search.rounds if search else [])],
            "validation_rmse": search.validation_rmse if search else [],
            "remaining_candidates": [e.as_dict() for e in self.remaining],
            "residual": self.residual,
            "unexplained": self.unexplained,
            "x0": {trials[i].name: [float(v) for v in x] for i, x in zip(self.training, self.final.x0)},
            "timings": self.timings,
            "data_checks": [f.as_dict() for f in self.data_checks],
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
        fit = {"effects": self.effects, "stand_ins": self.stand_ins, "rmse_before": self.before.rmse, "rmse_after": self.after.rmse,
               "heldout": [self.dataset.trials[i].name for i in self.heldout],
               "date": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")}
        paramfile.dump(path, params, model=model, fit=fit)


class _Progress:
    """One self-overwriting line on a terminal (a counter: "round 1: 3/12 stribeck"); on a pipe
    or a log file, one line per phase (an iteration counter rewritten with carriage returns
    would be unreadable there). Nothing in the first second: a clean set is done by then."""

    QUIET_SECONDS = 1.0

    def __init__(self, quiet: bool):
        self.quiet = quiet
        self.width = 0
        self.tty = sys.stderr.isatty()
        self.phase = ""
        self.started = time.perf_counter()

    def __call__(self, message: str) -> None:
        if self.quiet or time.perf_counter() - self.started < self.QUIET_SECONDS:
            return
        line = f"identify: {message}"
        if not self.tty:
            phase = message.split(":")[0]
            if phase != self.phase:
                print(line, file=sys.stderr)
                self.phase = phase
            return
        sys.stderr.write("\r" + line[:119].ljust(self.width))
        sys.stderr.flush()
        self.width = min(len(line), 119)

    def note(self, message: str) -> None:
        """A line that stays (a data-check finding), even between self-overwriting ones."""
        if self.quiet:
            return
        if self.tty and self.width:
            sys.stderr.write("\r" + " " * self.width + "\r")
            self.width = 0
        print(f"identify: {message}", file=sys.stderr)

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
        with one_blas_thread():
            result = _run(dataset, settings, progress, timings)
    finally:
        progress.done()
    timings["total"] = time.perf_counter() - clock
    return result


def one_blas_thread():
    """NumPy's BLAS limited to one thread while identifying (restored after).

    Why: the identification's linear algebra is small (normal equations of about 70 unknowns, a
    trial's Jacobian products of a few rows by a thousand samples), too small to gain from
    threads, while the Rust plant's own threads keep the cores busy; BLAS threads that wake
    and spin beside them take cores from the simulations. Measured on 30 drops with a drag,
    another job on the 2 cores: 2.9–3.0 s of CPU against 3.5–3.7 s with BLAS's default threads
    (docs/identification-speed-log.md, *Parameter sets side by side*). The results do not
    change (the products are the same sums on one thread; tests/test_ident_blas.py)."""
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=1, user_api="blas")


@contextmanager
def _timed(timings: dict, phase: str):
    tick = time.perf_counter()
    yield
    timings[phase] = time.perf_counter() - tick


def _run(dataset: Dataset, settings: IdentifySettings, progress: _Progress, timings: dict) -> IdentifyResult:
    with _timed(timings, "data_checks"):
        dataset, findings = screen(dataset, progress.note)
    trials = dataset.trials
    heldout, training = stratified_pick(trials) if settings.hold_out else ([], list(range(len(trials))))
    if not heldout:  # a single trial: score on it, and say so in the JSON (heldout == training)
        heldout = list(training)
    torque_scale = torque_scale_of(dataset)
    with _timed(timings, "equation_error"):
        progress("equation-error start")
        sensor = sensor_for(trials, dataset.encoder_ticks)
        start, tau_scale = fit_equation_error([trials[i] for i in training], dataset.mode)
        starts_all = initial_state_starts(trials)
        sim_all = Simulator(trials, dataset.mode, settings.friction, settings.max_step, tau_scale)
        sim_train, sim_held = sim_all.subset(training), sim_all.subset(heldout)
    with _timed(timings, "base_fit"):
        free = free_params(dataset.mode, [], dataset.has_torque)
        base, base_starts = fit_base(sim_train, start, free, [s[training] for s in starts_all], sensor,
                                      torque_scale, progress)
    with _timed(timings, "effect_search"):
        search = _search(sim_train, base, sensor, torque_scale, settings, progress)
    with _timed(timings, "final_fit_and_scoring"):
        final = _final_fit(sim_train, base, search, torque_scale, progress, [s[training] for s in starts_all])
        before, after = _scores(sim_held, base, final, [s[heldout] for s in starts_all], sensor, progress)
    with _timed(timings, "uncertainty"):
        progress("uncertainty: refits at half the step and without each group of trials")
        uncertainty = reported_uncertainty(sim_train, final, torque_scale)
    with _timed(timings, "residual_analysis"):
        progress("residual analysis")
        residual = analyse(sim_train, final, sensor)
        effects = search.effects if search else []
        remaining, unexplained = [], None
        # Ranking what is left only matters when something is left (it is the costliest batch).
        if not residual["nothing_left"]:
            remaining = rank_candidates(sim_train, final, candidate_effects(effects, dataset.has_torque,
                                                                            dataset.mode), torque_scale)
            unexplained = describe_unexplained(residual, search, remaining)
    return IdentifyResult(dataset, settings, heldout, training, base, final, before, after, search,
                          remaining, residual, sensor, unexplained, base_starts, timings, findings, uncertainty)


def _scores(sim_held: Simulator, base: FitResult, final: FitResult, data_starts: list[np.ndarray], sensor: Sensor,
            progress) -> tuple[FitResult, FitResult]:
    """The base and the final model scored on the held-out trials: each trial's initial state
    fitted under the model from the data's candidate starts screened in one batch (the final
    model also from the base model's states), each trial keeping its best.

    A held-out trial that the model then fits more than :data:`NEARBY_TRIGGER` times worse than
    its own training trials (or the sensor's grid, if coarser) may be in the wrong basin of its
    initial state (fit.nearby_starts): the starts nearby the data's are screened too, and each
    trial keeps the better. (Nearby the fitted states instead, on the set of
    tests/test_ident_scoring.py: 2.60 mrad held out, against 0.83.) Their steps are the same
    for both models: the angle to within the final model's training error (or the grid), the
    velocity to within what that error leaves of a velocity smoothed over
    :data:`SMOOTH_WINDOW_S`."""
    angle = max(final.rmse, sensor.quantum)
    rate = angle / SMOOTH_WINDOW_S

    def score(fit: FitResult, more: list[np.ndarray]) -> FitResult:
        sim = sim_held.with_tau_scale(fit.tau_scale)
        picked = screen_starts(sim, fit.vector, data_starts)
        scored = fit_initial_states_multi(sim, fit.vector, [picked, *more], progress=progress, label="scoring")
        if max(rmse([r]) for r in scored.residuals) <= NEARBY_TRIGGER * max(fit.rmse, sensor.quantum):
            return scored
        nearby = screen_starts(sim, fit.vector, [picked, *nearby_starts(picked, angle, rate)])
        return fit_initial_states_multi(sim, fit.vector, [scored.x0, nearby], progress=progress, label="scoring")

    before = score(base, [])
    return before, before if final is base else score(final, [before.x0])


def _search(sim_train: Simulator, base: FitResult, sensor: Sensor, torque_scale: float,
            settings: IdentifySettings, progress) -> SearchOutcome | None:
    """The effect search, cross-validated on the training trials (None when it cannot run)."""
    if settings.max_effects == 0:
        return None
    if nothing_left(sim_train, base, sensor):
        return SearchOutcome([], base, [], [], None, stopped="nothing left: the residual is at the sensor's noise")
    search_settings = SearchSettings(settings.max_effects, settings.min_gain, settings.min_sigma)
    context = search_context(sim_train, base, sensor, torque_scale, search_settings, progress)
    if context is None:
        return SearchOutcome([], base, [], [], None, stopped="too few trials to cross-validate")
    return search_effects(*context)


def _final_fit(sim_train: Simulator, base: FitResult, search: SearchOutcome | None, torque_scale: float,
               progress, x0_starts: list[np.ndarray]) -> FitResult:
    """The model with the admitted effects, refitted on all training trials. ``x0_starts``: the
    data's own candidate initial states of the training trials (equation_error.initial_state_starts)."""
    if not search or not search.effects:
        return base
    sim = sim_train.with_tau_scale(search.fit.tau_scale)
    best = None
    for start in _restarts(search.fit.vector, search.effects):
        # The initial states are refitted to the new model first (cheap, three simulations per
        # trial and iteration) so the joint fit starts near its optimum: from the base model's
        # states and from the data's own starts screened under the new model, each trial keeping
        # its best. From the base model's alone, an effect that changes where the joint sticks
        # (Stribeck at 1.5x the Coulomb level, 30 drops) left 8 of 20 training trials at 4-9 mrad
        # in a wrong basin while the held-out trials, scored from the data's starts, were at the
        # 2 mrad noise: the residual verdict then judged a fit short of its optimum.
        x0 = states_again(sim, start, base.x0, x0_starts, label="final fit")
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
