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
import tempfile
from pathlib import Path

from admittance import outfolder

PREDICT_FILES = ("metrics.json", "*.png")


def register(subparsers) -> None:
    _register_thesis(subparsers)
    _register_breakaway(subparsers)
    _register_predict(subparsers)
    _register_ladder(subparsers)
    _register_convert(subparsers)


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


def _register_ladder(subparsers) -> None:
    lad = subparsers.add_parser(
        "ladder", help="score chosen effect sets by cross-validation, with identify's verdict",
        description="Fit each rung (a set of effects) on identify's cross-validation folds (whole trials, or time "
                    "segments when there are few) and score it on the data left out, with identify's admission "
                    "verdict: for asking about effects identify did not try or did not admit.")
    lad.add_argument("dataset", type=Path, metavar="DATASET_DIR", help="dataset folder: manifest.toml and the trial files (format: admittance docs datasets)")
    lad.add_argument("--rung", action="append", required=True, metavar="EFFECTS",
                     help="comma-separated effect names ('' = the base model); repeat for each model")
    lad.add_argument("--start", action="append", default=[], metavar="NAME=VALUE",
                     help="starting value of an effect parameter in its unit, e.g. cogging_period=8 (repeatable; "
                     "default: the fit's own start)")
    lad.add_argument("--friction", choices=("stick", "tanh"), default="stick",
                     help="Coulomb law: exact stick-slip or the thesis's tanh (default stick)")
    lad.add_argument("--json", type=Path, metavar="FILE.json", help="also write the ladder as JSON (default: print only)")
    lad.add_argument("--params-dir", type=Path, metavar="DIR",
                     help="write each rung's parameters (Contract 2) into DIR (default: not written)")
    lad.set_defaults(func=_run_ladder)


def _register_convert(subparsers) -> None:
    conv = subparsers.add_parser(
        "convert", help="turn Motive / Dynamixel / DFKI recordings or a session.mcap into a dataset folder",
        description="Read recordings in a foreign format (Motive CSV, Dynamixel/BAM logs, DFKI CSV, a daemon's session.mcap) and write "
                    "a dataset folder (format: admittance docs datasets) that identify, thesis and predict read.")
    conv.add_argument("format", choices=("motive", "dynamixel", "dfki", "mcap"), help="the recordings' format")
    conv.add_argument("files", type=Path, nargs="+", metavar="FILE", help="the recordings, one trial each")
    conv.add_argument("--out", type=Path, required=True, metavar="DIR",
                      help="the dataset folder to write (new or empty unless --force)")
    conv.add_argument("--force", action="store_true", help="write into a non-empty DIR, replacing its manifest and CSVs")
    conv.add_argument("--motor", default="", metavar="LABEL", help="motor label for the manifest (default: none)")
    conv.add_argument("--rod", type=float, nargs=2, metavar=("MASS", "LENGTH"),
                      help="a uniform rod pivoted at one end (kg, m): geometry mode (default: none)")
    conv.add_argument("--bob", type=float, nargs=2, metavar=("MASS", "DISTANCE"),
                      help="a point bob (kg) at DISTANCE (m) from the axis: geometry mode (default: none)")
    conv.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                      help="a loader option, e.g. segment=all, axes=x,z, zero_tick=2048 (repeatable; default: none)")
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
    if args.out:
        from admittance.extras import require

        require("matplotlib", "predict --out")
        outfolder.check(args.out, args.force, "--out", PREDICT_FILES)
    dataset = load_dataset(args.dataset)
    predictions = predict.predict_dataset(dataset, args.params, args.thesis_k, args.x0)
    print(predict.metrics_table(predictions), end="")
    if args.out:
        outfolder.clear(args.out, "--out", PREDICT_FILES)
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

    if args.format == "mcap":  # a recording holds its own geometry and trials
        out = loaders.convert_recording(args.files, args.out)
        print(f"wrote {out}")
        return 0
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
    outfolder.check(args.out, args.force, "--out")
    with tempfile.TemporaryDirectory(dir=_existing_parent(args.out)) as tmp:  # a bad input leaves DIR as it was
        loaders.convert_files(args.files, args.format, tmp, header=header, extra=extra, **options)
        out = outfolder.clear(args.out, "--out")
        for path in Path(tmp).iterdir():
            path.replace(out / path.name)
    print(f"wrote {len(args.files)} trial(s) to {out}")
    return 0


def _existing_parent(path: Path) -> Path:
    """The nearest existing folder above ``path`` (a temporary folder there renames into it)."""
    for parent in Path(path).resolve().parents:
        if parent.is_dir():
            return parent
    return Path.cwd()


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
