"""A tiny declarative schema for the daemon's TOML: one dataclass per table, one field per key.

Why not a validation library (pydantic, cerberus)? The configuration has about forty keys and
one error style: *one line that names the key and the problem*. Keeping each key's type, range,
unit, default and live-updatability beside the dataclass field that holds it means the
validator, the documentation check (tests/test_daemon_config.py reads docs/daemon.md against
these fields) and the code that uses the values cannot drift apart.

The same metadata checks a live change (``admittance set``, ``<prefix>/params``): a key
declared ``live=True`` with bounds is checked on both paths by :func:`check_value`, with the
same message, so a new key is safe on both the day it is added. Values may come from the
network, so a message never echoes more than a short form of them (:func:`shown`).
"""

from __future__ import annotations

import dataclasses
import difflib
import math
from typing import Any

from admittance.errors import ConfigError

REQUIRED = object()


def key(
    kind: str,
    default: Any = REQUIRED,
    *,
    unit: str = "",
    lo: float | None = None,
    hi: float | None = None,
    lo_open: bool = False,
    choices: tuple | None = None,
    min_abs: float | None = None,
    length: int | None = None,
    live: bool = False,
    doc: str = "",
) -> Any:
    """Declare one configuration key.

    kind: "int", "float", "bool", "str", "str_list", "float_list" or "table" (kept as a dict).
    lo/hi bound numbers (and list items); lo_open makes the lower bound strict; min_abs keeps
    a number away from 0 (|value| >= min_abs, either sign); length fixes a list's length.
    live: the key can be changed while the loop runs (through the params queryable).
    """
    meta = dict(kind=kind, unit=unit, lo=lo, hi=hi, lo_open=lo_open, choices=choices, min_abs=min_abs,
                length=length, live=live, doc=doc)
    if default is REQUIRED:
        return dataclasses.field(metadata=meta)
    if isinstance(default, (list, dict)):
        return dataclasses.field(default_factory=lambda: type(default)(default), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def build(cls: type, table: Any, where: str) -> Any:
    """Validate ``table`` against the dataclass ``cls``; ``where`` prefixes every message."""
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: expected a table, got {type(table).__name__}")
    fields = {f.name: f for f in dataclasses.fields(cls) if not f.metadata.get("internal")}
    for name in table:
        if name not in fields:
            raise ConfigError(f"{where}: unknown key {clip(repr(name))}{did_you_mean(name, fields)}")
    values = {}
    for name, field in fields.items():
        if name in table:
            values[name] = check_value(field.metadata, table[name], f"{where}.{name}")
        elif field.default is dataclasses.MISSING and field.default_factory is dataclasses.MISSING:
            raise ConfigError(f"{where}.{name}: required key is missing")
    return cls(**values)


def did_you_mean(name: str, known) -> str:
    close = difflib.get_close_matches(name, list(known), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else f" (known: {', '.join(sorted(known))})"


def check_value(meta: dict, value: Any, where: str) -> Any:
    """``value`` checked against one key's metadata (type, finite, range, choices, length);
    returns it normalised (an int given for a float becomes a float). ConfigError says why."""
    kind = meta["kind"]
    if kind in ("str_list", "float_list"):
        if not isinstance(value, list):
            raise ConfigError(f"{where}: expected a list, got {shown(value)}")
        if meta.get("length") is not None and len(value) != meta["length"]:
            raise ConfigError(f"{where}: expected {meta['length']} values, got {len(value)}")
        item_kind = "str" if kind == "str_list" else "float"
        return [check_value({**meta, "kind": item_kind}, v, f"{where}[{i}]") for i, v in enumerate(value)]
    value = _check_type(kind, value, where)
    if meta["choices"] is not None and value not in meta["choices"]:
        options = ", ".join(repr(c) for c in meta["choices"])
        raise ConfigError(f"{where}: expected one of {options}, got {shown(value)}")
    if kind in ("int", "float"):
        _check_range(meta, value, where)
    return value


# Integers a float holds exactly: a larger one would be rounded (or overflow) on its way to the loop.
MAX_EXACT_INT = 2**53


def _check_type(kind: str, value: Any, where: str) -> Any:
    if kind == "table":
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a table, got {shown(value)}")
        return value
    if kind == "bool":
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {shown(value)}")
        return value
    if kind == "str":
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {shown(value)}")
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{where}: expected a number, got {shown(value)}")
    if isinstance(value, int) and abs(value) > MAX_EXACT_INT:
        raise ConfigError(f"{where}: integer out of range (beyond ±2^53), got {shown(value)}")
    if kind == "int":
        if isinstance(value, float):
            raise ConfigError(f"{where}: expected an integer, got {shown(value)}")
        return value
    if not math.isfinite(value):
        raise ConfigError(f"{where}: must be finite, got {shown(value)}")
    return float(value)


def _check_range(meta: dict, value: float, where: str) -> None:
    lo, hi, unit = meta["lo"], meta["hi"], f" {meta['unit']}" if meta["unit"] else ""
    if lo is not None and (value <= lo if meta["lo_open"] else value < lo):
        op = ">" if meta["lo_open"] else ">="
        raise ConfigError(f"{where}: must be {op} {lo:g}{unit}, got {shown(value)}")
    if hi is not None and value > hi:
        raise ConfigError(f"{where}: must be <= {hi:g}{unit}, got {shown(value)}")
    min_abs = meta.get("min_abs")
    if min_abs is not None and abs(value) < min_abs:
        raise ConfigError(f"{where}: must be at least {min_abs:g}{unit} either side of 0, got {shown(value)}")


SHOWN_CHARS = 40


def shown(value: Any) -> str:
    """A short, readable form of any value for a message: numbers in %.6g (a 400-digit int is
    not echoed), strings and everything else cut at 40 characters."""
    if isinstance(value, bool):
        return repr(value)
    if isinstance(value, int):
        return repr(value) if abs(value) < 10**15 else f"an integer of about {_digits(value)} digits"
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, (list, tuple)) and len(value) <= 6 and all(isinstance(v, (int, float)) for v in value):
        return "[" + ", ".join(shown(v) for v in value) + "]"
    text = repr(value) if not isinstance(value, (list, tuple, dict)) else f"a {type(value).__name__} of {len(value)}"
    return text if len(text) <= SHOWN_CHARS else f"{text[:SHOWN_CHARS]}… ({len(text)} characters)"


def clip(text: str, n: int = SHOWN_CHARS) -> str:
    """At most ``n`` characters of ``text`` (a name, a decoder's message), marked when cut."""
    return text if len(text) <= n else f"{text[:n]}…"


def _digits(value: int) -> int:
    """Decimal digits of a (possibly huge) int, without str() (which refuses beyond 4300 digits)."""
    return max(1, math.floor(abs(value).bit_length() * math.log10(2)) + 1)


def describe(cls: type) -> list[dict]:
    """Every key of ``cls`` with its metadata (for docs checks and `set` validation)."""
    out = []
    for f in dataclasses.fields(cls):
        default = None if f.default is dataclasses.MISSING else f.default
        if f.default_factory is not dataclasses.MISSING:
            default = f.default_factory()
        out.append({"name": f.name, "default": default, **f.metadata})
    return out
