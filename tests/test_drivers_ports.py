"""Messages for devices that cannot be opened."""

from __future__ import annotations

import errno

import pytest
import serial

from admittance.drivers.ports import open_error_message


@pytest.mark.parametrize(
    ("code", "hint"),
    [(errno.ENOENT, "is it plugged in"), (errno.EACCES, "dialout"), (errno.EBUSY, "busy")],
)
def test_usual_causes_get_their_fix(code, hint):
    exc = serial.SerialException(code, "could not open port /dev/ttyUSB0: [Errno …]")
    message = open_error_message("the Dynamixel port", "/dev/ttyUSB0", exc)
    assert message.startswith("cannot open the Dynamixel port /dev/ttyUSB0: ") and hint in message
    assert message.count("/dev/ttyUSB0") == 1


def test_other_errors_keep_their_own_text():
    exc = serial.SerialException("Could not configure port: (25, 'Inappropriate ioctl for device')")
    assert open_error_message("the port", "/dev/null", exc).endswith("Inappropriate ioctl for device')")
