"""The PPS tactile pads behind the shared TactileArray interface: a streamed frame per scan, newest wins.

The interface streams frames by itself (no request), so a background thread reads the port, feeds
`twin.hardware.pps.frame.FrameDecoder` and keeps the newest valid frame, stamped with the run clock when
it arrived; `read()` returns it at once. Lost frames are counted from gaps in the device's sequence
numbers: a corrupted, truncated or dropped frame each leaves one. Bad frames are not added on top (that
would count them twice, and noise that merely contains the sync makes one too). The port is opened with
`serial.serial_for_url`: a device path, `socket://host:port` or `ppsemu://` (an in-process emulator).
This module never imports the simulator.
"""

from __future__ import annotations

import contextlib
import dataclasses
import threading
import time
from typing import Any

import serial
from twin.hardware.pps.frame import SEQUENCE_MODULO, Frame, FrameDecoder

from twin.interface.backend import Clock
from twin.interface.devices import TactileArray, TactileReading
from twin.interface.errors import ConfigError, DeviceError
from twin.interface.specs import DeviceSpec
from twin.interface.tactile_spec import TactileConfig, tactile_device_spec

DEFAULT_BAUD = 921_600
PENDING_MAX = 256
"""Frames kept for read_pending() (8.5 s at 30 Hz)."""
POLL_S = 0.05
"""Longest the reader blocks in one read, so disconnect() is noticed quickly."""
READER_GRACE_S = 0.1
"""Before a frame older than timeout_s counts as a timeout, the reader thread gets this long to take
what the port holds: after this process was not scheduled for a while (a busy machine) the frames are
there, only not read yet."""


class TactileTimeoutError(DeviceError):
    """No valid frame from the tactile pads within the timeout."""


class TactilePortLostError(DeviceError):
    """The tactile port failed or disappeared."""


class PPSTactile(TactileArray):
    """The PPS RoboTouch interface on a serial port: 162 taxels at the scan rate, read in the background."""

    def __init__(
        self,
        config: TactileConfig,
        url: str,
        clock: Clock,
        *,
        baud: int = DEFAULT_BAUD,
        timeout_s: float = 0.5,
        connect_timeout_s: float = 2.0,
    ) -> None:
        """`url`: a device path or pyserial URL; `baud`: the interface's line rate (socket:// and ppsemu://
        ignore it); `clock`: stamps each frame on arrival (the run clock, e.g.
        twin.hardware.backend.WallClock)."""
        super().__init__()
        if not timeout_s > 0 or not connect_timeout_s > 0:
            raise ConfigError("tactile timeout_s and connect_timeout_s must be > 0")
        self.config = config
        self.url = url
        self.clock = clock
        self.baud = baud
        self.timeout_s = timeout_s
        """read() fails when the newest valid frame is older than this."""
        self.connect_timeout_s = connect_timeout_s
        """connect() fails when no valid frame arrives within this."""
        self._spec = tactile_device_spec(config)
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._port: serial.SerialBase | None = None
        self._reset_state()

    def _reset_state(self) -> None:
        self.decoder = FrameDecoder()
        self.dropped_frames = 0
        """Frames lost since connect(), from sequence gaps."""
        self.sequence_restarts = 0
        """Times the sequence went backwards or repeated (a device restart): not counted as drops."""
        self.last_frame: Frame | None = None
        """The newest valid frame as decoded (device sequence and timestamp)."""
        self._latest: TactileReading | None = None
        self._received = 0  # valid frames received since connect()
        self._received_at = 0.0  # time.monotonic() of the newest
        self._returned = 0  # self._received when read()/read_next() last returned
        self._lost: str | None = None
        self._pending: list[tuple[TactileReading, float]] = []  # (reading, arrival time.monotonic())
        self._joined_bytes = 0  # bytes discarded before the first valid frame (joining mid-frame)
        self._joined_bad = 0

    @property
    def spec(self) -> DeviceSpec:
        """Same declared channel as the sim's tactile array."""
        return self._spec

    # --- life cycle -------------------------------------------------------------------------

    def _connect(self) -> None:
        import twin.hardware.pps.urlhandler  # noqa: F401  (registers ppsemu://)

        self._reset_state()
        try:
            self._port = serial.serial_for_url(self.url, baudrate=self.baud, timeout=POLL_S)
            self._port.reset_input_buffer()  # frames queued before we were listening are stale
        except (serial.SerialException, OSError, ValueError) as exc:
            self._close_port()
            raise DeviceError(f"cannot open the tactile port {self.url}: {exc}") from None
        self._stop.clear()
        self._thread = threading.Thread(target=self._reader, name="pps-reader", daemon=True)
        self._thread.start()
        try:
            self._wait_for_frame(0, self.connect_timeout_s, "connecting")
        except DeviceError:
            self._disconnect()
            raise

    def _disconnect(self) -> None:
        self._stop.set()
        port = self._port
        if port is not None and hasattr(port, "cancel_read"):
            with contextlib.suppress(serial.SerialException, OSError):
                port.cancel_read()
        if self._thread is not None:
            self._thread.join(timeout=2 * POLL_S + 1.0)
            self._thread = None
        self._close_port()

    def _close_port(self) -> None:
        port, self._port = self._port, None
        if port is not None:
            with contextlib.suppress(serial.SerialException, OSError):
                port.close()

    # --- readings ---------------------------------------------------------------------------

    def read(self) -> TactileReading:
        """The newest valid frame; TactileTimeoutError if it is older than timeout_s, or the port's loss."""
        self._require_connection()
        with self._cond:
            self._check_port()
            self._grace_if_stale()
            age = time.monotonic() - self._received_at
            if self._latest is None or age > self.timeout_s:
                raise TactileTimeoutError(
                    f"no valid frame from the tactile pads on {self.url} for {age:.2f} s "
                    f"(timeout {self.timeout_s:g} s)"
                )
            self._returned = self._received
            return self._stamped()

    def read_next(self, timeout_s: float | None = None) -> TactileReading:
        """Wait for a frame newer than the last one returned (default wait: timeout_s), and return it."""
        self._require_connection()
        with self._cond:
            self._wait_for_frame(
                self._returned, self.timeout_s if timeout_s is None else timeout_s, "reading"
            )
            self._returned = self._received
            return self._stamped()

    def read_pending(self) -> list[TactileReading]:
        """Every valid frame that arrived since the last call (up to the newest PENDING_MAX), oldest
        first, each stamped with its arrival on the run clock; the port's loss raises."""
        self._require_connection()
        with self._cond:
            self._check_port()
            self._grace_if_stale()
            if self._received and time.monotonic() - self._received_at > self.timeout_s:
                raise TactileTimeoutError(
                    f"no valid frame from the tactile pads on {self.url} for "
                    f"{time.monotonic() - self._received_at:.2f} s (timeout {self.timeout_s:g} s)"
                )
            pending, self._pending = self._pending, []
            self._returned = self._received
            now_clock, now = self.clock.now(), time.monotonic()
        return [dataclasses.replace(r, t_s=now_clock - (now - arrived)) for r, arrived in pending]

    def _stamped(self) -> TactileReading:
        """The newest reading, its arrival placed on the run clock as it reads now (the rig restarts
        a wall clock when the run begins, after frames have started to arrive)."""
        age = time.monotonic() - self._received_at
        return dataclasses.replace(self._latest, t_s=self.clock.now() - age)

    def _grace_if_stale(self) -> None:
        """The newest frame is older than timeout_s: wait up to READER_GRACE_S for the reader (held)."""
        if self._received and time.monotonic() - self._received_at > self.timeout_s:
            before = self._received
            self._cond.wait_for(lambda: self._received > before or self._lost, READER_GRACE_S)
            self._check_port()

    def _wait_for_frame(self, after: int, timeout_s: float, doing: str) -> None:
        with self._cond:
            if not self._cond.wait_for(lambda: self._received > after or self._lost, timeout_s):
                raise TactileTimeoutError(
                    f"no valid frame from the tactile pads on {self.url} within {timeout_s:g} s while "
                    f"{doing}: is the interface powered, streaming and at {self.baud} baud?"
                )
            self._check_port()

    def _check_port(self) -> None:
        if self._lost is not None:
            raise TactilePortLostError(self._lost)

    # --- the reader thread ------------------------------------------------------------------

    def _reader(self) -> None:
        port = self._port
        while not self._stop.is_set():
            try:
                data = port.read(self.decoder.needed)  # exactly what could complete a frame: no extra wait
            except (serial.SerialException, OSError) as exc:
                if not self._stop.is_set():  # a closed port raises these too; then it was us
                    with self._cond:
                        self._lost = f"the tactile port {self.url} was lost: reading failed ({exc})"
                        self._cond.notify_all()
                return
            if not data:
                continue
            t_s = self.clock.now()
            frames = self.decoder.feed(data)
            if frames:
                with self._cond:
                    for frame in frames:
                        self._accept(frame, t_s)
                    self._cond.notify_all()

    def _accept(self, frame: Frame, t_s: float) -> None:
        if self.last_frame is None:  # joined a stream mid-frame: what came before is not a line fault
            self._joined_bytes = self.decoder.discarded_bytes
            self._joined_bad = self.decoder.bad_frames
        else:
            step = (frame.sequence - self.last_frame.sequence) % SEQUENCE_MODULO
            if 0 < step < SEQUENCE_MODULO // 2:
                self.dropped_frames += step - 1
            else:
                self.sequence_restarts += 1
        self.last_frame = frame
        self._latest = TactileReading(
            t_s=t_s, counts=frame.counts, sequence=frame.sequence, dropped_frames=self.dropped_frames
        )
        self._received += 1
        self._received_at = time.monotonic()
        self._pending.append((self._latest, self._received_at))
        if len(self._pending) > PENDING_MAX:  # nobody is draining: keep the newest
            del self._pending[0]

    def diagnostics(self) -> dict[str, Any]:
        """Counters of the link since the first valid frame: frames, drops, bad frames, discarded bytes
        (bytes of a frame already under way when we connected are counted apart)."""
        with self._cond:
            return {
                "frames": self._received,
                "dropped_frames": self.dropped_frames,
                "bad_frames": self.decoder.bad_frames - self._joined_bad,
                "discarded_bytes": self.decoder.discarded_bytes - self._joined_bytes,
                "joined_mid_frame_bytes": self._joined_bytes,
                "sequence_restarts": self.sequence_restarts,
            }

    def metadata(self) -> dict[str, Any]:
        """Port, rate and timeouts, for run.json."""
        return {
            "port": self.url,
            "baud": self.baud,
            "rate_hz": self.config.rate_hz,
            "timeout_s": self.timeout_s,
            "frame_layout": "twin.hardware.pps.frame (assumed; see its docstring)",
        }
