"""A live view in Foxglove: a WebSocket server (foxglove-sdk) fed from the supervisor's tick.

Off by default (``[foxglove].enabled``), bound to loopback unless told otherwise, and never on
the RT path: the supervisor hands it the newest state once per tick, and it forwards at most
``[foxglove].rate_hz`` messages per second per joint. Open Foxglove, "Open connection",
``ws://<host>:<port>``; docs/foxglove.md lists the panels.

One JSON channel per joint, ``/admittance/joint<ID>``: ``force`` (N), ``tau`` (N·m),
``theta_model``, ``theta_goal``, ``theta_present`` (rad; the last read), ``rendering_error``
(theta_present − theta_model, rad), ``omega_model`` (rad/s), ``t`` (s, CLOCK_MONOTONIC).
The present angle is the last one read, up to ``sync_read_divisor`` cycles older than the model
angle beside it; ``session.mcap`` has the exact per-cycle error.
"""

from __future__ import annotations

import time
from typing import Any

from admittance.daemon.telemetry import tick_to_rad
from admittance.errors import ConfigError

NUMBER = {"type": "number"}
JOINT_SCHEMA = {
    "type": "object",
    "properties": {name: NUMBER for name in ("t", "force", "tau", "theta_model", "theta_goal", "theta_present",
                                             "rendering_error", "omega_model")},
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
        try:
            self._server = foxglove.start_server(name="admittance", host=f.host, port=f.port, context=self._context)
        except Exception as exc:  # the SDK raises its own error type for a busy port or a bad address
            raise ConfigError(f"[foxglove]: cannot serve on {f.host}:{f.port} ({exc})") from None
        self._channels = {jid: foxglove.Channel(f"/admittance/joint{jid}", schema=JOINT_SCHEMA,
                                                context=self._context) for jid in self._joints}
        self._period_ns = int(1e9 / f.rate_hz)
        self._next_ns = 0
        self.published = 0

    @property
    def port(self) -> int:
        return self._server.port

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
        self._server.stop()
