"""`identify` against the thesis's method in plain SciPy, on one thesis-scale synthetic set.

The set: 5 bob distances × cw/ccw × 3 repeats = 30 pendulum drops, 120 Hz, 10 s each, made by
the core's synthetic generator (MX-64-like truth, 2 mrad noise, stick friction). In one run:

- ``identify`` (the core's Python API: Rust batch simulator, joint output-error LM, effect
  search, held-out scoring) on all 30 trials;
- the thesis's per-trial alternating LM with our Rust simulator (``admittance thesis``);
- the same procedure in pure Python/SciPy (``baseline_thesis``: a Python ode3 loop and
  ``least_squares``), on a subset when it would take too long, extrapolated per trial.

It prints the wall times, their ratios, and each method's parameter errors against the truth.
Usage: ``.venv/bin/python bench/identify_vs_thesis.py [--baseline-trials N] [--seed S]``
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from dataclasses import replace

from admittance.ident import baseline_thesis, synthetic, thesis
from admittance.ident.dataset import load_dataset
from admittance.ident.identify import IdentifySettings, identify_dataset

PARAMS = ("motor_inertia", "damping", "coulomb")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=30)
    parser.add_argument("--duration", type=float, default=10.0, help="s per trial")
    parser.add_argument("--baseline-trials", type=int, default=4,
                        help="trials the pure-Python baseline runs on (its time is extrapolated to all)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        spec = synthetic.SynthSpec(n_trials=args.trials, duration=args.duration, seed=args.seed)
        synthetic.generate(tmp, spec)
        dataset = load_dataset(tmp)
        truth = json.loads((dataset.folder / "truth.json").read_text())["params"]

        start = time.perf_counter()
        result = identify_dataset(dataset, IdentifySettings()).to_json()
        t_identify = time.perf_counter() - start

        start = time.perf_counter()
        rust_rows = thesis.fit_dataset(dataset)
        t_rust = time.perf_counter() - start

        subset = _spread(dataset, args.baseline_trials)
        start = time.perf_counter()
        py_rows = baseline_thesis.fit_dataset(subset)
        t_py_subset = time.perf_counter() - start
    t_py = t_py_subset * len(dataset.trials) / len(subset.trials)

    n, m = len(dataset.trials), len(subset.trials)
    print(f"dataset: {n} synthetic drops, {args.duration:g} s at {spec.rate:g} Hz, truth {_fmt(truth)}")
    print(f"identify (Rust, joint LM + effect search)      {t_identify:8.2f} s  ({n} trials)")
    print(f"thesis method, Rust simulator                  {t_rust:8.2f} s  ({n} trials)")
    extrapolated = "" if m == n else f", measured {t_py_subset:.1f} s on {m} trials, extrapolated ×{n / m:g}"
    print(f"thesis method, pure Python/SciPy baseline      {t_py:8.2f} s  ({n} trials{extrapolated})")
    print(f"ratio baseline / identify:                     {t_py / t_identify:8.1f}×")
    print(f"ratio baseline / thesis method on Rust:        {t_py / t_rust:8.1f}×  (same algorithm)")
    print()
    print("parameter errors against the truth (relative):")
    print(f"  identify, final model:        {_errors(result['params'], truth)}  effects {result['effects']}")
    print(f"  thesis method, Rust (avg {n}):  {_errors(_averages(rust_rows), truth)}")
    print(f"  thesis method, Python (avg {m}): {_errors(_averages(py_rows), truth)}")
    script = statistics.mean(r.inertia_motor for r in rust_rows)
    print(f"  thesis's script rod formula (half length) would report motor_inertia {script:.5f} "
          f"({(script - truth['motor_inertia']) / truth['motor_inertia']:+.1%})")


def _spread(dataset, count):
    """``count`` trials spread over the set (every k-th), so each distance is represented."""
    count = max(1, min(count, len(dataset.trials)))
    step = len(dataset.trials) / count
    picked = tuple(dataset.trials[int(i * step)] for i in range(count))
    return replace(dataset, trials=picked)


def _averages(rows):
    return {
        "motor_inertia": statistics.mean(r.inertia_motor_correct_rod for r in rows),
        "damping": statistics.mean(r.damping for r in rows),
        "coulomb": statistics.mean(r.friction for r in rows),
    }


def _errors(found, truth):
    return "  ".join(f"{p} {found[p]:.5f} ({(found[p] - truth[p]) / truth[p]:+.1%})" for p in PARAMS)


def _fmt(params):
    return ", ".join(f"{p} {params[p]:g}" for p in PARAMS)


if __name__ == "__main__":
    main()
