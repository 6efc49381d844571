"""A PPS tactile interface that streams frames at its scan rate: pseudo-terminal, TCP or socket pair.

The counts come from any `source() -> (162,) ints` (a synthetic pattern here; the twin's tactile
skin can be plugged in later — it is called from the emulator's thread at every scan). Frames leave
at line speed (10 bits per byte at the configured baud) and the layout is `twin.hardware.pps.frame`'s.
Faults are injected by frame number (see `FaultPlan`) to prove the driver's recovery and clear errors.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray
from twin.hardware.emulation import NO_ARG, Fault, FaultArg, Link, PortServer, parse_faults
from twin.hardware.pps.frame import FRAME_SIZE, SEQUENCE_MODULO, encode_frame

from twin.interface.devices import N_TAXELS, TAXEL_COUNT_MAX
from twin.interface.errors import ConfigError

MAX_STALL_S = 3600.0
"""The longest timed `stall` (without a time it is for good)."""
FAULTS = {
    "garbage": NO_ARG,
    "partial": NO_ARG,
    "corrupt": NO_ARG,
    "drop": NO_ARG,
    "stall": FaultArg("optional", 0.0, MAX_STALL_S, unit="s"),
    "vanish": NO_ARG,
}
DEFAULT_BAUD = 921_600
GARBAGE = b"\x00\xa5\x5a\x13\xff\xa5\x7f\x5a\xa5"
"""Line noise of the `garbage` fault: it holds a false sync and ends on half of one."""

Source = Callable[[], NDArray[np.integer]]


class FaultPlan:
    """Faults by frame, from `KIND@N[:ARG],...`, e.g. `garbage@10,corrupt@20,stall@30:0.5,vanish@60`.

    N counts the frames of a session. garbage: noise before frame N; partial: the first half of
    frame N, then the next frame; corrupt: frame N with one byte flipped (its CRC fails); drop: frame N
    never sent (a sequence gap); stall:S: the device stops for S seconds (0 to 3600) before frame N
    (for good without S), losing no frame; vanish: the port closes instead of frame N.
    """

    def __init__(self, faults: dict[int, Fault] | None = None) -> None:
        self.faults = faults or {}

    @classmethod
    def parse(cls, spec: str | None, option: str = "faults") -> FaultPlan:
        """Parse a fault SPEC; ConfigError (one line naming `option`) when malformed or out of range."""
        return cls(parse_faults(spec, FAULTS, option))

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


class _VanishedError(Exception):
    """The `vanish` fault: the port is gone."""


class StreamSession:
    """The device's side of one connection: scan at the rate, encode, fault, send at line speed."""

    def __init__(self, emulator: TactileEmulator, link: Link) -> None:
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
                    if self._stall(fault.arg if fault.arg is not None else float("inf")):
                        return "closed"
                    if stop.is_set():
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

    def _stall(self, duration_s: float) -> bool:
        """Send nothing for duration_s (or until close()); True if the host left meanwhile (a client
        gone during a stall must not keep the port from the next one)."""
        end = time.monotonic() + duration_s
        while not self.emu.stop_event.wait(min(0.05, max(0.0, end - time.monotonic()))):
            if self.link.peer_gone():
                return True
            if time.monotonic() >= end:
                return False
        return False

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


class TactileEmulator(PortServer):
    """The PPS tactile interface streaming `source()` scans over a pty, TCP or an in-process socket pair."""

    thread_name = "pps-emulator"

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
        super().__init__(on_event)
        self.source = source
        self.rate_hz = float(rate_hz)
        self.baud = int(baud)
        self.faults = faults if isinstance(faults, FaultPlan) else FaultPlan.parse(faults)
        self.unsent_frames = 0
        """Frames (or their tails) lost because nobody read the pty."""
        self.error: BaseException | None = None
        """What made the source fail, if it did (the session then closes its port)."""
        self._sequence = first_sequence % SEQUENCE_MODULO
        self._lock = threading.Lock()
        self._t0 = time.monotonic()

    def scan(self) -> bytes:
        """One scan of the source as a frame: the next sequence number, device time in µs."""
        with self._lock:  # one scan at a time, even with several ports open: sources need not be thread-safe
            counts = np.asarray(self.source())
            sequence = self._sequence
            self._sequence = (sequence + 1) % SEQUENCE_MODULO
        if counts.shape != (N_TAXELS,) or not np.issubdtype(counts.dtype, np.integer):
            raise ConfigError(f"the tactile source must return {N_TAXELS} integer counts, got {counts.shape}")
        timestamp_us = int((time.monotonic() - self._t0) * 1e6)
        return encode_frame(sequence, timestamp_us, np.clip(counts, 0, TAXEL_COUNT_MAX))  # saturates

    def _session(self, link: Link) -> str:
        try:
            return StreamSession(self, link).serve()
        except Exception as exc:  # a failing source: report it and close the port, never hang the host
            self.error = exc
            self.failure = f"the tactile source failed: {exc}"
            self.on_event(f"source failed: {exc}")
            return "vanished"


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
