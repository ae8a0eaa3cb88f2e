"""How long a Zenoh query to the daemon waits when the daemon's main thread is starved of CPU.

The real daemon (`admittance run` on the embedded simulated bench, recording every cycle, as
tests/test_hil_remote_input.py runs it) is started; once it is up, its main thread alone (the
queries' and the recording's thread; the RT threads are SCHED_FIFO and unaffected) is reniced to
``--nice`` while ``--busy`` busy loops run beside it: a machine loaded far beyond its cores, on
purpose. Then, for ``--seconds``, hostile payloads (the HIL test's) are sent to its params key,
each followed by a params get, every get waiting up to ``--timeout``.

Prints, in one run: the gets sent, answered and timed out, the slowest and the median wait, the
daemon's own `longest_poll_gap_s` (the longest its queryables went unpolled) and
`telemetry_drops` (cycles the starved thread could not record), and /proc/loadavg.
Run it on two commits to compare them (the figures are this machine's, at that load).

Usage: ``.venv/bin/python bench/query_starvation.py [--seconds 60] [--busy 2] [--nice 19]``
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import tomli_w

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from daemon_process import ADMITTANCE, EXIT_TIMEOUT_S, kill, wait_alive  # noqa: E402
from helpers import free_endpoint  # noqa: E402
from test_hil_remote_input import ISSUE_PAYLOADS, KEYS, PARAMS, PREFIX  # noqa: E402

EXTRA = [b'{"rate_hz":[]}', b'{"deadband": NaN}', b"[" * 100_000, b'{"deadband": "' + b"x" * (1 << 20) + b'"}', b"",
         b'{"virtual_damping": 0.1}', b'{"samples": 5}', b"\x93_"]


def daemon_config(folder: Path, endpoint: str) -> Path:
    doc = {"bus": {"port": "mock"},
           "joints": [{"id": 1, "model": "MX-64", "virtual_inertia": 0.02, "virtual_damping": 0.1,
                       "virtual_coulomb": 0.02}],
           "sensor": {"kind": "optoforce", "port": "mock", "lever_arm": 0.105}, "loop": {"sync_read_divisor": 1},
           "zenoh": {"prefix": PREFIX, "listen": [endpoint]},
           "bench": {"profile": "sine:amplitude=0.15,frequency=1", "hand_delay_s": 0.2}}
    path = folder / "daemon.toml"
    path.write_text(tomli_w.dumps(doc))
    return path


def timed_get(session, key: str, payload: bytes | None, timeout: float) -> tuple[float, bool]:
    """(seconds until the get ended, whether every reply was an answer, not zenoh's Timeout)."""
    kwargs = {} if payload is None else {"payload": payload}
    start = time.monotonic()
    answered = all(reply.ok is not None for reply in session.get(key, timeout=timeout, **kwargs))
    return time.monotonic() - start, answered


def replay(session, seconds: float, timeout: float, seed: int) -> list[tuple[float, bool]]:
    rnd = random.Random(seed)
    payloads = ISSUE_PAYLOADS + EXTRA
    gets = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        gets.append(timed_get(session, rnd.choice(KEYS), rnd.choice(payloads), timeout))
        gets.append(timed_get(session, PARAMS, None, timeout))
    return gets


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--busy", type=int, default=2, help="busy loops beside the daemon")
    ap.add_argument("--nice", type=int, default=19, help="the daemon's main thread's niceness")
    ap.add_argument("--timeout", type=float, default=60.0, help="each get's timeout (s)")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    from admittance.daemon.zenoh_iface import Client

    with tempfile.TemporaryDirectory(prefix="query-starvation-") as tmp:
        folder, endpoint = Path(tmp), free_endpoint()
        proc = subprocess.Popen([str(ADMITTANCE), "run", "--config", str(daemon_config(folder, endpoint)),
                                 "--record", str(folder / "rec"), "--stats-json", str(folder / "stats.json")],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        busy = []
        try:
            wait_alive(endpoint, PREFIX)
            os.setpriority(os.PRIO_PROCESS, proc.pid, args.nice)  # a tid: the main thread only
            busy = [subprocess.Popen(["sh", "-c", "while :; do :; done"]) for _ in range(args.busy)]
            with Client([endpoint]) as client:
                gets = replay(client._session, args.seconds, args.timeout, args.seed)
            load = open("/proc/loadavg").read().split()[:3]
        finally:
            for loop in busy:
                loop.kill()
                loop.wait()
            if proc.poll() is None:
                os.setpriority(os.PRIO_PROCESS, proc.pid, 0)  # let it stop in good time
                proc.send_signal(signal.SIGINT)
                try:
                    proc.wait(EXIT_TIMEOUT_S)
                except subprocess.TimeoutExpired:
                    kill(proc)
        stats = json.loads((folder / "stats.json").read_text())
    waits = [wait for wait, _ in gets]
    print(json.dumps({
        "gets": len(gets), "answered": sum(ok for _, ok in gets), "timed_out": sum(not ok for _, ok in gets),
        "wait_max_s": round(max(waits), 2), "wait_median_s": round(statistics.median(waits), 3),
        "longest_poll_gap_s": stats["daemon"].get("longest_poll_gap_s"),
        "daemon_queries": stats["daemon"]["queries"], "telemetry_drops": stats.get("telemetry_drops"),
        "cycles": stats["cycles"], "loadavg": load, "busy": args.busy, "nice": args.nice, "seconds": args.seconds}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
