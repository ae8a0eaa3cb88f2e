"""Stale-sensor holds of the daemon on the embedded bench under CPU load, with the simulated
DAQ streaming from Python and from Rust, side by side in one run (issue 18's target: 0 holds in
`admittance run --duration 600` with two CPU burners beside it).

Why both: the daemon's reader (Rust, its own thread) and loop never wait for the GIL, but the
embedded bench's simulated OptoForce DAQ did (`[bench] sensor_stream = "python"`): its samples
came late in bursts on a loaded machine and the loop held the joint. `"rust"` streams them from
a thread beside the simulated bus (dxlsim/src/daq.rs), as a real DAQ streams on its own clock.

Each run is `admittance run --duration S --stats-json` on the default embedded bench, with
``--burners`` busy-looping processes started before and killed after; the streams take turns
(``--runs`` each). Per run: stale-sensor holds (`sensor_stale_events`), the reader's longest gap
between samples beside the simulated DAQ's own longest gap between two frames written (the
Rust stream's `max_write_gap_ns`: a reader's gap no longer than it is the source's), the loop's overruns and bus errors, and the load average before the run: the
machine is shared, so read the two streams against each other, not against another run.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

import tomli_w

sys.path.insert(0, str(Path(__file__).resolve().parent))
from loop_timing import cpu_burners, free_tcp_port  # noqa: E402

from admittance import data  # noqa: E402

BENCH_CONFIG = Path(data.__file__).parent / "bench.toml"
STREAMS = ("python", "rust")


def daemon_run(stream: str, duration: float) -> dict:
    """One `admittance run` on the embedded bench with ``stream``; its stats and stop line."""
    with tempfile.TemporaryDirectory() as tmp:
        config, stats = Path(tmp) / "daemon.toml", Path(tmp) / "stats.json"
        doc = tomllib.loads(BENCH_CONFIG.read_text())  # `make run`'s configuration, the stream changed
        doc["joints"][0]["params"] = str(BENCH_CONFIG.parent / doc["joints"][0]["params"])
        doc["bench"]["sensor_stream"] = stream
        doc["zenoh"] |= {"prefix": f"bench/stream-{os.getpid()}", "listen": [f"tcp/127.0.0.1:{free_tcp_port()}"]}
        config.write_text(tomli_w.dumps(doc))
        done = subprocess.run([sys.executable, "-m", "admittance", "run", "--config", str(config), "--duration",
                               str(duration), "--stats-json", str(stats)], capture_output=True, text=True,
                              timeout=duration + 120)
        out = json.loads(stats.read_text()) if stats.exists() else {}
    out["exit"] = done.returncode
    out["stop_line"] = next((line for line in done.stderr.splitlines() if "stopped (" in line), done.stderr[-300:])
    return out


def row(stream: str, load: str, stats: dict) -> str:
    sensor = stats.get("daemon", {}).get("sensor", {})
    gap_ms = sensor.get("max_gap_ns", 0) / 1e6
    write_gap = stats.get("bench", {}).get("sensor", {}).get("max_write_gap_ns")
    source = "n/a" if write_gap is None else f"{write_gap / 1e6:.1f}"  # the Python stream does not time it
    return (f"| {stream} | {load} | {stats.get('exit')} | {stats.get('sensor_stale_events', '?')} | {gap_ms:.1f} | {source} | "
            f"{stats.get('overruns', '?')} | {stats.get('bus_errors', '?')} | {stats.get('cycles', '?')} |")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=60.0, help="seconds per daemon run (default 60)")
    parser.add_argument("--runs", type=int, default=1, help="runs per stream, taking turns (default 1)")
    parser.add_argument("--burners", type=int, default=2, help="CPU burners beside the daemon (default 2)")
    parser.add_argument("--streams", nargs="+", choices=STREAMS, default=list(STREAMS))
    args = parser.parse_args()
    print(f"admittance run --duration {args.duration:g} on the embedded bench, {args.burners} CPU burners; "
          f"{os.cpu_count()} CPUs")
    print("| stream | load before (1/5/15 min) | exit | stale holds | reader's longest gap, ms | "
          "DAQ's longest write gap, ms | overruns | bus errors | cycles |")
    print("|---|---|---|---|---|---|---|---|---|")
    holds: dict[str, list[int]] = {s: [] for s in args.streams}
    for _ in range(args.runs):
        for stream in args.streams:
            load = " ".join(Path("/proc/loadavg").read_text().split()[:3])
            burners = cpu_burners(args.burners)
            try:
                stats = daemon_run(stream, args.duration)
            finally:
                for p in burners:
                    p.kill()
                    p.wait()
            print(row(stream, load, stats), flush=True)
            if stats["exit"] != 0:
                print(f"  {stream}: {stats['stop_line']}", file=sys.stderr)
                return 1
            holds[stream].append(int(stats.get("sensor_stale_events", -1)))
    print("stale holds per stream: " + ", ".join(f"{s} {sum(h)} in {len(h)} runs" for s, h in holds.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
