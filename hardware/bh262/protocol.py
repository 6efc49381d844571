"""BH8-262 wire format: supervisory commands and replies, ERR flags, RealTime blocks.

Pure bytes in, values out (and back), shared by the driver and the emulator. Ambiguities marked (?)
in bh262_protocol.md are options of `WireOptions` with the stated defaults, never buried guesses.
Every malformed input raises a ProtocolError subclass; nothing else escapes the parsers.
"""

from __future__ import annotations

import re
import struct
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import IntFlag

from twin.interface.errors import DeviceError

PROMPT = b"=> "
CR = b"\r"
EXIT_REALTIME = b"\x03"
MAX_REPLY_BYTES = 4096


class ProtocolError(DeviceError):
    """Bytes that do not follow the BH8-262 protocol (a DeviceError: the CLI reports it in one line)."""


class ReplyFormatError(ProtocolError):
    """A supervisory reply that cannot be parsed (missing prompt, echo mismatch, stray bytes)."""


class FeedbackFormatError(ProtocolError):
    """A RealTime block of the wrong length or header."""


class ErrorFlag(IntFlag):
    """ERR n bit flags (BH8-262 manual); several may be summed."""

    NO_MOTOR_BOARD = 1
    NO_MOTOR = 2
    MOTOR_NOT_INITIALIZED = 4
    COULD_NOT_REACH_POSITION = 16
    UNKNOWN_COMMAND = 32
    UNKNOWN_PARAMETER = 64
    INVALID_VALUE = 128
    WRITE_TO_READ_ONLY = 256
    TOO_MANY_ARGUMENTS = 1024
    INVALID_REALTIME_HEADER = 2048
    INVALID_MOTOR_PREFIX = 4096
    OVER_TEMPERATURE = 8192
    ABORTED_BY_CTRL_C = 16384


KNOWN_FLAGS = sum(int(f) for f in ErrorFlag)


class HandCommandError(ProtocolError):
    """The hand answered ERR n: `flags` names every bit that was set."""

    def __init__(self, code: int, command: str = "") -> None:
        self.code = code
        self.command = command
        self.flags = ErrorFlag(code & KNOWN_FLAGS)
        names = [f.name for f in ErrorFlag if f in self.flags] or ["UNKNOWN"]
        unknown = code & ~KNOWN_FLAGS
        extra = f" + unknown bits {unknown:#x}" if unknown else ""
        where = f" to {command!r}" if command else ""
        super().__init__(f"hand replied ERR {code}{where}: {', '.join(names)}{extra}")


@dataclass(frozen=True)
class WireOptions:
    """Choices where public sources disagree (bh262_protocol.md, items marked (?))."""

    line_end: bytes = b"\n\r"
    """Reply line separator: LF CR, as the clients expect; the manual writes "CRLF"."""
    temperature_bytes: int = 1
    """RealTime LFT temperature: 1 unsigned byte (firmware 4.4) or 2 signed big-endian (4.3x)."""
    velocity_unit_s: float = 0.010
    """RealTime and MCV/MOV velocities in counts per 10 ms, as Barrett's API reads them; one client
    assumes a x16 scale per 409.6 us sample instead (409.6 us / 16 = 25.6 us)."""
    fget_order: str = "motor"
    """FGET with several motors and several properties: "motor" (each motor's properties in turn) or
    "property" (each property for every motor); the manual does not say."""
    err_leaves_realtime: bool = True
    """An ERR during RealTime returns the hand to Supervisory mode (the clients assume so)."""

    def __post_init__(self) -> None:
        if self.line_end not in (b"\n\r", b"\r\n"):
            raise ValueError("line_end must be LF CR or CR LF")
        if self.temperature_bytes not in (1, 2):
            raise ValueError("temperature_bytes must be 1 (firmware 4.4) or 2 (4.3x)")
        if not any(abs(self.velocity_unit_s - u) < 1e-12 for u in (0.010, 409.6e-6 / 16)):
            raise ValueError("velocity_unit_s must be 0.010 (API) or 25.6e-6 (x16 at 409.6 us)")
        if self.fget_order not in ("motor", "property"):
            raise ValueError('fget_order must be "motor" or "property"')


def format_command(command: str) -> bytes:
    """One supervisory command line: ASCII words ended by CR."""
    if not command.isascii() or any(c in command for c in "\r\n\x03"):
        raise ValueError(f"not a supervisory command: {command!r}")
    return command.strip().encode("ascii") + CR


@dataclass(frozen=True)
class SupervisoryReply:
    """A parsed reply: the echoed command and the result lines (empty when none)."""

    echo: str
    lines: tuple[str, ...]

    def integers(self) -> list[int]:
        """The result as space-separated integers (FGET/PGET)."""
        try:
            return [int(v) for line in self.lines for v in line.split()]
        except ValueError:
            raise ReplyFormatError(f"expected integers, got {self.lines!r}") from None


_ERR = re.compile(rb"ERR (\d{1,6})")


def split_reply(buffer: bytes) -> tuple[bytes, bytes] | None:
    """(one reply up to and including the prompt, the rest), or None while incomplete."""
    end = buffer.find(PROMPT)
    if end < 0:
        if len(buffer) > MAX_REPLY_BYTES:
            raise ReplyFormatError(f"no prompt within {MAX_REPLY_BYTES} bytes")
        return None
    end += len(PROMPT)
    return buffer[:end], buffer[end:]


def parse_reply(raw: bytes, command: str, options: WireOptions = WireOptions()) -> SupervisoryReply:
    """Parse `<echo>LE[result LE]=> ` or `<echo>LE ERR n LE=> `; raises HandCommandError on ERR."""
    if not raw.endswith(PROMPT):
        raise ReplyFormatError("reply does not end with the '=> ' prompt")
    body = raw[: -len(PROMPT)]
    le = options.line_end
    echo_bytes = command.strip().encode("ascii", "replace")
    if not body.startswith(echo_bytes):
        raise ReplyFormatError(f"reply does not echo {command!r}")
    rest = body[len(echo_bytes) :]
    if not rest:
        if echo_bytes:
            raise ReplyFormatError("reply has no line end after the echo")
        return SupervisoryReply("", ())
    if not rest.startswith(le) or not rest.endswith(le):
        raise ReplyFormatError("reply lines are not separated by the configured line end")
    lines = [line for line in rest[len(le) : len(rest) - len(le)].split(le)] if len(rest) > len(le) else []
    for line in lines:
        if not line.isascii() or any(b < 0x20 or b == 0x7F for b in line):
            raise ReplyFormatError("reply contains non-printable bytes")
    text = [line.decode("ascii") for line in lines]
    if len(text) == 1:
        match = _ERR.fullmatch(lines[0])
        if match:
            raise HandCommandError(int(match.group(1)), command)
    return SupervisoryReply(echo_bytes.decode("ascii"), tuple(text))


def format_reply(command: str, lines: Sequence[str] = (), options: WireOptions = WireOptions()) -> bytes:
    """What the hand sends back for `command` (the emulator's side of parse_reply)."""
    le = options.line_end
    echo = command.strip().encode("ascii")
    body = le.join(line.encode("ascii") for line in lines)
    if not echo and not lines:
        return PROMPT
    return echo + le + (body + le if lines else b"") + PROMPT


def format_error(command: str, code: int, options: WireOptions = WireOptions()) -> bytes:
    """An ERR reply to `command`."""
    return format_reply(command, [f"ERR {code}"], options)


# --- RealTime mode ----------------------------------------------------------------------------

CONTROL_FIELDS = ("LCV", "LCPG", "LCT")
FEEDBACK_FIELDS = ("LFV", "LFS", "LFAP", "LFDP", "LFBP", "LFAIN")
_FORMAT = {
    "LCV": "b",
    "LCPG": "B",
    "LCT": "h",
    "LFV": "b",
    "LFS": "B",
    "LFAP": "H",
    "LFDP": "b",
    "LFBP": "H",
    "LFAIN": "B",
}
HEADER_CONTROL_FEEDBACK = b"C"
HEADER_CONTROL_ONLY = b"c"
HEADER_FEEDBACK_ONLY = b"A"
HEADER_NOTHING = b"a"
ACK = b"*"


@dataclass(frozen=True)
class RealTimeConfig:
    """Which motors take part in LOOP and which control/feedback fields each cycle carries."""

    motors: tuple[int, ...] = (1, 2, 3, 4)
    control: tuple[str, ...] = ("LCV", "LCPG")
    feedback: tuple[str, ...] = ("LFV", "LFS", "LFAP")
    temperature: bool = False
    options: WireOptions = field(default_factory=WireOptions)

    def __post_init__(self) -> None:
        if (
            not self.motors
            or sorted(set(self.motors)) != list(self.motors)
            or not set(self.motors) <= {1, 2, 3, 4}
        ):
            raise ValueError(f"motors must be an increasing subset of 1-4, got {self.motors}")
        if not set(self.control) <= set(CONTROL_FIELDS) or not set(self.feedback) <= set(FEEDBACK_FIELDS):
            raise ValueError("unknown RealTime field")
        if "LCT" in self.control and ({"LCV", "LCPG"} & set(self.control)):
            raise ValueError("LCT cannot be combined with LCV or LCPG (BH8-262 manual)")
        # Canonical order on the wire, whatever order the caller gave.
        object.__setattr__(self, "control", tuple(f for f in CONTROL_FIELDS if f in self.control))
        object.__setattr__(self, "feedback", tuple(f for f in FEEDBACK_FIELDS if f in self.feedback))

    @property
    def prefix(self) -> str:
        """Motor prefix of the LOOP command, e.g. '1234'."""
        return "".join(str(m) for m in self.motors)

    def _struct(self, names: Sequence[str]) -> struct.Struct:
        return struct.Struct(">" + "".join(_FORMAT[n] for n in names) * len(self.motors))

    @property
    def control_size(self) -> int:
        """Bytes of control data after the header byte."""
        return self._struct(self.control).size

    @property
    def feedback_size(self) -> int:
        """Bytes of a feedback block, '*' included."""
        temp = self.options.temperature_bytes if self.temperature else 0
        return 1 + self._struct(self.feedback).size + temp

    def wire_limit_hz(self, baud: int) -> float:
        """Cycle-rate bound of a C-header cycle at `baud` (10 bits per byte on the wire)."""
        return baud / (10 * (1 + self.control_size + self.feedback_size))


def encode_control(config: RealTimeConfig, values: dict[str, Sequence[int]], header: bytes = b"C") -> bytes:
    """Header byte + control data; values[field] holds one integer per active motor."""
    if header not in (HEADER_CONTROL_FEEDBACK, HEADER_CONTROL_ONLY):
        raise ValueError("control data goes with header C or c")
    flat = [values[f][i] for i in range(len(config.motors)) for f in config.control]
    try:
        return header + config._struct(config.control).pack(*flat)
    except struct.error as exc:
        raise ValueError(f"control value out of range: {exc}") from None


def decode_control(config: RealTimeConfig, data: bytes) -> dict[str, list[int]]:
    """The emulator's side: control data (without the header) -> per-field lists."""
    s = config._struct(config.control)
    if len(data) != s.size:
        raise FeedbackFormatError(f"control data is {len(data)} bytes, expected {s.size}")
    flat = s.unpack(data)
    n = len(config.control)
    return {f: list(flat[k::n]) for k, f in enumerate(config.control)}


@dataclass(frozen=True)
class Feedback:
    """One decoded feedback block: per-field lists (one value per active motor), temperature."""

    fields: dict[str, list[int]]
    temperature: int | None = None


def decode_feedback(config: RealTimeConfig, block: bytes) -> Feedback:
    """'*' + per-motor fields (+ temperature) -> values; FeedbackFormatError on any mismatch."""
    if len(block) != config.feedback_size:
        raise FeedbackFormatError(f"feedback block is {len(block)} bytes, expected {config.feedback_size}")
    if block[:1] != ACK:
        raise FeedbackFormatError(f"feedback block starts with {block[:1]!r}, not '*'")
    s = config._struct(config.feedback)
    flat = s.unpack(block[1 : 1 + s.size])
    n = len(config.feedback)
    fields = {f: list(flat[k::n]) for k, f in enumerate(config.feedback)}
    temperature = None
    if config.temperature:
        raw = block[1 + s.size :]
        temperature = raw[0] if len(raw) == 1 else struct.unpack(">h", raw)[0]
    return Feedback(fields, temperature)


def encode_feedback(config: RealTimeConfig, feedback: Feedback) -> bytes:
    """The emulator's side of decode_feedback (values are clipped to their wire types first)."""
    flat = []
    for i in range(len(config.motors)):
        for f in config.feedback:
            flat.append(_clip(_FORMAT[f], int(feedback.fields[f][i])))
    out = ACK + config._struct(config.feedback).pack(*flat)
    if config.temperature:
        t = int(feedback.temperature or 0)
        out += (
            bytes([_clip("B", t)])
            if config.options.temperature_bytes == 1
            else struct.pack(">h", _clip("h", t))
        )
    return out


_RANGES = {"b": (-128, 127), "B": (0, 255), "h": (-32768, 32767), "H": (0, 65535)}


def _clip(fmt: str, value: int) -> int:
    lo, hi = _RANGES[fmt]
    return max(lo, min(hi, value))
