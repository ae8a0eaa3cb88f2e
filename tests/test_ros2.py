"""ROS 2 over rmw_zenoh: type hashes against the published RIHS01 values, CDR payloads decoded by
rosbags (never by our encoder), and the key expressions, attachment and liveliness tokens as
rmw_zenoh's design document specifies them, seen from a second Zenoh session on loopback."""

from __future__ import annotations

import time
from types import SimpleNamespace

import pytest
from hypothesis import given
from hypothesis import strategies as st

from admittance.daemon.messages import JointState, State
from admittance.ros2 import messages, rmw_zenoh

from helpers import free_endpoint

rosbags_typesys = pytest.importorskip("rosbags.typesys")
TYPESTORE = rosbags_typesys.get_typestore(rosbags_typesys.Stores.ROS2_JAZZY)

# As the ROS 2 distributions publish them (rosidl-generated *__description.c of Jazzy/Kilted).
PUBLISHED_HASHES = {
    "builtin_interfaces/msg/Time": "RIHS01_b106235e25a4c5ed35098aa0a61a3ee9c9b18d197f398b0e4206cea9acf9c197",
    "std_msgs/msg/Header": "RIHS01_f49fb3ae2cf070f793645ff749683ac6b06203e41c891e17701b1cb597ce6a01",
    "sensor_msgs/msg/JointState": "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e",
    "geometry_msgs/msg/Vector3": "RIHS01_cc12fe83e4c02719f1ce8070bfd14aecd40f75a96696a67a2a1f37f7dbb0765d",
    "geometry_msgs/msg/Wrench": "RIHS01_018e8519d57c16adbe97c9fe1460ef21fec7e31bc541de3d653a35895677ce52",
    "geometry_msgs/msg/WrenchStamped": "RIHS01_8dc3deaf06b2ab281f9f9a742a8961c328ca7cec16e3fd6586d3a5c83fa78f77",
}


@pytest.mark.parametrize("type_name", sorted(PUBLISHED_HASHES))
def test_type_hashes_are_the_published_ones(type_name):
    assert messages.type_hash(type_name) == PUBLISHED_HASHES[type_name]
    assert TYPESTORE.hash_rihs01(type_name) == PUBLISHED_HASHES[type_name]


finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
names = st.text(st.characters(codec="utf-8", exclude_characters="\x00"), max_size=12)


@given(stamp=st.integers(0, 2**31 * 10**9 - 1), joints=st.lists(st.tuples(names, finite, finite, finite), max_size=5),
       frame=names)
def test_joint_state_cdr_decodes_with_rosbags(stamp, joints, frame):
    raw = messages.joint_state(stamp, [j[0] for j in joints], [j[1] for j in joints], [j[2] for j in joints],
                               [j[3] for j in joints], frame_id=frame)
    msg = TYPESTORE.deserialize_cdr(raw, messages.JOINT_STATE)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == divmod(stamp, 10**9)
    assert msg.header.frame_id == frame and list(msg.name) == [j[0] for j in joints]
    assert list(msg.position) == [j[1] for j in joints] and list(msg.effort) == [j[3] for j in joints]
    assert TYPESTORE.serialize_cdr(msg, messages.JOINT_STATE) == raw  # byte for byte, padding included


@given(stamp=st.integers(0, 2**31 * 10**9 - 1), values=st.lists(finite, min_size=6, max_size=6), frame=names)
def test_wrench_stamped_cdr_decodes_with_rosbags(stamp, values, frame):
    raw = messages.wrench_stamped(stamp, frame, values[:3], values[3:])
    msg = TYPESTORE.deserialize_cdr(raw, messages.WRENCH_STAMPED)
    w = msg.wrench
    assert [w.force.x, w.force.y, w.force.z, w.torque.x, w.torque.y, w.torque.z] == values
    assert msg.header.frame_id == frame
    assert TYPESTORE.serialize_cdr(msg, messages.WRENCH_STAMPED) == raw


# --- rmw_zenoh's documented formats, parsed here independently of the module under test -------

def parse_token(key: str) -> dict:
    """rmw_zenoh docs/design.md: @ros2_lv/<domain>/<zid>/<nid>/<id>/<kind>/<enclave>/<ns>/<node>
    [/<topic>/<type>/<hash>/<qos>], names mangled with '%' for '/'."""
    parts = key.split("/")
    assert parts[0] == "@ros2_lv" and all(parts), key
    token = dict(domain=int(parts[1]), zid=parts[2], nid=parts[3], id=parts[4], kind=parts[5],
                 enclave=parts[6].replace("%", "/"), namespace=parts[7].replace("%", "/"), node=parts[8])
    if token["kind"] == "NN":
        assert len(parts) == 9, key
    else:
        assert len(parts) == 13, key
        token.update(topic=parts[9].replace("%", "/"), type=parts[10], hash=parts[11], qos=parts[12])
    return token


def state(position=True) -> State:
    return State(cycle=12, joints=[
        JointState(id=1, t=5.0, force=-2.5, tau=-0.26, theta=0.31, omega=1.5, goal_tick=2250,
                   present_tick=2240 if position else None, name="shoulder", wall=1.7e9 + 0.25,
                   position=0.296 if position else None),
        JointState(id=3, t=5.0, force=-2.5, tau=-0.26, theta=-0.1, omega=0.0, goal_tick=1980, name="joint3",
                   wall=1.7e9 + 0.25)])


@pytest.fixture
def sessions():
    import zenoh

    from admittance.daemon.zenoh_iface import make_config, open_session

    endpoint = free_endpoint()
    daemon = open_session(make_config(listen=[endpoint]), "daemon")
    ros = open_session(make_config(listen=[], connect=[endpoint]), "ros")
    yield daemon, ros, zenoh
    ros.close()
    daemon.close()


def test_a_ros2_graph_sees_the_node_and_its_publishers_and_decodes_the_samples(sessions):
    daemon, ros, zenoh = sessions
    cfg = SimpleNamespace(ros2=SimpleNamespace(domain_id=7, namespace="/bench1", node="admittance"),
                          sensor=SimpleNamespace(axis="y", frame_id="optoforce"))
    samples = ros.declare_subscriber("7/**", zenoh.handlers.FifoChannel(64))
    bridge = rmw_zenoh.Ros2Bridge(daemon, cfg)
    try:
        deadline = time.monotonic() + 10
        tokens = []
        while len(tokens) < 3 and time.monotonic() < deadline:
            tokens = [parse_token(str(r.ok.key_expr)) for r in ros.liveliness().get("@ros2_lv/7/**", timeout=1.0)
                      if r.ok is not None]
        kinds = sorted(t["kind"] for t in tokens)
        assert kinds == ["MP", "MP", "NN"]
        for t in tokens:
            assert (t["domain"], t["zid"], t["namespace"], t["node"]) == (7, str(daemon.info.zid()), "/bench1",
                                                                          "admittance")
        pubs = {t["topic"]: t for t in tokens if t["kind"] == "MP"}
        assert pubs["/bench1/joint_states"]["type"] == "sensor_msgs::msg::dds_::JointState_"
        assert pubs["/bench1/joint_states"]["hash"] == PUBLISHED_HASHES[messages.JOINT_STATE]
        assert pubs["/bench1/wrench"]["hash"] == PUBLISHED_HASHES[messages.WRENCH_STAMPED]
        assert pubs["/bench1/wrench"]["qos"] == "::,10:,:,:,,"  # reliable, volatile, keep last 10
        assert len({t["id"] for t in tokens if t["kind"] == "MP"}) == 2

        got = {}
        while len(got) < 2 and time.monotonic() < deadline:
            bridge.publish(state())
            time.sleep(0.05)
            while (sample := samples.try_recv()) is not None:
                got[str(sample.key_expr)] = sample
        joint_key = f"7/bench1/joint_states/sensor_msgs::msg::dds_::JointState_/{PUBLISHED_HASHES[messages.JOINT_STATE]}"
        wrench_key = f"7/bench1/wrench/geometry_msgs::msg::dds_::WrenchStamped_/{PUBLISHED_HASHES[messages.WRENCH_STAMPED]}"
        assert set(got) == {joint_key, wrench_key}

        js = TYPESTORE.deserialize_cdr(got[joint_key].payload.to_bytes(), messages.JOINT_STATE)
        assert list(js.name) == ["shoulder", "joint3"]
        assert list(js.position) == [0.296, -0.1]  # measured where read, else the model's angle
        assert list(js.velocity) == [1.5, 0.0] and list(js.effort) == [-0.26, -0.26]
        assert js.header.stamp.sec == 1_700_000_000 and abs(js.header.stamp.nanosec - 250_000_000) < 1000
        wrench = TYPESTORE.deserialize_cdr(got[wrench_key].payload.to_bytes(), messages.WRENCH_STAMPED)
        assert (wrench.wrench.force.x, wrench.wrench.force.y) == (0.0, -2.5)
        assert wrench.header.frame_id == "optoforce"

        from zenoh.ext import Int64, z_deserialize

        seq, stamp, gid = z_deserialize(tuple[Int64, Int64, bytes], got[joint_key].attachment)
        assert seq >= 1 and len(gid) == 16 and abs(stamp - time.time_ns()) < 60e9
    finally:
        bridge.close()
    deadline = time.monotonic() + 10  # undeclarations travel asynchronously
    while (left := [r for r in ros.liveliness().get("@ros2_lv/7/**", timeout=0.5) if r.ok is not None]):
        assert time.monotonic() < deadline, f"{len(left)} tokens left after close"
        time.sleep(0.05)


def test_names_map_to_keys_without_empty_chunks():
    assert rmw_zenoh.topic_keyexpr(0, "", "joint_states", messages.JOINT_STATE).startswith(
        "0/joint_states/sensor_msgs::msg::dds_::JointState_/RIHS01_")
    token = parse_token(rmw_zenoh.publisher_token(0, "abc", 1, "", "admittance", "wrench", messages.WRENCH_STAMPED))
    assert (token["namespace"], token["topic"], token["enclave"]) == ("/", "/wrench", "/")
    assert rmw_zenoh.gid_of("a") != rmw_zenoh.gid_of("b") and len(rmw_zenoh.gid_of("a")) == 16


@pytest.mark.parametrize("table, message", [
    ({"ros2": {"node": "9lives"}}, r"\[ros2\].node: '9lives' is not a ROS node name"),
    ({"ros2": {"namespace": "bench1"}}, r"\[ros2\].namespace: 'bench1' is not a ROS namespace"),
    ({"ros2": {"namespace": "/a//b"}}, r"\[ros2\].namespace"),
    ({"ros2": {"domain_id": 233}}, r"\[ros2\].domain_id: must be <= 232"),
    ({"joints": [{"id": 1, "model": "MX-64", "name": "j"}, {"id": 2, "model": "MX-64", "name": "j"}]},
     "two joints are called the same"),
])
def test_ros2_names_are_checked_at_load(tmp_path, table, message):
    import tomli_w

    from admittance.daemon import config
    from admittance.errors import ConfigError

    doc = {"bus": {"port": "/dev/ttyUSB0"}, "joints": [{"id": 1, "model": "MX-64"}],
           "sensor": {"kind": "optoforce", "port": "/dev/ttyACM0", "lever_arm": 0.1}, **table}
    path = tmp_path / "d.toml"
    path.write_text(tomli_w.dumps(doc))
    with pytest.raises(ConfigError, match=message):
        config.load_config(path)
    ok = {**doc, "ros2": {"enabled": True, "namespace": "/lab/bench_1", "node": "arm"}, "joints": doc["joints"][:1]}
    path.write_text(tomli_w.dumps(ok))
    cfg = config.load_config(path)
    assert cfg.ros2.namespace == "/lab/bench_1" and cfg.joints[0].name in ("joint1", "j")
