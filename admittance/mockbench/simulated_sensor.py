"""The simulated force sensor: a scripted hand pushing on an OptoForce DAQ.

The hand torque τ(t) acts at ``lever_arm`` from the joint axis, so the sensor on the horn
reads F = τ / lever_arm on its configured axis; that force becomes counts with the sensor's
sensitivity (counts_per_newton), plus an optional constant bias and seeded Gaussian noise, and
is clipped to int16 with the overload bit set, as the DAQ does.

Four outputs share that model:

- :class:`SimulatedOptoForce` streams OptoForce frames on a pseudo-terminal, so the real
  serial reader (or any OptoForce client) reads it as it would a ``/dev/ttyACM*``. Its
  :class:`PtyPort` follows protocols.md §6: raw mode on the slave, the slave kept open for the
  mock's whole life, and non-blocking writes; when the pty is full because nobody reads, whole
  samples are dropped (never half a frame), exactly as a DAQ's USB buffer overflows.
- :class:`SimulatedCanOptoForce` sends the same bytes over python-can (the in-process
  ``virtual`` bus by default), split into 8-byte frames with the data identifier, and takes
  configuration packets on the identifier after it (0x100 → 0x101).
- :class:`SimulatedSlcanOptoForce` puts those CAN frames behind a simulated USB-CAN adapter
  in slcan mode (:mod:`admittance.mockbench.slcan`) on a :class:`PtyPort`, so that another
  process reads them with python-can's ``slcan`` interface, as from a CANable. The virtual
  bus cannot do that (it is in-process only), and socketcan's vcan needs root to create.
- :class:`ScriptedForceSensor` is the registry's ``"mock"`` kind: a ForceSensor that pushes
  forces straight to a sink, with no wire at all.

Both streaming mocks honour a configuration packet from the host (sample rate, tare; SPEED 0
stops the stream) and answer it with an acknowledgement. Samples come from one thread on
absolute deadlines; if the machine stalls the thread catches up with a burst (as a USB DAQ
delivers a backlog) and, after 100 ms behind, skips ahead instead of flooding.

Fault modes, for tests of the readers and the daemon (each a method of the streaming mocks):
``silence`` (the DAQ stops sending, the port stays), ``saturate`` (the hand's axis reads the
int16 limit with its overload flag, as a DAQ does beyond its range), ``set_status`` (DAQ or
sensor error bits in every frame), ``inject_garbage`` and ``corrupt`` (noise before the next
frame; the next frames with a wrong checksum), and on the pty outputs ``unplug``/``replug``:
the pty closes (the reader's descriptor hangs up, the device node goes) and a new one opens,
reachable at the same path through the port's ``link``, as through /dev/serial/by-id.
"""

from __future__ import annotations

import abc
import contextlib
import logging
import math
import os
import random
import threading
import time
import tty
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from admittance.drivers import optoforce as of
from admittance.drivers.can_sensor import split_into_can_payloads
from admittance.drivers.force_reader import AXES, ForceSensor, Sink, counts_per_unit
from admittance.errors import ConfigError, DeviceError
from admittance.mockbench import slcan
from admittance.mockbench.hand import Profile, make_profile, tabulate

log = logging.getLogger(__name__)

INT16_MAX = 32767
MAX_CATCH_UP_S = 0.1
DEFAULT_COUNTS_PER_NEWTON = 451.89  # an OMD-20-class sensitivity, counts/N


@dataclass(frozen=True)
class ForceModel:
    """Hand torque → the counts a sensor on the horn reports."""

    lever_arm: float = 0.105
    axis: str = "x"
    counts_per_newton: tuple[float, ...] = (DEFAULT_COUNTS_PER_NEWTON,) * 3
    bias_n: float = 0.0
    noise_std_n: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.lever_arm) and self.lever_arm > 0):
            raise ConfigError(f"lever_arm must be a positive length in m, got {self.lever_arm}")
        if self.axis not in ("x", "y", "z"):
            raise ConfigError(f"the hand pushes along a force axis (x, y or z), not '{self.axis}'")
        counts_per_unit(self.counts_per_newton, len(self.counts_per_newton))
        if len(self.counts_per_newton) not in (3, 6):
            raise ConfigError("counts_per_newton has 3 (3-axis) or 6 (6-axis) values")
        if self.noise_std_n < 0:
            raise ConfigError("noise_std_n must be ≥ 0")

    @property
    def axis_index(self) -> int:
        return "xyz".index(self.axis)

    def force(self, tau: float) -> float:
        return tau / self.lever_arm

    def counts(self, tau: float, rng: random.Random) -> tuple[list[int], int]:
        """(counts per axis, status word with the overload bits of clipped axes)."""
        forces = [0.0] * len(self.counts_per_newton)
        forces[self.axis_index] = self.force(tau)
        status = 0
        counts = []
        for i, (f, cpn) in enumerate(zip(forces, self.counts_per_newton)):
            noise = rng.gauss(0.0, self.noise_std_n) if self.noise_std_n else 0.0
            value = round((f + (self.bias_n if i < 3 else 0.0) + noise) * cpn)
            if abs(value) > INT16_MAX:
                status |= 1 << of.STATUS_OVERLOAD_BITS[AXES[i]]
                value = max(-INT16_MAX, min(INT16_MAX, value))
            counts.append(value)
        return counts, status


class _StreamingSensor(abc.ABC):
    """The sample clock and DAQ behaviour shared by the pty and CAN outputs."""

    def __init__(self, torque_source: Profile, model: ForceModel, *, rate_hz: float = 1000.0, seed: int = 0):
        if not rate_hz > 0:
            raise ConfigError(f"the simulated sensor's rate must be positive, got {rate_hz}")
        self._torque_source = torque_source
        self.model = model
        self.rate_hz = float(rate_hz)
        self.streaming = True
        self._rng = random.Random(seed)
        self._parser = of.OptoForceParser()
        self._tare_counts: list[int] | None = None
        self._last_counts: list[int] = [0] * len(model.counts_per_newton)
        self._counter = 0
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.samples_sent = 0
        self.samples_dropped = 0
        self.configs_received = 0
        self.late_skips = 0
        self.last_torque = 0.0
        # Fault modes (set from any thread; read once per sample).
        self.silent = False
        self.saturated = False
        self.fault_status = 0
        self._garbage = 0
        self._corrupt = 0
        self.faulty_frames = 0

    # -- output contract ------------------------------------------------------------------------

    @abc.abstractmethod
    def _send(self, data: bytes) -> bool:
        """Send one whole frame; False if it had to be dropped."""

    @abc.abstractmethod
    def _receive(self) -> bytes:
        """Bytes the host sent since the last call (non-blocking)."""

    def _release(self) -> None:
        """Free the output's resources once the thread has ended."""

    # -- lifecycle -------------------------------------------------------------------------------

    def start(self) -> None:
        if self._thread is not None:
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="mock-force-sensor", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        thread, self._thread = self._thread, None
        if thread is not None:
            self._stop.set()
            thread.join()
        self._release()

    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _run(self) -> None:
        t0 = time.monotonic()
        deadline = t0
        while not self._stop.is_set():
            delay = deadline - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            elif -delay > MAX_CATCH_UP_S:
                self.late_skips += 1
                deadline = time.monotonic()
            self._tick(deadline - t0)
            self._handle_host_bytes()  # after the tick: a tare takes the load just sampled
            deadline += 1.0 / self.rate_hz

    def _tick(self, t: float) -> None:
        tau = self._torque_source(t)
        self.last_torque = tau
        counts, status = self.model.counts(tau, self._rng)
        self._last_counts = counts
        if not self.streaming or self.silent:
            return
        if self._tare_counts is not None:
            counts = [c - z for c, z in zip(counts, self._tare_counts)]
        frame = self._faulty(of.encode_sample(self._counter, *self._saturation(counts, status)))
        self._counter = (self._counter + 1) & 0xFFFF
        if self._send(frame):
            self.samples_sent += 1
        else:
            self.samples_dropped += 1

    def _saturation(self, counts: list[int], status: int) -> tuple[int, list[int]]:
        """The status word and counts, with the fault modes' flags and the saturated axis."""
        status |= self.fault_status
        if self.saturated:
            i = self.model.axis_index
            counts = list(counts)
            counts[i] = INT16_MAX if counts[i] >= 0 else -INT16_MAX
            status |= 1 << of.STATUS_OVERLOAD_BITS[AXES[i]]
        return status, counts

    def _faulty(self, frame: bytes) -> bytes:
        """Garbage before the frame, or a wrong checksum, while those faults are pending."""
        if self._corrupt > 0:
            self._corrupt -= 1
            self.faulty_frames += 1
            frame = frame[:-1] + bytes([frame[-1] ^ 0x5A])
        if self._garbage > 0:
            # No 0xAA in the noise: it must not be able to start a frame of its own.
            noise = bytes(self._rng.choice(range(0x00, 0xAA)) for _ in range(self._garbage))
            self._garbage = 0
            frame = noise + frame
        return frame

    # -- fault modes -------------------------------------------------------------------------------

    def silence(self, on: bool = True) -> None:
        """The DAQ stops sending (the port stays open); ``silence(False)`` resumes."""
        self.silent = bool(on)

    def saturate(self, on: bool = True) -> None:
        """The hand's axis reads the int16 limit with its overload flag set, until turned off."""
        self.saturated = bool(on)

    def set_status(self, bits: int) -> None:
        """DAQ or sensor status bits (e.g. 0x2000 DAQ error) in every frame; 0 clears them."""
        if not 0 <= bits <= 0xFFFF:
            raise ConfigError(f"an OptoForce status word is 16 bits, got {bits:#x}")
        self.fault_status = bits

    def inject_garbage(self, n_bytes: int) -> None:
        """``n_bytes`` of noise (never a header byte) before the next frame."""
        if not 0 < n_bytes <= 4096:
            raise ConfigError(f"garbage is 1..4096 bytes, got {n_bytes}")
        self._garbage = n_bytes

    def corrupt(self, n_frames: int) -> None:
        """The next ``n_frames`` frames go out with a wrong checksum."""
        if not 0 < n_frames <= 100_000:
            raise ConfigError(f"corrupt 1..100000 frames, got {n_frames}")
        self._corrupt = n_frames

    def _handle_host_bytes(self) -> None:
        data = self._receive()
        if not data:
            return
        for record in self._parser.feed(data):
            if type(record) is of.Config:
                self._apply_config(record)

    def _apply_config(self, config: of.Config) -> None:
        self.configs_received += 1
        if config.speed == 0:
            self.streaming = False
        else:
            self.streaming = True
            self.rate_hz = of.rate_of_speed_code(config.speed)
        if config.zero == of.ZERO_TARE:
            self._tare_counts = list(self._last_counts)
        elif config.zero == of.ZERO_CLEAR:
            self._tare_counts = None
        self._send(of.encode_ack(0))

    def stats(self) -> dict[str, Any]:
        return {
            "rate_hz": self.rate_hz,
            "streaming": self.streaming,
            "samples_sent": self.samples_sent,
            "samples_dropped": self.samples_dropped,
            "configs_received": self.configs_received,
            "late_skips": self.late_skips,
            "silent": self.silent,
            "saturated": self.saturated,
            "fault_status": self.fault_status,
            "faulty_frames": self.faulty_frames,
        }


class PtyPort:
    """The device end of a pseudo-terminal, as protocols.md §6 asks of a mock serial device.

    The slave is in raw mode and stays open while plugged in (so a host that closes and
    reopens ``path`` never makes the master see EIO), and writes are non-blocking. With
    ``link``, a symlink there points at the pty; ``unplug`` closes the pty (a host's
    descriptor hangs up, the node and the link disappear) and ``replug`` opens a new one and
    points the link at it.
    """

    def __init__(self, link: str | None = None) -> None:
        self.link = link
        self._lock = threading.Lock()
        self._master = self._slave = -1
        self._plug()
        self.unplugs = self.replugs = 0

    def _plug(self) -> None:
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.path = os.ttyname(self._slave)
        self._backlog = b""
        if self.link:
            point_link(self.link, self.path)

    @property
    def plugged(self) -> bool:
        return self._master >= 0

    def unplug(self) -> bool:
        """Pull the cable: False if it was out already."""
        with self._lock:
            if not self.plugged:
                return False
            self._close_fds()
            if self.link:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(self.link)
            self.unplugs += 1
            return True

    def replug(self) -> bool:
        """Put it back (a new pty, the link pointed at it): False if it was plugged in."""
        with self._lock:
            if self.plugged:
                return False
            self._plug()
            self.replugs += 1
            return True

    def send(self, data: bytes) -> bool:
        """Write one whole frame; False if it had to be dropped (pty full, or unplugged)."""
        with self._lock:
            return self.plugged and self._send(data)

    def _send(self, data: bytes) -> bool:
        # A frame cut short by a full pty is finished before anything new is written, so the
        # stream stays whole frames; a new frame that does not fit at all is dropped.
        if self._backlog:
            self._backlog = self._backlog[self._write(self._backlog) :]
            if self._backlog:
                return False
        written = self._write(data)
        self._backlog = data[written:] if written else b""
        return written > 0

    def _write(self, data: bytes) -> int:
        try:
            return os.write(self._master, data)
        except OSError:  # EAGAIN when the pty is full
            return 0

    def receive(self) -> bytes:
        """What the host wrote since the last call (non-blocking)."""
        with self._lock:
            if not self.plugged:
                return b""
            try:
                return os.read(self._master, 4096)
            except (BlockingIOError, OSError):
                return b""

    def close(self) -> None:
        with self._lock:
            self._close_fds()
            if self.link:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(self.link)

    def _close_fds(self) -> None:
        for fd in (self._master, self._slave):
            if fd >= 0:
                os.close(fd)
        self._master = self._slave = -1


def point_link(link: str, target: str) -> None:
    """Point the symlink ``link`` at ``target`` atomically (a new link renamed over the old)."""
    temporary = f"{link}.{os.getpid()}.new"
    with contextlib.suppress(FileNotFoundError):
        os.unlink(temporary)
    os.symlink(target, temporary)
    os.replace(temporary, link)


class _PtyOutput:
    """The unplug/replug of the streaming mocks that live on a :class:`PtyPort`."""

    _pty: PtyPort

    @property
    def port_path(self) -> str:
        """The pty a host opens now (a new one after each replug)."""
        return self._pty.path

    @property
    def link_path(self) -> str | None:
        """The stable path to it (None without a link)."""
        return self._pty.link

    def unplug(self) -> bool:
        return self._pty.unplug()

    def replug(self) -> bool:
        return self._pty.replug()

    def _port_stats(self) -> dict[str, Any]:
        return {"plugged": self._pty.plugged, "unplugs": self._pty.unplugs, "replugs": self._pty.replugs}


class SimulatedOptoForce(_PtyOutput, _StreamingSensor):
    """OptoForce frames on a pseudo-terminal: open ``port_path`` (or ``link_path``, stable
    across replugs) as you would /dev/ttyACM0."""

    def __init__(
        self, torque_source: Profile, model: ForceModel, *, rate_hz: float = 1000.0, seed: int = 0, link: str | None = None
    ):
        super().__init__(torque_source, model, rate_hz=rate_hz, seed=seed)
        self._pty = PtyPort(link)

    def _send(self, data: bytes) -> bool:
        return self._pty.send(data)

    def _receive(self) -> bytes:
        return self._pty.receive()

    def _release(self) -> None:
        self._pty.close()

    def stats(self) -> dict[str, Any]:
        return super().stats() | self._port_stats()


class NativeOptoForce:
    """:class:`SimulatedOptoForce`'s behaviour with its stream in a Rust thread (``_rtcore.SimulatedDaq``,
    dxlsim/src/daq.rs), beside the simulated bus: the bench's default sensor.

    Why: the daemon reads its sensor and runs its loop without the GIL, so a DAQ simulated by a
    Python thread was the one part of the embedded bench that waited for the interpreter, and a
    loaded machine's late bursts made the loop hold the joint. The profile must be one
    :func:`~admittance.mockbench.hand.tabulate` can hand over (the built-ins, a CSV); a hand
    scripted as any Python callable needs :class:`SimulatedOptoForce`.
    """

    def __init__(self, bus: Any, hand_servo: int, profile: Profile, model: ForceModel, *, rate_hz: float = 1000.0,
                 seed: int = 0, link: str | None = None, rt_priority: int | None = None):
        from admittance import _rtcore

        self._step_s = 1.0 / max(rate_hz, 1000.0)
        t, tau, period = self._table(profile)
        priority = {} if rt_priority is None else {"rt_priority": rt_priority}  # None: the bus thread's default
        self._daq = _rtcore.SimulatedDaq(
            bus, hand_servo, t, tau, period, model.lever_arm, model.axis_index, list(model.counts_per_newton),
            bias_n=model.bias_n, noise_std_n=model.noise_std_n, rate_hz=rate_hz, seed=seed, link=link, **priority)
        self.model = model

    def _table(self, profile: Profile) -> tuple[list[float], list[float], float | None]:
        table = tabulate(profile, self._step_s)
        if table is None:
            raise ConfigError("the Rust-paced simulated sensor takes the built-in or CSV hand profiles; a hand "
                              "scripted in Python needs the bench's sensor_stream = 'python'")
        return table

    def set_profile(self, profile: Profile) -> None:
        """A new hand profile, on the stream's time base (as replacing a Python stream's source)."""
        self._daq.set_profile(*self._table(profile))

    def hold_hand(self) -> None:
        self._daq.hold_hand()

    def start_hand(self, delay: float) -> None:
        self._daq.start_hand(delay)

    port_path = property(lambda self: self._daq.port_path, doc="The pty a host opens now.")
    link_path = property(lambda self: self._daq.link_path, doc="The stable path to it.")
    silent = property(lambda self: self._daq.stats()["silent"])
    saturated = property(lambda self: self._daq.stats()["saturated"])
    fault_status = property(lambda self: self._daq.stats()["fault_status"])
    last_torque = property(lambda self: self._daq.stats()["last_torque"])

    def start(self) -> None:
        self._daq.start()

    def stop(self) -> None:
        self._daq.close()

    def unplug(self) -> bool:
        return self._daq.unplug()

    def replug(self) -> bool:
        return self._daq.replug()

    def silence(self, on: bool = True) -> None:
        self._daq.silence(bool(on))

    def saturate(self, on: bool = True) -> None:
        self._daq.saturate(bool(on))

    def set_status(self, bits: int) -> None:
        self._daq.set_status(bits)

    def inject_garbage(self, n_bytes: int) -> None:
        self._daq.inject_garbage(n_bytes)

    def corrupt(self, n_frames: int) -> None:
        self._daq.corrupt(n_frames)

    def stats(self) -> dict[str, Any]:
        return dict(self._daq.stats())


class SimulatedSlcanOptoForce(_PtyOutput, _StreamingSensor):
    """The CAN sensor behind a simulated USB-CAN adapter in slcan mode, on a pseudo-terminal.

    Open ``port_path`` with python-can's ``slcan`` interface as you would /dev/ttyACM0 with a
    CANable. Frames reach the host only while the adapter's channel is open (after ``O``, until
    ``C``); a sample sent while it is closed, or that does not fit in a full pty, counts as
    dropped. Configuration packets arrive as transmitted frames on ``can_id + 1``, as on
    :class:`SimulatedCanOptoForce`.
    """

    def __init__(
        self,
        torque_source: Profile,
        model: ForceModel,
        *,
        can_id: int = 0x100,
        rate_hz: float = 1000.0,
        seed: int = 0,
        link: str | None = None,
    ):
        super().__init__(torque_source, model, rate_hz=rate_hz, seed=seed)
        if not 0 <= can_id < slcan.EXTENDED_ID_MAX:
            raise ConfigError(f"the simulated sensor's CAN identifier must be in 0..0x1FFFFFFE, got {can_id:#x}")
        self.can_id = can_id
        self.adapter = slcan.SlcanAdapter()
        self._pty = PtyPort(link)

    def _send(self, data: bytes) -> bool:
        if not self.adapter.is_open:
            return False
        now_ms = time.monotonic_ns() // 1_000_000
        return self._pty.send(self.adapter.frame_lines(self.can_id, split_into_can_payloads(data), now_ms))

    def _receive(self) -> bytes:
        replies, frames = self.adapter.feed(self._pty.receive())
        if replies:
            self._pty.send(replies)
        return b"".join(f.data for f in frames if f.can_id == self.can_id + 1)

    def _release(self) -> None:
        self._pty.close()

    def stats(self) -> dict[str, Any]:
        return super().stats() | self.adapter.stats() | self._port_stats()


class SimulatedCanOptoForce(_StreamingSensor):
    """The same frames over python-can: data on ``can_id``, configuration on ``can_id + 1``."""

    def __init__(
        self,
        torque_source: Profile,
        model: ForceModel,
        *,
        channel: str = "admittance-force",
        interface: str = "virtual",
        can_id: int = 0x100,
        rate_hz: float = 1000.0,
        seed: int = 0,
    ):
        super().__init__(torque_source, model, rate_hz=rate_hz, seed=seed)
        import can

        self.channel = channel
        self.interface = interface
        self.can_id = can_id
        try:
            self._bus = can.Bus(interface=interface, channel=channel, ignore_config=True, receive_own_messages=False)
        except (can.CanError, OSError, ImportError, ValueError) as exc:
            raise DeviceError(f"cannot open the simulated CAN sensor on {interface} channel {channel!r}: {exc}") from None
        self._message = can.Message
        self._can_error = can.CanError

    def _send(self, data: bytes) -> bool:
        try:
            for payload in split_into_can_payloads(data):
                self._bus.send(self._message(arbitration_id=self.can_id, data=payload, is_extended_id=self.can_id > 0x7FF), timeout=0.01)
        except self._can_error:
            return False
        return True

    def _receive(self) -> bytes:
        data = bytearray()
        while (msg := self._bus.recv(0.0)) is not None:
            if msg.arbitration_id == self.can_id + 1:
                data += msg.data
        return bytes(data)

    def _release(self) -> None:
        self._bus.shutdown()


class ScriptedForceSensor(ForceSensor):
    """The ``"mock"`` sensor kind: forces from a hand profile pushed straight to the sink."""

    kind = "mock"

    def __init__(self, sink: Sink, profile: Profile, model: ForceModel, *, rate_hz: float = 1000.0, seed: int = 0):
        super().__init__(sink)
        if not rate_hz > 0:
            raise ConfigError(f"the mock sensor's rate must be positive, got {rate_hz}")
        self._profile = profile
        self._model = model
        self._period = 1.0 / rate_hz
        self._rng = random.Random(seed)
        self._scale = tuple(1.0 / c for c in model.counts_per_newton)
        self._t0 = 0.0
        self._deadline = 0.0

    @classmethod
    def from_config(cls, section: Mapping[str, Any], sink: Sink) -> ScriptedForceSensor:
        cpn = section.get("counts_per_newton", DEFAULT_COUNTS_PER_NEWTON)
        model = ForceModel(
            lever_arm=float(section.get("lever_arm", 0.105)),
            axis=str(section.get("axis", "x")),
            counts_per_newton=counts_per_unit(cpn, len(cpn) if isinstance(cpn, Sequence) else 3),
            bias_n=float(section.get("bias_n", 0.0)),
            noise_std_n=float(section.get("noise_std_n", 0.0)),
        )
        return cls(sink, make_profile(str(section.get("profile", "push-release"))), model, rate_hz=float(section.get("rate_hz", 1000)))

    def _open(self) -> None:
        self._t0 = self._deadline = time.monotonic()

    def _poll(self) -> None:
        delay = self._deadline - time.monotonic()
        if delay > 0:
            time.sleep(min(delay, 0.05))
            return
        counts, _ = self._model.counts(self._profile(self._deadline - self._t0), self._rng)
        vector = [c * s for c, s in zip(counts, self._scale)]
        self._emit_all([vector + [0.0] * (6 - len(vector))])
        self._deadline += self._period
        if -delay > MAX_CATCH_UP_S:
            self._deadline = time.monotonic()

    def _close(self) -> None:
        """Nothing to release: there is no device."""
