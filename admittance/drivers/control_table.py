"""Control-table items by name, with their physical units, from the one model table.

The addresses, sizes and units come from ``_rtcore.model_table()`` (Contract 3), the same
table the Rust codec and the simulated bus read, so an address is written down exactly once.
This module only adds what Python needs at setup: look a model up by its model number, find an
item by name, and convert between raw register values and SI units.

Units are parsed from the table's unit text ("0.229 rev/min", "2 us", "pulse",
"0.11 rev/min, bit 10 = CW", "4.5 mA, 2048 = 0") rather than kept in a second table here,
for the same reason. Values come out in SI: rad, rad/s, rad/s², s, V, A, °C; percentages and
dimensionless items stay as they are.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from functools import cache
from typing import Any

from admittance.errors import ConfigError, DeviceError

TICKS_PER_REV = 4096

# Unit text → (SI factor per unit, SI unit name).
_SI_UNITS: dict[str, tuple[float, str]] = {
    "pulse": (2.0 * math.pi / TICKS_PER_REV, "rad"),
    "rev/min": (2.0 * math.pi / 60.0, "rad/s"),
    "rev/min^2": (2.0 * math.pi / 3600.0, "rad/s^2"),
    "deg/s^2": (math.pi / 180.0, "rad/s^2"),
    "deg": (math.pi / 180.0, "rad"),
    "V": (1.0, "V"),
    "mA": (1e-3, "A"),
    "A": (1.0, "A"),
    "us": (1e-6, "s"),
    "ms": (1e-3, "s"),
    "s": (1.0, "s"),
    "degC": (1.0, "degC"),
    "%": (1.0, "%"),
}
_SIGN_BIT = re.compile(r"bit\s+(\d+)\s*=\s*CW", re.IGNORECASE)
_OFFSET = re.compile(r"(-?\d+)\s*=\s*0")


@dataclass(frozen=True)
class Unit:
    """raw → SI: ``sign · (raw − offset) · scale`` where a sign bit marks CW (negative)."""

    scale: float = 1.0
    name: str = ""
    offset: int = 0
    sign_bit: int | None = None

    @classmethod
    def parse(cls, text: str) -> Unit:
        base, *modifiers = [part.strip() for part in text.split(",")]
        number, _, unit = base.partition(" ")
        try:
            count = float(number)
        except ValueError:  # "pulse": no leading number
            count, unit = 1.0, base
        factor, name = _SI_UNITS.get(unit.strip(), (1.0, unit.strip()))
        offset, sign_bit = 0, None
        for modifier in modifiers:
            if m := _SIGN_BIT.search(modifier):
                sign_bit = int(m.group(1))
            elif m := _OFFSET.search(modifier):
                offset = int(m.group(1))
        return cls(count * factor, name, offset, sign_bit)

    def to_si(self, raw: int) -> float:
        if self.sign_bit is not None:
            magnitude = raw & ((1 << self.sign_bit) - 1)
            return (-magnitude if raw & (1 << self.sign_bit) else magnitude) * self.scale
        return (raw - self.offset) * self.scale

    def from_si(self, value: float) -> int:
        counts = round(value / self.scale)
        if self.sign_bit is not None:
            return abs(counts) | ((1 << self.sign_bit) if counts < 0 else 0)
        return counts + self.offset


@dataclass(frozen=True)
class Item:
    name: str
    address: int
    size: int
    writable: bool
    eeprom: bool
    signed: bool
    minimum: int | None
    maximum: int | None
    unit: Unit

    def decode(self, data: bytes | list[int]) -> int:
        return int.from_bytes(bytes(data[: self.size]), "little", signed=self.signed)

    def encode(self, raw: int) -> bytes:
        if (self.minimum is not None and raw < self.minimum) or (self.maximum is not None and raw > self.maximum):
            raise ConfigError(f"{self.name} = {raw} is outside its range {self.minimum}..{self.maximum}")
        try:
            return int(raw).to_bytes(self.size, "little", signed=self.signed)
        except OverflowError:
            raise ConfigError(f"{self.name} = {raw} does not fit in {self.size} bytes") from None


@dataclass(frozen=True)
class ControlTable:
    """One servo model on one firmware protocol."""

    name: str
    number: int
    protocol: int
    items: dict[str, Item]

    def item(self, name: str) -> Item:
        try:
            return self.items[name.lower()]
        except KeyError:
            raise ConfigError(f"{self.name} (Protocol {self.protocol}.0) has no control-table item '{name}'") from None

    def has(self, name: str) -> bool:
        return name.lower() in self.items


def _item(entry: dict[str, Any]) -> Item:
    return Item(
        name=entry["name"],
        address=int(entry["address"]),
        size=int(entry["size"]),
        writable=str(entry["access"]).upper() == "RW",
        eeprom=bool(entry["eeprom"]),
        signed=bool(entry.get("signed", False)),
        minimum=entry.get("min"),
        maximum=entry.get("max"),
        unit=Unit.parse(entry.get("unit") or ""),
    )


@cache
def _tables() -> dict[tuple[int, int], ControlTable]:
    from admittance import _rtcore

    tables = {}
    for model in _rtcore.model_table():
        items = {entry["name"].lower(): _item(entry) for entry in model["items"]}
        table = ControlTable(model["name"], int(model["number"]), int(model["protocol"]), items)
        tables[(table.protocol, table.number)] = table
    return tables


def table_for_number(protocol: int, model_number: int) -> ControlTable:
    """The table of the model that answered with ``model_number`` on this protocol."""
    try:
        return _tables()[(protocol, model_number)]
    except KeyError:
        known = ", ".join(f"{t.name} ({t.number})" for t in _tables().values() if t.protocol == protocol)
        raise DeviceError(
            f"model number {model_number} is not a supported Protocol {protocol}.0 servo (supported: {known})"
        ) from None


def table_for_name(name: str, protocol: int) -> ControlTable:
    for table in _tables().values():
        if table.protocol == protocol and table.name.lower() == name.lower():
            return table
    known = sorted({t.name for t in _tables().values() if t.protocol == protocol})
    raise ConfigError(f"unknown servo model '{name}' for Protocol {protocol}.0 (known: {', '.join(known)})")
