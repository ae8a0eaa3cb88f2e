"""The simulated bus's fault modes, seen by ROBOTIS's SDK and by our Rust client as a real servo
would show them: the alert bit and Hardware Error Status with the firmware's Shutdown, the P1
error byte, torque found off, a brown-out, REBOOT's silence, the overload detector, and the
adapter unplugged and plugged back in at the same path.

Waits are on the simulated state (wait_until), never on a duration; the only time-bounded
assumption is that this process gets one packet answered within a 1 s boot.
"""

from __future__ import annotations

import os
import termios

import pytest
import serial

sdk = pytest.importorskip("dynamixel_sdk")

from admittance import _rtcore  # noqa: E402
from admittance.errors import DeviceError  # noqa: E402

from helpers import MX64_PLANT, patient, sdk_on_mock_bus, wait_until  # noqa: E402

P2_TORQUE, P2_LED, P2_RDT, P2_HW_ERROR, P2_GOAL = 64, 65, 9, 70, 116
P1_TORQUE = 24
P2_SHUTDOWN_DEFAULT = 0x34  # MX(2.0): overheating, electrical shock, overload
P1_SHUTDOWN_DEFAULT = 0x24  # MX (1.0) Alarm Shutdown: overheating, overload


def servo(servo_id: int = 1, protocol: int = 2, **extra) -> dict:
    return {"id": servo_id, "model": "MX-64", "protocol": protocol, "params": dict(MX64_PLANT), **extra}


@pytest.fixture
def open_bus():
    """``open(servos, protocol=2)``: a started MockBus (replies at once) and an SDK port on it."""
    with sdk_on_mock_bus() as open_:
        yield lambda servos, protocol=2: open_(servos, protocol, wire_delay=False)


def ok(result: int, error: int = 0) -> None:
    assert result == sdk.COMM_SUCCESS and error == 0, (result, error)


@pytest.mark.parametrize("bits", [0x01, 0x04, 0x08, 0x10, 0x20], ids=["voltage", "overheating", "encoder", "shock", "overload"])
def test_p2_hardware_errors_raise_the_alert_and_the_shutdown_mask_turns_torque_off(open_bus, bits):
    bus, port, ph = open_bus([servo()])
    ok(*ph.write1ByteTxRx(port, 1, P2_TORQUE, 1))
    bus.set_hardware_error(1, bits)
    value, result, error = ph.read1ByteTxRx(port, 1, P2_HW_ERROR)
    assert (value, result, error) == (bits, sdk.COMM_SUCCESS, 0x80)
    shut_down = bool(bits & P2_SHUTDOWN_DEFAULT)
    # Torque Enable = 1 is taken (alert bit, no error number) and undone while the error stands.
    assert ph.write1ByteTxRx(port, 1, P2_TORQUE, 1) == (sdk.COMM_SUCCESS, 0x80)
    assert ph.read1ByteTxRx(port, 1, P2_TORQUE)[0] == (0 if shut_down else 1)
    assert bus.servo_state(1)["torque_enabled"] is not shut_down


@pytest.mark.parametrize(("bits", "on_the_wire"), [(0x01, 0x01), (0x04, 0x04), (0x20, 0x20), (0x18, 0x00)],
                         ids=["voltage", "overheating", "overload", "shock+encoder"])
def test_p1_error_bytes_carry_the_hardware_bits_and_alarm_shutdown_applies(open_bus, bits, on_the_wire):
    bus, port, ph = open_bus([servo(protocol=1)], protocol=1)
    ok(*ph.write1ByteTxRx(port, 1, P1_TORQUE, 1))
    bus.set_hardware_error(1, bits)
    value, result, error = ph.read1ByteTxRx(port, 1, P1_TORQUE)
    assert (result, error) == (sdk.COMM_SUCCESS, on_the_wire), "P1 has bits for voltage, overheating, overload only"
    assert value == (0 if bits & P1_SHUTDOWN_DEFAULT else 1)
    bus.set_hardware_error(1, 0)  # P1 has no REBOOT: the bits go when their cause does
    assert ph.read1ByteTxRx(port, 1, P1_TORQUE)[2] == 0


def test_torque_found_off_carries_no_error(open_bus):
    bus, port, ph = open_bus([servo()])
    ok(*ph.write1ByteTxRx(port, 1, P2_TORQUE, 1))
    bus.torque_off(1)
    assert ph.read1ByteTxRx(port, 1, P2_TORQUE) == (0, sdk.COMM_SUCCESS, 0)
    assert ph.read1ByteTxRx(port, 1, P2_HW_ERROR)[0] == 0


def test_a_brown_out_is_silence_then_a_servo_fresh_from_power_up(open_bus):
    bus, port, ph = open_bus([servo(), servo(2)])
    ok(*ph.write1ByteTxRx(port, 1, P2_RDT, 3))
    ok(*ph.write1ByteTxRx(port, 1, P2_TORQUE, 1))
    ok(*ph.write1ByteTxRx(port, 1, P2_LED, 1))
    bus.brown_out(1, 1.0)
    assert bus.servo_state(1)["silent"]
    assert ph.ping(port, 1)[1] == sdk.COMM_RX_TIMEOUT
    assert ph.ping(port, 2)[1] == sdk.COMM_SUCCESS, "only the browned-out servo reset"
    assert wait_until(lambda: ph.ping(port, 1)[1] == sdk.COMM_SUCCESS)
    assert ph.read1ByteTxRx(port, 1, P2_TORQUE)[0] == 0, "torque off"
    assert ph.read1ByteTxRx(port, 1, P2_LED)[0] == 0, "RAM back to its defaults"
    assert ph.read1ByteTxRx(port, 1, P2_RDT)[0] == 3, "EEPROM kept"
    assert bus.stats()["silent_drops"] >= 1


def test_the_overload_detector_shuts_a_stalled_servo_down(open_bus):
    bus, port, ph = open_bus([servo(overload_time_s=0.2)])
    ok(*ph.write4ByteTxRx(port, 1, P2_GOAL, 2048 + 1000))  # far: the duty saturates
    bus.set_external_torque(1, -4.7)  # a hand holding the horn against the motor's 4.74 N·m
    ok(*ph.write1ByteTxRx(port, 1, P2_TORQUE, 1))
    assert wait_until(lambda: bus.servo_state(1)["hardware_error"] == 0x20)
    assert ph.read1ByteTxRx(port, 1, P2_TORQUE) == (0, sdk.COMM_SUCCESS, 0x80)


def test_unplug_and_replug_at_the_same_link_for_the_sdk(tmp_path):
    link = str(tmp_path / "ttyDXL")
    bus = _rtcore.MockBus(servos=[servo()], wire_delay=False, link_path=link)
    with bus:
        assert os.path.realpath(link) == bus.port_path
        first_pty = bus.port_path
        port = patient(sdk.PortHandler(link))
        assert port.openPort()
        ph = sdk.PacketHandler(2.0)
        ok(*ph.write1ByteTxRx(port, 1, P2_TORQUE, 1))
        assert bus.unplug() and not bus.plugged
        assert not os.path.exists(link) and not os.path.exists(first_pty), "the device node is gone"
        with pytest.raises((serial.SerialException, termios.error)) as err:  # the SDK flushes first
            ph.ping(port, 1)
        assert "Input/output error" in str(err.value), "EIO on the hung-up descriptor"
        port.closePort()
        assert bus.replug() and bus.plugged
        assert os.path.realpath(link) == bus.port_path
        port = patient(sdk.PortHandler(link))
        assert port.openPort()
        assert ph.read1ByteTxRx(port, 1, P2_TORQUE)[:2] == (1, sdk.COMM_SUCCESS), "the servo kept its power"
        port.closePort()
        assert (bus.stats()["unplugs"], bus.stats()["replugs"]) == (1, 1)
    del bus
    assert not os.path.exists(link)


def test_the_rust_client_sees_alert_brown_out_and_unplug(tmp_path):
    link = str(tmp_path / "ttyDXL")
    bus = _rtcore.MockBus(servos=[servo()], wire_delay=False, link_path=link)
    with bus:
        client = _rtcore.DxlClient(link, 1_000_000, 2, 0.25)
        bus.set_hardware_error(1, 0x04)
        assert client.write(1, P2_TORQUE, b"\x01") is True, "a status with the alert bit"
        assert client.read(1, P2_HW_ERROR, 1) == b"\x04"
        client.reboot(1)
        assert wait_until(lambda: _answers(client))
        assert client.read(1, P2_HW_ERROR, 1) == b"\x00"
        bus.brown_out(1, 1.0)
        with pytest.raises(DeviceError, match="no reply from servo 1"):
            client.ping(1)
        assert wait_until(lambda: _answers(client))
        bus.unplug()
        with pytest.raises(DeviceError):
            client.ping(1)
        client.close()
        bus.replug()
        client = _rtcore.DxlClient(link, 1_000_000, 2, 0.25)
        assert client.ping(1)["model_number"] == 311
        client.close()


def _answers(client) -> bool:
    try:
        client.ping(1)
    except DeviceError:
        return False
    return True
