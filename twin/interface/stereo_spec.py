"""The stereo pair's declared channels, built from a StereoConfig; shared by the sim and hardware."""

from __future__ import annotations

import math
from dataclasses import dataclass

from twin.interface.errors import ConfigError
from twin.interface.specs import ChannelSpec, DeviceSpec

FLEA2_PIXEL_PITCH_MM = 0.0074
"""Sony ICX424 (1/3" CCD of the Flea2 FL2-03S2): 7.4 um square pixels, 640x480 active (4.74 x 3.55 mm)."""
LENS_FOCAL_MM = 6.0
"""Assumed C-mount lens: a common 6 mm choice that frames a hand-sized object at ~40 cm."""
FLEA2_FOVY_DEG = math.degrees(2.0 * math.atan(480 * FLEA2_PIXEL_PITCH_MM / 2.0 / LENS_FOCAL_MM))
"""Vertical field of view of that sensor behind that lens: 2 atan(3.552 mm / 2 / 6 mm) = 32.98 deg."""


@dataclass(frozen=True, kw_only=True)
class StereoConfig:
    """Frame rate, delay, resolutions, noise and field of view of the Flea2 pair (both backends).

    Intrinsics: a Flea2 FL2-03S2 (Sony ICX424, 1/3" CCD, 7.4 um pixels, 640x480) behind a 6 mm lens
    has f = 6 / 0.0074 = 811 px at 640x480 (405 px at 320x240), i.e. fovy = 32.98 deg and a
    horizontal field of 43.0 deg; at ~39 cm the view is ~23 x 31 cm, so a 6 cm foam block spans
    ~65 of the 320 processed columns. Square pixels, principal point at the image centre, no
    distortion (the sim's pinhole; a real calibration file carries the measured values).
    """

    rate_hz: float = 30.0
    """Flea2 at 640x480 (hardware_facts §5)."""
    latency_s: float = 0.035
    """Exposure to host: FireWire isochronous transfer spreads a frame over its ~33 ms period."""
    native_width: int = 640
    native_height: int = 480
    """The sensor's readout (hardware_facts §5)."""
    width: int = 320
    height: int = 240
    """The processed frame every reading delivers (the paper's real-time resolution)."""
    noise_std: float = 2.0
    """Gaussian noise of a delivered pixel, in 8-bit levels, before rounding (a CCD at good light)."""
    fovy_deg: float = FLEA2_FOVY_DEG
    """Vertical field of view (MuJoCo camera fovy); see the class docstring."""

    def __post_init__(self) -> None:
        if not self.rate_hz > 0:
            raise ConfigError("stereo rate_hz must be > 0")
        if min(self.native_width, self.native_height, self.width, self.height) < 1:
            raise ConfigError("stereo image sizes must be >= 1 pixel")
        if self.width > self.native_width or self.height > self.native_height:
            raise ConfigError(
                f"processed size {self.width}x{self.height} exceeds the native "
                f"{self.native_width}x{self.native_height}"
            )
        if self.width * self.native_height != self.height * self.native_width:
            raise ConfigError("processed and native sizes must have the same aspect ratio")
        if self.noise_std < 0:
            raise ConfigError("stereo noise_std must be >= 0")
        if not 0 < self.fovy_deg < 180:
            raise ConfigError(f"stereo fovy_deg must be in (0, 180), got {self.fovy_deg:g}")

    @property
    def focal_px(self) -> float:
        """Focal length in processed pixels (fx = fy): (height / 2) / tan(fovy / 2)."""
        return 0.5 * self.height / math.tan(math.radians(self.fovy_deg) / 2.0)


def stereo_device_spec(config: StereoConfig) -> DeviceSpec:
    """The stereo DeviceSpec: left and right (H, W, 3) uint8 RGB frames at the processed size."""
    shape = (config.height, config.width, 3)

    def channel(side: str) -> ChannelSpec:
        return ChannelSpec(
            unit="level",
            shape=shape,
            dtype="uint8",
            saturation=(0, 255),
            noise_std=config.noise_std,
            description=f"{side} Flea2 frame, RGB, {config.width}x{config.height} "
            f"(native {config.native_width}x{config.native_height})",
        )

    return DeviceSpec(
        name="stereo",
        rate_hz=config.rate_hz,
        latency_s=config.latency_s,
        description="two Point Grey Flea2, 20 cm apart, ~30 deg between optical axes",
        channels={"left": channel("left"), "right": channel("right")},
    )
