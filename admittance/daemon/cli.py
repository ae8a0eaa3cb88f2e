"""``admittance run | monitor | set | tare``: the daemon and its remote tools (Contract 6).

Registration stays import-light: zenoh, NumPy and the Rust extension are imported inside the
handlers, so ``admittance --help`` is instant and a configuration error is reported before any
of them loads.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from admittance.errors import AdmittanceError, ConfigError

DEFAULT_PREFIX = "bench/arm1"
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


def register(subparsers) -> None:
    run = subparsers.add_parser(
        "run", help="run the admittance daemon (default: the simulated bench)",
        description="Run the admittance loop. Without --config: the embedded simulated bench "
                    "(a mock MX-64 and a scripted hand on pseudo-terminals). Stops on SIGINT/SIGTERM "
                    "or after --duration, holding position, then applying [stop].torque_policy.")
    run.add_argument("--config", type=Path, help="daemon configuration (TOML, see docs/daemon.md)")
    run.add_argument("--duration", type=_positive, metavar="S", help="stop after S seconds")
    run.add_argument("--stats-json", type=Path, metavar="FILE", help="write the loop's statistics on exit")
    run.add_argument("--record", metavar="DIR", help="record the session as a dataset for `admittance identify`")
    run.add_argument("--check", action="store_true", help="validate the configuration, print it and exit")
    run.set_defaults(func=cmd_run)

    monitor = subparsers.add_parser("monitor", help="live view of a running daemon's state and timing")
    _remote_args(monitor)
    monitor.add_argument("--duration", type=_positive, metavar="S", help="stop after S seconds")
    monitor.set_defaults(func=cmd_monitor)

    setp = subparsers.add_parser(
        "set", help="change parameters of a running daemon (all or nothing)",
        description="Set live parameters, e.g. `admittance set virtual_damping=0.08 1.virtual_inertia=0.03`. "
                    "A bare name applies to every joint, <id>.name to one joint.")
    setp.add_argument("assignments", nargs="+", metavar="NAME=VALUE")
    _remote_args(setp)
    setp.add_argument("--timeout", type=_positive, default=3.0, metavar="S", help="wait this long for a reply")
    setp.set_defaults(func=cmd_set)

    tare = subparsers.add_parser(
        "tare", help="re-zero a running daemon's force sensor (let go of the handle first)",
        description="The loop averages the next N force samples into its bias; a hand on the "
                    "handle during those samples becomes part of the zero.")
    tare.add_argument("--samples", type=int, default=100, metavar="N", help="samples to average (default 100)")
    _remote_args(tare)
    tare.add_argument("--timeout", type=_positive, default=3.0, metavar="S", help="wait this long for a reply")
    tare.set_defaults(func=cmd_tare)


def _remote_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--prefix", default=DEFAULT_PREFIX, help=f"the daemon's key prefix (default {DEFAULT_PREFIX})")
    parser.add_argument("--connect", action="append", metavar="ENDPOINT",
                        help=f"zenoh endpoint of the daemon (default {DEFAULT_ENDPOINT}; repeatable)")


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got {text!r}") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return value


def cmd_run(args: argparse.Namespace) -> int:
    import signal

    from admittance.daemon.stopsignals import StopRequest, stop_signals_call

    stop = StopRequest()
    # After a run the process only exits; a late stop signal (a second SIGTERM during teardown)
    # must not cut that exit short and turn a clean stop into -15. `--check` leaves them be.
    after = None if args.check else signal.SIG_IGN
    with stop_signals_call(lambda *_: stop.set(), then=after):
        return _run(args, stop)


def _run(args: argparse.Namespace, stop: Any) -> int:
    from admittance.daemon import config

    try:
        cfg = config.load_config(args.config) if args.config else config.load_default()
        cfg = config.with_overrides(cfg, record=args.record)
    except ConfigError as exc:
        _stats_of_a_failed_start(args, exc)
        raise
    if args.check:
        print(config.summary(cfg))
        return 0
    from admittance.daemon.backends import real_backends
    from admittance.daemon.supervisor import RunOptions, Supervisor

    options = RunOptions(duration=args.duration, stats_json=args.stats_json, stop=stop)
    return Supervisor(cfg, real_backends(), options).run()


def _stats_of_a_failed_start(args: argparse.Namespace, error: ConfigError) -> None:
    """--stats-json on every exit path: a configuration that did not load leaves its error."""
    if args.stats_json is None or args.check:
        return
    from admittance.daemon.supervisor import error_fields, write_stats_file

    try:
        write_stats_file(args.stats_json, error_fields(error))
    except AdmittanceError as exc:
        print(f"admittance run: warning: {exc}", file=sys.stderr)


def cmd_monitor(args: argparse.Namespace) -> int:
    from admittance.daemon.monitor import View, run_monitor
    from admittance.daemon.zenoh_iface import Client

    with Client(args.connect or [DEFAULT_ENDPOINT]) as client:
        subscription = client.try_stream(args.prefix)
        try:
            view = View(args.prefix, sys.stdout, sys.stdout.isatty())
            return run_monitor(subscription, view, args.duration)
        finally:
            subscription.close()


def parse_assignments(items: list[str]) -> dict[str, float | list[float]]:
    """``NAME=VALUE`` pairs; a comma list (``bias=0,0,0,0,0,0``) becomes a list of numbers."""
    out: dict[str, float | list[float]] = {}
    for item in items:
        name, sep, text = item.partition("=")
        if not sep or not name.strip():
            raise ConfigError(f"{item!r}: expected NAME=VALUE")
        try:
            values = [float(v) for v in text.split(",")]
        except ValueError:
            raise ConfigError(f"{name}: expected a number, got {text!r}") from None
        out[name.strip()] = values if len(values) > 1 else values[0]
    return out


def cmd_set(args: argparse.Namespace) -> int:
    return _remote_request(args, "params", parse_assignments(args.assignments))


def cmd_tare(args: argparse.Namespace) -> int:
    return _remote_request(args, "tare", {"samples": args.samples})


def _remote_request(args: argparse.Namespace, leaf: str, request: dict) -> int:
    """Send one request to ``<prefix>/<leaf>``, print the reply; 1 when the daemon rejects it."""
    from admittance.daemon.zenoh_iface import Client

    with Client(args.connect or [DEFAULT_ENDPOINT]) as client:
        reply = client.query(f"{args.prefix}/{leaf}", request, timeout=args.timeout)
    print(json.dumps(reply))
    if not reply.get("accepted", False):
        print(f"admittance {args.command}: rejected: {reply.get('reason', 'no reason given')}", file=sys.stderr)
        return 1
    return 0
