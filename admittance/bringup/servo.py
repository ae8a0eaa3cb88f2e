"""Change a servo's ID, baud rate or operating mode, safely.

Each change is an EEPROM write. On Protocol 2.0 EEPROM is locked while torque is on, and a
servo that changes ID or baud rate under torque would hold or drop the arm unpredictably, so
torque goes off first, always. Each change is then verified the only way that counts: the servo
answers again at the new setting and reads the new value back. A new ID that another servo
already answers is refused before anything is written (two servos with one ID answer every
packet at once, and neither can then be reached alone).
"""

from __future__ import annotations

from admittance.drivers.dynamixel import MAX_ID, ServoBus, ServoInfo
from admittance.errors import ConfigError, DeviceError

# Operating modes by name: Protocol 2.0's Operating Mode values, and Protocol 1.0's angle limits
# (CW, CCW), which select its mode.
P2_MODES = {"current": 0, "velocity": 1, "position": 3, "extended-position": 4, "current-position": 5, "pwm": 16}
P1_MODES = {"wheel": (0, 0), "position": (0, 4095), "multi-turn": (4095, 4095)}


def change_id(bus: ServoBus, old: int, new: int) -> ServoInfo:
    """Give the servo at ``old`` the ID ``new``; returns what answers at ``new``."""
    if not 0 <= new <= MAX_ID[bus.protocol]:
        raise ConfigError(f"a Protocol {bus.protocol}.0 ID is 0..{MAX_ID[bus.protocol]}, not {new}")
    before = _present(bus, old)
    if new == old:
        return before
    if bus.ping(new) is not None:
        raise ConfigError(f"ID {new} is already taken on this bus: give servo {old} a free ID")
    bus.set_torque(old, False)
    bus.write_raw(old, "ID", new)
    after = bus.ping(new)
    if after is None or after.model_number != before.model_number:
        raise DeviceError(f"servo {old} did not answer at its new ID {new}: scan the bus (admittance setup --scan)")
    if bus.ping(old) is not None:
        raise DeviceError(f"ID {old} still answers after the change to {new}: two servos may share it")
    return after


def change_baudrate(port: str, protocol: int, servo_id: int, old: int, new: int, **bus_options) -> ServoInfo:
    """Move the servo ``servo_id`` from ``old`` to ``new`` bit/s; verified at the new rate."""
    from admittance import _rtcore

    code = _rtcore.baud_code(protocol, new)
    if code is None:
        raise ConfigError(f"{new} bit/s is not a rate Protocol {protocol}.0 firmware can be set to")
    with ServoBus(port, baudrate=new, protocol=protocol, **bus_options) as bus:
        # Whoever answers there reports its own rate: the new one is another servo; the old one is
        # this servo heard through a link that ignores baud rates (a pseudo-terminal).
        if old != new and bus.ping(servo_id) is not None and bus.read_raw(servo_id, "Baud Rate") == code:
            raise ConfigError(f"ID {servo_id} already answers at {new} bit/s: change one of the two IDs first")
    with ServoBus(port, baudrate=old, protocol=protocol, **bus_options) as bus:
        _present(bus, servo_id)
        bus.set_torque(servo_id, False)
        if old != new:
            bus.write_raw(servo_id, "Baud Rate", code)
    with ServoBus(port, baudrate=new, protocol=protocol, **bus_options) as bus:
        info = bus.ping(servo_id)
        if info is None or bus.read_raw(servo_id, "Baud Rate") != code:
            raise DeviceError(f"servo {servo_id} did not answer at {new} bit/s after the change: it may still be at "
                              f"{old} (scan the bus with admittance setup --scan)")
        return info


def set_mode(bus: ServoBus, servo_id: int, mode: str) -> None:
    """Set the operating mode by name (P2_MODES / P1_MODES), torque off first; verified by reading back."""
    modes = P2_MODES if bus.protocol == 2 else P1_MODES
    if mode not in modes:
        raise ConfigError(f"Protocol {bus.protocol}.0 modes are {', '.join(modes)}, not {mode!r}")
    _present(bus, servo_id)
    bus.set_torque(servo_id, False)
    wanted = {"Operating Mode": modes[mode]} if bus.protocol == 2 else dict(zip(("CW Angle Limit", "CCW Angle Limit"), modes[mode]))
    for item, value in wanted.items():
        bus.write_raw(servo_id, item, value)
    got = {item: bus.read_raw(servo_id, item) for item in wanted}
    if got != wanted:
        raise DeviceError(f"servo {servo_id} reads back {got} after setting {wanted}")


def _present(bus: ServoBus, servo_id: int) -> ServoInfo:
    info = bus.ping(servo_id)
    if info is None:
        raise DeviceError(f"servo {servo_id} does not answer on {bus.port} at {bus.baudrate} bit/s, "
                          f"Protocol {bus.protocol}.0")
    return info
