"""A ``--record`` session as a rosbag2 bag (``DIR/rosbag2``): the ros2 MCAP profile, CDR
JointState and WrenchStamped, read by the ``rosbags`` library's rosbag2 reader (never by our
code), beside a session.mcap that the project's own readers (identify, fidelity) still read."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

from admittance.ros2.bag import Ros2Bag

from test_mcap_recording import batch

rosbag2 = pytest.importorskip("rosbags.rosbag2")
typesys = pytest.importorskip("rosbags.typesys")

WALL_OFFSET_NS = 1_700_000_000_000_000_000


def read_bag(folder):
    """topic -> [(log time, message)] as rosbags deserializes them, with the schemas the bag carries."""
    store = typesys.get_typestore(typesys.Stores.EMPTY)
    out: dict[str, list] = {}
    with rosbag2.Reader(folder) as reader:
        for conn in reader.connections:
            store.register(typesys.get_types_from_msg(conn.msgdef.data, conn.msgtype))
        types = {c.topic: c.msgtype for c in reader.connections}
        for conn, stamp, raw in reader.messages():
            out.setdefault(conn.topic, []).append((stamp, store.deserialize_cdr(raw, conn.msgtype)))
    return types, out


def test_the_bag_holds_every_cycle_as_ros2_messages(tmp_path):
    bag = Ros2Bag(tmp_path / "rosbag2", {1: "shoulder"}, "ft_frame", force_axis=2)
    batches = [batch(100.0 + k * 0.05, 50, read_every=5) for k in range(4)]
    for cols in batches:
        bag.append({1: cols, 3: cols}, WALL_OFFSET_NS)  # joint 3 shares the cycles: one message for both
    bag.close()
    types, topics = read_bag(tmp_path / "rosbag2")
    assert types == {"/joint_states": "sensor_msgs/msg/JointState", "/wrench": "geometry_msgs/msg/WrenchStamped"}
    assert len(topics["/joint_states"]) == len(topics["/wrench"]) == 200
    cols = {k: np.concatenate([b[k] for b in batches]) for k in batches[0]}
    stamps = np.array([s for s, _ in topics["/joint_states"]])
    assert np.array_equal(stamps, np.rint(cols["t"] * 1e9).astype(np.int64) + WALL_OFFSET_NS)
    messages = [m for _, m in topics["/joint_states"]]
    assert list(messages[0].name) == ["shoulder", "joint3"]
    expected = np.where(np.isnan(cols["theta_present"]), cols["theta_model"], cols["theta_present"])
    assert np.allclose([m.position[0] for m in messages], expected)
    assert np.allclose([m.velocity[1] for m in messages], cols["omega_model"])
    assert np.allclose([m.effort[0] for m in messages], cols["tau"])
    assert [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in messages] == stamps.tolist()
    wrench = [m for _, m in topics["/wrench"]]
    assert wrench[0].header.frame_id == "ft_frame"
    assert np.allclose([w.wrench.force.z for w in wrench], cols["force"])
    assert all(w.wrench.force.x == 0.0 and w.wrench.torque.z == 0.0 for w in wrench)


def test_joints_on_different_cycles_get_messages_of_their_own(tmp_path):
    bag = Ros2Bag(tmp_path / "rosbag2", {}, "f", force_axis=0)
    bag.append({1: batch(100.0, 20, 1), 2: batch(100.5, 20, 1)}, WALL_OFFSET_NS)
    bag.close()
    _, topics = read_bag(tmp_path / "rosbag2")
    assert [list(m.name) for _, m in topics["/joint_states"]] == [["joint1"]] * 20 + [["joint2"]] * 20


def test_a_recorded_daemon_session_is_a_bag_and_still_our_recording(tmp_path):
    from admittance.formats.recording import read_recording

    from daemon_process import ADMITTANCE
    from test_hil_daemon import daemon_config

    config, _ = daemon_config(tmp_path, loop={"sync_read_divisor": 5},
                              bench={"profile": "sine:amplitude=0.15,frequency=0.5", "hand_delay_s": 0.2})
    proc = subprocess.run([str(ADMITTANCE), "run", "--config", str(config), "--duration", "2",
                           "--record", str(tmp_path / "rec")], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    types, topics = read_bag(tmp_path / "rec" / "rosbag2")
    ours = read_recording(tmp_path / "rec")  # the JSON session.mcap, untouched by the bag
    cycles = ours.joints[1]["cycle"]
    assert len(topics["/joint_states"]) == len(cycles) > 1000
    assert np.allclose([m.velocity[0] for _, m in topics["/joint_states"]], ours.joints[1]["omega_model"])
    assert np.allclose([m.wrench.force.x for _, m in topics["/wrench"]], ours.joints[1]["force"])
    with open(tmp_path / "rec" / "session.mcap", "rb") as fh:  # ours keeps its JSON channels and profile
        from mcap.reader import make_reader

        assert make_reader(fh).get_header().profile == ""


def test_a_bag_that_fails_stops_alone(tmp_path):
    """A full disk under the bag: one warning, the bag off, session.mcap still written."""
    from types import SimpleNamespace

    from admittance.daemon.ecosystem import Ecosystem

    class FullDisk:
        closed = False

        def append(self, *_):
            raise OSError(28, "No space left on device")

        def close(self):
            self.closed = True

    written = []
    eco = Ecosystem()
    eco.mcap = SimpleNamespace(append=lambda jid, cols, off: written.append(jid), flush=lambda: None)
    eco.bag = bag = FullDisk()
    eco.record_cycles({1: batch(100.0, 5, 1)})
    eco.record_cycles({1: batch(100.005, 5, 1)})
    assert eco.bag is None and bag.closed and eco.mcap is not None and written == [1, 1]
    assert [w for w in eco.publish(None) if "rosbag2" in w] == ["rosbag2 stopped: OSError: [Errno 28] No space left on device"]


def test_a_cycle_repeated_across_two_drains_keeps_its_place_in_the_bag(tmp_path, monkeypatch):
    """A cycle that took no step repeats its predecessor's ``t`` (docs/daemon.md). When the two
    fall in different drains (a backlog is drained in chunks), a wall offset measured afresh per
    drain, one microsecond smaller the second time (clock-read jitter; a preemption between the
    two clock reads makes it milliseconds), stamped the repeat before its predecessor, and a
    ROS 2 reader, which orders by stamp, gave them in the wrong order: the same velocity (the
    repeated state), another cycle's force (CI, under load)."""
    from types import SimpleNamespace

    from admittance.daemon import telemetry
    from admittance.daemon.ecosystem import Ecosystem

    offsets = iter([WALL_OFFSET_NS, WALL_OFFSET_NS - 1_000] * 4)
    monkeypatch.setattr(telemetry, "wall_offset_ns", lambda: next(offsets))
    first, second = batch(100.0, 50, 1), batch(100.05, 50, 1)
    second["t"][0] = first["t"][-1]  # the second drain opens with a cycle that took no step
    second["omega_model"][0] = first["omega_model"][-1]
    eco = Ecosystem()
    eco.mcap = SimpleNamespace(append=lambda *_: None, flush=lambda: None)
    eco.bag = bag = Ros2Bag(tmp_path / "rosbag2", {1: "joint1"}, "f", force_axis=0)
    eco.record_cycles({1: first})
    eco.record_cycles({1: second})
    bag.close()
    _, topics = read_bag(tmp_path / "rosbag2")
    forces = np.concatenate([first["force"], second["force"]])
    assert [m.wrench.force.x for _, m in topics["/wrench"]] == forces.tolist()
    stamps = [s for s, _ in topics["/joint_states"]]
    assert stamps == sorted(stamps) and stamps[50] == stamps[49]  # the repeat ties, in the file's order


def test_the_wall_offset_is_read_where_the_two_clocks_were_read_closest_together(monkeypatch):
    """A thread preempted between its clock reads (5 ms here, as on CI) would put the whole
    session's wall stamps off by that much: of a few tries, the narrowest bracket counts."""
    from types import SimpleNamespace

    from admittance.daemon import telemetry

    offset = 1_700_000_000_000_000_000
    reads = iter([0, offset + 5_000_000, 5_000_100,  # preempted after the monotonic read
                  *[x for k in range(1, 5) for x in (k * 10**7, k * 10**7 + offset + 40, k * 10**7 + 80)]])
    clock = SimpleNamespace(monotonic_ns=lambda: next(reads), time_ns=lambda: next(reads))
    monkeypatch.setattr(telemetry, "time", clock)
    assert telemetry.wall_offset_ns() == offset
