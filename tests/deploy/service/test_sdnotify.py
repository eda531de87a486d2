"""systemd notifications against a real AF_UNIX datagram socket (no systemd needed)."""

import os
import socket
import uuid

import pytest

from deploy.service.sdnotify import Notifier


@pytest.fixture
def listener(tmp_path):
    """A datagram socket standing in for systemd's notification socket."""
    path = tmp_path / "notify.sock"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(path))
    sock.settimeout(2.0)
    yield str(path), sock
    sock.close()


def received(sock) -> str:
    return sock.recv(4096).decode("utf-8")


def test_every_message_arrives(listener):
    path, sock = listener
    n = Notifier(environ={"NOTIFY_SOCKET": path})
    assert n.enabled
    assert n.ready("identifying the payload; 4 bags")
    assert received(sock) == "READY=1\nSTATUS=identifying the payload; 4 bags"
    assert n.ready()
    assert received(sock) == "READY=1"
    assert n.status("controller silent: writes stopped")
    assert received(sock) == "STATUS=controller silent: writes stopped"
    assert n.watchdog()
    assert received(sock) == "WATCHDOG=1"
    assert n.stopping()
    assert received(sock) == "STOPPING=1"
    n.close()
    n.close()  # twice is fine


def test_abstract_socket_address():
    name = f"iem-test-{uuid.uuid4().hex}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind("\0" + name)
    sock.settimeout(2.0)
    try:
        n = Notifier(environ={"NOTIFY_SOCKET": "@" + name})
        assert n.watchdog()
        assert received(sock) == "WATCHDOG=1"
        n.close()
    finally:
        sock.close()


def test_without_notify_socket_everything_is_a_no_op():
    n = Notifier(environ={})
    assert not n.enabled
    assert n.watchdog_period() is None
    assert not any([n.ready("x"), n.status("x"), n.watchdog(), n.stopping(),
                    n.notify("ANYTHING=1")])
    n.close()


def test_a_socket_that_is_gone_returns_false_and_never_raises(tmp_path):
    n = Notifier(environ={"NOTIFY_SOCKET": str(tmp_path / "gone.sock")})
    assert n.enabled and n.ready() is False and n.watchdog() is False
    n.close()


@pytest.mark.parametrize(("env", "period"), [
    ({"WATCHDOG_USEC": "5000000"}, 2.5),
    ({"WATCHDOG_USEC": "5000000", "WATCHDOG_PID": str(os.getpid())}, 2.5),
    ({"WATCHDOG_USEC": "5000000", "WATCHDOG_PID": str(os.getpid() + 1)}, None),  # not us
    ({"WATCHDOG_USEC": "0"}, None),
    ({"WATCHDOG_USEC": "soon"}, None),
    ({}, None),
])
def test_watchdog_period_is_half_of_watchdog_usec(env, period):
    assert Notifier(environ=env).watchdog_period() == period
