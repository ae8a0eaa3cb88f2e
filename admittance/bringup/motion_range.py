"""The joint's range of motion, measured: the position limits ``admittance run`` keeps the model in.

With torque off the person moves the arm to one end of the range it may use (a hard stop, a
cable, the edge of the table), holds it still, then to the other end. Each end is read at rest
(``arm.read_still``) and turned into a joint angle with the ``zero_tick`` and ``direction`` just
measured; the limits are those ends brought inward by a margin, so the model stops short of what
the person showed instead of on it. The hanging angle (0) must lie between the ends: a range
that does not contain it was measured on the wrong side of a wrap, or with the arm not moved.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from admittance.bringup.arm import TICKS_PER_REV, read_still, wrapped
from admittance.bringup.prompt import Prompter
from admittance.drivers.dynamixel import ServoBus
from admittance.errors import DataError

DEFAULT_MARGIN_RAD = math.radians(5.0)
MIN_SPAN_RAD = math.radians(20.0)  # what is left between the limits: less is no useful range


@dataclass(frozen=True)
class MotionRange:
    low_end: float  # rad, the ends the person showed
    high_end: float
    margin: float

    @property
    def position_min(self) -> float:
        return round(self.low_end + self.margin, 3)

    @property
    def position_max(self) -> float:
        return round(self.high_end - self.margin, 3)

    def line(self) -> str:
        return (f"range of motion {math.degrees(self.low_end):+.1f}° .. {math.degrees(self.high_end):+.1f}°; "
                f"limits with a {math.degrees(self.margin):.1f}° margin: position_min = {self.position_min} rad, "
                f"position_max = {self.position_max} rad")


def tick_angle(tick: float, zero_tick: int, direction: int) -> float:
    """The joint angle (rad, 0 = hanging) of a Present Position, within one turn of the zero."""
    return direction * wrapped(tick - zero_tick) * 2.0 * math.pi / TICKS_PER_REV


def limits_from_ends(a: float, b: float, margin: float) -> MotionRange:
    """The limits of two measured ends (in either order), or DataError when they make no range."""
    if not (math.isfinite(margin) and margin >= 0):
        raise DataError(f"the range margin must be a finite angle ≥ 0, got {margin!r}")
    low, high = min(a, b), max(a, b)
    if not low < 0.0 < high:
        raise DataError(f"the ends {math.degrees(low):+.1f}° and {math.degrees(high):+.1f}° do not enclose the "
                        "hanging angle 0: move the arm to one side of where it hangs, then to the other")
    found = MotionRange(low, high, margin)
    if found.position_max - found.position_min < MIN_SPAN_RAD:
        raise DataError(f"the range {math.degrees(low):+.1f}° .. {math.degrees(high):+.1f}° leaves less than "
                        f"{math.degrees(MIN_SPAN_RAD):.0f}° inside a {math.degrees(margin):.1f}° margin: "
                        "move the arm further, or give a smaller --range-margin")
    return found


def measure_range(bus: ServoBus, servo_id: int, zero_tick: int, direction: int, prompter: Prompter,
                  margin: float = DEFAULT_MARGIN_RAD) -> MotionRange:
    bus.set_torque(servo_id, False)
    prompter.act("range-low", "Torque is off. Move the arm to one end of the range it may use and hold it still.")
    first = tick_angle(read_still(bus, servo_id), zero_tick, direction)
    prompter.act("range-high", "Now move it to the other end of its range and hold it still.")
    second = tick_angle(read_still(bus, servo_id), zero_tick, direction)
    prompter.act("release", "Let go: let the arm swing back and come to rest.")
    read_still(bus, servo_id)  # the next step holds the arm where it is: not mid-swing
    return limits_from_ends(first, second, margin)
