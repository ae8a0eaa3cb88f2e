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
}


def page(topic: str) -> str:
    return data.path("docs", f"{topic}.md").read_text(encoding="utf-8")


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "docs", help="print a format's documentation (datasets, recordings)",
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
