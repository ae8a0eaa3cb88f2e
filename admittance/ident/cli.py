"""``admittance identify`` and ``admittance synth`` (Contract 6).

Registration stays import-light (NumPy and the Rust core load only when a command runs), so
``admittance --help`` is instant. Errors a user can cause (a bad dataset, a bad option value)
are raised as ``DataError``/``ConfigError`` and printed as one line by ``admittance.cli``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from admittance import outfolder
from admittance.errors import ConfigError, DataError

LUMPED_BOB_DISTANCE = 0.30  # m: the one load of a `synth --lumped` dataset
REPORT_FILES = ("report.md", "report.html", "*.png")


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "identify",
        help="fit I, B, F and the effects the data supports from a pendulum dataset",
        description="Fit the base model by output error, add the effects held-back trials confirm, "
        "and report the simulation error on held-out trials (format: admittance docs datasets).",
    )
    p.add_argument("dataset", metavar="DATASET_DIR", help="folder with manifest.toml and the trial files")
    p.add_argument("--json", dest="json_out", metavar="FILE.json",
                   help="write the result here (default: not written; --report or --params-out alone are enough)")
    p.add_argument("--params-out", metavar="FILE.toml",
                   help="also write the final model as a parameter file (default: not written)")
    p.add_argument("--report", metavar="DIR", help="write a report into DIR: report.html (self-contained, "
                   "figures embedded: open it in a browser) and report.md with its PNG figures "
                   "(new or empty unless --force; default: no report; needs admittance[plots])")
    p.add_argument("--force", action="store_true", help="write the report into a non-empty DIR, replacing its "
                   "report.html, report.md and figures")
    p.add_argument("--friction", choices=("stick", "tanh"), default="stick",
                   help="Coulomb law: exact stick-slip (default) or the thesis's tanh")
    p.add_argument("--max-effects", type=int, default=4, metavar="N", help="add at most N effects (default 4)")
    p.add_argument("--min-gain", type=float, default=0.03, metavar="FRACTION",
                   help="relative validation improvement an effect must bring, as a fraction (default 0.03)")
    p.add_argument("--quiet", action="store_true", help="no progress line on stderr")
    p.set_defaults(func=run_identify)

    s = subparsers.add_parser(
        "synth",
        help="write a synthetic pendulum dataset (known truth, optional hidden effects)",
        description="Thesis-like MX-64 pendulum drops in the dataset format, with undeclared effects.",
    )
    s.add_argument("out_dir", metavar="DIR", help="the dataset folder to write (new or empty unless --force)")
    s.add_argument("--effect", action="append", metavar="NAME=VALUE",
                   help="inject an effect (e.g. stribeck=0.04, cogging=0.01) or set a parameter, in its unit; "
                   "repeatable (default: none)")
    s.add_argument("--trials", type=int, default=10, metavar="N", help="number of drops (default 10)")
    s.add_argument("--duration", type=float, default=8.0, metavar="S", help="length of each drop in s (default 8)")
    s.add_argument("--noise", type=float, default=0.002, metavar="RAD", help="angle noise σ in rad (default 0.002)")
    s.add_argument("--noise-corr", type=float, default=0.0, metavar="RHO",
                   help="AR(1) correlation of the noise between samples, dimensionless (default 0: white)")
    s.add_argument("--jitter", type=float, default=0.1, metavar="FRACTION",
                   help="sampling-time jitter as a fraction of the period (default 0.1)")
    s.add_argument("--seed", type=int, default=0, metavar="N", help="random seed (default 0)")
    s.add_argument("--force", action="store_true", help="write into a non-empty DIR, replacing its manifest and CSVs")
    s.add_argument("--with-torque", action="store_true", help="torque-driven trials with a tau column")
    s.add_argument("--ramps", action="store_true",
                   help="slow torque ramps from rest (a tau column), the breakaway test: try them with "
                        "admittance breakaway DIR")
    s.add_argument("--lumped", action="store_true",
                   help="leave the geometry out of the manifest (all trials then share one load)")
    s.set_defaults(func=run_synth)


def run_identify(args: argparse.Namespace) -> int:
    from admittance.formats.dataset import load_dataset
    from admittance.ident.identify import IdentifySettings, identify_dataset

    if args.max_effects < 0:
        raise ConfigError(f"--max-effects must be >= 0, got {args.max_effects}")
    if not (0.0 <= args.min_gain < 1.0):
        raise ConfigError(f"--min-gain must be in [0, 1), got {args.min_gain}")
    json_path = _writable(args.json_out, "--json") if args.json_out else None
    params_path = _writable(args.params_out, "--params-out") if args.params_out else None
    if args.report and Path(args.report).exists() and not Path(args.report).is_dir():
        raise DataError(f"--report {args.report}: exists and is not a folder")
    if args.report:
        from admittance.extras import require

        require("matplotlib", "identify --report")  # before the fit, not after it
        outfolder.check(args.report, args.force, "--report", REPORT_FILES)
    dataset = load_dataset(args.dataset)
    settings = IdentifySettings(friction=args.friction, max_effects=args.max_effects, min_gain=args.min_gain,
                                quiet=args.quiet)
    result = identify_dataset(dataset, settings)
    if json_path:
        _write_json(json_path, result.to_json())
    if params_path:
        result.write_params(params_path,
                            source=f"admittance identify {args.dataset} --friction {args.friction}")
    if args.report:
        from admittance.ident.report import write_report

        write_report(result, outfolder.clear(args.report, "--report", REPORT_FILES))
    if not args.quiet:
        _print_summary(result)
    return 0


def run_synth(args: argparse.Namespace) -> int:
    from admittance.ident.synthetic import SynthSpec, generate, parse_effect_args

    if args.trials < 1:
        raise ConfigError(f"--trials must be >= 1, got {args.trials}")
    if args.ramps and args.with_torque:
        raise ConfigError("--ramps and --with-torque are two kinds of torque: choose one")
    if not (0.0 < args.duration < math.inf) or not (0.0 <= args.noise < math.inf):
        raise ConfigError(f"--duration must be finite and > 0 and --noise finite and >= 0, "
                          f"got {args.duration} and {args.noise}")
    if not (0.0 <= args.noise_corr < 1.0) or not (0.0 <= args.jitter < math.inf):
        raise ConfigError(f"--noise-corr must be in [0, 1) and --jitter finite and >= 0, "
                          f"got {args.noise_corr} and {args.jitter}")
    # A lumped fit has one gravity-to-inertia ratio for all trials, so they must share one load.
    loads = {"distances": (LUMPED_BOB_DISTANCE,)} if args.lumped else {}
    spec = SynthSpec(n_trials=args.trials, duration=args.duration, noise=args.noise,
                     noise_correlation=args.noise_corr, jitter=args.jitter,
                     effects=parse_effect_args(args.effect), with_torque=args.with_torque, ramps=args.ramps,
                     geometry=not args.lumped, seed=args.seed, **loads)
    outfolder.check(args.out_dir, args.force, "synth")
    out = generate(outfolder.clear(args.out_dir, "synth"), spec)
    print(f"wrote {args.trials} trials to {out}")
    return 0


def _writable(path: str, option: str) -> Path:
    """Checked before the fit, so a typo in an output path does not cost a whole run."""
    p = Path(path)
    if p.is_dir():
        raise DataError(f"{option} {path}: is a folder, expected a file name")
    if not p.parent.is_dir():
        raise DataError(f"{option} {path}: folder {p.parent} does not exist")
    return p


def _write_json(path: Path, value) -> None:
    try:
        path.write_text(json.dumps(_finite(value), indent=2) + "\n")
    except OSError as exc:
        raise DataError(f"--json {path}: cannot write ({exc.strerror})") from None


def _finite(value):
    """JSON has no NaN/Infinity: write null instead, so strict parsers accept the file."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    return value


def summary_line(result) -> str:
    """The one line a run ends with: what is named, what is kept as a stand-in (in the model,
    not claimed), groups the data cannot tell apart, and trials the data checks dropped."""
    effects = ", ".join(result.effects) or "none"
    parts = [f"mode {result.mode}", f"effects: {effects}"]
    if result.stand_ins:
        parts.append(f"stand-ins: {', '.join(result.stand_ins)}")
    for group in result.search.groups() if result.search else []:
        parts.append(f"{' or '.join(group['effects'])} (one of them; {group['separate_by']})")
    if result.data_checks:
        parts.append(f"dropped: {', '.join(sorted({f.trial for f in result.data_checks}))}")
    return "; ".join(parts) + (f"; held-out RMSE {1e3 * result.before.rmse:.2f} → {1e3 * result.after.rmse:.2f} mrad "
                               f"({result.timings.get('total', 0.0):.1f} s)")


def _print_summary(result) -> None:
    print(summary_line(result), file=sys.stderr)
