"""sd_notify over a real AF_UNIX datagram socket (a filesystem path and an abstract name)."""

from __future__ import annotations

import os
import socket
import uuid
from collections.abc import Iterator

import pytest

from pdcov.service.systemd_notify import SystemdNotifier


@pytest.fixture
def receiver(tmp_path) -> Iterator[tuple[socket.socket, str]]:
    path = str(tmp_path / "notify")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    sock.settimeout(2.0)
    try:
        yield sock, path
    finally:
        sock.close()


def test_unset_is_a_no_op() -> None:
    n = SystemdNotifier({})
    assert not n.enabled
    assert n.watchdog_interval_s is None
    assert n.ready("starting") is False
    assert n.watchdog() is False
    n.close()


def test_ready_status_watchdog_stopping_reach_the_socket(receiver) -> None:
    sock, path = receiver
    n = SystemdNotifier({"NOTIFY_SOCKET": path})
    try:
        assert n.enabled
        assert n.ready("coverage 0.0 %")
        assert sock.recv(4096) == b"READY=1\nSTATUS=coverage 0.0 %"
        assert n.watchdog()
        assert sock.recv(4096) == b"WATCHDOG=1"
        assert n.status("two\nlines")
        assert sock.recv(4096) == b"STATUS=two lines"
        assert n.stopping()
        assert sock.recv(4096) == b"STOPPING=1"
    finally:
        n.close()


def test_abstract_socket_name() -> None:
    name = f"pdcov-test-{uuid.uuid4().hex}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.settimeout(2.0)
    n = SystemdNotifier({"NOTIFY_SOCKET": "@" + name})
    try:
        sock.bind("\0" + name)
        assert n.ready()
        assert sock.recv(4096) == b"READY=1"
    finally:
        n.close()
        sock.close()


def test_send_failure_returns_false_without_raising(tmp_path) -> None:
    n = SystemdNotifier({"NOTIFY_SOCKET": str(tmp_path / "nobody-listens")})
    try:
        assert n.enabled
        assert n.watchdog() is False
    finally:
        n.close()


@pytest.mark.parametrize(
    ("env", "interval_s"),
    [
        ({"WATCHDOG_USEC": "20000000"}, 10.0),
        ({"WATCHDOG_USEC": "20000000", "WATCHDOG_PID": str(os.getpid())}, 10.0),
        ({"WATCHDOG_USEC": "20000000", "WATCHDOG_PID": "1"}, None),  # meant for another process
        ({"WATCHDOG_USEC": "0"}, None),
        ({"WATCHDOG_USEC": "soon"}, None),
    ],
)
def test_watchdog_interval_is_half_the_timeout(env, interval_s) -> None:
    assert SystemdNotifier(env).watchdog_interval_s == interval_s
