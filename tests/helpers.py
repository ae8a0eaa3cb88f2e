"""Helpers that several test modules share: property-test example counts, waiting on another
thread or process without timed assertions, a free Zenoh endpoint, `admittance mock-bench` as a
subprocess, and ROBOTIS's SDK opened on a MockBus.

A plain module rather than conftest fixtures because the helpers are called with arguments
in the middle of a test (pytest puts tests/ on sys.path, so ``from helpers import ...`` works).
A wait polls a condition with a generous deadline and the test asserts on the state it
reached, never on how long that took: the machine the suite runs on is shared and noisy.
"""

from __future__ import annotations

import contextlib
import os
import select
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator

import pytest


def examples(n: int) -> int:
    """A property test's example count, times ``HYPOTHESIS_SCALE`` (default 1; a bug hunt sets more)."""
    scale = os.environ.get("HYPOTHESIS_SCALE", "1")
    if not scale.isdigit() or int(scale) < 1:
        raise pytest.UsageError(f"HYPOTHESIS_SCALE: expected a positive integer, got {scale!r}")
    return n * int(scale)


def wait_until(condition: Callable[[], bool], timeout: float = 10.0) -> bool:
    """Poll ``condition`` every 10 ms; True as soon as it holds, False at the deadline."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if condition():
            return True
        time.sleep(0.01)
    return bool(condition())


# An MX-64-like plant for simulated servos (the thesis's averages, rounded).
MX64_PLANT = {"motor_inertia": 0.0147, "damping": 0.035, "coulomb": 0.084}


# The SDK waits 34 ms for a status packet (it assumes a 16 ms FTDI latency timer). A machine
# shared with other jobs may not schedule the simulated bus's thread that soon (seen at load
# 8-10 on 2 cores), so the tests' ports wait this long: a servo that answers is never missed,
# and one that should not answer costs this per packet.
SDK_REPLY_TIMEOUT_MS = 500.0


def patient(port):
    """A dynamixel-sdk PortHandler that waits SDK_REPLY_TIMEOUT_MS for every reply."""
    port.setPacketTimeout = lambda _length: port.setPacketTimeoutMillis(SDK_REPLY_TIMEOUT_MS)
    return port


@contextlib.contextmanager
def sdk_on_mock_bus() -> Iterator[Callable]:
    """Yields ``open(servos, protocol=2, **bus_options) -> (bus, port, packet_handler)``: a started
    MockBus with a (patient) dynamixel-sdk PortHandler open on it. Everything opened is closed
    on exit."""
    import dynamixel_sdk as sdk

    from admittance import _rtcore

    opened = []

    def _open(servos, protocol=2, **bus_options):
        bus = _rtcore.MockBus(servos=servos, baudrate=1_000_000, **bus_options)
        bus.start()
        port = patient(sdk.PortHandler(bus.port_path))
        assert port.openPort() and port.setBaudRate(1_000_000)
        opened.append((bus, port))
        return bus, port, sdk.PacketHandler(float(protocol))

    try:
        yield _open
    finally:
        for bus, port in opened:
            port.closePort()
            bus.stop()


def free_endpoint() -> str:
    """A loopback TCP endpoint on a port the OS just reported free."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{sock.getsockname()[1]}"


def start_mock_bench(*args: str) -> subprocess.Popen:
    """``admittance mock-bench --print-ports ARGS`` with unbuffered output (the ports line comes at once)."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    return subprocess.Popen(
        [sys.executable, "-m", "admittance", "mock-bench", "--print-ports", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )


def first_line(proc: subprocess.Popen, timeout: float = 60.0) -> str:
    """The process's first stdout line; fails the test (with its stderr) if none comes in time."""
    ready, _, _ = select.select([proc.stdout], [], [], timeout)
    if not ready:
        proc.kill()
        pytest.fail(f"mock-bench printed nothing; stderr: {proc.stderr.read()}")
    return proc.stdout.readline()


@contextlib.contextmanager
def mock_bench_process(*args: str, stop: int = signal.SIGTERM) -> Iterator[tuple[subprocess.Popen, dict]]:
    """``admittance mock-bench --print-ports ARGS`` running for the block: yields the process and
    its ports; on leaving, sends ``stop`` and waits (``proc.returncode`` then holds the exit
    status; ``proc.stderr_text`` its stderr). Killed if it does not exit."""
    import json

    proc = start_mock_bench(*args)
    try:
        yield proc, json.loads(first_line(proc))
        proc.send_signal(stop)
        _, proc.stderr_text = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
