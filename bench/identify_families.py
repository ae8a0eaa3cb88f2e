"""`identify` on every family of test data, one table: what it names, how close I/B/F come, and
the held-out error before and after.

Families (all synthetic sets come from the TEST ORACLE tests/oracles/ivp.py: SciPy's solve_ivp
with stick events, not the Rust plant that identify fits with):

- clean: no effect, under each sensor: 2 mrad Gaussian (motion capture), a 4096-tick encoder
  (declared in the manifest, and inferred from the data), AR(1)-coloured noise, outliers,
  torque-driven trials; and 3 long swings;
- library: each effect of the catalogue alone, at the sizes of tests/test_ident_effects.py;
- unnamed: effects the library has no name for (backlash, Dahl presliding, damping that grows
  with the angle, a speed-dependent ripple, friction that warms up, an eccentric encoder);
- light: the same on a lightly damped joint that swings for seconds (and its clean set);
- long: three 20 s swings of a light pendulum, clean and with quadratic drag (a small measured
  set's shape);
- equivalent: a torque bias on driven trials only, where it is the same equation as an
  asymmetric Coulomb level (no name is the honest answer; with free swings in the set, the
  library row, the data decide);
- regime: the effects issue 19 found fitted right but not named (a load-dependent Coulomb
  level, a torque bias on driven and free trials, Stribeck at 1.5× the Coulomb level), each on
  a 4096-tick encoder and with 30 trials: what the regime test's floor (ident/regime.py) is for;
- real: the measured sets of ../shared/data/real (XL330 free swings, DFKI swing-ups), when present.

A row passes when: clean → no effect; library and regime → exactly that effect, I/B/F within 5/10/15 %;
unnamed → no library name; equivalent → no name. Real rows show held-out before → after (no
truth to compare).

Usage: ``.venv/bin/python bench/identify_families.py [--seeds 1 2] [--only clean,library,...]``
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from oracles import ivp as oracle  # noqa: E402  (the test oracle lives with the tests)

from admittance.formats.dataset import load_dataset  # noqa: E402
from admittance.ident.identify import IdentifySettings, identify_dataset  # noqa: E402

LIBRARY = [("stribeck", 0.04, False), ("asymmetric_coulomb", 0.02, False), ("load_dependent_coulomb", 0.1, False),
           ("angle_offset", 0.03, False), ("quadratic_drag", 0.002, False), ("cogging", 0.01, False),
           ("time_delay", 0.03, True), ("torque_bias", 0.02, "mixed"), ("torque_gain", 0.85, True),
           ("spring", 0.05, False), ("friction_ripple", 0.03, False)]
UNNAMED = [("backlash", 0.004), ("dahl", 0.01), ("position_damping", 0.05), ("speed_ripple", 0.02),
           ("friction_warmup", 0.4), ("eccentric_encoder", 0.02)]
LONG = {"motor_inertia": 0.002, "damping": 0.002, "coulomb": 0.004}
# A lightly damped joint (an MX-28-like drop: swings for several seconds), where unnamed effects
# shape many more swings than on the thesis's heavily damped MX-64.
LIGHT = {"motor_inertia": 0.004, "damping": 0.006, "coulomb": 0.015}
LIGHT_UNNAMED = [("backlash", 0.004), ("dahl", 0.01), ("position_damping", 0.01), ("speed_ripple", 0.005),
                 ("friction_warmup", 0.4), ("eccentric_encoder", 0.02)]
# The regime family: (effect, size, driven); Stribeck at 1.5× the MX-64's Coulomb level.
REGIME = [("load_dependent_coulomb", 0.1, False), ("torque_bias", 0.02, "mixed"), ("stribeck", 1.5 * 0.084, False)]
TOLERANCE = {"motor_inertia": 0.05, "damping": 0.10, "coulomb": 0.15}


def families(seed: int) -> list[tuple[str, str, oracle.OracleSpec]]:
    """(family, label, spec) for every synthetic row."""
    s = seed
    rows = [
        ("clean", "mocap 2 mrad", oracle.OracleSpec(seed=s)),
        ("clean", "encoder 4096 (manifest)", oracle.OracleSpec(noise=0.0, ticks=4096, declare_ticks=True, seed=s)),
        ("clean", "encoder 4096 (inferred)", oracle.OracleSpec(noise=0.0003, ticks=4096, seed=s)),
        ("clean", "AR(1) 0.9 coloured", oracle.OracleSpec(noise_correlation=0.9, seed=s)),
        ("clean", "outliers 1 %", oracle.OracleSpec(outliers=0.01, seed=s)),
        ("clean", "torque-driven", oracle.OracleSpec(with_torque=True, seed=s)),
        ("clean", "torque-driven encoder", oracle.OracleSpec(with_torque=True, noise=0.0, ticks=4096, seed=s)),
        ("clean", "3 long swings", oracle.OracleSpec(n_trials=3, duration=20.0, rate=100.0, params=dict(LONG),
                                                     release=1.2, seed=s)),
    ]
    for effect, size, torque in LIBRARY:
        label = effect + (" (driven and free trials)" if torque == "mixed" else "")
        rows.append(("library", label, oracle.OracleSpec(effect=effect, size=size, with_torque=bool(torque),
                                                         mixed=torque == "mixed", seed=s)))
    # On driven trials only, a torque bias is the same equation as an asymmetric Coulomb level.
    rows.append(("equivalent", "torque_bias, driven trials only",
                 oracle.OracleSpec(effect="torque_bias", size=0.02, with_torque=True, seed=s)))
    for effect, size in UNNAMED:
        rows.append(("unnamed", effect, oracle.OracleSpec(effect=effect, size=size, seed=s)))
    rows.append(("light", "clean, light joint", oracle.OracleSpec(params=dict(LIGHT), duration=8.0, seed=s)))
    for effect, size in LIGHT_UNNAMED:
        rows.append(("light", effect, oracle.OracleSpec(params=dict(LIGHT), duration=8.0, effect=effect, size=size,
                                                        seed=s)))
    rows.append(("long", "quadratic_drag, 3 long swings",
                 oracle.OracleSpec(n_trials=3, duration=20.0, rate=100.0, params=dict(LONG), release=1.2,
                                   effect="quadratic_drag", size=0.003, seed=s)))
    rows.append(("long", "quadratic_drag, 3 long swings, encoder",
                 oracle.OracleSpec(n_trials=3, duration=20.0, rate=100.0, params=dict(LONG), release=1.2,
                                   effect="quadratic_drag", size=0.003, noise=0.0, ticks=4096, seed=s)))
    for effect, size, torque in REGIME:
        driven = dict(with_torque=bool(torque), mixed=torque == "mixed")
        rows.append(("regime", f"{effect}, encoder 4096", oracle.OracleSpec(
            effect=effect, size=size, noise=0.0, ticks=4096, declare_ticks=True, seed=s, **driven)))
        rows.append(("regime", f"{effect}, 30 trials", oracle.OracleSpec(effect=effect, size=size, n_trials=30, seed=s,
                                                                         **driven)))
    return rows


def verdict(family: str, spec: oracle.OracleSpec, result: dict, truth: dict) -> tuple[bool, str]:
    named = result["effects"]
    errors = {p: (result[p] - truth["params"][p]) / truth["params"][p] for p in TOLERANCE}
    ibf = all(abs(errors[p]) <= TOLERANCE[p] for p in TOLERANCE)
    if family in ("clean", "unnamed") or (family == "light" and spec.effect not in oracle.LIBRARY_MAIN):
        return (not named), ""
    if family == "equivalent":  # nothing in the data tells the two apart: the group is the honest answer
        grouped = any(spec.effect in g["effects"] for g in result.get("groups", []))
        return (not named and grouped), "" if grouped else "group not named"
    expected = [spec.effect]
    ok = named == expected and ibf
    return ok, "" if ibf else "I/B/F off"


def run_row(family, label, spec, tmp: Path) -> dict:
    folder = oracle.generate(tmp / f"{family}_{label.replace(' ', '_')}_{spec.seed}", spec)
    truth = json.loads((folder / "truth.json").read_text())
    start = time.perf_counter()
    result = identify_dataset(load_dataset(folder), IdentifySettings()).to_json()
    seconds = time.perf_counter() - start
    ok, note = verdict(family, spec, result, truth)
    errors = {p: (result[p] - truth["params"][p]) / truth["params"][p] for p in TOLERANCE}
    return {"family": family, "label": label, "seed": spec.seed, "effects": result["effects"], "ok": ok,
            "note": note, "errors": errors, "before": result["rmse_before"], "after": result["rmse_after"],
            "seconds": seconds, "unexplained": bool(result.get("unexplained"))}


def real_sets() -> list[tuple]:
    """(label, files, format, header, extra, window) of each measured set present ([] without
    ../shared/data/real)."""
    from conftest import REAL_DATA
    from test_realdata import _dfki_files, _xl330_files

    if not REAL_DATA.is_dir():
        return []
    return [
        ("XL330 free swings (geometry)", _xl330_files(REAL_DATA), "dynamixel",
         {"motor": "XL330", "rod": {"mass": 0.0094, "length": 0.1}, "bob": {"mass": 0.49}}, {"bob_distance": 0.1}, {}),
        ("DFKI swing-ups (geometry)", _dfki_files(REAL_DATA), "dfki",
         {"motor": "AK80-6", "rod": {"mass": 0.13, "length": 0.5}, "bob": {"mass": 0.546}}, {"bob_distance": 0.5},
         {"t_stop": 3.3}),
    ]


def real_rows(tmp: Path) -> list[dict]:
    from admittance.formats.converters import convert_files

    out = []
    for label, files, fmt, header, extra, window in real_sets():
        folder = convert_files(files, fmt, tmp / label.split()[0], header=header, extra=extra, **window)
        start = time.perf_counter()
        result = identify_dataset(load_dataset(folder), IdentifySettings()).to_json()
        cv = result.get("crossvalidation") or {}
        out.append({"family": "real", "label": label, "seed": "-", "effects": result["effects"], "ok": None,
                    "note": _cv_note(cv), "errors": {}, "before": result["rmse_before"],
                    "after": result["rmse_after"], "seconds": time.perf_counter() - start,
                    "unexplained": bool(result.get("unexplained"))})
    return out


def _cv_note(cv: dict) -> str:
    steps = cv.get("steps") or []
    if not steps:
        return ""
    return "CV " + " → ".join(f"{1e3 * s['rmse']:.1f}" for s in steps) + " mrad"


def table(rows: list[dict]) -> str:
    head = "| family | set | seed | effects named | pass | I / B / F error | held-out before → after (mrad) | unexplained | s |"
    lines = [head, "|---" * 9 + "|"]
    for r in rows:
        err = " / ".join(f"{100 * r['errors'][p]:+.1f} %" for p in TOLERANCE) if r["errors"] else "–"
        ok = "–" if r["ok"] is None else ("yes" if r["ok"] else "**no**")
        note = f" ({r['note']})" if r["note"] else ""
        lines.append(f"| {r['family']} | {r['label']} | {r['seed']} | {', '.join(r['effects']) or '–'} | {ok}{note} "
                     f"| {err} | {1e3 * r['before']:.2f} → {1e3 * r['after']:.2f} | "
                     f"{'yes' if r['unexplained'] else '–'} | {r['seconds']:.1f} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1])
    parser.add_argument("--only", default="clean,library,equivalent,unnamed,light,long,regime,real")
    parser.add_argument("--match", default="", help="only the sets whose label contains this")
    parser.add_argument("--json", help="also write the rows as JSON here")
    args = parser.parse_args()
    wanted = set(args.only.split(","))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for seed in args.seeds:
            for family, label, spec in families(seed):
                if family in wanted and args.match in label:
                    rows.append(run_row(family, label, spec, tmp))
                    print(table(rows[-1:]).splitlines()[-1], flush=True)
        if "real" in wanted:
            rows.extend(real_rows(tmp))
    print()
    print(table(rows))
    scored = [r for r in rows if r["ok"] is not None]
    print(f"\npassed {sum(r['ok'] for r in scored)} of {len(scored)} synthetic rows; "
          f"total identify time {sum(r['seconds'] for r in rows):.1f} s")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1, default=float))


if __name__ == "__main__":
    main()
