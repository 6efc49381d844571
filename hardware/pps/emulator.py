"""A PPS tactile interface that streams frames at its scan rate: pseudo-terminal, TCP or socket pair.

The counts come from any `source() -> (162,) ints` (a synthetic pattern here; the twin's tactile
skin can be plugged in later — it is called from the emulator's thread at every scan). Frames leave
at line speed (10 bits per byte at the configured baud) and the layout is `hardware.pps.frame`'s.
Faults are injected by frame number (see `FaultPlan`) to prove the driver's recovery and clear errors.
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

import numpy as np
from numpy.typing import NDArray

from hardware.pps.frame import FRAME_SIZE, SEQUENCE_MODULO, encode_frame
from twin.interface.devices import N_TAXELS, TAXEL_COUNT_MAX
from twin.interface.errors import ConfigError

FAULT_KINDS = ("garbage", "partial", "corrupt", "drop", "stall", "vanish")
DEFAULT_BAUD = 921_600
GARBAGE = b"\x00\xa5\x5a\x13\xff\xa5\x7f\x5a\xa5"
"""Line noise of the `garbage` fault: it holds a false sync and ends on half of one."""

Source = Callable[[], NDArray[np.integer]]


@dataclass(frozen=True)
class Fault:
    """One fault on the N-th frame (1-based) of a session."""

    kind: str
    at_frame: int
    arg: float | None = None


class FaultPlan:
    """Faults parsed from `KIND@N[:ARG],...`, e.g. `garbage@10,corrupt@20,stall@30:0.5,vanish@60`.

    garbage: noise before frame N; partial: the first half of frame N, then the next frame; corrupt:
    frame N with one byte flipped (its CRC fails); drop: frame N never sent (a sequence gap);
    stall:S: the device stops for S seconds before frame N (for good without S), losing no frame;
    vanish: the port closes instead of frame N.
    """

    def __init__(self, faults: tuple[Fault, ...] = ()) -> None:
        self.faults = {f.at_frame: f for f in faults}

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
            if value is not None and (kind != "stall" or value < 0):
                raise ConfigError(f"--faults: {item!r}: only stall takes an argument (seconds >= 0)")
            faults.append(Fault(kind, int(at), value))
        return cls(tuple(faults))

    def at(self, frame: int) -> Fault | None:
        """The fault planned for this frame, if any."""
        return self.faults.get(frame)


# --- synthetic sources -----------------------------------------------------------------------


def constant_source(counts: NDArray[np.integer] | int = 1000) -> Source:
    """Every scan the same counts (one value for all taxels, or 162 of them)."""
    fixed = np.broadcast_to(np.asarray(counts, dtype=np.int64), (N_TAXELS,)).copy()
    return lambda: fixed


def ramp_source(step: int = 97) -> Source:
    """Taxel i of scan k reads (1000 i + step k) mod 32768: every scan differs, every taxel differs."""
    taxels = np.arange(N_TAXELS, dtype=np.int64) * 1000
    scan = 0

    def source() -> NDArray[np.int64]:
        nonlocal scan
        scan += 1
        return (taxels + step * scan) % (TAXEL_COUNT_MAX + 1)

    return source


def noise_source(mean: float = 2000.0, std: float = 4.0, seed: int = 0) -> Source:
    """A resting pad: Gaussian noise about `mean` counts, rounded."""
    rng = np.random.default_rng(seed)
    return lambda: np.rint(rng.normal(mean, std, N_TAXELS)).astype(np.int64)


SOURCES: dict[str, Callable[[], Source]] = {
    "ramp": ramp_source,
    "constant": constant_source,
    "zeros": lambda: constant_source(0),
    "noise": noise_source,
}
"""Sources by name, for `ppsemu://?source=NAME` and the CLI."""


# --- the wire --------------------------------------------------------------------------------


class _Link:
    """One endpoint: a non-blocking pty master fd or a connected socket."""

    def __init__(self, fd: int | None = None, sock: socket.socket | None = None) -> None:
        self.fd, self.sock = fd, sock
        if fd is not None:
            os.set_blocking(fd, False)

    def fileno(self) -> int:
        return self.sock.fileno() if self.sock is not None else self.fd

    def peer_gone(self) -> bool:
        """Whether the far end of a socket has closed (a pty has no such notion here)."""
        if self.sock is None:
            return False
        try:
            return self.sock.recv(4096, socket.MSG_DONTWAIT) == b""  # host bytes are ignored
        except (BlockingIOError, InterruptedError):
            return False
        except OSError:
            return True

    def write(self, data: bytes, deadline: float) -> bool:
        """Write all of data by the deadline; False if the host stopped reading (the rest is lost)."""
        if self.sock is not None:
            self.sock.settimeout(max(0.01, deadline - time.monotonic()))
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
                left = deadline - time.monotonic()
                if left <= 0 or not select.select([], [self.fd], [], left)[1]:
                    return False
        return True

    def close(self) -> None:
        if self.sock is not None:
            with contextlib.suppress(OSError):
                self.sock.shutdown(socket.SHUT_RDWR)
            self.sock.close()
        elif self.fd is not None:
            _close_fd(self.fd)


class _VanishedError(Exception):
    """The `vanish` fault: the port is gone."""


class StreamSession:
    """The device's side of one connection: scan at the rate, encode, fault, send at line speed."""

    def __init__(self, emulator: TactileEmulator, link: _Link) -> None:
        self.emu = emulator
        self.link = link
        self.frame = 0
        """Frames scanned in this session (1-based numbering, as in the FaultPlan)."""
        self._tx_end = 0.0

    def serve(self) -> str:
        """Stream until the peer leaves ('closed'), the emulator stops ('stopped') or a fault ('vanished')."""
        stop = self.emu.stop_event
        period = 1.0 / self.emu.rate_hz
        next_scan = time.monotonic()
        try:
            while not stop.is_set():
                if stop.wait(max(0.0, next_scan - time.monotonic())):
                    break
                if self.link.peer_gone():
                    return "closed"
                self.frame += 1
                fault = self.emu.faults.at(self.frame)
                if fault is not None and fault.kind == "stall":
                    self.emu.on_event(f"stall before frame {self.frame}")
                    if stop.wait(fault.arg if fault.arg is not None else None):
                        break
                    next_scan = time.monotonic()
                data = self.emu.scan()
                self._send_frame(data, fault, deadline=next_scan + period)
                next_scan += period
                if next_scan < time.monotonic() - period:  # fell behind (host not reading): no burst
                    next_scan = time.monotonic()
        except _VanishedError:
            return "vanished"
        except OSError:
            return "closed"
        return "stopped"

    def _send_frame(self, data: bytes, fault: Fault | None, deadline: float) -> None:
        kind = fault.kind if fault is not None else None
        if kind == "vanish":
            self.emu.on_event(f"vanish at frame {self.frame}")
            raise _VanishedError
        if kind == "drop":
            return
        if kind == "garbage":
            data = GARBAGE + data
        elif kind == "partial":
            data = data[: FRAME_SIZE // 2]
        elif kind == "corrupt":
            i = FRAME_SIZE // 2
            data = data[:i] + bytes([data[i] ^ 0x01]) + data[i + 1 :]
        self.send(data, deadline)

    def send(self, data: bytes, deadline: float) -> None:
        """Write at line speed, in chunks of about a millisecond of wire time."""
        byte_s = 10.0 / self.emu.baud
        chunk = max(1, int(self.emu.baud / 10 / 1000))
        t = max(time.monotonic(), self._tx_end)
        for i in range(0, len(data), chunk):
            part = data[i : i + chunk]
            if not self.link.write(part, deadline):
                self.emu.unsent_frames += 1
                self._tx_end = time.monotonic()
                return
            t += len(part) * byte_s
            delay = t - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        self._tx_end = t


class TactileEmulator:
    """The PPS tactile interface streaming `source()` scans over a pty, TCP or an in-process socket pair."""

    def __init__(
        self,
        source: Source,
        rate_hz: float = 30.0,
        *,
        baud: int = DEFAULT_BAUD,
        faults: FaultPlan | str | None = None,
        first_sequence: int = 0,
        on_event: Callable[[str], None] | None = None,
    ) -> None:
        if not rate_hz > 0:
            raise ConfigError("tactile emulator rate_hz must be > 0")
        if baud <= 0:
            raise ConfigError("tactile emulator baud must be > 0")
        wire_s = FRAME_SIZE * 10.0 / baud
        if wire_s > 0.8 / rate_hz:
            raise ConfigError(
                f"at {baud} baud a {FRAME_SIZE}-byte frame takes {wire_s * 1e3:.1f} ms, more than 80% of the "
                f"{1e3 / rate_hz:.1f} ms scan period: raise the baud or lower rate_hz"
            )
        self.source = source
        self.rate_hz = float(rate_hz)
        self.baud = int(baud)
        self.faults = faults if isinstance(faults, FaultPlan) else FaultPlan.parse(faults)
        self.on_event = on_event or (lambda _msg: None)
        self.stop_event = threading.Event()
        self.unsent_frames = 0
        """Frames (or their tails) lost because nobody read the pty."""
        self.error: BaseException | None = None
        """What made the source fail, if it did (the session then closes its port)."""
        self.address: str | None = None
        self._sequence = first_sequence % SEQUENCE_MODULO
        self._lock = threading.Lock()
        self._t0 = time.monotonic()
        self._threads: list[threading.Thread] = []
        self._closers: list[Callable[[], None]] = []

    def scan(self) -> bytes:
        """One scan of the source as a frame: the next sequence number, device time in µs."""
        counts = np.asarray(self.source())
        if counts.shape != (N_TAXELS,) or not np.issubdtype(counts.dtype, np.integer):
            raise ConfigError(f"the tactile source must return {N_TAXELS} integer counts, got {counts.shape}")
        with self._lock:
            sequence = self._sequence
            self._sequence = (sequence + 1) % SEQUENCE_MODULO
        timestamp_us = int((time.monotonic() - self._t0) * 1e6)
        return encode_frame(sequence, timestamp_us, np.clip(counts, 0, TAXEL_COUNT_MAX))  # saturates

    def _session(self, link: _Link) -> str:
        try:
            return StreamSession(self, link).serve()
        except Exception as exc:  # a failing source: report it and close the port, never hang the host
            self.error = exc
            self.on_event(f"source failed: {exc}")
            return "vanished"

    def _start(self, target: Callable[[], None]) -> None:
        thread = threading.Thread(target=target, name="pps-emulator", daemon=True)
        thread.start()
        self._threads.append(thread)

    def serve_pty(self) -> str:
        """Open a pseudo-terminal and stream on it from now on; returns the device path to open."""
        master, slave = os.openpty()
        tty.setraw(slave)
        path = os.ttyname(slave)
        closed = threading.Lock()

        def close_pty() -> None:  # once: a descriptor number closed twice may be someone else's by then
            if closed.acquire(blocking=False):
                _close_fd(master)
                _close_fd(slave)  # the device node goes away with the last descriptor

        self._closers.append(close_pty)
        link = _Link(fd=master)

        def run() -> None:
            outcome = self._session(link)
            self.on_event(f"pty session ended: {outcome}")
            close_pty()

        self._start(run)
        self.address = path
        return path

    def serve_tcp(self, port: int = 0, host: str = "127.0.0.1") -> str:
        """Listen on host:port (0 picks a free port), one client at a time; returns socket://host:port."""
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
                link = _Link(sock=conn)
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
        """An in-process connection (the ppsemu:// URL): returns the host's end."""
        host_end, device_end = socket.socketpair()
        link = _Link(sock=device_end)

        def run() -> None:
            self._session(link)
            link.close()

        self._start(run)
        return host_end

    def close(self) -> None:
        """Stop streaming and release the ports."""
        self.stop_event.set()
        for thread in self._threads:
            thread.join(timeout=2.0)
        for closer in self._closers:
            closer()

    def __enter__(self) -> TactileEmulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _close_fd(fd: int) -> None:
    with contextlib.suppress(OSError):
        os.close(fd)


def make_tactile_emulator(
    source: str = "ramp",
    *,
    rate_hz: float = 30.0,
    baud: int = DEFAULT_BAUD,
    faults: str | None = None,
    first_sequence: int = 0,
    on_event: Callable[[str], None] | None = None,
) -> TactileEmulator:
    """An emulator on a named synthetic source (see SOURCES); ConfigError for an unknown name."""
    if source not in SOURCES:
        raise ConfigError(f"unknown tactile source {source!r}: one of {', '.join(SOURCES)}")
    return TactileEmulator(
        SOURCES[source](),
        rate_hz,
        baud=baud,
        faults=FaultPlan.parse(faults),
        first_sequence=first_sequence,
        on_event=on_event,
    )
