"""``zero_tick`` and ``direction`` from the arm itself: let it hang, push it, let it hang again.

With torque off the arm hangs where gravity puts it: that is joint angle 0, the angle the
identified plant calls "hanging down". Friction stops a released arm anywhere within a small
band around that angle, so the rest is read twice, before the push and after the release (the
arm comes back from the pushed side), and ``zero_tick`` is their mean; their difference is
reported as the friction band. The push in the direction the user calls positive gives the
sign: ``direction`` is +1 when the encoder's tick grows that way, -1 when it falls.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass

from admittance.bringup.prompt import Prompter
from admittance.drivers.dynamixel import ServoBus, ServoTimeout
from admittance.errors import DataError, DeviceError

TICKS_PER_REV = 4096
MIN_PUSH_TICKS = 114  # 10°: a smaller push cannot be told from the friction band
STILL_SPREAD_TICKS = 3  # the encoder's jitter at rest, plus one
STILL_SAMPLES = 15
READ_PERIOD_S = 0.02
REST_TIMEOUT_S = 20.0


@dataclass(frozen=True)
class ArmReading:
    zero_tick: int
    direction: int
    rest_tick: float
    pushed_tick: float
    released_tick: float

    @property
    def band_ticks(self) -> float:
        return abs(wrapped(self.released_tick - self.rest_tick))

    def line(self) -> str:
        push = wrapped(self.pushed_tick - self.rest_tick)
        return (f"zero_tick = {self.zero_tick} (rests at {self.rest_tick:.0f} and {self.released_tick:.0f}: "
                f"friction band {self.band_ticks * 360 / TICKS_PER_REV:.1f}°), direction = {self.direction:+d} "
                f"(the push moved {push:+.0f} ticks)")


def wrapped(delta: float) -> float:
    """A tick difference folded into -2048..2048 (P1 positions wrap at one turn)."""
    return (delta + TICKS_PER_REV / 2) % TICKS_PER_REV - TICKS_PER_REV / 2


def read_still(bus: ServoBus, servo_id: int, *, timeout: float = REST_TIMEOUT_S) -> float:
    """The mean Present Position (ticks) once it stays within STILL_SPREAD_TICKS for STILL_SAMPLES reads."""
    window: deque[int] = deque(maxlen=STILL_SAMPLES)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            window.append(bus.read_raw(servo_id, "Present Position"))
        except ServoTimeout:  # a lost reply is one read fewer, not a failed step
            continue
        if len(window) == window.maxlen and max(window) - min(window) <= STILL_SPREAD_TICKS:
            return sum(window) / len(window)
        time.sleep(READ_PERIOD_S)
    seen = f"positions {min(window)}..{max(window)}" if window else "no position read"
    raise DeviceError(f"servo {servo_id}: the arm did not come to rest within {timeout:g} s ({seen})")


def measure_arm(bus: ServoBus, servo_id: int, prompter: Prompter) -> ArmReading:
    bus.set_torque(servo_id, False)
    prompter.act("hang", "Torque is off. Let the arm hang freely and come to rest.")
    rest = read_still(bus, servo_id)
    prompter.act("push", "Push the arm in the direction you want to call positive, at least 20°, and hold it still.")
    pushed = read_still(bus, servo_id)
    push = wrapped(pushed - rest)
    if abs(push) < MIN_PUSH_TICKS:
        raise DataError(f"the push moved the arm {push * 360 / TICKS_PER_REV:+.1f}°; push it at least "
                        f"{MIN_PUSH_TICKS * 360 / TICKS_PER_REV:.0f}° and hold it still")
    prompter.act("release", "Let go: let the arm swing back and come to rest.")
    released = read_still(bus, servo_id)
    zero = round(rest + wrapped(released - rest) / 2) % TICKS_PER_REV
    return ArmReading(zero, 1 if push > 0 else -1, rest, pushed, released)
