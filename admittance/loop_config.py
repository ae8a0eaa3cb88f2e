"""The RT loop's configuration as the Rust core reads it (``_rtcore.AdmittanceLoop(config)``,
rtcore/py/src/rt.rs): a typed object.

The daemon builds an :class:`RtLoopConfig` (``admittance.daemon.loopconfig``) and hands it to
``AdmittanceLoop`` as it is; the core converts it at that one call (``msgspec.to_builtins``) and
reads it key by key, naming an unknown or mistyped key. These are frozen ``msgspec.Struct``s, so
mypy holds the builder to every key and value type the Rust side reads (``make test-stub``),
and nothing changes it on the way. A field left ``UNSET`` is left out, and the loop takes its
own default (``rt::config``); no default is declared here, and the ones the daemon's
configuration shares are ``_rtcore.LOOP_DEFAULTS`` (one source). The benches and tests may still
pass a dict of the same keys. The stub ``admittance/_rtcore.pyi`` names these types, and
tests/test_rtcore_stub.py checks both against the built module.
"""

from __future__ import annotations

import msgspec
from msgspec import UNSET, UnsetType


class _Boundary(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """What crosses to the core: immutable, and every field named at construction."""


class RtLimits(_Boundary, frozen=True):
    position_min: float | UnsetType = UNSET  # rad
    position_max: float | UnsetType = UNSET  # rad
    velocity_max: float | UnsetType = UNSET  # rad/s
    acceleration_max: float | UnsetType = UNSET  # rad/s²


class RtServo(_Boundary, frozen=True):
    """A parameter file's ``[servo]`` (plant::servo::SERVO_PARAM_NAMES): the five, and the gear play's two
    when fitted (absent: no play)."""

    time_constant: float  # s
    inertial_time: float  # s
    dead_time: float  # s
    compliance: float  # rad/(N·m)
    deadband: float  # rad
    backlash: float | UnsetType = UNSET  # rad (absent: 0)
    backlash_torque: float | UnsetType = UNSET  # N·m (absent: 0)


class RtJoint(_Boundary, frozen=True):
    id: int
    model: str | UnsetType = UNSET
    goal_address: int | UnsetType = UNSET
    goal_size: int | UnsetType = UNSET
    present_address: int | UnsetType = UNSET
    present_size: int | UnsetType = UNSET
    torque_enable_address: int | UnsetType = UNSET
    zero_tick: int | UnsetType = UNSET
    direction: int | UnsetType = UNSET  # +1 or -1
    ticks_per_rev: float | UnsetType = UNSET
    tick_min: int | UnsetType = UNSET
    tick_max: int | UnsetType = UNSET
    virtual_inertia: float | UnsetType = UNSET  # kg·m²
    virtual_damping: float | UnsetType = UNSET  # N·m·s/rad
    virtual_coulomb: float | UnsetType = UNSET  # N·m
    axis: str | UnsetType = UNSET  # "x".."tz"
    lever_arm: float | UnsetType = UNSET  # m
    limits: RtLimits | UnsetType = UNSET
    servo: RtServo | None | UnsetType = UNSET  # None: no servo model
    servo_compensation: float | UnsetType = UNSET  # 0..1
    passivity_guard: float | UnsetType = UNSET  # 0 or 1: the passivity guard (docs/fidelity.md)
    passivity_margin: float | UnsetType = UNSET  # J
    passivity_damping_max: float | UnsetType = UNSET  # N·m·s/rad


class RtFaultPolicy(_Boundary, frozen=True):
    servo_error: str | UnsetType = UNSET  # "reboot" or "stop"
    torque_off: str | UnsetType = UNSET  # "reenable" or "stop"
    bus_lost_timeout_s: float | UnsetType = UNSET
    servo_silent_ms: float | UnsetType = UNSET
    max_recoveries: int | UnsetType = UNSET
    recovery_window_s: float | UnsetType = UNSET
    check_period_ms: float | UnsetType = UNSET
    horn_speed_max: float | UnsetType = UNSET  # rad/s


class RtLoopConfig(_Boundary, frozen=True):
    port: str  # the Dynamixel bus device
    joints: tuple[RtJoint, ...]
    baudrate: int | UnsetType = UNSET
    protocol: int | UnsetType = UNSET  # 1 or 2
    bus_read: str | UnsetType = UNSET  # "auto", "fast" or "sync": how the present positions are read
    rate_hz: float | UnsetType = UNSET
    rt_policy: str | UnsetType = UNSET  # "fifo" or "other"
    rt_priority: int | UnsetType = UNSET
    lock_memory: bool | UnsetType = UNSET
    cpu: int | None | UnsetType = UNSET
    sync_read_divisor: int | UnsetType = UNSET
    stale_timeout_ms: float | UnsetType = UNSET
    deadband: float | UnsetType = UNSET  # N
    lowpass_hz: float | UnsetType = UNSET
    ramp_time_s: float | UnsetType = UNSET
    bias: tuple[float, ...] | UnsetType = UNSET  # six: fx fy fz tx ty tz
    force_capacity: int | UnsetType = UNSET
    telemetry_capacity: int | UnsetType = UNSET
    start_timeout_ms: float | UnsetType = UNSET
    torque_on_start: bool | UnsetType = UNSET
    trigger: str | UnsetType = UNSET  # "sample" or "schedule"
    phase_lock: bool | UnsetType = UNSET
    faults: RtFaultPolicy | UnsetType = UNSET
