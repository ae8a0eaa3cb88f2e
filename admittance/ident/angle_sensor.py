"""What the angle sensor does to the data, and when a residual is "nothing but the sensor".

Two kinds of sensor read pendulum angles, and their errors look nothing alike:

- **Motion capture** (OptiTrack): continuous values with roughly white noise. A perfect model
  leaves a residual that is white, at the level second differences measure
  (var(Δ²e) = 6σ² for white e).
- **An encoder** (a Dynamixel's AS5045: 4096 ticks per revolution, 1.53 mrad per tick): the
  angle is rounded to a grid. While the joint moves several ticks per sample the rounding error
  is nearly white with variance Δ²/12; at rest it is a *constant* bias within ±Δ/2, and at slow
  speeds a sawtooth. So a perfect model leaves a residual that is neither white (the bias and the
  sawtooth are correlated) nor measured by second differences (they vanish at rest). Judged as
  motion-capture noise, a clean encoder set always looks structured, the effect search always
  runs, and on the one dataset in twenty where noise lines up with a candidate, it names one.

The grid step Δ comes from the manifest (``encoder_ticks``: ticks per revolution) or from the
data: the angles of an encoder log all sit on one lattice, so every sample-to-sample change is
a whole multiple of Δ (:func:`infer_quantum`). Motion-capture angles never are.

"Nothing left" (:func:`nothing_left`) then asks the question that fits the sensor. Without a
grid: is the residual at the second-difference noise level, and white (Ljung–Box) or with a
structure too small to matter (:func:`structure_share`: with 30 drops Ljung–Box finds a
correlation of 1 % of the variance, which no effect could be admitted for)? With a grid:
could the sensor itself have produced this residual from the simulated motion? The check is a
parametric bootstrap: the simulated angle is read through the same sensor (white noise of the
measured size, then the same rounding) a few dozen times, and the observed residual's RMS and
Ljung–Box statistic are compared with those replicas.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from admittance.ident.smoothing import chi2_sf

LJUNG_BOX_LAGS = 20
WHITE_P = 0.01  # Ljung–Box p above which the residual counts as white
NOISE_RATIO = 1.1  # RMSE within this factor of the noise floor: at the floor
# Share of the residual variance a structure must hold to matter: removing a share s lowers the
# RMS by 1 − √(1 − s), and below 3 % (the effect search's default --min-gain) no effect can be
# admitted for it. 1 − 0.97² = 0.059.
MATERIAL_SHARE = 1.0 - (1.0 - 0.03) ** 2
MIN_GRID_STEPS = 30  # sample-to-sample changes needed to trust an inferred grid
GRID_TOLERANCE = 0.02  # of a step: how far a change may sit from a whole number of steps
BOOTSTRAP_REPLICAS = 24
MOVING_STEPS = 4  # a sample counts as moving when the angle changes by this many steps over 2 samples


@dataclass(frozen=True)
class Sensor:
    """The angle sensor of a dataset: its grid step (0 for continuous values) and where that came from."""

    quantum: float = 0.0  # rad
    phase: float = 0.0  # rad: the grid is phase + k·quantum
    source: str = "none"  # "manifest", "inferred" or "none"

    @property
    def ticks(self) -> float | None:
        return 2 * math.pi / self.quantum if self.quantum > 0 else None

    def as_dict(self) -> dict:
        return {"quantum": self.quantum, "ticks_per_rev": self.ticks, "source": self.source}

    def read(self, theta: np.ndarray) -> np.ndarray:
        """The angle as this sensor would report it (rounded to its grid)."""
        if self.quantum <= 0:
            return theta
        return self.phase + self.quantum * np.round((theta - self.phase) / self.quantum)


def sensor_for(trials, encoder_ticks: int | None) -> Sensor:
    """The manifest's ``encoder_ticks`` if given, else a grid inferred from the angles."""
    thetas = [tr.theta for tr in trials]
    if encoder_ticks:
        quantum = 2 * math.pi / encoder_ticks
        return Sensor(quantum, _grid_phase(thetas, quantum), "manifest")
    quantum = infer_quantum(thetas)
    if quantum <= 0:
        return Sensor()
    return Sensor(quantum, _grid_phase(thetas, quantum), "inferred")


def infer_quantum(thetas: Sequence[np.ndarray]) -> float:
    """The grid step of quantised angles (rad), or 0 when they are not on a grid.

    Every sample-to-sample change of an encoder angle is a whole number of ticks, so the
    smallest non-zero change is a candidate step, accepted when (nearly) every change is a whole
    multiple of it. When the step is within 0.5 % of 2π/N for a whole N, it is snapped there
    (files store angles to a few digits)."""
    diffs = np.concatenate([np.abs(np.diff(th)) for th in thetas if th.size > 1])
    scale = max(float(np.max(np.abs(np.concatenate(thetas)))), 1.0)
    moved = diffs[diffs > 1e-9 * scale]
    if moved.size < MIN_GRID_STEPS:
        return 0.0
    step = float(np.min(moved))
    ratio = moved / step
    if float(np.quantile(ratio, 0.99)) > 1e4:  # continuous values: a tiny minimum difference
        return 0.0
    off = np.abs(ratio - np.round(ratio))
    if np.mean(off < GRID_TOLERANCE) < 0.99:
        return 0.0
    refined = float(np.median(moved / np.round(ratio)))
    ticks = 2 * math.pi / refined
    if abs(ticks - round(ticks)) < 0.005 * ticks:
        return 2 * math.pi / round(ticks)
    return refined


def _grid_phase(thetas: Sequence[np.ndarray], quantum: float) -> float:
    """Where the grid sits: the circular mean of the angles modulo the step."""
    values = np.concatenate(thetas)
    angle = 2 * math.pi * values / quantum
    return float(quantum * math.atan2(np.mean(np.sin(angle)), np.mean(np.cos(angle))) / (2 * math.pi))


def second_difference_noise(residuals: Sequence[np.ndarray]) -> float:
    """σ of the white part of the residual, from second differences."""
    d2 = np.concatenate([np.diff(r, 2) for r in residuals if r.size > 2])
    return float(np.sqrt(np.mean(d2**2) / 6.0)) if d2.size else 0.0


def ljung_box(residuals: Sequence[np.ndarray], lags: int = LJUNG_BOX_LAGS) -> tuple[float, float]:
    """(Q statistic, p-value) with the autocorrelation pooled over trials."""
    num = np.zeros(lags + 1)
    den = 0.0
    n_total = 0
    for r in residuals:
        if r.size == 0:  # a segment with no samples adds nothing (and its mean is undefined)
            continue
        x = r - r.mean()
        n = x.size
        n_total += n
        for k in range(min(lags, n - 1) + 1):
            num[k] += float(x[: n - k] @ x[k:])
        den += float(x @ x)
    if den <= 0 or n_total <= lags + 1:
        return 0.0, 1.0
    rho = num[1:] / den
    k = np.arange(1, lags + 1)
    q = float(n_total * (n_total + 2) * np.sum(rho**2 / (n_total - k)))
    return q, chi2_sf(q, lags)


@dataclass(frozen=True)
class NoiseVerdict:
    """How the residual compares with what the sensor alone would leave."""

    floor: float  # rad: RMS residual a perfect model would leave
    white: bool  # no more autocorrelation than the sensor makes
    ljung_box_q: float
    ljung_box_p: float
    white_noise: float  # rad: σ of the sensor's white part (before rounding)
    rmse: float
    quantised: bool = False
    correlation: float = 0.0  # lag-1 autocorrelation of the sensor noise (0: white)
    structure: float = 1.0  # estimated share of the residual variance that is not the sensor's (structure_share)

    @property
    def at_floor(self) -> bool:
        return self.floor > 0 and self.rmse < NOISE_RATIO * self.floor

    @property
    def immaterial(self) -> bool:
        """The structure Ljung–Box may find is too small to matter (MATERIAL_SHARE)."""
        return self.structure < MATERIAL_SHARE

    @property
    def nothing_left(self) -> bool:
        # On an encoder, whiteness is no test at the floor: a model error smaller than a tick
        # (the fit's own 1 ms integration error is ~0.3 mrad on a thesis pendulum) moves which
        # samples cross a tick, so the rounding pattern of the data and of any replica differ.
        # With a continuous sensor, a structure Ljung–Box finds only because it has many samples
        # (30 drops: 12,000 and more) is not left to explain when it is immaterial.
        return self.at_floor and (self.white or self.quantised or self.immaterial)


def noise_verdict(measured: Sequence[np.ndarray], residuals: Sequence[np.ndarray], sensor: Sensor,
                  at_rest: Sequence[np.ndarray] | None = None) -> NoiseVerdict:
    """Compare a residual (simulated − measured, per trial) with the sensor's own error.

    ``at_rest`` (per trial, boolean) marks samples where the simulated joint sticks: there the
    residual of a continuous sensor is its noise alone (plus a constant), whatever its colour,
    which :func:`rest_noise` uses to recognise filtered (coloured) motion-capture noise."""
    rmse = _rms(residuals)
    if sensor.quantum <= 0:
        return _continuous_verdict(residuals, at_rest, rmse)
    q, _ = ljung_box(residuals)
    simulated = [m + r for m, r in zip(measured, residuals)]
    white_noise = _white_part(measured, residuals, sensor.quantum)
    rng = np.random.default_rng(20240917)  # fixed: the same data always get the same verdict
    rms_rep, q_rep = [], []
    for _ in range(BOOTSTRAP_REPLICAS):
        replica = [s - sensor.read(s + rng.normal(0.0, white_noise, s.size)) for s in simulated]
        rms_rep.append(_rms(replica))
        q_rep.append(ljung_box(replica)[0])
    floor = float(np.mean(rms_rep))
    p_boot = _scaled_chi2_sf(q, np.asarray(q_rep))
    return NoiseVerdict(floor, p_boot > WHITE_P, q, p_boot, white_noise, rmse, quantised=True)


def _continuous_verdict(residuals, at_rest, rmse: float) -> NoiseVerdict:
    """White noise from second differences; or, when the rest periods show a coloured noise
    that an AR(1) describes, that noise, and whiteness tested after removing its colour."""
    sigma = second_difference_noise(residuals)
    rest = rest_noise(residuals, at_rest) if at_rest is not None else None
    if rest is None or rest[0] <= sigma:
        q, p = ljung_box(residuals)
        return NoiseVerdict(sigma, p > WHITE_P, q, p, sigma, rmse, structure=structure_share(q, residuals, sigma, rmse))
    rest_sigma, rho = rest
    whitened = [r[1:] - rho * r[:-1] for r in residuals if r.size > 1]
    q, p = ljung_box(whitened)
    return NoiseVerdict(rest_sigma, p > WHITE_P, q, p, rest_sigma, rmse, correlation=rho,
                        structure=structure_share(q, whitened, rest_sigma, rmse))


def structure_share(q: float, residuals: Sequence[np.ndarray], noise: float, rmse: float) -> float:
    """The share of the residual variance that is not the sensor's noise, the larger of two
    estimates: 1 − (noise / RMS)² (what the RMS test reads), and the correlation Ljung–Box
    found, √((Q − lags) / (n · lags)) (a slow part holding a share s of the variance correlates
    every lag by about s; Q − lags is Q's excess over its mean on white noise).

    Ljung–Box asks whether *any* correlation is there, and with many samples it finds the
    smallest: on 30 test-oracle drops with a load-dependent Coulomb term (12,020 training
    samples) the right model, every trial at the 2 mrad noise and 2.00 mrad held out, left lag
    3–12 correlations of 0.01–0.02 and p = 0.004: a share of about 1 %, which no effect could
    be admitted for. That verdict was `unexplained`."""
    n = sum(r.size for r in residuals)
    correlated = math.sqrt(max(q - LJUNG_BOX_LAGS, 0.0) / (max(n, 1) * LJUNG_BOX_LAGS))
    from_rms = 1.0 - (noise / rmse) ** 2 if rmse > 0 else 0.0
    return float(min(max(correlated, from_rms, 0.0), 1.0))


MIN_REST_RUN = 40  # samples: a rest period shorter than this says little about the noise
# Lag-1 correlation above which "noise" at rest is taken for motion: a correlation time of
# 2/(1 − ρ) = 40 samples, a third of a second at 120 Hz (filtered motion capture stays well below).
MAX_NOISE_CORRELATION = 0.95
MIN_REST_SAMPLES = 200


def rest_noise(residuals: Sequence[np.ndarray], at_rest: Sequence[np.ndarray]) -> tuple[float, float] | None:
    """(σ, lag-1 correlation ρ) of the residual where the model says the joint is at rest, when
    an AR(1) with those values explains it (its innovations are white); else None.

    At rest the simulated angle is constant, so the residual is the sensor's noise plus a
    constant: its variance is the noise variance whatever the noise's colour, which second
    differences badly underestimate for filtered noise (by 4× at ρ = 0.9). A real joint that
    still moves where the model has stopped (a presliding oscillation) leaves structure that an
    AR(1) does not whiten, and is then not taken for noise."""
    pieces = []
    for r, mask in zip(residuals, at_rest):
        for run in _runs(mask):
            if run.stop - run.start >= MIN_REST_RUN:
                piece = r[run.start + MIN_REST_RUN // 4 : run.stop]
                pieces.append(piece - piece.mean())
    if sum(p.size for p in pieces) < MIN_REST_SAMPLES:
        return None
    energy = sum(float(p @ p) for p in pieces)
    if energy <= 0.0:  # a residual exactly constant at rest (a noiseless angle): no noise to model
        return None
    var = energy / sum(p.size for p in pieces)
    lag1 = sum(float(p[1:] @ p[:-1]) for p in pieces) / energy
    rho = max(lag1, 0.0)
    if rho > MAX_NOISE_CORRELATION:  # that slow, it is the joint moving, not a sensor's noise
        return None
    _, p_white = ljung_box([p[1:] - rho * p[:-1] for p in pieces])
    if p_white <= WHITE_P:
        return None
    return float(math.sqrt(var)), float(rho)


def _runs(mask: np.ndarray) -> list[slice]:
    padded = np.concatenate([[False], np.asarray(mask, bool), [False]])
    edges = np.flatnonzero(np.diff(padded.astype(int)))
    return [slice(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2])]


def _white_part(measured, residuals, quantum: float) -> float:
    """σ of the noise added before rounding: second differences where the joint moves several
    steps per sample (there the rounding error is nearly white, variance Δ²/12), less the
    rounding's share."""
    d2, count = 0.0, 0
    for m, r in zip(measured, residuals):
        if m.size < 3:
            continue
        moving = np.abs(m[2:] - m[:-2]) >= MOVING_STEPS * quantum
        dd = np.diff(r, 2)[moving]
        d2 += float(dd @ dd)
        count += dd.size
    if count < MIN_GRID_STEPS:
        return 0.0
    return float(math.sqrt(max(d2 / count / 6.0 - quantum**2 / 12.0, 0.0)))


def _scaled_chi2_sf(q: float, replicas: np.ndarray) -> float:
    """Tail probability of ``q`` under a scaled χ² matched to the replicas' mean and variance
    (Satterthwaite): a few dozen replicas then give a usable 1 % tail."""
    mean, var = float(np.mean(replicas)), float(np.var(replicas, ddof=1))
    if mean <= 0:
        return 1.0 if q <= 0 else 0.0
    if var <= 0:
        return 1.0 if q <= mean else 0.0
    scale = var / (2 * mean)
    dof = max(2 * mean**2 / var, 1.0)
    return chi2_sf(q / scale, int(round(dof))) if dof >= 1 else 1.0


def _rms(residuals: Sequence[np.ndarray]) -> float:
    total = sum(float(r @ r) for r in residuals)
    count = sum(r.size for r in residuals)
    return float(math.sqrt(total / max(count, 1)))
