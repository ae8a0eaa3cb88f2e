"""`identify` on synthetic sets that hold one effect: this tree against a baseline commit, side by side.

Each set is 30 MX-64-like drops (``admittance synth``: the Rust plant at a 10× finer step, 2 mrad
noise, one undeclared effect). For every set, in one run on the same machine, identify runs
twice in a fresh Python process each: once as ``--baseline-ref`` was (default: the main this work
started from), its ``admittance/`` package with its own compiled extension, built from that
commit's ``rtcore/`` by maturin (kept in ``rtcore/target/baseline/<commit>``: the first run builds it, a
few minutes), and once as this tree is. ``--shared-extension`` gives the baseline this tree's
extension instead (then only the identification's Python differs; the plant's own speed-ups,
such as the rest of a drop not being stepped, count on both sides). The order alternates from
set to set so that a change in the machine's load does not favour one side.

Printed per set: both wall times (identify_dataset only, the data loaded) and both CPU times (all
threads of the process: on a machine shared with other jobs the work done, which the load
changes far less than the wall time), their ratios, and
whether the results agree: the same effects named, the same stand-ins, and every fitted
parameter within the larger of the two σ. Then the median ratio over the sets, with the load
average before and after. A figure is what one run measured: nothing is extrapolated.

Usage: ``.venv/bin/python bench/identify_speed.py [--sets stribeck=0.04,quadratic_drag=0.002,cogging=0.01]
[--trials 30] [--duration 10] [--seed 0] [--baseline-ref 74e9896] [--shared-extension] [--jacobian sensitivities]``
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BASELINE_REF = "74e9896"  # main before the screen (issue 19 item 2 started from it)
DEFAULT_SETS = "stribeck=0.04,quadratic_drag=0.002,cogging=0.01"

# Run in a child process whose PYTHONPATH puts one tree's ``admittance`` first.
RUNNER = """
import json, sys, time
import admittance
from admittance.formats.dataset import load_dataset
from admittance.ident.identify import identify_dataset
dataset = load_dataset(sys.argv[1])
if len(sys.argv) > 2:  # this tree's Jacobian (fit.JACOBIAN); the baseline has only differences
    import admittance.ident.fit as fit
    fit.JACOBIAN = sys.argv[2]
start, cpu = time.perf_counter(), time.process_time()
result = identify_dataset(dataset).to_json()
seconds, cpu = time.perf_counter() - start, time.process_time() - cpu
print(json.dumps({"package": admittance.__file__, "seconds": seconds, "cpu_seconds": cpu, "effects": result["effects"], "stand_ins": result.get("stand_ins", []),
                  "params": result["params"], "sigma": result.get("sigma", {}), "timings": result.get("timings", {})}))
"""


def _load() -> str:
    return Path("/proc/loadavg").read_text().strip() if Path("/proc/loadavg").exists() else "unknown"


def baseline_tree(ref: str, into: Path, shared_extension: bool) -> Path:
    """The ``admittance`` package of ``ref`` with its own compiled extension beside it (or, with
    ``shared_extension``, this tree's)."""
    into.mkdir(parents=True, exist_ok=True)
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", ref],
                             check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    extension = ROOT / "admittance" if shared_extension else baseline_extension(ref, archive)
    for ext in extension.glob("_rtcore*.so"):
        shutil.copy2(ext, into / "admittance" / ext.name)
    return into


def baseline_extension(ref: str, archive: bytes) -> Path:
    """The folder holding ``ref``'s own ``_rtcore``: built once with this venv's maturin from the
    commit's sources, then kept under ``rtcore/target/baseline/<commit>`` (a commit's sources
    never change, so neither does its build)."""
    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", f"{ref}^{{commit}}"], check=True,
                            capture_output=True, text=True).stdout.strip()
    home = ROOT / "rtcore" / "target" / "baseline" / commit
    built = home / "unpacked" / "admittance"
    if any(built.glob("_rtcore*.so")):
        print(f"the baseline's extension: {built} (built before)", flush=True)
        return built
    source = home / "src"
    shutil.rmtree(source, ignore_errors=True)
    source.mkdir(parents=True)
    subprocess.run(["tar", "-x", "-C", str(source)], input=archive, check=True)
    env = dict(os.environ, CARGO_TARGET_DIR=str(home / "target"))
    maturin = Path(sys.executable).with_name("maturin")
    print(f"building the baseline's extension in {source} (a few minutes, once)", flush=True)
    done = subprocess.run([str(maturin), "build", "--release", "--quiet", "-o", str(home / "wheels")], cwd=source,
                          env=env, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"cannot build the baseline's extension: {done.stderr[-2000:]}")
    with zipfile.ZipFile(next((home / "wheels").glob("*.whl"))) as wheel:
        wheel.extractall(home / "unpacked")
    return built


def run_identify(tree: Path, dataset: Path, jacobian: str | None = None) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree))
    # ``python -c`` puts the working directory first on sys.path: run from the data's folder, so
    # that a checkout in the caller's directory cannot stand in for ``tree`` (checked below).
    done = subprocess.run([sys.executable, "-c", RUNNER, str(dataset), *([jacobian] if jacobian else [])], env=env, capture_output=True, text=True,
                          check=False, cwd=dataset)
    if done.returncode != 0:
        raise RuntimeError(f"identify failed in {tree}: {done.stderr[-2000:]}")
    result = json.loads(done.stdout.strip().splitlines()[-1])
    if not Path(result["package"]).resolve().is_relative_to(tree.resolve()):
        raise RuntimeError(f"identify ran {result['package']}, not the tree {tree}")
    return result


def agreement(a: dict, b: dict) -> str:
    """"same" when both name the same effects and stand-ins and every parameter agrees within
    the larger σ; otherwise what differs."""
    notes = []
    if a["effects"] != b["effects"]:
        notes.append(f"effects {a['effects']} vs {b['effects']}")
    if a["stand_ins"] != b["stand_ins"]:
        notes.append(f"stand-ins {a['stand_ins']} vs {b['stand_ins']}")
    for name in sorted(set(a["params"]) & set(b["params"])):
        va, vb = a["params"][name], b["params"][name]
        sigma = max(a["sigma"].get(name) or 0.0, b["sigma"].get(name) or 0.0)
        if abs(va - vb) > sigma and abs(va - vb) > 1e-9 * max(abs(va), abs(vb), 1.0):
            notes.append(f"{name} {va:.5g} vs {vb:.5g} (σ {sigma:.2g})")
    return "same" if not notes else "; ".join(notes)


def make_set(folder: Path, effect: str, size: float, trials: int, duration: float, seed: int) -> Path:
    from admittance.ident.synthetic import SynthSpec, generate

    return generate(folder, SynthSpec(n_trials=trials, duration=duration, seed=seed, effects={effect: size}))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sets", default=DEFAULT_SETS, help="comma-separated EFFECT=SIZE, one set each")
    parser.add_argument("--trials", type=int, default=30)
    parser.add_argument("--duration", type=float, default=10.0, help="s per trial")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--baseline-ref", default=BASELINE_REF, help="git commit whose identification is the baseline")
    parser.add_argument("--shared-extension", action="store_true",
                        help="the baseline runs on this tree's compiled extension, not its own")
    parser.add_argument("--jacobian", choices=("differences", "sensitivities"), default=None,
                        help="this tree's Jacobian (admittance.ident.fit.JACOBIAN; default: the tree's own)")
    args = parser.parse_args()
    sets = [(name, float(size)) for name, size in (item.split("=") for item in args.sets.split(","))]

    print(f"machine: {os.cpu_count()} cpus; /proc/loadavg at start: {_load()}")
    extension = "this tree's extension" if args.shared_extension else "its own extension"
    print(f"baseline: admittance/ of {args.baseline_ref} on {extension}; this: {ROOT}; {args.trials} drops × {args.duration:g} s, "
          f"2 mrad noise, synthetic (admittance synth)")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        base = baseline_tree(args.baseline_ref, Path(tmp) / "baseline", args.shared_extension)
        for number, (effect, size) in enumerate(sets):
            folder = make_set(Path(tmp) / f"set{number}", effect, size, args.trials, args.duration, args.seed + number)
            order = [("baseline", base), ("this", ROOT)]
            if number % 2:
                order.reverse()
            results = {label: run_identify(tree, folder, args.jacobian if label == "this" else None)
                       for label, tree in order}
            b, t = results["baseline"], results["this"]
            rows.append((effect, size, b, t, agreement(b, t)))
            print(_row(rows[-1]) + f" load {_load().split()[0]}", flush=True)
    print(f"/proc/loadavg at the end: {_load()}")
    print("\n| set | wall baseline | wall this | wall ratio | CPU baseline | CPU this | CPU ratio | "
          "baseline names | this names | results |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for row in rows:
        print(_row(row))
    for kind, key in (("wall", "seconds"), ("CPU", "cpu_seconds")):
        ratios = [b[key] / t[key] for _, _, b, t, _ in rows]
        print(f"{'' if kind == 'CPU' else chr(10)}median {kind} ratio baseline / this: {statistics.median(ratios):.1f}× "
              f"over {len(ratios)} sets (min {min(ratios):.1f}×, max {max(ratios):.1f}×)")
    print(f"results agree on {sum(r[4] == 'same' for r in rows)} of {len(rows)} sets")


def _row(row) -> str:
    effect, size, b, t, agree = row
    return (f"| {effect}={size:g} | {b['seconds']:.1f} s | {t['seconds']:.1f} s | {b['seconds'] / t['seconds']:.1f}× | "
            f"{b['cpu_seconds']:.1f} s | {t['cpu_seconds']:.1f} s | {b['cpu_seconds'] / t['cpu_seconds']:.1f}× | "
            f"{', '.join(b['effects']) or '–'} | {', '.join(t['effects']) or '–'} | {agree} |")


if __name__ == "__main__":
    main()
