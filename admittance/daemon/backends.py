"""The real implementations behind the supervisor's :class:`~supervisor.Backends`.

Each function wraps another part of the project (the mock bench, the Dynamixel setup, the
force-sensor registry, the RT loop, Zenoh) and turns its failures into one-line
DeviceError/ConfigError messages that say which device and what to check. Keeping them here,
apart from the supervisor's sequencing, is what lets the sequence be tested with fakes.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any

from admittance.daemon.config import MOCK_PORT, DaemonConfig
from admittance.daemon.loopconfig import rt_loop_config
from admittance.daemon.supervisor import Backends, BenchPorts, GatedSink
from admittance.daemon.telemetry import TICKS_PER_REV
from admittance.errors import DeviceError

if TYPE_CHECKING:
    from admittance._rtcore import AdmittanceLoop
    from admittance.drivers.dynamixel import ServoBus
    from admittance.drivers.force_reader import ForceStream


def real_backends() -> Backends:
    from admittance.daemon.zenoh_iface import DaemonInterface

    return Backends(start_bench=start_bench, check_servos=check_servos, release_servos=release_servos,
                    make_sensor=make_sensor, make_loop=make_loop, make_interface=DaemonInterface,
                    claim_devices=claim_devices)


def claim_devices(cfg: DaemonConfig) -> contextlib.AbstractContextManager:
    """The configured serial devices, claimed for this daemon's whole run (drivers/ports.py):
    a second daemon on the same servo bus or sensor tty stops here with one line, before it
    opens or writes anything. The simulated bench's ptys are the daemon's own; CAN channels
    (socketcan) are shared buses, and an slcan adapter is claimed by its serial port."""
    from admittance.drivers.ports import claim

    ports = [cfg.bus.port]
    if cfg.sensor.kind == "optoforce":
        ports.append(cfg.sensor.port)
    elif (cfg.sensor.kind, cfg.sensor.interface) == ("can", "slcan"):
        ports.append(cfg.sensor.port.partition("@")[0])  # python-can's "port@tty_baudrate"
    return claim(port for port in ports if port and port != MOCK_PORT)


@contextlib.contextmanager
def start_bench(cfg: DaemonConfig) -> Iterator[BenchPorts]:
    """Yield the ports: the configured devices, or the embedded simulated bench's."""
    if cfg.bus.port != MOCK_PORT:
        yield BenchPorts(cfg.bus.port, cfg.sensor.port, lambda: None)
        return
    bench, go = _make_bench(cfg)
    bench.start()
    try:
        # The stable links, as udev's by-id paths: a replugged pty comes back under another
        # number, and the loop's and the reader's reopens must find it.
        links = bench.links
        pty_sensor = links["sensor"] or bench.sensor_port
        sensor_port = pty_sensor or bench.can_channel if cfg.sensor.port == MOCK_PORT else cfg.sensor.port
        yield BenchPorts(links["bus"] or bench.bus_port, sensor_port, go, bench.stats, bench.bus)
    finally:
        bench.stop()


class DelayedHand:
    """A hand that keeps off the joint until :meth:`go`, then follows ``profile`` after ``delay``.

    The simulated user must not touch the sensor while it is tared, and a loaded machine can
    take seconds to get there, so the hand waits for the supervisor's word rather than a clock.
    """

    def __init__(self, profile: Any, delay: float) -> None:
        self.profile = profile
        self.delay = delay
        self._start: float | None = None
        self._last_t = 0.0

    def go(self) -> None:
        self._start = self._last_t + self.delay

    def __call__(self, t: float) -> float:
        self._last_t = t
        start = self._start
        return 0.0 if start is None or t < start else self.profile(t - start)


def _make_bench(cfg: DaemonConfig) -> tuple[Any, Callable[[], None]]:
    """The simulated bench matching the configuration: same IDs, models, plant files and sensor."""
    from admittance.mockbench.bench import BenchConfig, MockBench

    servos = [{"id": j.id, "model": j.model, "protocol": cfg.bus.protocol, "params_file": j.params}
              for j in cfg.joints]
    s, b = cfg.sensor, cfg.bench
    hand = (b.hand_inertia, b.hand_damping, b.hand_stiffness)
    bench = MockBench(BenchConfig(
        servos=servos, baudrate=cfg.bus.baudrate, profile=b.profile,
        sensor="can" if s.kind == "can" else "optoforce", lever_arm=first_lever_arm(cfg), axis=s.axis,
        counts_per_newton=list(s.counts_per_newton), noise_std_n=b.noise_std_n, can_id=s.can_id,
        hand=hand if any(hand) else None, first_order_lag=b.servo_lag_s or None,
        rt_priority=cfg.loop.rt_priority, sensor_stream=b.sensor_stream))  # the loop's scheduling: the mock is not late where a servo is not
    return bench, _hand_held_until_go(bench, cfg.bench.hand_delay_s)


def first_lever_arm(cfg: DaemonConfig) -> float:
    """The first joint's lever arm, where a simulated hand pushes: a loaded configuration gives
    every joint one, its own or [sensor].lever_arm (config.py), which is also the fallback."""
    lever_arm = cfg.joints[0].lever_arm
    return cfg.sensor.lever_arm if lever_arm is None else lever_arm


def _hand_held_until_go(bench: Any, delay: float) -> Callable[[], None]:
    """Holds the bench's hand off the joint; the returned ``go`` starts its profile after ``delay``."""
    from admittance.mockbench.simulated_sensor import NativeOptoForce

    sensor = bench.sensor
    if isinstance(sensor, NativeOptoForce):  # the stream's own clock, in Rust
        sensor.hold_hand()
        return lambda: sensor.start_hand(delay)
    hand = DelayedHand(bench.profile, delay)
    bench.profile = hand
    return hand.go


PTY_REPLY_WAIT_MS = 3000.0


def open_setup_bus(cfg: DaemonConfig, port: str, *, auto_recover: bool = True) -> ServoBus:
    """The configured bus, for setup transactions, with their waits for a reply.

    A pseudo-terminal is always a simulated bus: its servos are a thread of another process
    that a loaded machine may not schedule for tens of milliseconds, or seconds, unlike a
    servo's firmware. Setup is not time-critical, so there a reply is awaited up to
    ``PTY_REPLY_WAIT_MS``; and an instruction is never sent again: a pty loses no bytes, so a
    second copy would only put a second reply on the way, which the next instruction would
    take for its own (dynamixel.py, late replies). Hardware gets the driver's defaults (one
    more try: a reply can be lost to noise there).
    """
    from admittance.drivers.dynamixel import DEFAULT_REPLY_SLACK_MS, ServoBus

    pty = os.path.realpath(port).startswith("/dev/pts/")
    return ServoBus(port, baudrate=cfg.bus.baudrate, protocol=cfg.bus.protocol, auto_recover=auto_recover,
                    reply_slack_ms=PTY_REPLY_WAIT_MS if pty else DEFAULT_REPLY_SLACK_MS, retries=0 if pty else 1)


def check_servos(cfg: DaemonConfig, port: str) -> list[str]:
    """Ping and prepare every joint's servo, hold it where it is, torque on; return warnings.

    The goal is set to the present position before torque goes on, so the joint does not jump
    to whatever goal it held from a previous session. The SDK's port is closed on return: from
    then on the RT loop owns the tty.
    """
    warnings: list[str] = []
    with open_setup_bus(cfg, port, auto_recover=False) as bus:
        if bus.warning:
            warnings.append(bus.warning)
        for joint in cfg.joints:
            recover_under_policy(bus, joint.id, cfg)
            info = bus.prepare(joint.id)
            if info.model.lower() != joint.model.lower():
                raise DeviceError(f"servo {joint.id} on {port} is a {info.model}, but the configuration "
                                  f"says {joint.model} ([[joints]] model)")
            bus.write_raw(joint.id, "Goal Position", present_within_one_turn(bus, joint.id))
            bus.set_torque(joint.id, True)
    return warnings


def recover_under_policy(bus: Any, servo_id: int, cfg: DaemonConfig) -> None:
    """A servo that reports a hardware error at start is treated as in a run (docs/faults.md):
    rebooted only where that is safe and the policy says so, else the start stops with exit 69
    before torque goes on. (Protocol 1.0 has no REBOOT; ``prepare`` reports its alert.)"""
    from admittance import _rtcore
    from admittance.daemon.faults import causes
    from admittance.errors import EXIT_UNAVAILABLE, FaultStop

    if bus.protocol != 2 or bus.ping(servo_id) is None:
        return  # prepare() says what is wrong
    bits = bus.read_raw(servo_id, "Hardware Error Status", alert_ok=True)
    if not bits:
        return
    if bits & _rtcore.UNSAFE_HARDWARE_ERRORS:
        raise FaultStop(f"servo {servo_id} on {bus.port} reports {causes(bits)} at start: a reboot would clear the "
                        "error, not its cause; check the servo before starting again", EXIT_UNAVAILABLE,
                        "unsafe_hardware_error")
    if cfg.faults.servo_error == "stop":
        raise FaultStop(f"servo {servo_id} on {bus.port} reports {causes(bits)} at start and [faults].servo_error "
                        "is \"stop\"", EXIT_UNAVAILABLE, "servo_error_policy")
    bus.recover(servo_id)


CLEAR_TURNS_TIMEOUT_S = 5.0
RESULT_FAIL = 1  # the Protocol 2.0 status a servo gives CLEAR while its horn moves


def present_within_one_turn(bus: Any, servo_id: int) -> int:
    """The present tick, folded into the one turn that position mode's goal accepts.

    A horn turned past a revolution with torque off reports a multi-turn position; CLEAR folds
    it, but a servo only accepts CLEAR at rest, so a horn still coasting gets a few seconds.
    """
    from admittance.drivers.dynamixel import ServoStatusError

    present = bus.read_raw(servo_id, "Present Position")
    if 0 <= present < TICKS_PER_REV:
        return present
    deadline = time.monotonic() + CLEAR_TURNS_TIMEOUT_S
    while True:
        try:
            bus.clear_turns(servo_id)
            break
        except ServoStatusError as exc:
            if exc.code != RESULT_FAIL or time.monotonic() >= deadline:
                raise DeviceError(f"servo {servo_id} on {bus.port} is at tick {present}, more than one turn "
                                  f"from its goal range, and CLEAR failed ({exc}): hold the joint still and "
                                  "start again, or power-cycle the servo") from None
            time.sleep(0.05)
    present = bus.read_raw(servo_id, "Present Position")
    if not 0 <= present < TICKS_PER_REV:
        raise DeviceError(f"servo {servo_id} on {bus.port} still reports tick {present} after CLEAR; "
                          "power-cycle the servo")
    return present


def release_servos(cfg: DaemonConfig, port: str) -> None:
    """Torque off every joint (a start that failed after torque-on, with policy torque_off)."""
    with open_setup_bus(cfg, port) as bus:
        for joint in cfg.joints:
            bus.set_torque(joint.id, False)


def make_sensor(cfg: DaemonConfig, port: str, sink: GatedSink) -> ForceStream:
    """The configured sensor's reader, the Rust one or a Python ForceSensor (native_sensor.py
    chooses), streaming into ``sink`` once started."""
    from admittance.drivers.force_reader import create_sensor
    from admittance.drivers.native_sensor import NativeForceReader, choose_reader, reader_priority

    s = cfg.sensor
    section = {"kind": s.kind, "port": port, "counts_per_newton": list(s.counts_per_newton),
               "interface": s.interface, "can_id": s.can_id, "bitrate": s.bitrate, "channel": s.channel,
               "can_options": dict(s.can_options), "saturation": s.saturation}
    if s.kind == "mock":  # a scripted sensor in this process: it plays the [bench] hand itself
        section.update(lever_arm=first_lever_arm(cfg), axis=s.axis, profile=cfg.bench.profile,
                       noise_std_n=cfg.bench.noise_std_n)
    section["reader"] = s.reader
    if choose_reader(section) == "rust":  # no sample passes through Python (native_sensor.py)
        return NativeForceReader.from_config(section, sink, rt_priority=reader_priority(cfg.loop.rt_priority))
    return create_sensor(section, sink)


def make_loop(cfg: DaemonConfig, bus_port: str) -> AdmittanceLoop:
    from admittance import _rtcore

    try:
        return _rtcore.AdmittanceLoop(rt_loop_config(cfg, bus_port))
    except (ValueError, TypeError) as exc:  # the loop's own check of its configuration
        raise DeviceError(f"RT loop: {exc}") from None
