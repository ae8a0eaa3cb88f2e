"""``admittance mock-bench``: run the simulated bench alone, for any client to drive.

With ``--print-ports`` the first line on stdout is one JSON object,
``{"bus": "/dev/pts/N", "sensor": "/dev/pts/M"}`` (flushed at once; with a CAN sensor it adds
``"can": {"interface", "channel", "can_id"}``), so a test or a script
can start the bench as a subprocess and read where to connect; nothing else goes to stdout.
With ``--control`` or ``--faults`` the object also has ``"links"``, the bus's and the
sensor's stable paths, which survive an unplug and replug (and ``"control"``, the socket).
The bench then runs until SIGINT or SIGTERM (or ``--duration``) and exits 0.

Faults (:mod:`admittance.mockbench.faults`): ``--control PATH`` takes commands from another
process on a Unix socket, one line each with a JSON reply; ``--faults FILE`` plays a timed
script of the same commands (``SECONDS COMMAND`` per line, seconds after the bench started).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import sys
import threading
import time

from admittance.daemon.config import DAEMON_RT_PRIORITY
from admittance.errors import ConfigError
from admittance.logs import add_verbosity_args, configure

log = logging.getLogger(__name__)
# The daemon's default [loop].rt_priority: a daemon driving this bench is its equal.
DEFAULT_RT_PRIORITY = DAEMON_RT_PRIORITY


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "mock-bench",
        help="run the simulated bench (mock Dynamixel bus + force sensor on ptys)",
        description="Start a simulated Dynamixel bus and a simulated OptoForce sensor on pseudo-terminals, "
        "driven by a scripted hand, and run until SIGINT/SIGTERM.",
    )
    parser.add_argument("--print-ports", action="store_true", help='first print {"bus": ..., "sensor": ...} as one JSON line')
    parser.add_argument("--servos", type=int, default=1, metavar="N", help="number of servos, IDs 1..N (default 1)")
    parser.add_argument("--model", default="MX-64", metavar="MODEL", help="servo model (default MX-64)")
    parser.add_argument("--protocol", type=int, choices=(1, 2), default=2, help="firmware protocol (default 2)")
    parser.add_argument("--params", metavar="FILE.toml", help="fitted parameter file (default: the shipped params/<model>.toml)")
    parser.add_argument("--baudrate", type=int, default=1_000_000, metavar="BIT/S",
                        help="bus rate in bit/s: the simulated wire's timing (default 1000000)")
    parser.add_argument("--profile", default="push-release", metavar="NAME|FILE", help="hand profile: push-release, sine, ramp, steps, still (NAME:key=value,...) or a CSV of t,tau (default push-release)")
    parser.add_argument(
        "--sensor",
        choices=("optoforce", "can", "slcan"),
        default="optoforce",
        help="optoforce: serial frames on a pty; can: python-can (--can-interface); slcan: a USB-CAN adapter in slcan mode on a pty (default optoforce)",
    )
    parser.add_argument("--rate", type=float, default=1000.0, metavar="HZ", help="sensor sample rate in Hz (default 1000)")
    parser.add_argument("--noise", type=float, default=0.0, metavar="NEWTON", help="sensor noise std in N (default 0)")
    parser.add_argument("--bias", type=float, default=0.0, metavar="NEWTON", help="sensor bias in N (default 0)")
    parser.add_argument("--lever-arm", type=float, default=0.105, metavar="M", help="hand-to-axis distance in m (default 0.105)")
    parser.add_argument("--can-interface", default="virtual", metavar="NAME",
                        help="python-can interface of the CAN sensor (default virtual: in-process only)")
    parser.add_argument("--can-channel", default="admittance-mock", metavar="CHANNEL",
                        help="python-can channel of the CAN sensor (default admittance-mock)")
    parser.add_argument("--can-id", type=parse_can_id, default=0x100, metavar="ID", help="CAN identifier of the data frames (default 0x100; configuration on ID+1)")
    parser.add_argument("--effect", action="append", default=[], metavar="NAME=VALUE", help="plant parameter laid over the fitted ones, in its unit (repeatable; default: none)")
    parser.add_argument("--seed", type=int, default=0, metavar="N", help="seed of the sensor noise (default 0)")
    parser.add_argument("--duration", type=float, metavar="S", help="stop after S seconds (default: run until a signal)")
    parser.add_argument("--control", metavar="PATH", help="take fault commands on a Unix socket at PATH (one line each, a JSON reply; default: none)")
    parser.add_argument("--faults", metavar="FILE", help="play a timed fault script: 'SECONDS COMMAND' per line (default: none)")
    parser.add_argument("--rt-priority", type=rt_priority, default=DEFAULT_RT_PRIORITY, metavar="N",
                        help="SCHED_FIFO priority of the bus thread, 1..99, falling back to SCHED_OTHER with a "
                             f"warning when refused; 0 = SCHED_OTHER (default {DEFAULT_RT_PRIORITY}, the daemon's loop)")
    add_verbosity_args(parser)
    parser.set_defaults(func=run)


def parse_effects(items: list[str]) -> dict[str, float]:
    effects = {}
    for item in items:
        name, sep, text = item.partition("=")
        try:
            if not sep:
                raise ValueError
            effects[name.strip()] = float(text)
        except ValueError:
            raise ConfigError(f"--effect takes NAME=VALUE with a number, not '{item}'") from None
    return effects


def rt_priority(text: str) -> int:
    """A SCHED_FIFO priority 0..99 (0 = SCHED_OTHER); argparse turns the error into one line."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= 99:
        raise argparse.ArgumentTypeError(f"a priority is 0..99 (0 = SCHED_OTHER), not '{text}'")
    return value


def parse_can_id(text: str) -> int:
    """An identifier in any base Python reads (0x100, 256); argparse turns the error into one line."""
    try:
        return int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"a CAN identifier is a number such as 0x100, not '{text}'") from None


def run(args: argparse.Namespace) -> int:
    from admittance.daemon.stopsignals import StopRequest, stop_signals_call

    configure("mock-bench", args.verbosity)
    # Set from a signal handler, so a StopRequest: a threading.Event's lock can deadlock when a
    # second signal lands inside the first one's handler (stopsignals.py).
    stop = StopRequest()
    with stop_signals_call(lambda *_: stop.set()):
        return _run(args, stop)


def _run(args: argparse.Namespace, stop) -> int:
    from admittance.mockbench.bench import BenchConfig, MockBench
    from admittance.mockbench.control import ControlServer
    from admittance.mockbench.faults import FaultScript

    script = FaultScript.load(args.faults) if args.faults else None

    if args.sensor == "can":
        from admittance.extras import require

        require("can", "mock-bench --sensor can")
    config = BenchConfig(
        servos=args.servos,
        model=args.model,
        protocol=args.protocol,
        params_file=args.params,
        effects=parse_effects(args.effect),
        baudrate=args.baudrate,
        profile=args.profile,
        sensor=args.sensor,
        sensor_rate_hz=args.rate,
        noise_std_n=args.noise,
        bias_n=args.bias,
        lever_arm=args.lever_arm,
        can_interface=args.can_interface,
        can_channel=args.can_channel,
        can_id=args.can_id,
        seed=args.seed,
        rt_priority=args.rt_priority,
    )
    with MockBench(config) as bench, contextlib.ExitStack() as stack:
        for warning in bench.bus.timing()["warnings"]:
            log.warning("%s", warning)
        ports = bench.ports(links=bool(args.control or args.faults))
        if args.control:
            server = ControlServer(bench, args.control)
            stack.callback(server.close)
            server.start()
            ports["control"] = args.control
        if args.print_ports:
            print(json.dumps(ports), flush=True)
        else:
            _describe(bench)
        if script is not None:
            player = threading.Thread(target=script.play, args=(bench, stop), name="fault-script", daemon=True)
            player.start()
        deadline = None if args.duration is None else time.monotonic() + args.duration
        while not stop.wait(0.2):
            if deadline is not None and time.monotonic() >= deadline:
                break
        stop.set()  # ends the script's thread too
    return 0


def _describe(bench) -> None:
    cfg = bench.config
    print(f"mock bus:    {bench.bus_port}  ({len(bench.servo_ids)} × {cfg.model}, Protocol {cfg.protocol}.0, IDs {bench.servo_ids}, {cfg.baudrate} baud)")
    if cfg.sensor == "slcan":
        print(f"mock sensor: {bench.sensor_port}  (slcan USB-CAN adapter, OptoForce frames on id {cfg.can_id:#x} at {cfg.sensor_rate_hz:g} Hz)")
    elif bench.sensor_port:
        print(f"mock sensor: {bench.sensor_port}  (OptoForce 3-axis frames at {cfg.sensor_rate_hz:g} Hz)")
    else:
        print(f"mock sensor: CAN {cfg.can_interface} channel {bench.can_channel!r}, id {cfg.can_id:#x}")
    print(f"hand:        {cfg.profile} on servo {bench.hand_servo_id}, lever arm {cfg.lever_arm} m; Ctrl-C to stop")
    sys.stdout.flush()
