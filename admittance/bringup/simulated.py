"""``admittance setup --mock``: the wizard against the simulated bench, with a simulated person.

The bench's arm carries a gravity load whose hanging angle is off the encoder's middle (an
``angle_offset``), so the measured ``zero_tick`` is not the default 2048; the simulated person
does what each instruction says by setting the hand torque, which reaches both the horn and the
force sensor (as a hand on the handle does). Tests drive the wizard through this.
"""

from __future__ import annotations

import math
import sys
import time
from typing import Any, TextIO

from admittance.mockbench.bench import MockBench

HANGING_OFFSET_RAD = 0.15  # where the simulated arm hangs: tick 2048 + 100
GRAVITY_TORQUE = 1.0  # N·m: m·g·l of the simulated arm
LOAD_INERTIA = 0.01  # kg·m²
PUSH_TORQUE = 0.5  # N·m: holds the arm about 30° off its rest
# The range of motion the simulated person shows: the arm held at asin(τ/m·g·l) each side of its rest.
RANGE_TORQUES = (-0.6, 0.8)  # N·m: -36.9° and +53.1°
RANGE_RAMP_S = 2.0
FACTORY_BAUD_CODE = 1  # 57 600 bit/s on Protocol 2.0
PRESS_PEAK = 0.8  # N·m at the top of the press (7.6 N at 0.105 m)


def simulated_bench(**options: Any) -> MockBench:
    """The bench the wizard rehearses on: one MX-64 with a hanging arm and a still hand, set to
    ROBOTIS's factory 57 600 bit/s. (A pty has no baud rate: the simulated wire keeps 1 Mbit/s
    timing, the rate the wizard moves the servo to.) The simulated person scripts the hand in
    Python as the wizard asks, so the sensor's stream is Python's."""
    settings = dict(gravity_torque=GRAVITY_TORQUE, load_inertia=LOAD_INERTIA, profile="still", sensor_stream="python",
                    effects={"angle_offset": HANGING_OFFSET_RAD}, baudrate=1_000_000,
                    servos=[{"id": 1, "registers": {"Baud Rate": FACTORY_BAUD_CODE}}])
    return MockBench(**(settings | options))


class SimulatedPerson:
    """A prompter whose actions are hand torques on the simulated bench.

    ``positive`` is the sign, in the encoder's direction, of what this person calls positive.
    """

    def __init__(self, bench: MockBench, *, positive: int = 1, press_s: float = 6.0, out: TextIO = sys.stderr):
        self.bench, self.positive, self.press_s, self.out = bench, positive, press_s, out

    def say(self, text: str) -> None:
        print(text, file=self.out, flush=True)

    def confirm(self, question: str) -> bool:
        self.say(f"{question} yes (simulated)")
        return True

    def act(self, action: str, instruction: str) -> None:
        self.say(f"{instruction} (simulated person: {action})")
        shape = {
            "push": lambda s: PUSH_TORQUE,
            # a person moves the arm to an end slowly: a step of 0.8 N·m would throw it over the top
            "range-low": lambda s: RANGE_TORQUES[0] * min(s / RANGE_RAMP_S, 1.0),
            "range-high": lambda s: RANGE_TORQUES[1] * min(s / RANGE_RAMP_S, 1.0),
            "press": lambda s: PRESS_PEAK * math.sin(math.pi * min(max(s / self.press_s, 0.0), 1.0)),
        }.get(action, lambda s: 0.0)  # hang, release, and the dry run until start_hand
        self._follow(shape)
        if action.startswith("range-"):  # a person says "done" once the arm is at the end, not before
            time.sleep(RANGE_RAMP_S + 0.5)

    def start_hand(self) -> None:
        """The dry run's pushes, once the loop runs (never during its tare)."""
        self._follow(lambda s: 0.15 * math.sin(2 * math.pi * 0.5 * s))

    def bench_stats(self) -> dict:
        """The simulated bench's counters, for the dry run's stop line."""
        return self.bench.stats()

    def _follow(self, shape) -> None:
        t0 = time.monotonic()
        self.bench.profile = lambda t: self.positive * shape(time.monotonic() - t0)
