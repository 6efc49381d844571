"""What every device emulator shares: fault specs, the two ends of a port, serving on a pty, a TCP
port or an in-process socket pair, and the pyserial URL handler that starts one in process.

An emulator subclasses `PortServer` and answers one connection in `_session(link)`; the serving,
the threads and the clean-up are here once.
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
import threading
import time
import tty
import urllib.parse
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from serial.serialutil import SerialException
from serial.urlhandler import protocol_socket

from twin.interface.errors import ConfigError


@dataclass(frozen=True)
class Fault:
    """One fault on the N-th reply or frame (1-based) of a session."""

    kind: str
    at: int
    arg: float | None = None


def parse_faults(spec: str | None, kinds: Mapping[str, str]) -> dict[int, Fault]:
    """Parse `KIND@N[:ARG],...`; kinds maps each KIND to "none", "optional" or "required" (its ARG).

    ConfigError (one line) on anything malformed.
    """
    if not spec:
        return {}
    faults: dict[int, Fault] = {}
    for item in spec.split(","):
        kind, _, rest = item.strip().partition("@")
        at, _, arg = rest.partition(":")
        if kind not in kinds or not at.isdigit() or int(at) < 1:
            known = ", ".join(kinds)
            raise ConfigError(f"--faults: bad item {item!r}: want KIND@N[:ARG], KIND one of {known}")
        try:
            value = float(arg) if arg else None
        except ValueError:
            raise ConfigError(f"--faults: bad argument in {item!r}") from None
        if value is None and kinds[kind] == "required":
            raise ConfigError(f"--faults: {kind} needs an argument ({kind}@N:VALUE)")
        if value is not None and kinds[kind] == "none":
            raise ConfigError(f"--faults: {item!r}: {kind} takes no argument")
        if value is not None and value < 0:
            raise ConfigError(f"--faults: {item!r}: the argument must be >= 0")
        faults[int(at)] = Fault(kind, int(at), value)
    return faults


class Link:
    """The device's end of one connection: a pty master descriptor or a connected socket."""

    def __init__(self, fd: int | None = None, sock: socket.socket | None = None) -> None:
        self.fd, self.sock = fd, sock
        self._closed = threading.Lock()

    def fileno(self) -> int:
        """For select()."""
        return self.sock.fileno() if self.sock is not None else self.fd

    def read(self) -> bytes | None:
        """Bytes waiting; b"" when the peer is gone; None when nothing was there after all."""
        try:
            return self.sock.recv(4096) if self.sock is not None else os.read(self.fd, 4096)
        except (BlockingIOError, InterruptedError):
            return None
        except OSError:
            return b""

    def peer_gone(self) -> bool:
        """Whether the far end of a socket has closed (host bytes are read and dropped; a pty never is)."""
        if self.sock is None:
            return False
        try:
            return bool(select.select([self.sock], [], [], 0)[0]) and self.sock.recv(4096) == b""
        except OSError:
            return True

    def write(self, data: bytes, deadline: float | None = None) -> bool:
        """Write all of data (by the deadline, if one is given); False if the host stopped reading."""
        if self.sock is not None:
            self.sock.settimeout(None if deadline is None else max(0.01, deadline - time.monotonic()))
            try:
                self.sock.sendall(data)
            except TimeoutError:
                return False
            return True
        view = memoryview(data)
        while view:
            try:
                view = view[os.write(self.fd, view) :]
            except BlockingIOError:
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    return False
                if not select.select([], [self.fd], [], left)[1]:
                    return False
        return True

    def close(self) -> None:
        """Close once (a descriptor closed twice may be someone else's by then)."""
        if not self._closed.acquire(blocking=False):
            return
        if self.sock is not None:
            with contextlib.suppress(OSError):
                self.sock.shutdown(socket.SHUT_RDWR)
            self.sock.close()
        elif self.fd is not None:
            close_fd(self.fd)


def close_fd(fd: int) -> None:
    """Close a descriptor, ignoring one that is already gone."""
    with contextlib.suppress(OSError):
        os.close(fd)


class PortServer:
    """Serves `_session(link)` on a pty, a TCP port (one client at a time) or a socket pair.

    `_session` returns how the session ended: "closed" (the peer left), "stopped" (close() was
    called) or "vanished" (a fault took the port away: the pty or the listening socket closes too).
    """

    thread_name = "emulator"

    def __init__(self, on_event: Callable[[str], None] | None = None) -> None:
        self.on_event = on_event or (lambda _msg: None)
        self.stop_event = threading.Event()
        self.address: str | None = None
        self._threads: list[threading.Thread] = []
        self._closers: list[Callable[[], None]] = []

    def _session(self, link: Link) -> str:
        raise NotImplementedError

    def _on_first_start(self) -> None:
        """Called before the first port is served (e.g. start the twin's clock)."""

    def _on_close(self) -> None:
        """Called after every port is closed."""

    def _start(self, target: Callable[[], None]) -> None:
        if not self._threads:
            self._on_first_start()
        thread = threading.Thread(target=target, name=self.thread_name, daemon=True)
        thread.start()
        self._threads.append(thread)

    def serve_pty(self) -> str:
        """Open a pseudo-terminal and answer on it; returns the device path to open.

        The emulator keeps the terminal's far end open, so clients may come and go on it.
        """
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        path = os.ttyname(slave)
        link = Link(fd=master)

        def close_pty() -> None:
            link.close()
            close_fd(slave)  # the device node goes away with the last descriptor

        self._closers.append(close_pty)

        def run() -> None:
            outcome = self._session(link)
            self.on_event(f"pty session ended: {outcome}")
            close_pty()

        self._start(run)
        self.address = path
        return path

    def serve_tcp(self, port: int = 0, host: str = "127.0.0.1") -> str:
        """Listen on host:port (0 picks a free port); returns socket://host:port."""
        server = socket.create_server((host, port))
        server.settimeout(0.1)
        self._closers.append(server.close)

        def run() -> None:
            while not self.stop_event.is_set():
                try:
                    conn, peer = server.accept()
                except TimeoutError:
                    continue
                except OSError:
                    return
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                self.on_event(f"client {peer[0]}:{peer[1]} connected")
                link = Link(sock=conn)
                outcome = self._session(link)
                link.close()
                self.on_event(f"client left: {outcome}")
                if outcome == "vanished":
                    server.close()
                    return

        self._start(run)
        self.address = f"socket://{host}:{server.getsockname()[1]}"
        return self.address

    def serve_socketpair(self) -> socket.socket:
        """An in-process connection (the emulators' URLs): returns the host's end."""
        host_end, device_end = socket.socketpair()
        link = Link(sock=device_end)

        def run() -> None:
            self._session(link)
            link.close()

        self._start(run)
        return host_end

    def close(self) -> None:
        """Stop answering and release the ports."""
        self.stop_event.set()
        for thread in self._threads:
            thread.join(timeout=2.0)
        for closer in self._closers:
            closer()
        self._on_close()

    def __enter__(self) -> PortServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class EmulatorPort(protocol_socket.Serial):
    """A pyserial port whose far end is a fresh in-process emulator (`scheme://?key=value&...`).

    Subclasses name the scheme and the parameters and build the emulator from the query.
    """

    scheme = ""
    parameters: frozenset[str] = frozenset()

    def _make_emulator(self, query: dict[str, str]) -> PortServer:
        raise NotImplementedError

    def from_url(self, url: str) -> dict[str, str]:
        """The query parameters of the URL; SerialException for another scheme or an unknown key."""
        parts = urllib.parse.urlsplit(url)
        if parts.scheme != self.scheme:
            raise SerialException(f"expected a {self.scheme}:// URL, got {url!r}")
        query = dict(urllib.parse.parse_qsl(parts.query))
        unknown = set(query) - self.parameters
        if unknown:
            raise SerialException(f"{url}: unknown parameter(s) {', '.join(sorted(unknown))}")
        return query

    def open(self) -> None:
        """Start the emulator and connect to it."""
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        if self.is_open:
            raise SerialException("Port is already open.")
        self.logger = None
        try:
            self.emulator = self._make_emulator(self.from_url(self.portstr))
        except (ValueError, KeyError) as exc:  # ConfigError is a ValueError
            raise SerialException(f"{self.portstr}: {exc}") from None
        self._socket = self.emulator.serve_socketpair()
        self._socket.setblocking(False)
        self._reconfigure_port()
        self.is_open = True
        self.reset_input_buffer()

    def close(self) -> None:
        """Close the connection and stop the emulator (without the 0.3 s pause of socket://)."""
        if self.is_open:
            sock, self._socket = self._socket, None
            if sock is not None:
                with contextlib.suppress(OSError):
                    sock.shutdown(socket.SHUT_RDWR)
                sock.close()
            self.is_open = False
        emulator = getattr(self, "emulator", None)
        if emulator is not None:
            emulator.close()
            self.emulator = None
