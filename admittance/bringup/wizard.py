"""The bring-up steps in order, from a bus scan to a validated configuration file.

Steps (each skippable, each also a module of its own):

1. scan      every servo, at every baud rate and protocol tried;
2. servo     new ID, baud rate, operating mode (only when asked for);
3. arm       zero_tick and direction, by letting the arm hang and pushing it;
   range     the range of motion: the person moves the arm end to end, torque off; the
             position limits are those ends less a margin;
4. sensor    the force axis, its sign and the lever arm, by pressing against the held arm;
5. dry-run   a short admittance session with the servo's output limited;
6. write     the configuration, validated by the daemon's own loader before it is written.

One servo is brought up per run (a multi-joint bench runs the wizard once per joint, then
merges the [[joints]] tables).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import tomli_w

from admittance.bringup import arm as arm_step
from admittance.bringup import dryrun, scan
from admittance.bringup import motion_range
from admittance.bringup import sensor_axis as sensor_step
from admittance.bringup import servo as servo_step
from admittance.bringup.prompt import Prompter
from admittance.drivers.dynamixel import ServoBus
from admittance.errors import ConfigError

STEPS = ("servo", "arm", "range", "sensor", "dry-run")
MIN_LOOP_BAUDRATE = 1_000_000
LEVER_ARM_MISMATCH = 0.15  # a measured lever arm this far off the given one is reported


@dataclass
class SetupOptions:
    port: str
    out: Path
    baudrates: tuple[int, ...] = scan.DEFAULT_BAUDRATES
    protocols: tuple[int, ...] = scan.DEFAULT_PROTOCOLS
    servo_id: int | None = None
    new_id: int | None = None
    new_baudrate: int | None = None
    mode: str | None = None
    zero_tick: int | None = None
    direction: int | None = None
    sensor: dict[str, Any] = field(default_factory=dict)  # [sensor] keys: kind, port, interface, ...
    axis: str | None = None
    lever_arm: float | None = None
    dry_run_s: float = 5.0
    output_limit: float = 0.2
    position_limits: tuple[float, float] | None = None  # given instead of measured (rad)
    range_margin: float = motion_range.DEFAULT_MARGIN_RAD
    skip: frozenset[str] = frozenset()
    force: bool = False
    press_s: float = sensor_step.PRESS_S
    bus_options: dict[str, Any] = field(default_factory=dict)  # ServoBus options (reply slack on a loaded host)
    written_ports: dict[str, str] = field(default_factory=dict)  # {"bus": ..., "sensor": ...} to write instead


def run_wizard(opts: SetupOptions, prompter: Prompter, *, start_hand: Callable[[], None] = lambda: None) -> dict:
    """Run the steps; returns the configuration written to ``opts.out``."""
    _check_out(opts.out, opts.force)
    found = _scan(opts, prompter)
    found = _servo_settings(opts, found, prompter)
    model, protocol, baudrate = found.info.model, found.info.protocol, found.baudrate
    with ServoBus(opts.port, baudrate=baudrate, protocol=protocol, **opts.bus_options) as bus:
        zero, direction = _arm(opts, bus, found.id, prompter)
        limits = _range(opts, bus, found.id, zero, direction, prompter)
        axis, lever = _sensor(opts, bus, found.id, model, direction, prompter)
    doc = build_doc(opts, found, zero, direction, axis, lever, limits)
    validate(doc, opts.out)
    if "dry-run" not in opts.skip and opts.dry_run_s > 0:
        _dry_run(opts, doc, prompter, start_hand)
    write(doc, opts.out, opts.written_ports)
    prompter.say(f"wrote {opts.out}: start with  admittance run --config {opts.out}")
    return doc


def _check_out(out: Path, force: bool) -> None:
    if out.exists() and not force:
        raise ConfigError(f"{out} exists: pass --force to replace it")
    if not out.parent.is_dir():
        raise ConfigError(f"--out {out}: folder {out.parent} does not exist")


def _scan(opts: SetupOptions, prompter: Prompter) -> scan.Found:
    prompter.say(f"scanning {opts.port}: protocols {', '.join(map(str, opts.protocols))}, "
                 f"{', '.join(map(str, opts.baudrates))} bit/s")
    found = scan.scan_bus(opts.port, baudrates=opts.baudrates, protocols=opts.protocols, bus_options=opts.bus_options)
    for f in found:
        prompter.say(f"  {f.line()}")
    if opts.servo_id is not None:
        found = [f for f in found if f.id == opts.servo_id]
        if not found:
            raise ConfigError(f"no servo answered at ID {opts.servo_id}")
    return scan.only_servo(found)


def _servo_settings(opts: SetupOptions, found: scan.Found, prompter: Prompter) -> scan.Found:
    if "servo" in opts.skip:
        return found
    protocol, baudrate, servo_id = found.info.protocol, found.baudrate, found.id
    if opts.new_id is not None and opts.new_id != servo_id:
        with ServoBus(opts.port, baudrate=baudrate, protocol=protocol, **opts.bus_options) as bus:
            servo_step.change_id(bus, servo_id, opts.new_id)
        prompter.say(f"servo {servo_id} now answers at ID {opts.new_id}")
        servo_id = opts.new_id
    if opts.new_baudrate is not None and opts.new_baudrate != baudrate:
        servo_step.change_baudrate(opts.port, protocol, servo_id, baudrate, opts.new_baudrate, **opts.bus_options)
        prompter.say(f"servo {servo_id} now answers at {opts.new_baudrate} bit/s")
        baudrate = opts.new_baudrate
    if opts.mode is not None:
        with ServoBus(opts.port, baudrate=baudrate, protocol=protocol, **opts.bus_options) as bus:
            servo_step.set_mode(bus, servo_id, opts.mode)
        prompter.say(f"servo {servo_id} is in {opts.mode} mode")
    with ServoBus(opts.port, baudrate=baudrate, protocol=protocol, **opts.bus_options) as bus:
        info = bus.ping(servo_id)
    if baudrate < MIN_LOOP_BAUDRATE:
        prompter.say(f"note: at {baudrate} bit/s one cycle's packets take longer than 1 ms; for the 1 kHz loop "
                     f"move the servo with --new-baud {MIN_LOOP_BAUDRATE}")
    return scan.Found(info, baudrate)


def _arm(opts: SetupOptions, bus: ServoBus, servo_id: int, prompter: Prompter) -> tuple[int, int]:
    if "arm" in opts.skip or (opts.zero_tick is not None and opts.direction is not None):
        return (2048 if opts.zero_tick is None else opts.zero_tick), (opts.direction or 1)
    reading = arm_step.measure_arm(bus, servo_id, prompter)
    prompter.say(f"  {reading.line()}")
    return (reading.zero_tick if opts.zero_tick is None else opts.zero_tick,
            reading.direction if opts.direction is None else opts.direction)


def _range(opts: SetupOptions, bus: ServoBus, servo_id: int, zero: int, direction: int,
           prompter: Prompter) -> tuple[float, float] | None:
    """(position_min, position_max) in rad; None when skipped (the daemon's default then applies)."""
    if opts.position_limits is not None:
        return opts.position_limits
    if "range" in opts.skip:
        prompter.say("  range skipped: the limits stay the daemon's default (±3.1 rad within the servo's reach)")
        return None
    found = motion_range.measure_range(bus, servo_id, zero, direction, prompter, opts.range_margin)
    prompter.say(f"  {found.line()}")
    return found.position_min, found.position_max


def _sensor(opts: SetupOptions, bus: ServoBus, servo_id: int, model: str, direction: int,
            prompter: Prompter) -> tuple[str, float]:
    if "sensor" in opts.skip:
        if opts.axis is None or opts.lever_arm is None:
            raise ConfigError("skipping the sensor step needs --axis and --lever-arm")
        return opts.axis, opts.lever_arm
    with _sensor_samples(opts.sensor) as samples:
        reading = sensor_step.measure_sensor(bus, servo_id, model, direction, samples, prompter, press_s=opts.press_s)
    prompter.say(f"  {reading.line()}")
    if opts.axis is not None and opts.axis != reading.axis:
        raise ConfigError(f"--axis {opts.axis} but the press loaded axis {reading.axis}: check the sensor's mounting")
    if opts.lever_arm is None:
        return reading.axis, round(reading.lever_arm, 4)
    if opts.lever_arm * reading.lever_arm < 0:
        raise ConfigError(f"--lever-arm {opts.lever_arm:g} m has the wrong sign: a positive push gives "
                          f"{reading.lever_arm:+.3f} m (negate it, or check the direction)")
    if abs(reading.lever_arm / opts.lever_arm - 1.0) > LEVER_ARM_MISMATCH:
        prompter.say(f"  note: the measured lever arm {reading.lever_arm:.3f} m is more than "
                     f"{LEVER_ARM_MISMATCH:.0%} off --lever-arm {opts.lever_arm:g} m; keeping --lever-arm")
    return reading.axis, opts.lever_arm


@contextlib.contextmanager
def _sensor_samples(section: dict[str, Any]) -> Iterator[Any]:
    from admittance.drivers.force_reader import SampleBuffer, create_sensor

    if section.get("kind") != "can" and not section.get("port"):
        raise ConfigError("the sensor step needs the force sensor's port: give --sensor-port")
    buffer = SampleBuffer()
    with create_sensor(section, buffer):
        yield buffer


def build_doc(opts: SetupOptions, found: scan.Found, zero: int, direction: int, axis: str, lever: float,
              limits: tuple[float, float] | None = None) -> dict:
    sensor = {k: v for k, v in opts.sensor.items() if v is not None} | {"axis": axis, "lever_arm": lever}
    joint = {"id": found.id, "model": found.info.model, "zero_tick": zero, "direction": direction}
    if limits is not None:
        joint["limits"] = {"position_min": limits[0], "position_max": limits[1]}
    return {
        "bus": {"port": opts.port, "baudrate": found.baudrate, "protocol": found.info.protocol},
        "joints": [joint],
        "sensor": sensor,
        "loop": {"rate_hz": 1000},
        "stop": {"torque_policy": "hold"},
    }


def validate(doc: dict, out: Path) -> None:
    """The daemon's own loader, as `admittance run --config` will read the file."""
    from admittance.daemon import config

    config.parse_config(doc, out)


def _dry_run(opts: SetupOptions, doc: dict, prompter: Prompter, start_hand: Callable[[], None]) -> None:
    if not prompter.confirm(f"Run a {opts.dry_run_s:g} s admittance session with the output limited to "
                            f"{opts.output_limit:.0%}? Keep clear of the arm's path."):
        prompter.say("dry run skipped")
        return
    prompter.act("dry-run", "During the session, push the handle gently: the arm should follow, "
                            "and stop when you let go.")
    stats = dryrun.run_dry(doc, opts.out, opts.dry_run_s, opts.output_limit, start_hand=start_hand,
                           log=prompter.say, bus_options=opts.bus_options,
                           bench_stats=getattr(prompter, "bench_stats", None))
    prompter.say(f"  dry run: {stats['cycles']} cycles, {stats['overruns']} overruns, "
                 f"{stats['bus_errors']} bus errors, {stats['sensor_samples']} force samples")


def write(doc: dict, out: Path, ports: dict[str, str]) -> None:
    final = {**doc, "bus": {**doc["bus"], "port": ports.get("bus", doc["bus"]["port"])}, "sensor": dict(doc["sensor"])}
    if "sensor" in ports:
        final["sensor"]["port"] = ports["sensor"]
    validate(final, out)
    header = ("# Written by `admittance setup`. Every key is described in docs/daemon.md; "
              "check it with `admittance run --check --config FILE`.\n")
    out.write_text(header + tomli_w.dumps(final))
