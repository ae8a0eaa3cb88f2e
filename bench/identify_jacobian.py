"""Why the fit builds its own Jacobian: structured LM against SciPy's least_squares, same data,
same Rust simulator, same start, in one run.

- ``structured``: ``admittance.ident.fit.fit_output_error``: per Jacobian ONE batch of
  n_params + 2 rows (a trial's initial state only moves that trial), normal equations by blocks.
- ``scipy+batch``: ``scipy.optimize.least_squares`` (trf) with the same one-batch Jacobian
  handed over as a dense matrix: isolates the solver.
- ``scipy 2-point``: ``least_squares`` with its own forward differences: one full simulation of
  every trial per unknown (n_params + 2·T columns), the textbook set-up.

Prints wall time, simulations of one trial, final RMSE and the fitted I, B, F of each.
Usage: ``.venv/bin/python bench/identify_jacobian.py [--trials 30] [--duration 10]``
"""

from __future__ import annotations

import argparse
import tempfile
import time

import numpy as np
from scipy.optimize import least_squares

from admittance.formats.dataset import load_dataset
from admittance.ident.equation_error import fit_equation_error, initial_states
from admittance.ident.fit import _Problem, fit_output_error, rmse
from admittance.ident.model import Simulator, bounds_for, free_params
from admittance.ident.synthetic import SynthSpec, generate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=30)
    parser.add_argument("--duration", type=float, default=10.0)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        generate(tmp, SynthSpec(n_trials=args.trials, duration=args.duration, seed=args.seed))
        ds = load_dataset(tmp)
    start, _ = fit_equation_error(ds.trials, ds.mode)
    x0 = initial_states(ds.trials)
    sim = Simulator(ds.trials, ds.mode)
    free = free_params(ds.mode, [], False)
    torque = float(np.mean([tr.gravity_torque for tr in ds.trials]))
    rows = [("structured", *_structured(sim, start, free, x0, torque))]
    rows.append(("scipy+batch", *_scipy(sim, start, free, x0, torque, batch=True)))
    rows.append(("scipy 2-point", *_scipy(sim, start, free, x0, torque, batch=False)))
    print(f"{len(ds.trials)} trials × {args.duration:g} s at 120 Hz; truth I 0.0147, B 0.035, F 0.084")
    print(f"{'method':15s} {'time [s]':>9s} {'trial sims':>10s} {'rmse [mrad]':>11s}   I, B, F")
    base_time = rows[0][1]
    for name, seconds, sims, err, params in rows:
        print(f"{name:15s} {seconds:9.2f} {sims:10d} {1e3 * err:11.3f}   "
              f"{params[0]:.5f}, {params[1]:.4f}, {params[2]:.4f}   ({seconds / base_time:.1f}× structured)")


def _structured(sim, start, free, x0, torque):
    tick = time.perf_counter()
    fit = fit_output_error(sim, start, free, x0, torque_scale=torque)
    return time.perf_counter() - tick, fit.simulations, fit.rmse, fit.vector[:3]


def _scipy(sim, start, free, x0, torque, batch: bool):
    problem = _Problem(sim, start, free, True, torque)
    lo, hi = bounds_for(free)
    lower = np.concatenate([lo, np.full(x0.size, -np.inf)])
    upper = np.concatenate([hi, np.full(x0.size, np.inf)])
    z0 = np.concatenate([start[:3], x0.ravel()])

    def residual(z):
        return np.concatenate(problem.residuals(z))

    def jacobian(z):
        r = problem.residuals(z)
        blocks = problem.jacobian(z, r, upper)
        return _dense(blocks, problem.n_g)

    tick = time.perf_counter()
    kw = {"jac": jacobian} if batch else {"jac": "2-point", "diff_step": 1e-2}
    sol = least_squares(residual, z0, bounds=(lower, upper), method="trf", x_scale="jac", **kw)
    seconds = time.perf_counter() - tick
    err = rmse(problem.residuals(sol.x))
    return seconds, problem.simulations, err, sol.x[:3]


def _dense(blocks, n_g):
    n_t = len(blocks)
    m = sum(b.shape[1] for b in blocks)
    jac = np.zeros((m, n_g + 2 * n_t))
    row = 0
    for k, b in enumerate(blocks):
        n = b.shape[1]
        jac[row : row + n, :n_g] = b[:n_g].T
        jac[row : row + n, n_g + 2 * k : n_g + 2 * k + 2] = b[n_g:].T
        row += n
    return jac


if __name__ == "__main__":
    main()
