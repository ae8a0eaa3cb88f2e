"""Typed payloads of the Zenoh keys, and their two encodings (JSON, MessagePack).

Every payload the daemon sends or accepts is described by a msgspec Struct here, so the daemon,
``admittance monitor``/``set`` and outside tools share one schema, and a malformed request
fails in the decoder with a message rather than deep in the supervisor.

Decoding sniffs the encoding: a JSON object starts with ``{`` (after optional blanks) and a
MessagePack map never does (0x80–0x8f, 0xde, 0xdf), so clients need not be told which
encoding a daemon was configured with.

Requests (a set, a tare) are hostile input: their size and nesting are bounded on the raw bytes
before decoding (``payload_limits``), an integer a float cannot hold exactly is refused by name,
and every failure is a DataError whose message stays short (``schema.shown``).
"""

from __future__ import annotations

from typing import Any, TypeVar

import msgspec

from admittance.daemon import payload_limits
from admittance.daemon.schema import MAX_EXACT_INT, clip, shown
from admittance.errors import DataError

T = TypeVar("T")


class JointState(msgspec.Struct, omit_defaults=True):
    id: int
    t: float  # s, CLOCK_MONOTONIC of the cycle
    force: float  # N, the tared force on the configured axis
    tau: float  # N·m, the hand torque applied to the model
    theta: float  # rad, model angle
    omega: float  # rad/s, model velocity
    goal_tick: int
    present_tick: int | None = None  # the servo's position when it was read this cycle
    fault: int = 0  # the fault kinds active for this joint (bits: _rtcore.FAULT_KINDS)
    # For ROS users (extensions; absent from older daemons):
    name: str | None = None  # the joint's configured name, else "joint<ID>"
    wall: float | None = None  # s since the Unix epoch (CLOCK_REALTIME) of the same cycle as t
    position: float | None = None  # rad, the measured angle of present_tick
    rendering_rms: float | None = None  # rad: running RMS of present − model angle (1 s), once read
    passivity_energy: float | None = None  # J: the passivity guard's energy balance (< −margin: it acts)
    passivity_damping: float | None = None  # N·m·s/rad: the damping the passivity guard adds now
    goal: float | None = None  # rad, the angle of goal_tick (within the joint's position limits)


class State(msgspec.Struct):
    cycle: int
    joints: list[JointState]
    mode: str = "running"  # the loop's mode: "running", "holding" (stale force) or "faulted"


class Percentiles(msgspec.Struct):
    p50: float
    p99: float
    p999: float
    max: float


class RtInfo(msgspec.Struct):
    policy: str
    priority: int
    memory_locked: bool


class Stats(msgspec.Struct):
    """The keys of ../shared/contracts/daemon.md that every stats object must hold."""

    cycles: int
    overruns: int
    rate_hz: float
    period_us: Percentiles
    latency_us: Percentiles
    bus_errors: int
    sensor_samples: int
    sensor_stale_events: int
    rt: RtInfo


STATS_KEYS = ("cycles", "overruns", "rate_hz", "period_us", "latency_us", "bus_errors",
              "sensor_samples", "sensor_stale_events", "rt")


class ParamsReply(msgspec.Struct):
    params: dict[str, float | list[float]]  # "<id>.<name>" per joint, loop-wide names bare


class SetReply(msgspec.Struct, omit_defaults=True):
    accepted: bool
    reason: str = ""


def stats_message(stats: dict[str, Any]) -> dict[str, Any]:
    """The loop's stats, checked against :class:`Stats`, published as they are.

    ``<prefix>/stats`` is "the --stats-json object so far", so the payload is the loop's own
    object with every key it reports (work_us, sync_reads...); the struct only guarantees that
    the contract's keys are there with the right types.
    """
    try:
        msgspec.convert(stats, Stats, strict=False)
    except msgspec.ValidationError as exc:
        raise DataError(f"stats: {exc}") from None
    return stats


class Codec:
    """Encoder for one configured encoding; the decoder accepts both."""

    def __init__(self, encoding: str = "json") -> None:
        if encoding not in ("json", "msgpack"):
            raise ValueError(f"unknown encoding {encoding!r}")
        self.encoding = encoding
        self._encoder = msgspec.json.Encoder() if encoding == "json" else msgspec.msgpack.Encoder()

    def encode(self, obj: Any) -> bytes:
        return self._encoder.encode(obj)


def is_json(payload: bytes) -> bool:
    return payload.lstrip()[:1] in (b"{", b"[")


# What the daemon accepts from the network, checked on the raw bytes before decoding.
MAX_REQUEST_BYTES = 16 * 1024
MAX_REQUEST_DEPTH = 4  # an object of lists of numbers is 2
# What the tools accept from a daemon (its publications are bounded by what it sends).
MAX_MESSAGE_BYTES = 16 * 1024 * 1024


def decode(payload: bytes, typ: type[T] = Any, *, max_bytes: int = MAX_MESSAGE_BYTES,  # type: ignore[assignment]
           max_depth: int | None = None) -> T:
    """Decode a JSON or MessagePack payload into ``typ``; DataError on anything malformed or too
    large, and, with ``max_depth``, nested too deep (checked on the raw bytes, before decoding)."""
    json = is_json(payload)
    payload_limits.check(payload, max_bytes=max_bytes, max_depth=max_depth, is_json=json)
    try:
        if json:
            return msgspec.json.decode(payload, type=typ)
        return msgspec.msgpack.decode(payload, type=typ)
    except (msgspec.DecodeError, msgspec.ValidationError, UnicodeDecodeError) as exc:
        # msgspec's MessagePack decoder lets a string with invalid UTF-8 escape as a
        # UnicodeDecodeError rather than its own DecodeError.
        raise DataError(f"malformed payload: {clip(str(exc), 120)}") from None
    except RecursionError:  # a publication nested past the interpreter's limit (requests never get here)
        raise DataError("malformed payload: nested too deep") from None


def decode_request(payload: bytes, typ: type[T] = Any) -> T:  # type: ignore[assignment]
    """A request from the network: :func:`decode` with the request's size and depth bounds."""
    return decode(payload, typ, max_bytes=MAX_REQUEST_BYTES, max_depth=MAX_REQUEST_DEPTH)


def decode_set_request(payload: bytes) -> dict[str, float | list[float]]:
    """A set request: an object of ``{"name": number or list of numbers}``; DataError says what is wrong.

    Values stay as the request gave them (ints are not turned into floats here: an int too
    large for a float is refused by name, not left to overflow); the schema checks their range.
    """
    if not payload.strip():
        raise DataError("empty request")
    request = decode_request(payload, dict[str, Any])
    if not request:
        raise DataError("empty request: no parameter given")
    return {name: _number_or_list(name, value) for name, value in request.items()}


def _number_or_list(name: str, value: Any) -> float | int | list[float | int]:
    if isinstance(value, list):
        return [_number(f"{name}[{i}]", v) for i, v in enumerate(value)]
    return _number(name, value)


def _number(name: str, value: Any) -> float | int:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise DataError(f"{clip(name)}: expected a number, got {shown(value)}")
    if isinstance(value, int) and abs(value) > MAX_EXACT_INT:
        raise DataError(f"{clip(name)}: integer out of range (beyond ±2^53), got {shown(value)}")
    return value


class TareRequest(msgspec.Struct, forbid_unknown_fields=True):
    samples: int = 100


MAX_TARE_SAMPLES = 100_000


def decode_tare_request(payload: bytes) -> int:
    """A tare request: ``{"samples": n}`` with 1 ≤ n ≤ 100000, or ``{}`` for 100 samples. A tare
    acts on the joint, so it needs an explicit payload: an empty get is not a tare."""
    if not payload.strip():
        raise DataError('a tare needs a payload: {"samples": n} (or {} for 100 samples)')
    samples = decode_request(payload, TareRequest).samples
    if not 1 <= samples <= MAX_TARE_SAMPLES:
        raise DataError(f"samples: must be 1..{MAX_TARE_SAMPLES}, got {shown(samples)}")
    return samples
