"""The ``admittance`` command line.

Each area owns its subcommands in its own ``cli`` module, which exposes
``register(subparsers)``; registration must stay cheap (heavy imports such as SciPy or Zenoh
happen inside the command handlers), so ``admittance --help`` is instant.
"""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys

from admittance import __version__
from admittance.errors import AdmittanceError
from admittance import logs
from admittance.logs import report_error

# Modules that register subcommands, in the order they appear in --help.
SUBCOMMAND_MODULES = (
    "admittance.daemon.cli",  # run, monitor, set, tare
    "admittance.mockbench.cli",  # mock-bench
    "admittance.bringup.cli",  # setup
    "admittance.ident.cli",  # identify, synth
    "admittance.thesis.cli",  # thesis, breakaway, predict
    "admittance.ident.tools_cli",  # ladder, convert
    "admittance.drops.cli",  # drops
    "admittance.fidelity.cli",  # fidelity
    "admittance.service",  # service install
    "admittance.docs",  # docs TOPIC
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="admittance",
        description="Real-time admittance control for Dynamixel servos, and its system identification.",
    )
    parser.add_argument("--version", action="version", version=f"admittance {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in SUBCOMMAND_MODULES:
        importlib.import_module(name).register(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return _run(args)
    finally:
        logs.reset()  # the next in-process command starts without this one's log handler


def _run(args) -> int:
    try:
        return int(args.func(args) or 0)
    except AdmittanceError as exc:
        report_error(args.command, str(exc))
        return exc.exit_code
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:  # stdout closed by the reader (`| head`): stop quietly, as `cat` does
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at exit
        return 128 + signal.SIGPIPE


if __name__ == "__main__":
    raise SystemExit(main())
