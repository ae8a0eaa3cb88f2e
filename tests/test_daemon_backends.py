"""The daemon's servo checks (admittance.daemon.backends) against the simulated bus: a horn
turned past a revolution with torque off is folded back into one turn before torque goes on."""

from __future__ import annotations

import pytest

from admittance import _rtcore
from admittance.daemon import backends
from admittance.daemon.config import parse_config
from admittance.drivers.force_reader import SampleBuffer
from admittance.errors import DeviceError

from helpers import wait_until

PLANT = {"motor_inertia": 0.0147, "damping": 0.0347, "coulomb": 0.0843}


@pytest.fixture
def turned_bus():
    """One MX-64 (Protocol 2.0) whose horn sits more than a turn from the centre tick."""
    bus = _rtcore.MockBus(servos=[{"id": 1, "model": "MX-64", "protocol": 2, "params": PLANT, "initial_theta": 7.0}],
                          baudrate=1_000_000, wire_delay=True)
    bus.start()
    yield bus
    bus.stop()


def _config(tmp_path, port: str):
    doc = {"bus": {"port": port}, "joints": [{"id": 1, "model": "MX-64"}],
           "sensor": {"kind": "optoforce", "port": "/dev/null", "lever_arm": 0.1}}
    return parse_config(doc, tmp_path / "daemon.toml")


def test_a_multi_turn_position_is_folded_before_the_goal_is_set(tmp_path, turned_bus):
    assert turned_bus.servo_state(1)["present_tick"] > 4095
    assert backends.check_servos(_config(tmp_path, turned_bus.port_path), turned_bus.port_path) == []
    state = turned_bus.servo_state(1)
    assert 0 <= state["goal_tick"] <= 4095
    assert state["torque_enabled"] and abs(state["present_tick"] - state["goal_tick"]) <= 2  # no jump


def test_a_horn_that_keeps_spinning_is_one_clear_error(tmp_path, turned_bus, monkeypatch):
    monkeypatch.setattr(backends, "CLEAR_TURNS_TIMEOUT_S", 0.2)
    turned_bus.set_external_torque(1, 1.0)
    assert wait_until(lambda: turned_bus.servo_state(1)["omega"] > 1.0)
    with pytest.raises(DeviceError, match=r"servo 1 on .* more than one turn .* hold the joint still") as err:
        backends.check_servos(_config(tmp_path, turned_bus.port_path), turned_bus.port_path)
    assert "\n" not in str(err.value)
    assert not turned_bus.servo_state(1)["torque_enabled"]


def _sensor_config(tmp_path, bus: str, sensor: dict):
    doc = {"bus": {"port": bus}, "joints": [{"id": 1, "model": "MX-64"}],
           "sensor": {"lever_arm": 0.1, **sensor}}
    return parse_config(doc, tmp_path / "daemon.toml")


@pytest.mark.parametrize(("bus", "sensor", "claimed"), [
    ("/dev/ttyDXL", {"kind": "optoforce", "port": "/dev/ttyOPTO"}, ["/dev/ttyDXL", "/dev/ttyOPTO"]),
    ("/dev/ttyDXL", {"kind": "can", "interface": "slcan", "port": "/dev/ttyCAN@3000000"}, ["/dev/ttyDXL", "/dev/ttyCAN"]),
    ("/dev/ttyDXL", {"kind": "can", "interface": "socketcan", "port": "can0"}, ["/dev/ttyDXL"]),
    ("mock", {"kind": "optoforce", "port": "mock"}, []),
], ids=["optoforce", "slcan", "socketcan", "bench"])
def test_the_daemon_claims_its_serial_devices_only(tmp_path, monkeypatch, bus, sensor, claimed):
    from admittance.drivers import ports

    monkeypatch.setenv(ports.LOCK_DIR_ENV, str(tmp_path))
    with backends.claim_devices(_sensor_config(tmp_path, bus, sensor)) as held:
        assert held.paths == [ports.lock_path(p, tmp_path) for p in claimed]


def test_the_saturation_policy_reaches_the_reader(tmp_path):
    for policy in ("hold", "pass"):
        cfg = _sensor_config(tmp_path, "mock", {"kind": "optoforce", "port": "/dev/null", "saturation": policy,
                                                "reader": "python"})
        reader = backends.make_sensor(cfg, "/dev/null", SampleBuffer())
        assert reader._converter.hold_saturated is (policy == "hold")
        # The Rust reader (the default): the policy reaches it (tests/test_rust_sensor.py runs both).
        cfg = _sensor_config(tmp_path, "mock", {"kind": "optoforce", "port": "/dev/null", "saturation": policy})
        rust = backends.make_sensor(cfg, "/dev/null", None)
        assert rust.reader_path == "rust-serial" and rust.saturation == policy


def test_the_embedded_bench_runs_its_bus_thread_at_the_loops_priority():
    """The simulated servos must not answer late where real ones would not: their thread asks
    for the RT loop's SCHED_FIFO priority (or says why it did not get it)."""
    import tomllib

    from admittance import data
    from admittance.daemon.config import parse_config as parse

    doc = tomllib.loads(data.bench_config().read_text())
    doc.setdefault("loop", {})["rt_priority"] = 7
    bench, _hand = backends._make_bench(parse(doc, data.bench_config()))
    bench.start()
    try:
        assert wait_until(lambda: bench.bus.timing()["wake_late_us"]["count"] > 0), "the bus thread never ran"
        rt, warnings = bench.bus.timing()["rt"], bench.bus.timing()["warnings"]
    finally:
        bench.stop()
    assert (rt["policy"], rt["priority"]) == ("SCHED_FIFO", 7) or any("SCHED_FIFO" in w for w in warnings), (rt, warnings)


class AlertingBus:
    """A ServoBus stand-in for the start-up check: one servo reporting ``bits``."""

    def __init__(self, bits: int, protocol: int = 2):
        self.bits, self.protocol, self.port, self.recovered = bits, protocol, "/dev/fake", []

    def ping(self, servo_id):
        return object()

    def read_raw(self, servo_id, name, alert_ok=False):
        assert name == "Hardware Error Status" and alert_ok
        return self.bits

    def recover(self, servo_id):
        self.recovered.append(servo_id)


@pytest.mark.parametrize(("bits", "policy", "outcome"), [
    (0x00, "reboot", "nothing"),
    (0x20, "reboot", "rebooted"),  # an overload: safe to reboot
    (0x01, "reboot", "rebooted"),
    (0x10, "reboot", "unsafe_hardware_error"),  # electrical shock: never rebooted
    (0x04, "reboot", "unsafe_hardware_error"),  # overheating
    (0x20, "stop", "servo_error_policy"),
])
def test_a_servo_in_error_at_start_is_treated_by_the_policy_before_torque(tmp_path, bits, policy, outcome):
    """docs/faults.md: rebooted where safe and allowed, else exit 69 before torque goes on."""
    from admittance.errors import EXIT_UNAVAILABLE, FaultStop

    doc = {"bus": {"port": "/dev/fake"}, "joints": [{"id": 1, "model": "MX-64"}],
           "sensor": {"kind": "optoforce", "port": "/dev/null", "lever_arm": 0.1}, "faults": {"servo_error": policy}}
    cfg = parse_config(doc, tmp_path / "daemon.toml")
    bus = AlertingBus(bits)
    if outcome in ("nothing", "rebooted"):
        backends.recover_under_policy(bus, 1, cfg)
        assert bus.recovered == ([1] if outcome == "rebooted" else [])
    else:
        with pytest.raises(FaultStop) as caught:
            backends.recover_under_policy(bus, 1, cfg)
        assert (caught.value.cause, caught.value.exit_code, bus.recovered) == (outcome, EXIT_UNAVAILABLE, [])
    p1 = AlertingBus(0x10, protocol=1)
    backends.recover_under_policy(p1, 1, cfg)  # Protocol 1.0: prepare() reports the alert instead
    assert p1.recovered == []
