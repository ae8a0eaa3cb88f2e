"""``admittance run | monitor | set | tare``: the daemon and its remote tools (Contract 6).

Registration stays import-light: zenoh, NumPy and the Rust extension are imported inside the
handlers, so ``admittance --help`` is instant and a configuration error is reported before any
of them loads.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path
from typing import Any

from admittance.errors import AdmittanceError, ConfigError, RefusedError
from admittance.logs import add_verbosity_args, configure

log = logging.getLogger(__name__)

DEFAULT_PREFIX = "bench/arm1"
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


def register(subparsers) -> None:
    run = subparsers.add_parser(
        "run", help="run the admittance daemon (default: the simulated bench)",
        description="Run the admittance loop. Without --config: the embedded simulated bench "
                    "(a mock MX-64 and a scripted hand on pseudo-terminals). Stops on SIGINT/SIGTERM "
                    "or after --duration, holding position, then applying [stop].torque_policy.")
    run.add_argument("--config", type=Path, metavar="FILE",
                     help="daemon configuration (TOML, see docs/daemon.md; default: the simulated bench)")
    run.add_argument("--duration", type=_positive, metavar="S",
                     help="stop after S seconds (default: run until SIGINT/SIGTERM)")
    run.add_argument("--stats-json", type=Path, metavar="FILE.json",
                     help="write the loop's statistics on exit (default: not written)")
    run.add_argument("--record", metavar="DIR",
                     help="record the session as a dataset for `admittance identify` (default: [record].path); "
                     "DIR must be new or empty unless --force")
    run.add_argument("--force", action="store_true",
                     help="record into a non-empty DIR, removing the trials and manifest already there")
    run.add_argument("--check", action="store_true", help="validate the configuration, print it and exit")
    run.add_argument("--print-example-config", action="store_true",
                     help="print the example configuration of a real bench and exit (start one with > my.toml)")
    add_verbosity_args(run)
    run.set_defaults(func=cmd_run)

    monitor = subparsers.add_parser(
        "monitor", help="live view of running daemons' state, timing and parameters",
        description="Subscribe to the state, stats and liveliness of every daemon under --prefix and show each "
                    "joint's state, the loop's mode, faults, timing and live virtual parameters, marking a daemon "
                    "gone (its liveliness token withdrawn) or stale (no state for 1 s); SI units unless "
                    "--degrees. Redraws in place on a terminal, plain lines otherwise.")
    _remote_args(monitor)
    monitor.add_argument("--degrees", action="store_true",
                         help="show every angle and angular rate in degrees (default: rad, rad/s; the rendering "
                              "error in mrad)")
    monitor.add_argument("--duration", type=_positive, metavar="S",
                         help="stop after S seconds (default: run until Ctrl-C)")
    monitor.set_defaults(func=cmd_monitor)

    setp = _request_command(
        subparsers, "set", cmd_set, help="change parameters of a running daemon (all or nothing)",
        description="Set live parameters, e.g. `admittance set virtual_damping=0.08 1.virtual_inertia=0.03`. "
                    "A bare name applies to every joint, <id>.name to one joint. Prints what changed "
                    "(old → new, and how it arrives) or why it was refused; exit 1 when refused.")
    setp.add_argument("assignments", nargs="+", metavar="NAME=VALUE",
                      help="a live key (docs/daemon.md) and its value in the key's unit; <id>.NAME for one joint")

    tare = _request_command(
        subparsers, "tare", cmd_tare, help="re-zero a running daemon's force sensor (let go of the handle first)",
        description="The loop averages the next N force samples into its bias; a hand on the "
                    "handle during those samples becomes part of the zero.")
    tare.add_argument("--samples", type=int, default=100, metavar="N", help="samples to average (default 100)")

    get = _request_command(
        subparsers, "get", cmd_get, help="read a running daemon's live parameters",
        description="Print the live parameters of the daemon at --prefix (all, or the NAMEs given): name, "
                    "value and unit, or a JSON object with --json.")
    get.add_argument("names", nargs="*", metavar="NAME", help="parameters to print, e.g. 1.virtual_damping (default: all)")

    router = subparsers.add_parser(
        "router", help="a Zenoh router for several benches (daemons in client mode connect to it)",
        description="Open a router-mode Zenoh session and serve until SIGINT/SIGTERM. Its [zenoh] table "
                    "(--zenoh-config) gives listen endpoints, authentication, TLS and the ACL (docs/lab-network.md).")
    router.add_argument("--listen", action="append", metavar="ENDPOINT",
                        help=f"endpoint to listen on (default: the file's listen, else {DEFAULT_ENDPOINT}; repeatable)")
    router.add_argument("--zenoh-config", type=Path, metavar="FILE", help="a TOML file with a [zenoh] table (default: none)")
    router.add_argument("--duration", type=_positive, metavar="S", help="stop after S seconds (default: run until SIGINT/SIGTERM)")
    add_verbosity_args(router)
    router.set_defaults(func=cmd_router)


def _request_command(subparsers, name: str, func, **texts) -> argparse.ArgumentParser:
    """A remote tool that sends one request and waits for its reply."""
    parser = subparsers.add_parser(name, **texts)
    _remote_args(parser)
    parser.add_argument("--timeout", type=_positive, default=3.0, metavar="S", help="wait this long for a reply, in s (default 3)")
    parser.add_argument("--json", action="store_true", dest="as_json",
                        help="print the daemon's reply as JSON, for scripts (default: in words)")
    parser.set_defaults(func=func)
    return parser


def _remote_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--prefix", default=DEFAULT_PREFIX, metavar="PREFIX",
                        help=f"the daemon's key prefix (default {DEFAULT_PREFIX})")
    parser.add_argument("--connect", action="append", metavar="ENDPOINT",
                        help=f"zenoh endpoint of the daemon or router (default {DEFAULT_ENDPOINT}; repeatable)")
    parser.add_argument("--zenoh-config", type=Path, metavar="FILE",
                        help="a TOML file whose [zenoh] table gives this session's login, TLS files and "
                             "connect endpoints (default: none: no login, --connect or loopback; docs/zenoh.md)")


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

    configure("run", args.verbosity)
    stop = StopRequest()
    # After a run the process only exits; a late stop signal (a second SIGTERM during teardown)
    # must not cut that exit short and turn a clean stop into -15. `--check` and
    # `--print-example-config` run nothing and leave them be.
    after = None if args.check or args.print_example_config else signal.SIG_IGN
    with stop_signals_call(lambda signum, _frame: stop.set(signum), then=after):
        return _run(args, stop)


def _run(args: argparse.Namespace, stop: Any) -> int:
    from admittance.daemon import config

    if args.print_example_config:
        from admittance import data

        print(data.example_config().read_text(), end="")
        return 0

    try:
        cfg = config.load_config(args.config) if args.config else config.load_default()
        cfg = config.with_overrides(cfg, record=args.record)
    except ConfigError as exc:
        _stats_of_a_failed_start(args, exc)
        raise
    if args.check:
        print(config.summary(cfg))
        return 0
    if args.record:  # a CLI folder, checked here; [record].path of a service may grow across restarts
        from admittance import outfolder

        outfolder.check(args.record, args.force, "--record")
        outfolder.clear(args.record, "--record")
    from admittance.daemon.backends import real_backends
    from admittance.daemon.interpreter import settle_for_the_reader
    from admittance.daemon.supervisor import RunOptions, Supervisor

    options = RunOptions(duration=args.duration, stats_json=args.stats_json, stop=stop,
                         before_loop=settle_for_the_reader)
    return Supervisor(cfg, real_backends(), options).run()


def _stats_of_a_failed_start(args: argparse.Namespace, error: ConfigError) -> None:
    """--stats-json on every exit path: a configuration that did not load leaves its error."""
    if args.stats_json is None or args.check:
        return
    from admittance.daemon.supervisor import error_fields, write_stats_file

    try:
        write_stats_file(args.stats_json, error_fields(error))
    except AdmittanceError as exc:
        log.warning("%s", exc)


def remote_client(args: argparse.Namespace):
    """The remote tools' session: --connect, else the --zenoh-config file's connect, else loopback;
    login and TLS files from --zenoh-config (access control is the daemon's or router's business)."""
    from admittance.daemon import config
    from admittance.daemon.zenoh_iface import Client, security_of

    security, connect = {}, args.connect
    if getattr(args, "zenoh_config", None):
        zen = config.load_zenoh_table(args.zenoh_config)
        security = {k: v for k, v in security_of(zen).items() if k != "access_control"}
        connect = connect or zen.connect
    return Client(connect or [DEFAULT_ENDPOINT], security)


def cmd_monitor(args: argparse.Namespace) -> int:
    from admittance.daemon.monitor import View, run_monitor

    with remote_client(args) as client:
        subscription = client.try_stream_benches(args.prefix)
        try:
            view = View(args.prefix, sys.stdout, sys.stdout.isatty(), degrees=args.degrees)
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
    """Set, and say what changed (old → new and how it arrives) or why not; 1 when refused."""
    from admittance.daemon.replies import set_reply_text

    request = parse_assignments(args.assignments)
    with remote_client(args) as client:
        key = f"{args.prefix}/params"
        before = {} if args.as_json else _params(client.query(key, None, timeout=args.timeout))
        reply = client.query(key, request, timeout=args.timeout)
        accepted = bool(reply.get("accepted", False))
        after = _params(client.query(key, None, timeout=args.timeout)) if accepted and not args.as_json else {}
    print(json.dumps(reply) if args.as_json else set_reply_text(request, reply, before, after))
    return 0 if accepted else 1


def cmd_tare(args: argparse.Namespace) -> int:
    from admittance.daemon.replies import tare_reply_text

    with remote_client(args) as client:
        reply = client.query(f"{args.prefix}/tare", {"samples": args.samples}, timeout=args.timeout)
    print(json.dumps(reply) if args.as_json else tare_reply_text(args.samples, reply))
    return 0 if reply.get("accepted", False) else 1


def _params(reply: dict[str, Any]) -> dict[str, Any]:
    params = reply.get("params")
    return params if isinstance(params, dict) else {}


def cmd_get(args: argparse.Namespace) -> int:
    """Print the live parameters (all, or the names asked for); 1 when a name is unknown."""
    from admittance.daemon.replies import params_table

    with remote_client(args) as client:
        params = _params(client.query(f"{args.prefix}/params", None, timeout=args.timeout))
    shown = {n: params[n] for n in args.names if n in params} if args.names else params
    if args.as_json or shown:
        print(json.dumps(shown, sort_keys=True) if args.as_json else params_table(shown))
    unknown = [n for n in args.names if n not in params]
    if unknown:
        raise RefusedError(f"unknown parameter(s): {', '.join(unknown)} (known: {', '.join(sorted(params))})")
    return 0


def cmd_router(args: argparse.Namespace) -> int:
    from admittance.daemon.router import run_router

    configure("router", args.verbosity)
    return run_router(args.zenoh_config, args.listen, args.duration)
