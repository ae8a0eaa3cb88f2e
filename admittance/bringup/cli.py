"""``admittance setup``: the bring-up wizard (docs/bring-up.md)."""

from __future__ import annotations

import argparse
import contextlib
import sys
from pathlib import Path

from admittance.cli_help import positive_float


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "setup", help="bring up a new bench: scan, servo settings, zero and direction, sensor, dry run, config",
        description="Walk a new bench from a bus scan to a first admittance session, and write its "
        "configuration (validated by the daemon's loader). Interactive on a terminal; scripted with --yes "
        "and the per-step flags. --mock rehearses it on the simulated bench. See docs/bring-up.md.")
    where = p.add_argument_group("where")
    where.add_argument("--port", metavar="DEVICE", help="the Dynamixel bus (e.g. /dev/ttyUSB0); required unless --mock (default: none)")
    where.add_argument("--mock", action="store_true", help="rehearse on the simulated bench with a simulated person "
                       "(writes port = \"mock\")")
    where.add_argument("--baud", type=int, action="append", metavar="BIT/S",
                       help="baud rate to scan (repeatable; default: 57600, 1000000, 115200, 2000000, 3000000, "
                       "4000000, 9600)")
    where.add_argument("--protocol", type=int, action="append", choices=(1, 2), metavar="{1,2}",
                       help="protocol to scan (repeatable; default: 2 then 1)")
    where.add_argument("--scan", action="store_true", help="only scan the bus, print what answers, and exit")
    where.add_argument("--id", type=int, metavar="ID", help="the servo to bring up (default: the only one found)")
    servo = p.add_argument_group("servo settings (EEPROM, torque off first, verified)")
    servo.add_argument("--new-id", type=int, metavar="ID", help="give the servo this ID (default: keep it)")
    servo.add_argument("--new-baud", type=int, metavar="BIT/S", help="move the servo to this baud rate (default: keep it; --mock: 1000000)")
    servo.add_argument("--mode", metavar="MODE", help="operating mode: position, extended-position, ... "
                       "(P1: position, wheel, multi-turn; default: keep it; the daemon sets position)")
    arm = p.add_argument_group("arm")
    arm.add_argument("--zero-tick", type=int, metavar="TICK", help="give zero_tick in ticks (0..4095) instead of measuring it (default: measured)")
    arm.add_argument("--direction", type=int, choices=(1, -1), help="give direction instead of measuring it (default: measured)")
    arm.add_argument("--position-limits", type=float, nargs=2, metavar=("MIN", "MAX"),
                     help="give the position limits in rad instead of measuring the range of motion (default: measured)")
    arm.add_argument("--range-margin", type=float, default=0.087, metavar="RAD",
                     help="how far inside the measured ends of the range the limits go, in rad (default 0.087 = 5°)")
    sensor = p.add_argument_group("force sensor")
    sensor.add_argument("--sensor-kind", choices=("optoforce", "can"), default="optoforce",
                        help="force sensor kind (default optoforce)")
    sensor.add_argument("--sensor-port", metavar="DEVICE", help="serial path (optoforce) or python-can channel (can) (default: none; needed by the sensor step)")
    sensor.add_argument("--can-interface", metavar="NAME", help="python-can interface, e.g. socketcan, slcan, pcan "
                        "(can only; default socketcan)")
    sensor.add_argument("--can-id", type=lambda t: int(t, 0), metavar="ID", help="CAN identifier of the data frames "
                        "(can only; default 0x100)")
    sensor.add_argument("--can-bitrate", type=int, metavar="BIT/S", help="CAN bit rate (can only; default 1000000)")
    sensor.add_argument("--counts-per-newton", type=float, nargs=3, metavar=("X", "Y", "Z"),
                        help="sensor scale per axis in count/N, from its calibration sheet (default 451.89 each)")
    sensor.add_argument("--axis", choices=("x", "y", "z"), help="expected force axis (default: measured)")
    sensor.add_argument("--lever-arm", type=float, metavar="M",
                        help="lever arm in m measured with a ruler (default: measured from the servo's torque)")
    run = p.add_argument_group("dry run and output")
    run.add_argument("--dry-run", type=float, default=5.0, metavar="S",
                     help="length of the limited-torque session in s; 0 skips it (default 5)")
    run.add_argument("--output-limit", type=float, default=0.2, metavar="FRACTION",
                     help="servo output cap during the dry run, fraction of full PWM/torque (default 0.2)")
    run.add_argument("--skip", action="append", default=[], choices=("servo", "arm", "range", "sensor", "dry-run"),
                     help="skip a step (repeatable; default: none); skipping arm or sensor needs their values given; "
                          "skipping range leaves the daemon's default limits")
    run.add_argument("--yes", action="store_true", help="answer yes and give each physical step --settle seconds "
                     "instead of waiting for Enter (default: ask on the terminal)")
    run.add_argument("--settle", type=positive_float, default=5.0, metavar="S",
                     help="seconds each physical step takes with --yes (default 5)")
    run.add_argument("--out", type=Path, default=Path("admittance.toml"), metavar="FILE",
                     help="configuration to write (default admittance.toml)")
    run.add_argument("--force", action="store_true", help="replace --out if it exists")
    p.set_defaults(func=cmd_setup)


def cmd_setup(args: argparse.Namespace) -> int:
    from admittance.bringup import scan, wizard

    if not args.mock and not args.port:
        from admittance.errors import ConfigError

        raise ConfigError("give the bus with --port DEVICE (e.g. /dev/ttyUSB0), or rehearse with --mock")
    if args.mock and args.new_id not in (None, 1):
        from admittance.errors import ConfigError

        raise ConfigError("--mock keeps ID 1: the simulated hand pushes the servo it was built with")
    with _bench(args) as (port, sensor_port, prompter, extra):
        if args.scan:
            for found in scan.scan_bus(port, baudrates=_bauds(args), protocols=_protocols(args),
                                       bus_options=extra.get("bus_options")):
                print(found.line())
            return 0
        opts = wizard.SetupOptions(
            port=port, out=args.out, baudrates=_bauds(args), protocols=_protocols(args), servo_id=args.id,
            new_id=args.new_id, new_baudrate=args.new_baud or (1_000_000 if args.mock else None), mode=args.mode, zero_tick=args.zero_tick,
            direction=args.direction, sensor=_sensor_section(args, sensor_port), axis=args.axis,
            lever_arm=args.lever_arm, dry_run_s=args.dry_run, output_limit=args.output_limit,
            position_limits=tuple(args.position_limits) if args.position_limits else None,
            range_margin=args.range_margin, skip=frozenset(args.skip), force=args.force, **extra)
        wizard.run_wizard(opts, prompter, start_hand=getattr(prompter, "start_hand", lambda: None))
    return 0


def _bauds(args: argparse.Namespace) -> tuple[int, ...]:
    from admittance.bringup import scan

    if args.baud:
        return tuple(args.baud)
    return (57_600,) if args.mock else scan.DEFAULT_BAUDRATES


def _protocols(args: argparse.Namespace) -> tuple[int, ...]:
    from admittance.bringup import scan

    return tuple(args.protocol) if args.protocol else ((2,) if args.mock else scan.DEFAULT_PROTOCOLS)


def _sensor_section(args: argparse.Namespace, port: str | None) -> dict:
    section = {"kind": args.sensor_kind, "port": port, "interface": args.can_interface, "can_id": args.can_id,
               "bitrate": args.can_bitrate,
               "counts_per_newton": list(args.counts_per_newton) if args.counts_per_newton else [451.89] * 3}
    if args.sensor_kind == "can":  # python-can's name for it (port is only its alias)
        section["channel"] = section.pop("port")
    else:
        section = {k: section[k] for k in ("kind", "port", "counts_per_newton")}
    return {k: v for k, v in section.items() if v is not None}


@contextlib.contextmanager
def _bench(args: argparse.Namespace):
    """The bus and sensor ports and who acts: the hardware and its user, or the simulated bench."""
    from admittance.bringup.prompt import ScriptedPrompter, TerminalPrompter

    if not args.mock:
        interactive = sys.stdin.isatty() and not args.yes
        yield args.port, args.sensor_port, TerminalPrompter() if interactive else ScriptedPrompter(args.settle), {}
        return
    from admittance.bringup.simulated import SimulatedPerson, simulated_bench

    with simulated_bench() as bench:
        extra = {"bus_options": {"reply_slack_ms": 500.0}, "written_ports": {"bus": "mock", "sensor": "mock"}}
        yield bench.bus_port, bench.sensor_port, SimulatedPerson(bench), extra
