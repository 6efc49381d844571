"""A BH8-262 on a serial line, backed by the twin: pseudo-terminal, TCP or in-process socket pair.

Bytes travel at the configured baud rate both ways (10 bits per byte): a request counts as received
only once its last byte would have crossed the wire, and replies leave at line speed. Faults can be
injected into RealTime replies (see `FaultPlan`) to prove the driver's recovery and safe stops.
"""

from __future__ import annotations

import select
import threading
import time
from collections.abc import Callable

from hardware.bh262.firmware import Firmware, RealTimeTwin
from hardware.bh262.protocol import EXIT_REALTIME, PROMPT, ErrorFlag, WireOptions
from hardware.emulation import Fault, Link, PortServer, parse_faults

FAULTS = {
    "garbage": "none",
    "drop": "none",
    "partial": "none",
    "late": "required",
    "err": "required",
    "vanish": "none",
    "mute": "optional",
}
DEFAULT_OPTIONS = WireOptions()
GARBAGE = b"\x00\xfe\x13#?\x7f"
"""Line noise injected by the `garbage` fault: no '*' first, no prompt inside."""


class FaultPlan:
    """Faults on RealTime replies, from `KIND@N[:ARG],...`, e.g. `garbage@40,late@80:0.3,err@120:8192`.

    N counts the RealTime replies of a session (a TCP client's connection; on a pty, the emulator's
    life). garbage: noise before the reply; drop: no reply; partial: the first half only; late:S: the
    reply S seconds late; err:N: `ERR N` instead of the block (the hand drops to Supervisory mode);
    vanish: the port disappears; mute[:S]: nothing answered (bytes received are lost) for S seconds,
    or for good without S.
    """

    def __init__(self, faults: dict[int, Fault] | None = None) -> None:
        self.faults = faults or {}

    @classmethod
    def parse(cls, spec: str | None) -> FaultPlan:
        """Parse a --faults SPEC; ConfigError (one line) when malformed."""
        return cls(parse_faults(spec, FAULTS))

    def at(self, reply: int) -> Fault | None:
        """The fault planned for this reply, if any."""
        return self.faults.get(reply)


class _VanishedError(Exception):
    """The `vanish` fault: the port is gone."""


class SerialSession:
    """The hand's side of one serial connection: bytes in, firmware, paced bytes out."""

    def __init__(self, firmware: Firmware, link: Link, faults: FaultPlan, stop: threading.Event) -> None:
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

    def _ctrl_c(self) -> bool:
        """During a motion: has a Ctrl-C (0x03) arrived? Other bytes wait for the prompt."""
        if not select.select([self.link], [], [], 0)[0]:
            return False
        data = self.link.read()
        if not data:
            return False
        self._rx_end = max(self._rx_end, time.monotonic()) + len(data) * self._byte_s
        if EXIT_REALTIME in data:
            cut = data.index(EXIT_REALTIME)
            self._buffer += data[:cut] + data[cut + 1 :]
            return True
        self._buffer += data
        return False

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
        rest = self.fw.handle_line(line, self.send, self._ctrl_c)
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


class HandEmulator(PortServer):
    """A twin-backed BH8-262 reachable over a pty, TCP or an in-process socket pair."""

    thread_name = "bh8-serial"

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

    def _on_first_start(self) -> None:
        self.twin.start()

    def _on_close(self) -> None:
        self.twin.stop()

    def _session(self, link: Link) -> str:
        return SerialSession(self.firmware, link, self.faults, self.stop_event).serve()


def make_hand_emulator(
    object_name: str | None = "block",
    *,
    baud: int = 9600,
    faults: str | None = None,
    options: WireOptions = DEFAULT_OPTIONS,
    seed: int = 0,
    on_event: Callable[[str], None] | None = None,
    stereo: bool = False,
) -> HandEmulator:
    """A hand emulator on a fresh twin holding `object_name` from the foam library (None: no object).

    `stereo`: build the twin's scene with the two cameras (for hardware.cameras.emulator)."""
    from twin.sim.backend import SimBackend
    from twin.sim.foam import get_object

    plan = FaultPlan.parse(faults)
    foam = get_object(object_name) if object_name else None
    twin = RealTimeTwin(SimBackend(foam, seed=seed, stereo=stereo))
    return HandEmulator(twin, baud=baud, options=options, faults=plan, on_event=on_event)
