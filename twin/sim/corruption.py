"""Apply a channel's declared noise, quantization and saturation to a true value."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from twin.interface.specs import ChannelSpec


def corrupt(value: ArrayLike, spec: ChannelSpec, rng: np.random.Generator) -> NDArray:
    """Noise, then quantization to the LSB, then saturation; cast to the channel dtype."""
    x = np.asarray(value, dtype=np.float64)
    if spec.noise_std > 0:
        x = x + rng.normal(0.0, spec.noise_std, size=x.shape)
    if spec.quantization > 0:
        x = np.round(x / spec.quantization) * spec.quantization
    x = np.clip(x, *spec.saturation)
    return x.astype(spec.dtype)
