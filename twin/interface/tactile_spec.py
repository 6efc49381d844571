"""The tactile pads' declared channel, built from a TactileConfig; shared by the sim and hardware."""

from __future__ import annotations

from dataclasses import dataclass

from twin.interface.devices import N_TAXELS, TAXEL_COUNT_MAX
from twin.interface.errors import ConfigError
from twin.interface.specs import ChannelSpec, DeviceSpec


@dataclass(frozen=True, kw_only=True)
class TactileConfig:
    """Scan rate, delay and noise of the PPS pads, as declared for both backends."""

    rate_hz: float = 30.0
    """Full scan of the 162 taxels (hardware_facts §4)."""
    latency_s: float = 0.005
    """Scan-to-host delay: one 336-byte frame at 1 Mbit/s is ~3.4 ms on the wire."""
    noise_counts: float = 4.0
    """Gaussian noise of a raw reading before quantization (counts)."""

    def __post_init__(self) -> None:
        if not self.rate_hz > 0:
            raise ConfigError("tactile rate_hz must be > 0")
        if self.noise_counts < 0:
            raise ConfigError("tactile noise_counts must be >= 0")


def tactile_device_spec(config: TactileConfig) -> DeviceSpec:
    """The tactile DeviceSpec: one (162,) channel of raw 15-bit counts."""
    return DeviceSpec(
        name="tactile",
        rate_hz=config.rate_hz,
        latency_s=config.latency_s,
        description="PPS RoboTouch: 3 fingertips x 22, 3 inner links x 24, palm 24 taxels",
        channels={
            "counts": ChannelSpec(
                unit="counts",
                shape=(N_TAXELS,),
                saturation=(0, TAXEL_COUNT_MAX),
                noise_std=config.noise_counts,
                description="raw capacitive reading per taxel, 15 bit; eq. 5 gives kPa",
            )
        },
    )
