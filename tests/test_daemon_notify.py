"""sd_notify over a real AF_UNIX datagram socket, and a watchdog that follows the loop's heartbeat."""

from __future__ import annotations

import os
import socket
import uuid

import pytest

from admittance.daemon.notify import Notifier, Watchdog


@pytest.fixture
def notify_socket(tmp_path):
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    path = str(tmp_path / "notify")
    sock.bind(path)
    sock.settimeout(2.0)
    yield path, sock
    sock.close()


def received(sock: socket.socket) -> list[str]:
    out = []
    sock.setblocking(False)
    try:
        while True:
            out.append(sock.recv(4096).decode())
    except BlockingIOError:
        pass
    finally:
        sock.settimeout(2.0)
    return out


def test_ready_status_and_stopping_reach_the_socket(notify_socket):
    path, sock = notify_socket
    notifier = Notifier({"NOTIFY_SOCKET": path})
    assert notifier.ready("running at 1000 Hz")
    assert sock.recv(4096) == b"READY=1\nSTATUS=running at 1000 Hz"
    assert notifier.status("holding")
    assert sock.recv(4096) == b"STATUS=holding"
    assert notifier.stopping()
    assert sock.recv(4096) == b"STOPPING=1"


def test_abstract_socket_names_start_with_at():
    name = f"admittance-test-{uuid.uuid4().hex}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind("\0" + name)
    sock.settimeout(2.0)
    try:
        assert Notifier({"NOTIFY_SOCKET": "@" + name}).ready()
        assert sock.recv(4096) == b"READY=1"
    finally:
        sock.close()


def test_without_systemd_nothing_is_sent_and_nothing_fails(tmp_path):
    assert not Notifier({}).ready()
    assert not Notifier({"NOTIFY_SOCKET": str(tmp_path / "gone")}).ready()  # systemd went away


class Clock:
    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


def test_watchdog_pings_at_half_period_only_while_the_heartbeat_advances(notify_socket):
    path, sock = notify_socket
    notifier = Notifier({"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "2000000"})
    beat, clock = [0], Clock()
    dog = Watchdog(notifier, lambda: beat[0], clock)
    assert dog.enabled and dog.interval_s == 1.0
    pinged = []
    for step in range(40):  # 4 s in 0.1 s steps; the loop stalls from 2 s on
        clock.now = step * 0.1
        if clock.now < 2.0:
            beat[0] += 100
        pinged.append(dog.poll())
    messages = received(sock)
    assert messages and set(messages) == {"WATCHDOG=1"}
    assert len(messages) == dog.pings == sum(pinged)
    assert not any(pinged[21:])  # stalled heartbeat: no more pings
    assert dog.missed >= 1
    assert 2 <= dog.pings <= 3  # one per second while alive, not one per poll


def test_watchdog_is_off_without_watchdog_usec_or_for_another_pid(notify_socket):
    path, _ = notify_socket
    assert not Watchdog(Notifier({"NOTIFY_SOCKET": path}), lambda: 1).poll()
    other = Notifier({"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "1000000", "WATCHDOG_PID": str(os.getpid() + 1)})
    assert other.watchdog_usec == 0
    assert Notifier({"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "x"}).watchdog_usec == 0


def test_a_reader_that_does_not_read_never_blocks_the_sender(notify_socket):
    path, _ = notify_socket
    notifier = Notifier({"NOTIFY_SOCKET": path})
    results = [notifier.status(f"line {i}") for i in range(200)]  # far beyond the datagram queue
    assert results[0] and not all(results)
