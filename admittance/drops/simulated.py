"""The drop tests on the simulated bench: a pendulum (rod, bob, distance) on the mock's servo.

The pendulum load is the contract's geometry (a uniform rod pivoted at its end, a point bob at
``distance``), turned into the inertia and gravity torque the simulated horn carries by the same
function ``identify`` uses to read a manifest (admittance.formats.trial.load_geometry). Moving
the bob is starting a bench with the new load: the simulated person re-clamps it between
distances as a person does on the real bench. The servo behind the horn is the mock's own plant
(the packaged fit of its model, ``params/<model>.toml``), so ``identify`` on these drops should
give that plant back (tests/test_drops.py).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from admittance.drops.procedure import BUS_RETRIES, REPLY_SLACK_MS, DropSession, Joint
from admittance.formats.trial import load_geometry

MODEL = "MX-64"
SERVO_ID = 1


def pendulum_load(rod: dict | None, bob: dict | None, distance: float) -> dict[str, float]:
    """The mock servo's load keys for a pendulum: its inertia (kg·m²) and m·g·l (N·m)."""
    inertia, gravity = load_geometry(rod, bob, distance)
    return {"load_inertia": inertia, "gravity_torque": gravity}


@contextmanager
def simulated_session(rod: dict | None, bob: dict | None, distance: float, joint: Joint, *, say=print,
                      **bench_options: Any) -> Iterator[DropSession]:
    """A simulated bench with the pendulum's bob at ``distance``, and the bus to drive it."""
    from admittance.drivers.dynamixel import ServoBus
    from admittance.mockbench.bench import MockBench

    servo = {"id": joint.servo_id, "model": MODEL} | pendulum_load(rod, bob, distance)
    with MockBench(servos=[servo], profile="still", **bench_options) as bench:
        say(f"drops: simulated bench, bob at {distance:g} m")
        with ServoBus(bench.bus_port, baudrate=bench.config.baudrate, protocol=bench.config.protocol,
                      retries=BUS_RETRIES,
                      reply_slack_ms=REPLY_SLACK_MS) as bus:
            bus.prepare(joint.servo_id)
            yield DropSession(bus, joint, say=say)
