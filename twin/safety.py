"""One safety layer for every backend, between the procedure and the hand.

Non-finite or out-of-range set points and velocities are rejected before they reach a device (the
run stops with a one-line error and the hand is idled). A finger whose fingertip force (eq. 3) has
reached the 2 kg limit may hold or open but not close further, whatever the procedure asks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from twin import units
from twin.interface.devices import HandCommand, HandReading
from twin.interface.errors import ConfigError, TwinError


class UnsafeCommandError(TwinError):
    """A command outside the rig's limits; it was not sent."""


@dataclass(frozen=True, kw_only=True)
class SafetyLimits:
    """The envelope every command must stay in (defaults: the BH8-262 datasheet)."""

    finger_counts: tuple[float, float] = (0.0, float(units.FINGER_MAX_COUNTS))
    spread_counts: tuple[float, float] = (0.0, float(units.SPREAD_FULL_COUNTS))
    max_velocity_counts_s: float = 17_000.0
    max_fingertip_force_kg: float = units.FINGERTIP_FORCE_LIMIT_KG

    def __post_init__(self) -> None:
        for name in ("finger_counts", "spread_counts"):
            lo, hi = getattr(self, name)
            if not (math.isfinite(lo) and math.isfinite(hi) and 0 <= lo < hi):
                raise ConfigError(f"limits {name} must be finite with 0 <= low < high, got {[lo, hi]}")
        if not self.finger_counts[1] <= units.FINGER_MAX_COUNTS:
            raise ConfigError(f"limits finger_counts above the firmware's {units.FINGER_MAX_COUNTS} counts")
        if not self.spread_counts[1] <= units.SPREAD_FULL_COUNTS:
            raise ConfigError(f"limits spread_counts above the firmware's {units.SPREAD_FULL_COUNTS} counts")
        for name in ("max_velocity_counts_s", "max_fingertip_force_kg"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"limits {name} must be a finite number > 0, got {value}")


class SafetyLayer:
    """Checks commands against SafetyLimits and the latest reading's fingertip forces."""

    def __init__(self, limits: SafetyLimits | None = None) -> None:
        self.limits = limits or SafetyLimits()
        self._position = None
        self._at_force_limit = np.zeros(3, dtype=bool)

    def observe(self, reading: HandReading) -> None:
        """Remember where the fingers are and which press at the force limit."""
        self._position = reading.position_counts.astype(float)
        force_kg = units.strain_to_force_kg(reading.strain_counts)
        self._at_force_limit = force_kg >= self.limits.max_fingertip_force_kg

    @property
    def at_force_limit(self) -> np.ndarray:
        """(3,) fingers held at the fingertip force limit by the last reading."""
        return self._at_force_limit.copy()

    def check(self, command: HandCommand) -> HandCommand:
        """The command to send, or UnsafeCommandError; never returns anything outside the limits."""
        pos = command.position_counts
        v = command.max_velocity_counts_s
        if not (np.isfinite(pos).all() and math.isfinite(v)):
            raise UnsafeCommandError(f"non-finite command refused: position {pos.tolist()}, velocity {v}")
        lo, hi = self.limits.finger_counts
        if (pos[:3] < lo).any() or (pos[:3] > hi).any():
            raise UnsafeCommandError(f"finger set point {pos[:3].tolist()} outside [{lo:g}, {hi:g}] counts")
        lo_s, hi_s = self.limits.spread_counts
        if not lo_s <= pos[3] <= hi_s:
            raise UnsafeCommandError(f"spread set point {pos[3]:g} outside [{lo_s:g}, {hi_s:g}] counts")
        if not 0 < v <= self.limits.max_velocity_counts_s:
            raise UnsafeCommandError(
                f"velocity {v:g} counts/s outside (0, {self.limits.max_velocity_counts_s:g}]"
            )
        if self._position is not None and self._at_force_limit.any():
            held = pos.copy()
            held[:3] = np.where(self._at_force_limit, np.minimum(pos[:3], self._position[:3]), pos[:3])
            return HandCommand(held, v)
        return command
