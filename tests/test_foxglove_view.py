"""The Foxglove live view, seen by a WebSocket client speaking Foxglove's protocol: it advertises
one channel per joint and streams force, torque, model/goal/present angles and the rendering error."""

from __future__ import annotations

import json
import math
import struct
import time
from types import SimpleNamespace

import pytest

from admittance.daemon.messages import JointState, State

pytest.importorskip("foxglove")
ws_client = pytest.importorskip("websockets.sync.client")

from admittance.daemon.foxglove_view import FoxgloveView  # noqa: E402


@pytest.mark.parametrize("offered, agreed", [
    (["foxglove.sdk.v1"], "foxglove.sdk.v1"),  # Foxglove's apps
    (["foxglove.websocket.v1"], "foxglove.websocket.v1"),  # the open-source compatible viewers
    (["foxglove.sdk.v1", "foxglove.websocket.v1"], "foxglove.sdk.v1"),
])
def test_a_foxglove_client_sees_every_quantity_of_the_joint(offered, agreed):
    joint = SimpleNamespace(id=1, zero_tick=2048, direction=1)
    view = FoxgloveView(SimpleNamespace(joints=[joint], foxglove=SimpleNamespace(host="127.0.0.1", port=0,
                                                                                rate_hz=1000.0)))
    state = State(cycle=5, joints=[JointState(id=1, t=2.0, force=3.0, tau=0.315, theta=0.40, omega=0.1,
                                              goal_tick=2048 + 261, present_tick=2300, name="joint1",
                                              wall=1.7e9, position=0.38)])
    try:
        with ws_client.connect(f"ws://127.0.0.1:{view.port}",
                               subprotocols=offered, open_timeout=10) as ws:
            assert ws.subprotocol == agreed
            channels = {}
            while not channels:
                message = json.loads(ws.recv(timeout=10))
                if message["op"] == "advertise":
                    channels = {c["topic"]: c for c in message["channels"]}
            assert list(channels) == ["/admittance/joint1"] and channels["/admittance/joint1"]["encoding"] == "json"
            assert channels["/admittance/joint1"]["schemaName"] == "admittance.JointState"
            schema = json.loads(channels["/admittance/joint1"]["schema"])
            units = {name: prop["unit"] for name, prop in schema["properties"].items()}
            assert units["force"] == "N" and units["tau"] == "N·m" and units["omega_model"] == "rad/s"
            assert all(f"[{unit}]" in schema["properties"][name]["description"] for name, unit in units.items())
            ws.send(json.dumps({"op": "subscribe",
                                "subscriptions": [{"id": 7, "channelId": channels["/admittance/joint1"]["id"]}]}))
            deadline = time.monotonic() + 10
            while True:
                view.publish(state)
                try:
                    frame = ws.recv(timeout=0.2)
                except TimeoutError:  # the subscription may not be in place yet: publish again
                    assert time.monotonic() < deadline, "no message arrived"
                    continue
                if isinstance(frame, bytes) and frame[0] == 1:
                    break
        subscription, log_time = struct.unpack_from("<IQ", frame, 1)
        data = json.loads(frame[13:])
        assert subscription == 7 and log_time == round(1.7e9 * 1e9)
        assert (data["force"], data["tau"], data["theta_model"], data["theta_present"]) == (3.0, 0.315, 0.40, 0.38)
        assert math.isclose(data["rendering_error"], -0.02, abs_tol=1e-12)
        assert math.isclose(data["theta_goal"], 261 * 2 * math.pi / 4096)
    finally:
        view.close()


def test_a_client_that_never_finishes_its_handshake_costs_only_its_own_connection():
    import socket

    joint = SimpleNamespace(id=1, zero_tick=2048, direction=1)
    view = FoxgloveView(SimpleNamespace(joints=[joint], foxglove=SimpleNamespace(host="127.0.0.1", port=0,
                                                                                rate_hz=1000.0)))
    try:
        with socket.create_connection(("127.0.0.1", view.port), timeout=10) as bad:
            bad.sendall(b"GET / HTTP/1.1\r\n" + b"X: " + b"a" * 70000)  # no end of header, past the bound
            assert bad.recv(10) == b""  # dropped
        with ws_client.connect(f"ws://127.0.0.1:{view.port}", subprotocols=["foxglove.websocket.v1"],
                               open_timeout=10) as ws:
            assert ws.subprotocol == "foxglove.websocket.v1"
    finally:
        view.close()


def test_the_shipped_layouts_are_the_generated_ones():
    from admittance import data
    from admittance.daemon.foxglove_layout import LAYOUTS, layout

    for name, (topic, recording) in LAYOUTS.items():
        shipped = data.path("foxglove", name).read_text()
        assert shipped == layout(topic, recording) + "\n", f"regenerate admittance/data/foxglove/{name}"
        assert f'"{topic}.rendering_error"' in shipped and ('"/params"' in shipped) == recording
