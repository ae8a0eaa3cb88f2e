"""Dynamixel setup (ServoBus, dynamixel-sdk) against the simulated bus, both protocols."""

from __future__ import annotations

import functools

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from admittance import _rtcore
from admittance.drivers import control_table
from admittance.drivers.dynamixel import ServoAlert, ServoError, ServoStatusError, decode_hardware_error
from admittance.drivers.dynamixel import ServoBus as _ServoBus
from admittance.errors import ConfigError, DeviceError

from helpers import examples, wait_until

PLANT = {"motor_inertia": 0.0147, "damping": 0.0347, "coulomb": 0.0843}
# The test machine is shared and loaded: give the simulated bus's replies a generous deadline.
SLACK_MS = 200.0

ServoBus = functools.partial(_ServoBus, reply_slack_ms=SLACK_MS)


def _bus(servos: list[tuple[int, str, int]]):
    specs = [{"id": i, "model": m, "protocol": p, "params": PLANT} for i, m, p in servos]
    bus = _rtcore.MockBus(servos=specs, baudrate=1_000_000, wire_delay=True)
    bus.start()
    return bus


@pytest.fixture
def p2_bus():
    bus = _bus([(1, "MX-64", 2), (2, "MX-28", 2), (5, "MX-106", 2)])
    yield bus
    bus.stop()


@pytest.fixture
def p1_bus():
    bus = _bus([(1, "MX-64", 1), (4, "MX-28", 1)])
    yield bus
    bus.stop()


def test_broadcast_scan_finds_every_servo_and_its_model(p2_bus):
    with ServoBus(p2_bus.port_path) as servos:
        found = servos.scan()
    assert [(s.id, s.model, s.model_number, s.protocol) for s in found] == [
        (1, "MX-64", 311, 2),
        (2, "MX-28", 30, 2),
        (5, "MX-106", 321, 2),
    ]


def test_a_scan_over_an_id_range_pings_each_id(p1_bus):
    with ServoBus(p1_bus.port_path, protocol=1) as servos:
        found = servos.scan(range(0, 6))
    assert [(s.id, s.model, s.model_number) for s in found] == [(1, "MX-64", 310), (4, "MX-28", 29)]
    assert all(s.firmware is not None for s in found)


def test_prepare_sets_rdt_zero_and_position_mode_with_torque_off(p2_bus):
    with ServoBus(p2_bus.port_path) as servos:
        servos.set_torque(1, True)
        info = servos.prepare(1)
        assert info.model == "MX-64"
        assert servos.read_raw(1, "Return Delay Time") == 0
        assert servos.read(1, "Return Delay Time") == 0.0
        assert servos.read_raw(1, "Operating Mode") == 3
        assert servos.read_raw(1, "Torque Enable") == 0
        servos.set_torque(1, True)
        assert p2_bus.register(1, "Torque Enable") == 1


def test_a_servo_already_set_up_gets_no_eeprom_write_and_keeps_its_torque(p2_bus):
    with ServoBus(p2_bus.port_path) as servos:
        servos.prepare(1)  # first start: RDT 250 -> 0 written, torque went off
        servos.set_torque(1, True)
        servos.prepare(1)  # restart: nothing differs, so no EEPROM write turns torque off
        assert servos.read_raw(1, "Torque Enable") == 1
    assert p2_bus.register(1, "Torque Enable") == 1


def test_protocol_1_uses_the_angle_limits_for_joint_mode(p1_bus):
    with ServoBus(p1_bus.port_path, protocol=1) as servos:
        servos.write_raw(4, "CCW Angle Limit", 0)  # wheel mode
        servos.write_raw(4, "CW Angle Limit", 0)
        servos.prepare(4)
        assert (servos.read_raw(4, "CW Angle Limit"), servos.read_raw(4, "CCW Angle Limit")) == (0, 4095)
        assert servos.read_raw(4, "Return Delay Time") == 0


def test_items_are_read_and_written_in_si_units(p2_bus):
    with ServoBus(p2_bus.port_path) as servos:
        servos.write(1, "Return Delay Time", 100e-6)
        assert servos.read_raw(1, "Return Delay Time") == 50
        assert servos.read(1, "Present Position") == pytest.approx(p2_bus.register(1, "Present Position") * 2 * 3.141592653589793 / 4096)
        assert servos.read(1, "Present Input Voltage") == pytest.approx(p2_bus.register(1, "Present Input Voltage") / 10)


def test_an_alert_is_read_and_the_servo_rebooted(p2_bus):
    with ServoBus(p2_bus.port_path) as servos:
        servos.prepare(1)
        servos.set_torque(1, True)
        p2_bus.set_hardware_error(1, 0x20)  # overload: the servo shuts down
        assert servos.hardware_error(1) == ["overload"]
        servos.read(1, "Present Position")  # alert seen, recovered, retried
        assert servos.hardware_error(1) == []
        assert servos.read_raw(1, "Torque Enable") == 0  # a reboot leaves torque off


def test_without_auto_recover_the_alert_is_raised_with_its_causes(p2_bus):
    with ServoBus(p2_bus.port_path, auto_recover=False) as servos:
        p2_bus.set_hardware_error(2, 0x04 | 0x01)
        with pytest.raises(ServoAlert, match="input voltage, overheating") as caught:
            servos.set_torque(2, True)
        assert caught.value.causes == ["input voltage", "overheating"]
        with pytest.raises(ServoAlert):
            servos.prepare(2)
        assert servos.recover(2) == ["input voltage", "overheating"]
        servos.prepare(2)


def test_protocol_1_alerts_are_reported_because_there_is_no_reboot(p1_bus):
    with ServoBus(p1_bus.port_path, protocol=1) as servos:
        p1_bus.set_hardware_error(1, 0x20)
        with pytest.raises(ServoAlert, match="overload.*no REBOOT"):
            servos.read(1, "Present Position")
        with pytest.raises(ServoError, match="no REBOOT"):
            servos.reboot(1)


def test_servo_errors_are_typed(p2_bus):
    with ServoBus(p2_bus.port_path) as servos:
        with pytest.raises(TimeoutError, match="servo 9 did not answer"):
            servos.read(9, "Present Position")
        assert servos.ping(9) is None
        servos.set_torque(1, True)
        with pytest.raises(ServoStatusError, match="Access Error"):
            servos.write_raw(1, "Operating Mode", 3)  # EEPROM while torque is on
        with pytest.raises(ConfigError, match="read-only"):
            servos.write_raw(1, "Present Position", 0)
        with pytest.raises(ConfigError, match="outside its range"):
            servos.write_raw(1, "Return Delay Time", 300)
        with pytest.raises(ConfigError, match="no control-table item 'Goal Torque'"):
            servos.read(1, "Goal Torque")


def test_clear_folds_a_multi_turn_position_into_one_turn_at_rest_only():
    bus = _rtcore.MockBus(servos=[{"id": 1, "model": "MX-64", "protocol": 2, "params": PLANT, "initial_theta": 7.0}],
                          baudrate=1_000_000, wire_delay=True)
    bus.start()
    try:
        with ServoBus(bus.port_path) as servos:
            before = servos.read_raw(1, "Present Position")
            assert before > 4095  # more than a turn from the centre tick
            servos.clear_turns(1)
            assert servos.read_raw(1, "Present Position") == before - 4096
            bus.set_external_torque(1, 1.0)  # a hand spins the torque-free horn
            assert wait_until(lambda: bus.servo_state(1)["omega"] > 1.0)
            with pytest.raises(ServoStatusError, match="Result Fail"):
                servos.clear_turns(1)
    finally:
        bus.stop()


def test_protocol_1_has_no_clear(p1_bus):
    with ServoBus(p1_bus.port_path, protocol=1) as servos, pytest.raises(DeviceError, match="no CLEAR"):
        servos.clear_turns(1)


def test_a_missing_port_is_a_device_error_naming_the_path():
    with pytest.raises(DeviceError, match="/dev/ttyUSB_absent"):
        ServoBus("/dev/ttyUSB_absent")


def test_model_numbers_map_to_the_shared_table():
    assert control_table.table_for_number(1, 310).name == "MX-64"
    assert control_table.table_for_number(2, 1020).name == "XM430-W350"
    with pytest.raises(DeviceError, match="model number 999"):
        control_table.table_for_number(2, 999)
    assert decode_hardware_error(0x3D) == ["input voltage", "overheating", "motor encoder", "electrical shock", "overload"]


@pytest.mark.parametrize(
    ("text", "raw", "si"),
    [
        ("pulse", 1024, 3.141592653589793 / 2),
        ("0.229 rev/min", -10, -10 * 0.229 * 2 * 3.141592653589793 / 60),
        ("2 us", 250, 500e-6),
        ("0.1 V", 120, 12.0),
        ("0.11 rev/min, bit 10 = CW", 1024 + 100, -100 * 0.11 * 2 * 3.141592653589793 / 60),
        ("4.5 mA, 2048 = 0", 2048 + 200, 0.9),
        ("", 7, 7.0),
    ],
)
def test_units_convert_both_ways(text, raw, si):
    unit = control_table.Unit.parse(text)
    assert unit.to_si(raw) == pytest.approx(si)
    assert unit.from_si(si) == raw



def _ranged_items():
    tables = control_table._tables().values()  # noqa: SLF001 - every model of the shared table
    return [item for t in tables for item in t.items.values() if item.minimum is not None]


@settings(max_examples=examples(400))
@given(item=st.sampled_from(_ranged_items()), fraction=st.floats(0.0, 1.0))
def test_every_ranged_item_round_trips_through_si_units(item, fraction):
    raw = round(item.minimum + fraction * (item.maximum - item.minimum))
    si = item.unit.to_si(raw)
    # Compared in SI: a sign-magnitude "-0" (bit 10 alone) and 0 are the same value.
    assert item.unit.to_si(item.unit.from_si(si)) == si
    assert item.decode(item.encode(raw)) == raw
