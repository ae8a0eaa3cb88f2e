"""``admittance fidelity RECORDING --json FILE.json [--params-out FILE.toml]`` (fidelity.md contract).

Registration stays import-light; NumPy and the Rust core load when the command runs. Bad input
(not a recording, no motion, no present positions...) is a ``DataError``: one line, exit 1.
"""

from __future__ import annotations

import argparse
import sys

# One rule for output paths and JSON (checked before the work; NaN written as null), shared with identify.
from admittance.ident.cli import _writable, _write_json


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "fidelity",
        help="what the joint really rendered, and the servo model that closes the gap",
        description="Measure the rendering error (present − model angle) of a recording, the admittance the "
        "horn really rendered against the one the loop ran, and identify the servo's tracking dynamics "
        "(docs/fidelity.md; the recording's format: admittance docs recordings).",
    )
    p.add_argument("recording", metavar="RECORDING",
                   help="a recording of `admittance run --record DIR`: the folder, or its session.mcap")
    p.add_argument("--json", dest="json_out", metavar="FILE.json", required=True, help="write the result here")
    p.add_argument("--params-out", metavar="FILE.toml",
                   help="also write the joint's plant with the servo model: a joint's `params` that compensates "
                   "(default: not written)")
    p.add_argument("--joint", type=int, metavar="ID", help="the joint to analyse (default: the first)")
    p.add_argument("--quiet", action="store_true", help="no summary on stderr")
    p.set_defaults(func=run_fidelity)


def run_fidelity(args: argparse.Namespace) -> int:
    from admittance.fidelity.recording import load_recording
    from admittance.fidelity.report import analyse, write_params

    json_path = _writable(args.json_out, "--json")
    params_path = _writable(args.params_out, "--params-out") if args.params_out else None
    recording = load_recording(args.recording)
    result = analyse(recording, args.joint)
    if params_path:
        write_params(params_path, recording, result, source=f"admittance fidelity {args.recording}")
    result.pop("_servo_fit")
    _write_json(json_path, result)
    if not args.quiet:
        print(summary(result), file=sys.stderr)
    return 0


def summary(r: dict) -> str:
    from admittance.fidelity.judge import verdict_line

    t, g, s = r["target"], r["rendered"], r["servo"]
    return (f"fidelity: joint {r['joint_id']}: rendering error {1e3 * r['rendering_rmse']:.2f} mrad RMS; rendered "
            f"I {g['virtual_inertia']:.4g} (target {t['virtual_inertia']:.4g}), B {g['virtual_damping']:.4g} "
            f"({t['virtual_damping']:.4g}), F {g['virtual_coulomb']:.4g} ({t['virtual_coulomb']:.4g}); servo: lag "
            f"{1e3 * s['time_constant']:.1f} ms, inertial {1e3 * s['inertial_time']:.1f} ms, dead time "
            f"{1e3 * s['dead_time']:.1f} ms, compliance {s['compliance']:.3g} rad/N·m, band "
            f"{1e3 * s['deadband']:.2f} mrad; held-out error {1e3 * s['rmse_heldout']:.2f} mrad "
            f"(following the goal exactly: {1e3 * s['baseline_heldout']['goal']:.2f}); servo model "
            f"{verdict_line(r['servo_verdict'])}; record → identify "
            f"{_check_word(r['target_check']['verdict'])}" + "".join(f"; note: {n}" for n in s["notes"]))


def _check_word(verdict: dict) -> str:
    if verdict["passed"] is None:
        return "not checked (" + verdict["reasons"][0] + ")"
    return "passes" if verdict["passed"] else "FAILS: " + "; ".join(verdict["reasons"])
