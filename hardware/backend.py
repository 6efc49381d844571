"""The hardware backend: the real BH8 (and later the tactile pads and cameras) on wall time.

Drivers live beside this module and never import the simulator. A device the rig does not
configure fails to connect with DeviceNotConfiguredError, before any run directory is written.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

from twin.interface.backend import Backend, Clock
from twin.interface.devices import Hand, HandCommand, HandReading
from twin.interface.errors import DeviceError, DeviceNotConfiguredError
from twin.interface.hand_spec import HandConfig, hand_device_spec
from twin.interface.specs import DeviceSpec


class WallClock(Clock):
    """Wall time since the clock was created; advancing it sleeps."""

    def __init__(self) -> None:
        self._t0 = time.monotonic()

    def now(self) -> float:
        """Seconds since the run started."""
        return time.monotonic() - self._t0

    def advance_to(self, t_s: float) -> None:
        """Sleep until t_s (returns at once if it has passed)."""
        delay = t_s - self.now()
        if delay > 0:
            time.sleep(delay)


@dataclass(frozen=True, kw_only=True)
class HardwareConfig:
    """The lab's rig: which devices are attached where. Nothing is configured by default."""

    hand: HandConfig = field(default_factory=HandConfig)


class UnconfiguredHand(Hand):
    """The hand slot of a rig that names no hand driver: connect() explains what is missing."""

    def __init__(self, config: HandConfig) -> None:
        super().__init__()
        self.config = config
        self._spec = hand_device_spec(config)

    @property
    def spec(self) -> DeviceSpec:
        """Same declared channels as the sim hand."""
        return self._spec

    def _connect(self) -> None:
        raise DeviceNotConfiguredError(
            "hardware backend: no BH8 hand is configured on this rig "
            "(this version ships no serial driver; use --backend sim)"
        )

    def _disconnect(self) -> None:
        pass

    def read(self) -> HandReading:
        """Never reached: connect() fails first."""
        self._require_connection()
        raise DeviceError("no hand configured")

    def command(self, command: HandCommand) -> HandCommand:
        """Never reached: connect() fails first."""
        self._require_connection()
        raise DeviceError("no hand configured")

    def idle(self) -> None:
        """Never reached: connect() fails first."""
        self._require_connection()


class HardwareBackend(Backend):
    """Real devices on wall time."""

    name = "hardware"

    def __init__(self, config: HardwareConfig | None = None) -> None:
        self.config = config or HardwareConfig()
        self.hand = UnconfiguredHand(self.config.hand)
        self._clock = WallClock()

    @property
    def clock(self) -> Clock:
        """Wall clock."""
        return self._clock

    def metadata(self) -> dict[str, Any]:
        """Ports and settings of this rig."""
        return {"backend": self.name}
