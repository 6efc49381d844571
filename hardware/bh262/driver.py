"""BH8-262 serial driver: Supervisory commands and the RealTime loop over any pyserial URL.

Opened with `serial.serial_for_url`, so a device path (/dev/ttyUSB0, a pty), `socket://host:port`,
`loop://` and `bh8emu://` (an in-process emulator on the twin) all work. Replies are read up to the
`=> ` prompt and parsed by twin.hardware.bh262.protocol; `ERR n` becomes HandCommandError naming its flags.
This module never imports the simulator.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import serial
from twin.hardware.bh262.protocol import (
    ACK,
    CR,
    EXIT_REALTIME,
    HEADER_CONTROL_FEEDBACK,
    HEADER_CONTROL_ONLY,
    HEADER_FEEDBACK_ONLY,
    HEADER_NOTHING,
    MAX_REPLY_BYTES,
    PROMPT,
    Feedback,
    FeedbackFormatError,
    RealTimeConfig,
    SupervisoryReply,
    WireOptions,
    decode_feedback,
    encode_control,
    format_command,
    parse_reply,
)

from twin.interface.errors import ConfigError, DeviceError

try:
    import termios

    TTY_ERRORS: tuple[type[Exception], ...] = (termios.error,)
    """What a vanished pty raises from tcflush (not an OSError)."""
except ImportError:  # not POSIX
    TTY_ERRORS = ()

SUPPORTED_BAUD = (600, 1200, 2400, 4800, 9600, 19200, 38400)
SCHEDULING_MARGIN_S = 0.5
"""How late a reply may come, beyond its bytes' wire time, and still count: a scheduling allowance.

A real BH8-262 answers a RealTime block within ~26 ms of its wire time
(shared/reference/bh262_protocol.md: one lab measured 33 ms per cycle at 38400 baud, 6.8 ms of it on the
wire). Everything beyond that is the host (or an emulator on the same machine) being scheduled late: with
every core busy, a Python process waits 100-500 ms for the CPU now and then (measured: RealTime replies
of `twin emulate hand` on a 2-core machine at load 7-14, p99 265 ms, worst 414 ms over 300 cycles). A
reply later than this counts as missing and the cycle is recovered; `watchdog_cycles` attempts in a row
without valid feedback stop the run, so a hand that went silent is given up on after about
(watchdog_cycles + 1) x this (2 s with the defaults: the reply, then leaving and re-entering LOOP). 50 ms
stopped half of the fault-free runs there."""
MOTOR_PREFIXES = ("", "1", "2", "3", "4", "S", "G", "GS", "12", "13", "23", "123", "1234")


class HandTimeoutError(DeviceError):
    """No complete reply from the hand within the timeout."""


class PortLostError(DeviceError):
    """The serial port failed or disappeared (EOF, EIO, a reset connection): not a silent hand."""


@dataclass(frozen=True, kw_only=True)
class PortSettings:
    """Where the hand is and how to talk to it."""

    url: str
    """A device path or a pyserial URL (socket://host:port, loop://, bh8emu://)."""
    baud: int = 9600
    """The rate the hand is at when we connect (9600 after power-up unless saved with PSAVE)."""
    switch_baud: int | None = 38400
    """Switch to this rate after connecting (PSET BAUD); None keeps `baud`."""
    timeout_s: float = 1.0
    """Supervisory replies that involve no motion."""
    motion_timeout_s: float = 15.0
    """Replies to HI, C, O, M, ...: the prompt comes once the motion has ended."""
    realtime_timeout_s: float = SCHEDULING_MARGIN_S
    """How late a RealTime reply may be beyond its wire time before it counts as missing."""
    baud_switch_wait_s: float = 1.0
    """Pause after PSET BAUD before the bare CR at the new rate (BH8-262 manual: about 1 s)."""
    recovery_timeout_s: float = SCHEDULING_MARGIN_S
    """Each step of re-entering RealTime mode after a lost reply (a live hand answers in ms; the rest
    is the same scheduling allowance)."""
    options: WireOptions = field(default_factory=WireOptions)

    def __post_init__(self) -> None:
        for name in ("baud", "switch_baud"):
            rate = getattr(self, name)
            if rate is not None and rate not in SUPPORTED_BAUD:
                raise ConfigError(f"{name} {rate} not one of {', '.join(map(str, SUPPORTED_BAUD))}")
        for name in ("timeout_s", "motion_timeout_s", "realtime_timeout_s", "recovery_timeout_s"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"{name} must be > 0")

    def byte_s(self, baud: int) -> float:
        """Wire time of one byte (8N1: 10 bits)."""
        return 10.0 / baud


class BH262:
    """One BH8-262 on a serial line."""

    def __init__(self, settings: PortSettings) -> None:
        self.settings = settings
        self.baud = settings.baud
        self.realtime: RealTimeConfig | None = None
        self._port: serial.SerialBase | None = None

    # --- port -----------------------------------------------------------------------------

    def open(self) -> None:
        """Open the port and find the prompt; switch the rate if the settings ask for it."""
        import twin.hardware.bh262.urlhandler  # noqa: F401  (registers bh8emu://)

        try:
            self._port = serial.serial_for_url(
                self.settings.url, baudrate=self.baud, timeout=self.settings.timeout_s, write_timeout=2.0
            )
        except (serial.SerialException, ValueError) as exc:
            reason = str(exc).removeprefix(f"{self.settings.url}: ")  # the URL handlers name it too
            raise DeviceError(f"cannot open the hand's port {self.settings.url}: {reason}") from None
        try:
            self.resync()
        except HandTimeoutError:
            # A session that ended without restoring the rate (a crash, a pulled cable) leaves the hand
            # at the fast rate until it is power-cycled: look for it there before giving up.
            fast = self.settings.switch_baud
            if not fast or fast == self.baud:
                raise
            self._require().baudrate = fast
            self.baud = fast
            try:
                self.resync()
            except HandTimeoutError:
                raise HandTimeoutError(
                    f"no prompt from the hand on {self.settings.url} at {self.settings.baud} or {fast} baud: "
                    "is it powered on and in Supervisory mode?"
                ) from None
        if self.settings.switch_baud and self.settings.switch_baud != self.baud:
            self.set_baud(self.settings.switch_baud)

    def close(self) -> None:
        """Close the port (safe to call twice)."""
        port, self._port = self._port, None
        if port is not None:
            with contextlib.suppress(serial.SerialException, OSError):
                port.close()

    @property
    def is_open(self) -> bool:
        """Whether the port is open."""
        return self._port is not None

    def _require(self) -> serial.SerialBase:
        if self._port is None:
            raise PortLostError(f"the hand's port {self.settings.url} is not open (closed or lost)")
        return self._port

    def _lost(self, what: str, exc: BaseException) -> PortLostError:
        """The port itself failed: say so, apart from a hand that is merely silent."""
        return PortLostError(f"the hand's port {self.settings.url} was lost: {what} failed ({exc})")

    def _write(self, data: bytes) -> None:
        try:
            self._require().write(data)
        except (serial.SerialException, OSError) as exc:
            raise self._lost("writing", exc) from None

    def _read(self, size: int, timeout_s: float) -> bytes:
        port = self._require()
        try:
            port.timeout = timeout_s
            return bytes(port.read(size))
        except (serial.SerialException, OSError) as exc:
            raise self._lost("reading", exc) from None

    def _read_until_prompt(self, timeout_s: float) -> bytes:
        port = self._require()
        try:
            port.timeout = timeout_s
            return bytes(port.read_until(PROMPT, MAX_REPLY_BYTES))
        except (serial.SerialException, OSError) as exc:
            raise self._lost("reading", exc) from None

    def _flush_input(self) -> None:
        try:
            self._require().reset_input_buffer()
        except (serial.SerialException, OSError, *TTY_ERRORS) as exc:
            raise self._lost("flushing its input", exc) from None

    # --- Supervisory ----------------------------------------------------------------------

    def resync(self, timeout_s: float | None = None) -> None:
        """Bare CR, then wait for the prompt: the documented way to find the hand's line again."""
        timeout_s = timeout_s or self.settings.timeout_s
        self._flush_input()
        self._write(CR)
        raw = self._read_until_prompt(timeout_s)
        if not raw.endswith(PROMPT):
            raise HandTimeoutError(
                f"no prompt from the hand on {self.settings.url} within {timeout_s:g} s: "
                f"is it powered on, in Supervisory mode and at {self.baud} baud?"
            )
        self._flush_input()

    def command(self, text: str, *, motion: bool = False) -> SupervisoryReply:
        """Send one Supervisory command and parse its reply (HandCommandError on ERR n)."""
        if self.realtime is not None:
            raise DeviceError(f"{text!r}: the hand is in RealTime mode; leave it first")
        self._write(format_command(text))
        timeout = self.settings.motion_timeout_s if motion else self.settings.timeout_s
        deadline = time.monotonic() + timeout
        raw = self._read_until_prompt(timeout)
        # Nothing but a prompt: an earlier resync's, come late on a busy machine; the reply follows it.
        while text.strip() and raw.endswith(PROMPT) and self._only_prompts(raw):
            left = deadline - time.monotonic()
            if left <= 0:
                break
            raw = self._read_until_prompt(left)
        if not raw.endswith(PROMPT):
            raise HandTimeoutError(f"no reply to {text!r} within {timeout:g} s (got {len(raw)} bytes)")
        return parse_reply(raw, text, self.settings.options)

    def _only_prompts(self, raw: bytes) -> bool:
        """Whether raw holds nothing but prompts and line ends (what bare CRs are answered with)."""
        return not raw.replace(PROMPT, b"").strip(self.settings.options.line_end)

    @staticmethod
    def _prefix(motors: str) -> str:
        if motors.upper() not in MOTOR_PREFIXES:
            raise ValueError(f"motor prefix {motors!r} not one of {MOTOR_PREFIXES}")
        return motors.upper()

    def initialize(self, motors: str = "") -> None:
        """HI: required after power-up or reset; opens the fingers (several seconds)."""
        self.command(f"{self._prefix(motors)}HI", motion=True)

    def close_fingers(self, motors: str = "G") -> None:
        """C: close to the CT targets; returns when the motion has ended."""
        self.command(f"{self._prefix(motors)}C", motion=True)

    def open_fingers(self, motors: str = "G") -> None:
        """O: open to the OT targets."""
        self.command(f"{self._prefix(motors)}O", motion=True)

    def move(self, motors: str, position_counts: int) -> None:
        """M: move to a position (counts), range-checked before it reaches the wire."""
        limit = 3150 if motors.upper() in ("4", "S") else 17800
        if not 0 <= int(position_counts) <= limit:
            raise ValueError(f"position {position_counts} outside 0-{limit} counts")
        self.command(f"{self._prefix(motors)}M {int(position_counts)}", motion=True)

    def step_close(self, motors: str, counts: int | None = None) -> None:
        """IC: close by `counts` (default DS)."""
        self.command(
            f"{self._prefix(motors)}IC" + (f" {int(counts)}" if counts is not None else ""), motion=True
        )

    def step_open(self, motors: str, counts: int | None = None) -> None:
        """IO: open by `counts` (default DS)."""
        self.command(
            f"{self._prefix(motors)}IO" + (f" {int(counts)}" if counts is not None else ""), motion=True
        )

    def torque_close(self, motors: str = "G") -> None:
        """TC: close under torque control."""
        self.command(f"{self._prefix(motors)}TC", motion=True)

    def torque_open(self, motors: str = "G") -> None:
        """TO: open under torque control."""
        self.command(f"{self._prefix(motors)}TO", motion=True)

    def terminate(self, motors: str = "") -> None:
        """T: motors idle (the worm drives hold the links)."""
        self.command(f"{self._prefix(motors)}T")

    def fget(self, motors: str, *props: str) -> list[int]:
        """FGET: motor properties; one value per motor (order 1-4) or per property."""
        return self.command(f"{self._prefix(motors)}FGET {' '.join(props)}").integers()

    def fget_table(self, motors: str, *props: str) -> dict[tuple[int, str], int]:
        """FGET of several motors and properties, keyed (motor, property) per WireOptions.fget_order."""
        prefix = self._prefix(motors)
        numbers = {"": (1, 2, 3, 4), "G": (1, 2, 3), "S": (4,), "GS": (1, 2, 3, 4)}
        ids = numbers.get(prefix) or tuple(sorted({4 if c == "S" else int(c) for c in prefix}))
        values = self.fget(prefix, *props)
        if len(values) != len(ids) * len(props):
            raise DeviceError(
                f"FGET {' '.join(props)}: expected {len(ids) * len(props)} values, got {values}"
            )
        if self.settings.options.fget_order == "property":
            keys = [(m, p) for p in props for m in ids]
        else:
            keys = [(m, p) for m in ids for p in props]
        return dict(zip(keys, values, strict=True))

    def fset(self, motors: str, **props: int) -> None:
        """FSET: set motor properties, e.g. fset('G', LCV=1, LFAP=1)."""
        pairs = " ".join(f"{k.upper()} {int(v)}" for k, v in props.items())
        self.command(f"{self._prefix(motors)}FSET {pairs}")

    def pget(self, prop: str) -> int:
        """PGET: one global property."""
        values = self.command(f"PGET {prop}").integers()
        if len(values) != 1:
            raise DeviceError(f"PGET {prop}: expected one value, got {values}")
        return values[0]

    def pset(self, **props: int) -> None:
        """PSET: set global properties (use set_baud for BAUD)."""
        if "BAUD" in {k.upper() for k in props}:
            raise ValueError("use set_baud() to change the rate")
        self.command("PSET " + " ".join(f"{k.upper()} {int(v)}" for k, v in props.items()))

    def reset(self) -> None:
        """RESET: firmware reset; back at 9600 baud (unless saved) and uninitialized."""
        self._write(format_command("RESET"))
        time.sleep(0.05)
        self.baud = 9600
        self._require().baudrate = 9600
        raw = self._read_until_prompt(self.settings.motion_timeout_s)
        if b"BarrettHand Firmware" not in raw:
            raise HandTimeoutError("no firmware banner after RESET")

    def set_baud(self, baud: int) -> None:
        """PSET BAUD: switch after the echo, wait, bare CR, prompt at the new rate."""
        if baud not in SUPPORTED_BAUD:
            raise ValueError(f"baud {baud} not one of {SUPPORTED_BAUD}")
        text = f"PSET BAUD {baud // 100}"
        self._write(format_command(text))
        echo = self._read(len(text), self.settings.timeout_s)
        if echo != text.encode():
            raise HandTimeoutError(f"the hand did not echo {text!r} (got {echo!r})")
        try:
            self._require().baudrate = baud
        except (serial.SerialException, OSError, ValueError) as exc:
            raise PortLostError(f"cannot switch {self.settings.url} to {baud} baud: {exc}") from None
        self.baud = baud
        time.sleep(self.settings.baud_switch_wait_s)
        self.resync()

    # --- RealTime -------------------------------------------------------------------------

    def enter_realtime(self, config: RealTimeConfig, *, lcvc: int = 1, lfvc: int = 1, lfdpc: int = 1) -> None:
        """Set the per-motor flags and coefficients, then LOOP: the hand answers its echo and '*'."""
        prefix = config.prefix
        flags = {f: int(f in config.control) for f in ("LCV", "LCPG", "LCT")}
        flags |= {f: int(f in config.feedback) for f in ("LFV", "LFS", "LFAP", "LFDP", "LFBP", "LFAIN")}
        self.command(f"{prefix}FSET " + " ".join(f"{k} {v}" for k, v in flags.items()))
        self.command(f"{prefix}FSET LCVC {lcvc} LFVC {lfvc} LFDPC {lfdpc}")
        self.command(f"PSET LFT {int(config.temperature)}")
        self._loop(config)

    def _loop(self, config: RealTimeConfig, timeout_s: float | None = None) -> None:
        timeout_s = timeout_s or self.settings.timeout_s
        text = f"{config.prefix}LOOP"
        self._write(format_command(text))
        raw = self._read_loop_answer(text, timeout_s)
        if raw == text.encode() + ACK:
            self.realtime = config
            return
        if raw.startswith(text.encode()) and raw.endswith(PROMPT):
            parse_reply(raw, text, self.settings.options)  # raises HandCommandError on ERR n
        raise HandTimeoutError(f"{text}: no '*' from the hand within {timeout_s:g} s (got {raw[-40:]!r})")

    def _read_loop_answer(self, text: str, timeout_s: float) -> bytes:
        """LOOP's answer from its echo on: the echo and '*', or an error reply up to the prompt.

        Bytes before the echo are an earlier answer that came late (a resync's prompt on a busy
        machine: the stream is in order, so everything before our echo is stale) and are skipped."""
        echo = text.encode()
        expected = echo + ACK
        deadline = time.monotonic() + timeout_s
        raw = b""
        while len(raw) <= MAX_REPLY_BYTES:
            start = raw.rfind(echo)
            answer = raw[start:] if start >= 0 else b""
            if answer == expected or answer.endswith(PROMPT):
                return answer
            left = deadline - time.monotonic()
            if left <= 0:
                break
            if len(answer) >= len(expected):  # something else than '*' after the echo: up to the prompt
                return answer + self._read_until_prompt(left)
            # Read no further than the end of the expected answer: RealTime blocks may follow it.
            overlap = max(k for k in range(len(expected) + 1) if raw.endswith(expected[:k]))
            chunk = self._read(len(expected) - overlap, left)
            if not chunk:
                break
            raw += chunk
        start = raw.rfind(echo)
        return raw[start:] if start >= 0 else raw

    def cycle(
        self, control: dict[str, Sequence[int]] | None = None, *, feedback: bool = True
    ) -> Feedback | None:
        """One RealTime block: header C/c (with control) or A/a, and the hand's reply."""
        config = self.realtime
        if config is None:
            raise DeviceError("not in RealTime mode; call enter_realtime() first")
        if control is not None:
            out = encode_control(
                config, control, HEADER_CONTROL_FEEDBACK if feedback else HEADER_CONTROL_ONLY
            )
        else:
            out = HEADER_FEEDBACK_ONLY if feedback else HEADER_NOTHING
        size = config.feedback_size if feedback else 1
        wire_s = (len(out) + size) * self.settings.byte_s(self.baud)
        self._write(out)
        block = self._read(size, wire_s + self.settings.realtime_timeout_s)
        if block[:1] != ACK and block:
            self._error_reply(block)
        if len(block) < size:
            raise HandTimeoutError(
                f"RealTime reply: {len(block)} of {size} bytes within {wire_s * 1e3:.0f} ms of wire time "
                f"+ {self.settings.realtime_timeout_s * 1e3:.0f} ms allowed late"
            )
        return decode_feedback(config, block) if feedback else None

    def _error_reply(self, head: bytes) -> None:
        """A reply that does not start with '*': an ERR (the hand is back in Supervisory) or noise."""
        le = self.settings.options.line_end
        raw = head
        if head.startswith(le[:1]):
            raw += self._read_until_prompt(self.settings.timeout_s)
            if raw.endswith(PROMPT):
                if self.settings.options.err_leaves_realtime:
                    self.realtime = None
                parse_reply(raw, "", self.settings.options)  # raises HandCommandError on ERR n
        raise FeedbackFormatError(f"RealTime reply starts with {head[:8]!r}, not '*'")

    def leave_realtime(self) -> None:
        """0x03, then read up to the prompt: back in Supervisory mode."""
        if self.realtime is None:
            return
        self._write(EXIT_REALTIME)
        raw = self._read_until_prompt(self.settings.timeout_s)
        self.realtime = None
        if not raw.endswith(PROMPT):
            raise HandTimeoutError("no prompt after leaving RealTime mode")

    def recover_realtime(self, config: RealTimeConfig) -> None:
        """After noise or a missing reply: leave RealTime (if still in it), find the prompt, LOOP again."""
        timeout = self.settings.recovery_timeout_s
        if self.realtime is not None:
            self._write(EXIT_REALTIME)
            self._read_until_prompt(timeout)  # whatever was in flight, up to the prompt
            self.realtime = None
        self.resync(timeout)
        self._loop(config, timeout)
