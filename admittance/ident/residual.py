"""What is left after the fit: is the residual white noise, and where is it large?

Three questions, each answered with a number and a one-line reading:

- **White?** A Ljung–Box test pooled over the trials (lags 1–20). A model that captured the
  physics leaves sensor noise, which is white; structure left in the residual shows as
  autocorrelation. With thousands of samples the test is strict, so the ratio of the RMSE to a
  noise estimate (from second differences, which model error of pendulum frequencies barely
  touches: var(Δ²e) = 6σ² for white e) says how far from the noise floor the fit is.
- **Where?** The residual's RMS in quantile bins of speed, angle and time since the start, with
  the bin that stands out most: speed points at friction terms, angle at offset or cogging,
  time at drift or a delay.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from admittance.ident.fit import FitResult, autocorrelation_time
from admittance.ident.model import Simulator
from admittance.ident.smoothing import chi2_sf

LJUNG_BOX_LAGS = 20
WHITE_P = 0.01  # Ljung–Box p above which the residual counts as white
N_BINS = 5


def noise_estimate(residuals: Sequence[np.ndarray]) -> float:
    """σ of the white part of the residual, from second differences."""
    d2 = np.concatenate([np.diff(r, 2) for r in residuals if r.size > 2])
    return float(np.sqrt(np.mean(d2**2) / 6.0)) if d2.size else 0.0


def ljung_box(residuals: Sequence[np.ndarray], lags: int = LJUNG_BOX_LAGS) -> tuple[float, float]:
    """(Q statistic, p-value) with the autocorrelation pooled over trials."""
    num = np.zeros(lags + 1)
    den = 0.0
    n_total = 0
    for r in residuals:
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


def binned_rms(values: np.ndarray, residual: np.ndarray, n_bins: int = N_BINS) -> list[dict]:
    """RMS of the residual in quantile bins of ``values``."""
    edges = np.unique(np.quantile(values, np.linspace(0, 1, n_bins + 1)))
    if edges.size < 2:
        return [{"low": float(values.min()), "high": float(values.max()), "rms": float(np.sqrt(np.mean(residual**2)))}]
    which = np.clip(np.searchsorted(edges, values, side="right") - 1, 0, edges.size - 2)
    out = []
    for b in range(edges.size - 1):
        sel = which == b
        if sel.any():
            out.append({"low": float(edges[b]), "high": float(edges[b + 1]),
                        "rms": float(np.sqrt(np.mean(residual[sel] ** 2)))})
    return out


def analyse(sim: Simulator, fit: FitResult) -> dict:
    """The residual verdict of ``fit`` on the trials of ``sim`` (those it was fitted on)."""
    sim = sim.with_tau_scale(fit.tau_scale)
    states = _simulate_states(sim, fit)
    speed = np.concatenate([np.abs(s[:, 1]) for s in states])
    angle = np.concatenate([s[:, 0] for s in states])
    since = np.concatenate([tr.t - tr.t[0] for tr in sim.trials])
    return verdict(fit.residuals, {"speed": speed, "angle": angle, "time": since})


def verdict(residuals: Sequence[np.ndarray], by: dict[str, np.ndarray]) -> dict:
    """Whiteness, distance from the noise floor and the worst bin of a residual (one array per
    trial); ``by`` gives, per sample of the concatenated residual, the speed (rad/s), angle (rad)
    and time since the trial's start (s) to bin it by."""
    residual = np.concatenate(residuals)
    rmse = float(np.sqrt(np.mean(residual**2)))
    noise = noise_estimate(residuals)
    q, p = ljung_box(residuals)
    bins = {name: binned_rms(values, residual) for name, values in by.items()}
    worst = _worst_bin(bins, rmse)
    out = {
        "rmse": rmse,
        "noise_estimate": noise,
        "rmse_over_noise": rmse / noise if noise > 0 else float("inf"),
        "ljung_box_q": q,
        "ljung_box_p": p,
        "white": bool(p > WHITE_P),
        "autocorrelation_time": autocorrelation_time(residuals),
        "bins": bins,
        "largest": worst,
    }
    out["summary"] = summary(out)
    return out


def _simulate_states(sim: Simulator, fit: FitResult) -> list[np.ndarray]:
    return [o[0] for o in sim.run(fit.vector[None, :], fit.x0[None, :, :], velocity=True)]


def _worst_bin(bins: dict, rmse: float) -> dict:
    best = {"by": "", "low": 0.0, "high": 0.0, "rms": 0.0, "ratio": 0.0}
    for by, rows in bins.items():
        for row in rows:
            ratio = row["rms"] / rmse if rmse > 0 else 0.0
            if ratio > best["ratio"]:
                best = {"by": by, **row, "ratio": ratio}
    return best


def summary(v: dict) -> str:
    """One sentence for the report and the CLI."""
    units = {"speed": "rad/s", "angle": "rad", "time": "s"}
    head = (f"residual RMS {1e3 * v['rmse']:.2f} mrad, {v['rmse_over_noise']:.2f}× the noise estimate "
            f"({1e3 * v['noise_estimate']:.2f} mrad); ")
    if v["white"]:
        head += f"white (Ljung–Box p = {v['ljung_box_p']:.2g}): nothing systematic left"
    else:
        head += f"not white (Ljung–Box p = {v['ljung_box_p']:.2g}, correlation time {v['autocorrelation_time']:.0f} samples)"
    w = v["largest"]
    if w["by"] and w["ratio"] > 1.3:
        head += (f"; largest at {w['by']} {w['low']:.3g}–{w['high']:.3g} {units[w['by']]} "
                 f"({w['ratio']:.1f}× the overall RMS)")
    return head
