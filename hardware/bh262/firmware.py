"""The BH8-262 firmware, emulated on the MuJoCo twin: commands, motor properties, RealTime blocks.

Written from bh262_protocol.md, not from our driver. The twin runs in real time on a thread of its
own (`RealTimeTwin`); the firmware turns each supervisory line or RealTime block into motion of the
simulated hand and answers from the simulated sensors. Choices where the documentation is silent:
  - the (?) items of bh262_protocol.md follow WireOptions (velocity unit, FGET order, line end,
    temperature bytes, whether ERR leaves RealTime mode);
  - RealTime velocity control (LCV) drives each motor's set point at the commanded velocity, the same
    slewed servo the twin uses for every motion (a stalled finger keeps the force it built up);
  - LFT sends the temperature in whole degrees C (1 byte, firmware 4.4) or tenths (2 bytes, 4.3x).
Emulators may import the simulator (architecture.md); drivers never do.
"""

from __future__ import annotations

import atexit
import struct
import threading
import time
import weakref
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from hardware.bh262.protocol import (
    ACK,
    CONTROL_FIELDS,
    FEEDBACK_FIELDS,
    PROMPT,
    ErrorFlag,
    WireOptions,
)
from twin import units
from twin.interface.devices import HandReading
from twin.sim.backend import SimBackend

DEFAULT_OPTIONS = WireOptions()
CATCH_UP_LAG_S = 0.010
"""Sensors are sampled, and commands applied, with the twin at most this far behind wall time..."""
CATCH_UP_TIMEOUT_S = 0.03
"""...waiting at most this long for it (beyond, the reply is simply late)."""
BANNER = "BarrettHand Firmware Version 4.4.3 (barrett-twin emulator)"
SUPPORTED_BAUD = (600, 1200, 2400, 4800, 9600, 19200, 38400)
MOTORS = (1, 2, 3, 4)
SPREAD = 4
_CONTROL_FMT = {"LCV": "b", "LCPG": "B", "LCT": "h"}
_FEEDBACK_FMT = {"LFV": "b", "LFS": "B", "LFAP": "H", "LFDP": "b", "LFBP": "H", "LFAIN": "B"}
# Motor properties: default value and allowed range; None marks a read-only property.
_FINGER_PROPS: dict[str, tuple[int, tuple[int, int] | None]] = {
    "P": (0, None),
    "S": (0, None),
    "SG": (0, None),
    "BD": (0, None),
    "BP": (0, None),
    "MCV": (100, (16, 4080)),
    "MOV": (100, (16, 4080)),
    "HSG": (256, (0, 256)),
    "LSG": (0, (0, 256)),
    "HOLD": (0, (0, 1)),
    "MPE": (1000, (0, 65535)),
    "TSTOP": (50, (0, 65535)),
    "DP": (8500, (0, units.FINGER_MAX_COUNTS)),
    "DS": (1000, (0, units.FINGER_MAX_COUNTS)),
    "OT": (0, (0, units.FINGER_MAX_COUNTS)),
    "CT": (units.FINGER_FULL_COUNTS, (0, units.FINGER_MAX_COUNTS)),
    "FPG": (100, (0, 255)),
    **{f: (0, (0, 1)) for f in (*CONTROL_FIELDS, *FEEDBACK_FIELDS)},
    "LCVC": (1, (1, 255)),
    "LFVC": (1, (1, 255)),
    "LFDPC": (1, (1, 255)),
}
_SPREAD_OVERRIDES = {
    "MCV": 60,
    "MOV": 60,
    "DP": 1570,
    "DS": 300,
    "CT": units.SPREAD_FULL_COUNTS,
}
_GLOBAL_PROPS: dict[str, tuple[int, tuple[int, int] | None]] = {
    "BAUD": (96, (6, 384)),
    "TEMP": (300, None),
    "OTEMP": (700, (0, 1000)),
    "PTEMP": (300, None),
    "SN": (2620, None),
    "LFT": (0, (0, 1)),
    "LFDPD": (0, (0, 1)),
}


class FirmwareError(Exception):
    """An ERR reply: `code` is the sum of ErrorFlag bits."""

    def __init__(self, *flags: ErrorFlag) -> None:
        self.code = int(sum(flags))
        super().__init__(f"ERR {self.code}")


_LIVE_TWINS: weakref.WeakSet[RealTimeTwin] = weakref.WeakSet()


@atexit.register
def _halt_twins_at_exit() -> None:
    """A twin still stepping at exit (an emulator never closed, e.g. a `bh8emu://` port left open by an
    error) would be inside mj_step, without the GIL, while the interpreter frees its model and data:
    a segmentation fault. Halt them all first."""
    for twin in list(_LIVE_TWINS):
        twin.halt()


class RealTimeTwin:
    """A SimBackend stepped to wall time on a background thread; `lock` guards every access to MuJoCo
    (stepping, sensors, commands, the cameras' state copies)."""

    def __init__(self, backend: SimBackend, *, chunk_s: float = 0.002) -> None:
        self.backend = backend
        self.lock = threading.RLock()
        self._chunk_s = chunk_s
        self._t0 = time.monotonic() - backend.world.time_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="bh8-twin", daemon=True)
        self.lag_s = 0.0
        """Worst lag of sim time behind wall time so far (s)."""
        self.failure: str | None = None
        """Why the stepping thread died (one line), None while it runs or after a clean stop."""
        _LIVE_TWINS.add(self)

    def start(self) -> None:
        """Connect the sim devices and start stepping (once; later calls do nothing)."""
        if self._thread.is_alive():
            return
        with self.lock:
            for device in self.backend.devices():  # the hand, and the tactile pads for the rig emulator
                if device is self.backend.stereo:  # the camera emulator renders on its own GL context
                    continue
                if not device.is_connected:
                    device.connect()
        self._thread.start()

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop stepping (the world stays as it is)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=timeout_s)

    def halt(self) -> None:
        """Stop stepping and take the lock for good: no thread (physics, serial, cameras) enters MuJoCo
        on this twin again. Called at interpreter exit, before MuJoCo's model and data are freed."""
        self.stop()
        self.lock.acquire(timeout=5.0)

    def now(self) -> float:
        """Wall time on the twin's clock (s)."""
        return time.monotonic() - self._t0

    def catch_up(self, max_lag_s: float = CATCH_UP_LAG_S, timeout_s: float = CATCH_UP_TIMEOUT_S) -> None:
        """Wait (briefly) until sim time is within max_lag_s of wall time.

        A real hand never falls behind; a twin starved of CPU can, and then its sensors would report
        the past and commands would act late. Sampling and commanding wait for it instead, so a busy
        machine shows up as a late reply (which the driver tolerates or recovers from), not as a hand
        in another state than it should be.
        """
        if not self._thread.is_alive():
            return
        deadline = time.monotonic() + timeout_s
        world = self.backend.world
        while self.now() - world.time_s > max_lag_s and time.monotonic() < deadline:
            time.sleep(0.0005)

    def _run(self) -> None:
        try:
            self._step_forever()
        except Exception as exc:  # recorded for the emulator to report (HandEmulator.failed)
            self.failure = f"{type(exc).__name__}: {exc}"

    def _step_forever(self) -> None:
        world = self.backend.world
        while not self._stop.is_set():
            target = self.now()
            with self.lock:  # short holds so that the serial thread is never kept waiting long
                world.advance_to(min(target, world.time_s + self._chunk_s))
                behind = target - world.time_s
            self.lag_s = max(self.lag_s, behind)
            if behind < world.timestep_s:
                time.sleep(world.timestep_s)


@dataclass
class LoopState:
    """RealTime mode: the motors taking part and the block layouts fixed when LOOP was entered."""

    motors: tuple[int, ...]
    control: dict[int, tuple[str, ...]]
    feedback: dict[int, tuple[str, ...]]
    temperature: bool
    control_size: int = 0
    velocity_counts_s: np.ndarray = field(default_factory=lambda: np.zeros(4))

    def __post_init__(self) -> None:
        self.control_size = sum(
            struct.calcsize(">" + "".join(_CONTROL_FMT[f] for f in self.control[m])) for m in self.motors
        )


class Firmware:
    """Answers supervisory lines and RealTime blocks from the twin, as the BH8-262 would."""

    def __init__(
        self,
        twin: RealTimeTwin,
        *,
        options: WireOptions = DEFAULT_OPTIONS,
        power_up_baud: int = 9600,
        motion_timeout_s: float = 8.0,
    ) -> None:
        if power_up_baud not in SUPPORTED_BAUD:
            raise ValueError(f"baud {power_up_baud} not one of {SUPPORTED_BAUD}")
        self.twin = twin
        self.options = options
        self.motion_timeout_s = motion_timeout_s
        self._saved_baud = power_up_baud
        self.baud = power_up_baud
        self.initialized = False
        self.loop: LoopState | None = None
        self.commands: list[str] = []
        """Every supervisory line received, in order (what a test or a log looks at)."""
        self.controls_received = 0
        self.last_control: dict[int, dict[str, int]] = {}
        """The latest RealTime control block, decoded per motor."""
        self._reset_properties()
        self._last_reported = np.zeros(4)
        self._abort: Callable[[], bool] = lambda: False

    # --- properties -----------------------------------------------------------------------

    def _reset_properties(self) -> None:
        self.props = {m: {k: v for k, (v, _) in _FINGER_PROPS.items()} for m in MOTORS}
        self.props[SPREAD].update(_SPREAD_OVERRIDES)
        self.globals = {k: v for k, (v, _) in _GLOBAL_PROPS.items()}
        self.globals["BAUD"] = self.baud // 100

    def _read_prop(self, motor: int, name: str, reading: HandReading) -> int:
        live = {
            "P": int(reading.position_counts[motor - 1]),
            "S": 0,
            "SG": int(reading.strain_counts[motor - 1]) if motor != SPREAD else 255,
            "BD": int(self._broken_away()[motor - 1]),
            "BP": int(self._breakaway_counts()[motor - 1]),
        }
        return live.get(name, self.props[motor][name])

    def _broken_away(self) -> np.ndarray:
        return np.append(self.twin.backend.world.clutches.broken_away, False)

    def _breakaway_counts(self) -> np.ndarray:
        clutches = self.twin.backend.world.clutches.fingers
        rad = [c.drive_at_breakaway_rad if c.broken_away else 0.0 for c in clutches]
        return np.append(np.round(units.inner_rad_to_finger_counts(rad)), 0)

    # --- supervisory ----------------------------------------------------------------------

    def banner(self) -> bytes:
        """What power-up and RESET print."""
        le = self.options.line_end
        return le + BANNER.encode() + le + PROMPT

    def handle_line(
        self,
        line: str,
        send_echo: Callable[[bytes], None],
        abort: Callable[[], bool] = lambda: False,
    ) -> bytes:
        """One supervisory line (without CR): `send_echo` is called first; returns the rest of the reply.

        Motion commands return only when the motion has ended, as the prompt does on the hand; `abort()`
        is polled meanwhile and True (a Ctrl-C on the line) stops the motors with ERR 16384.
        """
        le = self.options.line_end
        text = line.strip()
        self._abort = abort
        send_echo(line.encode("ascii", "replace"))  # every character as typed, the CR aside
        self.commands.append(text)
        if not text:
            return PROMPT
        try:
            result = self._dispatch(text)
        except FirmwareError as err:
            return le + f"ERR {err.code}".encode() + le + PROMPT
        if isinstance(result, bytes):  # LOOP: '*' with no line end
            return result
        lines = [str(r) for r in result] if result else []
        body = " ".join(lines).encode()
        return le + (body + le if lines else b"") + PROMPT

    def _dispatch(self, text: str) -> list[int] | bytes | None:
        words = text.upper().split()
        motors, verb = _split_prefix(words[0])
        args = words[1:]
        if verb in ("FGET", "FSET", "PGET", "PSET", "FDEF", "FLOAD", "FSAVE", "PDEF", "PLOAD", "PSAVE"):
            return self._properties(verb, motors, args)
        if verb == "RESET":
            return self._reset()
        if verb == "HI":
            return self._hi(motors)
        if not self.initialized and verb in ("C", "O", "M", "HOME", "IC", "IO", "TC", "TO", "LOOP"):
            raise FirmwareError(ErrorFlag.MOTOR_NOT_INITIALIZED)
        if verb == "LOOP":
            if args:
                raise FirmwareError(ErrorFlag.TOO_MANY_ARGUMENTS)
            return self._enter_loop(motors)
        if verb == "T":
            with self.twin.lock:
                self.twin.backend.hand.idle()
            return None
        if verb in ("C", "TC"):
            return self._move(motors, {m: self.props[m]["CT"] for m in motors}, "MCV")
        if verb in ("O", "TO"):
            return self._move(motors, {m: self.props[m]["OT"] for m in motors}, "MOV")
        if verb == "HOME":
            return self._move(motors, dict.fromkeys(motors, 0), "MOV")
        if verb == "M":
            targets = {m: self._int_arg(args, self.props[m]["DP"]) for m in motors}
            return self._move(motors, targets, "MCV")
        if verb in ("IC", "IO"):
            sign = 1 if verb == "IC" else -1
            reading = self._read()
            targets = {
                m: int(reading.position_counts[m - 1]) + sign * self._int_arg(args, self.props[m]["DS"])
                for m in motors
            }
            return self._move(motors, targets, "MCV" if sign > 0 else "MOV")
        raise FirmwareError(ErrorFlag.UNKNOWN_COMMAND)

    @staticmethod
    def _int_arg(args: list[str], default: int) -> int:
        if len(args) > 1:
            raise FirmwareError(ErrorFlag.TOO_MANY_ARGUMENTS)
        if not args:
            return default
        try:
            return int(args[0])
        except ValueError:
            raise FirmwareError(ErrorFlag.INVALID_VALUE) from None

    def _read(self) -> HandReading:
        self.twin.catch_up()
        with self.twin.lock:
            return self.twin.backend.hand.read()

    def _properties(self, verb: str, motors: tuple[int, ...], args: list[str]) -> list[int] | None:
        if verb == "FGET":
            if not args:
                raise FirmwareError(ErrorFlag.UNKNOWN_PARAMETER)
            for a in args:
                if a not in _FINGER_PROPS:
                    raise FirmwareError(ErrorFlag.UNKNOWN_PARAMETER)
            reading = self._read()
            if self.options.fget_order == "property":
                return [self._read_prop(m, a, reading) for a in args for m in motors]
            return [self._read_prop(m, a, reading) for m in motors for a in args]
        if verb == "FSET":
            pairs = self._pairs(args)
            for name, value in pairs:
                _check(_FINGER_PROPS, name, value)
            for m in motors:
                for name, value in pairs:
                    self.props[m][name] = value
            return None
        if verb == "PGET":
            if len(args) != 1:
                raise FirmwareError(ErrorFlag.UNKNOWN_PARAMETER if not args else ErrorFlag.TOO_MANY_ARGUMENTS)
            if args[0] not in _GLOBAL_PROPS:
                raise FirmwareError(ErrorFlag.UNKNOWN_PARAMETER)
            return [self.globals[args[0]]]
        if verb == "PSET":
            pairs = self._pairs(args)
            for name, value in pairs:
                _check(_GLOBAL_PROPS, name, value)
                if name == "BAUD" and value * 100 not in SUPPORTED_BAUD:
                    raise FirmwareError(ErrorFlag.INVALID_VALUE)
            for name, value in pairs:
                self.globals[name] = value
            return None
        if verb in ("FDEF", "PDEF"):
            baud = self.baud
            self._reset_properties()
            self.baud = baud
            self.globals["BAUD"] = baud // 100
            return None
        if verb == "PSAVE":
            self._saved_baud = self.globals["BAUD"] * 100
        return None  # FLOAD, FSAVE, PLOAD: nothing else is kept across resets

    @staticmethod
    def _pairs(args: list[str]) -> list[tuple[str, int]]:
        if not args or len(args) % 2:
            raise FirmwareError(ErrorFlag.INVALID_VALUE)
        try:
            return [(args[i], int(args[i + 1])) for i in range(0, len(args), 2)]
        except ValueError:
            raise FirmwareError(ErrorFlag.INVALID_VALUE) from None

    def pending_baud(self) -> int | None:
        """The new rate after `PSET BAUD n` (the server switches after the echo), else None."""
        rate = self.globals["BAUD"] * 100
        return rate if rate != self.baud else None

    def _reset(self) -> bytes:
        self.loop = None
        self.initialized = False
        self.baud = self._saved_baud
        self._reset_properties()
        with self.twin.lock:
            self.twin.backend.hand.idle()
        return self.banner()

    def _hi(self, motors: tuple[int, ...]) -> None:
        self._move(motors, dict.fromkeys(motors, 0), "MOV")
        self.initialized = True

    def _move(self, motors: tuple[int, ...], targets: dict[int, int], velocity_prop: str) -> None:
        """Drive the motors to their targets and return once they have stopped (or stalled)."""
        hand = self.twin.backend.hand
        with self.twin.lock:
            goal = hand.motor_setpoint_counts()
            speed = np.zeros(4)
            for m in motors:
                limit = units.SPREAD_FULL_COUNTS if m == SPREAD else units.FINGER_MAX_COUNTS
                goal[m - 1] = min(max(targets[m], 0), limit)
                speed[m - 1] = self.props[m][velocity_prop] / self.options.velocity_unit_s
            hand.drive(goal, np.where(speed > 0, speed, 1.0))
        deadline = time.monotonic() + self.motion_timeout_s
        last = None
        while time.monotonic() < deadline:
            time.sleep(0.02)
            if self._abort():
                with self.twin.lock:
                    hand.drive(hand.motor_setpoint_counts(), np.zeros(4))  # stop where the servos are
                raise FirmwareError(ErrorFlag.ABORTED_BY_CTRL_C)
            reading = self._read()
            with self.twin.lock:
                at_goal = np.allclose(hand.motor_setpoint_counts(), goal, atol=1.0)
            if at_goal and last is not None and np.abs(reading.position_counts - last).max() <= 2:
                return None
            last = reading.position_counts
        raise FirmwareError(ErrorFlag.COULD_NOT_REACH_POSITION)

    # --- RealTime -------------------------------------------------------------------------

    def _enter_loop(self, motors: tuple[int, ...]) -> bytes:
        for m in motors:
            if self.props[m]["LCT"] and (self.props[m]["LCV"] or self.props[m]["LCPG"]):
                raise FirmwareError(ErrorFlag.INVALID_VALUE)
        self.loop = LoopState(
            motors=motors,
            control={m: tuple(f for f in CONTROL_FIELDS if self.props[m][f]) for m in motors},
            feedback={m: tuple(f for f in FEEDBACK_FIELDS if self.props[m][f]) for m in motors},
            temperature=bool(self.globals["LFT"]),
        )
        self._last_reported = self._read().position_counts.astype(float)
        return ACK

    def apply_control(self, data: bytes) -> None:
        """Control data of one RealTime block (length loop.control_size)."""
        loop = self.loop
        assert loop is not None
        offset = 0
        hand = self.twin.backend.hand
        self.twin.catch_up()
        with self.twin.lock:
            goal = hand.motor_setpoint_counts()
            speed = np.zeros(4)
            position = None
            for m in loop.motors:
                fields = loop.control[m]
                fmt = ">" + "".join(_CONTROL_FMT[f] for f in fields)
                values = dict(zip(fields, struct.unpack_from(fmt, data, offset), strict=True))
                offset += struct.calcsize(fmt)
                self.last_control[m] = values
                props = self.props[m]
                gain = values.get("LCPG", props["FPG"])
                if "LCT" in values:  # position offset from the present position (?)
                    if position is None:
                        position = hand.read().position_counts
                    goal[m - 1] = position[m - 1] + values["LCT"]
                    speed[m - 1] = props["MCV"] / self.options.velocity_unit_s
                    continue
                v = values.get("LCV", 0) * props["LCVC"] / self.options.velocity_unit_s if gain > 0 else 0.0
                limit = units.SPREAD_FULL_COUNTS if m == SPREAD else units.FINGER_MAX_COUNTS
                goal[m - 1] = limit if v > 0 else (0 if v < 0 else goal[m - 1])
                speed[m - 1] = abs(v)
            hand.drive(goal, speed)
        self.controls_received += 1

    def feedback_block(self) -> bytes:
        """'*' and the enabled feedback of every active motor (and the temperature with LFT)."""
        loop = self.loop
        assert loop is not None
        reading = self._read()
        out = bytearray(ACK)
        discard = bool(self.globals["LFDPD"])
        for m in loop.motors:
            props = self.props[m]
            i = m - 1
            for f in loop.feedback[m]:
                if f == "LFV":
                    value = round(reading.velocity_counts[i] / props["LFVC"])
                elif f == "LFS":
                    value = self._read_prop(m, "SG", reading)
                elif f == "LFAP":
                    value = int(reading.position_counts[i])
                elif f == "LFDP":
                    delta = (reading.position_counts[i] - self._last_reported[i]) / props["LFDPC"]
                    value = int(np.clip(np.trunc(delta), -127, 127))
                    sent = value * props["LFDPC"]
                    self._last_reported[i] = (
                        reading.position_counts[i] if discard else self._last_reported[i] + sent
                    )
                elif f == "LFBP":
                    value = int(self._breakaway_counts()[i])
                else:  # LFAIN: no analog input is wired on the twin
                    value = 0
                out += struct.pack(">" + _FEEDBACK_FMT[f], _clip(_FEEDBACK_FMT[f], value))
        if loop.temperature:
            tenths = self.globals["TEMP"]
            if self.options.temperature_bytes == 1:
                out += struct.pack(">B", _clip("B", round(tenths / 10)))
            else:
                out += struct.pack(">h", _clip("h", tenths))
        return bytes(out)

    def leave_loop(self) -> bytes:
        """0x03: back to Supervisory mode; the host reads up to the prompt."""
        self.loop = None
        return self.options.line_end + PROMPT


def _split_prefix(word: str) -> tuple[tuple[int, ...], str]:
    """'123FGET' -> ((1, 2, 3), 'FGET'); no prefix means all motors."""
    i = 0
    while i < len(word) and word[i] in "0123456789SG":
        i += 1
    prefix, verb = word[:i], word[i:]
    if not verb:
        raise FirmwareError(ErrorFlag.UNKNOWN_COMMAND)
    if not prefix:
        return MOTORS, verb
    motors: set[int] = set()
    for c in prefix:
        if c == "G":
            motors |= {1, 2, 3}
        elif c == "S":
            motors.add(SPREAD)
        elif c in "1234":
            motors.add(int(c))
        else:
            raise FirmwareError(ErrorFlag.INVALID_MOTOR_PREFIX)
    return tuple(sorted(motors)), verb


def _check(table: dict[str, tuple[int, tuple[int, int] | None]], name: str, value: int) -> None:
    if name not in table:
        raise FirmwareError(ErrorFlag.UNKNOWN_PARAMETER)
    bounds = table[name][1]
    if bounds is None:
        raise FirmwareError(ErrorFlag.WRITE_TO_READ_ONLY)
    if not bounds[0] <= value <= bounds[1]:
        raise FirmwareError(ErrorFlag.INVALID_VALUE)


_RANGES = {"b": (-128, 127), "B": (0, 255), "h": (-32768, 32767), "H": (0, 65535)}


def _clip(fmt: str, value: float) -> int:
    lo, hi = _RANGES[fmt]
    return int(max(lo, min(hi, value)))
