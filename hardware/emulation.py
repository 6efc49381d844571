"""What every device emulator shares: fault specs, the two ends of a port, serving on a pty, a TCP
port or an in-process socket pair, and the pyserial URL handler that starts one in process.

An emulator subclasses `PortServer` and answers one connection in `_session(link)`; the serving,
the threads and the clean-up are here once.
"""

from __future__ import annotations

import contextlib
import math
import os
import re
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


@dataclass(frozen=True)
class FaultArg:
    """What a fault kind takes after `:`: nothing (need "none"), or a finite number in [low, high]
    that may be left out ("optional") or not ("required"); `integer` asks for a whole number."""

    need: str = "none"
    low: float = 0.0
    high: float = 0.0
    integer: bool = False
    unit: str = ""

    def describe(self) -> str:
        """The accepted range in words, for the error message."""
        kind = "an integer" if self.integer else "a number"
        unit = f" {self.unit}" if self.unit else ""
        return f"{kind} in [{self.low:g}, {self.high:g}]{unit}"


NO_ARG = FaultArg()
MAX_FAULT_AT = 1_000_000_000
"""The highest reply or frame number a fault may name (about a year of replies at 30 Hz)."""
_AT = re.compile(r"[0-9]{1,10}")


def parse_faults(
    spec: str | None, kinds: Mapping[str, FaultArg], option: str = "--faults"
) -> dict[int, Fault]:
    """Parse `KIND@N[:ARG],...`: a known KIND, N in [1, MAX_FAULT_AT], ARG as kinds[KIND] allows.

    Everything is checked here, before anything is served: ConfigError (one line naming `option`) on
    anything malformed, out of range or not finite, and on two faults at the same N.
    """
    if not spec:
        return {}
    faults: dict[int, Fault] = {}
    known = ", ".join(kinds)
    for item in spec.split(","):
        kind, _, rest = item.strip().partition("@")
        at, colon, arg = rest.partition(":")
        if kind not in kinds or not _AT.fullmatch(at) or not 1 <= int(at) <= MAX_FAULT_AT:
            raise ConfigError(
                f"{option}: bad item {item!r}: want KIND@N[:ARG] with N in [1, {MAX_FAULT_AT}], "
                f"KIND one of {known}"
            )
        allowed = kinds[kind]
        value = _fault_arg(option, item, kind, allowed, arg if colon else None)
        if int(at) in faults:
            raise ConfigError(f"{option}: {item!r}: a fault is already planned at {at}")
        faults[int(at)] = Fault(kind, int(at), value)
    return faults


def _fault_arg(option: str, item: str, kind: str, allowed: FaultArg, arg: str | None) -> float | None:
    """The checked ARG of one item (None when it has none)."""
    if arg is None:
        if allowed.need == "required":
            raise ConfigError(f"{option}: {item!r}: {kind} needs an argument ({kind}@N:VALUE)")
        return None
    if allowed.need == "none":
        raise ConfigError(f"{option}: {item!r}: {kind} takes no argument")
    try:
        value = float(arg)
    except ValueError:
        value = math.nan
    ok = math.isfinite(value) and allowed.low <= value <= allowed.high
    if not ok or (allowed.integer and value != int(value)):
        raise ConfigError(f"{option}: {item!r}: the argument of {kind} must be {allowed.describe()}")
    return value


class Link:
    """The device's end of one connection: a pty master descriptor or a connected socket."""

    def __init__(self, fd: int | None = None, sock: socket.socket | None = None) -> None:
        self.fd, self.sock = fd, sock
        self._closed = threading.Lock()
        self.last_received = time.monotonic()
        """When the host last sent a byte (monotonic s): what an idle timeout measures."""

    def fileno(self) -> int:
        """For select()."""
        return self.sock.fileno() if self.sock is not None else self.fd

    def read(self, size: int = 4096) -> bytes | None:
        """Up to `size` bytes waiting; b"" when the peer is gone; None when nothing was there after all."""
        try:
            data = self.sock.recv(size) if self.sock is not None else os.read(self.fd, size)
            if data:
                self.last_received = time.monotonic()
            return data
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

    def hang_up(self) -> None:
        """End a socket's connection from another thread: the session reads the end of the stream and
        closes the link itself (the descriptor stays valid until it does)."""
        if self.sock is not None:
            with contextlib.suppress(OSError):
                self.sock.shutdown(socket.SHUT_RDWR)

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


REALTIME_ENV = "BARRETT_TWIN_REALTIME"
"""Set (to anything) to raise the emulators' serial threads (off by default: with several emulators on a
loaded 2-core machine, real-time threads starved their own processes' shutdown in the test suite)."""
SERIAL_RT_PRIORITY = 1
"""The lowest SCHED_FIFO priority: above every ordinary thread, below the kernel's own."""
SERIAL_NICE = -10


def raise_thread_priority() -> str:
    """Let the calling thread (a serial line's) preempt ordinary work, as the hand's own firmware is
    never kept waiting by the host's load: SCHED_FIFO at priority 1 where permitted (root,
    CAP_SYS_NICE or an rtprio limit), else nice -10 where permitted, else nothing. Returns what it got.

    Only a thread that sleeps between short bursts may have this: it handles at most the wire's bytes.
    Threads it starts inherit the class, so it starts none. Linux only; elsewhere "normal"."""
    if not os.environ.get(REALTIME_ENV) or not hasattr(os, "sched_setscheduler"):
        return "normal"
    tid = threading.get_native_id()
    try:
        os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(SERIAL_RT_PRIORITY))
        return f"SCHED_FIFO {SERIAL_RT_PRIORITY}"
    except (PermissionError, OSError):
        pass
    try:
        os.setpriority(os.PRIO_PROCESS, tid, SERIAL_NICE)
        return f"nice {SERIAL_NICE}"
    except (PermissionError, OSError):
        return "normal"


def close_fd(fd: int) -> None:
    """Close a descriptor, ignoring one that is already gone."""
    with contextlib.suppress(OSError):
        os.close(fd)


BUSY_REPLY = b"\n\rbusy: another client is connected to this emulator\n\r"
"""What a second TCP client reads before its connection is closed (one client at a time, as a serial line)."""
BUSY_GRACE_S = 1.0
"""How long a newcomer waits for the present client's session to end (it may be leaving) before refusal.
One newcomer waits at a time, on a thread of its own: the others are refused at once, and the accept
loop never waits (a flood of connections delays nobody)."""
IDLE_TIMEOUT_S = 60.0
"""A TCP client of a host-driven emulator (the hand) that sends nothing this long is disconnected, so
a silent connection cannot hold the one session for ever."""


class PortServer:
    """Serves `_session(link)` on a pty, a TCP port (one client at a time) or a socket pair.

    `_session` returns how the session ended: "closed" (the peer left), "stopped" (close() was
    called) or "vanished" (a fault took the port away: the pty or the listening socket closes too).
    A session that raises instead ends as "failed": `failure` says why, `on_event` reports it and the
    port closes, so that an emulator never looks alive while nobody answers.

    On TCP a second client, while one is connected, reads `BUSY_REPLY` and is closed at once (a serial
    port has one host); once the first has left, the next is served. On a pty one client exists by
    nature (whoever opens the terminal).
    """

    thread_name = "emulator"
    idle_timeout_s: float | None = None
    """Disconnect a TCP client that has sent nothing this long (None: never; a device that streams on
    its own, as the pads, has clients that never send)."""

    def __init__(self, on_event: Callable[[str], None] | None = None) -> None:
        self.on_event = on_event or (lambda _msg: None)
        self.stop_event = threading.Event()
        self.address: str | None = None
        self.failure: str | None = None
        """Why a session failed (one line), None while every session has ended as it should."""
        self._started = False
        self._threads: list[threading.Thread] = []
        self._closers: list[Callable[[], None]] = []

    def _session(self, link: Link) -> str:
        raise NotImplementedError

    def _on_first_start(self) -> None:
        """Called before the first port is served (e.g. start the twin's clock)."""

    def _on_close(self) -> None:
        """Called after every port is closed."""

    def failed(self) -> str | None:
        """Why the emulator no longer serves (one line), or None while it does."""
        return self.failure

    def _start(self, target: Callable[[], None], name: str | None = None) -> threading.Thread:
        if not self._started:
            self._started = True
            self._on_first_start()
        thread = threading.Thread(target=target, name=name or self.thread_name, daemon=True)
        thread.start()
        self._threads = [t for t in self._threads if t.is_alive()]
        self._threads.append(thread)
        return thread

    def _guarded_session(self, link: Link) -> str:
        """`_session`, with an unexpected exception recorded and reported as the outcome "failed"."""
        try:
            return self._session(link)
        except Exception as exc:  # a bug or a broken twin: say so and close, never serve on half-dead
            self.failure = f"{type(exc).__name__}: {exc}"
            self.on_event(f"session failed, no longer serving: {self.failure}")
            return "failed"

    def serve_pty(self) -> str:
        """Open a pseudo-terminal and answer on it; returns the device path to open.

        The emulator keeps the terminal's far end open, so clients may come and go on it.
        """
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        path = os.ttyname(slave)
        link = Link(fd=master)
        once = threading.Lock()

        def close_pty() -> None:
            # Both the session's end and close() call this: the second call must not close the
            # descriptor numbers again, which by then may be another port's (a pty hung up mid-run).
            if not once.acquire(blocking=False):
                return
            link.close()
            close_fd(slave)  # the device node goes away with the last descriptor

        def run() -> None:
            outcome = self._guarded_session(link)
            self.on_event(f"pty session ended: {outcome}")
            close_pty()

        session = self._start(run)

        def release() -> None:
            # A session still running would go on reading and writing these descriptor numbers after
            # they were closed, by then maybe another port's: it closes them itself when it ends.
            if session.is_alive():
                self.on_event(f"the session on {path} has not ended: it closes its pty when it does")
                return
            close_pty()

        self._closers.append(release)
        self.address = path
        return path

    def serve_tcp(self, port: int = 0, host: str = "127.0.0.1") -> str:
        """Listen on host:port (0 picks a free port); returns socket://host:port."""
        server = socket.create_server((host, port))
        server.settimeout(0.1)
        self._closers.append(server.close)

        state: dict[str, object] = {"session": None, "link": None, "waiting": False}
        lock = threading.Lock()

        def serve_client(conn: socket.socket, link: Link) -> None:
            outcome = self._guarded_session(link)
            link.close()
            self.on_event(f"client left: {outcome}")
            if outcome in ("vanished", "failed"):
                server.close()

        def begin(conn: socket.socket, peer: str) -> None:
            """Serve `conn` now (under `lock`, with no session alive)."""
            link = Link(sock=conn)
            self.on_event(f"client {peer} connected")
            state["link"] = link
            state["session"] = self._start(lambda: serve_client(conn, link), f"{self.thread_name}-client")

        def wait_then_serve(conn: socket.socket, peer: str, session: threading.Thread) -> None:
            """The one newcomer allowed to wait: served if the present session ends within the grace."""
            session.join(timeout=BUSY_GRACE_S)
            with lock:
                state["waiting"] = False
                current = state["session"]
                if (current is None or not current.is_alive()) and not self.stop_event.is_set():
                    begin(conn, peer)
                    return
            self._refuse(conn, peer)

        def run() -> None:
            while not self.stop_event.is_set():
                self._disconnect_if_idle(state.get("link"), state.get("session"))
                try:
                    conn, addr = server.accept()
                except TimeoutError:
                    continue
                except OSError:
                    return
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                peer = f"{addr[0]}:{addr[1]}"
                with lock:
                    session = state["session"]
                    if session is None or not session.is_alive():
                        begin(conn, peer)
                        continue
                    if state["waiting"]:  # one newcomer already waits: refuse this one now
                        refuse = True
                    else:
                        refuse, state["waiting"] = False, True
                if refuse:
                    self._refuse(conn, peer)
                else:
                    self._start(lambda c=conn, p=peer, s=session: wait_then_serve(c, p, s), "emulator-wait")

        self._start(run, f"{self.thread_name}-accept")
        self.address = f"socket://{host}:{server.getsockname()[1]}"
        return self.address

    def _refuse(self, conn: socket.socket, peer: str) -> None:
        """A second client: one line saying why, then closed (never waiting on it: a newcomer that
        does not read cannot hold the accept loop)."""
        self.on_event(f"client {peer} refused: another client is connected")
        with contextlib.suppress(OSError):
            conn.setblocking(False)
            conn.send(BUSY_REPLY)
            conn.shutdown(socket.SHUT_RDWR)
        conn.close()

    def _disconnect_if_idle(self, link: object, session: object) -> None:
        """Close a TCP client's link once it has sent nothing for idle_timeout_s (its session then ends
        as the peer leaving would)."""
        timeout = self.idle_timeout_s
        if timeout is None or not isinstance(link, Link) or not isinstance(session, threading.Thread):
            return
        if session.is_alive() and time.monotonic() - link.last_received > timeout:
            self.on_event(f"client idle for {timeout:g} s: disconnected")
            link.hang_up()

    def serve_socketpair(self) -> socket.socket:
        """An in-process connection (the emulators' URLs): returns the host's end."""
        host_end, device_end = socket.socketpair()
        link = Link(sock=device_end)

        def run() -> None:
            self._guarded_session(link)
            link.close()

        self._start(run)
        return host_end

    def close(self, timeout_s: float = 5.0) -> None:
        """Stop answering, wait for the sessions to end (they look at stop_event at least every 50 ms)
        and release the ports."""
        self.stop_event.set()
        deadline = time.monotonic() + timeout_s
        for thread in list(self._threads):
            thread.join(timeout=max(0.0, deadline - time.monotonic()))
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
