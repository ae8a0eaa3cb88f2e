"""The RT loop's configuration (docs/realtime.md), built from a validated daemon config as the
typed object the Rust core takes (``admittance.loop_config.RtLoopConfig``).

The daemon's TOML speaks the user's language (a model name, a lever arm, limits in rad); the
loop wants register addresses and tick ranges. The addresses come from the one model table
(``_rtcore.model_table()``, read through ``admittance.drivers.control_table``), so an address
is never typed twice. The tick range is position mode's single turn (0..4095); the position
limits lie within what that range reaches from the joint's zero tick (config.py checks them).
"""

from __future__ import annotations

from typing import Any

import msgspec

from admittance.daemon.config import GOAL_TICKS, TICKS_PER_REV, DaemonConfig, JointConfig
from admittance.errors import ConfigError
from admittance.loop_config import RtFaultPolicy, RtJoint, RtLimits, RtLoopConfig, RtServo

GOAL_ITEM, PRESENT_ITEM, TORQUE_ITEM = "Goal Position", "Present Position", "Torque Enable"
# The loop's first read of the present positions. The servos answered the setup checks a
# moment before, so only a busy host or a simulated bus in another process (a pty) is slow
# here; the loop's 200 ms default is tight for those, and a start is not time-critical.
START_TIMEOUT_MS = 2000.0


def rt_loop_config(cfg: DaemonConfig, bus_port: str) -> RtLoopConfig:
    """What ``_rtcore.AdmittanceLoop`` takes (backends.make_loop)."""
    s, lp = cfg.sensor, cfg.loop
    return RtLoopConfig(
        port=bus_port,
        baudrate=cfg.bus.baudrate,
        protocol=cfg.bus.protocol,
        bus_read=cfg.bus.read,
        rate_hz=lp.rate_hz,
        rt_priority=lp.rt_priority,
        lock_memory=lp.lock_memory,
        sync_read_divisor=lp.sync_read_divisor,
        start_timeout_ms=START_TIMEOUT_MS,
        deadband=s.deadband,
        lowpass_hz=s.lowpass_hz,
        stale_timeout_ms=lp.stale_timeout_ms,
        ramp_time_s=lp.ramp_time_s,
        trigger=lp.trigger,
        phase_lock=lp.phase_lock,
        bias=tuple(float(b) for b in s.bias),
        joints=tuple(joint_entry(j, cfg.bus.protocol, s.axis) for j in cfg.joints),
        faults=fault_policy(cfg),
    )


def loop_config(cfg: DaemonConfig, bus_port: str) -> dict[str, Any]:
    """The same as the plain keys the core reads from it (its unset fields left out)."""
    built: dict[str, Any] = msgspec.to_builtins(rt_loop_config(cfg, bus_port))
    return built


def fault_policy(cfg: DaemonConfig) -> RtFaultPolicy:
    """The loop's part of [faults] (the sensor's timeout is the supervisor's)."""
    f = cfg.faults
    return RtFaultPolicy(servo_error=f.servo_error, torque_off=f.torque_off, bus_lost_timeout_s=f.bus_lost_timeout_s,
                         servo_silent_ms=f.servo_silent_ms, max_recoveries=f.max_recoveries,
                         recovery_window_s=f.recovery_window_s, check_period_ms=f.check_period_ms,
                         horn_speed_max=f.horn_speed_max)


def joint_entry(joint: JointConfig, protocol: int, axis: str) -> RtJoint:
    from admittance.drivers.control_table import table_for_name

    table = table_for_name(joint.model, protocol)
    goal, present, torque = (table.item(name) for name in (GOAL_ITEM, PRESENT_ITEM, TORQUE_ITEM))
    # Position mode (set up by the servo checks): one turn, whatever wider range the Goal
    # Position item allows in the extended or multi-turn modes.
    tick_min, tick_max = GOAL_TICKS
    if not tick_min <= joint.zero_tick <= tick_max:
        raise ConfigError(f"[joints.{joint.id}].zero_tick: {joint.zero_tick} is outside the {joint.model}'s "
                          f"goal range {tick_min}..{tick_max}")
    limits, plant = joint.resolved_limits, joint.plant
    if limits is None or plant is None:  # a JointConfig not through config.resolve
        raise ConfigError(f"[joints.{joint.id}]: its limits and parameter file are not resolved")
    servo = plant.get("servo")  # validated by formats.paramfile: the five names, finite
    return RtJoint(
        id=joint.id,
        model=table.name,
        goal_address=goal.address, goal_size=goal.size,
        present_address=present.address, present_size=present.size,
        torque_enable_address=torque.address,
        zero_tick=joint.zero_tick, direction=joint.direction, ticks_per_rev=float(TICKS_PER_REV),
        tick_min=tick_min, tick_max=tick_max,
        axis=axis,
        virtual_inertia=_resolved(joint, "virtual_inertia"),
        virtual_damping=_resolved(joint, "virtual_damping"),
        virtual_coulomb=_resolved(joint, "virtual_coulomb"),
        lever_arm=_resolved(joint, "lever_arm"),
        servo=None if servo is None else RtServo(**servo),
        servo_compensation=_resolved(joint, "servo_compensation"),
        passivity_guard=joint.passivity_guard,
        passivity_margin=joint.passivity_margin,
        passivity_damping_max=joint.passivity_damping_max,
        limits=RtLimits(
            # Within what the tick range reaches: the configuration checked (or clipped) them.
            position_min=_resolved(limits, "position_min", joint.id),
            position_max=_resolved(limits, "position_max", joint.id),
            velocity_max=limits.velocity_max,
            acceleration_max=limits.acceleration_max,
        ),
    )


def _resolved(table: object, name: str, joint_id: int | None = None) -> float:
    """A value config.resolve fills (None until then: the plant's or the reach's default)."""
    value = getattr(table, name)
    if value is None:
        raise ConfigError(f"[joints.{getattr(table, 'id', joint_id)}].{name} is not resolved")
    return float(value)
