"""The stereo capture's configuration: sources, the OpenCV backend by name, sizes and timeout.

Kept apart from the capture (hardware/cameras/driver.py) so that reading a rig file, or running a rig
without cameras, never imports OpenCV (~0.25 s of start-up).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from twin.interface.errors import ConfigError
from twin.interface.specs import DeviceSpec
from twin.interface.stereo_spec import StereoConfig, stereo_device_spec

BACKENDS: dict[str, str] = {
    "any": "CAP_ANY",
    "firewire": "CAP_FIREWIRE",
    "v4l2": "CAP_V4L2",
    "gstreamer": "CAP_GSTREAMER",
    "ffmpeg": "CAP_FFMPEG",
    "images": "CAP_IMAGES",
}
"""Backend names accepted in the config and the OpenCV API preference each selects (a cv2 constant's
name, looked up when the capture opens)."""
SIDES = ("left", "right")

Source = int | str


def describe_source(source: Source, limit: int = 120) -> str:
    """The source on one line, shortened in the middle (a file name stays whole): index, path or pipeline."""
    if isinstance(source, int):
        return f"device {source}"
    text = " ".join(str(source).split())
    if len(text) > limit:
        text = text[: limit // 3] + "..." + text[-(limit - limit // 3 - 3) :]
    return repr(text)


_FLEA2 = StereoConfig()
"""The Flea2 pair's declared rate, delay and sizes, defined once (twin.interface.stereo_spec)."""


@dataclass(frozen=True, kw_only=True)
class StereoCaptureConfig:
    """Sources, backend, sizes and timeout of the stereo capture (hardware/cameras/driver.py)."""

    left: Source
    right: Source
    """Device index, device path, video file, image pattern (frame_%04d.png) or GStreamer pipeline.
    A string of digits is taken as a device index."""
    backend: str = "any"
    """A key of BACKENDS: 'any', 'firewire', 'v4l2', 'gstreamer', 'ffmpeg' or 'images'."""
    rate_hz: float = _FLEA2.rate_hz
    """Expected frame rate: the period that gap and pairing checks compare to."""
    latency_s: float = _FLEA2.latency_s
    native_width: int = _FLEA2.native_width
    native_height: int = _FLEA2.native_height
    """Size requested from live cameras (the Flea2 readout)."""
    width: int = _FLEA2.width
    height: int = _FLEA2.height
    """Size of every delivered frame (the paper's real-time resolution)."""
    timeout_s: float = 1.0
    """read() fails when a camera gives no frame for this long."""
    resync: bool = True
    """Re-grab the lagging camera when comparable device timestamps are > half a period apart."""
    buffer_size: int | None = 1
    """CAP_PROP_BUFFERSIZE for live cameras (1: the newest frame, not a stale queued one); None: leave."""

    def __post_init__(self) -> None:
        for side in SIDES:
            source = getattr(self, side)
            if isinstance(source, bool) or not isinstance(source, int | str):
                raise ConfigError(f"stereo {side} source must be a device index or a string, got {source!r}")
            if isinstance(source, str):
                if not source.strip():
                    raise ConfigError(f"stereo {side} source is empty")
                if source.strip().isdigit():
                    object.__setattr__(self, side, int(source))
        if self.backend not in BACKENDS:
            raise ConfigError(f"stereo backend {self.backend!r} is not one of {', '.join(BACKENDS)}")
        if not (self.rate_hz > 0 and math.isfinite(self.rate_hz)):
            raise ConfigError(f"stereo rate_hz must be > 0, got {self.rate_hz}")
        if min(self.native_width, self.native_height, self.width, self.height) < 1:
            raise ConfigError("stereo image sizes must be >= 1 pixel")
        if self.width * self.native_height != self.height * self.native_width:
            raise ConfigError("stereo processed and native sizes must have the same aspect ratio")
        if not self.timeout_s > 0:
            raise ConfigError(f"stereo timeout_s must be > 0, got {self.timeout_s}")
        if self.buffer_size is not None and self.buffer_size < 1:
            raise ConfigError("stereo buffer_size must be >= 1 or None")

    @property
    def period_s(self) -> float:
        """Frame period (s)."""
        return 1.0 / self.rate_hz

    def is_live(self, source: Source) -> bool:
        """Whether a source is a camera (index, /dev path, FireWire, V4L2), not a file or a pipeline."""
        return (
            isinstance(source, int) or str(source).startswith("/dev/") or self.backend in ("firewire", "v4l2")
        )


def stereo_capture_spec(config: StereoCaptureConfig) -> DeviceSpec:
    """The declared channels: left and right (H, W, 3) uint8 RGB frames at the processed size (the
    shared stereo spec; the noise of real cameras is not declared: 0)."""
    frames = StereoConfig(
        rate_hz=config.rate_hz,
        latency_s=config.latency_s,
        native_width=config.native_width,
        native_height=config.native_height,
        width=config.width,
        height=config.height,
        noise_std=0.0,
    )
    return replace(stereo_device_spec(frames), description="two Point Grey Flea2 on cv2.VideoCapture")
