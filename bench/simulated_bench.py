"""The simulated bench under CPU load: bus errors of the daemon, and failures of the tests that
drive the mock bus, for two trees side by side in one run (issue 11, "a clean simulated bench").

Each tree is a folder with the `admittance` package (and its built extension) and `tests/`: this
checkout, and for a before/after comparison an export of the commit to compare with, e.g.

    git archive 86a73a1 admittance tests pyproject.toml | tar -x -C /tmp/before
    cp <that commit's built admittance/_rtcore.abi3.so> /tmp/before/admittance/

    .venv/bin/python bench/simulated_bench.py --tree before=/tmp/before --tree after=. \\
        --burners 0,2,4 --runs 3 --duration 10 --test-burners 3 --test-runs 4

Without ``--tree`` it measures this checkout alone (``make bench``): idle against loaded.

For each number of CPU burners (busy-looping processes at the default nice level, started here
and stopped after), the trees take turns: `admittance run --duration S --stats-json` (the
embedded simulated bench) reports its bus errors by kind and, where the tree measures it, the
simulated bus thread's stalls; then pytest runs the tests that drive the mock bus
(`--tests`), and the failed tests are counted. Prints one table per part and the load
(`uptime`) before each burner level: the machine is shared, so read the two trees against each
other, not against another run.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

DEFAULT_TESTS = ("tests/test_mockbus_sdk.py", "tests/test_drivers_dynamixel.py", "tests/test_bringup.py")


def burners(n: int) -> list[subprocess.Popen]:
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]


def stop(procs: list[subprocess.Popen]) -> None:
    for p in procs:
        p.kill()
    for p in procs:
        p.wait()


def env_for(tree: Path) -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(tree), "PYTHONDONTWRITEBYTECODE": "1"}


def daemon_run(tree: Path, duration: float) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "stats.json"
        done = subprocess.run([sys.executable, "-m", "admittance", "run", "--duration", str(duration),
                               "--stats-json", str(path)], cwd=tree, env=env_for(tree), capture_output=True,
                              text=True, timeout=duration + 120)
        stats = json.loads(path.read_text()) if path.exists() else {}
    stats["exit"] = done.returncode
    stats["stop_line"] = next((line for line in done.stderr.splitlines() if "stopped (" in line), "")
    return stats


def test_run(tree: Path, tests: list[str]) -> tuple[int, int, list[str]]:
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *tests], cwd=tree,
                          env=env_for(tree), capture_output=True, text=True, timeout=1800)
    failed = re.findall(r"^FAILED (\S+)", done.stdout, re.M)
    passed = int(m.group(1)) if (m := re.search(r"(\d+) passed", done.stdout)) else 0
    return passed, len(failed), failed


def daemon_row(s: dict) -> str:
    kinds = {key: v for key, v in (s.get("bus_error_kinds") or {}).items() if v} or "-"
    counts = f"{s.get('cycles', '?')} | {s.get('overruns', '?')} | {s.get('bus_errors', '?')} | {kinds}"
    timing = s.get("bench", {}).get("bus", {}).get("timing", {})
    if not timing:
        return f"{counts} | not measured | - | -"
    rt = timing.get("rt", {})
    late = max(timing.get("reply_late_us", {}).get("max", 0), timing.get("wake_late_us", {}).get("max", 0))
    return f"{counts} | {rt.get('policy', '?')} {rt.get('priority', '')} | {timing.get('stalls', '-')} | {late / 1e3:.1f}"


def test_row(tree: Path, tests: list[str]) -> str:
    passed, failed, which = test_run(tree, tests)
    return f"{passed} | {failed} | {', '.join(which) or '-'}"


def under_load(levels: str, runs: int, trees: dict[str, Path], header: str, row, settle_s: float = 0.0) -> None:
    """One table per burner count in ``levels`` ("0,2,4"): the trees take turns, ``runs`` times."""
    for n in [int(b) for b in levels.split(",") if b != ""]:
        print(f"\n{n} burners; {uptime()}")
        print(f"| {header} |\n|{'---|' * (header.count('|') + 1)}")
        procs = burners(n)
        try:
            time.sleep(settle_s)
            for k in range(runs):
                for name, tree in trees.items():
                    print(f"| {name} | {k + 1} | {row(tree)} |", flush=True)
        finally:
            stop(procs)


def uptime() -> str:
    return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tree", action="append", metavar="NAME=DIR",
                        help="a tree to measure (repeatable; they take turns; default: this checkout)")
    parser.add_argument("--burners", default="0,2,4", help="CPU burner counts for the daemon runs (default 0,2,4)")
    parser.add_argument("--runs", type=int, default=2, help="daemon runs per tree and burner count (default 2)")
    parser.add_argument("--duration", type=float, default=10.0, help="seconds per daemon run (default 10)")
    parser.add_argument("--test-burners", default="0,3", help="burner counts for the test runs (default 0,3; '' = none)")
    parser.add_argument("--test-runs", type=int, default=1, help="pytest runs per tree and burner count (default 1)")
    parser.add_argument("--tests", nargs="*", default=list(DEFAULT_TESTS), help="the tests that drive the mock bus")
    args = parser.parse_args()
    trees = {name: Path(path).resolve() for name, _, path in (t.partition("=") for t in args.tree or
                                                                [f"this={Path(__file__).resolve().parents[1]}"])}

    print(f"## daemon runs: `admittance run --duration {args.duration:g}` on the embedded simulated bench")
    under_load(args.burners, args.runs, trees, "tree | run | cycles | overruns | bus errors | by kind | bus thread | "
               "stalls > 0.25 ms | longest late ms", lambda tree: daemon_row(daemon_run(tree, args.duration)),
               settle_s=1.0)
    print(f"\n## test runs: pytest {' '.join(args.tests)}")
    under_load(args.test_burners, args.test_runs, trees, "tree | run | passed | failed | failed tests",
               lambda tree: test_row(tree, args.tests))
    print(f"\nend: {uptime()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
