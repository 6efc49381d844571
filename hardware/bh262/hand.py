"""The BH8-262 behind the shared Hand interface: RealTime feedback in, position set points out.

The 262's RealTime mode controls motor velocity (LCV, LCPG), so the host turns each position set
point into velocities: every cycle it commands the velocity that brings the motor's set point to the
target by the next control block (within one period; within its longest recent gap on a host that
stalls, since the firmware holds a velocity until the next block), limited by the command's maximum
velocity. The set point is integrated from the velocities actually sent, so a finger stalled on an
object keeps the force it built up instead of winding up to full torque: the same motor model as the
twin's position servo.

Recovery: a RealTime reply that is missing (later than its wire time plus the driver's scheduling
allowance), short or noisy is retried after leaving and re-entering LOOP; after `watchdog_cycles`
attempts in a row without valid feedback the read fails with WatchdogError, and the rig idles the hand
(`idle()`: T, which raises unless the hand acknowledges it). ERR replies and a lost port (PortLostError:
EOF, EIO, a reset connection) stop at once and say which it was.
"""

from __future__ import annotations

import logging
from collections import deque

import numpy as np
from twin.hardware.bh262.driver import BH262, SUPPORTED_BAUD, HandTimeoutError, PortLostError, PortSettings
from twin.hardware.bh262.protocol import FeedbackFormatError, RealTimeConfig, ReplyFormatError

from twin import units
from twin.interface.backend import Clock
from twin.interface.devices import Hand, HandCommand, HandReading
from twin.interface.errors import ConfigError, DeviceError
from twin.interface.hand_spec import HandConfig, hand_device_spec
from twin.interface.specs import DeviceSpec

log = logging.getLogger(__name__)

MAX_COUNTS = np.array([units.FINGER_MAX_COUNTS] * 3 + [units.SPREAD_FULL_COUNTS], dtype=float)
DEFAULT_REALTIME = RealTimeConfig(
    motors=(1, 2, 3, 4), control=("LCV", "LCPG"), feedback=("LFV", "LFS", "LFAP")
)


RECOVERABLE = (HandTimeoutError, FeedbackFormatError, ReplyFormatError)
"""A reply that was missing, late, short or garbled: the cycle is retried after re-entering LOOP."""
SET_POINT_DRIFT_COUNTS = 50
"""How far a motor may stop short of fully open before the host's set point model follows it
(BH8SerialHand._follow_an_opening_motor): well above the encoders' jitter of a few counts."""
STOPPED_COUNTS_S = 100.0
"""A motor reporting less than this speed (LFV) has stopped: a finger still on its way is only late."""
STOPPED_READS = 3
"""Readings in a row (0.1 s at 30 Hz) a motor must sit stopped short before the model follows it."""
STALL_WINDOW_S = 1.0
"""How far back the host's gaps between control blocks count toward how long a velocity stays in force."""
ON_TIME_PERIODS = 1.5
"""A gap up to this many periods is a loop on time (its velocity closes the error within one period)."""
IDLE_TRIES = 3
"""Bare CRs idle() sends, `timeout_s` apart, to find the prompt before T: a hand silent for a moment
(noise, a late reply in flight) is still stopped."""


class WatchdogError(DeviceError):
    """No valid feedback from the hand for too many consecutive cycles."""


class IdleError(DeviceError):
    """The hand did not acknowledge T (terminate): its motors may still be driving."""


class BH8SerialHand(Hand):
    """A BH8-262 on a serial port, in RealTime mode while connected."""

    def __init__(
        self,
        config: HandConfig,
        port: PortSettings,
        clock: Clock,
        *,
        realtime: RealTimeConfig = DEFAULT_REALTIME,
        initialize: bool = True,
        watchdog_cycles: int = 3,
        lcvc: int = 1,
        lfvc: int = 1,
        position_gain: float = 1.0,
    ) -> None:
        super().__init__()
        if realtime.motors != (1, 2, 3, 4):
            raise ConfigError("the hand interface needs all four motors in the RealTime loop (1234LOOP)")
        missing = {"LCV", "LCPG"} - set(realtime.control) or {"LFV", "LFS", "LFAP"} - set(realtime.feedback)
        if missing:
            raise ConfigError(f"the hand interface needs RealTime fields {', '.join(sorted(missing))}")
        if watchdog_cycles < 1:
            raise ConfigError("watchdog_cycles must be >= 1")
        self.velocity_unit_s = port.options.velocity_unit_s
        if abs(config.velocity_sample_time_s - self.velocity_unit_s) > 1e-12:
            raise ConfigError(
                f"the hand config reads velocity per {config.velocity_sample_time_s:g} s but the wire option "
                f"says {self.velocity_unit_s:g} s: make them agree"
            )
        self.config = config
        self.port = port
        self.clock = clock
        self.realtime = realtime
        self.initialize = initialize
        self.watchdog_cycles = watchdog_cycles
        self.lcvc, self.lfvc = lcvc, lfvc
        self.position_gain = position_gain
        """Fraction of the set-point error closed by the next block (1: deadbeat, as the twin's slew)."""
        self.bh = BH262(port)
        self._spec = hand_device_spec(config)
        self.recoveries: list[str] = []
        """Why each recovered cycle had to be retried (garbage, timeout, ...)."""
        self._target = np.zeros(4)
        self._max_velocity = config.max_velocity_counts_s
        self._setpoint: np.ndarray | None = None
        self._stopped_short = np.zeros(4, dtype=int)
        """Readings in a row each motor has sat stopped short of an opening target."""
        self._velocity = np.zeros(4)
        self._t_sent: float | None = None
        self._gaps: deque[tuple[float, float]] = deque()
        """(sent at, seconds since the block before) of the control blocks of the last STALL_WINDOW_S."""
        self._commanded_since_read = True
        self._resync_needed = False
        """A cycle failed: bytes of it may still be in flight, so LOOP is left and re-entered first."""
        self._idled = False
        """T was acknowledged and RealTime mode was not entered again since."""
        self._idle_failed = False
        """The last idle found no prompt: on disconnect one more try, not the full IDLE_TRIES."""

    @property
    def spec(self) -> DeviceSpec:
        """Same declared channels as the sim hand."""
        return self._spec

    @property
    def max_wire_velocity_counts_s(self) -> float:
        """Fastest velocity an int8 LCV can carry with the configured LCVC."""
        return 127 * self.lcvc / self.velocity_unit_s

    def wire_time_per_period_s(self, baud: int) -> float:
        """Bytes one period puts on the wire: an A cycle and a c cycle (10 bits per byte)."""
        rt = self.realtime
        nbytes = (1 + rt.feedback_size) + (1 + rt.control_size + 1)
        return nbytes * 10.0 / baud

    def _connect(self) -> None:
        baud = self.port.switch_baud or self.port.baud
        need = self.wire_time_per_period_s(baud)
        if need > 0.8 * self.spec.period_s:
            fastest = max(SUPPORTED_BAUD)
            advice = f"rate_hz at most {int(0.8 / need)}"
            if baud < fastest:
                advice = f"switch_baud = {fastest} (the fastest the hand has) or {advice}"
            raise ConfigError(
                f"at {baud} baud one RealTime period needs {need * 1e3:.1f} ms of wire time, more than 80% "
                f"of the {self.spec.period_s * 1e3:.1f} ms period: set {advice}"
            )
        self.bh.open()
        try:
            if self.initialize:
                self.bh.initialize()
            self.bh.enter_realtime(self.realtime, lcvc=self.lcvc, lfvc=self.lfvc)
        except BaseException:
            self.bh.close()
            raise
        self._setpoint = None
        self._velocity[:] = 0.0
        self._t_sent = None
        self._gaps.clear()
        self._stopped_short[:] = 0
        self._commanded_since_read = True
        self._resync_needed = False
        self._idled = self._idle_failed = False

    def _disconnect(self) -> None:
        reported = self._idle_failed  # the rig's safe stop already said the idle failed
        try:
            if not self._idled:  # once T was acknowledged (the rig's safe stop) it need not go again
                self._idle(tries=1 if self._idle_failed else IDLE_TRIES)
            if self.bh.baud != self.port.baud:  # leave the hand at the rate the next session expects
                self.bh.set_baud(self.port.baud)
        except DeviceError as exc:
            if not reported:  # once is enough: the run's error already says the idle failed
                log.warning("could not idle the hand or restore its baud rate on disconnect: %s", exc)
        finally:
            self.bh.close()

    def read(self) -> HandReading:
        """One RealTime feedback cycle (with a servo update if no command came since the last read)."""
        self._require_connection()
        self._idled = False
        control = None if self._commanded_since_read else self._servo(self.clock.now())
        self._commanded_since_read = False
        last: Exception | None = None
        for _ in range(self.watchdog_cycles):  # each attempt: (re-enter LOOP if needed,) one cycle
            try:
                if self._resync_needed or self.bh.realtime is None:
                    self.bh.recover_realtime(self.realtime)
                    self._resync_needed = False
                # stamped as the request that is answered goes out (after any re-entry into LOOP):
                # the hand samples on its arrival, one request's wire time later
                t_s = self.clock.now()
                feedback = self.bh.cycle(control)
                break
            except RECOVERABLE as exc:  # a PortLostError or an ERR reply stops at once
                last = exc
                self._resync_needed = True
                self.recoveries.append(f"{type(exc).__name__}: {exc}")
                # INFO, not WARNING: every recovered cycle goes into run.json (hand_recoveries), and
                # the CLI sums them up in one line; a failure's own line says the rest
                log.info("hand feedback lost (%s); re-entering RealTime mode", exc)
        else:
            raise WatchdogError(
                f"no valid feedback from the hand for {self.watchdog_cycles} cycles in a row (last: {last})"
            )
        fields = feedback.fields
        position = np.asarray(fields["LFAP"], dtype=np.int32)
        if self._setpoint is None:
            self._setpoint = position.astype(float)
            self._target = position.astype(float)
        velocity = np.asarray(fields["LFV"], dtype=np.int32) * self.lfvc
        self._follow_an_opening_motor(position, velocity / self.velocity_unit_s)
        return HandReading(
            t_s=t_s,
            position_counts=position,
            velocity_counts=velocity,
            strain_counts=np.asarray(fields["LFS"][:3], dtype=np.int32),
        )

    def command(self, command: HandCommand) -> HandCommand:
        """New set points: velocities go out at once in a control-only (c) cycle."""
        self._require_connection()
        self._idled = False
        target = np.clip(command.position_counts, 0.0, MAX_COUNTS)
        velocity = float(min(command.max_velocity_counts_s, self.max_wire_velocity_counts_s))
        self._target, self._max_velocity = target, velocity
        control = self._servo(self.clock.now())
        # After a failed cycle the next read() re-enters LOOP (counted by its watchdog) and sends the
        # servo velocities with its control block; a command never recovers on its own.
        self._commanded_since_read = False
        if self._resync_needed or self.bh.realtime is None:
            return HandCommand(target, velocity)
        try:
            self.bh.cycle(control, feedback=False)
        except RECOVERABLE as exc:
            self._resync_needed = True
            self.recoveries.append(f"{type(exc).__name__}: {exc}")
            return HandCommand(target, velocity)
        self._commanded_since_read = True
        return HandCommand(target, velocity)

    def _follow_an_opening_motor(self, position: np.ndarray, velocity_counts_s: np.ndarray) -> None:
        """Move the set point to a motor that stopped short of an opening target.

        The set point is the host's model of where the firmware servos each motor, integrated from the
        velocities sent on the host's clock; the firmware integrates them from when each block arrives.
        A block the host (or the line) delays leaves a velocity in force a little longer or shorter
        than the model has it: the model then reaches its target with the motor short of it, and a
        velocity loop stops there (a loaded host left fingers 100-800 counts short of open). Where the
        model has settled on the fully open target (0 counts, where the firmware stops a motor of
        itself, so driving on cannot overshoot) with the motor more than SET_POINT_DRIFT_COUNTS short
        of it and stopped for STOPPED_READS readings, the model restarts from the motor and drives it
        on. Elsewhere the model is left as it is: a motor still moving is only late, one short of a
        closing target is a finger held by the object building force, and restarting the model short
        of any other target would send the motor past it by as much."""
        settled = (np.abs(self._setpoint - self._target) < 0.5) & (self._target <= 0.5)
        short = position - self._target > SET_POINT_DRIFT_COUNTS
        stopped = np.abs(velocity_counts_s) < STOPPED_COUNTS_S
        self._stopped_short = np.where(settled & short & stopped, self._stopped_short + 1, 0)
        follow = self._stopped_short >= STOPPED_READS
        self._setpoint = np.where(follow, position.astype(float), self._setpoint)
        self._stopped_short[follow] = 0

    def _servo(self, t_s: float) -> dict[str, list[int]]:
        """LCV/LCPG per motor: the velocity that closes the set-point error by the next block."""
        if self._setpoint is None:
            return {"LCV": [0] * 4, "LCPG": [0] * 4}
        if self._t_sent is not None:
            dt = max(0.0, t_s - self._t_sent)
            self._setpoint = np.clip(self._setpoint + self._velocity * dt, 0.0, MAX_COUNTS)
            self._gaps.append((t_s, dt))
        self._t_sent = t_s
        wanted = self.position_gain * (self._target - self._setpoint) / self._hold_s(t_s)
        limit = min(self._max_velocity, self.max_wire_velocity_counts_s)
        # Truncated toward zero: the hand never moves faster than the command allows.
        lcv = np.trunc(np.clip(wanted, -limit, limit) * self.velocity_unit_s / self.lcvc).astype(int)
        lcv = np.clip(lcv, -127, 127)
        self._velocity = lcv * self.lcvc / self.velocity_unit_s
        gain = [100] * 4
        return {"LCV": lcv.tolist(), "LCPG": gain}

    def _hold_s(self, t_s: float) -> float:
        """How long the velocity sent now will stay in force: one period on a loop that keeps time, else
        the longest gap between blocks in the last STALL_WINDOW_S.

        The firmware holds a velocity until the next block. One that closes the error in a period, held
        for h periods, carries the set point past the target by (h - 1) times the error, and from h = 2
        on each correction overshoots further: a host stalling for 150 ms at 30 Hz sets the fingers
        swinging by over a thousand counts. Aimed at the longest recent gap, each block closes a part of
        the error no larger than all of it, however the stalls fall."""
        while self._gaps and self._gaps[0][0] < t_s - STALL_WINDOW_S:
            self._gaps.popleft()
        period = self.spec.period_s
        longest = max((gap for _, gap in self._gaps), default=0.0)
        return longest if longest > ON_TIME_PERIODS * period else period

    def idle(self) -> None:
        """Leave RealTime mode and send T: the motors stop driving (the worm drives hold).

        Returns only once the hand acknowledged T; otherwise IdleError (or PortLostError) says why."""
        self._idle(IDLE_TRIES)

    def _idle(self, tries: int) -> None:
        self._idled = False
        self._idle_failed = True  # until T is acknowledged
        if not self.bh.is_open:
            raise IdleError(f"the hand's port {self.port.url} is closed: T (terminate) could not be sent")
        if self.bh.realtime is not None:
            try:
                self.bh.leave_realtime()
            except RECOVERABLE:
                self.bh.realtime = None
        self._resync_needed = False
        self._find_prompt(tries)  # drop whatever a fault left in flight
        try:
            self.bh.terminate()
        except (HandTimeoutError, ReplyFormatError) as exc:
            raise IdleError(f"the hand did not acknowledge T (terminate): {exc}") from None
        self._idled, self._idle_failed = True, False

    def _find_prompt(self, tries: int) -> None:
        """Bare CRs until the prompt answers (`tries`, `timeout_s` each); IdleError if it never does."""
        for _ in range(tries):
            try:
                self.bh.resync()
                return
            except HandTimeoutError:
                continue
        waited_s = tries * self.port.timeout_s
        raise IdleError(
            f"no prompt from the hand within {waited_s:g} s ({tries} tries), so T (terminate) was not sent"
        )

    def metadata(self) -> dict:
        """Port, rate, RealTime layout and recoveries, for run.json."""
        rt = self.realtime
        return {
            "port": self.port.url,
            "baud": self.bh.baud,
            "realtime": {
                "motors": list(rt.motors),
                "control": list(rt.control),
                "feedback": list(rt.feedback),
                "lcvc": self.lcvc,
                "lfvc": self.lfvc,
                "wire_limit_hz": rt.wire_limit_hz(self.bh.baud),
            },
            "watchdog_cycles": self.watchdog_cycles,
            "recoveries": list(self.recoveries),
        }


__all__ = ["BH8SerialHand", "IdleError", "PortLostError", "WatchdogError"]
