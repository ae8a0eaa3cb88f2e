"""An OptoForce-format force sensor on CAN, through python-can (any interface it supports).

Frame layout (shared contracts/daemon.md): the sensor's OptoForce sample bytes, in order, split
over consecutive 8-byte data frames with one identifier ``can_id`` (a 16-byte 3-axis sample is
two frames, a 34-byte 4-channel sample five). The payloads are therefore just a byte stream,
and the reader feeds them to the serial parser unchanged: it reassembles samples by their
header and checks the checksum exactly as on serial. A lost CAN frame costs one checksum
error and a resync, never a wrong force reading.

The bus is created the python-can way (docs/drivers.md): ``can.Bus(interface=..., channel=...,
bitrate=..., **options)``, where ``options`` are the interface's own keyword arguments
(``[sensor.can_options]``, e.g. ``tty_baudrate`` for slcan or ``state`` for pcan), with an
acceptance filter on ``can_id`` (the kernel drops other traffic on socketcan). When the
configuration names an interface or a channel, python-can's own configuration is ignored
(``ignore_config=True``), so that no environment variable or ~/.canrc silently changes a bus
the file describes; when it names neither, python-can's configuration (``CAN_INTERFACE`` /
``CAN_CHANNEL``, ~/.canrc, /etc/can.conf) chooses them. The reader drains every queued
frame before parsing, so one parse serves a burst: at 2 kHz of frames the thread wakes at
most once per frame and usually less.

When the bus fails (an adapter pulled out, an interface taken down), the reader shuts it down
and creates a new one with backoff until the adapter is back (``ForceSensor``'s reopen).

With ``interface="slcan"`` (a USB-CAN adapter speaking the Lawicel ASCII protocol on a serial
port) two things differ. python-can waits ``sleep_after_open`` (2 s) after opening the port,
for adapters that reset when the port opens; a pseudo-terminal has nothing to reset, so the
reader waits 0 s there and keeps python-can's wait on real devices. And the frames arrive as
text that python-can decodes in ``recv``: a corrupted line raises there instead of being
dropped, so the reader counts it in ``undecodable_frames``, empties python-can's line buffer
and goes on; the bytes lost with it cost a checksum error or a resync, as a lost frame does.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from typing import Any

from admittance.drivers.optoforce import SampleConverter
from admittance.drivers.ports import open_error_message
from admittance.drivers.force_reader import ForceSensor, Sink, require_key
from admittance.errors import DeviceError

STANDARD_ID_MAX = 0x7FF
EXTENDED_ID_MAX = 0x1FFFFFFF
MAX_FRAMES_PER_BATCH = 256
MAX_CAN_OPTIONS = 32
DEFAULT_INTERFACE = "socketcan"
# can.Bus arguments the reader sets itself: the configuration has a key for each.
RESERVED_OPTIONS = {"interface": "interface", "channel": "channel", "bitrate": "bitrate", "can_filters": "can_id",
                    "ignore_config": "interface/channel", "bustype": "interface", "context": "interface"}
PTY_DIR = "/dev/pts/"


class CanForceReader(ForceSensor):
    """Reads OptoForce samples carried in CAN frames with identifier ``can_id``."""

    kind = "can"
    reader_path = "python-can"

    def __init__(
        self,
        channel: str | int | None,
        counts_per_newton: float | Sequence[float],
        sink: Sink,
        *,
        interface: str | None = DEFAULT_INTERFACE,
        can_id: int = 0x100,
        bitrate: int | None = 1_000_000,
        axes: int = 3,
        sensor_index: int = 0,
        recv_timeout: float = 0.05,
        open_delay: float | None = None,
        saturation: str = "hold",
        options: Mapping[str, Any] | None = None,
    ):
        """``open_delay`` (slcan only): seconds to wait after opening the serial port; by
        default 0 on a pseudo-terminal and python-can's own wait on a real device.
        ``options``: the interface's own keyword arguments, passed to ``can.Bus`` as they are.
        ``interface`` and ``channel`` both None: python-can's own configuration chooses them."""
        super().__init__(sink)
        self.options = check_can_options(options or {})
        self.use_can_config = not interface and channel in (None, "")
        self.channel = None if self.use_can_config else channel
        self.interface = None if self.use_can_config else (interface or DEFAULT_INTERFACE)
        self.can_id = int(can_id)
        self.bitrate = bitrate
        self.recv_timeout = recv_timeout
        self.open_delay = open_delay
        self.extended_id = self.can_id > STANDARD_ID_MAX
        self._converter = SampleConverter(counts_per_newton, axes=axes, sensor_index=sensor_index, saturation=saturation)
        self._bus = None
        self.can_frames = 0
        self.foreign_frames = 0
        self.undecodable_frames = 0

    @classmethod
    def from_config(cls, section: Mapping[str, Any], sink: Sink) -> CanForceReader:
        """``channel`` is python-can's name; ``port`` is kept as its alias (contracts/daemon.md)."""
        return cls(
            section.get("channel") or section.get("port") or None,
            require_key(section, "counts_per_newton"),
            sink,
            interface=section.get("interface") or None,
            can_id=int(section.get("can_id", 0x100)),
            bitrate=section.get("bitrate", 1_000_000),
            axes=int(section.get("axes", 3)),
            sensor_index=int(section.get("sensor_index", 0)),
            saturation=str(section.get("saturation", "hold")),
            options=section.get("can_options") or {},
        )

    def _open(self) -> None:
        from admittance.extras import require

        can = require("can", 'the CAN force sensor (kind = "can")')  # here, so the registry stays cheap

        mask = EXTENDED_ID_MAX if self.extended_id else STANDARD_ID_MAX
        options: dict[str, Any] = {
            "can_filters": [{"can_id": self.can_id, "can_mask": mask, "extended": self.extended_id}],
        }
        if not self.use_can_config:
            options |= {"interface": self.interface, "channel": self.channel, "ignore_config": True}
        if self.bitrate is not None:
            options["bitrate"] = int(self.bitrate)
        if self.interface == "slcan":
            options |= self._slcan_options()
        options |= self.options
        try:
            self._bus = can.Bus(**options)
        except (can.CanError, OSError, ImportError, ValueError, TypeError, RuntimeError) as exc:
            # RuntimeError: python-can raises its not-implemented error (a RuntimeError) for an
            # unknown interface name. It wraps the serial or socket error; that errno gives the
            # actionable hint (unplugged, no permission...).
            cause = exc if getattr(exc, "errno", None) else (exc.__cause__ or exc)
            where = ("(python-can's configuration: CAN_INTERFACE/CAN_CHANNEL or ~/.canrc)" if self.use_can_config
                     else f"(interface {self.interface!r}, channel {self.channel!r})")
            raise DeviceError(open_error_message("the CAN force sensor", where, cause)) from None

    def _slcan_options(self) -> dict[str, Any]:
        delay = self.open_delay
        if delay is None:
            port = str(self.channel).partition("@")[0]  # python-can's "port@tty_baudrate" form
            delay = 0.0 if os.path.realpath(port).startswith(PTY_DIR) else None
        return {} if delay is None else {"sleep_after_open": float(delay)}

    def _poll(self) -> None:
        chunk = bytearray()
        timeout = self.recv_timeout
        for _ in range(MAX_FRAMES_PER_BATCH):
            msg = self._recv(timeout)
            if msg is None:
                break
            self._append_payload(msg, chunk)
            timeout = 0.0
        if chunk:
            self._emit_converted(self._converter, chunk)

    def _recv(self, timeout: float) -> Any:
        try:
            return self._bus.recv(timeout)
        except Exception as exc:
            if not is_undecodable_frame(exc):
                raise  # the device failed: ForceSensor._run reports it
            if isinstance(exc.__cause__, UnicodeDecodeError):
                self._drop_stuck_line()
            self.undecodable_frames += 1  # counted once handled: what comes after is not flushed
            return None

    def _drop_stuck_line(self) -> None:
        # python-can's slcan reader keeps a non-ASCII line in its buffer (it fails to decode it
        # before clearing it), so every later line would fail too. Its flush() empties that
        # buffer, and the serial input with it: a few frames more are lost, one resync.
        flush = getattr(self._bus, "flush", None)
        if callable(flush):
            flush()

    def _append_payload(self, msg: Any, chunk: bytearray) -> None:
        if (
            msg.arbitration_id != self.can_id
            or msg.is_extended_id != self.extended_id
            or msg.is_error_frame
            or msg.is_remote_frame
        ):
            self.foreign_frames += 1
            return
        self.can_frames += 1
        chunk += msg.data

    def _close(self) -> None:
        if self._bus is not None:
            self._bus.shutdown()
            self._bus = None

    def stats(self) -> dict[str, Any]:
        return super().stats() | self._converter.stats() | {
            "can_frames": self.can_frames,
            "foreign_frames": self.foreign_frames,
            "undecodable_frames": self.undecodable_frames,
        }


def check_can_options(options: Mapping[str, Any]) -> dict[str, Any]:
    """Interface keyword arguments: bounded, scalar, and none the reader sets itself."""
    from admittance.errors import ConfigError

    if not isinstance(options, Mapping) or len(options) > MAX_CAN_OPTIONS:
        raise ConfigError(f"[sensor.can_options]: expected a table of at most {MAX_CAN_OPTIONS} keys")
    for key, value in options.items():
        if key in RESERVED_OPTIONS:
            raise ConfigError(f"[sensor.can_options].{key}: set it with [sensor].{RESERVED_OPTIONS[key]} instead")
        if isinstance(value, float) and not math.isfinite(value):
            raise ConfigError(f"[sensor.can_options].{key}: must be finite, got {value!r}")
        if not isinstance(value, str | int | float | bool):
            raise ConfigError(f"[sensor.can_options].{key}: expected a string, number or boolean, got {value!r}")
    return dict(options)


def is_undecodable_frame(exc: BaseException) -> bool:
    """Whether python-can raised over one text frame (slcan) it could not decode, not a dead port.

    Its slcan parser raises ValueError or IndexError on a bad line; a non-ASCII byte fails
    earlier, in its serial reader, which wraps every error as CanOperationError, so only the
    UnicodeDecodeError underneath tells that case from an unplugged adapter.
    """
    return isinstance(exc, ValueError | IndexError) or isinstance(exc.__cause__, UnicodeDecodeError)


def split_into_can_payloads(data: bytes, size: int = 8) -> list[bytes]:
    """The sender's side of the layout: consecutive chunks of at most ``size`` bytes."""
    return [data[i : i + size] for i in range(0, len(data), size)]
