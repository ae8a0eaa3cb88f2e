"""Subcommands beside identify: ``admittance ladder`` and ``admittance convert`` (Contract 6).

- ``admittance ladder DATASET_DIR --rung EFFECTS ...``: chosen effect sets scored by
  cross-validation (identify's folds and admission tests), each added effect with its verdict.
- ``admittance convert FORMAT FILE... --out DIR``: recordings in a foreign format (Motive,
  Dynamixel/BAM, DFKI) or a session.mcap to a contract dataset folder (``admittance.formats``).

The thesis's procedures (``thesis``, ``breakaway``, ``predict``) are ``admittance.thesis.cli``.
Registration imports nothing heavy: SciPy, matplotlib and the Rust core load in the handlers.
"""

from __future__ import annotations

import json
import math
import tempfile
from pathlib import Path

from admittance import outfolder

def register(subparsers) -> None:
    _register_ladder(subparsers)
    _register_convert(subparsers)


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


def _run_ladder(args) -> int:
    from dataclasses import asdict

    from admittance.ident import ladder
    from admittance.formats.dataset import load_dataset

    dataset = load_dataset(args.dataset)
    rungs = [tuple(e.strip() for e in rung.split(",") if e.strip()) for rung in args.rung]
    start = dict(_parse_start(item) for item in args.start)
    result = ladder.effect_ladder(dataset, rungs, args.friction, start)
    print(ladder.to_markdown(result), end="")
    if args.json:
        outfolder.write_texts(args.json.parent, {args.json.name: json.dumps([asdict(r) for r in result], indent=2)})
    if args.params_dir:
        ladder.write_params(result, dataset, args.params_dir, args.friction)
    return 0


def _run_convert(args) -> int:
    from admittance.formats import converters

    if args.format == "mcap":  # a recording holds its own geometry and trials
        from admittance.formats.recording import convert_recording

        out = convert_recording(args.files, args.out)
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
        converters.convert_files(args.files, args.format, tmp, header=header, extra=extra, **options)
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
