"""Identify the servo's tracking dynamics from a recording: goal and hand torque in, present angle out.

The model is ``plant::servo`` (docs/fidelity.md): m·θ'' + θ' = (u(t − d) + s·τ − θ − b·sgn θ')/T,
simulated in Rust (``_rtcore.servo_simulate_batch``), the same code the RT loop inverts.

What the fit sees, with the recording's real timing:

- the horn angle ``theta`` at each recorded cycle's wake-up ``t_wake`` (when the goal was
  written and the servo read);
- the goal between recorded cycles (the loop writes one every cycle, but rows exist only on the
  cycles that read the servo): the model's angle, which is smooth and whose velocity is
  recorded, is interpolated with cubic Hermite segments, and the goal's offset from it (the tick
  rounding, the compensation's lead) linearly. At 10 cycles per row and a 3 Hz hand a straight
  line between goals would be off by a millimetre-radian, the Hermite segments by 10⁻⁶ rad;
- the hand torque, linearly interpolated between rows from each interval's mean
  (``Segment.impulse_tau``), so its impulse is the one the model integrated.

The fit is output error (simulate each segment from its first sample, compare the angle) by a
small projected Levenberg–Marquardt over the lag form's five parameters, every Jacobian from ONE
batch simulation. Then the gear play (``backlash``, ``backlash_torque``): fitted from the lag
form's values and a small grid of plays, and **admitted only where the data support it**: the
play's held-out error at most ``BACKLASH_MIN_CUT`` of the lag form's and the play at least
``MIN_SIGMAS`` σ from 0; otherwise both stay 0. `notes` says which, with the held-out error
before and after. The first ``BURN_IN_S`` of a segment is left out of the cost: its initial velocity
is only the model's. Segments are split as `identify` splits trials: every third is held out
and scored, never fitted; the residual verdict is ident's (whiteness, noise floor, worst bin).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from admittance.fidelity.recording import Segment
from admittance.ident.fit import autocorrelation_time, rmse
from admittance.formats.paramfile import SERVO_PARAM_NAMES
from admittance.ident.residual import verdict

BURN_IN_S = 0.25
INPUT_STEP_S = 1e-3  # the goal's and torque's grid between recorded rows
MAX_STEP_S = 2.5e-4  # simulation substep: 1/4 of the fastest lag the bounds allow to matter
LOWER = np.array([2e-4, 0.0, -0.005, -0.5, 0.0, 0.0, 0.0])
UPPER = np.array([1.0, 0.5, 0.2, 0.5, 0.05, 0.035, 2.0])
# Forward-difference steps: T relative (with a floor), the others absolute in their units.
REL_STEP_T = 0.02
ABS_STEPS = np.array([2e-4, 5e-4, 2e-4, 2e-4, 5e-5, 2e-4, 2e-3])
LAG_FORM = 5  # the first five parameters; the last two are the gear play
PLAY = ("backlash", "backlash_torque")
# The play is kept only when it cuts the held-out error to at most this fraction of the lag
# form's (a 20 % cut: a play that only fits noise gains a few per cent at most), and is
# pinned (≥ MIN_SIGMAS σ from 0).
BACKLASH_MIN_CUT = 0.8
# Where the play's fit starts (the best of these on the training segments): plays from 0.1° to
# 1.2°, horn frictions from none to a light hand.
PLAY_GRID = [(b, q) for b in (0.002, 0.005, 0.01, 0.02) for q in (0.0, 0.02, 0.06)]
MAX_ITERATIONS = 60
HELDOUT_STRIDE = 3
# The two signed parameters are kept only when the data pin them down (|value| ≥ this many σ);
# otherwise they are fixed at 0 and the rest refitted. A dead time and a lag are nearly the same
# thing to a slow hand (both a phase lag ω·(T + d)), and without this rule the fit trades one
# for the other to whichever bound is nearer.
SIGNED = {"dead_time": 2, "compliance": 3}
MIN_SIGMAS = 2.0


@dataclass
class ServoData:
    """One segment, ready for the simulator."""

    name: str
    trial: object  # _rtcore.ServoTrial
    t: np.ndarray
    measured: np.ndarray
    x0: tuple[float, float]
    scored: np.ndarray  # bool: past the burn-in
    speed: np.ndarray
    angle: np.ndarray


def hermite(t: np.ndarray, y: np.ndarray, dy: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Cubic Hermite interpolation of samples (t, y) with derivatives dy, at the times ``at``."""
    k = np.clip(np.searchsorted(t, at, side="right") - 1, 0, len(t) - 2)
    h = t[k + 1] - t[k]
    s = (at - t[k]) / h
    h00, h10 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s
    h01, h11 = -2 * s**3 + 3 * s**2, s**3 - s**2
    return h00 * y[k] + h10 * h * dy[k] + h01 * y[k + 1] + h11 * h * dy[k + 1]


def prepare(segment: Segment) -> ServoData:
    from admittance import _rtcore

    t = segment.t_servo
    model, velocity = segment["theta_model"], segment["omega_model"]
    grid = np.union1d(np.arange(t[0], t[-1], INPUT_STEP_S), t)
    goal = hermite(t, model, velocity, grid) + np.interp(grid, t, segment["theta_goal"] - model)
    tau = np.interp(grid, t, segment.impulse_tau)
    trial = _rtcore.ServoTrial(t, grid, goal, tau)
    return ServoData(segment.name, trial, t, segment["theta"], (float(segment["theta"][0]), float(velocity[0])),
                     t - t[0] >= BURN_IN_S, np.abs(velocity), model)


def simulate(data: list[ServoData], params: np.ndarray) -> list[np.ndarray]:
    """Per segment, an (S, n) array of horn angles for S parameter rows."""
    from admittance import _rtcore

    params = np.atleast_2d(params)
    x0 = np.array([[d.x0 for d in data]] * params.shape[0], dtype=float)
    return _rtcore.servo_simulate_batch([d.trial for d in data], params, x0, max_step=MAX_STEP_S)


def residuals(data: list[ServoData], params: np.ndarray) -> list[np.ndarray]:
    """Simulated − measured angle of each segment, past its burn-in."""
    return [sim[0][d.scored] - d.measured[d.scored] for sim, d in zip(simulate(data, params), data)]


@dataclass
class ServoFit:
    params: np.ndarray
    sigma: np.ndarray
    training: list[str]
    heldout: list[str]
    rmse_training: float
    rmse_heldout: float
    baseline_heldout: dict[str, float]
    residual: dict
    iterations: int
    simulations: int = 0
    notes: list[str] = field(default_factory=list)

    def model(self) -> dict[str, float]:
        return {name: float(v) for name, v in zip(SERVO_PARAM_NAMES, self.params)}

    def to_json(self) -> dict:
        return {
            "form": "m·θ'' + θ' = (goal(t − dead_time) + compliance·τ − θ − deadband·sgn θ') / time_constant; "
                    "horn within ±backlash/2 of θ, against the side |τ| > backlash_torque pushes it to",
            **self.model(),
            "sigma": {name: float(v) for name, v in zip(SERVO_PARAM_NAMES, self.sigma)},
            "rmse_training": self.rmse_training,
            "rmse_heldout": self.rmse_heldout,
            "baseline_heldout": self.baseline_heldout,
            "training": self.training,
            "heldout": self.heldout,
            "residual": self.residual,
            "iterations": self.iterations,
            "notes": self.notes,
        }


def split(segments: list[Segment]) -> tuple[list[int], list[int]]:
    """(held-out, training) indices: every third segment from the second is held out; a single
    segment is both (scored on itself, and the JSON says so by listing it twice)."""
    if len(segments) < 2:
        return [0], [0]
    held = list(range(1, len(segments), HELDOUT_STRIDE))
    return held, [i for i in range(len(segments)) if i not in held]


def fit_servo(segments: list[Segment]) -> ServoFit:
    held, train = split(segments)
    prepared = [prepare(s) for s in segments]
    training, heldout = [prepared[i] for i in train], [prepared[i] for i in held]
    lag_form = np.arange(len(SERVO_PARAM_NAMES)) < LAG_FORM
    params, jac, free, iterations, sims, notes = _fit_form(training, _start(training), lag_form)
    scored_on = training if held == train else heldout
    params, jac, free, iterations, sims = _admit_play(training, scored_on, params, jac, free, iterations, sims, notes)
    train_res = residuals(training, params)
    held_res = train_res if held == train else residuals(heldout, params)
    sigma = _sigma(jac, train_res, free)
    scored = [d.scored for d in heldout]
    baseline = {
        "goal": rmse([s["theta_goal"][m] - s["theta"][m] for s, m in zip((segments[i] for i in held), scored)]),
        "model": rmse([s["theta_model"][m] - s["theta"][m] for s, m in zip((segments[i] for i in held), scored)]),
    }
    by = {"speed": np.concatenate([d.speed[d.scored] for d in training]),
          "angle": np.concatenate([d.angle[d.scored] for d in training]),
          "time": np.concatenate([(d.t - d.t[0])[d.scored] for d in training])}
    notes += [f"{name} at its bound {bound:g}" for name, value, lo, hi, f in zip(SERVO_PARAM_NAMES, params, LOWER, UPPER, free)
              for bound in (lo, hi) if f and value == bound and name not in ("inertial_time", "deadband", *PLAY)]
    return ServoFit(params, sigma, [segments[i].name for i in train], [segments[i].name for i in held],
                    rmse(train_res), rmse(held_res), baseline, verdict(train_res, by), iterations, sims, notes)


def _fit_form(training: list[ServoData], start: np.ndarray, free: np.ndarray):
    """LM over the ``free`` parameters, then the signed ones the data do not pin (|value| <
    MIN_SIGMAS σ) fixed at 0 and the rest refitted: (params, Jacobian, free, iterations,
    simulations, notes)."""
    free = free.copy()
    params, jac, iterations, sims = _levenberg_marquardt(training, start, free)
    sigma = _sigma(jac, residuals(training, params), free)
    notes = []
    for name, k in SIGNED.items():
        if free[k] and abs(params[k]) < MIN_SIGMAS * sigma[k]:
            notes.append(f"{name} {params[k]:.3g} is within {MIN_SIGMAS:g} σ ({sigma[k]:.2g}) of 0: fixed at 0")
            free[k], params[k] = False, 0.0
    if notes:
        params, jac, more, more_sims = _levenberg_marquardt(training, params, free)
        iterations, sims = iterations + more, sims + more_sims
    return params, jac, free, iterations, sims, notes


def _admit_play(training, scored_on, params, jac, free, iterations, sims, notes):
    """The lag form with the gear play added, kept only where the data support it (see the module
    doc); ``notes`` gets the held-out error before and after either way."""
    before = rmse(residuals(scored_on, params))
    # LM from the best start near the lag form's values and, separately, from the best start of
    # the lag form's own grid; the lower training cost wins. A play the lag form did not know
    # about distorts its values (a lag traded for a dead time: T 3.6 ms and a 12 ms dead time on
    # the 0.25° geared oracle, whose motor has T ≈ 21 ms), and LM from there stays in that valley
    # even when the grid's start scores worse before LM: the best start overall is not enough.
    near = np.array([[*params[:LAG_FORM], b, q] for b, q in PLAY_GRID])
    far = np.array([[*p[:LAG_FORM], b, q] for p in _START_GRID for b, q in PLAY_GRID])
    fits = [_fit_form(training, rows[int(np.argmin(_costs(training, rows)))], free | _play_mask()) for rows in (near, far)]
    costs = [float(_costs(training, fit[0][None, :])[0]) for fit in fits]
    played, played_jac, played_free, more, more_sims, played_notes = fits[int(np.argmin(costs))]
    iterations = iterations + sum(fit[3] for fit in fits)
    sims = sims + sum(fit[4] for fit in fits) + len(near) + len(far) + len(fits)
    after = rmse(residuals(scored_on, played))
    k = SERVO_PARAM_NAMES.index("backlash")
    sigma = _sigma(played_jac, residuals(training, played), played_free)[k]
    figures = f"held-out error {1e3 * before:.3f} mrad without the play, {1e3 * after:.3f} with it"
    if after <= BACKLASH_MIN_CUT * before and played[k] >= MIN_SIGMAS * sigma:
        notes += played_notes
        notes.append(f"gear backlash {1e3 * played[k]:.2f} ± {1e3 * sigma:.2f} mrad ({np.degrees(played[k]):.2f}°, "
                     f"pushed across by {played[k + 1]:.3g} N·m) admitted: {figures}")
        return played, played_jac, played_free, iterations, sims
    why = (f"cuts it by less than {100 * (1 - BACKLASH_MIN_CUT):.0f} %" if after > BACKLASH_MIN_CUT * before
           else f"the play {1e3 * played[k]:.2f} mrad is within {MIN_SIGMAS:g} σ ({1e3 * sigma:.2f}) of 0")
    notes.append(f"no gear backlash: {figures} ({why})")
    return params, jac, free, iterations, sims


def _play_mask() -> np.ndarray:
    return np.array([name in PLAY for name in SERVO_PARAM_NAMES])


def _costs(data: list[ServoData], rows: np.ndarray) -> np.ndarray:
    """Each parameter row's sum of squared residuals on ``data`` (one batch)."""
    sims = simulate(data, rows)
    return sum(((sim[:, d.scored] - d.measured[d.scored]) ** 2).sum(axis=1) for sim, d in zip(sims, data))


def _start(data: list[ServoData]) -> np.ndarray:
    """The best of a small grid of lags and inertial times (one batch): LM from a first-order lag
    of the wrong size can stall where the second-order term first helps."""
    return _START_GRID[int(np.argmin(_costs(data, _START_GRID)))]


_START_GRID = np.array([[tc, m * tc, 0.0, 0.0, 0.0, 0.0, 0.0] for tc in (0.005, 0.01, 0.02, 0.04, 0.08, 0.16)
                        for m in (0.0, 0.5, 1.0)])


def _levenberg_marquardt(data: list[ServoData], p: np.ndarray, free: np.ndarray) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Projected LM over the ``free`` parameters on the stacked residual; returns (params,
    Jacobian of the free ones at them, iterations, simulations)."""
    lam, sims = 1e-3, 0
    p = p.copy()
    r, jac = _residual_and_jacobian(data, p, free)
    sims += 1 + int(free.sum())
    cost = float(r @ r)
    for iteration in range(1, MAX_ITERATIONS + 1):
        jtj, jtr = jac.T @ jac, jac.T @ r
        improved = False
        for _ in range(8):
            step = np.zeros_like(p)
            step[free] = np.linalg.solve(jtj + lam * np.diag(np.diag(jtj) + 1e-12), -jtr)
            trial = np.clip(p + step, LOWER, UPPER)
            rt = np.concatenate(residuals(data, trial))
            sims += 1
            if float(rt @ rt) < cost:
                improved = True
                break
            lam *= 4.0
        if not improved:
            return p, jac, iteration, sims
        change = (cost - float(rt @ rt)) / max(cost, 1e-30)
        p, lam = trial, max(lam / 3.0, 1e-9)
        r, jac = _residual_and_jacobian(data, p, free)
        sims += 1 + int(free.sum())
        cost = float(r @ r)
        if change < 1e-7:
            return p, jac, iteration, sims
    return p, jac, MAX_ITERATIONS, sims


def _residual_and_jacobian(data: list[ServoData], p: np.ndarray, free: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    steps = ABS_STEPS.copy()
    steps[0] = max(REL_STEP_T * p[0], ABS_STEPS[0])
    steps = np.where(p + steps > UPPER, -steps, steps)[free]  # step inward at an upper bound
    rows = np.vstack([p, p + np.diag(np.where(free, 1.0, 0.0))[free] * steps[:, None]])
    sims = simulate(data, rows)
    stacked = np.hstack([sim[:, d.scored] - d.measured[d.scored] for sim, d in zip(sims, data)])
    r = stacked[0]
    jac = ((stacked[1:] - r) / steps[:, None]).T
    return r, jac


def _sigma(jac: np.ndarray, res: list[np.ndarray], free: np.ndarray) -> np.ndarray:
    """σ of each parameter (0 for a fixed one) from (JᵀJ)⁻¹ times the residual variance and its
    integrated autocorrelation time (output-error residuals are smooth, not independent samples;
    see ident.fit)."""
    r = np.concatenate(res)
    dof = max(r.size - jac.shape[1], 1)
    sigma = np.zeros(free.size)
    try:
        cov = np.linalg.pinv(jac.T @ jac) * float(r @ r) / dof * autocorrelation_time(res)
    except np.linalg.LinAlgError:
        sigma[free] = np.nan
        return sigma
    sigma[free] = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return sigma
