"""``admittance drops DIR``: pendulum drop tests on the bench, written as a dataset for ``identify``.

Without ``--config`` the drops run on the simulated bench (a pendulum on the mock's MX-64); with
a daemon configuration they run on that bus's joint, and between bob distances the person is
asked to move the bob and press Enter. docs/drops.md has the procedure and its safety rules.
"""

from __future__ import annotations

import argparse
import math
import sys
from contextlib import contextmanager
from pathlib import Path

from admittance import outfolder
from admittance.errors import ConfigError

THESIS_DISTANCES = "0.20,0.25,0.30,0.35,0.40"  # m, the thesis's five bob positions
THESIS_ROD = "0.0402,0.456"  # kg, m
THESIS_BOB = 0.1034  # kg


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "drops", help="pendulum drop tests on the bench (real or simulated) → a dataset folder for identify",
        description="Run the thesis's drop tests: for each bob distance and both directions, carry the pendulum "
                    "to the start angle with torque on, release it (torque off) and record Present Position as "
                    "fast as the bus answers; write DIR as a dataset (manifest.toml + CSVs) that `admittance "
                    "identify` takes. Without --config: the simulated bench. Procedure and safety: docs/drops.md.")
    p.add_argument("out_dir", metavar="DIR", help="the dataset folder to write (new or empty unless --force)")
    p.add_argument("--config", metavar="FILE.toml", help="a daemon configuration: its bus and joint (default: the "
                   "simulated bench)")
    p.add_argument("--joint", type=int, metavar="ID", help="the joint's servo ID (default: the configuration's first)")
    p.add_argument("--distances", default=THESIS_DISTANCES, metavar="M,M,...",
                   help=f"bob distances from the axis in m (default {THESIS_DISTANCES})")
    p.add_argument("--rod", default=THESIS_ROD, metavar="KG,M",
                   help=f"the rod's mass and length, or 'none' (default {THESIS_ROD}, the thesis's)")
    p.add_argument("--bob", type=float, default=THESIS_BOB, metavar="KG", help=f"the bob's mass in kg (default {THESIS_BOB} kg)")
    p.add_argument("--start-angle", type=float, default=math.pi / 2, metavar="RAD",
                   help="release angle from hanging straight down, both sides, in rad (default π/2 rad)")
    p.add_argument("--repeats", type=int, default=3, metavar="N", help="drops per distance and direction (default 3)")
    p.add_argument("--duration", type=float, default=8.0, metavar="S", help="recorded per drop, in s (default 8 s)")
    p.add_argument("--move-speed", type=float, default=0.5, metavar="RAD/S",
                   help="speed of the slow move to the start angle, in rad/s (default 0.5 rad/s)")
    p.add_argument("--margin", type=float, default=0.1, metavar="RAD",
                   help="the start angle stays this far inside the position limits, in rad (default 0.1 rad)")
    p.add_argument("--force", action="store_true", help="write into a non-empty DIR, replacing its manifest and CSVs")
    p.set_defaults(func=run_drops)


def _numbers(text: str, option: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise ConfigError(f"{option} {text!r}: expected numbers separated by commas") from None
    if not all(math.isfinite(v) and v > 0 for v in values):
        raise ConfigError(f"{option} {text!r}: every value must be finite and > 0")
    return values


def run_drops(args: argparse.Namespace) -> int:
    from admittance.drops.procedure import DropPlan, Joint, record_drops

    rod = None
    if args.rod.strip().lower() != "none":
        mass, length = (_numbers(args.rod, "--rod") + (0.0,))[:2]
        if length <= 0:
            raise ConfigError(f"--rod {args.rod!r}: expected MASS,LENGTH (kg, m)")
        rod = {"mass": mass, "length": length}
    bob = {"mass": _numbers(str(args.bob), "--bob")[0]}
    say = _say
    if args.config:
        joint, sessions, motor = _real_bench(args, say)
    else:
        from admittance.drops.simulated import MODEL, SERVO_ID, simulated_session

        joint = Joint(SERVO_ID, margin=args.margin)
        motor = f"{MODEL} (simulated bench)"

        def sessions(distance):
            return simulated_session(rod, bob, distance, joint, say=say)
    plan = DropPlan(distances=_numbers(args.distances, "--distances"), bob=bob, rod=rod,
                    start_angle=args.start_angle, repeats=args.repeats, duration=args.duration,
                    move_speed=args.move_speed, motor=motor)
    joint.check_start(plan.start_angle)
    outfolder.check(args.out_dir, args.force, "drops")
    out = record_drops(plan, sessions, outfolder.clear(args.out_dir, "drops"))
    n = len(plan.distances) * len(plan.directions) * plan.repeats
    print(f"wrote {n} drops to {out}: admittance identify {out} --report REPORT_DIR")
    return 0


def _say(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def _real_bench(args, say):
    """The configured bus and joint; the person moves the bob between distances."""
    from admittance.daemon.config import load_config
    from admittance.drivers.dynamixel import ServoBus
    from admittance.drops.procedure import BUS_RETRIES, REPLY_SLACK_MS, DropSession, Joint

    cfg = load_config(args.config)
    joints = {j.id: j for j in cfg.joints}
    chosen = joints.get(args.joint if args.joint is not None else cfg.joints[0].id)
    if chosen is None:
        raise ConfigError(f"--joint {args.joint}: not in {args.config} (joints {sorted(joints)})")
    limits = chosen.resolved_limits
    joint = Joint(chosen.id, zero_tick=float(chosen.zero_tick), direction=int(chosen.direction),
                  position_min=limits.position_min, position_max=limits.position_max, margin=args.margin)

    @contextmanager
    def sessions(distance):
        say(f"drops: clamp the bob at {distance:g} m from the axis, keep clear of the swing, then press Enter")
        input()
        with ServoBus(cfg.bus.port, baudrate=cfg.bus.baudrate, protocol=cfg.bus.protocol, retries=BUS_RETRIES,
                      reply_slack_ms=REPLY_SLACK_MS) as bus:
            bus.prepare(joint.servo_id)
            try:
                yield DropSession(bus, joint, say=say)
            finally:
                bus.set_torque(joint.servo_id, False)  # the bob is moved by hand next
    return joint, sessions, str(getattr(chosen, "model", "") or "")
