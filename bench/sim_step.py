"""Cost of one plant-simulation substep: rtcore (Rust) against NumPy and pure Python, in one run.

Prints ratios, not only absolutes: the machine is shared and noisy, so compare the lines
with each other. Three alternatives simulate the same model (Contract 1, every effect on):

- ``rtcore``: ``_rtcore.simulate_batch`` (one trial, one parameter set, one thread);
- ``python``: ``simulate_reference`` of the test oracle tests/oracles/reference.py, a plain Python loop;
- ``numpy``: the loop in Python, each substep vectorised over S parameter sets (the usual
  way to batch a time-stepping model in NumPy). Checked against rtcore in the same run.

Then the identification workload: T trials × S parameter sets, single-threaded against
rayon's pool. Runs in well under a minute.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np

from admittance import sim

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from oracles import reference  # noqa: E402  (the test oracle lives with the tests)

RATE_HZ = 120.0
DURATION_S = 12.0
MAX_STEP = 5e-4
N_TRIALS = 30
N_SETS = 20
PARAMS = {
    "motor_inertia": 2e-3, "damping": 0.02, "coulomb": 0.01, "coulomb_asym": 0.002,
    "stribeck_torque": 0.004, "load_coulomb": 0.05, "angle_offset": 0.02, "quadratic_drag": 1e-3,
    "cogging_amplitude": 0.002, "cogging_period": 8.0, "time_delay": 0.01, "torque_bias": 0.003,
    "torque_drift": 1e-3,
}


def make_trial(seed: int) -> sim.Trial:
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, DURATION_S, 1.0 / RATE_HZ)
    tau = 0.08 * np.sin(rng.uniform(1, 4) * t) + 0.01 * rng.standard_normal(t.size)
    return sim.make_trial(t, tau, load_inertia=1e-3, gravity_torque=0.1)


def best_of(repeats: int, run) -> float:
    """Shortest wall time of `repeats` runs: the least disturbed by other processes."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return min(times)


def numpy_simulate(trial: sim.Trial, sets: np.ndarray, theta0: float) -> np.ndarray:
    """The stick model, vectorised over parameter sets (rows of `sets`, PARAM_NAMES order)."""
    p = {name: sets[:, i] for i, name in enumerate(sim.PARAM_NAMES)}
    t, tau = trial.t, trial.tau
    inertia = p["motor_inertia"] + trial.load_inertia
    theta = np.full(len(sets), theta0)
    omega = np.zeros(len(sets))
    out = np.empty((len(sets), t.size))
    out[:, 0] = theta
    for i in range(1, t.size):
        n = max(1, int(np.ceil((t[i] - t[i - 1]) / MAX_STEP - 1e-9)))
        h = (t[i] - t[i - 1]) / n
        for k in range(n):
            tk = t[i - 1] + k * h
            applied = np.interp(tk - p["time_delay"], t, tau)
            tau_c = p["torque_gain"] * applied - p["torque_bias"] - p["torque_drift"] * (tk - t[0])
            g = trial.gravity_torque * np.sin(theta - p["angle_offset"])
            drive = tau_c - g - p["cogging_amplitude"] * np.sin(p["cogging_period"] * theta + p["cogging_phase"])
            direction = np.where(omega != 0, np.sign(omega), np.sign(drive))
            level = (p["coulomb"] + direction * p["coulomb_asym"]
                     + p["stribeck_torque"] * np.exp(-((omega / p["stribeck_velocity"]) ** 2))
                     + p["load_coulomb"] * np.abs(g - tau_c)).clip(min=0.0)
            gain = h / inertia
            free = omega + gain * drive
            moving = (free - np.sign(free) * gain * level) / (
                1.0 + gain * (p["damping"] + p["quadratic_drag"] * np.abs(omega)))
            omega = np.where(np.abs(free) <= gain * level, 0.0, moving)
            theta = theta + h * omega
        out[:, i] = theta
    return out


def per_step_costs() -> None:
    trial = make_trial(0)
    steps = trial.substeps(MAX_STEP)
    vector = sim.pack_params(PARAMS)[None, :]
    x0 = np.array([[[0.3, 0.0]]])
    rust_s = best_of(20, lambda: sim.simulate_many([trial], vector, x0, max_step=MAX_STEP, threads=1))
    python_s = best_of(1, lambda: reference.simulate_reference(trial, PARAMS, 0.3, 0.0, max_step=MAX_STEP))
    sets = np.repeat(vector, N_SETS, axis=0)
    numpy_result = {}
    numpy_s = best_of(1, lambda: numpy_result.setdefault("theta", numpy_simulate(trial, sets, 0.3)))
    rust_sets = sim.simulate_many([trial], sets, np.tile(x0, (N_SETS, 1, 1)), max_step=MAX_STEP)[0]
    disagreement = np.abs(numpy_result["theta"] - rust_sets).max()

    rust_ns = rust_s / steps * 1e9
    python_ns = python_s / steps * 1e9
    numpy_ns = numpy_s / steps / N_SETS * 1e9
    print(f"one trial: {DURATION_S:.0f} s at {RATE_HZ:.0f} Hz, max_step {MAX_STEP:g} s -> {steps} substeps")
    print(f"  rtcore (1 thread)         {rust_ns:10.1f} ns/substep   1.0x")
    print(f"  numpy, {N_SETS} sets vectorised {numpy_ns:10.1f} ns/substep/set {numpy_ns / rust_ns:6.0f}x slower"
          f"   (max |numpy - rtcore| = {disagreement:.1e} rad)")
    print(f"  pure python reference     {python_ns:10.1f} ns/substep {python_ns / rust_ns:8.0f}x slower")


def batch_throughput() -> None:
    trials = [make_trial(seed) for seed in range(N_TRIALS)]
    rng = np.random.default_rng(1)
    sets = sim.pack_params(PARAMS) * (1.0 + 0.01 * rng.standard_normal((N_SETS, len(sim.PARAM_NAMES))))
    x0 = np.zeros((N_SETS, N_TRIALS, 2))
    x0[..., 0] = 0.3
    substeps = N_SETS * sum(trial.substeps(MAX_STEP) for trial in trials)
    print(f"batch: {N_TRIALS} trials x {DURATION_S:.0f} s at {RATE_HZ:.0f} Hz x {N_SETS} parameter sets"
          f" = {substeps / 1e6:.1f} M substeps")
    serial = best_of(3, lambda: sim.simulate_many(trials, sets, x0, max_step=MAX_STEP, threads=1))
    pooled = best_of(3, lambda: sim.simulate_many(trials, sets, x0, max_step=MAX_STEP))
    print(f"  1 thread        {substeps / serial / 1e6:8.1f} M substeps/s  ({serial * 1e3:.0f} ms per batch)")
    print(f"  rayon ({os.cpu_count()} cpus)  {substeps / pooled / 1e6:8.1f} M substeps/s  ({pooled * 1e3:.0f} ms per batch)"
          f"  speed-up {serial / pooled:.2f}x")


if __name__ == "__main__":
    per_step_costs()
    batch_throughput()
