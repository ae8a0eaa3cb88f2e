"""`identify` against the thesis's method in plain SciPy: one speed figure, measured on all trials.

The data: 5 bob distances × cw/ccw × 3 repeats = 30 pendulum drops, 120 Hz, 10 s each, MX-64-like
truth (I 0.0147 kg·m², B 0.035 N·m·s/rad, F 0.084 N·m), 2 mrad Gaussian noise, made by the TEST
ORACLE (tests/oracles/ivp.py: SciPy's solve_ivp with stick events, an integrator independent of
the Rust plant that identify fits with). In one run, on all 30 trials, nothing extrapolated:

- ``identify`` (the core's Python API: Rust batch simulator, joint output-error LM, effect
  search, held-out scoring);
- the thesis's per-trial alternating LM on our Rust simulator (``admittance thesis``);
- the same procedure in pure Python/SciPy (``baseline_thesis``: a Python ode3 loop and
  ``least_squares``).

It prints the wall times and their ratios (side by side, one run, with the machine's load),
then each method's parameter errors against the truth, on the oracle's data and, for
comparison, on data from the core's own synthetic generator (the Rust plant at a 10× finer
step), so no accuracy figure rests on identify's own simulator alone.

With ``--effect NAME=SIZE`` the oracle's drops hold one undeclared library effect (the thesis
method has no term for it; its parameter errors then show what that costs).

Usage: ``.venv/bin/python bench/identify_vs_thesis.py [--trials 30] [--duration 10] [--seed S] [--effect stribeck=0.04]``
(``--baseline-trials N`` runs the pure-Python baseline on N spread trials only, and then
prints no speed ratio: a figure on part of the data is not the figure.)
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from oracles import ivp as oracle  # noqa: E402  (the test oracle lives with the tests)

from admittance.ident import synthetic  # noqa: E402
from admittance.thesis import alternating as thesis  # noqa: E402
from oracles import thesis_ode3 as baseline_thesis  # noqa: E402
from admittance.formats.dataset import load_dataset  # noqa: E402
from admittance.ident.identify import IdentifySettings, identify_dataset  # noqa: E402

PARAMS = ("motor_inertia", "damping", "coulomb")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=30)
    parser.add_argument("--duration", type=float, default=10.0, help="s per trial")
    parser.add_argument("--baseline-trials", type=int, default=None,
                        help="run the pure-Python baseline on this many trials only (no speed ratio then)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--effect", default="", metavar="NAME=SIZE",
                        help="one undeclared library effect in the oracle's data, e.g. stribeck=0.04 (default: clean)")
    args = parser.parse_args()
    effect, size = (args.effect.split("=") + ["0"])[:2] if args.effect else ("", "0")

    print(f"machine: {os.cpu_count()} cpus, load average at start {_load()}")
    with tempfile.TemporaryDirectory() as tmp:
        folder = oracle.generate(Path(tmp) / "oracle", oracle.OracleSpec(
            n_trials=args.trials, duration=args.duration, distances=(0.20, 0.25, 0.30, 0.35, 0.40), seed=args.seed,
            effect=effect, size=float(size)))
        dataset = load_dataset(folder)
        truth = json.loads((folder / "truth.json").read_text())["params"]
        timed = _time_all(dataset, args.baseline_trials)
        synthetic_set = load_dataset(synthetic.generate(Path(tmp) / "synthetic", synthetic.SynthSpec(
            n_trials=args.trials, duration=args.duration, seed=args.seed)))
        own = identify_dataset(synthetic_set, IdentifySettings()).to_json()
        own_thesis = thesis.fit_dataset(synthetic_set)
    print(f"load average at the end {_load()}")

    n = len(dataset.trials)
    t_identify, t_rust, t_py, m = timed["identify"][0], timed["rust"][0], timed["python"][0], timed["python_trials"]
    print(f"\ndata: {n} drops from the test oracle (solve_ivp, stick events), {args.duration:g} s at 120 Hz, "
          f"2 mrad noise; truth {_fmt(truth)}")
    print(f"identify (Rust, joint LM + effect search)      {t_identify:8.2f} s  ({n} trials)")
    print(f"thesis method, Rust simulator                  {t_rust:8.2f} s  ({n} trials)")
    print(f"thesis method, pure Python/SciPy baseline      {t_py:8.2f} s  ({m} trials)")
    if m == n:
        print(f"ratio baseline / identify:                     {t_py / t_identify:8.1f}×  (measured, all trials, one run)")
        print(f"ratio baseline / thesis method on Rust:        {t_py / t_rust:8.1f}×  (same algorithm)")
    else:
        print(f"no ratio: the baseline ran on {m} of {n} trials (--baseline-trials); a part is not the figure")
    print("\nparameter errors against the truth (relative):")
    print("  oracle data (an integrator independent of the fit):")
    print(f"    identify, final model:           {_errors(timed['identify'][1]['params'], truth)}  "
          f"effects {timed['identify'][1]['effects']}")
    print(f"    thesis method, Rust (avg {n}):     {_errors(_averages(timed['rust'][1]), truth)}")
    print(f"    thesis method, Python (avg {m}):   {_errors(_averages(timed['python'][1]), truth)}")
    print("  the core's own synthetic data (Rust plant at 0.1 ms):")
    print(f"    identify, final model:           {_errors(own['params'], synthetic.MX64)}  effects {own['effects']}")
    print(f"    thesis method, Rust (avg {n}):     {_errors(_averages(own_thesis), synthetic.MX64)}")


def _time_all(dataset, baseline_trials):
    out = {}
    start = time.perf_counter()
    result = identify_dataset(dataset, IdentifySettings()).to_json()
    out["identify"] = (time.perf_counter() - start, result)
    start = time.perf_counter()
    rows = thesis.fit_dataset(dataset)
    out["rust"] = (time.perf_counter() - start, rows)
    subset = _spread(dataset, baseline_trials) if baseline_trials else dataset
    start = time.perf_counter()
    rows = baseline_thesis.fit_dataset(subset)
    out["python"] = (time.perf_counter() - start, rows)
    out["python_trials"] = len(subset.trials)
    return out


def _load() -> str:
    try:
        return " ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "unknown"


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
