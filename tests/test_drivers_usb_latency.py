"""The FTDI latency-timer check: a fake sysfs tree, symlinked ports, and ports without a timer."""

from __future__ import annotations

import os

import pytest

from admittance.drivers import usb_latency


@pytest.fixture
def sysfs(tmp_path):
    def make(tty: str, value: str):
        d = tmp_path / "sys" / "bus" / "usb-serial" / "devices" / tty
        d.mkdir(parents=True)
        (d / "latency_timer").write_text(value + "\n")

    return tmp_path / "sys", make


def test_a_16ms_timer_gives_the_fix(sysfs):
    root, make = sysfs
    make("ttyUSB0", "16")
    warning = usb_latency.latency_warning("/dev/ttyUSB0", sysfs_root=root)
    assert "16 ms" in warning
    assert f"echo 1 | sudo tee {root}/bus/usb-serial/devices/ttyUSB0/latency_timer" in warning
    assert usb_latency.UDEV_RULE in warning


def test_a_1ms_timer_is_fine(sysfs):
    root, make = sysfs
    make("ttyUSB3", "1")
    assert usb_latency.read_latency_timer("/dev/ttyUSB3", sysfs_root=root) == 1
    assert usb_latency.latency_warning("/dev/ttyUSB3", sysfs_root=root) is None


def test_symlinks_are_resolved_to_the_tty(sysfs, tmp_path):
    root, make = sysfs
    make("ttyUSB7", "16")
    link = tmp_path / "dev" / "serial" / "by-id" / "usb-FTDI_U2D2-if00-port0"
    link.parent.mkdir(parents=True)
    os.symlink(tmp_path / "dev" / "ttyUSB7", link)
    assert usb_latency.latency_timer_path(str(link), sysfs_root=root).parent.name == "ttyUSB7"
    assert "16 ms" in usb_latency.latency_warning(str(link), sysfs_root=root)


def test_a_pty_has_no_timer_and_nothing_is_said():
    master, slave = os.openpty()
    try:
        path = os.ttyname(slave)
        assert usb_latency.read_latency_timer(path) is None
        assert usb_latency.latency_warning(path) is None
    finally:
        os.close(master)
        os.close(slave)
