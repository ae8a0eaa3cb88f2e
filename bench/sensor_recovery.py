"""How long a force reader takes to deliver samples again after its sensor is plugged back in.

The simulated OptoForce sensor (1 kHz, on a pseudo-terminal behind a stable link) is unplugged
for a given outage, then replugged; the serial reader, reading the link, reopens it with
backoff (0.05 s doubling to 2 s). Measured per outage: the time from the replug to the first
sample pushed to the sink, against the wait the backoff schedule predicts (the time to the
first reopen attempt after the replug), side by side. Outages are wall time here on purpose:
what is measured is the reader's reaction to a replug at a moment it does not know.

Run: .venv/bin/python bench/sensor_recovery.py [--outages 0.1 0.5 1 3] [--repeats 3]
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import tempfile
import time

from admittance.drivers.optoforce import OptoForceSerialReader
from admittance.drivers.force_reader import RECONNECT_FIRST_S, RECONNECT_MAX_S, SampleBuffer
from admittance.mockbench.hand import make_profile
from admittance.mockbench.simulated_sensor import ForceModel, SimulatedOptoForce

OUTAGES_S = (0.1, 0.5, 1.0, 3.0)
REPEATS = 3


def predicted_wait(outage_s: float) -> float:
    """The wait from a replug at ``outage_s`` after the failure to the next reopen attempt."""
    t, delay = 0.0, RECONNECT_FIRST_S
    while t + delay < outage_s:
        t += delay
        delay = min(2 * delay, RECONNECT_MAX_S)
    return t + delay - outage_s


def recovery_s(sim: SimulatedOptoForce, reader: OptoForceSerialReader, buffer: SampleBuffer, outage_s: float) -> float:
    assert buffer.wait_for(buffer.total + 10, timeout=30)
    sim.unplug()
    deadline = time.monotonic() + 30
    while reader.state != "reconnecting" and time.monotonic() < deadline:
        time.sleep(0.001)
    time.sleep(outage_s)
    pushed = buffer.total
    sim.replug()
    replugged = time.monotonic()
    assert buffer.wait_for(pushed + 1, timeout=30), "no sample after the replug"
    return time.monotonic() - replugged


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--outages", type=float, nargs="+", default=list(OUTAGES_S), metavar="S",
                        help=f"outages to measure, s (default {' '.join(map(str, OUTAGES_S))})")
    parser.add_argument("--repeats", type=int, default=REPEATS, help=f"replugs per outage (default {REPEATS})")
    args = parser.parse_args()
    if not 1 <= args.repeats <= 100 or not all(math.isfinite(o) and 0 <= o <= 600 for o in args.outages):
        parser.error("--repeats must be 1-100 and every outage 0-600 s")
    with tempfile.TemporaryDirectory() as folder:
        sim = SimulatedOptoForce(make_profile("still:torque=0.1"), ForceModel(), rate_hz=1000, link=os.path.join(folder, "ttyACM"))
        buffer = SampleBuffer()
        with sim, OptoForceSerialReader(sim.link_path, 451.89, buffer) as reader:
            median = f"replug → sample, s (median of {args.repeats})"
            print(f"{'outage s':>9} | {median:>34} | {'backoff predicts, s':>19}")
            for outage in args.outages:
                times = [recovery_s(sim, reader, buffer, outage) for _ in range(args.repeats)]
                print(f"{outage:9.2f} | {statistics.median(times):34.3f} | {predicted_wait(outage):19.3f}")
            print(f"reconnects {reader.stats()['reconnects']}, reopen failures {reader.stats()['reopen_failures']}")
    print(f"load: {os.getloadavg()[0]:.2f} (1-min average)")


if __name__ == "__main__":
    main()
