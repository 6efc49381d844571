"""A BH8-262 on a serial line, backed by the twin: pseudo-terminal, TCP or in-process socket pair.

Bytes travel at the configured baud rate both ways (10 bits per byte): a request counts as received
only once its last byte would have crossed the wire, and replies leave at line speed. Faults can be
injected into RealTime replies (see `FaultPlan`) to prove the driver's recovery and safe stops.
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
import threading
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass

from hardware.bh262.firmware import Firmware, RealTimeTwin
from hardware.bh262.protocol import EXIT_REALTIME, PROMPT, ErrorFlag, WireOptions
from twin.interface.errors import ConfigError

FAULT_KINDS = ("garbage", "drop", "partial", "late", "err", "vanish", "mute")
DEFAULT_OPTIONS = WireOptions()
GARBAGE = b"\x00\xfe\x13#?\x7f"
"""Line noise injected by the `garbage` fault: no '*' first, no prompt inside."""


@dataclass(frozen=True)
class Fault:
    """One fault on the k-th RealTime reply (1-based) of a session."""

    kind: str
    at_reply: int
    arg: float | None = None


class FaultPlan:
    """Faults parsed from `KIND@N[:ARG],...`, e.g. `garbage@40,late@80:0.3,err@120:8192,vanish@200`.

    garbage: noise before the reply; drop: no reply; partial: the first half only; late:S: the reply
    S seconds late; err:N: `ERR N` instead of the block (the hand drops to Supervisory mode);
    vanish: the port disappears; mute[:S]: nothing answered (bytes received are lost) for S seconds,
    or for good without S.
    """

    def __init__(self, faults: tuple[Fault, ...] = ()) -> None:
        self.faults = {f.at_reply: f for f in faults}

    @classmethod
    def parse(cls, spec: str | None) -> FaultPlan:
        """Parse a --faults SPEC; ConfigError (one line) when malformed."""
        if not spec:
            return cls()
        faults = []
        for item in spec.split(","):
            kind, _, rest = item.strip().partition("@")
            at, _, arg = rest.partition(":")
            if kind not in FAULT_KINDS or not at.isdigit() or int(at) < 1:
                raise ConfigError(
                    f"--faults: bad item {item!r}: want KIND@N[:ARG], KIND one of {', '.join(FAULT_KINDS)}"
                )
            try:
                value = float(arg) if arg else None
            except ValueError:
                raise ConfigError(f"--faults: bad argument in {item!r}") from None
            if kind in ("late", "err") and value is None:
                raise ConfigError(f"--faults: {kind} needs an argument ({kind}@N:VALUE)")
            faults.append(Fault(kind, int(at), value))
        return cls(tuple(faults))

    def at(self, reply: int) -> Fault | None:
        """The fault planned for this reply, if any."""
        return self.faults.get(reply)


class _Link:
    """One endpoint: a pty master fd or a connected socket."""

    def __init__(self, fd: int | None = None, sock: socket.socket | None = None) -> None:
        self.fd, self.sock = fd, sock

    def fileno(self) -> int:
        return self.sock.fileno() if self.sock is not None else self.fd

    def read(self) -> bytes | None:
        """Bytes waiting; b"" when the peer is gone; None when nothing was there after all."""
        try:
            return self.sock.recv(4096) if self.sock is not None else os.read(self.fd, 4096)
        except (BlockingIOError, InterruptedError):
            return None
        except OSError:
            return b""

    def write(self, data: bytes) -> None:
        if self.sock is not None:
            self.sock.sendall(data)
        else:
            view = memoryview(data)
            while view:
                n = os.write(self.fd, view)
                view = view[n:]

    def close(self) -> None:
        if self.sock is not None:
            with contextlib.suppress(OSError):
                self.sock.shutdown(socket.SHUT_RDWR)
            self.sock.close()
        elif self.fd is not None:
            os.close(self.fd)


class _VanishedError(Exception):
    """The `vanish` fault: the port is gone."""


class SerialSession:
    """The hand's side of one serial connection: bytes in, firmware, paced bytes out."""

    def __init__(self, firmware: Firmware, link: _Link, faults: FaultPlan, stop: threading.Event) -> None:
        self.fw = firmware
        self.link = link
        self.faults = faults
        self.stop = stop
        self._buffer = bytearray()
        self._rx_end = 0.0
        self._tx_end = 0.0
        self._replies = 0
        self._mute_until = 0.0

    @property
    def _byte_s(self) -> float:
        return 10.0 / self.fw.baud

    def serve(self) -> str:
        """Answer until the peer leaves ('closed'), the emulator stops ('stopped') or a fault ('vanished')."""
        try:
            while not self.stop.is_set():
                ready, _, _ = select.select([self.link], [], [], 0.05)
                if not ready:
                    continue
                data = self.link.read()
                if data is None:
                    continue
                if not data:
                    return "closed"
                now = time.monotonic()
                self._rx_end = max(self._rx_end, now) + len(data) * self._byte_s
                if now < self._mute_until:
                    continue
                self._buffer += data
                self._process()
        except _VanishedError:
            return "vanished"
        except OSError:
            return "closed"
        return "stopped"

    def _wait_rx(self) -> None:
        """The request is complete only once its last byte has crossed the wire."""
        delay = self._rx_end - time.monotonic()
        if delay > 0:
            time.sleep(delay)

    def send(self, data: bytes) -> None:
        """Write at line speed: chunks of about a millisecond of wire time."""
        if not data:
            return
        chunk = max(1, int(self.fw.baud / 10 / 1000))
        t = max(time.monotonic(), self._tx_end)
        for i in range(0, len(data), chunk):
            part = data[i : i + chunk]
            self.link.write(part)
            t += len(part) * self._byte_s
            delay = t - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        self._tx_end = t

    def _process(self) -> None:
        while self._buffer and time.monotonic() >= self._mute_until:
            if self.fw.loop is None:
                if not self._supervisory():
                    return
            elif not self._realtime():
                return

    def _supervisory(self) -> bool:
        # Ctrl-C (0x03) outside a motion has nothing to abort; LF is ignored as on a terminal.
        while self._buffer[:1] in (EXIT_REALTIME, b"\n"):
            del self._buffer[:1]
        end = self._buffer.find(b"\r")
        if end < 0:
            if len(self._buffer) > 256:  # no command is this long: drop it, as the line buffer would
                self._buffer.clear()
                self.send(self.fw.options.line_end + b"ERR 32" + self.fw.options.line_end + PROMPT)
            return False
        raw = bytes(self._buffer[:end])
        del self._buffer[: end + 1]
        self._wait_rx()
        line = raw.decode("ascii", "replace")
        rest = self.fw.handle_line(line, self.send)
        new_baud = self.fw.pending_baud()
        if new_baud is not None:  # PSET BAUD: the echo went at the old rate; the prompt waits for a CR
            self.fw.baud = new_baud
            self._buffer.clear()
            return True
        self.send(rest)
        return True

    def _realtime(self) -> bool:
        loop = self.fw.loop
        header = self._buffer[:1]
        le = self.fw.options.line_end
        if header == EXIT_REALTIME:
            del self._buffer[:1]
            self._wait_rx()
            self.send(self.fw.leave_loop())
            return True
        if header not in (b"C", b"c", b"A", b"a"):
            del self._buffer[:1]
            self._wait_rx()
            self.fw.loop = None
            self.send(le + f"ERR {int(ErrorFlag.INVALID_REALTIME_HEADER)}".encode() + le + PROMPT)
            return True
        size = 1 + loop.control_size if header in (b"C", b"c") else 1
        if len(self._buffer) < size:
            return False
        data = bytes(self._buffer[1:size])
        del self._buffer[:size]
        # The sensors are sampled as the block comes in; the control takes effect once it is all in.
        reply = self.fw.feedback_block() if header in (b"C", b"A") else b"*"
        self._wait_rx()
        if data:
            self.fw.apply_control(data)
        self._replies += 1
        self._send_reply(reply)
        return True

    def _send_reply(self, reply: bytes) -> None:
        fault = self.faults.at(self._replies)
        if fault is None:
            self.send(reply)
            return
        le = self.fw.options.line_end
        if fault.kind == "garbage":
            self.send(GARBAGE + reply)
        elif fault.kind == "drop":
            pass
        elif fault.kind == "partial":
            self.send(reply[: max(1, len(reply) // 2)])
        elif fault.kind == "late":
            time.sleep(float(fault.arg or 0.0))
            self.send(reply)
        elif fault.kind == "err":
            if self.fw.options.err_leaves_realtime:
                self.fw.loop = None
            self.send(le + f"ERR {int(fault.arg or 0)}".encode() + le + PROMPT)
        elif fault.kind == "mute":
            self._mute_until = time.monotonic() + (fault.arg if fault.arg is not None else float("inf"))
        elif fault.kind == "vanish":
            raise _VanishedError


class HandEmulator:
    """A twin-backed BH8-262 reachable over a pty, TCP or an in-process socket pair."""

    def __init__(
        self,
        twin: RealTimeTwin,
        *,
        baud: int = 9600,
        options: WireOptions = DEFAULT_OPTIONS,
        faults: FaultPlan | None = None,
        on_event: Callable[[str], None] | None = None,
    ) -> None:
        self.twin = twin
        self.firmware = Firmware(twin, options=options, power_up_baud=baud)
        self.faults = faults or FaultPlan()
        self.on_event = on_event or (lambda _msg: None)
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._closers: list[Callable[[], None]] = []
        self.address: str | None = None

    def _start(self, target: Callable[[], None]) -> None:
        if not self._threads:
            self.twin.start()
        thread = threading.Thread(target=target, name="bh8-serial", daemon=True)
        thread.start()
        self._threads.append(thread)

    def serve_pty(self) -> str:
        """Open a pseudo-terminal and answer on it; returns the device path to open."""
        master, slave = os.openpty()
        tty.setraw(slave)
        path = os.ttyname(slave)
        self._closers.append(lambda: _close_fd(slave))
        link = _Link(fd=master)

        def run() -> None:
            outcome = SerialSession(self.firmware, link, self.faults, self._stop).serve()
            self.on_event(f"pty session ended: {outcome}")
            if outcome in ("vanished", "stopped"):
                link.close()
                _close_fd(slave)  # the device node goes away with the last descriptor

        self._start(run)
        self.address = path
        return path

    def serve_tcp(self, port: int = 0, host: str = "127.0.0.1") -> str:
        """Listen on host:port (0 picks a free port), one client at a time; returns socket://host:port."""
        server = socket.create_server((host, port))
        server.settimeout(0.1)
        self._closers.append(server.close)

        def run() -> None:
            while not self._stop.is_set():
                try:
                    conn, peer = server.accept()
                except TimeoutError:
                    continue
                except OSError:
                    return
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                self.on_event(f"client {peer[0]}:{peer[1]} connected")
                outcome = SerialSession(self.firmware, _Link(sock=conn), self.faults, self._stop).serve()
                _Link(sock=conn).close()
                self.on_event(f"client left: {outcome}")
                if outcome == "vanished":
                    server.close()
                    return

        self._start(run)
        self.address = f"socket://{host}:{server.getsockname()[1]}"
        return self.address

    def serve_socketpair(self) -> socket.socket:
        """An in-process connection (the bh8emu:// URL): returns the host's end."""
        host_end, hand_end = socket.socketpair()
        link = _Link(sock=hand_end)

        def run() -> None:
            SerialSession(self.firmware, link, self.faults, self._stop).serve()
            link.close()

        self._start(run)
        return host_end

    def close(self) -> None:
        """Stop answering, stop the twin, release the ports."""
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=2.0)
        for closer in self._closers:
            closer()
        self.twin.stop()

    def __enter__(self) -> HandEmulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _close_fd(fd: int) -> None:
    with contextlib.suppress(OSError):
        os.close(fd)


def make_hand_emulator(
    object_name: str | None = "block",
    *,
    baud: int = 9600,
    faults: str | None = None,
    options: WireOptions = DEFAULT_OPTIONS,
    seed: int = 0,
    on_event: Callable[[str], None] | None = None,
) -> HandEmulator:
    """A hand emulator on a fresh twin holding `object_name` from the foam library (None: no object)."""
    from twin.sim.backend import SimBackend
    from twin.sim.foam import get_object

    plan = FaultPlan.parse(faults)
    foam = get_object(object_name) if object_name else None
    twin = RealTimeTwin(SimBackend(foam, seed=seed))
    return HandEmulator(twin, baud=baud, options=options, faults=plan, on_event=on_event)
