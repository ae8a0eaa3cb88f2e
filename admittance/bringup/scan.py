"""Find the servos on a bus: every (protocol, baud rate) pair tried, each servo's ID and model.

A new servo comes at 57 600 bit/s (Protocol 2.0 firmware) or 57 600 / 1 000 000 bit/s (older
Protocol 1.0 MX), and a bench may mix them, so a scan tries each pair in turn. Protocol 2.0
answers a broadcast ping for the whole bus in one round trip; Protocol 1.0 has none, so it is
pinged ID by ID (``p1_ids``, by default the first 32 IDs: a full P1 scan takes seconds per
baud rate).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from admittance.drivers.dynamixel import ServoBus, ServoInfo
from admittance.errors import ConfigError, DeviceError

# The rates a lab meets: ROBOTIS's factory setting first, then the loop's usual rate.
DEFAULT_BAUDRATES = (57_600, 1_000_000, 115_200, 2_000_000, 3_000_000, 4_000_000, 9_600)
DEFAULT_PROTOCOLS = (2, 1)
DEFAULT_P1_IDS = range(0, 32)


@dataclass(frozen=True)
class Found:
    """One servo that answered, and where."""

    info: ServoInfo
    baudrate: int

    @property
    def id(self) -> int:
        return self.info.id

    def line(self) -> str:
        firmware = "" if self.info.firmware is None else f", firmware {self.info.firmware}"
        return (f"ID {self.info.id:3d}  {self.info.model} (model number {self.info.model_number}{firmware}), "
                f"Protocol {self.info.protocol}.0 at {self.baudrate} bit/s")


def scan_bus(port: str, *, baudrates: Sequence[int] = DEFAULT_BAUDRATES, protocols: Sequence[int] = DEFAULT_PROTOCOLS,
             p1_ids: Iterable[int] = DEFAULT_P1_IDS, bus_options: dict | None = None) -> list[Found]:
    """Every servo on ``port`` at any of ``baudrates`` and ``protocols``, sorted by ID."""
    p1_ids = list(p1_ids)
    found: list[Found] = []
    for protocol in protocols:
        for baudrate in baudrates:
            try:
                with ServoBus(port, baudrate=baudrate, protocol=protocol, auto_recover=False, **(bus_options or {})) as bus:
                    infos = bus.scan(None if protocol == 2 else p1_ids)
            except ConfigError:
                continue  # a rate this adapter cannot set: nothing can answer there
            found += [Found(info, baudrate) for info in infos]
    return sorted(found, key=lambda f: (f.id, f.info.protocol, f.baudrate))


def only_servo(found: Sequence[Found]) -> Found:
    """The one servo on a bus being brought up one servo at a time."""
    if not found:
        raise DeviceError("no servo answered at any baud rate or protocol tried: check power (the U2D2 does "
                          "not power the servos), the cable, and the port")
    if len(found) > 1:
        raise ConfigError(f"{len(found)} servos answered ({', '.join(str(f.id) for f in found)}): "
                          "choose one with --id")
    return found[0]
