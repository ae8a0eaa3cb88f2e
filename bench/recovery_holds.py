"""How long a servo's recovery holds its joint on the busy mock bus: the HIL glitch test's runs.

Runs tests/test_hil_faults.py::test_glitched_position_reads_never_move_the_joint (the daemon on
the mock bench over pseudo-terminals, 1 kHz, a SyncRead every cycle; every third read of the
servo's position glitched; a torque found off, then a brown-out, each recovered) ``--runs``
times, and reads every cycle of each run's session.mcap: each stretch of cycles in which joint 1
was marked torque_off, servo_silent or servo_error (held by its recovery; the brown-out's silence
is one of them, about 0.1 s by the bench's 0.2 s outage), and the stats' ``reads_deferred``
(SyncReads put off to give the recovery the bus, rtcore/rt/src/cycle.rs RECOVERY_WAIT_CYCLES).

Prints one line per run and a summary: the median and longest recovery hold (the silences left
out), and /proc/loadavg. Run it on two commits to compare them (the figures are this machine's,
at that load): the recovery's transactions compete with the SyncRead for each cycle's time.

Usage: ``.venv/bin/python bench/recovery_holds.py [--runs 10]``
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from mcap.reader import make_reader

from admittance import _rtcore

ROOT = Path(__file__).resolve().parents[1]
TEST = "tests/test_hil_faults.py::test_glitched_position_reads_never_move_the_joint"
KINDS = list(_rtcore.FAULT_KINDS)
HELD = {k: 1 << KINDS.index(k) for k in ("torque_off", "servo_silent", "servo_error")}


def holds(mcap: str) -> list[tuple[float, bool]]:
    """Each stretch of joint 1's cycles held by its recovery: (seconds, whether it was a silence)."""
    with open(mcap, "rb") as fh:
        cycles = [json.loads(m.data) for _, _, m in make_reader(fh).iter_messages(topics=["/joint1/cycle"])]
    out, start, silent, last = [], None, False, None
    for c in cycles:
        bits = int(c["fault"])
        if bits & sum(HELD.values()) and start is None:
            start, silent = c["t"], False
        if start is not None and bits & HELD["servo_silent"]:
            silent = True
        if start is not None and not bits & sum(HELD.values()):
            out.append((last - start, silent))
            start = None
        last = c["t"]
    if start is not None:
        out.append((last - start, silent))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10)
    args = ap.parse_args()
    recovery, failed = [], 0
    with tempfile.TemporaryDirectory(prefix="recovery-holds-") as tmp:
        for run in range(1, args.runs + 1):
            base = Path(tmp) / f"run{run}"
            base.mkdir()
            done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", f"--basetemp={base}", TEST],
                                  cwd=ROOT, capture_output=True, text=True)
            verdict = done.stdout.strip().splitlines()[-1] if done.stdout.strip() else "no output"
            failed += done.returncode != 0
            mcaps = glob.glob(f"{base}/*/rec/session.mcap")
            stats = glob.glob(f"{base}/*/stats.json")
            if not mcaps or not stats:
                print(f"run {run}: {verdict}; no recording")
                continue
            spans = holds(mcaps[0])
            recovery += [s for s, silent in spans if not silent]
            deferred = json.loads(Path(stats[0]).read_text()).get("reads_deferred")
            shown = ", ".join(f"{s:.3f}{' (silent)' if silent else ''}" for s, silent in spans)
            print(f"run {run}: {verdict}; held s: {shown}; reads_deferred {deferred}")
    load = " ".join(Path("/proc/loadavg").read_text().split()[:3]) if os.path.exists("/proc/loadavg") else "?"
    if recovery:
        print(f"recovery holds: median {statistics.median(recovery):.3f} s, longest {max(recovery):.3f} s, "
              f"{sum(s > 0.5 for s in recovery)} of {len(recovery)} over 0.5 s; {failed} of {args.runs} runs failed; "
              f"load {load}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
