"""The ROS 2 message types the daemon publishes, their RIHS01 type hashes, and their CDR encoders.

Type hashes follow REP-2011 as ``rosidl_generator_type_description`` computes them: the type's
description (its fields, and every type it references, sorted by name; default values left
out) written as JSON with ``", "`` and ``": "`` separators and keys in a fixed order, hashed with
SHA-256 and prefixed ``RIHS01_``. rmw_zenoh puts the hash in every key expression, so a
subscriber whose hash differs never matches. tests/test_ros2.py checks each hash against the
values the ROS 2 distributions publish (and against rosbags' own computation).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from dataclasses import dataclass

from admittance.ros2.cdr import CdrWriter

# type_description_interfaces/msg/FieldType ids used here
NESTED = 1
INT32 = 6
UINT32 = 7
DOUBLE = 11
STRING = 17
DOUBLE_UNBOUNDED_SEQUENCE = 155
STRING_UNBOUNDED_SEQUENCE = 161


@dataclass(frozen=True)
class Field:
    name: str
    type_id: int
    nested: str = ""  # the nested type's name ("pkg/msg/Name") for NESTED fields


TYPES: dict[str, tuple[Field, ...]] = {
    "builtin_interfaces/msg/Time": (Field("sec", INT32), Field("nanosec", UINT32)),
    "std_msgs/msg/Header": (Field("stamp", NESTED, "builtin_interfaces/msg/Time"), Field("frame_id", STRING)),
    "sensor_msgs/msg/JointState": (
        Field("header", NESTED, "std_msgs/msg/Header"), Field("name", STRING_UNBOUNDED_SEQUENCE),
        Field("position", DOUBLE_UNBOUNDED_SEQUENCE), Field("velocity", DOUBLE_UNBOUNDED_SEQUENCE),
        Field("effort", DOUBLE_UNBOUNDED_SEQUENCE)),
    "geometry_msgs/msg/Vector3": (Field("x", DOUBLE), Field("y", DOUBLE), Field("z", DOUBLE)),
    "geometry_msgs/msg/Wrench": (Field("force", NESTED, "geometry_msgs/msg/Vector3"),
                                 Field("torque", NESTED, "geometry_msgs/msg/Vector3")),
    "geometry_msgs/msg/WrenchStamped": (Field("header", NESTED, "std_msgs/msg/Header"),
                                        Field("wrench", NESTED, "geometry_msgs/msg/Wrench")),
}

JOINT_STATE = "sensor_msgs/msg/JointState"
WRENCH_STAMPED = "geometry_msgs/msg/WrenchStamped"


def _individual(type_name: str) -> dict:
    return {"type_name": type_name, "fields": [
        {"name": f.name, "type": {"type_id": f.type_id, "capacity": 0, "string_capacity": 0,
                                  "nested_type_name": f.nested}}
        for f in TYPES[type_name]]}


def _referenced(type_name: str) -> list[str]:
    found: set[str] = set()
    queue = [f.nested for f in TYPES[type_name] if f.nested]
    while queue:
        name = queue.pop()
        if name not in found:
            found.add(name)
            queue.extend(f.nested for f in TYPES[name] if f.nested)
    return sorted(found)


def referenced_types(type_name: str) -> list[str]:
    """Every type ``type_name`` uses, directly or not, sorted by name."""
    return _referenced(type_name)


def type_hash(type_name: str) -> str:
    """``RIHS01_<sha256 hex>`` of a type in :data:`TYPES` (REP-2011)."""
    description = {"type_description": _individual(type_name),
                   "referenced_type_descriptions": [_individual(n) for n in _referenced(type_name)]}
    text = json.dumps(description, ensure_ascii=True, allow_nan=False, separators=(", ", ": "), sort_keys=False)
    return "RIHS01_" + hashlib.sha256(text.encode("utf-8")).hexdigest()


def dds_type_name(type_name: str) -> str:
    """The name rmw_zenoh puts in keys: ``sensor_msgs/msg/JointState`` -> ``sensor_msgs::msg::dds_::JointState_``."""
    package, kind, name = type_name.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def _header(w: CdrWriter, stamp_ns: int, frame_id: str) -> None:
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    w.int32(sec)
    w.uint32(nanosec)
    w.string(frame_id)


def joint_state(stamp_ns: int, names: Sequence[str], position: Sequence[float], velocity: Sequence[float],
                effort: Sequence[float], frame_id: str = "") -> bytes:
    """A CDR-encoded sensor_msgs/msg/JointState."""
    w = CdrWriter()
    _header(w, stamp_ns, frame_id)
    w.string_sequence(names)
    w.float64_sequence(position)
    w.float64_sequence(velocity)
    w.float64_sequence(effort)
    return bytes(w)


def wrench_stamped(stamp_ns: int, frame_id: str, force: Sequence[float], torque: Sequence[float]) -> bytes:
    """A CDR-encoded geometry_msgs/msg/WrenchStamped (N, N·m)."""
    w = CdrWriter()
    _header(w, stamp_ns, frame_id)
    for value in (*force, *torque):
        w.float64(value)
    return bytes(w)
