"""Do identify's 95 % intervals cover the truth? Coverage of ±1.96 σ on synthetic sets.

Each row is one `admittance synth` set (the Rust plant at a 10× finer step than the fit, known
truth) for one seed: clean, or with one library effect injected at a clearly visible size. For
every parameter identify reports a σ for and the truth knows (I, B, F, and the injected effect's
main parameter when that effect was named), the interval est ± 1.96 σ either holds the truth or
not; so does the reported 95 % interval (``uncertainty.interval95``: the jackknife over trial
groups of uncertainty.py). The table gives both, per set kind, from the same identify runs;
the target is ≥ 90 %. Driven effects (time delay, torque bias, torque gain) get driven trials.

Synthetic data: this measures the σ against a known truth, with the only model errors the ones
the generator makes (a finer integration step). Measured data have more.

``--encoder TICKS`` rounds every angle the generator wrote to a TICKS-per-revolution encoder
(no Gaussian noise: the rounding is the sensor) and declares it in the manifest; ``--trials 30``
gives 30-drop sets.

Measured sets have no truth. ``--real`` runs a consistency check instead on the sets of
../shared/data/real (converted as bench/identify_families.py does): the trials of each set are
dealt into two disjoint halves (alternately, in file order), each half is identified on its own
(no held-out trials taken: every trial of the half trains), and for every parameter both halves
report, the two 95 % intervals must overlap. With a right σ two independent estimates' intervals
of half-width 1.96 σ fail to overlap in < 1 % of cases; a frequent miss means the intervals are
too narrow (or the halves see different physics: the test cannot say which).

Usage: ``nice .venv/bin/python bench/identify_coverage.py [--seeds 20] [--kinds clean,stribeck,...]
[--trials 10] [--encoder 4096] [--real]``; prints the machine load with the table. To measure
another checkout (the side by side of docs/identification.md), run this file with that
checkout's interpreter and ``--root``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

KINDS = {  # effect → (size, driven trials?): the sizes of bench/identify_families.py's library rows
    "clean": (None, False),
    "stribeck": (0.06, False),
    "asymmetric_coulomb": (0.02, False),
    "load_dependent_coulomb": (0.12, False),
    "angle_offset": (0.03, False),
    "quadratic_drag": (0.01, False),
    "cogging": (0.01, False),
    "time_delay": (0.03, True),
    "torque_bias": (0.02, True),
    "torque_gain": (0.85, True),
    "spring": (0.05, False),
    "friction_ripple": (0.03, False),
}
Z95 = 1.959964


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--kinds", default=",".join(KINDS))
    parser.add_argument("--trials", type=int, default=10)
    parser.add_argument("--duration", type=float, default=6.0)
    parser.add_argument("--root", default=str(Path(__file__).resolve().parents[1]),
                        help="the checkout whose admittance package to measure")
    parser.add_argument("--encoder", type=int, default=0, help="round the angles to this many ticks per revolution")
    parser.add_argument("--seed0", type=int, default=1000, help="the first seed")
    parser.add_argument("--real", action="store_true", help="the consistency check on the measured sets instead")
    parser.add_argument("--json", help="also write the rows here")
    args = parser.parse_args()
    if args.real:
        return real_consistency(args)
    sys.path.insert(0, args.root)
    try:
        from admittance.formats.dataset import load_dataset
    except ImportError:  # a checkout from before the formats package (a side-by-side run)
        from admittance.ident.dataset import load_dataset
    from admittance.ident.identify import IdentifySettings, identify_dataset
    from admittance.ident.synthetic import EFFECT_MAIN, SynthSpec, generate

    print(f"load before: {Path('/proc/loadavg').read_text().strip()}; root {args.root}")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for kind in args.kinds.split(","):
            size, driven = KINDS[kind]
            for seed in range(args.seeds):
                spec = SynthSpec(n_trials=args.trials, duration=args.duration, seed=args.seed0 + seed,
                                 with_torque=driven, effects={} if size is None else {kind: size},
                                 **({"noise": 0.0} if args.encoder else {}))
                folder = generate(Path(tmp) / f"{kind}_{seed}", spec)
                if args.encoder:
                    quantise(folder, args.encoder)
                truth = json.loads((folder / "truth.json").read_text())["params"]
                tick = time.perf_counter()
                j = identify_dataset(load_dataset(folder), IdentifySettings()).to_json()
                seconds = time.perf_counter() - tick
                names = ["motor_inertia", "damping", "coulomb"]
                if size is not None and kind in j.get("model_effects", j["effects"]):
                    names.append(EFFECT_MAIN[kind][0])
                reported = j.get("uncertainty") or {}
                for name in names:
                    sigma = j["sigma"].get(name)
                    if sigma is None or truth.get(name) is None:
                        continue
                    error = j["params"][name] - truth[name]
                    interval = reported.get("interval95", {}).get(name)
                    rows.append({"kind": kind, "seed": seed, "param": name, "estimate": j["params"][name],
                                 "truth": truth[name], "sigma": sigma, "z": error / sigma if sigma > 0 else float("inf"),
                                 "covered": abs(error) <= Z95 * sigma, "named": j["effects"], "seconds": seconds,
                                 "interval": interval,
                                 "covered_reported": None if interval is None else interval[0] <= truth[name] <= interval[1],
                                 "seconds_uncertainty": j.get("timings", {}).get("uncertainty")})
                print(f"  {kind:24s} seed {seed:3d}: {seconds:6.1f} s, named {j['effects']}, "
                      + ", ".join(f"{r['param']} z={r['z']:+.1f}" + ("" if r["covered_reported"] is None else
                                  " in" if r["covered_reported"] else " OUT")
                                  for r in rows if r["kind"] == kind and r["seed"] == seed),
                      flush=True)
    print(f"load after: {Path('/proc/loadavg').read_text().strip()}")
    print("\n| set | intervals | fit σ ±1.96σ: covering | coverage | reported interval: covering | coverage "
          "| max |z| (fit σ) |\n|---|---|---|---|---|---|---|")
    for kind in args.kinds.split(",") + ["all"]:
        sel = [r for r in rows if kind in ("all", r["kind"])]
        if sel:
            covered = sum(r["covered"] for r in sel)
            judged = [r for r in sel if r["covered_reported"] is not None]
            held = sum(r["covered_reported"] for r in judged)
            after = f"{held} of {len(judged)} | {100 * held / len(judged):.0f} %" if judged else "– | not reported"
            print(f"| {kind} | {len(sel)} | {covered} | {100 * covered / len(sel):.0f} % | {after} | "
                  f"{max(abs(r['z']) for r in sel):.1f} |")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


def quantise(folder: Path, ticks: int) -> None:
    """Round every angle in ``folder``'s CSVs to ``ticks`` per revolution and declare the encoder
    in the manifest (what a Dynamixel's 4096-tick encoder records)."""
    import numpy as np
    import tomli_w
    import tomllib

    step = 2 * np.pi / ticks
    for path in folder.glob("*.csv"):
        header = path.read_text().splitlines()[0]
        data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
        data[:, 1] = np.round(data[:, 1] / step) * step
        np.savetxt(path, data, delimiter=",", header=header, comments="", fmt="%.9g")
    manifest = folder / "manifest.toml"
    content = tomllib.loads(manifest.read_text())
    content["encoder_ticks"] = ticks
    manifest.write_text(tomli_w.dumps(content))


def real_consistency(args) -> int:
    """The measured sets' disjoint-halves check (module doc)."""
    sys.path.insert(0, str(Path(args.root) / "tests"))
    sys.path.insert(0, str(Path(args.root) / "bench"))
    from identify_families import real_sets

    from admittance.formats.converters import convert_files
    from admittance.formats.dataset import load_dataset
    from admittance.ident.identify import IdentifySettings, identify_dataset

    print(f"load before: {Path('/proc/loadavg').read_text().strip()}; root {args.root}")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for label, files, fmt, header, extra, window in real_sets():
            halves = [files[0::2], files[1::2]]
            found, base = [], []
            for k, half in enumerate(halves):
                folder = convert_files(half, fmt, Path(tmp) / f"{label.split()[0]}_{k}", header=header, extra=extra,
                                       **window)
                tick = time.perf_counter()
                found.append(identify_dataset(load_dataset(folder), IdentifySettings(hold_out=False)))
                base.append(identify_dataset(load_dataset(folder), IdentifySettings(hold_out=False, max_effects=0)))
                print(f"  {label} half {k} ({len(half)} trials): {time.perf_counter() - tick:.1f} s, named "
                      f"{found[-1].effects}, model {found[-1].model_effects}", flush=True)
            # The halves compared as identified (their models may differ: a stand-in trades the
            # inertia against a spring or a cogging term), in the base model's form, and in the
            # form each half chose, fitted to the other half too: I, B, F of one model, twice.
            forms = {"as identified": [_intervals(r) for r in found], "base model (both)": [_intervals(r) for r in base]}
            for k, chooser in enumerate(found):
                if chooser.model_effects:
                    form = "+".join(chooser.model_effects)
                    forms[f"{form} (both)"] = [_intervals(chooser if i == k else _in_form(other, chooser))
                                               for i, other in enumerate(found)]
            for form, (a, b) in forms.items():
                names = ("motor_inertia", "damping", "coulomb") if form != "as identified" else sorted(set(a) & set(b))
                for name in names:
                    ia, ib = a[name], b[name]
                    overlap = ia[0] <= ib[1] and ib[0] <= ia[1]
                    rows.append({"set": label, "form": form, "param": name, "half_a": ia, "half_b": ib,
                                 "overlap": overlap})
                    print(f"    {form:32s} {name:16s} [{ia[0]:.5g}, {ia[1]:.5g}] vs [{ib[0]:.5g}, {ib[1]:.5g}]: "
                          f"{'overlap' if overlap else 'DISJOINT'}", flush=True)
    print(f"load after: {Path('/proc/loadavg').read_text().strip()}")
    print("\n| measured set | model form of both halves | parameters | intervals overlapping |\n|---|---|---|---|")
    for label, form in sorted({(r["set"], r["form"]) for r in rows}):
        sel = [r for r in rows if r["set"] == label and r["form"] == form]
        held = sum(r["overlap"] for r in sel)
        print(f"| {label} | {form} | {len(sel)} | {held} ({100 * held / len(sel):.0f} %) |")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


def _intervals(result) -> dict:
    """The reported 95 % intervals of an identify result, by parameter."""
    return (result.intervals() or {}).get("interval95", {})


def _in_form(result, form):
    """``result``'s trials fitted in ``form``'s model (its effects and free parameters), started
    from ``form``'s values and ``result``'s initial states; reported as identify reports."""
    from dataclasses import replace

    from admittance.ident.base import torque_scale_of
    from admittance.ident.fit import fit_initial_states_multi, fit_output_error
    from admittance.ident.model import Simulator
    from admittance.ident.uncertainty import reported_uncertainty

    data = result.dataset
    sim = Simulator(data.trials, data.mode, result.settings.friction, result.settings.max_step,
                    form.final.tau_scale).subset(result.training)
    scale = torque_scale_of(data)
    x0 = fit_initial_states_multi(sim, form.final.vector, [result.final.x0]).x0
    fit = fit_output_error(sim, form.final.vector, form.final.free, x0, torque_scale=scale)
    return replace(result, final=fit, uncertainty=reported_uncertainty(sim, fit, scale))


if __name__ == "__main__":
    raise SystemExit(main())
