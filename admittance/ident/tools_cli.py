"""Subcommands for the thesis's procedures and data conversion (Contract 6).

- ``admittance thesis DATASET_DIR [--out DIR]``: the thesis's per-trial alternating fit,
  printed as tables 3.2–3.4 (Markdown) and written as Markdown + CSV with ``--out``.
- ``admittance breakaway DATASET_DIR [--json OUT]``: breakaway torque of force-ramp trials
  (table 3.1).
- ``admittance predict DATASET_DIR --params FILE.toml [--out DIR]``: section 3.3's testing of
  fitted parameters against measured torque, with appendix-B-style plots.
- ``admittance ladder DATASET_DIR --rung EFFECTS ...``: chosen effect sets scored by
  cross-validation (identify's folds and admission tests), each added effect with its verdict.
- ``admittance convert FORMAT FILE... --out DIR``: recordings in a foreign format (Motive,
  Dynamixel/BAM, DFKI) to a contract dataset folder.

Registration imports nothing heavy: SciPy, matplotlib and the Rust core load in the handlers.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path


def register(subparsers) -> None:
    _register_thesis(subparsers)
    _register_breakaway(subparsers)
    _register_predict(subparsers)
    _register_ladder(subparsers)
    _register_convert(subparsers)


def _register_thesis(subparsers) -> None:
    thesis = subparsers.add_parser("thesis",
                                   help="reproduce the thesis's per-trial alternating LM fit (tables 3.2-3.4)")
    thesis.add_argument("dataset", type=Path, metavar="DATASET_DIR")
    thesis.add_argument("--out", type=Path, help="write thesis_table.md and thesis_table.csv here")
    thesis.add_argument("--cycles", type=int, default=5, help="(I,B)/F alternations (default 5, as appendix C.3)")
    thesis.add_argument("--initial-friction", type=float, help="initial F in N·m (default: table 3.1 for the motor)")
    thesis.add_argument("--initial-inertia", type=float, default=0.0385,
                        help="initial total inertia in kg·m² (default 0.0385, appendix C.3)")
    thesis.add_argument("--initial-damping", type=float, default=0.0286,
                        help="initial damping in N·m·s/rad (default 0.0286, appendix C.3)")
    thesis.add_argument("--x0", choices=("rest", "data"), default="rest",
                        help="initial state: first angle at rest (the thesis) or velocity from the data")
    thesis.set_defaults(func=_run_thesis)


def _register_breakaway(subparsers) -> None:
    brk = subparsers.add_parser("breakaway", help="breakaway friction torque of slow force-ramp trials (table 3.1)")
    brk.add_argument("dataset", type=Path, metavar="DATASET_DIR")
    brk.add_argument("--json", type=Path, metavar="OUT", help="write the results as JSON")
    brk.set_defaults(func=_run_breakaway)


def _register_predict(subparsers) -> None:
    pred = subparsers.add_parser(
        "predict", help="test fitted parameters on recorded trials: predicted position, calculated torque (thesis 3.3)")
    pred.add_argument("dataset", type=Path, metavar="DATASET_DIR")
    pred.add_argument("--params", type=Path, required=True, metavar="FILE.toml", help="a Contract 2 parameter file")
    pred.add_argument("--out", type=Path, help="write metrics.json and the appendix-B plots here")
    pred.add_argument("--thesis-k", type=float,
                      help="k of the thesis formula's tanh(k*vel) (default: the file's tanh_k; appendix C.4 used 1)")
    pred.add_argument("--x0", choices=("fit", "data"), default="fit",
                      help="initial state: fitted to the trial (as identify scores) or from its first 50 ms")
    pred.set_defaults(func=_run_predict)


def _register_ladder(subparsers) -> None:
    lad = subparsers.add_parser("ladder", help="score chosen effect sets by cross-validation, with identify's verdict")
    lad.add_argument("dataset", type=Path, metavar="DATASET_DIR")
    lad.add_argument("--rung", action="append", required=True, metavar="EFFECTS",
                     help="comma-separated effect names ('' = the base model); repeat for each model")
    lad.add_argument("--start", action="append", default=[], metavar="NAME=VALUE",
                     help="starting value of an effect parameter, e.g. cogging_period=8 (repeatable)")
    lad.add_argument("--friction", choices=("stick", "tanh"), default="stick")
    lad.add_argument("--json", type=Path, metavar="OUT", help="write the ladder as JSON")
    lad.add_argument("--params-dir", type=Path, metavar="DIR", help="write each rung's parameters (Contract 2) here")
    lad.set_defaults(func=_run_ladder)


def _register_convert(subparsers) -> None:
    conv = subparsers.add_parser("convert", help="turn Motive / Dynamixel / DFKI recordings into a dataset folder")
    conv.add_argument("format", choices=("motive", "dynamixel", "dfki"))
    conv.add_argument("files", type=Path, nargs="+", metavar="FILE")
    conv.add_argument("--out", type=Path, required=True, help="the dataset folder to write")
    conv.add_argument("--motor", default="", help="motor label for the manifest")
    conv.add_argument("--rod", type=float, nargs=2, metavar=("MASS", "LENGTH"),
                      help="a uniform rod pivoted at one end (kg, m): geometry mode")
    conv.add_argument("--bob", type=float, nargs=2, metavar=("MASS", "DISTANCE"),
                      help="a point bob (kg) at DISTANCE (m) from the axis: geometry mode")
    conv.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                      help="a loader option, e.g. segment=all, axes=x,z, zero_tick=2048 (repeatable)")
    conv.set_defaults(func=_run_convert)


def _run_thesis(args) -> int:
    from admittance.ident import thesis
    from admittance.ident.dataset import load_dataset

    _check_thesis_options(args)
    dataset = load_dataset(args.dataset)
    progress = (lambda line: print(line, file=sys.stderr)) if sys.stderr.isatty() else None
    rows = thesis.fit_dataset(dataset, cycles=args.cycles, x0=args.x0, initial_friction=args.initial_friction,
                              initial_inertia=args.initial_inertia, initial_damping=args.initial_damping,
                              progress=progress)
    markdown = thesis.to_markdown(rows, f"Thesis-method fit: {dataset.motor or args.dataset.name}")
    print(markdown, end="")
    if args.out:
        _write(args.out, {"thesis_table.md": markdown, "thesis_table.csv": thesis.to_csv(rows)})
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
    from admittance.ident import breakaway
    from admittance.ident.dataset import load_dataset

    dataset = load_dataset(args.dataset)
    summary = breakaway.summarise([breakaway.breakaway_of(tr) for tr in dataset.trials])
    print(breakaway.to_markdown(summary), end="")
    if args.json:
        _write(args.json.parent, {args.json.name: json.dumps(summary, indent=2)})
    return 0


def _run_predict(args) -> int:
    from admittance.ident import predict
    from admittance.ident.dataset import load_dataset

    if args.thesis_k is not None and not (math.isfinite(args.thesis_k) and args.thesis_k > 0):
        from admittance.errors import ConfigError

        raise ConfigError(f"--thesis-k must be a finite number > 0, got {args.thesis_k}")
    dataset = load_dataset(args.dataset)
    predictions = predict.predict_dataset(dataset, args.params, args.thesis_k, args.x0)
    print(predict.metrics_table(predictions), end="")
    if args.out:
        _write(args.out, {"metrics.json": json.dumps(predict.metrics_dicts(predictions), indent=2)})
        for p in predictions:
            predict.plot_trial(p, args.out)
    return 0


def _run_ladder(args) -> int:
    from dataclasses import asdict

    from admittance.ident import ladder
    from admittance.ident.dataset import load_dataset

    dataset = load_dataset(args.dataset)
    rungs = [tuple(e.strip() for e in rung.split(",") if e.strip()) for rung in args.rung]
    start = dict(_parse_start(item) for item in args.start)
    result = ladder.effect_ladder(dataset, rungs, args.friction, start)
    print(ladder.to_markdown(result), end="")
    if args.json:
        _write(args.json.parent, {args.json.name: json.dumps([asdict(r) for r in result], indent=2)})
    if args.params_dir:
        ladder.write_params(result, dataset, args.params_dir, args.friction)
    return 0


def _run_convert(args) -> int:
    from admittance.ident import loaders

    options = dict(_parse_option(item) for item in args.option)
    header: dict = {"motor": args.motor} if args.motor else {}
    extra = {}
    for option, values in (("--rod", args.rod), ("--bob", args.bob)):
        if values and not all(math.isfinite(v) and v > 0 for v in values):
            from admittance.errors import ConfigError

            raise ConfigError(f"{option} takes two positive finite numbers, got {' '.join(map(str, values))}")
    if args.rod:
        header["rod"] = {"mass": args.rod[0], "length": args.rod[1]}
    if args.bob:
        header["bob"] = {"mass": args.bob[0]}
        extra["bob_distance"] = args.bob[1]
    out = loaders.convert_files(args.files, args.format, args.out, header=header, extra=extra, **options)
    print(f"wrote {len(args.files)} trial(s) to {out}")
    return 0


def _parse_start(item: str) -> tuple[str, float]:
    """``NAME=NUMBER`` of ``ladder --start``."""
    from admittance.errors import ConfigError

    key, value = _parse_option(item, "--start")
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"--start {item!r}: expected NAME=NUMBER, e.g. cogging_period=8")
    return key, float(value)


def _parse_option(item: str, option: str = "--option") -> tuple[str, object]:
    """``KEY=VALUE``: a number, a comma list (``axes=x,z``), or a string."""
    from admittance.errors import ConfigError

    key, sep, value = item.partition("=")
    if not sep or not key.strip():
        raise ConfigError(f"{option} {item!r}: expected KEY=VALUE")
    if "," in value:
        return key.strip(), [_number_or_text(v) for v in value.split(",")]
    return key.strip(), _number_or_text(value)


def _number_or_text(text: str):
    text = text.strip()
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def _write(folder: Path, files: dict[str, str]) -> None:
    from admittance.errors import ConfigError

    try:
        folder.mkdir(parents=True, exist_ok=True)
        for name, text in files.items():
            (folder / name).write_text(text)
    except OSError as exc:
        raise ConfigError(f"{folder}: cannot write ({exc.strerror})") from None
