"""A live view in Foxglove: a WebSocket server (foxglove-sdk) fed from the supervisor's tick.

Off by default (``[foxglove].enabled``), bound to loopback unless told otherwise, and never on
the RT path: the supervisor hands it the newest state once per tick, and it forwards at most
``[foxglove].rate_hz`` messages per second per joint. Open Foxglove, "Open connection",
``ws://<host>:<port>``; docs/foxglove.md lists the panels.

One JSON channel per joint, ``/admittance/joint<ID>``, schema ``admittance.JointState`` (its
JSON Schema gives each field's unit in ``description``): ``force`` (N), ``tau`` (N·m),
``theta_model``, ``theta_goal``, ``theta_present`` (rad; the last read), ``rendering_error``
(theta_present − theta_model, rad), ``omega_model`` (rad/s), ``t`` (s, CLOCK_MONOTONIC).

Clients may speak either subprotocol name of the Foxglove WebSocket protocol,
``foxglove.sdk.v1`` (Foxglove's apps) or ``foxglove.websocket.v1`` (the open-source compatible
viewers): the configured port is a :class:`SubprotocolBridge` in front of the SDK's server,
which itself listens on a loopback port of its own.
The present angle is the last one read, up to ``sync_read_divisor`` cycles older than the model
angle beside it; ``session.mcap`` has the exact per-cycle error.
"""

from __future__ import annotations

import time
from typing import Any

from admittance.daemon.telemetry import tick_to_rad
from admittance.errors import ConfigError

FIELDS = {  # name: (unit, what it is)
    "t": ("s", "the cycle's time, CLOCK_MONOTONIC"),
    "force": ("N", "the conditioned force along the sensor's axis"),
    "tau": ("N·m", "the torque the model integrated"),
    "theta_model": ("rad", "the admittance model's angle"),
    "theta_goal": ("rad", "the goal sent to the servo"),
    "theta_present": ("rad", "the servo's last measured angle"),
    "rendering_error": ("rad", "theta_present − theta_model"),
    "omega_model": ("rad/s", "the admittance model's speed"),
}
JOINT_SCHEMA = {
    "title": "admittance.JointState",
    "type": "object",
    "properties": {name: {"type": ["number", "null"] if name in ("theta_present", "rendering_error") else "number",
                          "description": f"{what} [{unit}]", "unit": unit}
                   for name, (unit, what) in FIELDS.items()},
}


class FoxgloveView:
    def __init__(self, cfg: Any) -> None:
        try:
            import foxglove
        except ImportError:
            raise ConfigError("[foxglove].enabled needs the foxglove-sdk package "
                              "(pip install 'admittance[ecosystem]')") from None
        f = cfg.foxglove
        self._joints = {j.id: j for j in cfg.joints}
        self._context = foxglove.Context()
        from admittance.daemon.foxglove_subprotocol import SubprotocolBridge

        try:
            self._server = foxglove.start_server(name="admittance", host="127.0.0.1", port=0, context=self._context)
        except Exception as exc:  # the SDK raises its own error type for a busy port or a bad address
            raise ConfigError(f"[foxglove]: cannot start the Foxglove server ({exc})") from None
        try:
            self._bridge = SubprotocolBridge(f.host, f.port, self._server.port)
        except OSError as exc:
            self._server.stop()
            raise ConfigError(f"[foxglove]: cannot serve on {f.host}:{f.port} ({exc.strerror or exc})") from None
        self._channels = {jid: foxglove.Channel(f"/admittance/joint{jid}", schema=JOINT_SCHEMA,
                                                context=self._context) for jid in self._joints}
        self._period_ns = int(1e9 / f.rate_hz)
        self._next_ns = 0
        self.published = 0

    @property
    def port(self) -> int:
        return self._bridge.port

    def publish(self, state: Any) -> None:
        now = time.time_ns()
        if now < self._next_ns:
            return
        self._next_ns = now + self._period_ns
        for j in state.joints:
            joint = self._joints.get(j.id)
            if joint is None:
                continue
            present = j.position
            self._channels[j.id].log({
                "t": j.t, "force": j.force, "tau": j.tau, "theta_model": j.theta,
                "theta_goal": float(tick_to_rad(j.goal_tick, joint)), "omega_model": j.omega,
                "theta_present": present, "rendering_error": None if present is None else present - j.theta,
            }, log_time=round(j.wall * 1e9) if j.wall is not None else now)
        self.published += 1

    def close(self) -> None:
        for channel in self._channels.values():
            channel.close()
        self._bridge.close()
        self._server.stop()
