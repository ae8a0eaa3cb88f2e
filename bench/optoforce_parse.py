"""How fast the OptoForce readers are, against what a 1 kHz sensor needs.

Prints, in one run:
1. parse throughput of OptoForceParser (bytearray + find + struct) fed in different cuts, next
   to a byte-at-a-time state machine (the straightforward port of the C drivers);
2. end to end through a pseudo-terminal: frames written in bulk, read by OptoForceSerialReader
   (in_waiting + read(n)) into a sink;
3. end to end on python-can's virtual bus: 8-byte frames read by CanForceReader.
Each figure is also given as a ratio to the rate the hardware needs (1 kHz samples; 2 kHz CAN
frames for a 3-axis sensor at 1 kHz), so the result means the same on any machine.

Run: .venv/bin/python bench/optoforce_parse.py
"""

from __future__ import annotations

import os
import struct
import time
import tty

from admittance.drivers import optoforce as of
from admittance.drivers.can_sensor import CanForceReader, split_into_can_payloads
from admittance.drivers.force_reader import SampleBuffer

N_FRAMES = 50_000
NEEDED_SAMPLES_HZ = 1000.0
NEEDED_CAN_FRAMES_HZ = 2000.0


def _stream(n: int) -> bytes:
    frames = [of.encode_sample(i, 0, (i % 1000, -(i % 700), i % 300)) for i in range(n)]
    # An ack every 1000 samples and a little garbage, as a real stream has.
    for k in range(0, n, 1000):
        frames[k] = b"\x00\x13" + of.encode_ack(0) + frames[k]
    return b"".join(frames)


class BytewiseParser:
    """Reference: a per-byte state machine (header match, then collect, then checksum)."""

    HEADER = b"\xaa\x07\x08\x0a"
    BODY = struct.Struct(">HHhhh")

    def __init__(self) -> None:
        self.frame = bytearray()
        self.samples = 0

    def feed(self, data: bytes) -> int:
        for byte in data:
            frame = self.frame
            if len(frame) < 4:
                if byte == self.HEADER[len(frame)]:
                    frame.append(byte)
                else:
                    frame.clear()
                    if byte == 0xAA:
                        frame.append(byte)
                continue
            frame.append(byte)
            if len(frame) == 16:
                if sum(frame[:14]) & 0xFFFF == (frame[14] << 8 | frame[15]):
                    self.BODY.unpack_from(frame, 4)
                    self.samples += 1
                frame.clear()
        return self.samples


def _parse_rate(feed, stream: bytes, cut: int) -> float:
    t0 = time.perf_counter()
    for i in range(0, len(stream), cut):
        feed(stream[i : i + cut])
    return N_FRAMES / (time.perf_counter() - t0)


def _pty_rate(stream: bytes) -> float:
    master, slave = os.openpty()
    tty.setraw(slave)
    buffer = SampleBuffer(maxlen=16)
    reader = of.OptoForceSerialReader(os.ttyname(slave), 451.89, buffer)
    reader.start()
    t0 = time.perf_counter()
    view = memoryview(stream)
    while view:
        view = view[os.write(master, view[:4096]) :]
    buffer.wait_for(N_FRAMES, timeout=120)
    elapsed = time.perf_counter() - t0
    reader.stop()
    os.close(master)
    os.close(slave)
    return buffer.total / elapsed


def _can_rate(n_samples: int) -> float:
    import can

    sender = can.Bus(interface="virtual", channel="bench-optoforce", ignore_config=True)
    buffer = SampleBuffer(maxlen=16)
    reader = CanForceReader("bench-optoforce", 451.89, buffer, interface="virtual")
    messages = [
        can.Message(arbitration_id=0x100, data=payload, is_extended_id=False)
        for i in range(n_samples)
        for payload in split_into_can_payloads(of.encode_sample(i, 0, (i % 100, 0, 0)))
    ]
    reader.start()
    t0 = time.perf_counter()
    for message in messages:
        sender.send(message)
    buffer.wait_for(n_samples, timeout=120)
    elapsed = time.perf_counter() - t0
    reader.stop()
    sender.shutdown()
    return len(messages) / elapsed


def main() -> None:
    stream = _stream(N_FRAMES)
    print(f"OptoForce 3-axis frames: {N_FRAMES} per measurement (16 B each, acks and garbage mixed in)\n")
    print("parse only                                     frames/s    × 1 kHz need")
    rows = []
    for cut, label in ((16, "one frame per read"), (64, "one USB packet per read"), (4096, "4 KiB per read")):
        parser = of.OptoForceParser()
        rows.append((f"OptoForceParser, {label}", _parse_rate(parser.feed, stream, cut)))
    for cut, label in ((16, "one frame per read"), (4096, "4 KiB per read")):
        rows.append((f"byte-at-a-time reference, {label}", _parse_rate(BytewiseParser().feed, stream, cut)))
    for name, rate in rows:
        print(f"  {name:<44} {rate:>10,.0f}   {rate / NEEDED_SAMPLES_HZ:>8.0f}×")
    ours, ref = rows[2][1], rows[-1][1]
    print(f"  OptoForceParser / byte-at-a-time (4 KiB reads): {ours / ref:.1f}×\n")

    print("end to end                                     frames/s    × need")
    pty = _pty_rate(stream)
    print(f"  serial reader over a pty (samples/s)         {pty:>10,.0f}   {pty / NEEDED_SAMPLES_HZ:>8.0f}× (1 kHz samples)")
    can_rate = _can_rate(20_000)
    print(f"  CAN reader, virtual bus (CAN frames/s)       {can_rate:>10,.0f}   {can_rate / NEEDED_CAN_FRAMES_HZ:>8.0f}× (2 kHz frames)")


if __name__ == "__main__":
    main()
