"""The supervisor's side of the fault policy (docs/faults.md): tell, mark, stop, and judge health.

The RT loop detects servo and bus faults and acts on them itself (``rtcore/rt/src/recovery.rs``:
hold, reboot, re-enable, reopen the port); when its policy gives up it raises a *stop request*.
The force sensor's reader reopens its device by itself and tells what happens through an event
hook. What is left to the supervisor, each tick, lives here:

- :class:`FaultWatch` compares the loop's statistics with the previous tick's and tells every
  new fault event and every recovery step in one line with its reason, each kind (per servo) at
  most once per ``EVENT_REPEAT_S`` with the count held back (the reader's own ``EventLog``);
- the sensor's events arrive on the reader's thread and are queued for the main thread, which
  logs them and marks the loop's cycles with ``sensor_lost`` / ``sensor_saturated``;
- a stop: the loop's request, or a sensor silent beyond ``[faults].sensor_lost_timeout_s``,
  becomes a :class:`~admittance.errors.FaultStop` carrying its exit status (:data:`EXIT_STATUS`);
- :meth:`FaultWatch.health` is what the systemd watchdog pings on: a loop that cycles but whose
  bus, servos or sensor are beyond what the policy allows is not healthy.
"""

from __future__ import annotations

import collections
import os
import time
from collections.abc import Callable
from typing import Any

from admittance.drivers.dynamixel import decode_hardware_error
from admittance.drivers.force_reader import EVENT_REPEAT_S, EventLog
from admittance.errors import EXIT_TEMPFAIL, EXIT_UNAVAILABLE, FaultStop

# What a restart may cure exits 75 (EX_TEMPFAIL: systemd restarts it); what needs a person at the
# servo exits 69 (EX_UNAVAILABLE: the unit's RestartPreventExitStatus keeps it down).
EXIT_STATUS = {
    "bus_lost": EXIT_TEMPFAIL,
    "servo_lost": EXIT_TEMPFAIL,
    "sensor_lost": EXIT_TEMPFAIL,
    "servo_error_policy": EXIT_UNAVAILABLE,
    "unsafe_hardware_error": EXIT_UNAVAILABLE,
    "repeated_overload": EXIT_UNAVAILABLE,
    "too_many_recoveries": EXIT_UNAVAILABLE,
    "torque_off_policy": EXIT_UNAVAILABLE,
    "error_persists": EXIT_UNAVAILABLE,
}
# A saturated sample marks the cycles for at least this long (the flag is set once per tick).
SATURATION_MARK_S = 0.2
# The servo counters of the loop's stats, and what an increase means (the line told).
SERVO_EVENTS = (
    ("errors", "shut down ({causes}); rebooting it, then torque on at its present position"),
    ("tolerated", "reports {causes} but kept its torque on; running on"),
    ("torque_offs", "found with its torque off (no error: a brown-out or another client); "
                    "torque on again at its present position"),
    ("silences", "does not answer; its joint holds"),
    ("recoveries", "recovered: torque on again, its model restarted at the horn's position"),
)


def causes(bits: int) -> str:
    return ", ".join(decode_hardware_error(bits)) or "no cause reported"


class FaultWatch:
    """Tells the faults of the loop and the sensor, marks the sensor's, and decides the stop.

    ``log(text)`` takes each line (the supervisor adds its prefix and records it); ``clock`` is
    monotonic seconds. Only the main thread calls it, except :meth:`sensor_event`, which the
    reader's thread calls and which only queues.
    """

    def __init__(self, cfg: Any, log: Callable[[str], None], clock: Callable[[], float] = time.monotonic) -> None:
        self.cfg = cfg
        self.policy = cfg.faults
        self.clock = clock
        self.events = EventLog(lambda _kind, text: log(text), EVENT_REPEAT_S, clock)
        self._sensor_queue: collections.deque[tuple[str, str]] = collections.deque(maxlen=1000)
        self._last: dict[str, Any] = {}
        self._saturated_until = 0.0
        self._sensor_seen = clock()
        self.stop: FaultStop | None = None
        self.unhealthy: str | None = None  # why the last health check failed

    # -- the sensor's events (the reader's thread) ----------------------------------------------

    def sensor_event(self, kind: str, message: str) -> None:
        """The reader's event hook: queued for the main thread (a deque append is thread-safe)."""
        self._sensor_queue.append((kind, message))

    # -- each tick (the main thread) --------------------------------------------------------------

    def poll(self, stats: dict[str, Any], sensor: dict[str, Any], loop: Any) -> FaultStop | None:
        """Tell what changed since the last tick, mark the sensor's faults on the loop, and
        return the stop to make (once), if any."""
        while self._sensor_queue:
            kind, message = self._sensor_queue.popleft()
            self.events(f"sensor.{kind}", f"sensor: {message}")
        self._tell_servos(stats.get("servos", []))
        self._tell_bus(stats.get("bus", {}))
        self._tell_kinds(stats.get("faults", {}))
        self._tell_passivity(stats.get("passivity", []))
        self._tell_compensation(stats.get("compensation_fallbacks", 0))
        loop.set_sensor_faults(self._sensor_faults(sensor))
        # update, not replace: _sensor_faults keeps the saturation count here too (replaced, every
        # later tick saw the old count as new and the mark never ended).
        self._last.update({"servos": stats.get("servos", []), "bus": stats.get("bus", {}), "faults": stats.get("faults", {}),
                           "passivity": stats.get("passivity", []),
                           "compensation_fallbacks": stats.get("compensation_fallbacks", 0)})
        if self.stop is None:
            self.stop = self._loop_stop(loop) or self._sensor_stop(sensor)
            return self.stop
        return None

    def _tell_servos(self, servos: list[dict[str, Any]]) -> None:
        before = {s["id"]: s for s in self._last.get("servos", [])}
        for servo in servos:
            old = before.get(servo["id"], {})
            for key, text in SERVO_EVENTS:
                if servo.get(key, 0) > old.get(key, 0):
                    # The last counted error's bits: a reboot faster than this tick has cleared hardware_error.
                    bits = servo["last_error"]
                    self.events(f"servo{servo['id']}.{key}", f"servo {servo['id']} " + text.format(causes=causes(bits)))

    def _tell_bus(self, bus: dict[str, Any]) -> None:
        old = self._last.get("bus", {})
        if bus.get("losses", 0) > old.get("losses", 0):
            errno = bus.get("loss_errno") or 0
            why = os.strerror(errno) if errno else "hung up"
            self.events("bus.lost", f"the Dynamixel bus {self.cfg.bus.port} failed ({why}); every joint holds while "
                                    f"it is reopened (for up to {self.policy.bus_lost_timeout_s:g} s)")
        if bus.get("reconnects", 0) > old.get("reconnects", 0):
            self.events("bus.back", f"the Dynamixel bus {self.cfg.bus.port} is back; checking every servo's torque")

    def _tell_kinds(self, faults: dict[str, int]) -> None:
        old = self._last.get("faults", {})
        if faults.get("model_state_invalid", 0) > old.get("model_state_invalid", 0):
            self.events("model_state_invalid", "fault: model_state_invalid (a model state or gain the loop cannot "
                                               "use); the joint holds at its last good state")
        if faults.get("position_glitch", 0) > old.get("position_glitch", 0):
            self.events("position_glitch", "fault: position_glitch (a servo's position read jumped farther than a "
                                           "horn can turn, or an anchoring read was not confirmed); the read is kept "
                                           "out of the model, the goal and the recording")

    def _tell_passivity(self, guards: list[dict[str, Any]]) -> None:
        """Once per episode of a joint's passivity guard (its ``episodes`` count grew): the joint
        generated energy beyond its margin and the guard adds damping until it is passive again."""
        before = {g["id"]: g for g in self._last.get("passivity", [])}
        margins = {j.id: j.passivity_margin for j in self.cfg.joints}
        for guard in guards:
            jid = guard["id"]
            if guard.get("episodes", 0) > before.get(jid, {}).get("episodes", 0):
                self.events(f"passivity{jid}", f"joint {jid}: passivity guard acting: the joint gave the hand "
                            f"{-guard.get('energy', 0.0):.3g} J more than the hand put in (margin "
                            f"{margins.get(jid, float('nan')):g} J, [joints] passivity_margin), an oscillation or a "
                            "virtual inertia too light for the hand; it adds damping (now "
                            f"{guard.get('damping', 0.0):.3g} N·m·s/rad) until the joint is passive again")

    def _tell_compensation(self, fallbacks: int) -> None:
        if fallbacks > self._last.get("compensation_fallbacks", 0):
            self.events("compensation_fallback", "servo compensation turned off: with it the horn strayed from the "
                                                 "model farther than the servo model says it would without it (a "
                                                 "model that does not fit this servo); blended out without a jump. "
                                                 "Identify the servo again (`admittance fidelity`), or set "
                                                 "servo_compensation to another value to try again")

    def _sensor_faults(self, sensor: dict[str, Any]) -> list[str]:
        now = self.clock()
        marks = []
        if sensor.get("state") == "reconnecting":
            marks.append("sensor_lost")
        saturated = sensor.get("events", {}).get("saturated", 0)
        if saturated > self._last.get("saturated", 0):
            self._saturated_until = now + SATURATION_MARK_S
        self._last["saturated"] = saturated
        if now < self._saturated_until:
            marks.append("sensor_saturated")
        return marks

    # -- the stop ---------------------------------------------------------------------------------

    def _loop_stop(self, loop: Any) -> FaultStop | None:
        request = loop.stop_request()
        if request is None:
            return None
        cause = request["cause"]
        return FaultStop(self._reason(cause, request), EXIT_STATUS.get(cause, EXIT_TEMPFAIL), cause)

    def _reason(self, cause: str, request: dict[str, Any]) -> str:
        p, servo = self.policy, f"servo {request.get('joint')}"
        bits = causes(request.get("hardware_error", 0))
        return {
            "bus_lost": f"the Dynamixel bus {self.cfg.bus.port} did not come back within "
                        f"{p.bus_lost_timeout_s:g} s ([faults].bus_lost_timeout_s)",
            "servo_lost": f"{servo} did not answer for {p.bus_lost_timeout_s:g} s ([faults].bus_lost_timeout_s)",
            "servo_error_policy": f"{servo} shut down ({bits}) and [faults].servo_error is \"stop\"",
            "unsafe_hardware_error": f"{servo} reports {bits}: a reboot would clear the error, not its cause; "
                                     "check the servo (temperature, wiring, encoder) before starting again",
            "repeated_overload": f"{servo} overloaded again within {p.recovery_window_s:g} s "
                                 "([faults].recovery_window_s): the load is beyond it",
            "too_many_recoveries": f"{servo} needed more than {p.max_recoveries} recoveries within "
                                   f"{p.recovery_window_s:g} s ([faults].max_recoveries)",
            "torque_off_policy": f"{servo} was found with its torque off and [faults].torque_off is \"stop\"",
            "error_persists": f"{servo} reports {bits}, which did not clear within {p.bus_lost_timeout_s:g} s "
                              "(Protocol 1.0 has no REBOOT: remove the cause)",
        }.get(cause, f"the loop stopped on a fault ({cause})")

    def _sensor_stop(self, sensor: dict[str, Any]) -> FaultStop | None:
        timeout = self.policy.sensor_lost_timeout_s
        silent = self.sensor_silent_s(sensor)
        if timeout <= 0 or silent < timeout:
            return None
        return FaultStop(f"the force sensor gave no usable sample for {silent:.1f} s "
                         f"([faults].sensor_lost_timeout_s = {timeout:g} s; last error: "
                         f"{sensor.get('last_error') or 'none'})", EXIT_STATUS["sensor_lost"], "sensor_lost")

    def sensor_silent_s(self, sensor: dict[str, Any]) -> float:
        """Seconds since the sensor's last sample reached the loop (since the watch began, before one)."""
        last_ns = sensor.get("last_sample_ns") or 0
        if last_ns:
            self._sensor_seen = max(self._sensor_seen, last_ns * 1e-9)
        return max(self.clock() - self._sensor_seen, 0.0)

    # -- the watchdog -----------------------------------------------------------------------------

    def health(self, stats: dict[str, Any], sensor: dict[str, Any], loop: Any) -> bool:
        """Healthy: no stop is due, the bus is up or lost for less than its timeout, no servo has
        been silent that long, and the sensor is fresh or silent within what the policy allows
        (holding forever when ``sensor_lost_timeout_s`` is 0). Why not, in ``unhealthy``."""
        p = self.policy
        bus = stats.get("bus", {})
        reasons = [
            (self.stop is not None or loop.stop_request() is not None, "a fault stop is due"),
            ((bus.get("lost_for_s") or 0.0) >= p.bus_lost_timeout_s, "the bus is lost"),
            (p.sensor_lost_timeout_s > 0 and self.sensor_silent_s(sensor) >= p.sensor_lost_timeout_s,
             "the sensor is lost"),
        ]
        self.unhealthy = next((why for bad, why in reasons if bad), None)
        return self.unhealthy is None
