"""The real daemon (`.venv/bin/admittance run`) as a subprocess, watched from outside over Zenoh.

Shared by the hardware-in-loop modules. Every wait is on the daemon's own progress (its
liveliness token, a state it publishes, its cycle count) with a generous deadline, never on
wall time: the scripted hand and the loop both slow down on a loaded machine, so "run for 3 s"
can mean 0.3 s of pushing there, while "run 2000 more cycles" means the same motion anywhere.
"""

from __future__ import annotations

import contextlib
import csv
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ADMITTANCE = Path(sys.executable).with_name("admittance")

# Deadlines for a loaded machine: a daemon start imports zenoh and NumPy and tares the sensor,
# which takes well under a second when idle and has taken tens of seconds under load.
START_TIMEOUT_S = 60.0
EXIT_TIMEOUT_S = 60.0
# A Zenoh query to the daemon is answered from its main thread's poll: Client's 3 s default was
# missed at load 22-27 (the reply is zenoh's "Timeout"). A daemon that never answers still fails.
QUERY_TIMEOUT_S = 30.0


def run_daemon(config: Path, *args: str, timeout: float = 120.0) -> subprocess.CompletedProcess:
    """`admittance run --config CONFIG ARGS` to completion (for runs that end by themselves)."""
    return subprocess.run([str(ADMITTANCE), "run", "--config", str(config), *args], capture_output=True,
                          text=True, timeout=timeout)


@dataclass
class Daemon:
    """A running daemon; ``returncode`` and ``stderr`` are filled in once it has been stopped."""

    proc: subprocess.Popen
    stderr: str = ""

    @property
    def returncode(self) -> int | None:
        return self.proc.returncode


@contextlib.contextmanager
def running_daemon(config: Path, *args: str, stop: signal.Signals = signal.SIGINT) -> Iterator[Daemon]:
    """`admittance run --config CONFIG ARGS` in the background; on leaving the block it gets
    ``stop`` and is waited for, its exit status and stderr kept for the test to check."""
    proc = subprocess.Popen([str(ADMITTANCE), "run", "--config", str(config), *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    daemon = Daemon(proc)
    try:
        yield daemon
    finally:
        proc.send_signal(stop)
        try:
            _, daemon.stderr = proc.communicate(timeout=EXIT_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            kill(proc)
            raise
        if proc.returncode < 0:  # ended by a signal it does not handle (SIGKILL): its bench left its folder
            remove_bench_folders()


def kill(proc: subprocess.Popen) -> None:
    """SIGKILL a daemon, and remove the simulated bench's folder it could not
    (``admittance-bench-<pid>-*``: only a dead process's)."""
    proc.kill()
    proc.communicate()
    remove_bench_folders()


def remove_bench_folders() -> None:
    """The simulated benches' link folders of processes that are gone."""
    from admittance.mockbench.link_dirs import remove_orphan_link_dirs

    remove_orphan_link_dirs()


def wait_alive(endpoint: str, prefix: str, timeout: float = START_TIMEOUT_S) -> None:
    """Until the daemon declares ``<prefix>/alive`` (its loop runs)."""
    from admittance.daemon.zenoh_iface import Client

    deadline = time.monotonic() + timeout
    with Client([endpoint]) as client:
        while time.monotonic() < deadline:
            if client.alive(prefix, timeout=0.5):
                return
            time.sleep(0.1)
    raise AssertionError(f"the daemon never declared {prefix}/alive")


def wait_for_state(client, prefix: str, condition: Callable[[dict], bool], what: str,
                   timeout: float = START_TIMEOUT_S, leaf: str = "state") -> dict:
    """Watch ``<prefix>/state`` (or ``<prefix>/stats`` with ``leaf="stats"``: once a second)
    until a message satisfies ``condition``; return that message."""
    sub = client.try_stream(prefix)
    deadline = time.monotonic() + timeout
    try:
        while time.monotonic() < deadline:
            for kind, message in sub.drain():
                if kind == leaf and condition(message):
                    return message
            time.sleep(0.02)
    finally:
        sub.close()
    raise AssertionError(f"the daemon's {leaf} never showed {what}")


def wait_for_cycles(client, prefix: str, cycles: int, after: dict | None = None) -> None:
    """Wait until the loop has run ``cycles`` more cycles than at the state message ``after``
    (default: the next state published): loop time rather than wall time, so a starved loop
    still gets its full settling time."""
    if after is None:
        after = wait_for_state(client, prefix, lambda message: True, "any state")
    target = after["cycle"] + cycles
    wait_for_state(client, prefix, lambda m: m["cycle"] >= target, f"cycle {target}")


def read_recording(folder: Path, joint_id: int = 1) -> dict[str, np.ndarray]:
    """Every segment of one joint's recording (``--record``), concatenated, by column."""
    rows = []
    for path in sorted(folder.glob(f"joint{joint_id}_*.csv")):
        with path.open() as fh:
            rows += list(csv.DictReader(fh))
    return {name: np.array([float(r[name]) for r in rows]) for name in rows[0]}
