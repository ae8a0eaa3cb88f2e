"""The daemon's configuration (``admittance run --config FILE``): read, validate, resolve.

Every table of ../shared/contracts/daemon.md is one frozen dataclass below, and every key a
field declared with :func:`schema.key` (type, unit, range, default, live-updatable). A bad
file fails here, before any device is opened, with one line that names the key.

Two defaults are not constants and are filled after validation:

- ``params`` of a joint defaults to ``params/<model>.toml`` (e.g. ``mx64.toml``); a relative
  path is looked up beside the configuration file, then in the working directory, and last
  among the fits shipped in the package (:mod:`admittance.data`);
- ``virtual_inertia/damping/coulomb`` default to the fitted plant's ``motor_inertia``,
  ``damping`` and ``coulomb``, so the powered joint feels like the same servo moving passively;
- ``servo_compensation`` defaults to the parameter file's ``[fit] servo_compensation`` when it
  carries a ``[servo]`` model (``admittance fidelity --params-out`` writes 1 only when the fit
  passed its verdict, 0 otherwise; 1 when the file does not say), else 0.

The live keys (``live=True``) obey one more layer, shared with every live change: the rules
between keys (:func:`check_joint_params`, :func:`check_loop_params`: limits in order and within
what the servo reaches, a stable virtual joint, a compensation only with a servo model, a
low-pass below half the rate). The configuration runs them on the resolved file, and
``liveparams`` on every candidate set, so a value refused in the file is refused over Zenoh with
the same reason, and the other way round. Why each bound is where it is: docs/daemon.md, "Bounds".
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from admittance import data
# The loop's defaults, the fault policy's bounds and the ID range are the Rust core's (rt::config,
# rt::recovery, rt::params): one source.
from admittance._rtcore import LOOP_BOUNDS, LOOP_DEFAULTS, MAX_JOINT_ID
from admittance.daemon import endpoints
from admittance.daemon.schema import build, check_value, clip, did_you_mean, key, shown
from admittance.drivers.force_reader import READER_CLASSES
from admittance.errors import ConfigError
from admittance.formats import paramfile

MOCK_PORT = "mock"
AXES = ("x", "y", "z")
# [sensor].kind: one of the readers the driver registry knows (drivers.force_reader.READER_CLASSES).
CONFIG_SENSOR_KINDS = tuple(READER_CLASSES)
_KEY_CHUNK = re.compile(r"^[^*$?#/]+$")
# Every supported model (MX-28/64/106, XM430, XL330) has a 12-bit absolute encoder, and position
# mode (set up by the servo checks) takes goals of one turn.
TICKS_PER_REV = 4096
GOAL_TICKS = (0, TICKS_PER_REV - 1)
# [loop].rt_priority's default: the daemon asks for more than a bare loop (LOOP_DEFAULTS has none).
DAEMON_RT_PRIORITY = 80
# The default position limits: a turn, clipped to what the joint's goal range reaches.
DEFAULT_POSITION_LIMIT = 3.1  # rad


@dataclass(frozen=True, kw_only=True)
class BusConfig:
    port: str = key("str", doc='serial device, or "mock" for the embedded simulated bench')
    baudrate: int = key("int", LOOP_DEFAULTS["baudrate"], unit="bit/s", lo=9600, hi=10_500_000, doc="bus baud rate")
    protocol: int = key("int", LOOP_DEFAULTS["protocol"], choices=(1, 2), doc="Dynamixel protocol")
    read: str = key("str", "auto", choices=("auto", "fast", "sync"),
                    doc="how the loop reads the present positions: Fast Sync Read (one reply for all servos; "
                        "Protocol 2.0), Sync Read, or auto: fast where every joint's model has it and the "
                        "servos answer it at start, else Sync Read (Bulk Read on Protocol 1.0)")


@dataclass(frozen=True, kw_only=True)
class LimitsConfig:
    """Limits on the model's state (not just its output), so the integrator never winds up."""

    # None = ∓3.1 rad clipped to the joint's reach (filled by _resolve_joint); an explicit value
    # must lie within the reach.
    position_min: float | None = key("float", None, unit="rad", lo=-math.pi, hi=math.pi, live=True,
                                     doc="lowest model angle")
    position_max: float | None = key("float", None, unit="rad", lo=-math.pi, hi=math.pi, live=True,
                                     doc="highest model angle")
    velocity_max: float = key("float", LOOP_DEFAULTS["velocity_max"], unit="rad/s", lo=0.0, lo_open=True, hi=12.0, live=True,
                              doc="model speed limit")
    acceleration_max: float = key("float", LOOP_DEFAULTS["acceleration_max"], unit="rad/s²", lo=0.0, lo_open=True, hi=1000.0, live=True,
                                  doc="model acceleration limit")


@dataclass(frozen=True, kw_only=True)
class JointConfig:
    id: int = key("int", lo=0, hi=MAX_JOINT_ID, doc="Dynamixel ID")
    model: str = key("str", doc="servo model, e.g. MX-64 (the model table's names)")
    zero_tick: int = key("int", LOOP_DEFAULTS["zero_tick"], unit="tick", lo=0, hi=4095, doc="encoder tick of joint angle 0")
    direction: int = key("int", LOOP_DEFAULTS["direction"], choices=(1, -1), doc="+1: the angle grows with the tick; -1: reversed")
    params: str = key("str", "", doc="fitted parameter file (Contract 2); default params/<model>.toml")
    name: str = key("str", "", doc="the joint's name in ROS 2 joint_states and MCAP; default joint<ID>")
    # None = the fitted plant's value (filled by _resolve_joint).
    virtual_inertia: float | None = key("float", None, unit="kg·m²", lo=1e-4, hi=10.0, live=True,
                                        doc="felt inertia")
    virtual_damping: float | None = key("float", None, unit="N·m·s/rad", lo=0.0, hi=100.0, live=True,
                                        doc="felt damping")
    virtual_coulomb: float | None = key("float", None, unit="N·m", lo=0.0, hi=10.0, live=True,
                                        doc="felt Coulomb friction")
    lever_arm: float | None = key("float", None, unit="m", lo=-2.0, hi=2.0, min_abs=1e-3, live=True,
                                  doc="this joint's lever arm; default [sensor].lever_arm")
    # None = 1 when the parameter file has a [servo] model, else 0 (filled by _resolve_joint).
    servo_compensation: float | None = key("float", None, lo=0.0, hi=1.0, live=True,
                                           doc="weight of the servo compensation: 1 = on, 0 = off; "
                                               "default 1 when `params` has a [servo] model, else 0")
    # The passivity guard (docs/fidelity.md, "The passivity guard"; rtcore/rt/src/passivity.rs).
    passivity_guard: float = key("float", LOOP_DEFAULTS["passivity_guard"], choices=(0.0, 1.0), live=True,
                               doc="passivity guard: 1 = on (a damping added while the joint generates energy "
                                   "beyond passivity_margin), 0 = off (observed only)")
    passivity_margin: float = key("float", LOOP_DEFAULTS["passivity_margin"], unit="J", lo=1e-5, hi=10.0, live=True,
                                  doc="the most energy the joint may give the hand beyond what the hand put in "
                                      "(the guard starts at half of it)")
    passivity_damping_max: float = key("float", LOOP_DEFAULTS["passivity_damping_max"], unit="N·m·s/rad", lo=0.0, lo_open=True, hi=100.0, live=True,
                                       doc="the most damping the passivity guard adds")
    limits: dict = key("table", {}, doc="per-joint [joints.limits] table")
    # Filled by resolve(): the parsed limits and the loaded parameter file.
    resolved_limits: LimitsConfig | None = dataclasses.field(default=None, metadata={"internal": True})
    plant: dict | None = dataclasses.field(default=None, metadata={"internal": True})


@dataclass(frozen=True, kw_only=True)
class SensorConfig:
    kind: str = key("str", choices=CONFIG_SENSOR_KINDS, doc="force sensor kind")
    port: str = key("str", "", doc='serial path (optoforce); for can an alias of channel; "mock" = the bench\'s')
    channel: str = key("str", "", doc="python-can channel, e.g. can0, /dev/ttyACM0, PCAN_USBBUS1 (can only)")
    interface: str = key("str", "", doc="python-can interface (can only); socketcan when a channel is given, "
                                        "python-can's own configuration when neither is")
    can_options: dict = key("table", {}, doc="the interface's own keyword arguments, passed to can.Bus (can only)")
    can_id: int = key("int", 0x100, lo=0, hi=0x1FFFFFFF, doc="CAN identifier of the data frames (can only)")
    bitrate: int = key("int", 1_000_000, unit="bit/s", lo=10_000, hi=8_000_000, doc="CAN bit rate (can only)")
    counts_per_newton: list = key("float_list", [451.89, 451.89, 451.89], unit="count/N", lo=0.0, lo_open=True,
                                  doc="OptoForce scale per axis")
    axis: str = key("str", LOOP_DEFAULTS["axis"], choices=AXES, doc="force axis that drives the joints")
    lever_arm: float = key("float", unit="m", lo=-2.0, hi=2.0, min_abs=1e-3,
                           doc="torque = force × lever_arm (negative flips the direction)")
    deadband: float = key("float", LOOP_DEFAULTS["deadband"], unit="N", lo=0.0, hi=100.0, live=True,
                          doc="half-width of the smooth dead zone on the force")
    lowpass_hz: float = key("float", LOOP_DEFAULTS["lowpass_hz"], unit="Hz", lo=0.0, hi=2000.0, live=True,
                            doc="first-order low-pass on the torque; 0 = off")
    bias: list = key("float_list", LOOP_DEFAULTS["bias"], unit="N, N·m", lo=-2000.0, hi=2000.0, length=6, live=True,
                     doc="offset the loop subtracts (fx fy fz tx ty tz) after the start-up tare")
    tare_samples: int = key("int", 100, lo=0, hi=100_000, doc="samples averaged at start as the zero; 0 = no tare")
    saturation: str = key("str", "hold", choices=("hold", "pass"),
                          doc="a saturated sample (overload flag, clipped count): hold drops it (the joint holds), pass uses it")
    reader: str = key("str", "auto", choices=("auto", "rust", "python"),
                      doc="auto: the Rust reader for optoforce and CAN on socketcan/slcan, python-can otherwise")
    frame_id: str = key("str", "force_sensor", doc="the sensor's frame name (ROS 2 wrench header.frame_id)")


@dataclass(frozen=True, kw_only=True)
class LoopConfig:
    rate_hz: float = key("float", LOOP_DEFAULTS["rate_hz"], unit="Hz", lo=10.0, hi=4000.0, doc="control rate")
    # The daemon's own choice, above the bare loop's 50 (docs/realtime.md): its one default for a
    # key the loop also reads that is not the loop's (tests/test_rtcore_stub.py names it).
    rt_priority: int = key("int", DAEMON_RT_PRIORITY, lo=0, hi=99, doc="SCHED_FIFO priority asked for; 0 = stay SCHED_OTHER")
    lock_memory: bool = key("bool", LOOP_DEFAULTS["lock_memory"], doc="mlockall the process (falls back, and reports, when refused)")
    sync_read_divisor: int = key("int", LOOP_DEFAULTS["sync_read_divisor"], lo=0, hi=10_000, doc="read present positions every N cycles; 0 = never")
    stale_timeout_ms: float = key("float", LOOP_DEFAULTS["stale_timeout_ms"], unit="ms", lo=0.0, lo_open=True, hi=500.0, live=True,
                                  doc="no force sample for this long: hold position")
    ramp_time_s: float = key("float", LOOP_DEFAULTS["ramp_time_s"], unit="s", lo=0.0, hi=10.0, live=True,
                             doc="a live parameter change blends in over this time (no jump)")
    trigger: str = key("str", LOOP_DEFAULTS["trigger"], choices=("sample", "schedule"),
                       doc="what starts a cycle: a force sample's arrival in the period's window, or the fixed schedule")
    phase_lock: bool = key("bool", LOOP_DEFAULTS["phase_lock"], doc="with trigger = sample: move the cycle grid (≤ period/500 per cycle) "
                                             "so a sensor at the loop's rate arrives mid-window")


@dataclass(frozen=True, kw_only=True)
class StopConfig:
    torque_policy: str = key("str", "hold", choices=("hold", "torque_off"), doc="what the servos do at exit")


@dataclass(frozen=True, kw_only=True)
class FaultsConfig:
    """What the daemon does about servo, bus and sensor faults (docs/faults.md has the table)."""

    servo_error: str = key("str", LOOP_DEFAULTS["servo_error"], choices=("reboot", "stop"),
                           doc="a servo that shut down on a hardware error: reboot it where safe (not overheating, "
                               "encoder or electrical shock; not a second overload in the window) and turn torque "
                               "on again at its present position, or stop (exit 69)")
    torque_off: str = key("str", LOOP_DEFAULTS["torque_off"], choices=("reenable", "stop"),
                          doc="a servo found with torque off and no error (a brown-out): torque on again at its "
                              "present position, or stop (exit 69)")
    bus_lost_timeout_s: float = key("float", LOOP_DEFAULTS["bus_lost_timeout_s"], unit="s", lo=0.1, hi=600.0,
                                    doc="the bus's port failed (unplugged), or a servo does not answer, for this "
                                        "long: stop, exit 75 (systemd restarts the daemon)")
    servo_silent_ms: float = key("float", LOOP_DEFAULTS["servo_silent_ms"], unit="ms", lo=5.0, hi=10_000.0,
                                 doc="a servo that does not answer for this long is silent: its joint holds")
    max_recoveries: int = key("int", LOOP_DEFAULTS["max_recoveries"], lo=LOOP_BOUNDS["max_recoveries"][0],
                              hi=LOOP_BOUNDS["max_recoveries"][1],
                              doc="reboots and re-enables allowed per servo within recovery_window_s; one more "
                                  "stops (exit 69); 0 = never recover")
    recovery_window_s: float = key("float", LOOP_DEFAULTS["recovery_window_s"], unit="s", lo=1.0, hi=86_400.0,
                                   doc="the window of max_recoveries, and in which a second overload stops")
    check_period_ms: float = key("float", LOOP_DEFAULTS["check_period_ms"], unit="ms", lo=10.0, hi=10_000.0,
                                 doc="one servo's Torque Enable is read this often, in turn (torque found off)")
    horn_speed_max: float = key("float", LOOP_DEFAULTS["horn_speed_max"], unit="rad/s",
                                lo=LOOP_BOUNDS["horn_speed_max"][0], hi=LOOP_BOUNDS["horn_speed_max"][1],
                                doc="the fastest a horn can turn: a position read implying more is a glitch, kept "
                                    "out of the model, the goal and the recording until a second read confirms it; "
                                    "the start and every re-anchor need two agreeing reads within the limits")
    sensor_lost_timeout_s: float = key("float", 0.0, unit="s", lo=0.0, hi=86_400.0,
                                       doc="no usable force sample for this long: stop, exit 75; 0 = hold forever "
                                           "(the reader keeps reopening the sensor)")


@dataclass(frozen=True, kw_only=True)
class ZenohConfig:
    prefix: str = key("str", "bench/arm1", doc="key-expression prefix of every key")
    listen: list = key("str_list", ["tcp/127.0.0.1:7447"], doc="endpoints to listen on; empty = zenoh defaults")
    connect: list = key("str_list", [], doc="endpoints to connect to")
    scouting: bool = key("bool", False, doc="multicast scouting")
    mode: str = key("str", "peer", choices=("peer", "client", "router"), doc="zenoh session mode")
    state_rate_hz: float = key("float", 100.0, unit="Hz", lo=50.0, hi=1000.0, doc="rate of <prefix>/state")
    encoding: str = key("str", "json", choices=("json", "msgpack"), doc="payload encoding")
    # Security (docs/zenoh.md, docs/lab-network.md); paths are relative to the configuration file.
    auth_dictionary: str = key("str", "", doc="user:password file; sessions that connect must log in as one of them")
    auth_user: str = key("str", "", doc="user name this session logs in with (to an authenticating router or peer)")
    auth_password_file: str = key("str", "", doc="file holding auth_user's password (one line)")
    tls_ca: str = key("str", "", doc="CA certificate (PEM) that peers' TLS certificates must chain to")
    tls_certificate: str = key("str", "", doc="this session's TLS certificate (PEM); needed to listen on tls/")
    tls_private_key: str = key("str", "", doc="the private key (PEM) of tls_certificate")
    tls_client_auth: bool = key("bool", False, doc="mutual TLS: peers must present a certificate signed by tls_ca")
    operators: list = key("str_list", [], doc="user names or certificate common names allowed to send commands "
                          "(params, tare); non-empty turns access control on")


ROS_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")


@dataclass(frozen=True, kw_only=True)
class Ros2Config:
    """Visibility to ROS 2 nodes on rmw_zenoh (docs/ros2.md, ../shared/contracts/ros2.md)."""

    enabled: bool = key("bool", False, doc="publish joint_states and wrench for ROS 2 nodes on rmw_zenoh")
    domain_id: int = key("int", 0, lo=0, hi=232, doc="ROS_DOMAIN_ID")
    namespace: str = key("str", "", doc='ROS namespace of the node and its topics, e.g. "/bench1"; "" = none')
    node: str = key("str", "admittance", doc="the node name ROS 2 tools show")


@dataclass(frozen=True, kw_only=True)
class FoxgloveConfig:
    """The live view: a Foxglove WebSocket server fed by the supervisor (docs/foxglove.md)."""

    enabled: bool = key("bool", False, doc="serve a live view to Foxglove over WebSocket")
    host: str = key("str", "127.0.0.1", doc="address the WebSocket server binds")
    port: int = key("int", 8765, lo=0, hi=65535, doc="its TCP port (0 = any free port)")
    rate_hz: float = key("float", 50.0, unit="Hz", lo=1.0, hi=1000.0, doc="most messages per second per channel")


@dataclass(frozen=True, kw_only=True)
class RecordConfig:
    path: str = key("str", "", doc="record the session into this dataset folder; empty = no recording")
    segment_s: float = key("float", 10.0, unit="s", lo=0.5, hi=3600.0, doc="one trial file per joint per this long")


@dataclass(frozen=True, kw_only=True)
class BenchConfig:
    """The simulation: the embedded bench ([bus].port = "mock") or the scripted sensor (kind = "mock")."""

    profile: str = key("str", "push-release", doc="the scripted hand: a mock-bench profile (NAME[:k=v,...] or CSV)")
    hand_delay_s: float = key("float", 0.5, unit="s", lo=0.0, hi=3600.0,
                              doc="the hand starts this long after the loop runs (it keeps off during the tare)")
    noise_std_n: float = key("float", 0.0, unit="N", lo=0.0, hi=10.0, doc="sensor noise of the simulated sensor")
    sensor_stream: str = key("str", "rust", choices=("rust", "python"),
                             doc="the embedded bench's OptoForce stream: a Rust thread beside the simulated bus, or "
                                 "the Python one (a comparison: it waits for the daemon's interpreter)")
    servo_lag_s: float = key("float", 0.0, unit="s", lo=0.0, hi=10.0,
                             doc="0: the BAM-style MX firmware and motor; > 0: a horn that lags its goal by this "
                                 "time constant instead (embedded bench only)")
    hand_inertia: float = key("float", 0.0, unit="kg·m²", lo=0.0, hi=1.0,
                              doc="a hand gripping the horn (embedded bench): its inertia rides with the horn")
    hand_damping: float = key("float", 0.0, unit="N·m·s/rad", lo=0.0, hi=100.0, doc="the gripping hand's damping")
    hand_stiffness: float = key("float", 0.0, unit="N·m/rad", lo=0.0, hi=1000.0,
                                doc="the gripping hand's stiffness about where it gripped")


@dataclass(frozen=True, kw_only=True)
class DaemonConfig:
    bus: BusConfig
    joints: tuple[JointConfig, ...]
    sensor: SensorConfig
    loop: LoopConfig
    stop: StopConfig
    zenoh: ZenohConfig
    record: RecordConfig
    bench: BenchConfig
    source: Path  # the file it came from (relative paths are resolved beside it)
    ros2: Ros2Config = dataclasses.field(default_factory=Ros2Config)
    foxglove: FoxgloveConfig = dataclasses.field(default_factory=FoxgloveConfig)
    faults: FaultsConfig = dataclasses.field(default_factory=FaultsConfig)


TABLES = {"bus": BusConfig, "sensor": SensorConfig, "loop": LoopConfig, "stop": StopConfig, "faults": FaultsConfig,
          "zenoh": ZenohConfig, "record": RecordConfig, "bench": BenchConfig, "ros2": Ros2Config,
          "foxglove": FoxgloveConfig}
REQUIRED_TABLES = ("bus", "joints", "sensor")


def load_config(path: str | Path) -> DaemonConfig:
    """Read, validate and resolve a configuration file."""
    path = Path(path)
    return parse_config(read_toml(path), path)


def read_toml(path: Path) -> dict[str, Any]:
    """The configuration file's TOML, read as every TOML file of the project is (bounded, UTF-8,
    one line naming the file on any failure: formats.paramfile.read_toml)."""
    return paramfile.read_toml(path, ConfigError, "configuration file")


def parse_config(doc: dict[str, Any], path: Path) -> DaemonConfig:
    where = str(path)
    for name in doc:
        if name not in (*TABLES, "joints"):
            raise ConfigError(f"{where}: unknown table [{clip(name)}]{did_you_mean(name, [*TABLES, 'joints'])}")
    for name in REQUIRED_TABLES:
        if name not in doc:
            raise ConfigError(f"{where}: [{name}] is required")
    tables = {name: build(cls, doc.get(name, {}), f"{where}: [{name}]") for name, cls in TABLES.items()}
    tables["zenoh"] = absolute_zenoh_paths(tables["zenoh"], path.resolve().parent)
    joints = _parse_joints(doc["joints"], path, tables["bus"].protocol)
    lever_arm = tables["sensor"].lever_arm
    joints = tuple(j if j.lever_arm is not None else dataclasses.replace(j, lever_arm=lever_arm) for j in joints)
    _check_cross(tables, joints, where)
    if "bench" in doc and tables["bus"].port != MOCK_PORT and tables["sensor"].kind != "mock":
        raise ConfigError(f"{where}: [bench] only applies to a simulation "
                          "([bus].port = \"mock\" or [sensor].kind = \"mock\")")
    return DaemonConfig(joints=joints, source=path, **tables)


def _parse_joints(raw: Any, path: Path, protocol: int) -> tuple[JointConfig, ...]:
    if not isinstance(raw, list) or not raw:
        raise ConfigError(f"{path}: [[joints]] must be a non-empty array of tables")
    models = known_models(protocol)
    joints, seen = [], set()
    for i, table in enumerate(raw):
        where = f"{path}: [[joints]] #{i + 1}"
        joint = build(JointConfig, table, where)
        if joint.id in seen:
            raise ConfigError(f"{where}.id: duplicate joint id {joint.id}")
        seen.add(joint.id)
        if joint.model not in models:
            raise ConfigError(f"{where}.model: {joint.model!r} is not a Protocol {protocol}.0 model"
                              f"{did_you_mean(joint.model, models)}")
        joints.append(_resolve_joint(joint, path, f"{path}: [joints.{joint.id}]"))
    names = [j.name for j in joints]
    if len(set(names)) != len(names):
        raise ConfigError(f"{path}: [[joints]] name: two joints are called the same ({', '.join(names)})")
    return tuple(joints)


def _resolve_joint(joint: JointConfig, path: Path, where: str) -> JointConfig:
    limits = _default_position_limits(build(LimitsConfig, joint.limits, f"{where}.limits"), reachable_range(joint))
    params_path = resolve_params_path(joint, path, where)
    plant = paramfile.load(params_path)
    if plant["model"].get("mode", "geometry") == "lumped":
        raise ConfigError(f"{where}.params: {params_path} is a lumped fit (per unit inertia); "
                          "the daemon needs a geometry fit in SI units")
    fitted = plant["params"]
    if "motor_inertia" not in fitted:
        raise ConfigError(f"{where}.params: {params_path} has no motor_inertia")
    compensation = _or(joint.servo_compensation, _fitted_compensation(plant, params_path))  # checked in check_joint_params
    return dataclasses.replace(
        joint,
        params=str(params_path),
        name=joint.name or f"joint{joint.id}",
        virtual_inertia=_or(joint.virtual_inertia, fitted["motor_inertia"]),
        virtual_damping=_or(joint.virtual_damping, fitted.get("damping", 0.0)),
        virtual_coulomb=_or(joint.virtual_coulomb, fitted.get("coulomb", 0.0)),
        servo_compensation=compensation,
        resolved_limits=limits,
        plant=plant,
    )


def _fitted_compensation(plant: dict, path: Path) -> float:
    """The default ``servo_compensation`` of a parameter file: 0 without a ``[servo]`` model, else
    its ``[fit] servo_compensation`` (what `fidelity` judged its fit worth: 0 when refused), 1 when
    the file does not say (written by hand or before the verdict existed)."""
    if "servo" not in plant:
        return 0.0
    value = plant["fit"].get("servo_compensation", 1.0)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 <= value <= 1.0:
        raise ConfigError(f"{path}: [fit] servo_compensation: expected a number in [0, 1], got {value!r}")
    return float(value)


def _or(value: float | None, fallback: float) -> float:
    return fallback if value is None else value


def _default_position_limits(limits: LimitsConfig, reach: tuple[float, float]) -> LimitsConfig:
    """An omitted position limit is ∓3.1 rad clipped to the reach (an explicit one is checked)."""
    return dataclasses.replace(
        limits,
        position_min=_or(limits.position_min, max(-DEFAULT_POSITION_LIMIT, reach[0])),
        position_max=_or(limits.position_max, min(DEFAULT_POSITION_LIMIT, reach[1])),
    )


def has_servo_model(joint: JointConfig) -> bool:
    """The joint's parameter file carries a servo model (``[servo]``) to compensate with."""
    return "servo" in (joint.plant or {})


def reachable_range(joint: JointConfig) -> tuple[float, float]:
    """The joint angles the goal's tick range covers from ``zero_tick`` (direction taken into account)."""
    ends = sorted(joint.direction * (t - joint.zero_tick) * 2 * math.pi / TICKS_PER_REV for t in GOAL_TICKS)
    return ends[0], ends[1]


def resolve_params_path(joint: JointConfig, config_path: Path, where: str) -> Path:
    """The joint's parameter file: beside the config file first, then in the working directory
    (a user's own fit wins over a shipped one), and last among the fits shipped in the package."""
    name = joint.params or f"{data.PARAMS}/{data.params_name(joint.model)}"
    if Path(name).is_absolute():
        candidates = [Path(name)]
    else:
        candidates = [config_path.resolve().parent / name, Path.cwd() / name, data.packaged(name)]
    for candidate in candidates:
        if candidate is not None and candidate.is_file():
            return candidate
    if not joint.params:
        raise ConfigError(f"{where}.params: required (no shipped parameter file for model {joint.model!r})")
    raise ConfigError(f"{where}.params: file {name!r} not found beside {config_path}, in the working "
                      "directory nor among the shipped fits")


def _check_cross(tables: dict, joints: tuple[JointConfig, ...], where: str) -> None:
    """Rules that involve more than one key."""
    bus, sensor, loop, zen = tables["bus"], tables["sensor"], tables["loop"], tables["zenoh"]
    if sensor.kind == "optoforce" and not sensor.port:
        raise ConfigError(f"{where}: [sensor].port: required for kind {sensor.kind!r}")
    if sensor.kind == "can":
        _check_can(sensor, where)
    if sensor.port == MOCK_PORT and bus.port != MOCK_PORT:
        raise ConfigError(f"{where}: [sensor].port: \"mock\" needs the simulated bench ([bus].port = \"mock\")")
    if len(sensor.counts_per_newton) != 3:
        raise ConfigError(f"{where}: [sensor].counts_per_newton: expected 3 values (x, y, z), got "
                          f"{len(sensor.counts_per_newton)}")
    for j in joints:
        joint_where = f"{where}: [joints.{j.id}]"
        check_joint_params(joint_values(j), reach=reachable_range(j), has_servo=has_servo_model(j),
                           rate_hz=loop.rate_hz, where=joint_where, name=lambda k, w=joint_where: f"{w}.{'limits.' if k in LIMIT_KEYS else ''}{k}")
    check_loop_params(loop_values(tables), rate_hz=loop.rate_hz, where=where,
                      name=lambda k: f"{where}: [{LOOP_LIVE[k][0]}].{k}")
    faults = tables["faults"]
    if faults.servo_silent_ms >= 1000.0 * faults.bus_lost_timeout_s:
        raise ConfigError(f"{where}: [faults].servo_silent_ms: must be below bus_lost_timeout_s "
                          f"({1000.0 * faults.bus_lost_timeout_s:g} ms): a servo is silent before it is lost")
    if zen.state_rate_hz > loop.rate_hz:
        raise ConfigError(f"{where}: [zenoh].state_rate_hz: must not exceed [loop].rate_hz ({loop.rate_hz:g} Hz)")
    if zen.mode == "client" and not zen.connect:
        raise ConfigError(f"{where}: [zenoh].connect: required with mode = \"client\" (a client only "
                          "reaches others through the router or peer it connects to)")
    check_endpoints(zen, where)
    check_prefix(zen.prefix, where)
    check_zenoh_security(zen, where)
    _check_ros2(tables["ros2"], where)


ZENOH_PATH_KEYS = ("auth_dictionary", "auth_password_file", "tls_ca", "tls_certificate", "tls_private_key")


def absolute_zenoh_paths(zen: ZenohConfig, base: Path) -> ZenohConfig:
    """The [zenoh] table with its file keys made absolute (relative ones are beside the configuration)."""
    return dataclasses.replace(zen, **{name: str(base / value) for name in ZENOH_PATH_KEYS
                                       if (value := getattr(zen, name)) and not Path(value).is_absolute()})


def load_zenoh_table(path: str | Path) -> ZenohConfig:
    """Only the [zenoh] table of a file (the remote tools' and the router's ``--zenoh-config``)."""
    path = Path(path)
    zen = build(ZenohConfig, read_toml(path).get("zenoh", {}), f"{path}: [zenoh]")
    zen = absolute_zenoh_paths(zen, path.resolve().parent)
    check_prefix(zen.prefix, str(path))
    check_endpoints(zen, str(path))
    check_zenoh_security(zen, str(path))
    return zen


def check_prefix(prefix: str, where: str) -> None:
    if not all(_KEY_CHUNK.match(c) for c in prefix.split("/")):
        raise ConfigError(f"{where}: [zenoh].prefix: {shown(prefix)} is not a valid key expression "
                          "(non-empty '/'-separated chunks without * $ ? #)")


def check_endpoints(zen: ZenohConfig, where: str) -> None:
    """Every listen/connect endpoint parses (one line naming it, before any device is opened)."""
    for name in ("listen", "connect"):
        for i, text in enumerate(getattr(zen, name)):
            endpoints.parse(text, f"{where}: [zenoh].{name}[{i}]")


def _check_can(sensor: SensorConfig, where: str) -> None:
    from admittance.drivers.can_sensor import check_can_options

    if sensor.channel and sensor.port and sensor.channel != sensor.port:
        raise ConfigError(f"{where}: [sensor].port is an alias of channel: give one ({sensor.port!r} or "
                          f"{sensor.channel!r})")
    if sensor.interface and not (sensor.channel or sensor.port):
        raise ConfigError(f"{where}: [sensor].channel: required with interface = {sensor.interface!r} (leave both "
                          "out to use python-can's own configuration)")
    try:
        check_can_options(sensor.can_options)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None


def check_zenoh_security(zen: ZenohConfig, where: str) -> None:
    """Security keys that only make sense together (files are checked when the session opens)."""
    if bool(zen.auth_user) != bool(zen.auth_password_file):
        raise ConfigError(f"{where}: [zenoh].auth_user and auth_password_file: give both or neither")
    if bool(zen.tls_certificate) != bool(zen.tls_private_key):
        raise ConfigError(f"{where}: [zenoh].tls_certificate and tls_private_key: give both or neither")
    everywhere = [*zen.listen, *zen.connect]
    if any(e.startswith("tls/") for e in zen.listen) and not zen.tls_certificate:
        raise ConfigError(f"{where}: [zenoh].tls_certificate: required to listen on a tls/ endpoint")
    if any(e.startswith("tls/") for e in everywhere) and not zen.tls_ca:
        raise ConfigError(f"{where}: [zenoh].tls_ca: required with a tls/ endpoint (it verifies the peer)")
    if zen.tls_client_auth and not (zen.tls_ca and zen.tls_certificate):
        raise ConfigError(f"{where}: [zenoh].tls_client_auth: needs tls_ca, tls_certificate and tls_private_key")
    if zen.operators and not (zen.auth_dictionary or zen.tls_client_auth):
        raise ConfigError(f"{where}: [zenoh].operators: needs a way to tell who connects: auth_dictionary "
                          "(user/password) or tls_client_auth (certificates)")
    for name in zen.operators:
        if not name.strip():
            raise ConfigError(f"{where}: [zenoh].operators: empty name")


def _check_ros2(ros2: Ros2Config, where: str) -> None:
    if not ROS_NAME.match(ros2.node):
        raise ConfigError(f"{where}: [ros2].node: {ros2.node!r} is not a ROS node name "
                          "(a letter, then letters, digits or _)")
    chunks = ros2.namespace.split("/")
    if ros2.namespace and (chunks[0] != "" or not all(ROS_NAME.match(c) for c in chunks[1:])):
        raise ConfigError(f"{where}: [ros2].namespace: {ros2.namespace!r} is not a ROS namespace "
                          '(e.g. "/bench1": "/"-separated names, each a letter then letters, digits or _)')


# -- the live keys, and the rules between them (shared with every live set: liveparams) ----------

# Tables whose live keys belong to each joint ("1.virtual_damping"); every other table's live keys
# are loop-wide ("deadband"). A key declared live=True in one of them is a live parameter.
JOINT_TABLES = {"joints": JointConfig, "joints.limits": LimitsConfig}


def _live_keys(tables: Mapping[str, type]) -> dict[str, tuple[str, dict]]:
    return {f.name: (table, dict(f.metadata)) for table, cls in tables.items()
            for f in dataclasses.fields(cls) if f.metadata.get("live")}


JOINT_LIVE = _live_keys(JOINT_TABLES)  # name -> (table, metadata)
LOOP_LIVE = _live_keys(TABLES)
LIMIT_KEYS = tuple(k for k, (table, _) in JOINT_LIVE.items() if table == "joints.limits")
# Every key of every table (live or not) -> the tables that have it, for a clear refusal of a
# key that is not live (rate_hz is in [loop] and in [foxglove]).
ALL_KEYS: dict[str, list[str]] = {}
for _table, _cls in {**TABLES, **JOINT_TABLES}.items():
    for _field in dataclasses.fields(_cls):
        if not _field.metadata.get("internal"):
            ALL_KEYS.setdefault(_field.name, []).append(_table)


def joint_values(joint: JointConfig) -> dict[str, Any]:
    """A resolved joint's live values, by key name."""
    return {k: getattr(joint.resolved_limits if table == "joints.limits" else joint, k)
            for k, (table, _) in JOINT_LIVE.items()}


def loop_values(tables: Mapping[str, Any]) -> dict[str, Any]:
    """The loop-wide live values of the parsed tables, by key name."""
    return {k: getattr(tables[table], k) for k, (table, _) in LOOP_LIVE.items()}


REACH_SLACK = 1e-9  # rad: the reach computed here and in the loop may differ by a rounding


def check_joint_params(values: Mapping[str, Any], *, reach: tuple[float, float], has_servo: bool, rate_hz: float,
                       where: str, name: Callable[[str], str]) -> dict[str, Any]:
    """One joint's live values: each against its key's metadata, then the rules between them.

    The configuration calls it on each resolved joint, liveparams on each candidate set, so
    both refuse the same values for the same reasons. ``name(key)`` is how a message names a
    key, ``where`` the joint. Values absent from ``values`` are not checked. Returns the values,
    normalised.
    """
    out = {k: check_value(JOINT_LIVE[k][1], v, name(k)) for k, v in values.items()}
    lo, hi = out.get("position_min"), out.get("position_max")
    for k, v in (("position_min", lo), ("position_max", hi)):
        if v is not None and not reach[0] - REACH_SLACK <= v <= reach[1] + REACH_SLACK:
            raise ConfigError(f"{name(k)}: must be within [{reach[0]:.4f}, {reach[1]:.4f}] rad, the angles the "
                              f"servo's goal range reaches from its zero_tick; got {shown(v)}")
    if lo is not None and hi is not None and lo >= hi:
        raise ConfigError(f"{name('position_min')}: must be below position_max ({hi:g} rad), got {lo:g}")
    if out.get("servo_compensation", 0.0) > 0 and not has_servo:
        raise ConfigError(f"{name('servo_compensation')}: {out['servo_compensation']:g} needs a servo model, and "
                          "this joint's parameter file has no [servo] table (make one with `admittance fidelity "
                          "RECORDING --params-out FILE`)")
    if {"virtual_inertia", "virtual_damping", "virtual_coulomb"} <= out.keys():
        from admittance import _rtcore  # the plant's own gate: one source of physics

        reason = _rtcore.admittance_check_stable(out["virtual_inertia"], out["virtual_damping"],
                                                 out["virtual_coulomb"], 1.0 / rate_hz)
        if reason:
            raise ConfigError(f"{where} virtual_*: {reason}")
    return out


def check_loop_params(values: Mapping[str, Any], *, rate_hz: float, where: str,
                      name: Callable[[str], str]) -> dict[str, Any]:
    """The loop-wide live values: each against its key's metadata, then the rules between them
    (the same function on both paths, like :func:`check_joint_params`)."""
    out = {k: check_value(LOOP_LIVE[k][1], v, name(k)) for k, v in values.items()}
    if out.get("lowpass_hz", 0.0) >= rate_hz / 2:
        raise ConfigError(f"{name('lowpass_hz')}: must be below half of [loop].rate_hz ({rate_hz / 2:g} Hz), "
                          f"got {out['lowpass_hz']:g}")
    return out


def known_models(protocol: int) -> list[str]:
    """The model table's names on one protocol (the same table the codec and the mock use)."""
    from admittance import _rtcore

    return sorted({m["name"] for m in _rtcore.model_table() if int(m["protocol"]) == protocol})


def load_default() -> DaemonConfig:
    """The embedded default: the simulated bench of the packaged bench.toml."""
    bench = data.bench_config()
    if not bench.is_file():
        raise ConfigError(f"the default bench configuration {bench} is missing; pass --config FILE")
    return load_config(bench)


def summary(cfg: DaemonConfig) -> str:
    """A few lines for `run --check`: what would run, with every default filled in."""
    lines = [f"config: {cfg.source}",
             f"bus: {cfg.bus.port} at {cfg.bus.baudrate} bit/s, protocol {cfg.bus.protocol}"]
    for j in cfg.joints:
        lines.append(f"joint {j.id}: {j.model}, zero tick {j.zero_tick}, params {j.params}; virtual "
                     f"I={j.virtual_inertia:g} kg·m², B={j.virtual_damping:g} N·m·s/rad, "
                     f"F={j.virtual_coulomb:g} N·m, lever arm {j.lever_arm:g} m; servo compensation "
                     f"{j.servo_compensation:g}{'' if 'servo' in j.plant else ' (no [servo] model)'}")
    s = cfg.sensor
    lines.append(f"sensor: {s.kind} on {s.port or '-'}, axis {s.axis}, tare {s.tare_samples} samples")
    lines.append(f"loop: {cfg.loop.rate_hz:g} Hz, rt priority {cfg.loop.rt_priority}; "
                 f"stop: {cfg.stop.torque_policy}")
    f = cfg.faults
    sensor_lost = f"stop after {f.sensor_lost_timeout_s:g} s" if f.sensor_lost_timeout_s else "hold"
    lines.append(f"faults: servo error {f.servo_error}, torque off {f.torque_off}, bus lost {f.bus_lost_timeout_s:g} s, "
                 f"at most {f.max_recoveries} recoveries per {f.recovery_window_s:g} s, sensor lost {sensor_lost}")
    z = cfg.zenoh
    lines.append(f"zenoh: {z.prefix} ({z.encoding}), listen {z.listen or 'defaults'}, connect {z.connect}")
    lines += [f"warning: {w}" for w in endpoints.exposure_warnings(z)]
    security = [name for name, on in (("user/password", z.auth_dictionary or z.auth_user),
                                      ("TLS", z.tls_ca or z.tls_certificate), ("mutual TLS", z.tls_client_auth),
                                      (f"ACL (operators {', '.join(z.operators)})", z.operators)) if on]
    lines.append(f"zenoh security: {', '.join(security) or 'none (loopback only by default)'}")
    if cfg.ros2.enabled:
        r = cfg.ros2
        lines.append(f"ros2: node {r.namespace or ''}/{r.node}, domain {r.domain_id} (rmw_zenoh)")
    if cfg.foxglove.enabled:
        lines.append(f"foxglove: ws://{cfg.foxglove.host}:{cfg.foxglove.port}")
    return "\n".join(lines)


def with_overrides(cfg: DaemonConfig, *, record: str | None = None) -> DaemonConfig:
    """A copy with command-line overrides applied (they win over the file)."""
    if record is not None:
        cfg = dataclasses.replace(cfg, record=dataclasses.replace(cfg.record, path=str(Path(record).resolve())))
    return cfg


def record_dir(cfg: DaemonConfig) -> Path | None:
    """Where to record, or None: a relative [record].path is beside the configuration file."""
    if not cfg.record.path:
        return None
    path = Path(cfg.record.path)
    return path if path.is_absolute() else cfg.source.resolve().parent / path
