"""The fit's numerics (admittance/ident/fit.py) of this tree against a baseline's, side by side,
and bit for bit the same results.

Both sides run this tree's compiled extension (the Rust plant): only the Python differs. For
each data set, ``--rounds`` times, ``admittance identify DIR --json`` runs once as
``--baseline-ref`` has it and once as this tree has it, each in a fresh Python process, the
order alternating from round to round so that a change of the machine's load favours neither.
Printed per run: the wall and CPU time of the command (``main()`` in the child, data loading
and the JSON included; CPU summed over all threads) with ``/proc/loadavg``; per set the
medians and their ratios. Every JSON written is compared with the first baseline run's, every
key and every bit except the ``timings``: a result that moves is reported as a difference.

``--profile`` adds one cProfile run per side and set: the own time (tottime) of the plant's
``simulate_batch``, of everything in fit.py, numpy's FFT and SVD, and of fit.py's heaviest
functions. cProfile slows Python down, so those figures compare the two sides with each other,
not with the wall times.

Usage: ``.venv/bin/python bench/fit_numerics.py [--sets DIR,DIR,...] [--rounds 3]
[--baseline-ref REF] [--profile]``; without ``--sets`` it makes the three sets of issue 19
(``admittance synth --effect E --trials 30 --duration 10 --seed 0``: quadratic_drag=0.002,
cogging=0.01, stribeck=0.04) in a temporary folder.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import pstats
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EFFECTS = ("quadratic_drag=0.002", "cogging=0.01", "stribeck=0.04")

# The child: one tree's ``admittance`` first on the path, ``identify`` as the command line runs it.
RUNNER = """
import cProfile, json, sys, time
tree, dataset, out, profile = sys.argv[1:5]
sys.path.insert(0, tree)
import admittance
assert admittance.__file__.startswith(tree), admittance.__file__
from admittance.cli import main
argv = ["identify", "--quiet", "--json", out, dataset]
start, cpu = time.perf_counter(), time.process_time()
if profile != "-":
    cProfile.run("main(argv)", profile)
else:
    main(argv)
print(json.dumps({"seconds": time.perf_counter() - start, "cpu_seconds": time.process_time() - cpu}))
"""


def load() -> str:
    return Path("/proc/loadavg").read_text().strip() if Path("/proc/loadavg").exists() else "unknown"


def baseline_package(ref: str, into: Path) -> Path:
    """``ref``'s ``admittance`` package, with this tree's compiled extension in it."""
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", ref, "admittance"], check=True,
                             capture_output=True).stdout
    into.mkdir(parents=True, exist_ok=True)
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    for ext in (ROOT / "admittance").glob("_rtcore*.so"):
        shutil.copy2(ext, into / "admittance" / ext.name)
    return into


def make_sets(folder: Path) -> list[Path]:
    sets = []
    for spec in EFFECTS:
        target = folder / spec.split("=")[0]
        subprocess.run([sys.executable, "-m", "admittance", "synth", "--effect", spec, "--trials", "30",
                        "--duration", "10", "--seed", "0", str(target)], check=True, capture_output=True, cwd=folder)
        sets.append(target)
    return sets


def identify(tree: Path, dataset: Path, out: Path, profile: Path | None = None) -> dict:
    # Run from the data's folder: ``python -c`` puts the working directory first on sys.path.
    done = subprocess.run([sys.executable, "-c", RUNNER, str(tree), str(dataset), str(out),
                           str(profile) if profile else "-"], capture_output=True, text=True, cwd=dataset)
    if done.returncode != 0:
        raise RuntimeError(f"identify failed in {tree}: {done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def differences(a, b, path: str = "") -> list[str]:
    """Every place where two JSON values differ (floats compared exactly; NaN equals NaN),
    ignoring the keys that hold timings."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for key in sorted(set(a) | set(b)):
            if key == "timings":
                continue
            if key not in a or key not in b:
                out.append(f"{path}/{key}: only on one side")
            else:
                out += differences(a[key], b[key], f"{path}/{key}")
        return out
    if isinstance(a, list) and isinstance(b, list):
        out = [] if len(a) == len(b) else [f"{path}: {len(a)} vs {len(b)} items"]
        for i, (x, y) in enumerate(zip(a, b)):
            out += differences(x, y, f"{path}[{i}]")
        return out
    same = a == b or (isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b))
    same = same and type(a) is type(b) and (not isinstance(a, float) or math.copysign(1, a) == math.copysign(1, b))
    return [] if same else [f"{path}: {a!r} vs {b!r}"]


def own_times(profile: Path) -> dict[str, float]:
    """Own time (s) of the plant, of fit.py as a whole, numpy's FFT and SVD, and of each fit.py
    function (by name; list comprehensions by their line)."""
    stats = pstats.Stats(str(profile)).stats
    out: dict[str, float] = {"simulate_batch": 0.0, "fit.py": 0.0, "numpy fft": 0.0, "numpy svd": 0.0, "all": 0.0}
    for (filename, line, name), (_, _, tottime, _, _) in stats.items():
        out["all"] += tottime
        if "simulate_batch" in name:
            out["simulate_batch"] += tottime
        elif filename.endswith("ident/fit.py"):
            out["fit.py"] += tottime
            key = f"fit.py {name}" if not name.startswith("<") else f"fit.py {name}:{line}"
            out[key] = out.get(key, 0.0) + tottime
        elif "numpy/fft" in filename:
            out["numpy fft"] += tottime
        elif filename.endswith("_linalg.py") and name == "svd":
            out["numpy svd"] += tottime
    out["all but simulate_batch"] = out["all"] - out["simulate_batch"]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sets", default="", help="comma-separated data set folders (default: make issue 19's three)")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--baseline-ref", default="", help="default: where this branch left main (git merge-base HEAD main)")
    parser.add_argument("--profile", action="store_true", help="one cProfile run per side and set")
    args = parser.parse_args()
    ref = args.baseline_ref or subprocess.run(["git", "-C", str(ROOT), "merge-base", "HEAD", "main"], check=True,
                                              capture_output=True, text=True).stdout.strip()
    print(f"machine: {os.cpu_count()} cpus; /proc/loadavg at start: {load()}; baseline {ref}, this {ROOT}")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        base = baseline_package(ref, tmp / "baseline")
        sets = [Path(s).resolve() for s in args.sets.split(",")] if args.sets else make_sets(tmp)
        trees = {"baseline": base, "this": ROOT}
        summary = []
        for number, dataset in enumerate(sets):
            times: dict[str, list[dict]] = {"baseline": [], "this": []}
            reference = None
            diffs: list[str] = []
            for round_ in range(args.rounds):
                order = ["baseline", "this"] if (round_ + number) % 2 == 0 else ["this", "baseline"]
                for side in order:
                    out = tmp / f"{dataset.name}.{side}.{round_}.json"
                    result = identify(trees[side], dataset, out)
                    result["load"] = load().split()[0]
                    times[side].append(result)
                    print(f"{dataset.name} round {round_ + 1} {side:8s}: wall {result['seconds']:.2f} s, "
                          f"CPU {result['cpu_seconds']:.2f} s, load {result['load']}", flush=True)
                    written = json.loads(out.read_text())
                    if reference is None:
                        reference = written
                    diffs += [f"{side} round {round_ + 1}: {d}" for d in differences(reference, written)]
            medians = {side: {k: statistics.median(r[k] for r in runs) for k in ("seconds", "cpu_seconds")}
                       for side, runs in times.items()}
            summary.append((dataset.name, medians, len(diffs)))
            for d in diffs[:20]:
                print("  DIFFERENCE", d)
            print(f"{dataset.name}: {args.rounds * 2} JSON outputs, {len(diffs)} differences from the first", flush=True)
            if args.profile:
                profiles = {}
                for side in ("baseline", "this"):
                    path = tmp / f"{dataset.name}.{side}.prof"
                    identify(trees[side], dataset, tmp / f"{dataset.name}.{side}.prof.json", path)
                    profiles[side] = own_times(path)
                keys = ["all but simulate_batch", "simulate_batch", "fit.py", "numpy fft", "numpy svd"]
                keys += sorted({k for p in profiles.values() for k in p if k.startswith("fit.py ")},
                               key=lambda k: -max(p.get(k, 0.0) for p in profiles.values()))[:12]
                print(f"  cProfile own time (s), baseline → this, load {load().split()[0]}:")
                for k in keys:
                    print(f"    {k:40s} {profiles['baseline'].get(k, 0.0):7.3f} → {profiles['this'].get(k, 0.0):7.3f}")
    print(f"/proc/loadavg at the end: {load()}")
    print("\n| set | wall baseline | wall this | ratio | CPU baseline | CPU this | ratio | JSON differences |")
    print("|---|---|---|---|---|---|---|---|")
    for name, m, n_diffs in summary:
        b, t = m["baseline"], m["this"]
        print(f"| {name} | {b['seconds']:.2f} s | {t['seconds']:.2f} s | {b['seconds'] / t['seconds']:.3f} | "
              f"{b['cpu_seconds']:.2f} s | {t['cpu_seconds']:.2f} s | {b['cpu_seconds'] / t['cpu_seconds']:.3f} | {n_diffs} |")
    print(f"(medians of {args.rounds} runs a side)")


if __name__ == "__main__":
    main()
