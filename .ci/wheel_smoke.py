"""Smoke test of an installed wheel: the commands a lab runs, from a folder outside the checkout.

Run by .ci/run with the interpreter of a fresh venv that has only the wheel (and its default
dependencies) installed, in an empty working directory, with no Rust toolchain on PATH:

    $VENV/bin/python .ci/wheel_smoke.py

Each entry of smoke_steps() is one command line (run with the venv's ``admittance``) and what its
output must show. Add a command by adding an entry; a step with ``until_signal`` runs in the
background until its first stdout line arrives, then gets SIGTERM and must exit 0.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

BIN = Path(sys.executable).parent
ADMITTANCE = BIN / "admittance"
TIMEOUT_S = 300


@dataclass
class Step:
    name: str
    argv: list[str]
    check: Callable[[str], None] = lambda out: None  # gets stdout; raises AssertionError on failure
    until_signal: bool = False


def _installed_not_checkout(out: str) -> None:
    location = Path(out.strip())
    assert location.is_relative_to(BIN.parent), f"admittance imported from {location}, not from the venv"
    assert (location.parent / "data" / "bench.toml").is_file(), "the packaged bench configuration is missing"


def _stats(path: str) -> Callable[[str], None]:
    def check(out: str) -> None:
        stats = json.loads(Path(path).read_text())
        assert stats["cycles"] > 0 and stats["sensor_samples"] > 0, stats
    return check


def _ports(line: str) -> None:
    ports = json.loads(line)
    assert Path(ports["bus"]).exists() and Path(ports["sensor"]).exists(), ports


def _identified(path: str) -> Callable[[str], None]:
    def check(out: str) -> None:
        result = json.loads(Path(path).read_text())
        assert result["params"]["motor_inertia"] > 0, result["params"]
    return check


def _fidelity(path: str) -> Callable[[str], None]:
    def check(out: str) -> None:
        result = json.loads(Path(path).read_text())
        assert result["rendering_rmse"] > 0 and result["servo"]["time_constant"] > 0, result.get("servo")
        assert result["target_source"].startswith("recording"), result["target_source"]
    return check


def _joint_line(out: str) -> None:
    assert "joint 1: MX-64" in out, out
    limits = tomllib.loads(Path("bench.toml").read_text())["joints"][0]["limits"]
    assert -1.0 < limits["position_min"] < 0 < limits["position_max"] < 1.2, limits  # the range the wizard measured


def _docs(topic: str, word: str) -> Callable[[str], None]:
    def check(out: str) -> None:
        assert out.startswith("# ") and word in out, out[:200]
    return check


def _unit_for_this_venv(out: str) -> None:
    assert f"ExecStart={ADMITTANCE} run --config /etc/admittance/admittance.toml" in out, out


def _example_config(out: str) -> None:
    assert "[bus]" in out and "[[joints]]" in out and "[sensor]" in out, out[:200]


def _bench_run() -> list[str]:
    """The embedded bench; if another process holds its Zenoh port (a shared dev machine), the
    same packaged configuration on a free port (its params then resolve to the shipped fit)."""
    with socket.socket() as s:
        if s.connect_ex(("127.0.0.1", 7447)) != 0:
            return ["run"]
        s.close()
    from admittance import data  # the installed package (this interpreter is the venv's)

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    text = data.bench_config().read_text().replace("tcp/127.0.0.1:7447", f"tcp/127.0.0.1:{port}")
    Path("bench-free-port.toml").write_text(text)
    return ["run", "--config", "bench-free-port.toml"]


def smoke_steps() -> list[Step]:
    """The list to extend: one Step per command a lab runs after `pip install admittance`."""
    return [
        Step("import location", [str(BIN / "python"), "-c", "import admittance; print(admittance.__file__)"],
             _installed_not_checkout),
        Step("help", ["--help"]),
        Step("example config", ["run", "--print-example-config"], _example_config),
        Step("run on the embedded bench", [*_bench_run(), "--duration", "3", "--stats-json", "stats.json"],
             _stats("stats.json")),
        Step("record a session", [*_bench_run(), "--duration", "8", "--record", "rec"]),
        Step("fidelity", ["fidelity", "rec", "--json", "fidelity.json", "--quiet"], _fidelity("fidelity.json")),
        Step("fidelity on the MCAP", ["fidelity", "rec/session.mcap", "--json", "fidelity-mcap.json", "--quiet"],
             _fidelity("fidelity-mcap.json")),
        Step("mock-bench", ["mock-bench", "--print-ports"], _ports, until_signal=True),
        Step("synth", ["synth", "ds", "--trials", "4", "--duration", "4"]),
        Step("identify", ["identify", "ds", "--json", "ident.json", "--quiet"], _identified("ident.json")),
        Step("setup rehearsal", ["setup", "--mock", "--dry-run", "1", "--out", "bench.toml"]),
        Step("the wizard's file", ["run", "--check", "--config", "bench.toml"], _joint_line),
        Step("docs datasets", ["docs", "datasets"], _docs("datasets", "bob_distance")),
        Step("docs recordings", ["docs", "recordings"], _docs("recordings", "theta_model")),
        Step("service unit", ["service", "install", "--print"], _unit_for_this_venv),
    ]


def run_step(step: Step) -> float:
    argv = step.argv if step.argv[0].startswith("/") else [str(ADMITTANCE), *step.argv]
    t0 = time.monotonic()
    if step.until_signal:
        proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            line = proc.stdout.readline()
            step.check(line)
            proc.send_signal(signal.SIGTERM)
            _, err = proc.communicate(timeout=30)
        finally:
            proc.kill()
        assert proc.returncode == 0, f"exit {proc.returncode} after SIGTERM: {err.strip()}"
    else:
        done = subprocess.run(argv, capture_output=True, text=True, timeout=TIMEOUT_S)
        assert done.returncode == 0, f"exit {done.returncode}: {done.stderr.strip()[-2000:]}"
        step.check(done.stdout)
    return time.monotonic() - t0


def main() -> int:
    assert not (Path.cwd() / "admittance").exists(), "run the smoke test outside the checkout"
    failed = 0
    steps = smoke_steps()
    for step in steps:
        try:
            seconds = run_step(step)
            print(f"ok   {step.name} ({seconds:.1f} s)", flush=True)
        except (AssertionError, subprocess.TimeoutExpired, json.JSONDecodeError, KeyError, OSError) as exc:
            failed += 1
            print(f"FAIL {step.name}: {exc}", flush=True)
    print(f"{len(steps) - failed} passed, {failed} failed")
    return 1 if failed else 0


if __name__ == "__main__":
    os.environ.setdefault("MPLBACKEND", "Agg")
    raise SystemExit(main())
