"""The fit's numerics replayed: during one ``identify`` run with this tree, every call of the
numerics reorganised in fit.py also runs through the baseline's fit.py on the same inputs.

Per call, both versions run one after the other in the same process (which goes first
alternates from call to call), their CPU time (``time.process_time``) is summed per side, and
their outputs must agree bit for bit (an assertion stops the run otherwise). On a machine
shared with other jobs this compares the two versions far more closely than two whole runs
do: the same inputs, the same moment, the same load. What is replayed:

- ``normal_equations`` (also as effects.py calls it);
- ``autocorrelation_time`` (as fit.py, crossval.py, regime.py and residual.py call it);
- the Jacobian's finite differences, a whole Jacobian at a time: the baseline's
  ``(s − (r + m)) / h`` on every trial's simulation, this tree's ``chord_slopes`` on copies
  of them made outside the timing (it works in the simulation's array);
- the start screen's choice in ``closest_starts`` (the simulation itself is not timed).

Usage: ``.venv/bin/python bench/fit_numerics_replay.py DATASET_DIR [...] [--baseline-ref REF]``
(default: where this branch left main).
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def same(x, y) -> bool:
    x, y = np.asarray(x), np.asarray(y)
    return x.shape == y.shape and np.array_equal(x, y, equal_nan=True) and bool((np.signbit(x) == np.signbit(y)).all())


class Replay:
    """Runs a call both ways, times each side and checks the outputs agree."""

    def __init__(self):
        self.times = defaultdict(lambda: [0.0, 0.0, 0])  # name -> [baseline s, this s, calls]
        self._first = False

    def both(self, name, baseline, this, agree):
        self._first = not self._first
        order = [(0, baseline), (1, this)] if self._first else [(1, this), (0, baseline)]
        out = [None, None]
        for side, call in order:
            start = time.process_time()
            out[side] = call()
            self.times[name][side] += time.process_time() - start
        self.times[name][2] += 1
        if not agree(out[0], out[1]):
            raise AssertionError(f"{name}: this tree's result differs from the baseline's")
        return out[1]


def load_baseline_fit(ref: str, into: Path):
    source = subprocess.run(["git", "-C", str(ROOT), "show", f"{ref}:admittance/ident/fit.py"], check=True,
                            capture_output=True, text=True).stdout
    path = into / "baseline_fit.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location("baseline_fit", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules["baseline_fit"] = module  # dataclasses look their module up here
    spec.loader.exec_module(module)
    return module


def install(replay: Replay, base) -> None:
    import admittance.ident.base as base_fit
    import admittance.ident.crossval as crossval
    import admittance.ident.effects as effects
    import admittance.ident.fit as fit
    import admittance.ident.regime as regime
    import admittance.ident.residual as residual

    this_normal = fit.normal_equations

    def normal_equations(jac, residuals, n_g, fit_x0):
        return replay.both("normal_equations", lambda: base.normal_equations(jac, residuals, n_g, fit_x0),
                           lambda: this_normal(jac, residuals, n_g, fit_x0),
                           lambda x, y: same(x[0], y[0]) and same(x[1], y[1]))

    fit.normal_equations = effects.normal_equations = normal_equations

    this_tau = fit.autocorrelation_time

    def autocorrelation_time(residuals, max_lag=400):
        return replay.both("autocorrelation_time", lambda: base.autocorrelation_time(residuals, max_lag),
                           lambda: this_tau(residuals, max_lag), same)

    for module in (fit, crossval, regime, residual):
        if hasattr(module, "autocorrelation_time"):
            module.autocorrelation_time = autocorrelation_time

    this_slopes = fit.chord_slopes
    this_jacobian = fit._Problem.jacobian
    inputs: list[tuple] = []

    def chord_slopes(perturbed, base_sim, steps):
        inputs.append((perturbed.copy(), base_sim, steps))  # before this tree divides in place
        return this_slopes(perturbed, base_sim, steps)

    def jacobian(problem, z, residuals, upper):
        # A whole Jacobian at a time, as the fit forms it: every trial's block both ways, this
        # tree's on copies of the simulation made outside the timing.
        inputs.clear()
        blocks = this_jacobian(problem, z, residuals, upper)
        own = [(p.copy(), b, h) for p, b, h in inputs]
        replay.both("Jacobian differences", lambda: [(p - b[None, :]) / h[:, None] for p, b, h in inputs],
                    lambda: [this_slopes(p, b, h) for p, b, h in own],
                    lambda x, y: len(x) == len(y) and all(same(a, c) for a, c in zip(x, y)))
        return blocks

    fit.chord_slopes = chord_slopes
    fit._Problem.jacobian = jacobian

    this_closest = fit.closest_starts

    def closest_starts(sim, vector, starts):
        sims = sim.run(np.repeat(np.asarray(vector, float)[None, :], len(starts), axis=0), np.stack(starts))
        replay.both("start screen's choice",
                    lambda: [int(np.argmin([np.mean((s[k] - m) ** 2) for k in range(len(starts))]))
                             for s, m in zip(sims, sim.measured)],
                    lambda: [int(np.argmin(np.mean((s - m[None, :]) ** 2, axis=1))) for s, m in zip(sims, sim.measured)],
                    lambda x, y: x == y)
        return this_closest(sim, vector, starts)

    for module in (fit, effects, base_fit):
        if hasattr(module, "closest_starts"):
            module.closest_starts = closest_starts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("datasets", nargs="+")
    parser.add_argument("--baseline-ref", default="", help="default: git merge-base HEAD main")
    args = parser.parse_args()
    ref = args.baseline_ref or subprocess.run(["git", "-C", str(ROOT), "merge-base", "HEAD", "main"], check=True,
                                              capture_output=True, text=True).stdout.strip()
    from admittance.formats.dataset import load_dataset
    from admittance.ident.identify import IdentifySettings, identify_dataset

    with tempfile.TemporaryDirectory() as tmp:
        base = load_baseline_fit(ref, Path(tmp))
    replay = Replay()
    install(replay, base)
    for folder in args.datasets:
        replay.times.clear()
        load = Path("/proc/loadavg").read_text().split()[:3]
        identify_dataset(load_dataset(folder), IdentifySettings(quiet=True))
        print(f"{Path(folder).name} (baseline fit.py of {ref[:7]}; /proc/loadavg {' '.join(load)} at the start):")
        for name, (b, t, calls) in replay.times.items():
            print(f"  {name:24s} {calls:6d} calls  baseline {b:.3f} s  this {t:.3f} s  ({b / t if t else float('nan'):.2f}×)"
                  "  every output bit for bit")


if __name__ == "__main__":
    main()
