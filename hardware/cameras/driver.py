"""The Flea2 stereo pair behind the shared StereoCamera interface, on two `cv2.VideoCapture` sources.

Paired acquisition as in the paper: `grab()` both cameras, then `retrieve()` both, so the two frames
are taken as close together as the host allows; decoding (retrieve, BGR->RGB, resize) comes after
both grabs. A pair is stamped with the run clock at grab time (the mean of the two grab instants).

Each source is a device index, a device path, a video file, an image-sequence pattern
(`frame_%04d.png`) or a GStreamer pipeline; the OpenCV backend is chosen by name (BACKENDS). Which
backends exist depends on the OpenCV build: the opencv-python wheels have FFMPEG, V4L2 and image
sequences, but neither FireWire (libdc1394) nor GStreamer; `available_backends()` lists them.

Lost frames are counted, per camera, from what the backend tells us: a frame grabbed on one side
without a partner on the other (discarded), a jump in the device's frame counter
(CAP_PROP_POS_FRAMES) or timestamp (CAP_PROP_POS_MSEC, more than one period), and frames skipped to
bring the pair back in step when both devices report comparable timestamps that are more than half a
period apart. A grab that fails is counted apart (`failed_grabs`): a camera at the end of a file fails
every retry, which is not a lost frame each time.

The grabs run on a worker thread so a camera that blocks inside `grab()` cannot hang `read()`: it
fails after the timeout with a one-line error naming the camera. The capture config
(`StereoCaptureConfig`, hardware/cameras/config.py: read without OpenCV) takes its frame defaults from
twin.interface.stereo_spec.StereoConfig.
This module never imports the simulator.
"""

from __future__ import annotations

import math
import queue
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeoutError
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from twin.hardware.cameras.config import (  # apart from this module: a rig file is read without cv2
    BACKENDS,
    SIDES,
    Source,
    StereoCaptureConfig,
    describe_source,
    stereo_capture_spec,
)

from twin.interface.backend import Clock
from twin.interface.devices import StereoCamera, StereoFrame
from twin.interface.errors import DeviceError
from twin.interface.specs import DeviceSpec

STOP_GRACE_S = 0.5
"""Extra wait for the worker beyond timeout_s before a blocked grab is declared."""
CLOCK_MISMATCH_S = 1.0
"""Device timestamps further apart than this are on different clocks: not used to pair frames."""


class CameraMissingError(DeviceError):
    """A camera could not be opened (isOpened() is False)."""


class CameraTimeoutError(DeviceError):
    """A camera gave no frame within the timeout (a stopped camera, or the end of a file)."""


class CameraFormatError(DeviceError):
    """A camera delivered frames that cannot become the configured RGB size."""


def available_backends() -> list[str]:
    """Names in BACKENDS that this OpenCV build can open (for error messages and the report)."""
    # hasBackend, not getBackends: the latter also lists plugin backends whose library is absent
    has = cv2.videoio_registry.hasBackend
    return [name for name, api in BACKENDS.items() if api == "CAP_ANY" or has(getattr(cv2, api))]


@dataclass
class _Side:
    """One camera: its capture, its newest grab and its counters."""

    name: str
    source: Source
    cap: cv2.VideoCapture | None = None
    backend_name: str = ""
    held: bool = False  # grabbed and not yet retrieved
    grab_t: float = math.nan  # run clock when the held frame's grab returned
    pos_frames: float = -1.0  # device counters of the held frame (-1: not reported)
    pos_msec: float = -1.0
    grabs: int = 0
    failed_grabs: int = 0
    failed_retrieves: int = 0
    dropped_frames: int = 0
    counter_gaps: int = 0
    reports_pos_frames: bool = False
    reports_pos_msec: bool = False
    frame_size: tuple[int, int] | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def label(self, backend: str) -> str:
        return f"{self.name} camera ({describe_source(self.source)}, backend {backend})"


class StereoCapture(StereoCamera):
    """Two cv2.VideoCapture sources read as one synchronised pair: grab both, then retrieve both."""

    def __init__(self, config: StereoCaptureConfig, clock: Clock) -> None:
        """`clock` stamps each pair at grab time (the run clock, e.g. twin.hardware.backend.WallClock)."""
        super().__init__()
        self.config = config
        self.clock = clock
        self._spec = stereo_capture_spec(config)
        self._jobs: queue.SimpleQueue[tuple[Future[Any], Callable[[], Any]] | None] = queue.SimpleQueue()
        self._worker: threading.Thread | None = None
        self._blocked: Future[Any] | None = None
        self._in_grab: str | None = None  # the side the worker is inside grab() on
        self._lock = threading.Lock()  # guards the counters read by diagnostics()
        self._reset_state()

    def _reset_state(self) -> None:
        self.sides = {name: _Side(name, getattr(self.config, name)) for name in SIDES}
        self.pairs = 0
        self.resyncs = 0
        """Frames skipped on the lagging side to bring the device timestamps back within half a period."""
        self.unsynced_pairs = 0
        """Pairs delivered whose grab instants on the run clock were more than half a period apart."""
        self.max_grab_skew_s = 0.0
        self.timeouts = 0
        self.clock_mismatch = False
        """True once the two devices' timestamps proved to be on different clocks (no resync on them)."""

    @property
    def spec(self) -> DeviceSpec:
        """Declared rate, latency and channels (same names and shapes as the sim's stereo pair)."""
        return self._spec

    # --- life cycle -------------------------------------------------------------------------

    def _connect(self) -> None:
        self._reset_state()
        api = getattr(cv2, BACKENDS[self.config.backend])
        if self.config.backend not in available_backends():
            raise CameraMissingError(
                f"this OpenCV build ({cv2.__version__}) has no {self.config.backend} backend; "
                f"it has: {', '.join(available_backends())}"
            )
        try:
            for side in self.sides.values():
                self._open(side, api)
        except DeviceError:
            self._release()
            raise
        self._jobs = queue.SimpleQueue()  # a fresh queue: a worker left blocked earlier must not take jobs
        self._worker = threading.Thread(
            target=self._work, args=(self._jobs,), name="stereo-capture", daemon=True
        )
        self._worker.start()

    def _open(self, side: _Side, api: int) -> None:
        label = side.label(self.config.backend)
        try:
            cap = cv2.VideoCapture(side.source, api)
        except cv2.error as exc:
            raise CameraMissingError(f"cannot open the {label}: {' '.join(str(exc).split())}") from None
        if not cap.isOpened():
            cap.release()
            raise CameraMissingError(
                f"cannot open the {label}: not connected, wrong index or path, or unsupported here "
                f"(this OpenCV has: {', '.join(available_backends())})"
            )
        side.cap = cap
        side.backend_name = cap.getBackendName()
        c = self.config
        if c.is_live(side.source):  # ask a camera for the native size and a short queue; files ignore it
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, c.native_width)
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, c.native_height)
            if c.buffer_size is not None:
                cap.set(cv2.CAP_PROP_BUFFERSIZE, c.buffer_size)
        w, h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        side.frame_size = (w, h) if w > 0 and h > 0 else None
        side.extra = {"reported_fps": cap.get(cv2.CAP_PROP_FPS)}

    def _disconnect(self) -> None:
        worker, self._worker = self._worker, None
        if worker is not None:
            self._jobs.put(None)
            worker.join(timeout=STOP_GRACE_S)
            if worker.is_alive():  # blocked inside grab(): releasing under it could crash; leave it
                for side in self.sides.values():
                    side.cap = None
                return
        self._release()

    def _release(self) -> None:
        for side in self.sides.values():
            cap, side.cap = side.cap, None
            side.held = False
            if cap is not None:
                cap.release()

    # --- readings ---------------------------------------------------------------------------

    def read(self) -> StereoFrame:
        """Grab both cameras, then retrieve both frames: the next pair, RGB at the processed size."""
        self._require_connection()
        if self._blocked is not None and not self._blocked.done():
            raise CameraTimeoutError(f"the {self._grabbing_label()} is still blocked in grab(); reconnect")
        self._blocked = None
        future: Future[StereoFrame] = Future()
        self._jobs.put((future, self._acquire))
        try:
            return future.result(timeout=self.config.timeout_s + STOP_GRACE_S)
        except FutureTimeoutError:
            self._blocked = future
            with self._lock:
                self.timeouts += 1
            raise CameraTimeoutError(
                f"the {self._grabbing_label()} blocked in grab() for more than "
                f"{self.config.timeout_s:g} s: is it streaming?"
            ) from None

    def _grabbing_label(self) -> str:
        side = self.sides.get(self._in_grab or "")
        return side.label(self.config.backend) if side else "stereo camera"

    def _work(self, jobs: queue.SimpleQueue[tuple[Future[Any], Callable[[], Any]] | None]) -> None:
        while (job := jobs.get()) is not None:
            future, fn = job
            if not future.set_running_or_notify_cancel():
                continue
            try:
                future.set_result(fn())
            except BaseException as exc:  # delivered to read(), which raises it
                future.set_exception(exc)

    def _acquire(self) -> StereoFrame:
        """On the worker: grab until both sides hold a frame in step, then retrieve and convert both."""
        c = self.config
        deadline = time.monotonic() + c.timeout_s
        retry_s = min(c.period_s / 4.0, 0.01)
        left, right = self.sides["left"], self.sides["right"]
        while True:
            for side in (left, right):
                if not side.held:
                    self._grab(side)
            if left.held and right.held:
                lagging = self._lagging(left, right) if c.resync else None
                if lagging is None:
                    break
                with self._lock:
                    lagging.dropped_frames += 1
                    self.resyncs += 1
                lagging.held = False
                if time.monotonic() < deadline:
                    continue
            elif time.monotonic() < deadline:
                time.sleep(retry_s)
                continue
            self._raise_timeout(left, right)
        skew = abs(left.grab_t - right.grab_t)
        left.held = right.held = False  # a failed retrieve must not leave the other side's frame for later
        images = [self._retrieve(side) for side in (left, right)]
        with self._lock:
            self.pairs += 1
            self.max_grab_skew_s = max(self.max_grab_skew_s, skew)
            if skew > c.period_s / 2:
                self.unsynced_pairs += 1
        return StereoFrame(t_s=(left.grab_t + right.grab_t) / 2, left=images[0], right=images[1])

    def _grab(self, side: _Side) -> None:
        self._in_grab = side.name
        ok = side.cap.grab()
        t_s = self.clock.now()
        self._in_grab = None
        with self._lock:
            if not ok:
                side.failed_grabs += 1
                return
            side.grabs += 1
            side.held, side.grab_t = True, t_s
            self._note_counters(side)

    def _note_counters(self, side: _Side) -> None:
        """Count frames lost between two grabs from the device's frame counter and timestamp."""
        frames, msec = side.cap.get(cv2.CAP_PROP_POS_FRAMES), side.cap.get(cv2.CAP_PROP_POS_MSEC)
        frames = frames if math.isfinite(frames) and frames > 0 else -1.0
        msec = msec if math.isfinite(msec) and msec >= 0 else -1.0
        lost = 0
        if frames >= 0 and side.pos_frames >= 0:
            lost = max(lost, round(frames - side.pos_frames) - 1)
        if msec >= 0 and side.pos_msec >= 0:
            lost = max(lost, round((msec - side.pos_msec) / (1000.0 * self.config.period_s)) - 1)
        if lost > 0:
            side.dropped_frames += lost
            side.counter_gaps += 1
        side.reports_pos_frames |= frames >= 0
        side.reports_pos_msec |= msec > 0
        side.pos_frames, side.pos_msec = frames, msec

    def _lagging(self, left: _Side, right: _Side) -> _Side | None:
        """The side whose held frame is more than half a period older, by comparable device timestamps."""
        if self.clock_mismatch or left.backend_name != right.backend_name:
            return None
        if not (left.reports_pos_msec and right.reports_pos_msec):
            return None
        skew_s = (left.pos_msec - right.pos_msec) / 1000.0
        if abs(skew_s) > CLOCK_MISMATCH_S:
            self.clock_mismatch = True
            return None
        if abs(skew_s) <= self.config.period_s / 2:
            return None
        return left if skew_s < 0 else right

    def _raise_timeout(self, left: _Side, right: _Side) -> None:
        waiting = [s for s in (left, right) if not s.held] or [left, right]
        with self._lock:
            for side in (left, right):  # a frame without a partner is lost
                if side.held:
                    side.dropped_frames += 1
                    side.held = False
            self.timeouts += 1
        names = " and ".join(s.label(self.config.backend) for s in waiting)
        fails = ", ".join(f"{s.failed_grabs} failed grabs on the {s.name}" for s in waiting)
        raise CameraTimeoutError(
            f"no frame from the {names} within {self.config.timeout_s:g} s ({fails}): "
            "the end of a file, or the camera stopped streaming"
        )

    def _retrieve(self, side: _Side) -> NDArray[np.uint8]:
        ok, image = side.cap.retrieve()
        if not ok or image is None or image.size == 0:
            with self._lock:
                side.failed_retrieves += 1
            label = side.label(self.config.backend)
            raise CameraFormatError(f"the {label} grabbed a frame it could not decode")
        return self._to_rgb(side, image)

    def _to_rgb(self, side: _Side, image: NDArray[np.uint8]) -> NDArray[np.uint8]:
        """BGR (or grey, BGRA) 8-bit -> RGB at the processed size, area-averaged like the sim's frames."""
        c = self.config
        if image.dtype != np.uint8:
            raise CameraFormatError(f"the {side.label(c.backend)} delivers {image.dtype} frames, not uint8")
        if image.ndim == 2 or image.shape[2] == 1:
            rgb = cv2.cvtColor(image, cv2.COLOR_GRAY2RGB)
        elif image.shape[2] == 4:
            rgb = cv2.cvtColor(image, cv2.COLOR_BGRA2RGB)
        else:
            rgb = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
        h, w = rgb.shape[:2]
        side.frame_size = (w, h)
        if (h, w) != (c.height, c.width):
            if w * c.height != h * c.width:
                raise CameraFormatError(
                    f"the {side.label(c.backend)} delivers {w}x{h}, which does not scale to "
                    f"{c.width}x{c.height} without distortion"
                )
            rgb = cv2.resize(rgb, (c.width, c.height), interpolation=cv2.INTER_AREA)
        return rgb

    # --- reports ----------------------------------------------------------------------------

    def diagnostics(self) -> dict[str, Any]:
        """Counters since connect(): pairs, frames lost per camera and in total, failed grabs, resyncs."""
        with self._lock:
            per_side = {
                s.name: {
                    "grabs": s.grabs,
                    "failed_grabs": s.failed_grabs,
                    "failed_retrieves": s.failed_retrieves,
                    "dropped_frames": s.dropped_frames,
                    "counter_gaps": s.counter_gaps,
                    "reports_pos_frames": s.reports_pos_frames,
                    "reports_pos_msec": s.reports_pos_msec,
                    "frame_size": s.frame_size,
                    "backend": s.backend_name,
                    **s.extra,
                }
                for s in self.sides.values()
            }
            return {
                "pairs": self.pairs,
                "dropped_frames": sum(s.dropped_frames for s in self.sides.values()),
                "resyncs": self.resyncs,
                "unsynced_pairs": self.unsynced_pairs,
                "max_grab_skew_s": self.max_grab_skew_s,
                "timeouts": self.timeouts,
                "clock_mismatch": self.clock_mismatch,
                **per_side,
            }

    def metadata(self) -> dict[str, Any]:
        """Sources, backend, sizes and timeout, for run.json."""
        c = self.config
        return {
            "left": c.left,
            "right": c.right,
            "backend": c.backend,
            "rate_hz": c.rate_hz,
            "native_size": [c.native_width, c.native_height],
            "size": [c.width, c.height],
            "timeout_s": c.timeout_s,
            "opencv": cv2.__version__,
        }
