"""The daemon's optional outputs for the robotics ecosystem, fed from the supervisor's tick.

- ``session.mcap`` beside a ``--record`` dataset (:mod:`mcap_recording`): every cycle, params,
  stats, events; and the same cycles as a rosbag2 bag in ``rosbag2/`` (:mod:`admittance.ros2.bag`);
- the ROS 2 bridge (``[ros2]``, :mod:`admittance.ros2.rmw_zenoh`) on the daemon's Zenoh session;
- the Foxglove live view (``[foxglove]``, :mod:`foxglove_view`).

All of them run on the supervisor's thread, after the RT loop's telemetry was drained: none of
them is on the RT path, and a slow one only delays the next tick. The supervisor holds one
:class:`Ecosystem` and calls it without knowing which outputs are on, so its own code stays the
sequence of docs/daemon.md. An output that fails while running (a closed socket, a full disk)
is reported once as a warning and switched off; it never stops the loop.
"""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Any

from admittance.daemon import telemetry
from admittance.formats.mcap_layout import MCAP_NAME

BAG_FOLDER = "rosbag2"


class Ecosystem:
    def __init__(self) -> None:
        self.mcap: Any = None
        self.bag: Any = None  # admittance.ros2.bag.Ros2Bag
        self.views: list[Any] = []  # objects with publish(state) and close()
        self._failed: list[str] = []
        # CLOCK_REALTIME − CLOCK_MONOTONIC, measured at the first drain and kept for the session:
        # a cycle's wall stamp is its monotonic t plus this, so stamps keep the cycles' order. A
        # fresh measurement per drain moved by its jitter (µs, ms when preempted between the
        # clock reads) and stamped a repeated cycle (same t) at the start of one drain before
        # its predecessor at the end of the last; a ROS 2 reader orders the bag by stamp.
        self.wall_offset_ns: int | None = None

    def start_mcap(self, stack: contextlib.ExitStack, folder: Path, cfg: Any, t0: float,
                   params: dict[str, Any], joint_info: dict[int, dict] | None = None) -> None:
        """``joint_info``: per joint id, what the CSV manifest's [[joints]] carries (plant, servo
        model, loop timing), so `admittance fidelity` can judge the MCAP alone."""
        from admittance.daemon.mcap_recording import McapRecorder

        info = joint_info or {}
        session = {"joints": [{**info.get(j.id, {}), "id": j.id, "name": telemetry.joint_name(j), "model": j.model}
                              for j in cfg.joints],
                   "t0": t0, "segment_s": cfg.record.segment_s, "measured_theta": cfg.loop.sync_read_divisor > 0,
                   "rate_hz": cfg.loop.rate_hz, "prefix": cfg.zenoh.prefix}
        self.mcap = McapRecorder(folder / MCAP_NAME, session)
        stack.callback(self._close_mcap)
        self._start_bag(stack, folder, cfg)
        self.record("params", params)

    def _start_bag(self, stack: contextlib.ExitStack, folder: Path, cfg: Any) -> None:
        from admittance.ros2.bag import Ros2Bag
        from admittance.ros2.rmw_zenoh import AXIS_INDEX

        names = {j.id: telemetry.joint_name(j) for j in cfg.joints}
        sensor = getattr(cfg, "sensor", None)
        frame = str(getattr(sensor, "frame_id", "") or "force_sensor")
        self.bag = Ros2Bag(folder / BAG_FOLDER, names, frame, AXIS_INDEX.get(getattr(sensor, "axis", "x"), 0))
        stack.callback(self._close_bag)

    def start_views(self, stack: contextlib.ExitStack, cfg: Any, interface: Any) -> None:
        """The ROS 2 bridge declares on the Zenoh interface's own session (once it is open: a
        client whose router is down gets it later, zenoh_iface.RouterLink)."""
        if cfg.ros2.enabled:
            from admittance.ros2.rmw_zenoh import Ros2Bridge

            interface.when_connected(lambda session: self._add_view(stack, Ros2Bridge(session, cfg)))
        if cfg.foxglove.enabled:
            from admittance.daemon.foxglove_view import FoxgloveView

            self._add_view(stack, FoxgloveView(cfg))

    def _add_view(self, stack: contextlib.ExitStack, view: Any) -> None:
        self.views.append(view)
        stack.callback(view.close)

    def record_cycles(self, by_joint: dict[int, dict[str, Any]]) -> None:
        if self.mcap is None:
            return
        if self.wall_offset_ns is None:
            self.wall_offset_ns = telemetry.wall_offset_ns()
        offset = self.wall_offset_ns

        def write() -> None:
            for joint_id, columns in by_joint.items():
                self.mcap.append(joint_id, columns, offset)
            self.mcap.flush()

        self._guard("session.mcap", write)
        if self.bag is not None:
            self._guard("rosbag2", lambda: (self.bag.append(by_joint, offset), self.bag.flush()))

    def record(self, kind: str, value: Any, request: dict | None = None) -> None:
        """A params snapshot ("params"), a stats object ("stats") or a line of text ("event")."""
        if self.mcap is None:
            return

        def write() -> None:
            if kind == "params":
                self.mcap.params("set" if request else "start", value, request)
            elif kind == "stats":
                self.mcap.stats(value)
            else:
                self.mcap.event(value)
            self.mcap.flush()

        self._guard("session.mcap", write)

    def publish(self, state: Any) -> list[str]:
        """Hand the newest state to every view; returns warnings to log (each failure once)."""
        if state is not None:
            for view in list(self.views):
                self._guard(type(view).__name__, lambda v=view: v.publish(state), view)
        failed, self._failed = self._failed, []
        return failed

    def _guard(self, what: str, action: Any, view: Any = None) -> None:
        try:
            action()
        except Exception as exc:  # an optional output must never stop the loop
            self._failed.append(f"{what} stopped: {type(exc).__name__}: {exc}")
            if view is not None:
                self.views.remove(view)
            elif what in ("session.mcap", "rosbag2"):
                failed = self.mcap if what == "session.mcap" else self.bag
                if what == "session.mcap":
                    self.mcap = None
                else:
                    self.bag = None
                with contextlib.suppress(Exception):
                    failed.close()  # the summary if it still fits; the file closed either way

    def _close_mcap(self) -> None:
        if self.mcap is not None:
            self.mcap.close()

    def _close_bag(self) -> None:
        if self.bag is not None:
            self.bag.close()
