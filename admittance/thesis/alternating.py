"""The thesis's identification procedure, reproduced (Rao 2016, section 2.5 and appendix C.3).

Per trial, the thesis simulated its Simulink model

    I·θ'' = −m·g·l·sin θ − B·θ' − F·tanh(100·θ')

with the fixed-step ode3 solver and fitted it to the measured angle by Levenberg–Marquardt
(``lsqnonlin``), alternating: (I, B) with F fixed, then F alone, ``cycles = 5`` times, then a
last (I, B). ``I`` is the *total* inertia; the motor's share is ``I − I_rod − I_bob``.

Why alternate rather than fit (I, B, F) together: that is what the thesis did ("since B and F
are both dissipative parameters, they cannot both be optimized in the same model at the same
time"); reproducing its numbers needs its procedure, including this choice.

Design choices:
- The scheme (:func:`alternating_fit`) takes a *batch simulator* (rows of (I, B, F) → angle
  series), so the same code drives our Rust simulator here and the pure-NumPy ode3 of
  the test oracle ``tests/oracles/thesis_ode3.py``; only the simulator differs in the bench.
- With the Rust batch simulator the forward-difference Jacobian is one call: the base row and
  its perturbations run in parallel without the GIL.
- The trial is simulated with ``load_inertia = 0`` and ``motor_inertia = I`` (the total), since
  the thesis fits the total; the load geometry enters only through the gravity torque.
- The initial state is the first measured angle at rest (the Simulink model's initial
  condition); ``x0="data"`` estimates the initial velocity instead, for trials that do not
  start at the release.
- The rod inertia is reported twice: the thesis script's ``(1/3)·m·(L/2)²`` (it used the half
  length, 0.228 m of a 0.456 m rod) and the correct ``(1/3)·m·L²`` about the end.
"""

from __future__ import annotations

import csv
import io
import math
import statistics
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass

import numpy as np
from scipy.optimize import least_squares

from admittance.errors import DataError

# Table 3.1's overall breakaway averages: the thesis's initial guess of F per motor (N·m).
BREAKAWAY_AVERAGE = {"MX-28": 0.0176, "MX-64": 0.1061, "MX-106": 0.1234}
# Appendix C.3's initial guesses of the total inertia (kg·m²) and damping (N·m·s/rad).
INITIAL_INERTIA = 0.0385
INITIAL_DAMPING = 0.0286
TANH_K = 100.0
CYCLES = 5
TOLERANCE = 1e-3  # the script's TolX and TolFun
MAX_STEP = 1e-3  # s; well inside ode3's stability limit for tanh friction with k = 100
FD_STEP = 1e-6  # relative step of the forward-difference Jacobian

# rows (S, 3) of (I_total, B, F) -> simulated angles (S, n)
BatchSimulator = Callable[[np.ndarray], np.ndarray]


@dataclass
class AlternatingResult:
    """The final (I, B, F) of one trial and how the fit went."""

    inertia_total: float
    damping: float
    friction: float
    rmse: float
    n_simulations: int


def alternating_fit(
    simulate: BatchSimulator,
    theta: np.ndarray,
    initial: tuple[float, float, float],
    cycles: int = CYCLES,
    tol: float = TOLERANCE,
    batched_jacobian: bool = True,
) -> AlternatingResult:
    """LM over (I, B) with F fixed, then over F, ``cycles`` times; then a final (I, B)."""
    if cycles < 1:
        raise ValueError("cycles must be >= 1")
    counter = [0]
    inertia, damping, friction = initial
    for _ in range(cycles):
        inertia, damping = _lm(simulate, theta, counter, (inertia, damping, friction), (0, 1), tol, batched_jacobian)
        (friction,) = _lm(simulate, theta, counter, (inertia, damping, friction), (2,), tol, batched_jacobian)
    inertia, damping = _lm(simulate, theta, counter, (inertia, damping, friction), (0, 1), tol, batched_jacobian)
    final = simulate(np.array([[inertia, damping, friction]]))[0]
    counter[0] += 1
    rmse = float(np.sqrt(np.mean((final - theta) ** 2)))
    return AlternatingResult(inertia, damping, friction, rmse, counter[0])


def _lm(simulate, theta, counter, point, free, tol, batched_jacobian) -> np.ndarray:
    """One ``lsqnonlin``: Levenberg–Marquardt over the ``free`` entries of (I, B, F)."""
    base = np.asarray(point, dtype=float)

    def rows_for(x: np.ndarray) -> np.ndarray:
        rows = np.repeat(base[None, :], x.shape[0], axis=0)
        rows[:, free] = x
        return rows

    def residual(x):
        counter[0] += 1
        return simulate(rows_for(x[None, :]))[0] - theta

    def jacobian(x):
        steps = FD_STEP * np.maximum(np.abs(x), 1e-3)
        probes = np.vstack([x, x + np.diag(steps)])
        counter[0] += len(probes)
        sims = simulate(rows_for(probes))
        return ((sims[1:] - sims[0]) / steps[:, None]).T

    x0 = base[list(free)]
    jac = jacobian if batched_jacobian else "2-point"
    result = least_squares(residual, x0, jac=jac, method="lm", xtol=tol, ftol=tol)
    return result.x


def rust_simulator(trial, x0: tuple[float, float], tanh_k: float = TANH_K,
                   max_step: float = MAX_STEP) -> BatchSimulator:
    """A :data:`BatchSimulator` over one trial, running on ``_rtcore.simulate_batch``."""
    from admittance import _rtcore

    names = list(_rtcore.PARAM_NAMES)
    defaults = _default_vector(names, tanh_k)
    rt_trial = _rtcore.Trial(trial.t, trial.tau, load_inertia=0.0, gravity_torque=trial.gravity_torque)
    cols = [names.index(n) for n in ("motor_inertia", "damping", "coulomb")]

    def simulate(rows: np.ndarray) -> np.ndarray:
        params = np.repeat(defaults[None, :], len(rows), axis=0)
        params[:, cols] = rows
        params[:, cols[0]] = np.maximum(params[:, cols[0]], 1e-9)  # LM may probe I <= 0
        start = np.tile(np.asarray(x0, dtype=float), (len(rows), 1, 1))
        return np.asarray(
            _rtcore.simulate_batch([rt_trial], params, start, max_step=max_step, friction="tanh")[0]
        )

    return simulate


def _default_vector(names: Sequence[str], tanh_k: float) -> np.ndarray:
    from admittance.formats.paramfile import PARAM_DEFAULTS

    vec = np.array([PARAM_DEFAULTS.get(n) or 0.0 for n in names], dtype=float)
    vec[names.index("tanh_k")] = tanh_k
    return vec


def initial_friction_for(motor: str) -> float:
    """Table 3.1's average for the motor named in the label (e.g. "MX-64 (bench 2)"); else the
    script's 0.1234."""
    for name in sorted(BREAKAWAY_AVERAGE, key=len, reverse=True):
        if name.lower() in motor.lower():
            return BREAKAWAY_AVERAGE[name]
    return BREAKAWAY_AVERAGE["MX-106"]


def initial_state(trial, x0: str = "rest") -> tuple[float, float]:
    """(θ0, ω0): the first angle at rest (the thesis), or with ω0 from the first 50 ms."""
    if x0 == "rest":
        return float(trial.theta[0]), 0.0
    if x0 != "data":
        raise ValueError(f"x0 must be 'rest' or 'data', got {x0!r}")
    head = trial.t <= trial.t[0] + 0.05
    if head.sum() < 3:
        head = np.arange(trial.t.size) < 3
    coef = np.polyfit(trial.t[head] - trial.t[0], trial.theta[head], 2)
    return float(coef[2]), float(coef[1])


# --------------------------------------------------------------------------- the tables


@dataclass
class ThesisRow:
    """One line of tables 3.2–3.4 (plus the script-vs-correct rod inertia and the fit error)."""

    trial: str
    bob_distance_cm: float | None
    direction: str
    friction: float
    inertia_motor: float  # I − I_rod(script, half length) − I_bob: the thesis's column
    inertia_motor_correct_rod: float  # I − (1/3)·m·L² − I_bob
    inertia_total: float
    damping: float
    rmse: float


def rod_inertias(geometry: dict) -> tuple[float, float]:
    """(the script's (1/3)·m·(L/2)², the correct (1/3)·m·L²) of the dataset's rod; 0 without one."""
    rod = (geometry or {}).get("rod")
    if not rod:
        return 0.0, 0.0
    return rod["mass"] * (rod["length"] / 2) ** 2 / 3.0, rod["mass"] * rod["length"] ** 2 / 3.0


def thesis_row(trial, geometry: dict, fit: AlternatingResult) -> ThesisRow:
    script_rod, correct_rod = rod_inertias(geometry)
    bob_inertia = trial.load_inertia - correct_rod  # the dataset's load = correct rod + bob
    distance = trial.meta.get("bob_distance")
    return ThesisRow(
        trial=trial.name,
        bob_distance_cm=None if distance is None else round(100.0 * float(distance), 6),
        direction=str(trial.meta.get("direction", "")),
        friction=fit.friction,
        inertia_motor=fit.inertia_total - script_rod - bob_inertia,
        inertia_motor_correct_rod=fit.inertia_total - trial.load_inertia,
        inertia_total=fit.inertia_total,
        damping=fit.damping,
        rmse=fit.rmse,
    )


def fit_dataset(
    dataset,
    cycles: int = CYCLES,
    x0: str = "rest",
    initial_friction: float | None = None,
    initial_inertia: float = INITIAL_INERTIA,
    initial_damping: float = INITIAL_DAMPING,
    simulator_factory=rust_simulator,
    batched_jacobian: bool = True,
    progress: Callable[[str], None] | None = None,
) -> list[ThesisRow]:
    """Fit every trial of a geometry-mode dataset the thesis's way; one row per trial.

    The initial guesses default to the thesis's (its MX rig, I_total ≈ 0.02–0.05 kg·m²); like
    ``lsqnonlin``'s LM the fit is unbounded, so a rig far from them (a small servo) needs its
    own guesses or the inertia can wander negative.
    """
    if dataset.mode != "geometry":
        raise DataError("thesis mode needs the pendulum geometry ([rod] and/or [bob] in the manifest)")
    friction0 = initial_friction if initial_friction is not None else initial_friction_for(dataset.motor)
    rows = []
    for trial in dataset.trials:
        simulate = simulator_factory(trial, initial_state(trial, x0))
        fit = alternating_fit(
            simulate, trial.theta, (initial_inertia, initial_damping, friction0), cycles,
            batched_jacobian=batched_jacobian,
        )
        rows.append(thesis_row(trial, dataset.geometry, fit))
        if progress:
            progress(f"{trial.name}: I={fit.inertia_total:.4f} B={fit.damping:.4f} F={fit.friction:.4f}")
    return rows


VALUE_COLUMNS = ("friction", "inertia_motor", "inertia_motor_correct_rod", "inertia_total", "damping", "rmse")
HEADINGS = (
    "Friction (N·m)", "Inertia motor (kg·m²)", "Inertia motor, correct rod (kg·m²)",
    "Inertia total (kg·m²)", "Damping (N·m·s/rad)", "RMSE (rad)",
)


def summary_rows(rows: Sequence[ThesisRow]) -> list[tuple[str, dict[str, float]]]:
    """The tables' layout: each distance's trials then its average, last the motor average.

    Like the thesis, the motor average leaves out the total inertia (it depends on the bob).
    """
    out: list[tuple[str, dict[str, float]]] = []
    distances = sorted({r.bob_distance_cm for r in rows if r.bob_distance_cm is not None}, reverse=True)
    groups = [[r for r in rows if r.bob_distance_cm == d] for d in distances]
    groups += [[r for r in rows if r.bob_distance_cm is None]]
    for d, group in zip(distances + [None], groups):
        if not group:
            continue
        out += [(r.trial, {c: getattr(r, c) for c in VALUE_COLUMNS}) for r in group]
        if d is not None:
            out.append((f"Average at {d:g} cm", _means(group)))
    overall = _means(rows)
    overall.pop("inertia_total")
    out.append(("Motor average", overall))
    return out


def _means(rows: Sequence[ThesisRow]) -> dict[str, float]:
    return {c: statistics.mean(getattr(r, c) for r in rows) for c in VALUE_COLUMNS}


def to_markdown(rows: Sequence[ThesisRow], title: str = "") -> str:
    lines = [f"### {title}", ""] if title else []
    lines += ["| Trial | " + " | ".join(HEADINGS) + " |", "|---" * (len(HEADINGS) + 1) + "|"]
    for label, values in summary_rows(rows):
        cells = [_fmt(values.get(c)) for c in VALUE_COLUMNS]
        bold = label.startswith(("Average", "Motor"))
        name = f"**{label}**" if bold else label
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def to_csv(rows: Sequence[ThesisRow]) -> str:
    """Per-trial rows (all fields), then the average lines with an empty direction."""
    buf = io.StringIO()
    fields = list(asdict(rows[0])) if rows else ["trial", *VALUE_COLUMNS]
    writer = csv.DictWriter(buf, fieldnames=fields, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow(asdict(row))
    for label, values in summary_rows(rows):
        if label.startswith(("Average", "Motor")):
            writer.writerow({"trial": label, **{k: v for k, v in values.items()}})
    return buf.getvalue()


def _fmt(value: float | None) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ""
    return f"{value:.4f}"
