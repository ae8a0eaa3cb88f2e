"""``admittance docs TOPIC``: the format pages that ship inside the package.

The data formats a lab must write or read (datasets, recordings) are documented in
``admittance/data/docs/*.md`` (the repository's docs/ links to the same files), so a wheel
installed anywhere explains itself without a checkout or anything outside it.
"""

from __future__ import annotations

import argparse
import sys

from admittance import data

TOPICS = {
    "datasets": "the dataset folder identify/thesis/predict/ladder read: manifest keys, CSV columns, formats",
    "recordings": "what run --record writes: the CSV columns, the manifest, session.mcap's channels",
    "servo": "a parameter file's [servo] table: every key, its unit, domain and default",
}


def page(topic: str) -> str:
    return data.path("docs", f"{topic}.md").read_text(encoding="utf-8")


def servo_page() -> str:
    """The ``[servo]`` page, from the declaration that validates the keys (``paramfile.SERVO_KEYS``):
    the shipped servo.md is this text (tests/test_docs_formats.py), so a key declared without its
    line on the page fails there."""
    from admittance.formats.paramfile import SERVO_KEYS

    rows = [f"| `{name}` | {key.unit} | {'(' if name == 'time_constant' else '['}{key.bounds[0]:g}, {key.bounds[1]:g}] | "
            f"{'required' if key.default is None else f'{key.default:g}'} | {key.meaning} |"
            for name, key in SERVO_KEYS.items()]
    return "\n".join([
        "# The [servo] table of a parameter file (`admittance docs servo`)",
        "",
        "The servo's tracking dynamics that `admittance fidelity --params-out` writes and the loop's",
        "compensation inverts (docs/fidelity.md in the repository):",
        "",
        "    m·θ'' + θ' = (goal(t − dead_time) + compliance·τ − θ − deadband·sgn θ') / time_constant",
        "",
        "θ is the motor side in horn radians; the horn is within ±backlash/2 of it, held against the",
        "side the hand pushes to when |τ| > backlash_torque. A value outside its domain, a key not",
        "listed, or a required key missing is refused with the file and the key.",
        "",
        "| key | unit | domain | default | meaning |",
        "|---|---|---|---|---|",
        *rows, ""])


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "docs", help="print a format's documentation (datasets, recordings, servo)",
        description="Print a page of the documentation shipped inside the package.",
        epilog="\n".join(f"  {name:11} {text}" for name, text in TOPICS.items()),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("topic", choices=sorted(TOPICS), metavar="TOPIC", help="one of: " + ", ".join(TOPICS))
    parser.add_argument("--path", action="store_true", help="print where the page is instead of its text")
    parser.set_defaults(func=_command)


def _command(args: argparse.Namespace) -> int:
    if args.path:
        print(data.path("docs", f"{args.topic}.md"))
    else:
        sys.stdout.write(page(args.topic))
    return 0
