"""The thesis's pendulum-drop procedure (section 2.1) on a servo, real or simulated.

For each bob distance, in each direction, ``repeats`` times: the servo, torque on, carries the
pendulum slowly up to the start angle and holds it there; torque goes off (the release, t = 0);
Present Position is read back to back, as fast as the bus answers, for ``duration`` seconds;
then the servo catches the pendulum softly (its goal set to where the horn is before torque
comes back on, so it does not jump) and the next drop starts. The trials are written as a
dataset folder (manifest.toml and one CSV per drop, shared/contracts/datasets.md) that
``admittance identify`` takes.

Safety (docs/drops.md): the start angle, and every angle the slow move passes through, must lie
inside the joint's position limits less a margin; the swing is watched while it is recorded, and
a horn that leaves the limits is caught at once (torque on where it is) and the run stops with
one line. Everything here works through the bus alone: the same code drives the simulated
bench (simulated.py) and a real one (cli.py).
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable
from contextlib import AbstractContextManager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from admittance.drivers.dynamixel import ServoCommError, ServoTimeout
from admittance.errors import ConfigError, DeviceError

RAD_PER_TICK = 2.0 * math.pi / 4096.0
MOVE_PERIOD_S = 0.02  # the slow move's goal updates
ARRIVE_TOLERANCE = 0.05  # rad: the horn is at the start angle (a position loop holding gravity sags a little)
SETTLE_S = 1.0  # held at the start angle before the release, so the drop starts at rest
ARRIVE_TIMEOUT_S = 10.0
MIN_SAMPLES = 50  # a drop with fewer answered reads is a bus problem, not a dataset
BUS_RETRIES = 3  # a command whose reply is lost is sent again: a busy host must not end a run of drops
REPLY_SLACK_MS = 100.0  # waited for a reply beyond its wire time: costs nothing unless a reply is lost
READ_ATTEMPTS = 5  # a reply lost to noise or a busy host costs a sample, not the drop
DIRECTIONS = {"cw": 1.0, "ccw": -1.0}  # the sign of the start angle, as synth labels its trials


@dataclass(frozen=True)
class Joint:
    """Where the pendulum hangs on the servo: the tick of 0 rad (hanging straight down), the
    direction (+1: angle grows with the tick), the position limits (rad) and their margin."""

    servo_id: int
    zero_tick: float = 2048.0
    direction: int = 1
    position_min: float = -math.pi
    position_max: float = math.pi
    margin: float = 0.1

    def angle(self, tick: float) -> float:
        return (tick - self.zero_tick) * RAD_PER_TICK * self.direction

    def tick(self, angle: float) -> int:
        return int(round(self.zero_tick + angle / (RAD_PER_TICK * self.direction)))

    def inside(self, angle: float) -> bool:
        return self.position_min <= angle <= self.position_max

    def check_start(self, start_angle: float) -> None:
        """Both start angles (±) inside the limits less the margin, before anything moves."""
        low, high = self.position_min + self.margin, self.position_max - self.margin
        if not (low <= -start_angle and start_angle <= high):
            raise ConfigError(f"--start-angle {start_angle:g} rad: ±{start_angle:g} must lie inside the joint's "
                              f"position limits less a {self.margin:g} rad margin [{low:.3f}, {high:.3f}] rad; "
                              "lower it or widen the limits (docs/drops.md)")


@dataclass(frozen=True)
class DropPlan:
    distances: tuple[float, ...]
    bob: dict[str, float]
    rod: dict[str, float] | None = None
    start_angle: float = math.pi / 2  # rad from hanging straight down
    repeats: int = 3
    duration: float = 8.0  # s recorded after each release
    move_speed: float = 0.5  # rad/s: the slow move to the start angle
    directions: tuple[str, ...] = ("cw", "ccw")
    motor: str = ""

    def __post_init__(self) -> None:
        checks = [(all(d > 0 and math.isfinite(d) for d in self.distances) and bool(self.distances),
                   f"bob distances must be finite and > 0 m, got {list(self.distances)}"),
                  (0 < self.start_angle < math.pi, f"--start-angle must be in (0, π) rad, got {self.start_angle}"),
                  (self.repeats >= 1, f"--repeats must be >= 1, got {self.repeats}"),
                  (0 < self.duration <= 120, f"--duration must be in (0, 120] s, got {self.duration}"),
                  (0 < self.move_speed <= 3, f"--move-speed must be in (0, 3] rad/s, got {self.move_speed}")]
        for ok, message in checks:
            if not ok:
                raise ConfigError(message)


@dataclass
class Drop:
    file: str
    bob_distance: float
    direction: str
    t: np.ndarray
    theta: np.ndarray

    @property
    def read_rate_hz(self) -> float:
        return (self.t.size - 1) / max(float(self.t[-1] - self.t[0]), 1e-9)


@dataclass
class DropSession:
    """One bob distance on the bench: the bus to drive, with the pendulum mounted."""

    bus: Any  # admittance.drivers.dynamixel.ServoBus (or anything with its read_raw/write_raw/set_torque)
    joint: Joint
    say: Callable[[str], None] = print
    clock: Callable[[], float] = time.monotonic

    def _persist(self, op: Callable[[], Any]) -> Any:
        """``op`` again when its reply is lost, at most READ_ATTEMPTS times (each with the bus's
        own retries): the catch and the release must happen even on a busy host."""
        for attempt in range(READ_ATTEMPTS):
            try:
                return op()
            except (ServoTimeout, ServoCommError):
                if attempt == READ_ATTEMPTS - 1:
                    raise
        raise AssertionError("unreachable")

    def angle(self) -> float:
        return self.joint.angle(self._persist(lambda: self.bus.read_raw(self.joint.servo_id, "Present Position")))

    def sample(self) -> tuple[float, float] | None:
        """(time, angle) of one read, stamped halfway between the request and the reply (where
        the servo sampled it, give or take the wire); None when the reply was lost."""
        before = self.clock()
        try:
            tick = self.bus.read_raw(self.joint.servo_id, "Present Position")
        except (ServoTimeout, ServoCommError):
            return None
        return 0.5 * (before + self.clock()), self.joint.angle(tick)

    def goal(self, angle: float) -> None:
        self._persist(lambda: self.bus.write_raw(self.joint.servo_id, "Goal Position", self.joint.tick(angle)))

    def torque(self, on: bool) -> None:
        self._persist(lambda: self.bus.set_torque(self.joint.servo_id, on))

    def catch(self) -> float:
        """Torque on where the horn is: the goal first, so the servo holds rather than jumps."""
        here = self.angle()
        self.goal(here)
        self.torque(True)
        return here

    def move_to(self, target: float, speed: float) -> None:
        """From where the horn is to ``target`` at ``speed`` rad/s, then held for SETTLE_S."""
        here = self.catch()
        steps = max(int(abs(target - here) / (speed * MOVE_PERIOD_S)), 1)
        for k in range(1, steps):
            with contextlib.suppress(ServoTimeout, ServoCommError):  # the next step's goal supersedes a lost one
                self.bus.write_raw(self.joint.servo_id, "Goal Position", self.joint.tick(here + (target - here) * k / steps))
            time.sleep(MOVE_PERIOD_S)
        self.goal(target)
        deadline = self.clock() + ARRIVE_TIMEOUT_S
        while abs(self.angle() - target) > ARRIVE_TOLERANCE:
            if self.clock() > deadline:
                raise DeviceError(f"servo {self.joint.servo_id} did not reach {target:.3f} rad within "
                                  f"{ARRIVE_TIMEOUT_S:g} s (at {self.angle():.3f} rad): is the load too heavy?")
            time.sleep(MOVE_PERIOD_S)
        time.sleep(SETTLE_S)

    def drop(self, duration: float) -> tuple[np.ndarray, np.ndarray]:
        """Release and record (t from the release, s; theta, rad) for ``duration`` seconds."""
        sid = self.joint.servo_id
        self.torque(False)
        t0 = self.clock()
        times, angles = [], []
        while self.clock() - t0 < duration:
            read = self.sample()
            if read is None:
                continue
            times.append(read[0] - t0)
            angles.append(theta := read[1])
            if not self.joint.inside(theta):
                caught = self.catch()
                raise DeviceError(f"the swing left the position limits at {theta:.3f} rad and was caught at "
                                  f"{caught:.3f} rad: lower --start-angle (docs/drops.md)")
        self.catch()
        if len(times) < MIN_SAMPLES:
            raise DeviceError(f"servo {sid}: only {len(times)} of the drop's reads were answered in {duration:g} s; "
                              "check the bus (baud rate, latency timer, cabling)")
        return np.asarray(times), np.asarray(angles)

    def run(self, plan: DropPlan, distance: float) -> list[Drop]:
        found = []
        for direction in plan.directions:
            for repeat in range(1, plan.repeats + 1):
                name = f"drop_{round(distance * 1000):03d}mm_{direction}_{repeat}.csv"
                self.say(f"drops: {name}: moving to {DIRECTIONS[direction] * plan.start_angle:+.3f} rad")
                self.move_to(DIRECTIONS[direction] * plan.start_angle, plan.move_speed)
                t, theta = self.drop(plan.duration)
                found.append(Drop(name, distance, direction, t, theta))
                self.say(f"drops: {name}: {t.size} reads in {plan.duration:g} s ({found[-1].read_rate_hz:.0f} Hz)")
        self.move_to(0.0, plan.move_speed)
        return found


def record_drops(plan: DropPlan, sessions: Callable[[float], AbstractContextManager[DropSession]],
                 out: Path) -> Path:
    """Every drop of ``plan``; ``sessions(distance)`` mounts the bob and yields the bench's session."""
    drops: list[Drop] = []
    for distance in plan.distances:
        with sessions(distance) as session:
            drops += session.run(plan, distance)
    return write_dataset(out, plan, drops)


def write_dataset(out: Path, plan: DropPlan, drops: list[Drop]) -> Path:
    """The contract's folder: manifest.toml (rod, bob, one entry per trial) and the CSVs."""
    out.mkdir(parents=True, exist_ok=True)
    for d in drops:
        np.savetxt(out / d.file, np.column_stack([d.t, d.theta]), delimiter=",", header="t,theta", comments="",
                   fmt="%.9g")
    manifest: dict[str, Any] = {"motor": plan.motor, "recorded_by": "admittance drops",
                                "start_angle": plan.start_angle, "duration": plan.duration}
    if plan.rod:
        manifest["rod"] = dict(plan.rod)
    manifest["bob"] = dict(plan.bob)
    manifest["trials"] = [{"file": d.file, "bob_distance": d.bob_distance, "direction": d.direction,
                           "read_rate_hz": round(d.read_rate_hz, 1)} for d in drops]
    (out / "manifest.toml").write_text(tomli_w.dumps(manifest))
    return out
