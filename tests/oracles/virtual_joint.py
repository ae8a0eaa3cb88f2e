"""TEST ORACLE: one cycle of the RT loop's virtual joint, written from Contract 1
(docs/architecture.md), not from the loop's code (``plant::admittance``).

The torque needed to stop the joint within the step is clipped to ±F (stick), damping is taken
implicitly (at the new velocity), then semi-implicit Euler: velocity first, position with it.
"""

from __future__ import annotations

import math


def step(theta: float, omega: float, tau: float, inertia: float, damping: float, coulomb: float,
         h: float) -> tuple[float, float]:
    """(θ, ω) after one step of ``h`` seconds under the user's torque ``tau``."""
    gain = h / inertia
    free = omega + gain * tau
    if abs(free) <= gain * coulomb:
        omega = 0.0
    else:
        omega = (free - math.copysign(gain * coulomb, free)) / (1.0 + gain * damping)
    return theta + h * omega, omega
