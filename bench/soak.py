"""Soak: the real daemon for a long run on the simulated bench, with faults injected, watched over time.

`admittance run` drives the mock bench's servo (over pseudo-terminals, on the bench's stable
links) while the scripted hand pushes a sine. Every ``--fault-every`` seconds one fault of a
round is injected in turn (docs/faults.md: a torque found off, a brown-out, an input-voltage
shutdown, the bus unplugged then replugged, the sensor unplugged then replugged), so the
recovery paths run all along. Every ``--every`` seconds it samples the daemon's RSS
(/proc/PID/status) and its own stats over Zenoh (cycles, overruns, bus errors, fault counts).

Writes to ``--out``: ``samples.csv`` (one row per sample), ``summary.json`` and, when
matplotlib is present, ``soak.png`` (RSS, overruns per 1000 cycles, bus errors, over time).
Prints the summary: RSS after the warm-up (the first 10 %) and at the end, its slope over the
second half, the overrun rate in the first and second half side by side, bus errors, faults.

Fails (exit 1) if the daemon dies or exits non-zero, does not end the run running with its bus
up, or its RSS grows by more than ``--max-rss-growth-mb`` after the warm-up.

Usage: ``.venv/bin/python bench/soak.py`` (30 min), ``--seconds 60`` (the CI's version),
``--no-faults`` (a quiet run).
"""

from __future__ import annotations

import argparse
import csv
import json
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import tomli_w

from admittance import data
from admittance.daemon.zenoh_iface import Client
from admittance.mockbench.bench import BenchConfig, MockBench

ADMITTANCE = Path(sys.executable).with_name("admittance")
PREFIX = "soak/arm"
WARMUP = 0.1  # the first 10 % of the run: imports, tare, allocator warm-up
# One round of faults, one step per --fault-every; a step of two commands replugs after REPLUG_S.
ROUND = (("servo 1 torque-off",), ("servo 1 brown-out 0.2",), ("servo 1 hardware-error 0x01",),
         ("bus unplug", "bus replug"), ("sensor unplug", "sensor replug"))
REPLUG_S = 0.5
COLUMNS = ("t_s", "rss_mb", "cycles", "overruns", "bus_errors", "faults", "mode", "bus")


def free_endpoint() -> str:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def write_config(folder: Path, bench: MockBench, endpoint: str) -> Path:
    links = bench.links
    doc = {
        "bus": {"port": links["bus"]},
        "joints": [{"id": 1, "model": "MX-64", "params": str(data.params_file("MX-64")),
                    "virtual_inertia": 0.02, "virtual_damping": 0.1}],
        "sensor": {"kind": "optoforce", "port": links["sensor"], "lever_arm": 0.105, "tare_samples": 100},
        "loop": {"rate_hz": 1000.0, "sync_read_divisor": 10},
        # A soak injects a recovery every few seconds: allow them all (the policy's limits are
        # the HIL tests' business, tests/test_hil_faults.py).
        "faults": {"max_recoveries": 16, "recovery_window_s": 1.0},
        "zenoh": {"prefix": PREFIX, "listen": [endpoint]},
    }
    path = folder / "daemon.toml"
    path.write_text(tomli_w.dumps(doc))
    return path


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def latest_stats(sub, last: dict | None) -> dict | None:
    for kind, message in sub.drain():
        if kind == "stats":
            last = message
    return last


def wait_for_first_stats(client, proc: subprocess.Popen, timeout: float = 120.0) -> None:
    sub = client.try_stream(PREFIX)
    deadline = time.monotonic() + timeout
    try:
        while time.monotonic() < deadline and proc.poll() is None:
            if latest_stats(sub, None) is not None:
                return
            time.sleep(0.05)
    finally:
        sub.close()
    if proc.poll() is not None:  # its own reason (a record folder in use, say), not only its status
        raise SystemExit(f"soak: the daemon exited {proc.returncode} before its first stats: "
                         f"{proc.stderr.read().strip()[-500:]}")
    raise SystemExit(f"soak: the daemon published no stats in {timeout:g} s")


def soak(args: argparse.Namespace, out: Path) -> tuple[list[dict], int, str]:
    endpoint = free_endpoint()
    with MockBench(BenchConfig(profile="sine:amplitude=0.15,frequency=0.5")) as bench:
        config = write_config(out, bench, endpoint)
        proc = subprocess.Popen([str(ADMITTANCE), "run", "--config", str(config), "--record", str(out / "rec"),
                                 "--stats-json", str(out / "stats.json")], stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, text=True)
        samples: list[dict] = []
        try:
            with Client([endpoint]) as client:
                wait_for_first_stats(client, proc)
                samples = watch(args, bench, client, proc)
        finally:
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
            _, stderr = proc.communicate(timeout=60)
    return samples, proc.returncode, stderr


def watch(args: argparse.Namespace, bench: MockBench, client, proc: subprocess.Popen) -> list[dict]:
    sub = client.try_stream(PREFIX)
    start = time.monotonic()
    next_sample, next_fault, step, replug_at, replug = start, start + args.fault_every, 0, None, None
    stats, samples = None, []
    try:
        while (now := time.monotonic()) < start + args.seconds and proc.poll() is None:
            stats = latest_stats(sub, stats)
            if replug is not None and now >= replug_at:
                inject(bench, replug)
                replug = None
            if args.faults and replug is None and now >= next_fault and now + args.fault_every <= start + args.seconds:
                commands = ROUND[step % len(ROUND)]
                inject(bench, commands[0])
                replug, replug_at = (commands[1], now + REPLUG_S) if len(commands) > 1 else (None, None)
                step, next_fault = step + 1, now + args.fault_every
            if now >= next_sample and stats is not None:
                samples.append(sample(now - start, proc.pid, stats))
                next_sample += args.every
            time.sleep(0.05)
        if replug is not None:
            inject(bench, replug)
    finally:
        sub.close()
    return samples


def inject(bench: MockBench, line: str) -> None:
    """One fault command; a refused one ends the soak (else it would run on without its faults)."""
    reply = bench.command(line)
    if not reply.get("ok"):
        raise SystemExit(f"soak: the mock bench refused {line!r}: {reply.get('error')}")


def sample(t: float, pid: int, stats: dict) -> dict:
    faults = sum(stats.get("faults", {}).values())
    return {"t_s": round(t, 3), "rss_mb": round(rss_mb(pid), 3), "cycles": stats["cycles"],
            "overruns": stats["overruns"], "bus_errors": stats["bus_errors"], "faults": faults,
            "mode": stats.get("mode", "?"), "bus": stats.get("bus", {}).get("state", "?")}


def summarize(samples: list[dict]) -> dict:
    t = np.array([s["t_s"] for s in samples])
    rss = np.array([s["rss_mb"] for s in samples])
    cycles = np.array([s["cycles"] for s in samples], dtype=float)
    overruns = np.array([s["overruns"] for s in samples], dtype=float)
    warm = t >= WARMUP * t[-1]
    half = len(t) // 2

    def rate(a: int, b: int) -> float:  # overruns per 1000 cycles between two samples
        return 1000.0 * (overruns[b] - overruns[a]) / max(cycles[b] - cycles[a], 1.0)

    second = slice(half, None)
    slope = float(np.polyfit(t[second], rss[second], 1)[0] * 3600.0) if len(t[second]) >= 3 else float("nan")
    return {
        "seconds": float(t[-1]), "samples": len(t), "cycles": int(cycles[-1]),
        "rss_after_warmup_mb": float(rss[warm][0]), "rss_end_mb": float(rss[-1]), "rss_max_mb": float(rss.max()),
        "rss_growth_mb": float(rss[-1] - rss[warm][0]), "rss_slope_second_half_mb_per_h": slope,
        "overruns_per_1000_first_half": rate(0, half), "overruns_per_1000_second_half": rate(half, len(t) - 1),
        "bus_errors": samples[-1]["bus_errors"], "fault_events": samples[-1]["faults"],
        "mode_at_end": samples[-1]["mode"], "bus_at_end": samples[-1]["bus"],
    }


def plot(samples: list[dict], path: Path) -> bool:
    try:
        import matplotlib
    except ImportError:
        return False
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.array([s["t_s"] for s in samples]) / 60.0
    cycles = np.array([s["cycles"] for s in samples], dtype=float)
    overruns = np.array([s["overruns"] for s in samples], dtype=float)
    per_1000 = 1000.0 * np.diff(overruns, prepend=overruns[0]) / np.maximum(np.diff(cycles, prepend=cycles[0]), 1.0)
    fig, axes = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
    axes[0].plot(t, [s["rss_mb"] for s in samples])
    axes[0].set_ylabel("RSS (MB)")
    axes[1].plot(t, per_1000)
    axes[1].set_ylabel("overruns / 1000 cycles")
    axes[2].plot(t, [s["bus_errors"] for s in samples], label="bus errors")
    axes[2].plot(t, [s["faults"] for s in samples], label="fault events")
    axes[2].set_ylabel("count (cumulative)")
    axes[2].set_xlabel("minutes")
    axes[2].legend()
    fig.suptitle("admittance run on the mock bench, faults injected" if any(s["faults"] for s in samples)
                 else "admittance run on the mock bench")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return True


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=1800.0, help="length of the soak (default 30 min)")
    parser.add_argument("--every", type=float, help="seconds between samples (default: seconds/120, at least 0.5)")
    parser.add_argument("--fault-every", type=float, help="seconds between injected faults (default: seconds/12, "
                                                          "at least 2)")
    parser.add_argument("--no-faults", dest="faults", action="store_false", help="inject no faults")
    parser.add_argument("--max-rss-growth-mb", type=float, default=32.0, help="fail above this RSS growth")
    parser.add_argument("--out", type=Path, help="output folder (default: a new temporary one)")
    args = parser.parse_args()
    if not args.seconds > 0:
        parser.error("--seconds must be > 0")
    args.every = args.every or max(args.seconds / 120.0, 0.5)
    args.fault_every = args.fault_every or max(args.seconds / 12.0, 2.0)
    out = args.out or Path(tempfile.mkdtemp(prefix="admittance-soak-"))
    out.mkdir(parents=True, exist_ok=True)
    samples, status, stderr = soak(args, out)
    problems = []
    if status != 0:
        problems.append(f"the daemon exited {status}: {stderr.strip().splitlines()[-1:] or ''}")
    if len(samples) < 3:
        problems.append(f"only {len(samples)} samples")
        print(stderr, file=sys.stderr)
        print("soak: FAILED: " + "; ".join(problems), file=sys.stderr)
        return 1
    with (out / "samples.csv").open("w", newline="") as fh:
        writer = csv.DictWriter(fh, COLUMNS)
        writer.writeheader()
        writer.writerows(samples)
    summary = summarize(samples)
    summary["plot"] = str(out / "soak.png") if plot(samples, out / "soak.png") else None
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    for key, value in summary.items():
        print(f"{key:36s} {value:.3f}" if isinstance(value, float) else f"{key:36s} {value}")
    print(f"{'output':36s} {out}")
    if summary["rss_growth_mb"] > args.max_rss_growth_mb:
        problems.append(f"RSS grew {summary['rss_growth_mb']:.1f} MB after the warm-up (> {args.max_rss_growth_mb:g})")
    if summary["mode_at_end"] != "running" or summary["bus_at_end"] != "up":
        problems.append(f"the run ended {summary['mode_at_end']} with its bus {summary['bus_at_end']}")
    if problems:
        print("soak: FAILED: " + "; ".join(problems), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
