"""Savitzky–Golay smoothing and differentiation, and a tiny bounded least squares, in NumPy.

Both exist in SciPy (``scipy.signal.savgol_filter``, ``scipy.optimize.lsq_linear``), but
importing ``scipy.signal`` costs seconds on a loaded machine, more than the whole output-error
fit of a small dataset. The two pieces needed here are short:

- Savitzky–Golay: each output is the value (or a derivative) at the centre of a least-squares
  polynomial through a window of samples; interior points are one convolution, the first and
  last half-windows use the polynomial of the end window (SciPy's ``mode="interp"``).
- Bounded least squares with lower bounds only and a handful of unknowns: the solution has
  some unknowns at their bound and the rest from an unconstrained solve, so trying every
  subset (2ⁿ, n ≤ 5) and keeping the best feasible one is exact and instant.
"""

from __future__ import annotations

import itertools
import math

import numpy as np


def savgol(y: np.ndarray, window: int, order: int, deriv: int, dt: float) -> np.ndarray:
    """The ``deriv``-th derivative of the local polynomial fit (odd ``window`` ≤ len(y))."""
    half = window // 2
    offsets = np.arange(-half, half + 1, dtype=float)
    vander = offsets[:, None] ** np.arange(order + 1)[None, :]
    pinv = np.linalg.pinv(vander)  # (order+1, window): polynomial coefficients from samples
    factor = math.factorial(deriv) / dt**deriv
    centre = pinv[deriv] * factor
    out = np.empty_like(y, dtype=float)
    out[half : y.size - half] = np.convolve(y, centre[::-1], mode="valid")
    powers = np.arange(deriv, order + 1)
    scale = np.array([math.factorial(p) / math.factorial(p - deriv) for p in powers]) / dt**deriv
    head = (offsets[:half, None] ** (powers - deriv)[None, :]) @ ((pinv @ y[:window])[deriv:] * scale)
    tail = (offsets[half + 1 :, None] ** (powers - deriv)[None, :]) @ ((pinv @ y[-window:])[deriv:] * scale)
    out[:half] = head
    out[y.size - half :] = tail
    return out


def nonneg_lstsq(a: np.ndarray, y: np.ndarray, lower: np.ndarray) -> np.ndarray:
    """argmin ‖a·x − y‖ subject to x ≥ lower, exactly, for a few unknowns."""
    n = a.shape[1]
    lower = np.asarray(lower, dtype=float)
    bounded = [j for j in range(n) if np.isfinite(lower[j])]  # -inf: a free unknown, never at a bound
    best, best_cost = None, math.inf
    for at_bound in itertools.product((False, True), repeat=len(bounded)):
        fixed = [False] * n
        for j, flag in zip(bounded, at_bound):
            fixed[j] = flag
        x = np.where(np.isfinite(lower), lower, 0.0)
        free = [j for j in range(n) if not fixed[j]]
        if free:
            rhs = y - a[:, [j for j in range(n) if fixed[j]]] @ x[[j for j in range(n) if fixed[j]]]
            x[free] = np.linalg.lstsq(a[:, free], rhs, rcond=None)[0]
        if np.any(x < lower - 1e-15):
            continue
        cost = float(np.sum((a @ x - y) ** 2))
        if cost < best_cost:
            best, best_cost = x, cost
    return best if best is not None else np.where(np.isfinite(lower), lower, 0.0)


def chi2_sf(q: float, dof: int) -> float:
    """Survival function of χ² by the Wilson–Hilferty cube-root normal approximation (error
    < 1e-3 in p for dof ≥ 10, ample for a whiteness verdict)."""
    if q <= 0:
        return 1.0
    k = float(dof)
    z = ((q / k) ** (1.0 / 3.0) - (1.0 - 2.0 / (9.0 * k))) / math.sqrt(2.0 / (9.0 * k))
    return 0.5 * math.erfc(z / math.sqrt(2.0))
