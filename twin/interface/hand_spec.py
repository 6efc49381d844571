"""The BH8's declared channels, built from a HandConfig; shared by the sim and hardware backends."""

from __future__ import annotations

from dataclasses import dataclass

from twin import units
from twin.interface.devices import FINGER_LABELS, MOTOR_LABELS
from twin.interface.errors import ConfigError
from twin.interface.specs import ChannelSpec, DeviceSpec


@dataclass(frozen=True, kw_only=True)
class HandConfig:
    """Sampling and corruption of the hand's feedback, as declared for both backends."""

    rate_hz: float = 30.0
    """RealTime feedback rate: one lab measured ~33 ms per cycle at 38400 baud (bh262_protocol.md)."""
    latency_s: float = 0.004
    """Sample-to-host delay: ~13 feedback bytes at 38400 baud take ~3.4 ms on the wire."""
    strain_noise_counts: float = 0.6
    """Gaussian noise on the strain gauges before quantization (counts)."""
    velocity_sample_time_s: float = units.VELOCITY_SAMPLE_TIME_S
    max_velocity_counts_s: float = 17_000.0
    """Fastest finger motion: the BH8 closes its full range in about 1 s (datasheet)."""

    def __post_init__(self) -> None:
        if self.strain_noise_counts < 0:
            raise ConfigError("strain_noise_counts must be >= 0")
        if not self.velocity_sample_time_s > 0:
            raise ConfigError("velocity_sample_time_s must be > 0")
        if not self.max_velocity_counts_s > 0:
            raise ConfigError("max_velocity_counts_s must be > 0")


def hand_device_spec(config: HandConfig) -> DeviceSpec:
    """The hand's DeviceSpec: position, velocity (counts) and strain (0-255) channels."""
    return DeviceSpec(
        name="hand",
        rate_hz=config.rate_hz,
        latency_s=config.latency_s,
        description="Barrett BH8-262: motors F1, F2, F3, spread",
        channels={
            "position_counts": ChannelSpec(
                unit="counts",
                shape=(4,),
                saturation=(0, units.FINGER_MAX_COUNTS),
                labels=MOTOR_LABELS,
                description="motor encoder position",
            ),
            "velocity_counts": ChannelSpec(
                unit=f"counts/{config.velocity_sample_time_s:g}s",
                shape=(4,),
                saturation=(-127 * 255, 127 * 255),
                labels=MOTOR_LABELS,
                description="encoder counts per velocity sample time",
            ),
            "strain_counts": ChannelSpec(
                unit="counts",
                shape=(3,),
                saturation=(units.SG_MIN, units.SG_MAX),
                noise_std=config.strain_noise_counts,
                labels=FINGER_LABELS,
                description="distal-joint strain gauge, eq. 2",
            ),
        },
    )
