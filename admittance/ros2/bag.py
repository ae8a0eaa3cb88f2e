"""``DIR/rosbag2/``: a ``--record`` session as a rosbag2 bag, for ROS 2's own tools.

``session.mcap`` (admittance.daemon.mcap_recording) holds JSON channels, which rosbag2 readers
refuse ("Profile is not ros2"); a ROS 2 reader also refuses a file that mixes JSON channels with
its own. So the same cycles are written a second time, beside it, as a rosbag2 folder:
``metadata.yaml`` and ``rosbag2_0.mcap`` (the ``ros2`` MCAP profile, ``ros2msg`` schemas, CDR
messages, zstd chunks), which ``ros2 bag info``/``ros2 bag play`` and the ``rosbags`` library
read. The topics are those of the live ROS 2 bridge (rmw_zenoh.py, docs/ros2.md):

| topic | type | one message per | content |
|---|---|---|---|
| ``/joint_states`` | ``sensor_msgs/msg/JointState`` | loop cycle | per joint: ``name``, ``position`` (rad: the measured angle on the cycles that read it, else the model's), ``velocity`` (rad/s, the model's), ``effort`` (N·m, the torque the cycle integrated) |
| ``/wrench`` | ``geometry_msgs/msg/WrenchStamped`` | loop cycle | the cycle's force (N) on the sensor's configured axis, ``header.frame_id`` the sensor's frame |

``header.stamp`` and the message's log time are the cycle's wall-clock time, with the session's
one clock offset (as session.mcap): a reader that orders by stamp keeps the cycles' order, and a
cycle that took no step (its predecessor's ``t``) ties with it and follows it. ``metadata.yaml``
(written as JSON, which YAML reads) is written at the close; a session cut short leaves the MCAP
file readable up to its last chunk, and ``ros2 bag reindex`` rebuilds the metadata.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from admittance.errors import ConfigError
from admittance.ros2 import messages

BAG_FILE = "rosbag2_0.mcap"
METADATA = "metadata.yaml"
CHUNK_BYTES = 256 * 1024
MSG_TYPES = {  # type_id -> the .msg spelling
    messages.INT32: "int32", messages.UINT32: "uint32", messages.DOUBLE: "float64", messages.STRING: "string",
    messages.DOUBLE_UNBOUNDED_SEQUENCE: "float64[]", messages.STRING_UNBOUNDED_SEQUENCE: "string[]",
}
SEPARATOR = "=" * 80


def _short(type_name: str) -> str:
    """``std_msgs/msg/Header`` -> ``std_msgs/Header``, as .msg files and rosbag2 schemas name types."""
    package, _, name = type_name.split("/")
    return f"{package}/{name}"


def _msg_text(type_name: str) -> str:
    return "\n".join(f"{_short(f.nested) if f.type_id == messages.NESTED else MSG_TYPES[f.type_id]} {f.name}"
                     for f in messages.TYPES[type_name]) + "\n"


def msg_definition(type_name: str) -> str:
    """The ``ros2msg`` schema rosbag2 stores: the type's .msg text, then each type it uses."""
    parts = [_msg_text(type_name)]
    for nested in messages.referenced_types(type_name):
        parts.append(f"{SEPARATOR}\nMSG: {_short(nested)}\n{_msg_text(nested)}")
    return "\n".join(parts)


class Ros2Bag:
    """Writes ``folder/rosbag2_0.mcap`` as cycles arrive and ``folder/metadata.yaml`` at the close."""

    TOPICS = {"/joint_states": messages.JOINT_STATE, "/wrench": messages.WRENCH_STAMPED}

    def __init__(self, folder: Path, names: dict[int, str], frame_id: str, force_axis: int) -> None:
        from mcap.writer import CompressionType, Writer

        from admittance.daemon.mcap_recording import pack_chunk_indices

        self.folder = folder
        try:
            folder.mkdir(parents=True, exist_ok=True)
            # a previous session's metadata must not describe this file if this one is cut short
            (folder / METADATA).unlink(missing_ok=True)
            self._fh = (folder / BAG_FILE).open("wb")
        except OSError as exc:
            raise ConfigError(f"record: cannot write the rosbag2 bag in {folder} ({exc.strerror})") from None
        self._writer = Writer(self._fh, chunk_size=CHUNK_BYTES, compression=CompressionType.ZSTD)
        pack_chunk_indices(self._writer)
        self._writer.start(profile="ros2", library="admittance")
        self._channels = {}
        for topic, type_name in self.TOPICS.items():
            schema = self._writer.register_schema(type_name, "ros2msg", msg_definition(type_name).encode())
            self._channels[topic] = self._writer.register_channel(topic, "cdr", schema,
                                                                  metadata={"offered_qos_profiles": ""})
        self._names, self._frame_id, self._axis = names, frame_id, force_axis
        self.counts = dict.fromkeys(self.TOPICS, 0)
        self._first_ns: int | None = None
        self._last_ns = 0

    def _write(self, topic: str, wall_ns: int, data: bytes) -> None:
        self._writer.add_message(self._channels[topic], log_time=wall_ns, publish_time=wall_ns, data=data,
                                 sequence=self.counts[topic])
        self.counts[topic] += 1
        self._first_ns = wall_ns if self._first_ns is None else min(self._first_ns, wall_ns)
        self._last_ns = max(self._last_ns, wall_ns)

    def append(self, by_joint: dict[int, dict[str, np.ndarray]], wall_offset_ns: int) -> None:
        """The cycles of one drain: one JointState (every joint) and one WrenchStamped per cycle.
        Joints whose cycles differ from the first joint's are written in messages of their own."""
        groups: list[list[int]] = []
        for jid, columns in by_joint.items():
            same = next((g for g in groups if np.array_equal(by_joint[g[0]]["cycle"], columns["cycle"])), None)
            if same is None:
                groups.append([jid])
            else:
                same.append(jid)
        for group in groups:
            self._append_group(group, by_joint, wall_offset_ns)

    def _append_group(self, group: list[int], by_joint: dict[int, dict[str, np.ndarray]], offset: int) -> None:
        first = by_joint[group[0]]
        stamps = (np.rint(first["t"] * 1e9).astype(np.int64) + offset).tolist()
        names = [self._names.get(jid, f"joint{jid}") for jid in group]
        position = np.array([np.where(np.isnan(by_joint[j]["theta_present"]), by_joint[j]["theta_model"],
                                      by_joint[j]["theta_present"]) for j in group]).T.tolist()
        velocity = np.array([by_joint[j]["omega_model"] for j in group]).T.tolist()
        effort = np.array([by_joint[j]["tau"] for j in group]).T.tolist()
        force = first["force"].tolist()
        for k, stamp in enumerate(stamps):
            self._write("/joint_states", stamp, messages.joint_state(stamp, names, position[k], velocity[k], effort[k]))
            vector = [0.0, 0.0, 0.0]
            vector[self._axis] = force[k]
            self._write("/wrench", stamp, messages.wrench_stamped(stamp, self._frame_id, vector, (0.0, 0.0, 0.0)))

    def flush(self) -> None:
        self._fh.flush()

    def close(self) -> None:
        try:
            self._writer.finish()
        finally:
            self._fh.close()
        (self.folder / METADATA).write_text(json.dumps(self.metadata(), indent=1) + "\n")

    def metadata(self) -> dict[str, Any]:
        """rosbag2's bag information (version 8: type hashes; QoS left to the player's defaults)."""
        start = self._first_ns or 0
        duration = self._last_ns - start if self._first_ns is not None else 0
        total = sum(self.counts.values())
        topics = [{"topic_metadata": {"name": topic, "type": type_name, "serialization_format": "cdr",
                                      "offered_qos_profiles": "", "type_description_hash": messages.type_hash(type_name)},
                   "message_count": self.counts[topic]} for topic, type_name in self.TOPICS.items()]
        return {"rosbag2_bagfile_information": {
            "version": 8, "storage_identifier": "mcap", "relative_file_paths": [BAG_FILE],
            "duration": {"nanoseconds": duration}, "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": total, "topics_with_message_count": topics,
            "compression_format": "", "compression_mode": "",
            "files": [{"path": BAG_FILE, "starting_time": {"nanoseconds_since_epoch": start},
                       "duration": {"nanoseconds": duration}, "message_count": total}],
            "custom_data": {"recorded_by": "admittance run --record"}, "ros_distro": ""}}
