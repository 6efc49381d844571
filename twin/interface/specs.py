"""Declared sensor properties: rate, latency, quantization, saturation and noise per channel.

As in dm_control's observables, timing and corruption are declared, not scattered through code:
the sim honours these numbers, a hardware backend reports them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from twin.interface.errors import ConfigError


@dataclass(frozen=True, kw_only=True)
class ChannelSpec:
    """One reading channel of a device, in the device's own (hardware) units."""

    unit: str
    shape: tuple[int, ...] = ()
    dtype: str = "int32"
    quantization: float = 1.0
    """Least significant bit, in `unit` (0 for a continuous channel)."""
    saturation: tuple[float, float] = (-math.inf, math.inf)
    noise_std: float = 0.0
    """Standard deviation of additive Gaussian noise before quantization, in `unit`."""
    labels: tuple[str, ...] = ()
    description: str = ""

    def __post_init__(self) -> None:
        lo, hi = self.saturation
        if not lo < hi:
            raise ConfigError(f"saturation must be (low, high) with low < high, got {self.saturation}")
        if self.noise_std < 0 or self.quantization < 0:
            raise ConfigError("noise_std and quantization must be >= 0")
        if self.labels and self.shape and len(self.labels) != self.shape[0]:
            raise ConfigError(f"{len(self.labels)} labels for a channel of shape {self.shape}")


@dataclass(frozen=True, kw_only=True)
class DeviceSpec:
    """A device's sampling schedule and its channels; readable before connect()."""

    name: str
    rate_hz: float
    latency_s: float = 0.0
    channels: dict[str, ChannelSpec] = field(default_factory=dict)
    description: str = ""

    def __post_init__(self) -> None:
        if not (self.rate_hz > 0 and math.isfinite(self.rate_hz)):
            raise ConfigError(f"{self.name}: rate_hz must be a positive number, got {self.rate_hz}")
        if not (0 <= self.latency_s < 1.0):
            raise ConfigError(f"{self.name}: latency_s must be in [0, 1) s, got {self.latency_s}")

    @property
    def period_s(self) -> float:
        """Sampling period (s)."""
        return 1.0 / self.rate_hz
