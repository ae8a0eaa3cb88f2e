"""Parameter sets stepped side by side (rtcore/plant/src/trial.rs, `simulate_lanes`) against one
at a time, in one run on one build.

`simulate_batch` hands the plant up to 4 parameter sets of one trial as one work item and steps
them side by side (`plant::batch::LANES`); a call with a single set has nothing to step beside
it. So S sets in one call against S calls of one set each, on the same trials, starts and
thread count, measures what the lanes gain, with the numbers checked equal (bit for bit).

The workload is an identification's: 30 synthetic MX-64-like drops (`admittance synth`, seed 0,
quadratic drag 0.002: the Rust plant at a 10× finer step, 2 mrad noise), the base model's
parameters near the truth, each set's damping 1 % apart (a Jacobian's rows). Printed per S:
the time per call of both ways (the shortest of ``--repeats`` alternating rounds: the least
disturbed by the machine's other work), their ratio, and the time per moving substep (the
substeps of a drop before it rests for good, which are the ones the plant steps).

Usage: ``.venv/bin/python bench/plant_lanes.py [--sets 1 2 3 4 6 8] [--threads 1] [--repeats 7]``
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from admittance import _rtcore
from admittance.formats.dataset import load_dataset
from admittance.ident.model import INDEX, Simulator, default_vector

MAX_STEP = 1e-3  # identify's step (ident/identify.py FIT_MAX_STEP)
TRUTH = {"motor_inertia": 0.0147, "damping": 0.035, "coulomb": 0.084, "quadratic_drag": 0.002}


def make_set(folder: Path) -> None:
    subprocess.run([sys.executable, "-m", "admittance", "synth", "--effect", "quadratic_drag=0.002", "--trials", "30",
                    "--duration", "10", "--seed", "0", str(folder)], check=True, capture_output=True)


def rows_for(n_sets: int) -> np.ndarray:
    vector = default_vector()
    for name, value in TRUTH.items():
        vector[INDEX[name]] = value
    rows = np.repeat(vector[None, :], n_sets, axis=0)
    rows[:, INDEX["damping"]] *= 1.0 + 0.01 * np.arange(n_sets)
    return rows


def moving_substeps(sim: Simulator, out: list[np.ndarray]) -> int:
    """Substeps before each simulation's last change of angle, summed over sets and trials."""
    total = 0
    for theta, trial in zip(out, sim.trials):
        for row in theta:
            changed = np.flatnonzero(np.diff(row) != 0)
            last = int(changed[-1]) + 1 if changed.size else 0
            dt = np.diff(trial.t[: last + 1])
            total += int(np.ceil(dt / MAX_STEP - 1e-9).sum())
    return total


def measure(sim: Simulator, n_sets: int, threads: int, repeats: int) -> tuple[float, float, int]:
    rows = rows_for(n_sets)
    x0 = np.repeat(np.array([[tr.theta[0], 0.0] for tr in sim.trials])[None], n_sets, axis=0)

    def together():
        return _rtcore.simulate_batch(sim._rt, rows, x0, max_step=MAX_STEP, friction="stick", threads=threads)

    def apart():
        runs = [_rtcore.simulate_batch(sim._rt, rows[s:s + 1], x0[s:s + 1], max_step=MAX_STEP, friction="stick",
                                       threads=threads) for s in range(n_sets)]
        return [np.concatenate([run[k] for run in runs]) for k in range(len(sim.trials))]

    joint, single = together(), apart()
    if not all(np.array_equal(a, b) for a, b in zip(joint, single)):
        raise SystemExit(f"{n_sets} sets: side by side and one at a time disagree")
    best = {"together": np.inf, "apart": np.inf}
    for _ in range(repeats):
        for name, run in (("together", together), ("apart", apart)):
            start = time.perf_counter()
            run()
            best[name] = min(best[name], time.perf_counter() - start)
    return best["together"], best["apart"], moving_substeps(sim, joint)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sets", type=int, nargs="+", default=[1, 2, 3, 4, 6, 8])
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    load = Path("/proc/loadavg").read_text().split()[:3] if Path("/proc/loadavg").exists() else ["?"]
    with tempfile.TemporaryDirectory() as tmp:
        make_set(Path(tmp) / "drag")
        dataset = load_dataset(Path(tmp) / "drag")
    sim = Simulator(dataset.trials, dataset.mode, "stick", MAX_STEP)
    print(f"30 synthetic drops (quadratic drag), {args.threads} thread(s), best of {args.repeats}; load {' '.join(load)}")
    print("| sets | one call, side by side | one call per set | ratio | ns per moving substep (side by side / apart) |")
    print("|---|---|---|---|---|")
    for n_sets in args.sets:
        together, apart, substeps = measure(sim, n_sets, args.threads, args.repeats)
        print(f"| {n_sets} | {1e3 * together:.2f} ms | {1e3 * apart:.2f} ms | {apart / together:.2f}× | "
              f"{1e9 * together / substeps:.1f} / {1e9 * apart / substeps:.1f} |")


if __name__ == "__main__":
    main()
