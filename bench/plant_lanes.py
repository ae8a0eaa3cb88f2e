"""Simulations stepped side by side (rtcore/plant/src/lanes.rs, `simulate_lanes`): S parameter
sets in one call against one call per set, in one run on one build.

`simulate_batch` cuts its (set, trial) pairs into work items of up to 4 and steps each item's
pairs side by side (`plant::batch::LANES`), whichever trials they are of. S sets in one call
against S calls of one set each, on the same trials, starts and thread count, shows what the
lanes gain beside one another; the S = 1 row is identification's single-set call (a damped
trial) over 30 trials, which before the lanes took different trials had one lane per work item.
Every number of both ways is checked equal, bit for bit, to each pair simulated alone (a call
with one set and one trial: one lane).

The workload is an identification's: 30 synthetic MX-64-like drops (`admittance synth`, seed 0,
quadratic drag 0.002: the Rust plant at a 10× finer step, 2 mrad noise), the base model's
parameters near the truth, each set's damping 1 % apart (a Jacobian's rows). Printed per S:
the time per call of both ways (the shortest of ``--repeats`` alternating rounds: the least
disturbed by the machine's other work), their ratio, the time per trial simulation of the call
(its time over S × 30) and per moving substep (the substeps of a drop before it rests for good,
which are the ones the plant steps).

Usage: ``.venv/bin/python bench/plant_lanes.py [--sets 1 2 3 4 5 6 7 8] [--threads 1] [--repeats 7]``
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

    def alone():
        return [np.concatenate([_rtcore.simulate_batch([trial], rows[s:s + 1], x0[s:s + 1, k:k + 1], max_step=MAX_STEP,
                                                       friction="stick", threads=threads)[0] for s in range(n_sets)])
                for k, trial in enumerate(sim._rt)]

    joint, single, lone = together(), apart(), alone()
    if not all(np.array_equal(a, c) and np.array_equal(b, c) for a, b, c in zip(joint, single, lone)):
        raise SystemExit(f"{n_sets} sets: side by side, one call per set and each pair alone disagree")
    best = {"together": np.inf, "apart": np.inf}
    for _ in range(repeats):
        for name, run in (("together", together), ("apart", apart)):
            start = time.perf_counter()
            run()
            best[name] = min(best[name], time.perf_counter() - start)
    return best["together"], best["apart"], moving_substeps(sim, joint)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sets", type=int, nargs="+", default=[1, 2, 3, 4, 5, 6, 7, 8])
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    load = Path("/proc/loadavg").read_text().split()[:3] if Path("/proc/loadavg").exists() else ["?"]
    with tempfile.TemporaryDirectory() as tmp:
        make_set(Path(tmp) / "drag")
        dataset = load_dataset(Path(tmp) / "drag")
    sim = Simulator(dataset.trials, dataset.mode, "stick", MAX_STEP)
    print(f"30 synthetic drops (quadratic drag), {args.threads} thread(s), best of {args.repeats}; load {' '.join(load)}")
    print("| sets | one call | one call per set | ratio | µs per trial simulation (one call) "
          "| ns per moving substep (one call / per set) |")
    print("|---|---|---|---|---|---|")
    for n_sets in args.sets:
        together, apart, substeps = measure(sim, n_sets, args.threads, args.repeats)
        per_simulation = 1e6 * together / (n_sets * len(sim.trials))
        print(f"| {n_sets} | {1e3 * together:.2f} ms | {1e3 * apart:.2f} ms | {apart / together:.2f}× | "
              f"{per_simulation:.1f} | {1e9 * together / substeps:.1f} / {1e9 * apart / substeps:.1f} |")


if __name__ == "__main__":
    main()
