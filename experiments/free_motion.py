"""Free motion: the fingers swing open and closed with nothing in the hand (R = 0 in eq. 4).

The run that identifies the hand's own terms of eq. 4 (twin.identify.hand_dynamics): two sines per
finger (0.3 and 0.7 Hz) so velocity and acceleration are not proportional, over the middle of the
travel where the links never touch each other or the palm. Backend-agnostic, like compress.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from twin.interface.devices import HandCommand, HandReading
from twin.interface.errors import ConfigError

if TYPE_CHECKING:
    from twin.interface.backend import Backend
    from twin.session import RunOutcome

PHASES = ("swing",)


@dataclass(frozen=True, kw_only=True)
class FreeMotionProfile:
    """Set points m(t) = centre + a1 sin(2 pi f1 t) + a2 sin(2 pi f2 t), counts."""

    centre_counts: float = 5000.0
    amplitudes_counts: tuple[float, float] = (2500.0, 800.0)
    frequencies_hz: tuple[float, float] = (0.3, 0.7)
    max_velocity_counts_s: float = 8000.0
    """Slew limit: above the profile's peak rate (~8200 counts/s is the sum of the two sines' peaks)."""

    def __post_init__(self) -> None:
        low = self.centre_counts - sum(self.amplitudes_counts)
        high = self.centre_counts + sum(self.amplitudes_counts)
        if low < 500 or high > 9000:
            raise ConfigError(
                "free motion: the swing must stay within 500-9000 counts (links clear of the palm)"
            )

    def setpoint_counts(self, t_s: float) -> float:
        """The set point at time t_s (counts)."""
        return self.centre_counts + sum(
            a * math.sin(2 * math.pi * f * t_s)
            for a, f in zip(self.amplitudes_counts, self.frequencies_hz, strict=True)
        )

    def to_json(self) -> dict:
        """Plain-JSON constants for run metadata."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in vars(self).items()}


@dataclass
class FreeMotionController:
    """Every finger follows the profile; the spread stays at 0."""

    profile: FreeMotionProfile = field(default_factory=FreeMotionProfile)
    phase: str = "swing"
    _t0: float | None = None

    def __call__(self, reading: HandReading) -> HandCommand:
        """Next set points from the latest reading."""
        if self._t0 is None:
            self._t0 = reading.t_s
        target = self.profile.setpoint_counts(reading.t_s - self._t0)
        return HandCommand(
            np.array([target, target, target, 0.0]), max_velocity_counts_s=self.profile.max_velocity_counts_s
        )


def run_free_motion(
    backend: Backend,
    run_dir: Path | str,
    *,
    duration_s: float,
    profile: FreeMotionProfile | None = None,
    progress: Callable[[float], None] | None = None,
    argv: list[str] | None = None,
) -> RunOutcome:
    """The free-motion procedure on any backend (what `twin run free` does); the hand must be empty."""
    from twin.session import run_experiment

    profile = profile or FreeMotionProfile()
    return run_experiment(
        backend=backend,
        controller=FreeMotionController(profile),
        phases=PHASES,
        duration_s=duration_s,
        run_dir=Path(run_dir),
        experiment={"name": "free", "object": "none", "profile": profile.to_json()},
        progress=progress,
        argv=argv,
    )
