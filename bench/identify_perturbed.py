"""Which of `identify`'s verdicts hang on the last bit of the plant's sine: the families bench
under two builds of this tree's extension, side by side.

The default build takes the C library's sine; the other is built with the `libm-sine` feature
(rtcore/plant/src/trig.rs: the `libm` crate's sine and exponential, within 1 ulp of glibc's and
different from it in about 3 % of arguments). The test data do not change (the families come
from the test oracle, tests/oracles/ivp.py, in plain SciPy), so a row whose verdict or named
effects differ between the two runs is a verdict that hangs on rounding: the same data would
give another answer on another machine's C library, on a Pi, or after any change that moves a
sum in its last bit. On 2026-11-28 this comparison found five such verdicts; four were fixed by
general rules (docs/identification-speed-log.md, *The plant's sine changed in its last bit*).

The perturbed extension is built with this venv's maturin into ``rtcore/target/perturbed``
(its own Cargo target folder: the first build takes a few minutes, later ones only what changed)
and run from a copy of this tree's ``admittance`` package. Each build runs
``bench/identify_families.py`` in its own process with the same arguments; printed: every row
whose verdict or named effects differ (or whose held-out errors are more than 10 % apart), then
both totals. A figure is what one
run measured.

Usage: ``.venv/bin/python bench/identify_perturbed.py [--seeds 1] [--only clean,library,...] [--match TEXT]``
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HOME = ROOT / "rtcore" / "target" / "perturbed"
FEATURE = "libm-sine"


def perturbed_extension() -> Path:
    """This tree's ``_rtcore`` built with :data:`FEATURE`; the path of the ``.so``."""
    wheels = HOME / "wheels"
    shutil.rmtree(wheels, ignore_errors=True)
    env = dict(os.environ, CARGO_TARGET_DIR=str(HOME / "target"))
    maturin = Path(sys.executable).with_name("maturin")
    print(f"building the extension with --features {FEATURE} in {HOME} (minutes the first time)", flush=True)
    done = subprocess.run([str(maturin), "build", "--release", "--quiet", "--features", FEATURE, "-o", str(wheels)],
                          cwd=ROOT, env=env, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"cannot build the perturbed extension: {done.stderr[-2000:]}")
    unpacked = HOME / "unpacked"
    shutil.rmtree(unpacked, ignore_errors=True)
    with zipfile.ZipFile(next(wheels.glob("*.whl"))) as wheel:
        wheel.extractall(unpacked)
    return next((unpacked / "admittance").glob("_rtcore*.so"))


def perturbed_tree(extension: Path, into: Path) -> Path:
    """A copy of this tree's ``admittance`` package with the perturbed extension in it."""
    package = into / "admittance"
    shutil.copytree(ROOT / "admittance", package, ignore=shutil.ignore_patterns("_rtcore*.so", "__pycache__"))
    shutil.copy2(extension, package / extension.name)
    return into


def families(args: list[str], out: Path, pythonpath: Path | None) -> list[dict]:
    """bench/identify_families.py's rows, in a process of its own (``pythonpath`` first)."""
    env = dict(os.environ)
    if pythonpath is not None:
        env["PYTHONPATH"] = os.pathsep.join([str(pythonpath), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    # Run from the script's folder, as the families run is: `python -c` would put the working
    # directory first on sys.path, and from the repository root it found this tree's extension
    # while the families run took the perturbed one (2026-11-28: both lines named the default).
    probe = "import admittance._rtcore as m; print(m.__file__)"
    where = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True, check=True,
                           cwd=ROOT / "bench")
    extension = Path(where.stdout.strip())
    print(f"identify_families.py with {extension}", flush=True)
    if pythonpath is not None and pythonpath.resolve() not in extension.resolve().parents:
        raise SystemExit(f"the perturbed run would import {extension}, not the extension under {pythonpath}: "
                         "an installed admittance shadows PYTHONPATH; nothing compared")
    subprocess.run([sys.executable, str(ROOT / "bench" / "identify_families.py"), *args, "--json", str(out)],
                   env=env, check=True, stdout=subprocess.DEVNULL)
    return json.loads(out.read_text())


HELD_OUT_APART = 0.1  # held-out errors further apart than this fraction of the smaller differ


def differences(default: list[dict], perturbed: list[dict]) -> list[tuple[dict, dict]]:
    """Pairs of rows (same family, label, seed) whose verdict or named effects differ, or whose
    held-out errors differ by more than :data:`HELD_OUT_APART` of the smaller."""
    key = lambda row: (row["family"], row["label"], row.get("seed"))  # noqa: E731
    other = {key(row): row for row in perturbed}
    out = []
    for row in default:
        twin = other.get(key(row))
        if twin is None:
            continue
        a, b = row.get("after"), twin.get("after")
        apart = a is not None and b is not None and abs(a - b) > HELD_OUT_APART * min(a, b)
        if (row["ok"], row["effects"]) != (twin["ok"], twin["effects"]) or apart:
            out.append((row, twin))
    return out


def _verdict(row: dict) -> str:
    after = f"{1e3 * row['after']:.2f} mrad" if row.get("after") is not None else "–"
    ok = {True: "pass", False: "FAIL", None: "–"}[row["ok"]]
    return f"{ok}, {', '.join(row['effects']) or 'nothing'} named, held-out {after}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", nargs="+", default=["1"])
    parser.add_argument("--only", default="clean,library,equivalent,unnamed,light,long,regime")
    parser.add_argument("--match", default="")
    args = parser.parse_args()
    passed = ["--seeds", *args.seeds, "--only", args.only, "--match", args.match]
    print(f"/proc/loadavg at start: {_load()}", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        tree = perturbed_tree(perturbed_extension(), tmp / "tree")
        default = families(passed, tmp / "default.json", None)
        perturbed = families(passed, tmp / "perturbed.json", tree)
    changed = differences(default, perturbed)
    print(f"\n| family | set | seed | C library's sine | libm's sine |\n|---|---|---|---|---|")
    for row, twin in changed:
        print(f"| {row['family']} | {row['label']} | {row.get('seed', '-')} | {_verdict(row)} | {_verdict(twin)} |")
    scored = lambda rows: [r for r in rows if r["ok"] is not None]  # noqa: E731
    for name, rows in (("C library's sine", default), ("libm's sine", perturbed)):
        print(f"{name}: passed {sum(r['ok'] for r in scored(rows))} of {len(scored(rows))} synthetic rows")
    print(f"rows whose verdict, names or held-out error changed with the last bit of the sine: {len(changed)} of {len(default)}")
    print(f"/proc/loadavg at the end: {_load()}")


def _load() -> str:
    return Path("/proc/loadavg").read_text().strip() if Path("/proc/loadavg").exists() else "unknown"


if __name__ == "__main__":
    main()
