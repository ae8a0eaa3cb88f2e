"""The RT loop's configuration as the Rust core reads it (``_rtcore.AdmittanceLoop(config)``,
rtcore/py/src/rt.rs): its typed shape.

The configuration crosses the boundary as a dict (pyo3 reads it key by key and names an unknown
or mistyped key); these ``TypedDict``s are that dict's type, so mypy holds every builder
(``admittance.daemon.loopconfig``, the benches) to the keys and value types the Rust side reads.
A key left out takes the loop's default (``rt::config``; the ones the daemon's configuration
shares are ``_rtcore.LOOP_DEFAULTS``). The stub ``admittance/_rtcore.pyi`` uses them, and
tests/test_rtcore_stub.py checks both against the built module.
"""

from __future__ import annotations

from typing import NotRequired, TypedDict


class LimitsDict(TypedDict, total=False):
    position_min: float  # rad
    position_max: float  # rad
    velocity_max: float  # rad/s
    acceleration_max: float  # rad/s²


class ServoDict(TypedDict):
    time_constant: float  # s
    inertial_time: float  # s
    dead_time: float  # s
    compliance: float  # rad/(N·m)
    deadband: float  # rad
    backlash: NotRequired[float]  # rad (absent: 0)
    backlash_torque: NotRequired[float]  # N·m (absent: 0)


class JointDict(TypedDict, total=False):
    id: int  # required
    model: str
    goal_address: int
    goal_size: int
    present_address: int
    present_size: int
    torque_enable_address: int
    zero_tick: int
    direction: int  # +1 or -1
    ticks_per_rev: float
    tick_min: int
    tick_max: int
    virtual_inertia: float  # kg·m²
    virtual_damping: float  # N·m·s/rad
    virtual_coulomb: float  # N·m
    axis: str  # "x".."tz"
    lever_arm: float  # m
    limits: LimitsDict
    servo: ServoDict | dict | None
    servo_compensation: float  # 0..1
    passivity_guard: float  # 0 or 1: the passivity guard (docs/fidelity.md)
    passivity_margin: float  # J
    passivity_damping_max: float  # N·m·s/rad


class FaultPolicyDict(TypedDict, total=False):
    servo_error: str  # "reboot" or "stop"
    torque_off: str  # "reenable" or "stop"
    bus_lost_timeout_s: float
    servo_silent_ms: float
    max_recoveries: int
    recovery_window_s: float
    check_period_ms: float
    horn_speed_max: float  # rad/s


class LoopConfigDict(TypedDict):
    port: str  # the Dynamixel bus device (required)
    joints: list[JointDict]
    baudrate: NotRequired[int]
    protocol: NotRequired[int]  # 1 or 2
    bus_read: NotRequired[str]  # "auto", "fast" or "sync": how the present positions are read
    rate_hz: NotRequired[float]
    rt_policy: NotRequired[str]  # "fifo" or "other"
    rt_priority: NotRequired[int]
    lock_memory: NotRequired[bool]
    cpu: NotRequired[int | None]
    sync_read_divisor: NotRequired[int]
    stale_timeout_ms: NotRequired[float]
    deadband: NotRequired[float]  # N
    lowpass_hz: NotRequired[float]
    ramp_time_s: NotRequired[float]
    bias: NotRequired[list[float]]  # six values
    force_capacity: NotRequired[int]
    telemetry_capacity: NotRequired[int]
    start_timeout_ms: NotRequired[float]
    torque_on_start: NotRequired[bool]
    trigger: NotRequired[str]  # "sample" or "schedule"
    phase_lock: NotRequired[bool]
    faults: NotRequired[FaultPolicyDict]
