"""Messages for devices that cannot be opened."""

from __future__ import annotations

import errno

import pytest
import serial

from admittance.drivers.ports import open_error_message


@pytest.mark.parametrize(
    ("code", "hint"),
    [(errno.ENOENT, "is it plugged in"), (errno.EACCES, "dialout"), (errno.EBUSY, "busy"), (errno.EAGAIN, "another daemon")],
)
def test_usual_causes_get_their_fix(code, hint):
    exc = serial.SerialException(code, "could not open port /dev/ttyUSB0: [Errno …]")
    message = open_error_message("the Dynamixel port", "/dev/ttyUSB0", exc)
    assert message.startswith("cannot open the Dynamixel port /dev/ttyUSB0: ") and hint in message
    assert message.count("/dev/ttyUSB0") == 1


def test_other_errors_keep_their_own_text():
    exc = serial.SerialException("Could not configure port: (25, 'Inappropriate ioctl for device')")
    assert open_error_message("the port", "/dev/null", exc).endswith("Inappropriate ioctl for device')")


# -- the claim and the exclusive open ------------------------------------------------------------

import fcntl  # noqa: E402
import os  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import textwrap  # noqa: E402

from admittance.drivers import ports  # noqa: E402
from admittance.errors import DeviceError  # noqa: E402


@pytest.fixture
def lock_dir(tmp_path, monkeypatch):
    monkeypatch.setenv(ports.LOCK_DIR_ENV, str(tmp_path / "locks"))
    (tmp_path / "locks").mkdir()
    return tmp_path / "locks"


def test_a_second_claim_on_a_device_fails_in_one_line_naming_the_holder(lock_dir, tmp_path):
    device = tmp_path / "ttyDXL"
    device.touch()
    with ports.claim([str(device)]) as held:
        assert held.paths == [lock_dir / ports.lock_path(str(device)).name]
        assert held.paths[0].read_text().strip() == str(os.getpid())
        with pytest.raises(DeviceError) as err, ports.claim(["", str(device)]):
            pass
    message = str(err.value)
    assert "\n" not in message and str(device) in message and f"pid {os.getpid()}" in message
    with ports.claim([str(device)]):  # released on leaving the block
        pass


def test_an_alias_of_a_claimed_device_collides_with_it(lock_dir, tmp_path):
    device = tmp_path / "ttyUSB0"
    device.touch()
    (tmp_path / "by-id").mkdir()
    alias = tmp_path / "by-id" / "usb-FTDI_adapter"
    alias.symlink_to(device)
    with ports.claim([str(alias)]) as held:
        assert len(held.paths) == 2, "the alias and the device it resolves to"
        with pytest.raises(DeviceError, match="ttyUSB0: another admittance daemon"), ports.claim([str(device)]):
            pass


def test_a_claim_held_by_another_process_names_its_pid(lock_dir, tmp_path):
    device = tmp_path / "ttyACM0"
    device.touch()
    holder = subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(f"""
            import sys
            from admittance.drivers import ports
            with ports.claim([{str(device)!r}]):
                print("held", flush=True)
                sys.stdin.read()
        """)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(DeviceError, match=f"pid {holder.pid}"), ports.claim([str(device)]):
            pass
    finally:
        holder.communicate("", timeout=30)
    with ports.claim([str(device)]):  # the holder exited: its flock went with it
        pass


def test_the_lock_holder_of_a_device_node_is_read_from_proc_locks(tmp_path):
    device = tmp_path / "ttyS9"
    device.touch()
    assert ports.lock_holder(str(device)) is None
    with open(device) as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        assert ports.lock_holder(str(device)) == os.getpid()
        message = open_error_message("the sensor port", str(device), OSError(11, "Resource temporarily unavailable"))
    assert message == (f"cannot open the sensor port {device}: the device is busy: another process has it open "
                       f"(pid {os.getpid()}); is another daemon running on it?")
    assert ports.lock_holder(str(tmp_path / "absent")) is None


def test_the_lock_directory_falls_back_when_the_first_choice_is_not_writable(tmp_path, monkeypatch):
    monkeypatch.setenv(ports.LOCK_DIR_ENV, str(tmp_path / "missing"))
    monkeypatch.setattr(ports, "SYSTEM_LOCK_DIR", str(tmp_path / "also-missing"))
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    assert ports.lock_dir() == tmp_path


def test_nothing_to_claim_needs_no_lock_directory(monkeypatch, tmp_path):
    monkeypatch.setenv(ports.LOCK_DIR_ENV, str(tmp_path / "missing"))
    monkeypatch.setattr(ports, "SYSTEM_LOCK_DIR", str(tmp_path / "missing"))
    monkeypatch.delenv("XDG_RUNTIME_DIR", raising=False)
    monkeypatch.setattr(ports.tempfile, "gettempdir", lambda: str(tmp_path / "missing"))
    with ports.claim(["", ""]) as held:
        assert held.paths == []
    with pytest.raises(DeviceError, match="no writable directory"), ports.claim(["/dev/ttyUSB0"]):
        pass
