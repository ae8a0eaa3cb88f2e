"""Publish the joints and the force to ROS 2 nodes that use rmw_zenoh, on the daemon's own session.

What rmw_zenoh (ros2/rmw_zenoh, docs/design.md) needs to see a publisher, and what is built here:

- data on ``<domain_id>/<fully qualified topic, no leading '/'>/<DDS type name>/<RIHS01 hash>``,
  e.g. ``0/joint_states/sensor_msgs::msg::dds_::JointState_/RIHS01_a13e...``;
- CDR payloads with their encapsulation header (admittance.ros2.messages);
- an attachment on every sample: sequence number (int64 LE), source timestamp (int64 LE, ns since
  the Unix epoch), then the publisher's 16-byte GID as a sequence (one length byte, 16);
- liveliness tokens for the graph cache, one for the node and one per publisher:
  ``@ros2_lv/<domain>/<zid>/<node id>/<node id>/NN/<enclave>/<namespace>/<node>`` and
  ``@ros2_lv/<domain>/<zid>/<node id>/<entity id>/MP/<enclave>/<namespace>/<node>/<topic>/<type>/<hash>/<qos>``,
  where names have each ``/`` replaced by ``%`` (an empty enclave or namespace is ``%``) and the
  QoS is rmw_zenoh's compact form with defaults left empty (reliable, volatile, keep-last 10:
  ``::,10:,:,:,,``).

rmw_zenoh derives a GID by hashing the token with XXH3-128; subscribers only copy it into the
message info, so a BLAKE2b-128 of the same token serves (no extra dependency), still unique per
publisher.

The supervisor calls :meth:`Ros2Bridge.publish` from its own tick (never the RT thread), with the
newest State message; nothing here runs on Zenoh's threads.
"""

from __future__ import annotations

import hashlib
import struct
import time
from dataclasses import dataclass
from typing import Any

from admittance.ros2 import messages

ADMIN_SPACE = "@ros2_lv"
DEPTH = 10
# reliability:durability:history,depth:deadline:lifespan:liveliness (defaults left empty)
QOS_KEYEXPR = f"::,{DEPTH}:,:,:,,"
NODE_ID = 0
AXIS_INDEX = {"x": 0, "y": 1, "z": 2}


def mangle(name: str) -> str:
    """rmw_zenoh's name mangling: every '/' becomes '%' (so "" and "/" both need care: see below)."""
    return name.replace("/", "%")


def fully_qualified(namespace: str, topic: str) -> str:
    return f"{namespace.rstrip('/')}/{topic}" if namespace else f"/{topic}"


def topic_keyexpr(domain_id: int, namespace: str, topic: str, type_name: str) -> str:
    return (f"{domain_id}/{fully_qualified(namespace, topic).lstrip('/')}/"
            f"{messages.dds_type_name(type_name)}/{messages.type_hash(type_name)}")


def node_token(domain_id: int, zid: str, namespace: str, node: str) -> str:
    return f"{ADMIN_SPACE}/{domain_id}/{zid}/{NODE_ID}/{NODE_ID}/NN/%/{mangle(namespace or '/')}/{node}"


def publisher_token(domain_id: int, zid: str, entity_id: int, namespace: str, node: str, topic: str,
                    type_name: str) -> str:
    return (f"{ADMIN_SPACE}/{domain_id}/{zid}/{NODE_ID}/{entity_id}/MP/%/{mangle(namespace or '/')}/{node}/"
            f"{mangle(fully_qualified(namespace, topic))}/{messages.dds_type_name(type_name)}/"
            f"{messages.type_hash(type_name)}/{QOS_KEYEXPR}")


def gid_of(token: str) -> bytes:
    return hashlib.blake2b(token.encode(), digest_size=16).digest()


def attachment(sequence: int, source_timestamp_ns: int, gid: bytes) -> bytes:
    """rmw_zenoh's sample attachment (zenoh-ext serialization of int64, int64, uint8[16])."""
    return struct.pack("<qqB", sequence, source_timestamp_ns, len(gid)) + gid


@dataclass
class _Publisher:
    publisher: Any
    token: Any
    gid: bytes
    sequence: int = 1

    def put(self, zenoh_bytes: bytes) -> None:
        self.publisher.put(zenoh_bytes, attachment=attachment(self.sequence, time.time_ns(), self.gid))
        self.sequence += 1


class Ros2Bridge:
    """The node ``[ros2].node`` with publishers ``joint_states`` and ``wrench`` on ``session``."""

    def __init__(self, session: Any, cfg: Any) -> None:
        import zenoh

        r = cfg.ros2
        self._cfg = cfg
        zid = str(session.info.zid())
        self._node_token = session.liveliness().declare_token(node_token(r.domain_id, zid, r.namespace, r.node))
        self._publishers: dict[str, _Publisher] = {}
        for entity_id, (topic, type_name) in enumerate(
                (("joint_states", messages.JOINT_STATE), ("wrench", messages.WRENCH_STAMPED)), start=1):
            token_key = publisher_token(r.domain_id, zid, entity_id, r.namespace, r.node, topic, type_name)
            publisher = session.declare_publisher(
                topic_keyexpr(r.domain_id, r.namespace, topic, type_name),
                congestion_control=zenoh.CongestionControl.DROP, reliability=zenoh.Reliability.RELIABLE)
            self._publishers[topic] = _Publisher(publisher, session.liveliness().declare_token(token_key),
                                                 gid_of(token_key))
        self._axis = AXIS_INDEX.get(cfg.sensor.axis, 0)
        self.published = 0

    def publish(self, state: Any) -> None:
        """One JointState and one WrenchStamped from a State message (docs/ros2.md says what is in them)."""
        joints = state.joints
        if not joints:
            return
        stamp_ns = round(joints[-1].wall * 1e9) if joints[-1].wall is not None else time.time_ns()
        self._publishers["joint_states"].put(messages.joint_state(
            stamp_ns, [j.name or f"joint{j.id}" for j in joints],
            [j.position if j.position is not None else j.theta for j in joints],
            [j.omega for j in joints], [j.tau for j in joints]))
        force = [0.0, 0.0, 0.0]
        force[self._axis] = joints[0].force
        self._publishers["wrench"].put(messages.wrench_stamped(stamp_ns, self._cfg.sensor.frame_id, force,
                                                               (0.0, 0.0, 0.0)))
        self.published += 1

    def close(self) -> None:
        """Tokens first, so ROS 2 graphs drop the node at once."""
        for pub in self._publishers.values():
            pub.token.undeclare()
        self._node_token.undeclare()
        for pub in self._publishers.values():
            pub.publisher.undeclare()
