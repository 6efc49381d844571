"""A BH8-262 on a serial line, backed by the twin: pseudo-terminal, TCP or in-process socket pair.

Bytes travel at the configured baud rate both ways (10 bits per byte): a request counts as received
only once its last byte would have crossed the wire, and replies leave at line speed. Faults can be
injected into RealTime replies (see `FaultPlan`) to prove the driver's recovery and safe stops.
"""

from __future__ import annotations

import contextlib
import queue
import select
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np
from twin.hardware.bh262.firmware import QUIET_AFTER_S, QUIET_BEFORE_S, Firmware, RealTimeTwin
from twin.hardware.bh262.protocol import EXIT_REALTIME, PROMPT, ErrorFlag, WireOptions
from twin.hardware.emulation import (
    IDLE_TIMEOUT_S,
    NO_ARG,
    Fault,
    FaultArg,
    Link,
    PortServer,
    parse_faults,
    raise_thread_priority,
)

if TYPE_CHECKING:
    from twin.sim.foam import FoamParams

MAX_DELAY_S = 60.0
"""The longest `late` delay a fault may ask for (the driver gives up on a reply long before)."""
MAX_MUTE_S = 3600.0
"""The longest timed `mute` (without a time it is for good)."""
FAULTS = {
    "garbage": NO_ARG,
    "drop": NO_ARG,
    "partial": NO_ARG,
    "late": FaultArg("required", 0.0, MAX_DELAY_S, unit="s"),
    "err": FaultArg("required", 1, 65535, integer=True, unit="(the ERR code)"),
    "vanish": NO_ARG,
    "mute": FaultArg("optional", 0.0, MAX_MUTE_S, unit="s"),
}
DEFAULT_OPTIONS = WireOptions()
GARBAGE = b"\x00\xfe\x13#?\x7f"
"""Line noise injected by the `garbage` fault: no '*' first, no prompt inside."""
MAX_LINE_BYTES = 256
"""The hand's command line buffer: a longer line is dropped whole as it comes (unechoed, costing no wire
time) and its CR is answered `ERR 32`, so that a flood cannot hold the hand for its wire time."""
MAX_INPUT_BYTES = 4096
"""Bytes the hand holds unprocessed (e.g. sent during a motion); more wait in the link (the pty's or
socket's buffer, as behind flow control) until the firmware takes them: nothing is lost at random."""
POLL_S = 0.05
"""How often a waiting session looks at its link: a departed host, a Ctrl-C, close()."""
WRITE_TIMEOUT_S = 1.0
"""A host that takes no byte for this long loses the rest of a reply (the hand never waits for it)."""


class FaultPlan:
    """Faults on RealTime replies, from `KIND@N[:ARG],...`, e.g. `garbage@40,late@80:0.3,err@120:8192`.

    N counts the RealTime replies of a session (a TCP client's connection; on a pty, the emulator's
    life). garbage: noise before the reply; drop: no reply; partial: the first half only; late:S: the
    reply S seconds late (0 to 60); err:N: `ERR N` instead of the block (N an integer, 1 to 65535; the
    hand drops to Supervisory mode); vanish: the port disappears; mute[:S]: nothing answered (bytes
    received are lost) for S seconds (0 to 3600), or for good without S.
    """

    def __init__(self, faults: dict[int, Fault] | None = None) -> None:
        self.faults = faults or {}

    @classmethod
    def parse(cls, spec: str | None, option: str = "--faults") -> FaultPlan:
        """Parse a --faults SPEC; ConfigError (one line) when malformed or out of range."""
        return cls(parse_faults(spec, FAULTS, option))

    def at(self, reply: int) -> Fault | None:
        """The fault planned for this reply, if any."""
        return self.faults.get(reply)


class _VanishedError(Exception):
    """The `vanish` fault: the port is gone."""


class _ClientLeftError(Exception):
    """The host closed its end: whatever it sent and the hand has not handled yet is dropped."""


class _StoppedError(Exception):
    """close() was called: the session ends wherever it is."""


class SerialSession:
    """The hand's side of one serial connection: bytes in, firmware, paced bytes out.

    Received bytes wait in a buffer with their arrival times; a request counts as received once its
    last byte would have crossed the wire (10 bits a byte from its arrival, after the bytes before it).
    Every wait (the wire, a reply's pacing, a motion, a `late` fault) keeps reading the link, so a host
    that leaves is seen within POLL_S and its backlog is dropped instead of being paced out.
    """

    def __init__(
        self,
        firmware: Firmware,
        link: Link,
        faults: FaultPlan,
        stop: threading.Event,
        on_event: Callable[[str], None] | None = None,
    ) -> None:
        self.fw = firmware
        self.link = link
        self.faults = faults
        self.stop = stop
        self.on_event = on_event or (lambda _msg: None)
        """Told each Supervisory exchange and, when RealTime mode ends, how many blocks it answered."""
        self._loop_blocks = 0
        self.priority = "normal"
        """The scheduling the serial thread got (raise_thread_priority), for the loop summaries."""
        self._late_s: deque[float] = deque(maxlen=100_000)
        """Per RealTime reply of the present loop: how much later than due it was written (s)."""
        self._buffer = bytearray()
        self._arrivals: deque[list[float]] = deque()
        """Per received chunk still (partly) in the buffer: [its bytes left in the buffer, arrival time]."""
        self._rx_end = 0.0
        self._tx_end = 0.0
        self._replies = 0
        self._mute_until = 0.0
        self._overflow = False

    @property
    def _byte_s(self) -> float:
        return 10.0 / self.fw.baud

    def serve(self) -> str:
        """Answer until the peer leaves ('closed'), the emulator stops ('stopped') or a fault ('vanished')."""
        try:
            while True:
                self._pump(POLL_S)
                self._process()
        except _VanishedError:
            return "vanished"
        except _ClientLeftError:
            return "closed"
        except _StoppedError:
            return "stopped"
        except OSError:
            return "closed"

    # --- the link ------------------------------------------------------------------------------

    def _pump(self, timeout_s: float) -> None:
        """Take what the host has sent, waiting up to timeout_s for it; raises when the host has left,
        the emulator is closing or the twin has stopped."""
        if self.stop.is_set():
            raise _StoppedError
        if self.fw.twin.failure is not None:
            raise RuntimeError(f"the twin stopped: {self.fw.twin.failure}")
        room = MAX_INPUT_BYTES - len(self._buffer)
        if room <= 0:  # full: the host's bytes wait in the link, as behind flow control; none is lost
            time.sleep(max(0.0, min(timeout_s, POLL_S)))
            return
        if not select.select([self.link], [], [], max(0.0, timeout_s))[0]:
            return
        data = self.link.read(room)
        if data is None:
            return
        if not data:
            raise _ClientLeftError
        now = time.monotonic()
        if now < self._mute_until:
            return  # muted: what arrives is lost
        if data:
            self._buffer += data
            self._arrivals.append([len(data), now])

    def _consume(self, n: int, *, on_wire: bool = True) -> None:
        """Drop the first n bytes of the buffer; `on_wire`: they count toward the wire time (_rx_end)."""
        del self._buffer[:n]
        while n > 0 and self._arrivals:
            chunk = self._arrivals[0]
            k = min(n, int(chunk[0]))
            if on_wire:
                self._rx_end = max(self._rx_end, chunk[1]) + k * self._byte_s
            chunk[0] -= k
            n -= k
            if chunk[0] <= 0:
                self._arrivals.popleft()

    def _flush_pending(self) -> None:
        """An error ends RealTime mode: blocks the host sent after the failing one are dropped, not
        read as a Supervisory line, so that its 0x03 (RTAbort) is answered with a prompt at once."""
        self._pump(0.0)
        self._consume(len(self._buffer), on_wire=False)

    def _cut(self, index: int) -> None:
        """Remove the byte at `index` of the buffer (a Ctrl-C taken out of the stream)."""
        del self._buffer[index]
        for chunk in self._arrivals:
            if index < chunk[0]:
                chunk[0] -= 1
                if chunk[0] <= 0:
                    self._arrivals.remove(chunk)
                return
            index -= int(chunk[0])

    def _sleep_until(self, t: float) -> None:
        """Wait until monotonic time t, reading the link meanwhile."""
        while (left := t - time.monotonic()) > 0:
            self._pump(min(left, POLL_S))

    def _ctrl_c(self) -> bool:
        """During a motion: has a Ctrl-C (0x03) arrived? It is taken out; other bytes wait for the prompt."""
        self._pump(0.0)
        index = self._buffer.find(EXIT_REALTIME)
        if index < 0:
            return False
        self._cut(index)
        return True

    def _wait_rx(self) -> None:
        """The request is complete only once its last byte has crossed the wire."""
        self._sleep_until(self._rx_end)

    def send(self, data: bytes) -> None:
        """Write at line speed: chunks of about a millisecond of wire time. A host that stops reading
        loses the rest (the hand never waits for it)."""
        if not data:
            return
        chunk = max(1, int(self.fw.baud / 10 / 1000))
        t = max(time.monotonic(), self._tx_end)
        for i in range(0, len(data), chunk):
            part = data[i : i + chunk]
            t += len(part) * self._byte_s
            self._sleep_until(t)  # a byte reaches the host once it has crossed the wire, not before
            if not self.link.write(part, time.monotonic() + WRITE_TIMEOUT_S):
                self._tx_end = time.monotonic()
                return
        self._tx_end = t

    def send_block(self, data: bytes) -> None:
        """A RealTime reply, written whole when its last byte would have crossed the wire after the
        request's (one wake-up per cycle instead of one per millisecond of wire: on a loaded machine
        every wake-up can be late). A host that stops reading loses it, as with send()."""
        due = max(self._rx_end, self._tx_end) + len(data) * self._byte_s
        self.fw.twin.keep_quiet(due - QUIET_BEFORE_S, due + QUIET_AFTER_S)
        self._sleep_until(due)
        self._late_s.append(time.monotonic() - due)
        if not self.link.write(data, time.monotonic() + WRITE_TIMEOUT_S):
            self._tx_end = time.monotonic()
            return
        self._tx_end = max(due, time.monotonic())

    # --- the firmware --------------------------------------------------------------------------

    def _process(self) -> None:
        while self._buffer and time.monotonic() >= self._mute_until:
            if self.fw.loop is None:
                if not self._supervisory():
                    return
            elif not self._realtime():
                return

    def _supervisory(self) -> bool:
        while self._buffer[:1] == b"\n":  # LF is ignored, as on a terminal
            self._consume(1)
        end = self._buffer.find(b"\r")
        ctrl_c = self._buffer.find(EXIT_REALTIME)
        if ctrl_c >= 0 and (end < 0 or ctrl_c < end):
            return self._cancel_line(ctrl_c)
        if self._overflow or end > MAX_LINE_BYTES or (end < 0 and len(self._buffer) > MAX_LINE_BYTES):
            return self._drop_long_line(end)
        if end < 0:
            return False
        raw = bytes(self._buffer[:end])
        self._consume(end + 1)
        self._wait_rx()
        line = raw.decode("ascii", "replace")
        rest = self.fw.handle_line(line, self.send, self._ctrl_c)
        if line.strip():
            self.on_event(f"{line.strip()} -> {_summary(rest, self.fw.options.line_end)}")
        if self.fw.loop is not None:
            self._loop_blocks = 0
        new_baud = self.fw.pending_baud()
        if new_baud is not None:  # PSET BAUD: the echo went at the old rate; the prompt waits for a CR
            self.fw.baud = new_baud
            self._consume(len(self._buffer), on_wire=False)
            return True
        self.send(rest)
        return True

    def _loop_ended(self, how: str) -> None:
        late = ""
        if self._late_s:
            ms = np.sort(np.asarray(self._late_s)) * 1e3
            p50, p99 = ms[len(ms) // 2], ms[min(len(ms) - 1, int(0.99 * len(ms)))]
            late = f"; written late by p50 {p50:.2f} ms, p99 {p99:.2f} ms, max {ms[-1]:.1f} ms"
        self._late_s.clear()
        blocks, priority = self._loop_blocks, self.priority
        self.on_event(f"RealTime: {blocks} blocks answered, then {how}{late} (serial thread: {priority})")

    def _cancel_line(self, ctrl_c: int) -> bool:
        """Ctrl-C (0x03) outside a motion: the line typed so far is dropped and a fresh prompt answered,
        as leaving RealTime does (Barrett's RTAbort and libgripper's connect both wait for it)."""
        self._consume(ctrl_c + 1)
        self._overflow = False
        self._wait_rx()
        self.send(self.fw.options.line_end + PROMPT)
        return True

    def _drop_long_line(self, end: int) -> bool:
        """A line longer than MAX_LINE_BYTES: dropped as it comes; its CR is answered ERR 32."""
        if end < 0:
            self._consume(len(self._buffer), on_wire=False)
            self._overflow = True
            return False
        self._consume(end + 1, on_wire=False)
        self._overflow = False
        le = self.fw.options.line_end
        self.send(le + f"ERR {int(ErrorFlag.UNKNOWN_COMMAND)}".encode() + le + PROMPT)
        return True

    def _realtime(self) -> bool:
        loop = self.fw.loop
        header = self._buffer[:1]
        le = self.fw.options.line_end
        if header == EXIT_REALTIME:
            self._consume(1)
            self._wait_rx()
            self._loop_ended("0x03")
            self.send(self.fw.leave_loop())
            return True
        if header not in (b"C", b"c", b"A", b"a"):
            self._consume(1)
            self._wait_rx()
            self.fw.loop = None
            self._loop_ended(f"ERR {int(ErrorFlag.INVALID_REALTIME_HEADER)} (header {bytes(header)!r})")
            self._flush_pending()
            self.send(le + f"ERR {int(ErrorFlag.INVALID_REALTIME_HEADER)}".encode() + le + PROMPT)
            return True
        size = 1 + loop.control_size if header in (b"C", b"c") else 1
        if len(self._buffer) < size:
            return False
        data = bytes(self._buffer[1:size])
        self._consume(size)
        # The sensors are sampled as the block comes in, from the twin's latest published state; the
        # control is handed to the twin to take effect once its last byte has crossed the wire.
        reply = self.fw.feedback_block() if header in (b"C", b"A") else b"*"
        if data:
            self.fw.apply_control(data, self._rx_end)
        self._replies += 1
        self._loop_blocks += 1
        self._send_reply(reply)
        return True

    def _send_reply(self, reply: bytes) -> None:
        fault = self.faults.at(self._replies)
        if fault is None:
            self.send_block(reply)
            return
        self._wait_rx()
        le = self.fw.options.line_end
        if fault.kind == "garbage":
            self.send(GARBAGE + reply)
        elif fault.kind == "drop":
            pass
        elif fault.kind == "partial":
            self.send(reply[: max(1, len(reply) // 2)])
        elif fault.kind == "late":
            self._sleep_until(time.monotonic() + float(fault.arg or 0.0))
            self.send(reply)
        elif fault.kind == "err":
            if self.fw.options.err_leaves_realtime:
                self.fw.loop = None
                self._loop_ended(f"ERR {int(fault.arg or 0)} (injected)")
                self._flush_pending()
            self.send(le + f"ERR {int(fault.arg or 0)}".encode() + le + PROMPT)
        elif fault.kind == "mute":
            self._mute_until = time.monotonic() + (fault.arg if fault.arg is not None else float("inf"))
        elif fault.kind == "vanish":
            raise _VanishedError


class EventLog:
    """Event lines passed to `on_event` from a thread of its own, so that a slow or stopped reader of
    the emulator's output (a full pipe) never holds the hand; past MAX_QUEUED waiting lines, new
    ones are dropped."""

    MAX_QUEUED = 1000

    def __init__(self, on_event: Callable[[str], None]) -> None:
        self._on_event = on_event
        self._queue: queue.Queue[str] = queue.Queue(self.MAX_QUEUED)
        # Started here, by the thread that builds the emulator: a thread started by a serial thread
        # would inherit its raised priority (raise_thread_priority).
        threading.Thread(target=self._run, name="bh8-events", daemon=True).start()

    def __call__(self, message: str) -> None:
        with contextlib.suppress(queue.Full):
            self._queue.put_nowait(message)

    def _run(self) -> None:
        while True:
            self._on_event(self._queue.get())


class HandEmulator(PortServer):
    """A twin-backed BH8-262 reachable over a pty, TCP or an in-process socket pair."""

    thread_name = "bh8-serial"
    idle_timeout_s = IDLE_TIMEOUT_S  # the host drives the BH8: a client that says nothing holds it idle

    def __init__(
        self,
        twin: RealTimeTwin,
        *,
        baud: int = 9600,
        options: WireOptions = DEFAULT_OPTIONS,
        faults: FaultPlan | None = None,
        on_event: Callable[[str], None] | None = None,
    ) -> None:
        super().__init__(on_event)
        self.twin = twin
        self.firmware = Firmware(twin, options=options, power_up_baud=baud)
        self.faults = faults or FaultPlan()
        self._exchanges = EventLog(self.on_event)
        """Each Supervisory exchange and the end of each RealTime loop, off the serial thread."""

    def _on_first_start(self) -> None:
        self.twin.start()

    def _on_close(self) -> None:
        self.twin.stop()

    def _session(self, link: Link) -> str:
        session = SerialSession(self.firmware, link, self.faults, self.stop_event, self._exchanges)
        session.priority = raise_thread_priority()
        return session.serve()

    def failed(self) -> str | None:
        """Why the emulator no longer serves (a session or the twin's physics thread died), else None."""
        return self.failure or (f"the twin stopped: {self.twin.failure}" if self.twin.failure else None)


def make_hand_emulator(
    obj: str | FoamParams | None = "block",
    *,
    baud: int = 9600,
    faults: str | None = None,
    options: WireOptions = DEFAULT_OPTIONS,
    seed: int = 0,
    on_event: Callable[[str], None] | None = None,
    stereo: bool = False,
    camera_placements: str | Sequence[str] | None = None,
) -> HandEmulator:
    """A hand emulator on a fresh twin holding `obj`: a library name, any foam (a hidden modulus, size
    or scan for an identification through the bridge), or None for the empty hand.

    `stereo`: build the twin's scene with the stereo cameras (for twin.hardware.cameras.emulator), one
    pair at each of `camera_placements` (twin.sim.cameras PLACEMENTS; None: the default pair)."""
    from twin.sim.backend import SimBackend
    from twin.sim.foam import get_object

    plan = FaultPlan.parse(faults)
    placements = None
    if camera_placements is not None:
        from twin.sim.cameras import placements_named

        placements = placements_named(camera_placements)
    foam = get_object(obj) if isinstance(obj, str) else obj
    twin = RealTimeTwin(SimBackend(foam, seed=seed, stereo=stereo, stereo_placement=placements))
    return HandEmulator(twin, baud=baud, options=options, faults=plan, on_event=on_event)


def _summary(reply: bytes, line_end: bytes) -> str:
    """A reply in one line for the event log: its result lines, `ERR n`, `*` or the prompt."""
    body = reply.removesuffix(PROMPT).strip(line_end).replace(line_end, b" | ")
    return body.decode("ascii", "replace") or "(prompt)"
