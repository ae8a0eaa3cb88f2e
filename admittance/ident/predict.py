"""The thesis's testing trials (section 3.3, appendix B): fitted parameters against torque data.

Two checks per trial that carries a measured torque:

(a) **torque → position.** Simulate the fitted model (a Contract 2 file) driven by the measured
    torque from the trial's initial state, and compare the predicted angle with the recorded
    one. This is the thesis's "recorded and predicted position" figure.
(b) **position → torque.** Low-pass the recorded angle (2nd-order Butterworth at 5 Hz, run
    forwards and backwards with ``filtfilt``, as appendix C.4), differentiate twice, and
    compute the torque the model needs: the thesis's ``I·acc + D·vel + tanh(k·vel)·F`` and the
    full model of Contract 1 (gravity, asymmetric/Stribeck friction, drag, cogging). Compare
    with the measured torque: RMSE, correlation, and the lag that maximises their
    cross-correlation (the thesis saw the measured torque late at fast speeds).

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
    torque_rmse_thesis: float  # N·m, (b) with the thesis's formula
    torque_rmse_model: float  # N·m, (b) with the full model
    torque_corr_model: float
    torque_lag: float  # s, > 0: the measured torque lags the calculated one


@dataclass
class TrialPrediction:
    """The series behind the metrics and the appendix-B plots."""

    t: np.ndarray
    theta: np.ndarray
    theta_pred: np.ndarray
    tau: np.ndarray
    tau_thesis: np.ndarray
    tau_model: np.ndarray
    metrics: PredictMetrics


def load_params(path: str | Path) -> tuple[dict[str, float], str]:
    """(parameters with defaults filled in, friction law) of a geometry-mode Contract 2 file."""
    from admittance.ident import paramfile

    doc = paramfile.load(path)
    if doc["model"].get("mode", "geometry") != "geometry":
        raise ConfigError(f"{path}: predict needs a geometry-mode parameter file (this one is lumped)")
    full = dict(zip(paramfile.PARAM_NAMES, paramfile.full_vector(doc["params"])))
    return full, doc["model"].get("friction", "stick")


def predict_trial(trial, params: dict[str, float], friction: str, tanh_k_thesis: float | None = None,
                  max_step: float = 1e-3) -> TrialPrediction:
    """Both checks on one ``TrialData`` with a torque column."""
    if trial.tau is None:
        raise DataError(f"{trial.name}: no tau column; predict needs the measured torque")
    theta_pred = predict_position(trial, params, friction, max_step)
    k = params["tanh_k"] if tanh_k_thesis is None else tanh_k_thesis
    grid, vel, acc, theta_f = filtered_derivatives(trial.t, trial.theta)
    inertia = params["motor_inertia"] + trial.load_inertia
    thesis_grid = inertia * acc + params["damping"] * vel + np.tanh(k * vel) * params["coulomb"]
    model_grid = model_torque(params, inertia, trial.gravity_torque, theta_f, vel, acc, friction)
    tau_thesis = np.interp(trial.t, grid, thesis_grid)
    tau_model = np.interp(trial.t, grid, model_grid)
    measured = corrected_torque(trial.t, trial.tau, params)
    metrics = PredictMetrics(
        trial=trial.name,
        position_rmse=_rmse(theta_pred, trial.theta),
        position_corr=_corr(theta_pred, trial.theta),
        torque_rmse_thesis=_rmse(tau_thesis, trial.tau),
        torque_rmse_model=_rmse(tau_model, measured),
        torque_corr_model=_corr(tau_model, measured),
        torque_lag=lag_of(grid, model_grid, np.interp(grid, trial.t, trial.tau)),
    )
    return TrialPrediction(trial.t, trial.theta, theta_pred, trial.tau, tau_thesis, tau_model, metrics)


def predict_position(trial, params: dict[str, float], friction: str, max_step: float = 1e-3) -> np.ndarray:
    """(a): the fitted model driven by the measured torque, from the trial's initial state."""
    from admittance import sim
    from admittance.ident.thesis import initial_state

    rt = sim.make_trial(trial.t, trial.tau, trial.load_inertia, trial.gravity_torque)
    theta0, omega0 = initial_state(trial, "data")
    return sim.simulate(rt, params, theta0, omega0, max_step=max_step, friction=friction)


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


def model_torque(p: dict[str, float], inertia: float, gravity: float, theta, vel, acc, friction: str) -> np.ndarray:
    """Inverse dynamics of Contract 1: the applied torque that produces (θ, ω, ω')."""
    load = gravity * np.sin(theta - p["angle_offset"])
    cogging = p["cogging_amplitude"] * np.sin(p["cogging_period"] * theta + p["cogging_phase"])
    direction = np.sign(vel)
    level = (p["coulomb"] + direction * p["coulomb_asym"]
             + p["stribeck_torque"] * np.exp(-(vel / max(p["stribeck_velocity"], 1e-12)) ** 2))
    applied = inertia * acc + load + cogging + p["damping"] * vel + p["quadratic_drag"] * vel * np.abs(vel)
    level = level + p["load_coulomb"] * np.abs(load - applied)  # first-order: τ ≈ applied
    shape = np.tanh(p["tanh_k"] * vel) if friction == "tanh" else np.where(np.abs(vel) > VELOCITY_EPS, direction, 0.0)
    return applied + np.maximum(level, 0.0) * shape


def corrected_torque(t: np.ndarray, tau: np.ndarray, p: dict[str, float]) -> np.ndarray:
    """The measured torque as the model sees it: delayed, minus bias and drift (Contract 1)."""
    delayed = np.interp(t - p["time_delay"], t, tau)
    return delayed - p["torque_bias"] - p["torque_drift"] * (t - t[0])


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


def predict_dataset(dataset, params_path: str | Path, tanh_k_thesis: float | None = None) -> list[TrialPrediction]:
    params, friction = load_params(params_path)
    driven = [tr for tr in dataset.trials if tr.tau is not None]
    if not driven:
        raise DataError("no trial of this dataset has a tau column; predict needs measured torque")
    return [predict_trial(tr, params, friction, tanh_k_thesis) for tr in driven]


def metrics_table(predictions: list[TrialPrediction]) -> str:
    head = ("| Trial | Position RMSE (rad) | Position corr. | Torque RMSE, thesis formula (N·m) "
            "| Torque RMSE, model (N·m) | Torque corr., model | Lag of measured torque (s) |")
    lines = [head, "|---|---|---|---|---|---|---|"]
    for p in predictions:
        m = p.metrics
        lines.append(f"| {m.trial} | {m.position_rmse:.4f} | {m.position_corr:.3f} | {m.torque_rmse_thesis:.4f} "
                     f"| {m.torque_rmse_model:.4f} | {m.torque_corr_model:.3f} | {m.torque_lag:+.3f} |")
    return "\n".join(lines) + "\n"


def metrics_dicts(predictions: list[TrialPrediction]) -> list[dict]:
    return [asdict(p.metrics) for p in predictions]


def plot_trial(prediction: TrialPrediction, out_dir: Path) -> list[Path]:
    """Appendix B's three figures: position and torque; measured vs calculated torque;
    recorded vs predicted position."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    p = prediction
    stem = Path(p.metrics.trial).stem
    paths = []
    fig, ax = plt.subplots(figsize=(8, 3.5))
    ax.plot(p.t, p.theta, color="tab:blue", label="position")
    ax.set_xlabel("Time (s)")
    ax.set_ylabel("Position (rad)")
    ax2 = ax.twinx()
    ax2.plot(p.t, p.tau, color="tab:red", label="torque")
    ax2.set_ylabel("Torque (N·m)")
    ax.set_title(f"{stem}: measured position and torque")
    paths.append(_save(fig, out_dir / f"{stem}_position_torque.png"))
    fig, ax = plt.subplots(figsize=(8, 3.5))
    ax.plot(p.t, p.tau_thesis, label="calculated (thesis formula)")
    ax.plot(p.t, p.tau_model, label="calculated (model)")
    ax.plot(p.t, p.tau, label="measured", alpha=0.8)
    ax.set(xlabel="Time (s)", ylabel="Torque (N·m)", title=f"{stem}: measured and calculated torque")
    ax.legend()
    paths.append(_save(fig, out_dir / f"{stem}_torque.png"))
    fig, ax = plt.subplots(figsize=(8, 3.5))
    ax.plot(p.t, p.theta, label="recorded")
    ax.plot(p.t, p.theta_pred, label="predicted")
    ax.set(xlabel="Time (s)", ylabel="Position (rad)", title=f"{stem}: recorded and predicted position")
    ax.legend()
    paths.append(_save(fig, out_dir / f"{stem}_position.png"))
    return paths


def _save(fig, path: Path) -> Path:
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
