"""The thesis's testing trials (section 3.3, appendix B): fitted parameters against torque data.

Two checks per trial:

(a) **torque → position.** Simulate the fitted model (a Contract 2 file) driven by the measured
    torque from the trial's initial state, and compare the predicted angle with the recorded
    one. This is the thesis's "recorded and predicted position" figure. It also runs on free
    swings (no torque), which makes it the residual plot of an identification.
(b) **position → torque** (trials with a measured torque). Low-pass the recorded angle
    (2nd-order Butterworth at 5 Hz, run forwards and backwards with ``filtfilt``, as
    appendix C.4), differentiate twice, and compute the torque the model needs: the thesis's
    ``I·acc + D·vel + tanh(k·vel)·F`` and the full model of Contract 1 (gravity,
    asymmetric/Stribeck friction, drag, cogging). Compare with the measured torque: RMSE,
    correlation, and the lag that maximises their cross-correlation (the thesis saw the
    measured torque late at fast speeds).

Why both: (a) is what a user feels (does the joint go where the model says?) but integrates
torque errors into drift; (b) localises errors in time and exposes a delay directly.

Non-uniform sampling: filtering and the cross-correlation need a uniform grid, so the angle
and torque are resampled (linear interpolation) at the median interval, processed, and the
calculated torque is interpolated back to the trial's times.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy.signal import butter, correlate, filtfilt

from admittance.errors import ConfigError, DataError

CUTOFF_HZ = 5.0
MAX_LAG_S = 0.5
VELOCITY_EPS = 1e-3  # rad/s: below this the Coulomb sign is taken as 0 in inverse dynamics


@dataclass
class PredictMetrics:
    trial: str
    position_rmse: float  # rad, (a)
    position_corr: float
    torque_rmse_thesis: float | None = None  # N·m, (b) with the thesis's formula
    torque_rmse_model: float | None = None  # N·m, (b) with the full model
    torque_corr_model: float | None = None
    torque_lag: float | None = None  # s, > 0: the measured torque lags the calculated one


@dataclass
class TrialPrediction:
    """The series behind the metrics and the appendix-B plots (torques None for a free swing)."""

    t: np.ndarray
    theta: np.ndarray
    theta_pred: np.ndarray
    metrics: PredictMetrics
    tau: np.ndarray | None = None
    tau_thesis: np.ndarray | None = None
    tau_model: np.ndarray | None = None


def load_params(path: str | Path) -> tuple[dict[str, float], str]:
    """(parameters with defaults filled in, friction law) of a geometry-mode Contract 2 file."""
    from admittance.formats import paramfile

    doc = paramfile.load(path)
    if doc["model"].get("mode", "geometry") != "geometry":
        raise ConfigError(f"{path}: predict needs a geometry-mode parameter file (this one is lumped)")
    full = dict(zip(paramfile.PARAM_NAMES, paramfile.full_vector(doc["params"])))
    return full, doc["model"].get("friction", "stick")


def predict_trial(trial, params: dict[str, float], friction: str, tanh_k_thesis: float | None = None,
                  max_step: float = 1e-3, x0: str = "fit") -> TrialPrediction:
    """(a) on any ``TrialData``; (b) as well when it carries a measured torque."""
    theta_pred = predict_position(trial, params, friction, max_step, x0)
    metrics = PredictMetrics(trial.name, _rmse(theta_pred, trial.theta), _corr(theta_pred, trial.theta))
    prediction = TrialPrediction(trial.t, trial.theta, theta_pred, metrics)
    if trial.tau is not None:
        _torque_check(prediction, trial, params, friction, tanh_k_thesis)
    return prediction


def _torque_check(prediction: TrialPrediction, trial, params, friction, tanh_k_thesis) -> None:
    """(b): calculated torques from the filtered motion, against the measured torque."""
    k = params["tanh_k"] if tanh_k_thesis is None else tanh_k_thesis
    grid, vel, acc, theta_f = filtered_derivatives(trial.t, trial.theta)
    thesis_grid = thesis_torque(params, k, trial.load_inertia, vel, acc)
    model_grid = model_torque(params, trial.load_inertia, trial.gravity_torque, theta_f, vel, acc, friction)
    prediction.tau = trial.tau
    prediction.tau_thesis = np.interp(trial.t, grid, thesis_grid)
    prediction.tau_model = np.interp(trial.t, grid, model_grid)
    measured = corrected_torque(trial.t, trial.tau, params)
    m = prediction.metrics
    m.torque_rmse_thesis = _rmse(prediction.tau_thesis, trial.tau)
    m.torque_rmse_model = _rmse(prediction.tau_model, measured)
    m.torque_corr_model = _corr(prediction.tau_model, measured)
    m.torque_lag = lag_of(grid, model_grid, np.interp(grid, trial.t, trial.tau))


def predict_position(trial, params: dict[str, float], friction: str, max_step: float = 1e-3,
                     x0: str = "fit") -> np.ndarray:
    """(a): the fitted model driven by the measured torque, from the trial's initial state.

    ``x0="fit"`` fits (θ0, ω0) to the whole trial with the model fixed, the same scoring as
    ``identify``'s held-out trials; ``"data"`` takes them from the first 50 ms of the record.
    """
    from admittance import sim
    from admittance.thesis.alternating import initial_state

    start = initial_state(trial, "data")
    if x0 == "fit":
        from admittance.ident.fit import fit_initial_states
        from admittance.ident.model import Simulator, vector_from

        fitted = fit_initial_states(Simulator([trial], "geometry", friction, max_step), vector_from(params),
                                    np.array([start]))
        return trial.theta + fitted.residuals[0]
    if x0 != "data":
        raise ConfigError(f"x0 must be 'fit' or 'data', got {x0!r}")
    rt = sim.make_trial(trial.t, trial.tau, trial.load_inertia, trial.gravity_torque)
    return sim.simulate(rt, params, start[0], start[1], max_step=max_step, friction=friction)


def filtered_derivatives(t: np.ndarray, theta: np.ndarray, cutoff: float = CUTOFF_HZ):
    """(uniform grid, velocity, acceleration, filtered angle): appendix C.4's filtfilt + derivatives."""
    dt = float(np.median(np.diff(t)))
    grid = t[0] + dt * np.arange(int(math.floor((t[-1] - t[0]) / dt)) + 1)
    nyquist = 0.5 / dt
    if cutoff >= nyquist:
        raise DataError(f"sampling at {1 / dt:.1f} Hz is too slow for a {cutoff} Hz low-pass")
    b, a = butter(2, cutoff / nyquist)
    if grid.size <= 3 * max(len(a), len(b)):
        raise DataError(f"only {grid.size} samples: too short to filter")
    theta_f = filtfilt(b, a, np.interp(grid, t, theta))
    vel = np.gradient(theta_f, dt)
    acc = np.gradient(vel, dt)
    return grid, vel, acc, theta_f


def thesis_torque(p: dict[str, float], tanh_k: float, load_inertia: float, vel, acc) -> np.ndarray:
    """The thesis's formula ``I·acc + D·vel + tanh(k·vel)·F`` (appendix C.4): Contract 1's inverse
    (the Rust plant's) with only I, D and F, tanh friction of slope k, and no gravity."""
    thesis = {"motor_inertia": p["motor_inertia"], "damping": p["damping"], "coulomb": p["coulomb"], "tanh_k": tanh_k}
    return model_torque(thesis, load_inertia, 0.0, np.zeros_like(vel), vel, acc, "tanh")


def model_torque(p: dict[str, float], load_inertia: float, gravity: float, theta, vel, acc, friction: str) -> np.ndarray:
    """Inverse dynamics of Contract 1: the applied torque that produces (θ, ω, ω'), computed by
    the Rust plant (``plant::inverse``), the same code that simulates the model forwards."""
    from admittance import _rtcore
    from admittance.sim import pack_params

    try:
        return _rtcore.required_torque(pack_params(p), theta, vel, acc, load_inertia=load_inertia,
                                       gravity_torque=gravity, friction=friction, velocity_eps=VELOCITY_EPS)
    except ValueError as exc:
        raise DataError(f"cannot compute the model's torque: {exc}") from exc


def corrected_torque(t: np.ndarray, tau: np.ndarray, p: dict[str, float]) -> np.ndarray:
    """The measured torque as the model sees it: delayed, scaled by the gain, minus bias and drift
    (Contract 1; the Rust plant's interpolation)."""
    from admittance import _rtcore
    from admittance.sim import pack_params

    try:
        return _rtcore.corrected_torque(pack_params(p), t, tau)
    except ValueError as exc:
        raise DataError(f"cannot correct the measured torque: {exc}") from exc


def lag_of(grid: np.ndarray, calculated: np.ndarray, measured: np.ndarray, max_lag: float = MAX_LAG_S) -> float:
    """The shift (s) of ``measured`` behind ``calculated`` that maximises their correlation."""
    dt = float(grid[1] - grid[0])
    a = calculated - calculated.mean()
    b = measured - measured.mean()
    xc = correlate(b, a, mode="full")
    lags = np.arange(-len(a) + 1, len(b))
    window = np.abs(lags) * dt <= max_lag
    return float(lags[window][int(np.argmax(xc[window]))] * dt)


def _rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a - b) ** 2)))


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    if np.std(a) == 0 or np.std(b) == 0:
        return float("nan")
    return float(np.corrcoef(a, b)[0, 1])


def predict_dataset(dataset, params_path: str | Path, tanh_k_thesis: float | None = None,
                    x0: str = "fit") -> list[TrialPrediction]:
    params, friction = load_params(params_path)
    return [predict_trial(tr, params, friction, tanh_k_thesis, x0=x0) for tr in dataset.trials]


def metrics_table(predictions: list[TrialPrediction]) -> str:
    head = ("| Trial | Position RMSE (rad) | Position corr. | Torque RMSE, thesis formula (N·m) "
            "| Torque RMSE, model (N·m) | Torque corr., model | Lag of measured torque (s) |")
    lines = [head, "|---|---|---|---|---|---|---|"]
    for p in predictions:
        m = p.metrics
        cells = [_fmt(m.position_rmse, ".4f"), _fmt(m.position_corr, ".3f"), _fmt(m.torque_rmse_thesis, ".4f"),
                 _fmt(m.torque_rmse_model, ".4f"), _fmt(m.torque_corr_model, ".3f"), _fmt(m.torque_lag, "+.3f")]
        lines.append(f"| {m.trial} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _fmt(value: float | None, spec: str) -> str:
    return "–" if value is None else format(value, spec)


def metrics_dicts(predictions: list[TrialPrediction]) -> list[dict]:
    return [asdict(p.metrics) for p in predictions]


def plot_trial(prediction: TrialPrediction, out_dir: Path) -> list[Path]:
    """Appendix B's figures: position and torque; measured vs calculated torque (trials with
    torque); recorded vs predicted position, with the residual below it."""
    import matplotlib

    matplotlib.use("Agg")
    stem = Path(prediction.metrics.trial).stem
    paths = _plot_torques(prediction, out_dir, stem) if prediction.tau is not None else []
    return paths + [_plot_position(prediction, out_dir, stem)]


def _plot_torques(p: TrialPrediction, out_dir: Path, stem: str) -> list[Path]:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 3.5))
    ax.plot(p.t, p.theta, color="tab:blue", label="position")
    ax.set(xlabel="Time (s)", ylabel="Position (rad)", title=f"{stem}: measured position and torque")
    ax2 = ax.twinx()
    ax2.plot(p.t, p.tau, color="tab:red", label="torque")
    ax2.set_ylabel("Torque (N·m)")
    first = _save(fig, out_dir / f"{stem}_position_torque.png")
    fig, ax = plt.subplots(figsize=(8, 3.5))
    ax.plot(p.t, p.tau_thesis, label="calculated (thesis formula)")
    ax.plot(p.t, p.tau_model, label="calculated (model)")
    ax.plot(p.t, p.tau, label="measured", alpha=0.8)
    ax.set(xlabel="Time (s)", ylabel="Torque (N·m)", title=f"{stem}: measured and calculated torque")
    ax.legend()
    return [first, _save(fig, out_dir / f"{stem}_torque.png")]


def _plot_position(p: TrialPrediction, out_dir: Path, stem: str) -> Path:
    import matplotlib.pyplot as plt

    fig, (ax, res) = plt.subplots(2, 1, figsize=(8, 5), sharex=True, gridspec_kw={"height_ratios": [2, 1]})
    ax.plot(p.t, p.theta, label="recorded")
    ax.plot(p.t, p.theta_pred, label="predicted")
    ax.set(ylabel="Position (rad)", title=f"{stem}: recorded and predicted position")
    ax.legend()
    res.plot(p.t, 1e3 * (p.theta - p.theta_pred), color="tab:gray")
    res.set(xlabel="Time (s)", ylabel="Residual (mrad)")
    return _save(fig, out_dir / f"{stem}_position.png")


def _save(fig, path: Path) -> Path:
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
