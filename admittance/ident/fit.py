"""Output-error fit: a structured Levenberg–Marquardt over shared parameters and per-trial
initial states, with every Jacobian from ONE batch simulation.

The unknowns are the model's free parameters g (shared by all trials) and each trial's initial
state x0_k = (θ0, ω0). The residual is simulated θ − measured θ over every sample of every trial.

Why a hand-written LM instead of ``scipy.optimize.least_squares``:

- **One simulation call per Jacobian.** A forward-difference Jacobian needs the trials simulated
  under 1 + n_g + 2 parameter sets, not 1 + n_g + 2·T: a trial's x0 only moves that trial, so
  one row perturbs θ0 of *every* trial at once and another ω0, and each trial's column is read
  off its own block. The rows go to ``_rtcore.simulate_batch`` together (parallel, no GIL).
  ``least_squares`` would ask for the residual and the Jacobian separately and treat the
  x0 columns as 2·T unrelated ones.
- **The normal equations by blocks.** Jᵀ J is assembled trial by trial (global×global,
  global×own x0, own x0×own x0) without forming the dense m × (n_g + 2T) Jacobian (tens of MB
  on a thesis-sized set) or taking its SVD each iteration; the n × n system that is left
  (n ≈ 70 for 30 trials) is solved directly.
- **Bounds by projection.** Damping and friction live on [0, ∞) and often sit at 0 on clean
  data; a projected step (clip, then accept only if the cost falls) keeps them there without
  a log-reparameterisation that could never reach 0.

Parameter uncertainty: σ from (JᵀJ)⁻¹ scaled by the residual variance *and* by the residual's
integrated autocorrelation time. Output-error residuals are smooth (model error, not white
noise), so the textbook σ, which assumes independent samples, would be too small by about
√τ_int and make every candidate effect look significant.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Callable, Iterator, Sequence

import numpy as np

from admittance.ident.model import INDEX, TAU_SCALE, Simulator, bounds_for

# Forward-difference steps: relative to the value, with a floor in each parameter's own units
# (torque floors are relative to the problem's torque scale, see _step_floor). The steps are
# deliberately large (1 %): with Coulomb friction the simulated angle is continuous in the
# parameters but has kinks (whether the joint sticks at a turning point, how long it creeps
# near the edge of the stick band), and tiny steps land on one side of a kink and give a
# Jacobian that the next iteration contradicts. Measured on 30 synthetic thesis-like trials:
# steps of 1e-3 stalled LM for 60 iterations, 1e-2 converged in 9 to the noise floor.
REL_STEP = 1e-2
THETA0_STEP = 1e-3  # rad
OMEGA0_STEP = 1e-2  # rad/s
ABS_STEP = {
    "angle_offset": 1e-3,
    "stribeck_velocity": 1e-2,
    "cogging_phase": 1e-2,
    "cogging_period": 1e-2,
    "time_delay": 2e-3,
    "load_coulomb": 1e-3,
    "tanh_k": 1.0,
    "torque_gain": 1e-3,
    "spring_neutral": 1e-3,
    "friction_ripple_phase": 1e-2,
    "friction_ripple_period": 1e-2,
}

# How Jacobians are computed: "differences" (the 1 % steps above, one batch) or "sensitivities"
# (the Rust plant's forward sensitivities, one pass per trial: rtcore/plant/src/sensitivity.rs).
# The tangent is the exact derivative of the branch the plant took, and that is what loses: on
# 30 drops with a Stribeck term (bench/identify_speed.py's set) LM with exact derivatives
# stalled in worse optima, Stribeck ended a stand-in instead of named, its torque 3.8 of its σ
# from the finite-difference fit's, and the CPU time was 3× higher
# (docs/identification-speed-log.md, *With an effect in the data*).
# The 1 % chords step over the kinks of stick friction; the tangent sees every kink.
JACOBIAN = "differences"

Progress = Callable[[str], None]
# A damped step predicted to gain less than this fraction of the stopping tolerance ends the fit.
CONVERGED_FRACTION = 0.1
# Dampings simulated per batch in an LM iteration once its first try has failed (_lm_step).
LOOKAHEAD = 4


@dataclass
class FitResult:
    vector: np.ndarray  # the full Contract 1 parameter vector (sim units)
    tau_scale: float
    free: tuple[str, ...]
    sigma: dict[str, float]
    x0: np.ndarray  # (T, 2)
    residuals: list[np.ndarray]
    iterations: int
    simulations: int
    seconds: float
    jacobian: list[np.ndarray] = field(repr=False, default_factory=list)  # per trial (n_g+2, n_k)
    damping: float = 1e-3  # the LM's damping at the end: a fit carried on from here starts with it
    # The covariance of the free globals, computed when first asked for (see _Covariance).
    uncertainty: "_Covariance | None" = field(repr=False, default=None)
    # Where it ended with the Jacobian taken there (it stopped on a failed step), else None: a
    # fit started exactly there can take both (EndPoint).
    end_point: "EndPoint | None" = field(repr=False, default=None)
    # (simulator, sensor, verdict) of each noise verdict asked of this fit (residual.noise_of):
    # the search asks the same fit up to four times. Not an __init__ field, so a fit made by
    # dataclasses.replace starts with none.
    noise_verdicts: list = field(repr=False, default_factory=list, init=False, compare=False)

    @property
    def covariance(self) -> np.ndarray:
        return self.uncertainty.globals() if self.uncertainty is not None else np.zeros((0, 0))

    @property
    def rmse(self) -> float:
        return rmse(self.residuals)

    def value(self, name: str) -> float:
        return self.tau_scale if name == TAU_SCALE else float(self.vector[INDEX[name]])


def rmse(residuals: Sequence[np.ndarray]) -> float:
    total = sum(float(np.dot(r, r)) for r in residuals)
    count = sum(r.size for r in residuals)
    return float(np.sqrt(total / max(count, 1)))


class _Problem:
    """Maps the unknown vector z = [g, x0 flat] to simulations and residuals."""

    def __init__(self, sim: Simulator, vector: np.ndarray, free: Sequence[str], fit_x0: bool, torque_scale: float):
        self.sim = sim
        self.vector = np.asarray(vector, dtype=float)
        self.free = tuple(free)
        self.fit_x0 = fit_x0
        self.n_g = len(self.free)
        self.n_trials = len(sim.trials)
        self.measured = sim.measured
        self.torque_scale = torque_scale
        self.simulations = 0
        self.scale_slot = self.free.index(TAU_SCALE) if TAU_SCALE in self.free else None
        self._sims: dict[float, Simulator] = {sim.tau_scale: sim}

    def rows(self, gmat: np.ndarray) -> np.ndarray:
        rows = np.repeat(self.vector[None, :], gmat.shape[0], axis=0)
        for j, name in enumerate(self.free):
            if name != TAU_SCALE:
                rows[:, INDEX[name]] = gmat[:, j]
        return rows

    def simulate(self, gmat: np.ndarray, x0s: np.ndarray) -> list[np.ndarray]:
        """θ per trial (S, n_k) for S rows of globals and S sets of initial states."""
        rows = self.rows(gmat)
        self.simulations += gmat.shape[0] * self.n_trials
        if self.scale_slot is None:
            return self.sim.run(rows, x0s)
        # The torque scale lives in the trials: one batch per distinct value (two for a Jacobian).
        scales = gmat[:, self.scale_slot]
        out = [np.empty((gmat.shape[0], m.size)) for m in self.measured]
        for value in np.unique(scales):
            pick = np.flatnonzero(scales == value)
            for k, block in enumerate(self._sim_at(float(value)).run(rows[pick], x0s[pick])):
                out[k][pick] = block
        return out

    def _sim_at(self, tau_scale: float) -> Simulator:
        if tau_scale not in self._sims:
            if len(self._sims) > 4:
                self._sims = {self.sim.tau_scale: self.sim}
            self._sims[tau_scale] = self.sim.with_tau_scale(tau_scale)
        return self._sims[tau_scale]

    def split(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return z[: self.n_g], z[self.n_g :].reshape(self.n_trials, 2)

    def residuals(self, z: np.ndarray) -> list[np.ndarray]:
        return self.residuals_of([z])[0]

    def residuals_of(self, zs: Sequence[np.ndarray]) -> list[list[np.ndarray]]:
        """:meth:`residuals` at each of ``zs``, simulated in one batch (each row alone, so bit for
        bit what one call per point gives)."""
        if not zs:
            return []
        parts = [self.split(z) for z in zs]
        sims = self.simulate(np.array([g for g, _ in parts]), np.array([x0 for _, x0 in parts]))
        return [[s[i] - m for s, m in zip(sims, self.measured)] for i in range(len(zs))]

    def steps(self, g: np.ndarray, upper: np.ndarray) -> np.ndarray:
        h = np.array([max(REL_STEP * abs(v), self._step_floor(n)) for n, v in zip(self.free, g)])
        # Step inward at an upper bound, so the probe stays inside the domain.
        return np.where(g + h > upper[: self.n_g], -h, h)

    def _step_floor(self, name: str) -> float:
        if name in ABS_STEP:
            return ABS_STEP[name]
        if name == TAU_SCALE:
            return 1e-6
        if name == "motor_inertia":
            return 1e-5 * self.torque_scale
        return 1e-4 * self.torque_scale

    def jacobian(self, z: np.ndarray, residuals: list[np.ndarray], upper: np.ndarray) -> list[np.ndarray]:
        """Per trial, the (n_g [+2], n_k) block of ∂θ/∂(g, own x0), from one batch."""
        if JACOBIAN == "sensitivities":
            return self.tangent(z)
        g, x0 = self.split(z)
        h = self.steps(g, upper)
        n_rows = self.n_g + (2 if self.fit_x0 else 0)
        gmat = np.repeat(g[None, :], n_rows, axis=0)
        gmat[np.arange(self.n_g), np.arange(self.n_g)] += h
        x0s = np.repeat(x0[None, :, :], n_rows, axis=0)
        if self.fit_x0:
            x0s[self.n_g, :, 0] += THETA0_STEP
            x0s[self.n_g + 1, :, 1] += OMEGA0_STEP
        steps = np.concatenate([h, [THETA0_STEP, OMEGA0_STEP] if self.fit_x0 else []])
        sims = self.simulate(gmat, x0s)
        return [chord_slopes(s, r + m, steps) for s, r, m in zip(sims, residuals, self.measured)]


    def tangent(self, z: np.ndarray) -> list[np.ndarray]:
        """:meth:`jacobian` from the plant's forward sensitivities: one pass per trial."""
        g, x0 = self.split(z)
        vector = self.rows(g[None, :])[0]
        # The torque scale multiplies the measured torque as the gain does: ∂/∂scale = gain/scale · ∂/∂gain.
        wrt = ["torque_gain" if n == TAU_SCALE else n for n in self.free]
        sim = self.sim if self.scale_slot is None else self._sim_at(float(g[self.scale_slot]))
        self.simulations += self.n_trials
        out = []
        for block in sim.sensitivities(vector, x0, wrt):
            jk = block[1 : 1 + self.n_g + (2 if self.fit_x0 else 0)].copy()
            if self.scale_slot is not None:
                jk[self.scale_slot] *= vector[INDEX["torque_gain"]] / g[self.scale_slot]
            out.append(jk)
        return out


def normal_equations(jac: list[np.ndarray], residuals: list[np.ndarray], n_g: int, fit_x0: bool):
    """JᵀJ and Jᵀr of the whole problem, assembled from per-trial blocks.

    Each block is the BLAS product it always was, one call per block and trial: merging a
    trial's blocks into one call of another shape changes their last bits (tried: the global
    × own x0 and Jᵀr blocks differ). What is saved is around the calls: every product is
    written straight into its place (``out=``), the global blocks are summed in trial order
    by one ``add.accumulate`` (0 + first + second + …, as the loop's ``+=`` did), the lower
    cross blocks are one transposed copy, and a fit with no free globals does no empty
    products."""
    n_t = len(jac)
    n = n_g + (2 * n_t if fit_x0 else 0)
    a = np.zeros((n, n))
    b = np.zeros(n)
    gg = np.zeros((n_t + 1, n_g, n_g))  # per trial gₖgₖᵀ after a row of zeros the running sum starts from
    gr = np.zeros((n_t + 1, n_g))
    for k, (jk, rk) in enumerate(zip(jac, residuals)):
        gk = jk[:n_g]
        if n_g:
            np.matmul(gk, gk.T, out=gg[k + 1])
            np.matmul(gk, rk, out=gr[k + 1])
        if fit_x0:
            xk = jk[n_g:]
            s = n_g + 2 * k
            if n_g:
                np.matmul(gk, xk.T, out=a[:n_g, s : s + 2])
            np.matmul(xk, xk.T, out=a[s : s + 2, s : s + 2])
            np.matmul(xk, rk, out=b[s : s + 2])
    if n_g:
        a[:n_g, :n_g] = np.add.accumulate(gg, axis=0)[-1]
        b[:n_g] = np.add.accumulate(gr, axis=0)[-1]
        if fit_x0:
            a[n_g:, :n_g] = a[:n_g, n_g:].T
    return a, b


def chord_slopes(perturbed: np.ndarray, base: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """(perturbed − base) / step per row: a trial's finite-difference Jacobian block from its
    perturbed simulations (rows, n_k), computed in the simulation's own array when it may be
    written (the same subtraction and division, without two temporaries of its size)."""
    out = perturbed if perturbed.flags.writeable else None
    slopes = np.subtract(perturbed, base[None, :], out=out)
    return np.divide(slopes, steps[:, None], out=slopes)


def fit_output_error(
    sim: Simulator,
    vector: np.ndarray,
    free: Sequence[str],
    x0: np.ndarray,
    *,
    fit_x0: bool = True,
    torque_scale: float = 1.0,
    max_iter: int = 60,
    tol: float = 1e-5,
    progress: Progress | None = None,
    label: str = "fit",
    damping: float = 1e-3,
    residuals: list[np.ndarray] | None = None,
    known: EndPoint | None = None,
    floors: Mapping[str, float] | None = None,
) -> FitResult:
    """Levenberg–Marquardt on simulated − measured θ over all trials of ``sim``.

    ``vector`` holds the starting (and fixed) parameter values in sim units; ``free`` names the
    ones to fit (``tau_scale`` for lumped mode with torque); ``x0`` (T, 2) the starting states.
    ``residuals``: θ − measured at exactly this start on ``sim``'s trials, when the caller has
    simulated it already (a fit carried on from where another ended on the same trials, step
    and torque scale; the start a batch of candidate states picked): used instead of simulating
    it again, so bit for bit the same fit with one simulation fewer. Ignored when the bounds
    move the start. ``known``: where another fit ended (:class:`EndPoint`); its residuals and
    Jacobian blocks are taken when this fit starts exactly there, on those trials or a subset.
    ``floors``: lower bounds above the physical ones for some free parameters, for this fit only
    (the base fit's start held at the data's rest, base.py).
    """
    started = time.perf_counter()
    problem = _Problem(sim, vector, free, fit_x0, torque_scale)
    lower, upper = _z_bounds(problem, floors)
    g0 = np.array([sim.tau_scale if n == TAU_SCALE else vector[INDEX[n]] for n in problem.free], dtype=float)
    start = np.concatenate([g0, np.asarray(x0, dtype=float).ravel()])
    z = np.clip(start, lower, upper)
    known = known.lookup(problem, z) if known is not None else None  # a fit that ended exactly here
    if known:
        r = known[0]
    elif residuals is not None and np.array_equal(z, start):
        r = list(residuals)
    else:
        r = problem.residuals(z)
    cost = _cost(r)
    samples = max(sum(m.size for m in problem.measured), 1)
    lam = damping
    jac: list[np.ndarray] = []
    a = None
    jac_at = None
    iteration = 0
    for iteration in range(1, max_iter + 1):
        jac = known[1] if known and iteration == 1 else problem.jacobian(z, r, upper)
        jac_at = z
        a, b = normal_equations(jac, r, problem.n_g, fit_x0)
        z_new, r_new, cost_new, lam = _lm_step(problem, z, a, b, cost, lam, lower, upper, tol)
        if z_new is None:
            break
        improvement = cost - cost_new
        step = np.max(np.abs(z_new - z) / (np.abs(z) + 1e-9))
        z, r, cost = z_new, r_new, cost_new
        if progress:  # rmse(r), from the cost already summed (the same sums in the same order)
            progress(f"{label}: iteration {iteration}, rmse {1e3 * np.sqrt(cost / samples):.3f} mrad")
        if improvement <= tol * cost or step < 1e-10:
            break
    result = _result(problem, z, r, jac, a, iteration, time.perf_counter() - started)
    result.damping = lam
    if jac_at is z and problem.n_g:  # the last Jacobian was taken at the end point (it ended on a failed step)
        result.end_point = EndPoint(problem, z, r, jac)
    return result


class EndPoint:
    """Where a fit ended, with its residuals and Jacobian blocks per trial.

    The phases after a fit start new fits exactly where it ended: each cross-validation fold
    and each jackknife replicate refits the model without some trials from the full fit's
    values and initial states, and a short refit is carried on from where it stopped. A trial's
    residual and Jacobian block depend only on the shared parameters, that trial's own initial
    state, the step, the friction law and the torque scale, so a block computed for the full
    fit is, bit for bit, the one a subset fit would simulate again (1 + P + 2 simulations per
    trial). :meth:`lookup` hands them over only on an exact match of all of these; anything
    else is simulated as before, so no result can change. It is handed to the fits that may
    start there (``fit_output_error(..., known=)``), not kept in a module-level cache."""

    def __init__(self, problem: _Problem, z: np.ndarray, residuals: list[np.ndarray], jac: list[np.ndarray]):
        g, x0 = problem.split(z)
        self._key = self._key_of(problem)
        self._point = self._point_of(problem, g)
        self._x0 = x0.copy()
        # The trial objects themselves are kept: identity is what a later lookup matches on.
        self._trials = list(problem.sim.trials)
        self._slots = {id(tr): k for k, tr in enumerate(self._trials)}
        self._residuals = residuals
        self._jac = jac

    @staticmethod
    def _key_of(problem: _Problem) -> tuple:
        sim = problem.sim
        return (problem.free, problem.fit_x0, sim.max_step, sim.friction, sim.tau_scale, sim.mode,
                problem.torque_scale)

    @staticmethod
    def _point_of(problem: _Problem, g: np.ndarray) -> np.ndarray:
        """Every parameter the simulation sees: the free ones and the fixed rest of the vector."""
        return np.concatenate([problem.rows(g[None, :])[0], g])

    def lookup(self, problem: _Problem, z: np.ndarray):
        """(residuals, Jacobian blocks) for ``problem`` at ``z`` when this fit ended exactly there
        on a superset of its trials; else None."""
        if JACOBIAN != "differences":
            return None
        g, x0 = problem.split(z)
        if self._key != self._key_of(problem) or not np.array_equal(self._point, self._point_of(problem, g)):
            return None
        picked = [self._slots.get(id(tr)) for tr in problem.sim.trials]
        if any(k is None for k in picked) or not np.array_equal(self._x0[picked], x0):
            return None
        return [self._residuals[k] for k in picked], [self._jac[k] for k in picked]


def end_point_of(sim: Simulator, fit: FitResult, torque_scale: float) -> EndPoint | None:
    """``fit``'s end point (on ``sim``'s trials, its own torque scale), its Jacobian simulated
    now when the fit ended without one there (it stopped after a successful step). For a phase
    that then starts several fits exactly there (the jackknife's replicates, the cross-validation
    folds): one Jacobian instead of one per fit."""
    if not fit.free:
        return None
    sim = sim.with_tau_scale(fit.tau_scale)
    problem = _Problem(sim, fit.vector, fit.free, True, torque_scale)
    lower, upper = _z_bounds(problem)
    g = np.array([fit.value(n) for n in problem.free], dtype=float)
    z = np.clip(np.concatenate([g, fit.x0.ravel()]), lower, upper)
    if fit.end_point is not None and fit.end_point.lookup(problem, z) is not None:
        return fit.end_point
    return EndPoint(problem, z, fit.residuals, problem.jacobian(z, fit.residuals, upper))


def _z_bounds(problem: _Problem, floors: Mapping[str, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = bounds_for(problem.free)
    for name, floor in (floors or {}).items():
        k = problem.free.index(name)
        lo[k] = max(lo[k], floor)
    n_x = 2 * problem.n_trials
    return np.concatenate([lo, np.full(n_x, -np.inf)]), np.concatenate([hi, np.full(n_x, np.inf)])


def _cost(residuals: list[np.ndarray]) -> float:
    return float(sum(np.dot(r, r) for r in residuals))


def _lm_step(problem, z, a, b, cost, lam, lower, upper, tol=0.0):
    """Damped Gauss–Newton steps until one lowers the cost (or the damping runs away).

    A step whose linearised gain is below a tenth of ``tol``·cost ends the search: at a minimum
    every damping fails, and trying each up to 1e10 (about twenty simulations) was a third of
    all simulations of an effect search (measured with cProfile, bench/identify_speed.py); a step
    that did succeed there would gain less than the fit's own stopping tolerance.

    The first damping is tried alone: it succeeds in most iterations (225 of 381 on 30 drops with
    a quadratic drag, bench/identify_speed.py's set). Once it has failed, the next
    :data:`LOOKAHEAD` dampings are simulated together in one batch, each as if the ones before
    it failed: a failed first try is usually the start of a run of them (up to 11 tries on that
    set, at a kink of stick friction), and one call for them replaces several. The result is the one the steps taken one by one give, to the
    bit: the first that lowers the cost wins, and each is simulated exactly as alone."""
    proposals = _damped_steps(z, a, b, lam, lower, upper, CONVERGED_FRACTION * tol * cost)
    for size in itertools.chain([1], itertools.repeat(LOOKAHEAD)):
        batch = list(itertools.islice(proposals, size))
        tries = [p for p in batch if p[1] is not None]
        for (lam_try, z_new), r_new in zip(tries, problem.residuals_of([zn for _, zn in tries])):
            cost_new = _cost(r_new)
            if np.isfinite(cost_new) and cost_new < cost:
                return z_new, r_new, cost_new, max(lam_try / 3.0, 1e-9)
        if len(tries) < len(batch) or len(batch) < size:  # a stop: the gain ran out or the damping ran away
            return None, None, cost, batch[-1][0] if batch else lam
    raise AssertionError("unreachable: the proposals end with a stop")


def _damped_steps(z, a, b, lam, lower, upper, least_gain) -> Iterator[tuple[float, np.ndarray | None]]:
    """(damping, clipped step) for each damping in turn, each as if the one before failed (×5);
    ends with (damping, None) where the predicted gain falls below ``least_gain``, or with
    (damping, None) once the damping reaches 1e10."""
    n_active = a.shape[0]
    diag = np.maximum(np.diag(a), 1e-12 * max(np.diag(a).max(), 1e-300))
    while lam < 1e10:
        try:
            delta = np.linalg.solve(a + lam * np.diag(diag), -b)
        except np.linalg.LinAlgError:
            lam *= 10.0
            continue
        z_new = z.copy()
        z_new[:n_active] = np.clip(z[:n_active] + delta, lower[:n_active], upper[:n_active])
        # Unclipped: a bound that cuts the step is no reason to stop (larger damping may pass it).
        if _predicted_gain(a, b, delta) < least_gain:
            yield lam, None
            return
        yield lam, z_new
        lam *= 5.0
    yield lam, None


def _predicted_gain(a: np.ndarray, b: np.ndarray, step: np.ndarray) -> float:
    """The cost drop the Gauss–Newton model predicts for ``step``: −(2 bᵀδ + δᵀAδ)."""
    return float(-(2.0 * b @ step + step @ a @ step))


def _result(problem: _Problem, z, r, jac, jtj, iterations, seconds) -> FitResult:
    """``jtj``: JᵀJ of ``jac`` as the last iteration assembled it (it depends on nothing else)."""
    g, x0 = problem.split(z)
    vector = problem.rows(g[None, :])[0]
    tau_scale = float(g[problem.scale_slot]) if problem.scale_slot is not None else problem.sim.tau_scale
    uncertainty = _Covariance(jac, r, problem.n_g, problem.fit_x0, jtj) if jac else None
    return FitResult(
        vector=vector,
        tau_scale=tau_scale,
        free=problem.free,
        sigma=_Sigma(uncertainty, problem.free) if uncertainty is not None else {},
        x0=x0.copy(),
        residuals=r,
        iterations=iterations,
        simulations=problem.simulations,
        seconds=seconds,
        jacobian=jac,
        uncertainty=uncertainty,
    )


class _Covariance:
    """Covariance of all unknowns (globals first, then initial states), computed on first use.

    Most fits are never asked for their σ (the initial-state fits, the short refits of the
    screen, the cross-validation folds), and the residual's autocorrelation time and the
    pseudo-inverse were a tenth of an effect search's CPU (cProfile,
    docs/identification-speed-log.md, *The Python around the simulations*). Computed later from
    the same Jacobian and residuals, it is bit for bit the same."""

    def __init__(self, jac: list[np.ndarray], residuals: list[np.ndarray], n_g: int, fit_x0: bool,
                 jtj: np.ndarray | None = None):
        # ``jtj``: JᵀJ of ``jac`` when the fit has it already (its last iteration assembled it).
        self._inputs = (jac, residuals, n_g, fit_x0, jtj)
        self._full: np.ndarray | None = None
        self.n_g = n_g

    def full(self) -> np.ndarray:
        if self._full is None:
            jac, residuals, n_g, fit_x0, a = self._inputs
            if a is None:
                a, _ = normal_equations(jac, residuals, n_g, fit_x0)
            m = sum(res.size for res in residuals)
            dof = max(m - a.shape[0], 1)
            variance = _cost(residuals) / dof * autocorrelation_time(residuals)
            self._full = np.linalg.pinv(a) * variance
        return self._full

    def globals(self) -> np.ndarray:
        return self.full()[: self.n_g, : self.n_g]


class _Sigma(Mapping):
    """σ of each free global, read off :class:`_Covariance` when first looked at."""

    def __init__(self, covariance: _Covariance, free: tuple[str, ...]):
        self._covariance = covariance
        self._free = free
        self._values: dict[str, float] | None = None

    def _dict(self) -> dict[str, float]:
        if self._values is None:
            full = self._covariance.full()
            self._values = {name: float(np.sqrt(max(full[j, j], 0.0))) for j, name in enumerate(self._free)}
        return self._values

    def __getitem__(self, name: str) -> float:
        return self._dict()[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._free)

    def __len__(self) -> int:
        return len(self._free)

    def __repr__(self) -> str:
        return repr(self._dict())


def autocorrelation_time(residuals: Sequence[np.ndarray], max_lag: int = 400) -> float:
    """Integrated autocorrelation time 1 + 2·Σρ_k (summed until ρ first drops below 0),
    pooled over trials: the factor by which correlated samples overstate the information."""
    num = np.zeros(max_lag + 1)
    den = 0.0
    for acov in autocovariances(residuals, max_lag):
        num[: acov.size] += acov
        den += acov[0]
    if den <= 0:
        return 1.0
    rho = num / den
    negative = np.flatnonzero(rho[1:] < 0)
    cut = negative[0] + 1 if negative.size else rho.size
    return float(max(1.0, 1.0 + 2.0 * rho[1:cut].sum()))


def autocovariances(pieces: Sequence[np.ndarray], max_lag: int) -> list[np.ndarray]:
    """Per piece of two samples or more (in order; shorter ones have no correlation to add), its
    autocovariance Σₜ xₜxₜ₊ₖ about its mean for lags k ≤ min(max_lag, n − 1), by FFT (zero-padded
    to 2n, so nothing wraps around).

    Pieces of one length share one transform each way: numpy's rfft/irfft of a stack are, row
    by row, bit for bit the transforms of each row alone (a trial of 1201 samples takes a
    2402-point transform with a prime factor, about 0.25 ms each way). The power spectrum is
    taken row by row: numpy's complex product of a 2D stack rounds differently from that of
    one row (checked in tests/test_ident_fit_numerics.py)."""
    pieces = [np.asarray(p, dtype=float) for p in pieces]
    pieces = [p for p in pieces if p.size >= 2]
    by_length: dict[int, list[int]] = {}
    for i, p in enumerate(pieces):
        by_length.setdefault(p.size, []).append(i)
    out: list[np.ndarray] = [np.empty(0)] * len(pieces)
    for n, members in by_length.items():
        centred = np.empty((len(members), n))
        for row, i in zip(centred, members):
            np.subtract(pieces[i], pieces[i].mean(), out=row)
        spectra = np.fft.rfft(centred, 2 * n, axis=1)
        for spectrum in spectra:
            np.multiply(spectrum, np.conj(spectrum), out=spectrum)
        acov = np.fft.irfft(spectra, axis=1)
        lags = min(max_lag, n - 1)
        for row, i in zip(acov, members):
            out[i] = row[: lags + 1]
    return out


def fit_initial_states(sim: Simulator, vector: np.ndarray, x0: np.ndarray, tau_scale: float | None = None,
                       progress: Progress | None = None, label: str = "initial states") -> FitResult:
    """Each trial's (θ0, ω0) with the model fixed: how held-out and validation trials are scored."""
    if tau_scale is not None:
        sim = sim.with_tau_scale(tau_scale)
    return fit_output_error(sim, vector, (), x0, progress=progress, label=label)


def fit_initial_states_multi(sim: Simulator, vector: np.ndarray, starts: Sequence[np.ndarray],
                             tau_scale: float | None = None, progress: Progress | None = None,
                             label: str = "initial states") -> FitResult:
    """:func:`fit_initial_states` from several starts, keeping each trial's best.

    A trial's initial state is a two-unknown problem, but not a convex one: started where the
    simulated swing runs half a period out of phase, LM settles in the wrong basin (a held-out
    trial once scored 107 mrad that way, from a start that suited the other model; from the
    data's own start it scored 7). Trials are independent given the model, so each keeps the
    start that ends lowest."""
    unique: list[np.ndarray] = []
    for s in starts:
        s = np.asarray(s, dtype=float)
        if not any(np.array_equal(s, u) for u in unique):
            unique.append(s)
    fits = [fit_initial_states(sim, vector, s, tau_scale, progress, label) for s in unique]
    if len(fits) == 1:
        return fits[0]
    best = [min(fits, key=lambda f: float(f.residuals[k] @ f.residuals[k])) for k in range(len(sim.trials))]
    first = fits[0]
    return FitResult(
        vector=first.vector,
        tau_scale=first.tau_scale,
        free=first.free,
        sigma={},
        x0=np.array([f.x0[k] for k, f in enumerate(best)]).reshape(-1, 2),
        residuals=[f.residuals[k] for k, f in enumerate(best)],
        iterations=sum(f.iterations for f in fits),
        simulations=sum(f.simulations for f in fits),
        seconds=sum(f.seconds for f in fits),
        jacobian=[f.jacobian[k] for k, f in enumerate(best)] if all(f.jacobian for f in best) else [],
    )


def states_again(sim: Simulator, vector: np.ndarray, own: np.ndarray, starts: Sequence[np.ndarray],
                 label: str = "initial states") -> np.ndarray:
    """Each trial's initial state fitted under ``vector`` from ``own`` (the states a fit already
    has) and from the data's candidate ``starts`` screened under ``vector``, each trial keeping
    its best (:func:`fit_initial_states_multi`): a model that changed where the joint sticks
    may want another release for some trials than the states it was handed."""
    return fit_initial_states_multi(sim, vector, [own, screen_starts(sim, vector, starts)], label=label).x0


def screen_starts(sim: Simulator, vector: np.ndarray, starts: Sequence[np.ndarray]) -> np.ndarray:
    """Per trial, the start (of ``starts``, each (T, 2)) whose simulation under ``vector`` is
    closest to the data: one batch, no fitting."""
    return closest_starts(sim, vector, starts)[0]


NEARBY_ANGLES = range(-4, 5)  # multiples of nearby_starts' angle step
NEARBY_RATES = range(-8, 9)  # multiples of its rate step


def nearby_starts(x0: np.ndarray, angle_step: float, rate_step: float) -> list[np.ndarray]:
    """Starts around each trial's ``x0`` (T, 2): its angle moved by k·``angle_step`` and its
    velocity by m·``rate_step``, for every k of :data:`NEARBY_ANGLES` and m of
    :data:`NEARBY_RATES` but both 0 (152 starts; a step of 0 moves nothing).

    Why: with stick friction a trial's error is a landscape of basins in its initial state, one
    per turning point the simulated swing sticks at; LM from the data's own starts cannot cross
    from one to the next. On 4096-tick encoder drops with Stribeck at 1.5× the Coulomb level
    (bench/identify_families.py's regime row, seed 1) a held-out trial scored 5.17 mrad from the
    data's starts and 1.15 with these screened too (the sensor's rounding alone leaves 0.38)."""
    x0 = np.asarray(x0, dtype=float).reshape(-1, 2)
    angles = [k * angle_step for k in NEARBY_ANGLES] if angle_step > 0 else [0.0]
    rates = [m * rate_step for m in NEARBY_RATES] if rate_step > 0 else [0.0]
    return [x0 + np.array([a, r]) for a in angles for r in rates if a or r]


def closest_starts(sim: Simulator, vector: np.ndarray, starts: Sequence[np.ndarray]) -> tuple[np.ndarray, list[np.ndarray]]:
    """:func:`screen_starts` and, per trial, the residual (θ − measured) its pick leaves: the
    batch simulated it already (each trial and row is simulated on its own, so it is bit for
    bit what a fit from there would simulate first: ``fit_output_error(..., residuals=)``)."""
    sims = sim.run(np.repeat(np.asarray(vector, float)[None, :], len(starts), axis=0), np.stack(starts))
    # Each row's mean square, a row at a time (the reduction of one row is the 1D one).
    choice = [int(np.argmin(np.mean((s - m[None, :]) ** 2, axis=1))) for s, m in zip(sims, sim.measured)]
    x0 = np.array([starts[c][i] for i, c in enumerate(choice)], dtype=float).reshape(-1, 2)
    return x0, [s[c] - m for s, c, m in zip(sims, choice, sim.measured)]
