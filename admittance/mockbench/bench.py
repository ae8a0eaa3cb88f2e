"""``MockBench``: a whole simulated test bench, servos and force sensor, on pseudo-terminals.

The servos are the simulated Dynamixel bus of the Rust core (``_rtcore.MockBus``, Contract 4):
each one is a plant (Contract 1) with the fitted parameters of its model, read from
the packaged ``params/<model>.toml`` (Contract 2), so the mock moves as the identified servo does.
An *effect* (``cogging_amplitude=0.02``...) changes the simulated truth without changing the
configuration the daemon reads: that is how a test checks what an unmodelled effect does to
the loop, or whether identification finds it.

The force sensor is a :mod:`admittance.mockbench.simulated_sensor` mock. One hand-torque profile drives
both: the hand pushes on the sensor mounted on the horn, so at each sensor sample the same τ(t)
goes to the sensor (as F = τ / lever_arm) and to the horn (``bus.set_external_torque``). Doing
both in the sensor's thread keeps them consistent without a second 1 kHz thread.

Two options change the simulated truth for fidelity checks (docs/fidelity.md): ``hand`` =
(inertia, damping, stiffness) makes the hand grip the horn, so the sensor reads the torque it
transmits (the profile is then the muscle's torque), and a servo's ``first_order_lag`` (s)
replaces its firmware and motor by a horn that lags its goal.

Stable paths: a pty's number changes when it is unplugged and replugged, so the bench also
offers each pty at a symlink in a directory of its own (``links``: ``<dir>/dxl`` and
``<dir>/sensor``), re-pointed at every replug and removed while unplugged, as udev's
/dev/serial/by-id links behave for a real adapter. Faults are injected with the bus's and the
sensor's methods or with :meth:`MockBench.command` (:mod:`admittance.mockbench.faults`).
"""

from __future__ import annotations

import shutil
import weakref
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from admittance.errors import ConfigError, DeviceError
from admittance.mockbench.hand import Profile, make_profile
from admittance.mockbench.link_dirs import new_link_dir
from admittance.mockbench.simulated_sensor import (
    DEFAULT_COUNTS_PER_NEWTON,
    ForceModel,
    NativeOptoForce,
    SimulatedCanOptoForce,
    SimulatedOptoForce,
    SimulatedSlcanOptoForce,
)

SENSOR_CORRECTIONS = frozenset({"torque_gain", "torque_bias", "torque_drift"})
SIMULATED_SENSOR_KINDS = ("optoforce", "can", "slcan")  # slcan: the CAN frames through a simulated USB-CAN adapter on a pty
SENSOR_STREAMS = ("rust", "python")  # the OptoForce sensor's stream (the CAN ones are Python's)
# Per-servo keys handed to MockBus unchanged (motor constants of models without built-in ones,
# start angle, register presets...).
MOCKBUS_PASSTHROUGH_KEYS = ("kt", "resistance", "input_voltage", "initial_theta", "ambient_temperature", "registers", "name",
                            "reboot_time_s", "overload_time_s", "first_order_lag")


@dataclass
class BenchConfig:
    """What to simulate. ``servos`` is a count (IDs 1..N, all ``model``/``protocol``) or a list
    of per-servo tables with keys id, model, protocol, params_file, load_inertia, gravity_torque
    (and any of MOCKBUS_PASSTHROUGH_KEYS)."""

    servos: int | Sequence[Mapping[str, Any]] = 1
    model: str = "MX-64"
    protocol: int = 2
    params_file: str | None = None
    effects: Mapping[str, float] = field(default_factory=dict)
    load_inertia: float = 0.0
    gravity_torque: float = 0.0
    baudrate: int = 1_000_000
    wire_delay: bool = True
    profile: str = "push-release"
    hand_servo_id: int | None = None  # default: the first servo
    sensor: str = "optoforce"
    sensor_rate_hz: float = 1000.0
    lever_arm: float = 0.105
    axis: str = "x"
    counts_per_newton: float | Sequence[float] = DEFAULT_COUNTS_PER_NEWTON
    noise_std_n: float = 0.0
    bias_n: float = 0.0
    can_interface: str = "virtual"
    can_channel: str = "admittance-mock"
    can_id: int = 0x100
    seed: int = 0
    # A hand gripping the horn: (inertia kg·m², damping N·m·s/rad, stiffness N·m/rad); None = a pure torque.
    hand: tuple[float, float, float] | None = None
    first_order_lag: float | None = None  # s: every servo lags its goal instead of firmware + motor
    # The bus thread's SCHED_FIFO priority (0 = SCHED_OTHER; None = MockBus's default, the RT
    # loop's): the simulated servos must not answer late where real ones never would.
    rt_priority: int | None = None
    # The OptoForce sensor's stream: "rust" (a thread of the simulated bus's crate, at the bus's
    # priority: never waits for the interpreter) or "python" (any callable profile, scripted live).
    sensor_stream: str = "rust"


def params_path(model: str) -> Path:
    """The shipped fit of ``model``: params/<model>.toml in the package (MX-64 → mx64.toml)."""
    from admittance import data

    return data.params_file(model)


def load_plant(model: str, params_file: str | None, effects: Mapping[str, float]) -> tuple[dict[str, float], str]:
    """The fitted parameters and friction law of ``model`` (Contract 2), ``effects`` laid over them."""
    from admittance.formats import paramfile

    path = Path(params_file) if params_file else params_path(model)
    if not path.is_file():
        raise ConfigError(f"no fitted parameters for {model}: {path} does not exist (give one with --params FILE)")
    fitted = paramfile.load(path)
    # A fitted file may carry corrections of the *torque sensor* it was fitted with (gain, bias,
    # drift); they describe that measurement, not the horn, so the simulated servo drops them.
    params = {k: v for k, v in fitted["params"].items() if k not in SENSOR_CORRECTIONS}
    params.update(paramfile.validate_params(dict(effects), where="mock-bench effect"))
    return params, str(fitted["model"].get("friction", "stick"))


def servo_specs(config: BenchConfig) -> list[dict[str, Any]]:
    """The servo tables handed to ``_rtcore.MockBus`` (Contract 4)."""
    if isinstance(config.servos, int):
        if not 1 <= config.servos <= 252:
            raise ConfigError(f"the mock bench has 1..252 servos, not {config.servos}")
        wanted: Sequence[Mapping[str, Any]] = [{"id": i} for i in range(1, config.servos + 1)]
    else:
        wanted = config.servos
    specs = [_servo_spec(servo, config) for servo in wanted]
    ids = [s["id"] for s in specs]
    if len(set(ids)) != len(ids):
        raise ConfigError(f"servo IDs must be unique, got {ids}")
    return specs


def _servo_spec(servo: Mapping[str, Any], config: BenchConfig) -> dict[str, Any]:
    model = servo.get("model", config.model)
    params, friction = load_plant(model, servo.get("params_file", config.params_file), config.effects)
    extra = {key: servo[key] for key in MOCKBUS_PASSTHROUGH_KEYS if key in servo}
    if config.first_order_lag is not None:
        extra.setdefault("first_order_lag", config.first_order_lag)
    return extra | {
        "id": int(servo["id"]),
        "model": model,
        "protocol": int(servo.get("protocol", config.protocol)),
        "params": params,
        "friction": friction,
        "load_inertia": float(servo.get("load_inertia", config.load_inertia)),
        "gravity_torque": float(servo.get("gravity_torque", config.gravity_torque)),
    }


class MockBench:
    """The simulated bench; ``with MockBench() as bench:`` starts it and stops it.

    ``profile`` (the hand, any ``t -> τ`` callable) may be replaced while the bench runs: it
    is read at every sensor sample. ``bus`` is the ``_rtcore.MockBus`` (``servo_state``,
    ``set_hardware_error``...) and ``sensor`` the simulated sensor.
    """

    def __init__(self, config: BenchConfig | None = None, **options: Any):
        if config is not None and options:
            raise ConfigError(f"give MockBench a BenchConfig or options, not both ({', '.join(options)})")
        try:
            self.config = config or BenchConfig(**options)
        except TypeError as exc:
            raise ConfigError(f"MockBench: {exc}") from None
        cfg = self.config
        if cfg.sensor not in SIMULATED_SENSOR_KINDS:
            raise ConfigError(f"the mock bench's sensor is one of {', '.join(SIMULATED_SENSOR_KINDS)}, not '{cfg.sensor}'")
        specs = servo_specs(cfg)
        self.servo_ids = [s["id"] for s in specs]
        self.hand_servo_id = cfg.hand_servo_id if cfg.hand_servo_id is not None else self.servo_ids[0]
        if self.hand_servo_id not in self.servo_ids:
            raise ConfigError(f"the hand pushes on servo {self.hand_servo_id}, which is not on the bus {self.servo_ids}")
        if cfg.sensor_stream not in SENSOR_STREAMS:
            raise ConfigError(f"the mock bench's sensor_stream is one of {', '.join(SENSOR_STREAMS)}, not '{cfg.sensor_stream}'")
        self._profile: Profile = make_profile(cfg.profile)
        self.force_model = ForceModel(
            lever_arm=cfg.lever_arm,
            axis=cfg.axis,
            counts_per_newton=_per_axis(cfg.counts_per_newton),
            bias_n=cfg.bias_n,
            noise_std_n=cfg.noise_std_n,
        )
        self._link_dir = new_link_dir()
        # Also when the bench is never stopped (a lockstep bench only lends its bus) and is
        # collected, or at the interpreter's exit: stop() runs it early, once.
        self._remove_link_dir = weakref.finalize(self, shutil.rmtree, self._link_dir, ignore_errors=True)
        try:
            self.bus = _mock_bus(specs, cfg.baudrate, cfg.wire_delay, f"{self._link_dir}/dxl", cfg.rt_priority)
            if cfg.hand is not None:
                try:
                    self.bus.set_hand(self.hand_servo_id, *cfg.hand)
                except (TypeError, ValueError) as exc:
                    raise ConfigError(f"MockBench: hand: {exc}") from None
            self.sensor = self._make_sensor()
        except BaseException:
            self._remove_link_dir()
            raise
        self._running = False

    def _make_sensor(self) -> SimulatedOptoForce | SimulatedCanOptoForce | SimulatedSlcanOptoForce:
        cfg = self.config
        link = f"{self._link_dir}/sensor"
        if cfg.sensor == "slcan":
            return SimulatedSlcanOptoForce(
                self._hand_torque, self.force_model, can_id=cfg.can_id, rate_hz=cfg.sensor_rate_hz, seed=cfg.seed, link=link
            )
        if cfg.sensor == "can":
            return SimulatedCanOptoForce(
                self._hand_torque,
                self.force_model,
                channel=cfg.can_channel,
                interface=cfg.can_interface,
                can_id=cfg.can_id,
                rate_hz=cfg.sensor_rate_hz,
                seed=cfg.seed,
            )
        if cfg.sensor_stream == "rust":
            return NativeOptoForce(self.bus, self.hand_servo_id, self._profile, self.force_model,
                                   rate_hz=cfg.sensor_rate_hz, seed=cfg.seed, link=link, rt_priority=cfg.rt_priority)
        return SimulatedOptoForce(self._hand_torque, self.force_model, rate_hz=cfg.sensor_rate_hz, seed=cfg.seed, link=link)

    @property
    def profile(self) -> Profile:
        """The hand: read at every sensor sample, so it may be replaced while the bench runs."""
        return self._profile

    @profile.setter
    def profile(self, profile: Profile) -> None:
        if isinstance(self.sensor, NativeOptoForce):
            self.sensor.set_profile(profile)
        self._profile = profile

    def _hand_torque(self, t: float) -> float:
        """The torque the sensor reads: the profile's, or with a gripping hand what it transmits."""
        tau = self._profile(t)
        self.bus.set_external_torque(self.hand_servo_id, tau)
        if self.config.hand is None:
            return tau
        return self.bus.servo_state(self.hand_servo_id)["hand_torque"]

    @property
    def bus_port(self) -> str:
        return self.bus.port_path

    @property
    def sensor_port(self) -> str | None:
        """The sensor's pty (None with the CAN sensor on python-can; the adapter's with slcan)."""
        return getattr(self.sensor, "port_path", None)

    @property
    def can_interface(self) -> str | None:
        """The python-can interface that reads the sensor (None with the serial sensor)."""
        return {"can": self.config.can_interface, "slcan": "slcan"}.get(self.config.sensor)

    @property
    def can_channel(self) -> str | None:
        """The python-can channel of the CAN sensor (None with the serial sensor)."""
        return {"can": self.config.can_channel, "slcan": self.sensor_port}.get(self.config.sensor)

    def start(self) -> None:
        if self._running:
            return
        try:
            self.bus.start()
            self.sensor.start()
        except BaseException:
            self.stop()  # a `with` block whose start fails never reaches __exit__
            raise
        self._running = True

    def stop(self) -> None:
        """Stop the sensor and the bus; the bench cannot be started again (its ptys are closed).
        The links' folder goes whatever the stops raise."""
        self._running = False
        try:
            self.sensor.stop()
            self.bus.stop()
        finally:
            self._remove_link_dir()

    @property
    def links(self) -> dict[str, str | None]:
        """The stable paths of the bus and the sensor (None for a sensor without a pty)."""
        return {"bus": self.bus.link_path, "sensor": getattr(self.sensor, "link_path", None)}

    def command(self, line: str) -> dict[str, Any]:
        """Run one fault command (:mod:`admittance.mockbench.faults`); its reply."""
        from admittance.mockbench.faults import run_command

        return run_command(self, line)

    def __enter__(self) -> MockBench:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def ports(self, links: bool = False) -> dict[str, Any]:
        """The JSON object that ``admittance mock-bench --print-ports`` prints (``links``: with
        the stable paths too, as it does when faults can be injected)."""
        ports: dict[str, Any] = {"bus": self.bus_port, "sensor": self.sensor_port}
        if links:
            ports["links"] = self.links
        if self.can_interface is not None:
            ports["can"] = {"interface": self.can_interface, "channel": self.can_channel, "can_id": self.config.can_id}
        return ports

    def stats(self) -> dict[str, Any]:
        """The bus's counters and its thread's timing (``MockBus.timing``: how late it ran, its
        scheduling), and the sensor's counters."""
        return {"bus": {**self.bus.stats(), "timing": self.bus.timing()}, "sensor": self.sensor.stats()}


def _per_axis(counts_per_newton: float | Sequence[float]) -> tuple[float, ...]:
    if isinstance(counts_per_newton, int | float):
        return (float(counts_per_newton),) * 3
    return tuple(float(c) for c in counts_per_newton)


def _mock_bus(specs: list[dict[str, Any]], baudrate: int, wire_delay: bool, link: str, rt_priority: int | None) -> Any:
    from admittance import _rtcore

    if not hasattr(_rtcore, "MockBus"):
        raise DeviceError("this build of admittance._rtcore has no MockBus: rebuild it with `make ext`")
    priority = {} if rt_priority is None else {"rt_priority": rt_priority}
    try:
        return _rtcore.MockBus(servos=specs, baudrate=baudrate, wire_delay=wire_delay, link_path=link, **priority)
    except (ValueError, TypeError, KeyError) as exc:
        raise ConfigError(f"the simulated bus refused the servos: {exc}") from None
