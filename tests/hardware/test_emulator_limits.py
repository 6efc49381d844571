"""The emulators' servers against local abuse (issue 37): a TCP client that connects and says nothing
is disconnected after the idle timeout, a flood of newcomers never holds up the accept loop, and the
MJPEG server holds a bounded number of connections, each with a request timeout."""

from __future__ import annotations

import socket
import time

import pytest
from twin.hardware.bh262.emulator import make_hand_emulator
from twin.hardware.cameras import emulator as camera_emulator
from twin.hardware.cameras.emulator import MAX_CONNECTIONS, CameraEmulator
from twin.hardware.emulation import BUSY_REPLY

HANG_GUARD_S = 30.0


def _connect(url: str) -> socket.socket:
    host, port = url.removeprefix("socket://").split(":")
    sock = socket.create_connection((host, int(port)), timeout=HANG_GUARD_S)
    return sock


def _prompt(sock: socket.socket) -> bytes:
    """A CR, and what the hand answers until its prompt (served: b'=> ')."""
    sock.sendall(b"\r")
    got = b""
    while b"=> " not in got:
        chunk = sock.recv(4096)
        if not chunk:
            break
        got += chunk
    return got


def _until_closed(sock: socket.socket) -> bytes:
    got = b""
    while chunk := sock.recv(4096):
        got += chunk
    return got


def test_a_silent_client_is_disconnected_and_the_next_one_served():
    with make_hand_emulator(None) as emulator:
        emulator.idle_timeout_s = 0.5
        url = emulator.serve_tcp(0)
        silent = _connect(url)
        assert _until_closed(silent) == b""  # hung up after its idle time, having sent nothing
        silent.close()
        with _connect(url) as client:
            assert b"=> " in _prompt(client)


def test_a_flood_of_newcomers_is_refused_without_holding_up_the_next_client():
    """Fifty connections that never read while a client holds the hand: each is refused (or closed)
    at once, not after a grace each, and the next client after the first leaves is served."""
    with make_hand_emulator(None) as emulator:
        url = emulator.serve_tcp(0)
        first = _connect(url)
        assert b"=> " in _prompt(first)
        flood = [_connect(url) for _ in range(50)]
        deadline = time.monotonic() + HANG_GUARD_S
        for sock in flood:
            sock.settimeout(max(0.1, deadline - time.monotonic()))
            reply = _until_closed(sock)
            assert reply in (BUSY_REPLY, b""), reply
            sock.close()
        first.close()
        with _connect(url) as client:
            assert b"=> " in _prompt(client)


@pytest.fixture
def cameras():
    hand = make_hand_emulator("block", stereo=True)
    emulator = CameraEmulator(hand.twin)
    try:
        left, _ = emulator.serve_http()
        yield emulator, left
    finally:
        emulator.close()
        hand.close()


def test_the_mjpeg_server_bounds_its_connections_and_times_idle_ones_out(cameras, monkeypatch):
    emulator, left = cameras
    monkeypatch.setattr(camera_emulator._Handler, "timeout", 1.0)
    host, port = left.removeprefix("http://").split("/")[0].split(":")
    idle = [
        socket.create_connection((host, int(port)), timeout=HANG_GUARD_S) for _ in range(3 * MAX_CONNECTIONS)
    ]
    try:
        # every connection is closed: those beyond the limit at once, the admitted ones after the
        # request timeout (none of them sent a request)
        for sock in idle:
            assert _until_closed(sock) == b""
        # a handler thread releases its place just after it closes the socket: every place comes back
        deadline = time.monotonic() + HANG_GUARD_S
        while emulator._server._admitted and time.monotonic() < deadline:
            time.sleep(0.01)
        assert emulator._server._admitted == 0
    finally:
        for sock in idle:
            sock.close()
    with socket.create_connection((host, int(port)), timeout=HANG_GUARD_S) as sock:  # still serving
        sock.sendall(b"GET /left.mjpg HTTP/1.0\r\n\r\n")
        assert sock.recv(64).startswith(b"HTTP/1.0 200")
