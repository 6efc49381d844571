"""The BH8-262 firmware, emulated on the MuJoCo twin: commands, motor properties, RealTime blocks.

Written from bh262_protocol.md, not from our driver. The twin runs in real time on a thread of its
own (`RealTimeTwin`); the firmware turns each supervisory line or RealTime block into motion of the
simulated hand and answers from the simulated sensors. Choices where the documentation is silent:
  - the (?) items of bh262_protocol.md follow WireOptions (velocity unit, FGET order, line end,
    temperature bytes, whether ERR leaves RealTime mode);
  - RealTime velocity control (LCV) drives each motor's set point at the commanded velocity, the same
    slewed servo the twin uses for every motion (a stalled finger keeps the force it built up);
  - LFT sends the temperature in whole degrees C (1 byte, firmware 4.4) or tenths (2 bytes, 4.3x);
  - the property table is the manual's and Barrett's API's (`properties.py`); an FSET/PSET line sets
    its valid pairs and answers ERR with the flags of the others (§5.1.3, "the sum of the status
    codes encountered");
  - motions end when each motor has arrived or stalled for TSTOP ms (§5.5); HI opens to the stops at
    IVEL and strikes them IHIT times;
  - RealTime blocks are answered from the state the physics thread last published, and controls are
    handed to that thread (`RealTimeTwin.submit`): a reply never waits for the physics.
Emulators may import the simulator (architecture.md); drivers never do.
"""

from __future__ import annotations

import atexit
import contextlib
import struct
import threading
import time
import weakref
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np
from twin.hardware.bh262.properties import ALIASES, GLOBAL_PROPERTIES, MOTOR_PROPERTIES, Property
from twin.hardware.bh262.protocol import (
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
from twin.sim.hand import COUNTS_TO_RAD, FINGER_ACTUATORS, SPREAD_ACTUATOR

DEFAULT_OPTIONS = WireOptions()
CATCH_UP_LAG_S = 0.010
"""Sensors are sampled, and commands applied, with the twin at most this far behind wall time..."""
QUIET_BEFORE_S = 0.0015
"""The physics thread stays off the GIL this long before a RealTime reply is due..."""
QUIET_AFTER_S = 0.0005
"""...and this long after (RealTimeTwin.keep_quiet)."""
CATCH_UP_TIMEOUT_S = 0.03
"""...waiting at most this long for it (beyond, the reply is simply late)."""
VERSION = "4.4.3"
BANNER_LINES = ("BarrettHand Firmware", f"Version {VERSION} (barrett-twin emulator)")
"""Power-up and RESET print these lines. Barrett's API checks the first for "BarrettHand Firmware\\n"
(`BHandSerialDriver::HandReset`), so it ends a line of its own."""
SUPPORTED_BAUD = (600, 1200, 2400, 4800, 9600, 19200, 38400)
MOTORS = (1, 2, 3, 4)
SPREAD = 4
MOTION_POLL_S = 0.01
"""How often a motion command looks at the motors (stall and arrival)."""
STILL_COUNTS = 2.0
"""A motor that moved no more than this between two looks is not moving."""
STALL_LAG_COUNTS = 100.0
"""A motor stalls when it does not move while its set point is more than this ahead of it."""
MOTOR_NOT_READY = int(ErrorFlag.MOTOR_NOT_INITIALIZED)
"""S of a motor before its HI (libgripper reads `1234FGET S` to decide whether to send HI)."""
_CONTROL_FMT = {"LCV": "b", "LCPG": "B", "LCT": "h"}
_FEEDBACK_FMT = {"LFV": "b", "LFS": "B", "LFAP": "H", "LFDP": "b", "LFBP": "H", "LFAIN": "B"}
_ACTUATORS = (*FINGER_ACTUATORS, SPREAD_ACTUATOR)
_MOTION_VERBS = ("C", "O", "M", "HOME", "IC", "IO", "TC", "TO", "LOOP")


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
        self._pending: deque[tuple[float, Callable[[], None]]] = deque()
        self._latest: TwinState | None = None
        self._quiet = (0.0, 0.0)
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

    def submit(self, action: Callable[[], None], at_s: float = 0.0) -> None:
        """Have `action` run under the lock, on the physics thread, once sim time reaches monotonic
        `at_s` on the twin's clock (before the physics step that passes it): the serial thread never
        waits for the physics to hand a command over, and a twin running behind wall time applies the
        command at the instant it arrived, only later. With no physics thread running it runs now."""
        if not self._thread.is_alive():
            with self.lock:
                action()
            return
        self._pending.append((at_s, action))

    def keep_quiet(self, start_s: float, end_s: float) -> None:
        """Ask the physics thread not to step between these monotonic times (a reply is due then): a
        step holds the GIL between MuJoCo calls, and a physics thread preempted while holding it by
        other work on the machine keeps the serial thread from writing, whatever its priority."""
        self._quiet = (start_s, end_s)

    @property
    def pending_actions(self) -> int:
        """Submitted actions the physics thread has not run yet."""
        return len(self._pending)

    @contextlib.contextmanager
    def locked(self) -> Iterator[None]:
        """The lock, with every submitted action run first (due or not), so that a command taken
        under it (T, a motion) always comes after the RealTime controls sent before it."""
        with self.lock:
            self._run_pending(float("inf"))
            yield

    def state(self, *, fresh: bool = False) -> TwinState:
        """The hand's sensors as published after the latest physics chunk: RealTime replies are
        answered from it at once, never waiting for the physics (or its lock) to come round.
        `fresh` (Supervisory queries): let the twin catch up with wall time and read it now."""
        latest = self._latest
        if fresh or latest is None or not self._thread.is_alive():
            if fresh:
                self.catch_up()
            with self.locked():
                return self._publish()
        return latest

    def _publish(self) -> TwinState:
        clutches = self.backend.world.clutches
        rad = [c.drive_at_breakaway_rad if c.broken_away else 0.0 for c in clutches.fingers]
        state = TwinState(
            reading=self.backend.hand.read(),
            broken_away=np.append(clutches.broken_away, False),
            breakaway_counts=np.append(np.round(units.inner_rad_to_finger_counts(rad)), 0),
        )
        self._latest = state
        return state

    def _run_pending(self, now: float) -> None:
        while self._pending and self._pending[0][0] <= now:
            self._pending.popleft()[1]()

    def catch_up(self, max_lag_s: float = CATCH_UP_LAG_S, timeout_s: float = CATCH_UP_TIMEOUT_S) -> None:
        """Wait (briefly) until sim time is within max_lag_s of wall time.

        A real hand never falls behind; a twin starved of CPU can, and then its sensors would report
        the past and commands would act late. Supervisory queries and motions wait for it. RealTime
        replies do not: they answer from the latest published state (`state()`), because a client's
        read timeout (libgripper: 100 ms) is stricter than a few milliseconds of staleness.
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
            start, end = self._quiet
            now = time.monotonic()  # read once: a second read can pass `end` on a loaded machine
            if start <= now < end:
                time.sleep(end - now)
                continue
            target = self.now()
            with self.lock:  # short holds so that the serial thread is never kept waiting long
                # A command takes effect at the sim time of its arrival, not at whatever sim time a
                # lagging twin has reached when it arrives: a twin starved of CPU integrates every
                # velocity over the time it was in force on the wire, as the firmware does, and only
                # reports it later (the host's own set point model then agrees with the fingers).
                self._run_pending(self._t0 + world.time_s + 0.5 * world.timestep_s)
                step_to = min(target, world.time_s + self._chunk_s)
                if self._pending:
                    step_to = min(step_to, max(self._pending[0][0] - self._t0, world.time_s))
                world.advance_to(step_to)
                behind = target - world.time_s
                if self.backend.hand.is_connected:
                    self._publish()
            self.lag_s = max(self.lag_s, behind)
            if behind < world.timestep_s:
                time.sleep(world.timestep_s)


@dataclass(frozen=True)
class TwinState:
    """What the hand's sensors said after one physics chunk."""

    reading: HandReading
    broken_away: np.ndarray
    breakaway_counts: np.ndarray


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
        self.initialized: set[int] = set()
        """The motors that have had their HI since power-up or RESET."""
        self.loop: LoopState | None = None
        self.commands: list[str] = []
        """Every supervisory line received, in order (what a test or a log looks at)."""
        self.controls_received = 0
        self.last_control: dict[int, dict[str, int]] = {}
        """The latest RealTime control block, decoded per motor."""
        self.props: dict[int, dict[str, int]] = {}
        self.globals: dict[str, int] = {}
        self._reset_properties(MOTORS)
        self._reset_globals()
        self._powered_up = time.monotonic()
        self._last_reported = np.zeros(4)
        self._abort: Callable[[], bool] = lambda: False

    # --- properties -----------------------------------------------------------------------

    def _reset_properties(self, motors: tuple[int, ...]) -> None:
        """Factory defaults (FDEF, power-up) of the motors' writable properties."""
        for m in motors:
            self.props[m] = {
                name: (p.spread if m == SPREAD else p.finger)
                for name, p in MOTOR_PROPERTIES.items()
                if p.writable is not None and name not in ALIASES
            }

    def _reset_globals(self) -> None:
        """Factory defaults (PDEF, power-up) of the writable global properties, the rate aside."""
        self.globals = {n: p.finger for n, p in GLOBAL_PROPERTIES.items() if p.writable is not None}
        self.globals["BAUD"] = self.baud // 100

    def _read_prop(self, motor: int, name: str, state: TwinState) -> int:
        name = ALIASES.get(name, name)
        props = self.props[motor]
        if name == "P":
            return int(state.reading.position_counts[motor - 1])
        if name == "S":
            return 0 if motor in self.initialized else MOTOR_NOT_READY
        if name == "SG":
            if motor == SPREAD:
                return 255  # no strain gauge on the spread
            strain = int(np.clip(state.reading.strain_counts[motor - 1], 0, 255))
            return 255 - strain if props["SGFLIP"] else strain
        if name == "BD":
            return int(state.broken_away[motor - 1])
        if name == "BP":
            return int(state.breakaway_counts[motor - 1])
        if name == "OD":
            return 0  # the odometer of a fresh twin
        return props[name]

    def _read_global(self, name: str) -> int:
        if name == "UPSECS":
            return int(time.monotonic() - self._powered_up)
        if name in ("TEMP", "PTEMP"):
            return 300  # tenths of a degree C: the twin has no thermal model
        if name == "SN":
            return 2620
        return self.globals[name]

    # --- supervisory ----------------------------------------------------------------------

    def banner(self) -> bytes:
        """What power-up and RESET print: the banner lines, then the prompt."""
        le = self.options.line_end
        return le + b"".join(line.encode() + le for line in BANNER_LINES) + PROMPT

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
        return le + b"".join(str(r).encode() + le for r in result or ()) + PROMPT

    def _dispatch(self, text: str) -> list[str] | bytes | None:
        """Run one command; its result lines (None: no result), or raw bytes (LOOP, RESET)."""
        words = text.upper().split()
        motors, verb = _split_prefix(words[0])
        args = words[1:]
        if verb in _MOTION_VERBS and words[0] == verb:  # no prefix: the motors with EN set (§5.3.4)
            motors = tuple(m for m in MOTORS if self.props[m]["EN"])
        if verb in ("FGET", "FSET", "PGET", "PSET", "FDEF", "FLOAD", "FSAVE", "PDEF", "PLOAD", "PSAVE"):
            return self._properties(verb, motors, args)
        if verb == "RESET":
            return self._reset()
        if verb == "VERS":
            return [BANNER_LINES[1]]
        if verb == "HI":
            return self._hi(motors)
        if verb in _MOTION_VERBS and not set(motors) <= self.initialized:
            raise FirmwareError(ErrorFlag.MOTOR_NOT_INITIALIZED)
        if verb == "LOOP":
            if args:
                raise FirmwareError(ErrorFlag.TOO_MANY_ARGUMENTS)
            return self._enter_loop(motors)
        if verb == "T":
            with self.twin.locked():
                self.twin.backend.hand.idle()
            return None
        if verb in ("C", "TC"):
            return self._move(motors, {m: self.props[m]["CT"] for m in motors}, "MCV")
        if verb in ("O", "TO"):
            return self._move(motors, {m: self.props[m]["OT"] for m in motors}, "MOV")
        if verb == "HOME":
            return self._move(motors, dict.fromkeys(motors, 0), "MOV", position=True)
        if verb == "M":
            targets = {m: self._int_arg(args, self.props[m]["DP"]) for m in motors}
            return self._move(motors, targets, "MCV", position=True)
        if verb in ("IC", "IO"):
            sign = 1 if verb == "IC" else -1
            reading = self._read()
            targets = {
                m: int(reading.position_counts[m - 1]) + sign * self._int_arg(args, self.props[m]["DS"])
                for m in motors
            }
            return self._move(motors, targets, "MCV" if sign > 0 else "MOV", position=True)
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
        with self.twin.locked():
            return self.twin.backend.hand.read()

    def _properties(self, verb: str, motors: tuple[int, ...], args: list[str]) -> list[str] | None:
        if verb == "FGET":
            if not args:
                raise FirmwareError(ErrorFlag.UNKNOWN_PARAMETER)
            if any(a not in MOTOR_PROPERTIES for a in args):
                raise FirmwareError(ErrorFlag.UNKNOWN_PARAMETER)
            state = self.twin.state(fresh=True)
            if self.options.fget_order == "property":
                values = [self._read_prop(m, a, state) for a in args for m in motors]
            else:
                values = [self._read_prop(m, a, state) for m in motors for a in args]
            return [" ".join(map(str, values))]
        if verb == "FSET":
            valid, flags = self._settable(MOTOR_PROPERTIES, args)
            for name, value in valid:
                for m in motors:
                    self.props[m][ALIASES.get(name, name)] = value
            if flags:
                raise FirmwareError(*flags)
            return None
        if verb == "PGET":
            if not args:
                raise FirmwareError(ErrorFlag.UNKNOWN_PARAMETER)
            if any(a not in GLOBAL_PROPERTIES for a in args):
                raise FirmwareError(ErrorFlag.UNKNOWN_PARAMETER)
            return [str(self._read_global(a)) for a in args]  # one line per parameter (§5.2.3)
        if verb == "PSET":
            valid, flags = self._settable(GLOBAL_PROPERTIES, args)
            for name, value in valid:
                self.globals[name] = value
            if flags:
                raise FirmwareError(*flags)
            return None
        if verb == "FDEF":
            self._reset_properties(motors)
            return None
        if verb == "PDEF":
            self._reset_globals()
            return None
        if verb == "PSAVE":
            self._saved_baud = self.globals["BAUD"] * 100
        return None  # FLOAD, FSAVE, PLOAD: nothing else is kept across resets

    @staticmethod
    def _settable(
        table: dict[str, Property], args: list[str]
    ) -> tuple[list[tuple[str, int]], set[ErrorFlag]]:
        """The (name, value) pairs of an FSET/PSET line that can be set, and the flags of the others.

        Each pair is checked on its own: the caller sets the valid ones and then answers ERR with the
        sum of the flags met (§5.1.3: "the sum of the status codes encountered"), so one unknown name
        never drops the rest of the line.
        """
        if not args:
            raise FirmwareError(ErrorFlag.INVALID_VALUE)
        flags: set[ErrorFlag] = set()
        valid: list[tuple[str, int]] = []
        for i in range(0, len(args), 2):
            name = args[i]
            if name not in table:
                flags.add(ErrorFlag.UNKNOWN_PARAMETER)
                continue
            bounds = table[name].writable
            if bounds is None:
                flags.add(ErrorFlag.WRITE_TO_READ_ONLY)
                continue
            try:
                value = int(args[i + 1])
            except (IndexError, ValueError):
                flags.add(ErrorFlag.INVALID_VALUE)
                continue
            if not bounds[0] <= value <= bounds[1] or (name == "BAUD" and value * 100 not in SUPPORTED_BAUD):
                flags.add(ErrorFlag.INVALID_VALUE)
                continue
            valid.append((name, value))
        return valid, flags

    def pending_baud(self) -> int | None:
        """The new rate after `PSET BAUD n` (the server switches after the echo), else None."""
        rate = self.globals["BAUD"] * 100
        return rate if rate != self.baud else None

    def _reset(self) -> bytes:
        self.loop = None
        self.initialized = set()
        self.baud = self._saved_baud
        self._reset_properties(MOTORS)
        self._reset_globals()
        with self.twin.locked():
            self.twin.backend.hand.idle()
        return self.banner()

    def _hi(self, motors: tuple[int, ...]) -> None:
        """HI: each motor opens to its stop at IVEL (which replaces MOV while initializing, §5.3.4);
        a finger with IHIT > 0 then strikes the stop IHIT times, backing off IOFF counts before each
        strike. The motors count from 0 at the stop, and are ready (S = 0) afterwards."""
        self._move(motors, dict.fromkeys(motors, 0), "IVEL")
        for _ in range(max((self.props[m]["IHIT"] for m in motors if m != SPREAD), default=0)):
            strikers = tuple(m for m in motors if m != SPREAD and self.props[m]["IHIT"] > _)
            if not strikers:
                break
            self._move(strikers, {m: self.props[m]["IOFF"] for m in strikers}, "IVEL")
            self._move(strikers, dict.fromkeys(strikers, 0), "IVEL")
        self.initialized |= set(motors)

    def _move(
        self,
        motors: tuple[int, ...],
        targets: dict[int, int],
        velocity_prop: str,
        *,
        position: bool = False,
    ) -> None:
        """Drive the motors to their targets at `velocity_prop` and return when each has arrived or
        stalled for TSTOP ms (§5.5, cases 1 and 3). `position` (M, HOME, IC, IO): ERR 16 unless every
        motor ended within MPE of its target (O and C never raise it, §5.2.1)."""
        if not motors:
            return
        hand = self.twin.backend.hand
        index = [m - 1 for m in motors]
        self.twin.catch_up()
        with self.twin.locked():
            present = hand.read().position_counts
            world = self.twin.backend.world
            ctrl = world.data.ctrl
            # The profile starts where each motor is (the HCTL-1100 plans every move from the present
            # position), not where an earlier set point had got to while the finger was blocked.
            for m in motors:
                ctrl[world.model.actuator(_ACTUATORS[m - 1]).id] = present[m - 1] * COUNTS_TO_RAD[m - 1]
            goal = hand.motor_setpoint_counts()
            speed = np.zeros(4)
            for m in motors:
                limit = units.SPREAD_FULL_COUNTS if m == SPREAD else units.FINGER_MAX_COUNTS
                goal[m - 1] = min(max(targets[m], 0), limit)
                speed[m - 1] = self.props[m][velocity_prop] / self.options.velocity_unit_s
            hand.drive(goal, np.where(speed > 0, speed, 1.0))
        deadline = time.monotonic() + self.motion_timeout_s
        tstop_s = np.array([self.props[m]["TSTOP"] / 1000.0 for m in motors])
        last: np.ndarray | None = None
        still_since = np.full(len(motors), np.inf)
        while True:
            time.sleep(MOTION_POLL_S)
            if self._abort():
                with self.twin.locked():
                    hand.drive(hand.motor_setpoint_counts(), np.zeros(4))  # stop where the servos are
                raise FirmwareError(ErrorFlag.ABORTED_BY_CTRL_C)
            reading = self._read()
            now = time.monotonic()
            with self.twin.locked():
                setpoint = hand.motor_setpoint_counts()
            position_now = reading.position_counts[index]
            if last is None:
                moving = np.ones(len(motors), dtype=bool)
            else:
                moving = np.abs(position_now - last) > STILL_COUNTS
            still_since = np.where(moving, np.inf, np.minimum(still_since, now))
            last = position_now
            arrived = (np.abs(setpoint[index] - goal[index]) <= 1.0) & ~moving
            lagging = np.abs(setpoint[index] - position_now) > STALL_LAG_COUNTS
            stalled = lagging & (now - still_since >= np.maximum(tstop_s, MOTION_POLL_S))
            if np.all(arrived | stalled):
                break
            if now > deadline:
                raise FirmwareError(ErrorFlag.COULD_NOT_REACH_POSITION)
        if position:
            mpe = np.array([self.props[m]["MPE"] for m in motors])
            if np.any(np.abs(position_now - goal[index]) > mpe):
                raise FirmwareError(ErrorFlag.COULD_NOT_REACH_POSITION)
        return None

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

    def apply_control(self, data: bytes, at_s: float = 0.0) -> None:
        """Control data of one RealTime block (length loop.control_size), decoded now and handed to
        the twin to act on at monotonic time `at_s` (when its last byte has crossed the wire)."""
        loop = self.loop
        assert loop is not None
        offset = 0
        decoded: dict[int, dict[str, int]] = {}
        for m in loop.motors:
            fields = loop.control[m]
            fmt = ">" + "".join(_CONTROL_FMT[f] for f in fields)
            decoded[m] = dict(zip(fields, struct.unpack_from(fmt, data, offset), strict=True))
            offset += struct.calcsize(fmt)
        self.last_control.update(decoded)
        self.controls_received += 1
        props = {m: dict(self.props[m]) for m in loop.motors}
        self.twin.submit(lambda: self._drive(decoded, props), at_s)

    def _drive(self, decoded: dict[int, dict[str, int]], props: dict[int, dict[str, int]]) -> None:
        """Apply one decoded control block to the twin's motor servos (under its lock)."""
        hand = self.twin.backend.hand
        goal = hand.motor_setpoint_counts()
        speed = np.zeros(4)
        position = None
        for m, values in decoded.items():
            p = props[m]
            gain = values.get("LCPG", p["FPG"])
            if "LCT" in values:  # position offset from the present position (?)
                if position is None:
                    position = hand.read().position_counts
                goal[m - 1] = position[m - 1] + values["LCT"]
                speed[m - 1] = p["MCV"] / self.options.velocity_unit_s
                continue
            v = values.get("LCV", 0) * p["LCVC"] / self.options.velocity_unit_s if gain > 0 else 0.0
            limit = units.SPREAD_FULL_COUNTS if m == SPREAD else units.FINGER_MAX_COUNTS
            goal[m - 1] = limit if v > 0 else (0 if v < 0 else goal[m - 1])
            speed[m - 1] = abs(v)
        hand.drive(goal, speed)

    def feedback_block(self) -> bytes:
        """'*' and the enabled feedback of every active motor (and the temperature with LFT)."""
        loop = self.loop
        assert loop is not None
        state = self.twin.state()
        reading = state.reading
        out = bytearray(ACK)
        discard = bool(self.globals["LFDPD"])
        for m in loop.motors:
            props = self.props[m]
            i = m - 1
            for f in loop.feedback[m]:
                if f == "LFV":
                    value = round(reading.velocity_counts[i] / max(1, props["LFVC"]))
                elif f == "LFS":
                    value = self._read_prop(m, "SG", state)
                elif f == "LFAP":
                    value = int(reading.position_counts[i])
                elif f == "LFDP":
                    coefficient = max(1, props["LFDPC"])  # 0 is allowed (§5.3.3) and read as 1
                    delta = (reading.position_counts[i] - self._last_reported[i]) / coefficient
                    value = int(np.clip(np.trunc(delta), -127, 127))
                    sent = value * coefficient
                    self._last_reported[i] = (
                        reading.position_counts[i] if discard else self._last_reported[i] + sent
                    )
                elif f == "LFBP":
                    value = int(state.breakaway_counts[i])
                else:  # LFAIN: no analog input is wired on the twin
                    value = 0
                out += struct.pack(">" + _FEEDBACK_FMT[f], _clip(_FEEDBACK_FMT[f], value))
        if loop.temperature:
            tenths = self._read_global("TEMP")
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


_RANGES = {"b": (-128, 127), "B": (0, 255), "h": (-32768, 32767), "H": (0, 65535)}


def _clip(fmt: str, value: float) -> int:
    lo, hi = _RANGES[fmt]
    return int(max(lo, min(hi, value)))
