"""Subcommands of the thesis's procedures (Contract 6): ``admittance thesis``, ``breakaway`` and
``predict``.

- ``admittance thesis DATASET_DIR [--out DIR]``: the thesis's per-trial alternating fit,
  printed as tables 3.2–3.4 (Markdown) and written as Markdown + CSV with ``--out``.
- ``admittance breakaway DATASET_DIR [--json OUT]``: breakaway torque of force-ramp trials
  (table 3.1).
- ``admittance predict DATASET_DIR --params FILE.toml [--out DIR]``: section 3.3's testing of
  fitted parameters against measured torque, with appendix-B-style plots.

Registration imports nothing heavy: SciPy, matplotlib and the Rust core load in the handlers.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

from admittance import outfolder

PREDICT_FILES = ("metrics.json", "*.png")


def register(subparsers) -> None:
    _register_thesis(subparsers)
    _register_breakaway(subparsers)
    _register_predict(subparsers)


def _register_thesis(subparsers) -> None:
    thesis = subparsers.add_parser(
        "thesis", help="reproduce the thesis's per-trial alternating LM fit (tables 3.2-3.4)",
        description="Fit each trial as the thesis did (appendix C.3): Levenberg-Marquardt on (I, B), then on F, "
                    "alternated; print the per-trial table in the layout of tables 3.2-3.4.")
    thesis.add_argument("dataset", type=Path, metavar="DATASET_DIR", help="dataset folder: manifest.toml and the trial files (format: admittance docs datasets)")
    thesis.add_argument("--out", type=Path, metavar="DIR",
                        help="also write thesis_table.md and thesis_table.csv into DIR (default: print only)")
    thesis.add_argument("--cycles", type=int, default=5, metavar="N",
                        help="(I,B)/F alternations (default 5, as appendix C.3)")
    thesis.add_argument("--initial-friction", type=float, metavar="NM",
                        help="initial F in N·m (default: table 3.1 for the motor)")
    thesis.add_argument("--initial-inertia", type=float, default=0.0385, metavar="KGM2",
                        help="initial total inertia in kg·m² (default 0.0385, appendix C.3)")
    thesis.add_argument("--initial-damping", type=float, default=0.0286, metavar="NMS",
                        help="initial damping in N·m·s/rad (default 0.0286, appendix C.3)")
    thesis.add_argument("--x0", choices=("rest", "data"), default="rest",
                        help="initial state: first angle at rest (the thesis) or velocity from the data (default rest)")
    thesis.set_defaults(func=_run_thesis)


def _register_breakaway(subparsers) -> None:
    brk = subparsers.add_parser(
        "breakaway", help="breakaway friction torque of slow force-ramp trials (table 3.1)",
        description="For each trial, find where the angle leaves its rest band under a slow torque ramp and read "
                    "the torque there (thesis section 2.3, table 3.1). Every trial needs a tau column (N·m), and "
                    "tau must ramp steadily up to the breakaway: a step, hold or oscillation is refused.")
    brk.add_argument("dataset", type=Path, metavar="DATASET_DIR", help="dataset folder: manifest.toml and the trial files (format: admittance docs datasets)")
    brk.add_argument("--json", type=Path, metavar="FILE.json", help="also write the results as JSON (default: print only)")
    brk.set_defaults(func=_run_breakaway)


def _register_predict(subparsers) -> None:
    pred = subparsers.add_parser(
        "predict", help="test fitted parameters on recorded trials: predicted position, calculated torque (thesis 3.3)",
        description="Thesis section 3.3: simulate each trial's position from its torque with the given parameters, "
                    "and compute the torque from its position; print the errors, and with --out write "
                    "metrics.json and appendix-B-style plots.")
    pred.add_argument("dataset", type=Path, metavar="DATASET_DIR", help="dataset folder: manifest.toml and the trial files (format: admittance docs datasets)")
    pred.add_argument("--params", type=Path, required=True, metavar="FILE.toml", help="a Contract 2 parameter file")
    pred.add_argument("--out", type=Path, metavar="DIR", help="write metrics.json and the appendix-B plots into DIR "
                      "(new or empty unless --force; default: print only; needs admittance[plots])")
    pred.add_argument("--force", action="store_true", help="write into a non-empty DIR, replacing its metrics.json "
                      "and plots")
    pred.add_argument("--thesis-k", type=float, metavar="S/RAD",
                      help="k of the thesis formula's tanh(k*vel) in s/rad (default: the file's tanh_k; appendix C.4 used 1)")
    pred.add_argument("--x0", choices=("fit", "data"), default="fit",
                      help="initial state: fitted to the trial (as identify scores) or from its first 50 ms (default fit)")
    pred.set_defaults(func=_run_predict)


def _run_thesis(args) -> int:
    from admittance.thesis import alternating as thesis
    from admittance.formats.dataset import load_dataset

    _check_thesis_options(args)
    dataset = load_dataset(args.dataset)
    progress = (lambda line: print(line, file=sys.stderr)) if sys.stderr.isatty() else None
    rows = thesis.fit_dataset(dataset, cycles=args.cycles, x0=args.x0, initial_friction=args.initial_friction,
                              initial_inertia=args.initial_inertia, initial_damping=args.initial_damping,
                              progress=progress)
    markdown = thesis.to_markdown(rows, f"Thesis-method fit: {dataset.motor or args.dataset.name}")
    print(markdown, end="")
    if args.out:
        outfolder.write_texts(args.out, {"thesis_table.md": markdown, "thesis_table.csv": thesis.to_csv(rows)})
    return 0


def _check_thesis_options(args) -> None:
    from admittance.errors import ConfigError

    if args.cycles < 1:
        raise ConfigError(f"--cycles must be >= 1, got {args.cycles}")
    if not (math.isfinite(args.initial_inertia) and args.initial_inertia > 0):
        raise ConfigError(f"--initial-inertia must be a finite number > 0, got {args.initial_inertia}")
    for option, value in (("--initial-damping", args.initial_damping), ("--initial-friction", args.initial_friction)):
        if value is not None and not (math.isfinite(value) and value >= 0):
            raise ConfigError(f"{option} must be a finite number >= 0, got {value}")


def _run_breakaway(args) -> int:
    from admittance.thesis import breakaway
    from admittance.formats.dataset import load_dataset

    dataset = load_dataset(args.dataset)
    summary = breakaway.summarise([breakaway.breakaway_of(tr) for tr in dataset.trials])
    print(breakaway.to_markdown(summary), end="")
    if args.json:
        outfolder.write_texts(args.json.parent, {args.json.name: json.dumps(summary, indent=2)})
    return 0


def _run_predict(args) -> int:
    from admittance.thesis import predict
    from admittance.formats.dataset import load_dataset

    if args.thesis_k is not None and not (math.isfinite(args.thesis_k) and args.thesis_k > 0):
        from admittance.errors import ConfigError

        raise ConfigError(f"--thesis-k must be a finite number > 0, got {args.thesis_k}")
    if args.out:
        from admittance.extras import require

        require("matplotlib", "predict --out")
        outfolder.check(args.out, args.force, "--out", PREDICT_FILES)
    dataset = load_dataset(args.dataset)
    predictions = predict.predict_dataset(dataset, args.params, args.thesis_k, args.x0)
    print(predict.metrics_table(predictions), end="")
    if args.out:
        outfolder.clear(args.out, "--out", PREDICT_FILES)
        outfolder.write_texts(args.out, {"metrics.json": json.dumps(predict.metrics_dicts(predictions), indent=2)})
        for p in predictions:
            predict.plot_trial(p, args.out)
    return 0
