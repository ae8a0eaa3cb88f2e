"""Bytes and microseconds per SyncWrite cycle: the bus's physical limit beside our measured cost.

For 1, 6 and 12 servos at 1, 3 and 4 Mbps it prints
- the SyncWrite of Goal Position (4 bytes each): 14 + 5·N bytes;
- the full cycle with a SyncRead of Present Position: instruction 14 + N bytes, then N status
  replies of 15 bytes (Return Delay Time 0 assumed; the factory 500 µs adds N × 0.5 ms);
- wire time at 10 bits/byte (8N1) and the highest loop rate the wire allows;
- the measured encode+write cost of one SyncWrite through our Rust serial port
  (`DxlClient.sync_write`) into a pseudo-terminal whose master a thread drains, beside the
  same packet sent by dynamixel-sdk's GroupSyncWrite (pure Python + pyserial), as a ratio.

A pty ignores baud, so the measured cost is the host's CPU/syscall cost per cycle, the part of
the cycle budget that is not wire time. Run: .venv/bin/python bench/syncwrite_cycle.py
"""

from __future__ import annotations

import os
import statistics
import threading
import time
import tty

from admittance import _rtcore

GOAL_POSITION, PRESENT_POSITION, SIZE = 116, 132, 4
SERVO_COUNTS = (1, 6, 12)
BAUDS = (1_000_000, 3_000_000, 4_000_000)
ITERATIONS = 3000


class DrainedPty:
    """A pty whose master a thread reads and discards (os.read releases the GIL)."""

    def __init__(self):
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)
        self._stop = False
        self._thread = threading.Thread(target=self._drain, daemon=True)
        self._thread.start()

    def _drain(self):
        while not self._stop:
            try:
                os.read(self.master, 65536)
            except OSError:
                return

    def close(self):
        self._stop = True
        os.write(self.slave, b"\0")  # wake the reader
        self._thread.join(timeout=1)
        os.close(self.master)
        os.close(self.slave)


def records(n: int) -> list[tuple[int, bytes]]:
    return [(i + 1, (2048 + i).to_bytes(4, "little")) for i in range(n)]


def time_us(send, iterations: int = ITERATIONS) -> tuple[float, float]:
    """Median and 99th percentile of one call, in µs (after a warm-up of caches and pages)."""
    for _ in range(iterations // 10):
        send()
    samples = []
    for _ in range(iterations):
        t0 = time.perf_counter_ns()
        send()
        samples.append((time.perf_counter_ns() - t0) / 1000)
    samples.sort()
    return statistics.median(samples), samples[int(0.99 * len(samples)) - 1]


def measure_rust(path: str, n: int) -> tuple[float, float]:
    client = _rtcore.DxlClient(path, 4_000_000, 2, 0.001)
    recs = records(n)
    try:
        return time_us(lambda: client.sync_write(GOAL_POSITION, SIZE, recs))
    finally:
        client.close()


def measure_sdk(path: str, n: int) -> tuple[float, float] | None:
    try:
        import dynamixel_sdk as sdk
    except ImportError:
        return None
    port = sdk.PortHandler(path)
    port.openPort()
    group = sdk.GroupSyncWrite(port, sdk.PacketHandler(2.0), GOAL_POSITION, SIZE)
    for id_, data in records(n):
        group.addParam(id_, list(data))
    try:
        return time_us(group.txPacket)
    finally:
        port.closePort()


def wire_us(n_bytes: int, baud: int) -> float:
    return n_bytes * 10 / baud * 1e6


def main() -> None:
    pty = DrainedPty()
    try:
        measured = {n: (measure_rust(pty.path, n), measure_sdk(pty.path, n)) for n in SERVO_COUNTS}
    finally:
        pty.close()
    print(__doc__.split("\n\n")[0])
    print(f"measured over {ITERATIONS} cycles each; times in µs (median / p99)\n")
    header = (
        f"{'servos':>6} {'baud':>5} | {'SW bytes':>8} {'SW wire':>8} | {'cycle B':>7} {'cycle wire':>10} "
        f"{'max Hz':>7} | {'rust enc+write':>15} {'sdk enc+write':>15} {'sdk/rust':>8}"
    )
    print(header)
    print("-" * len(header))
    for n in SERVO_COUNTS:
        (rust_med, rust_p99), sdk = measured[n]
        sw_bytes = len(_rtcore.encode_sync_write(GOAL_POSITION, SIZE, records(n)))
        sr_bytes = len(_rtcore.encode_sync_read(PRESENT_POSITION, SIZE, list(range(1, n + 1))))
        cycle_bytes = sw_bytes + sr_bytes + n * len(_rtcore.encode_status(1, 0, bytes(SIZE)))
        assert (sw_bytes, sr_bytes) == (14 + 5 * n, 14 + n)
        sdk_text = f"{sdk[0]:7.1f} /{sdk[1]:6.1f}" if sdk else f"{'n/a':>15}"
        ratio = f"{sdk[0] / rust_med:7.1f}x" if sdk else f"{'n/a':>8}"
        for baud in BAUDS:
            cycle = wire_us(cycle_bytes, baud)
            print(
                f"{n:>6} {baud // 1_000_000:>4}M | {sw_bytes:>8} {wire_us(sw_bytes, baud):>8.1f} | "
                f"{cycle_bytes:>7} {cycle:>10.1f} {1e6 / cycle:>7.0f} | "
                f"{rust_med:7.1f} /{rust_p99:6.1f} {sdk_text} {ratio}"
            )
    print("\nSW = SyncWrite of Goal Position; cycle = SyncWrite + SyncRead + N status replies.")
    print("max Hz = 1 / cycle wire time: the loop-rate ceiling of the bus before any host cost.")


if __name__ == "__main__":
    main()
