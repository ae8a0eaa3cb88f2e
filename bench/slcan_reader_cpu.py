"""What reading a 1 kHz force sensor costs the reader's process: serial OptoForce against CAN over slcan.

Both sensors are the mock bench's (``admittance mock-bench --sensor optoforce|slcan``, in a
subprocess, so only the reader's own CPU is counted). The serial reader takes whatever is
waiting in one read; python-can's slcan interface reads its serial port one byte at a time
(44 bytes of text per 3-axis sample), which is what this measures. Printed: samples/s read,
the process's CPU share over the window, and the slcan / serial ratio, which means the same
on any machine.

Run: .venv/bin/python bench/slcan_reader_cpu.py [--window 3]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time

from admittance.drivers.can_sensor import CanForceReader
from admittance.drivers.optoforce import OptoForceSerialReader
from admittance.drivers.force_reader import SampleBuffer

COUNTS_PER_NEWTON = 451.89
WINDOW_S = 3.0
WARM_UP_SAMPLES = 200


def measure(kind: str, window_s: float) -> tuple[float, float]:
    """(samples/s, CPU seconds per second) of a reader of the mock bench's ``kind`` sensor."""
    bench = subprocess.Popen([sys.executable, "-m", "admittance", "mock-bench", "--print-ports", "--sensor", kind], stdout=subprocess.PIPE, text=True)
    try:
        port = json.loads(bench.stdout.readline())["sensor"]
        sink = SampleBuffer()
        if kind == "optoforce":
            reader = OptoForceSerialReader(port, COUNTS_PER_NEWTON, sink)
        else:
            reader = CanForceReader(port, COUNTS_PER_NEWTON, sink, interface="slcan")
        with reader:
            if not sink.wait_for(WARM_UP_SAMPLES, timeout=30):
                raise SystemExit(f"slcan_reader_cpu: the {kind} reader on {port} delivered {sink.total} samples "
                                 f"in 30 s, not the {WARM_UP_SAMPLES} of the warm-up; nothing to measure")
            n0, cpu0, t0 = sink.total, time.process_time(), time.monotonic()
            time.sleep(window_s)
            n1, cpu1, t1 = sink.total, time.process_time(), time.monotonic()
    finally:
        bench.terminate()
        bench.wait()
    return (n1 - n0) / (t1 - t0), (cpu1 - cpu0) / (t1 - t0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--window", type=float, default=WINDOW_S, metavar="S",
                        help=f"seconds each reader is measured over (default {WINDOW_S:g})")
    args = parser.parse_args()
    if not 0 < args.window < 3600:
        parser.error("--window must be between 0 and 3600 s")
    results = {kind: measure(kind, args.window) for kind in ("optoforce", "slcan")}
    for kind, (rate, cpu) in results.items():
        print(f"{kind:10s} {rate:7.0f} samples/s   reader process CPU {100 * cpu:5.1f} %")
    print(f"slcan / serial CPU: {results['slcan'][1] / results['optoforce'][1]:.1f}x")


if __name__ == "__main__":
    main()
