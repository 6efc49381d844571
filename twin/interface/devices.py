"""The backend-agnostic device interface: the hand, the tactile array and the stereo camera.

A device does not know whether it is simulated. Readings leave it in the units the real device
reports (encoder counts, strain 0-255, 15-bit taxel counts, 8-bit frames); physical units come from
twin.units. This module imports no backend.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from concurrent.futures import Future
from dataclasses import dataclass
from typing import TYPE_CHECKING, Self

import numpy as np
from numpy.typing import NDArray

from twin.interface.errors import DeviceNotConnectedError
from twin.interface.specs import DeviceSpec

if TYPE_CHECKING:
    from twin.interface.hand_spec import HandConfig
    from twin.interface.tactile_spec import TactileConfig

MOTOR_LABELS = ("F1", "F2", "F3", "S")
FINGER_LABELS = ("F1", "F2", "F3")


class Device(ABC):
    """Connect/disconnect life cycle shared by every device (a context manager)."""

    def __init__(self) -> None:
        self._connected = False

    @property
    @abstractmethod
    def spec(self) -> DeviceSpec:
        """Rate, latency and channels; available before connect()."""

    @property
    def is_connected(self) -> bool:
        """Whether connect() succeeded and disconnect() has not been called."""
        return self._connected

    def connect(self) -> None:
        """Open the device; raises DeviceNotConfiguredError or DeviceError on failure."""
        self._connect()
        self._connected = True

    def disconnect(self) -> None:
        """Close the device; safe to call twice."""
        if self._connected:
            self._connected = False
            self._disconnect()

    def _require_connection(self) -> None:
        if not self._connected:
            raise DeviceNotConnectedError(f"{self.spec.name} is not connected; call connect() first")

    @abstractmethod
    def _connect(self) -> None: ...

    @abstractmethod
    def _disconnect(self) -> None: ...

    def __enter__(self) -> Self:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.disconnect()


@dataclass(frozen=True)
class HandReading:
    """One feedback sample of the BH8: motors in order F1, F2, F3, spread."""

    t_s: float
    """When the hand sampled it, on the run clock."""
    position_counts: NDArray[np.int32]
    """(4,) encoder counts of the finger motors and the spread motor."""
    velocity_counts: NDArray[np.int32]
    """(4,) encoder counts per velocity sample time (see HandSpec)."""
    strain_counts: NDArray[np.int32]
    """(3,) strain gauges 0-255 of F1-F3 (torque about the distal joint)."""


@dataclass(frozen=True)
class HandCommand:
    """Position set points for the 4 motors (counts) and the slew limit to reach them."""

    position_counts: NDArray[np.float64]
    max_velocity_counts_s: float = 8_000.0

    def __post_init__(self) -> None:
        pos = np.asarray(self.position_counts, dtype=np.float64)
        if pos.shape != (4,):
            raise ValueError(f"position_counts must have 4 entries (F1, F2, F3, S), got {pos.shape}")
        object.__setattr__(self, "position_counts", pos)


class Hand(Device):
    """The BH8 hand: 4 motors commanded in counts; encoder, velocity and strain readings."""

    config: HandConfig
    """Declared sampling and corruption (same type for every backend)."""
    recoveries: Sequence[str] = ()
    """Why each feedback cycle the driver had to retry was retried, one line each, in order (a real hand's
    driver appends to it; a simulated hand loses no cycle). The rig marks each one at its reading."""

    @abstractmethod
    def read(self) -> HandReading:
        """Sample the hand now (sim: the present state; hardware: one feedback cycle)."""

    @abstractmethod
    def command(self, command: HandCommand) -> HandCommand:
        """Send set points; returns the command actually applied after the device's clipping."""

    @abstractmethod
    def idle(self) -> None:
        """Terminate motor control (the protocol's T): motors stop driving."""


N_TAXELS = 162
"""7 pads: 3 fingertips x 22, 3 inner links x 24, the palm 24 (paper §5, hardware_facts §4)."""
TAXEL_COUNT_MAX = 32767
"""Largest raw reading: 15-bit counts (hardware_facts §4)."""


@dataclass(frozen=True)
class TactileReading:
    """One scan of the 162 taxels in raw 15-bit counts, in taxel-id order (twin.tactile.layout)."""

    t_s: float
    """When the scan was taken, on the run clock."""
    counts: NDArray[np.int32]
    """(162,) raw counts 0-32767."""
    sequence: int = -1
    """The device's frame number (-1 where the device has none, as in the sim)."""
    dropped_frames: int = 0
    """Frames lost on the way since the device was connected (sequence gaps, bad frames)."""

    def __post_init__(self) -> None:
        counts = np.asarray(self.counts)
        if counts.shape != (N_TAXELS,):
            raise ValueError(f"a tactile scan has {N_TAXELS} counts, got shape {counts.shape}")


class TactileArray(Device):
    """The PPS tactile pads (7 pads, 162 taxels)."""

    config: TactileConfig
    """Declared rate, latency and noise (same type for every backend)."""

    @abstractmethod
    def read(self) -> TactileReading:
        """The latest scan of all taxels (sim: scanned now; hardware: the newest frame received)."""

    def read_pending(self) -> list[TactileReading]:
        """Every scan not yet returned, oldest first: what the rig records at each sampling instant.

        A device scanned on demand (the sim) returns one scan taken now; one that streams frames by
        itself (the PPS interface) returns those that arrived since the last call, so none is recorded
        twice or skipped when its clock and the rig's drift apart.
        """
        return [self.read()]


@dataclass(frozen=True)
class StereoFrame:
    """A synchronised image pair (H, W, 3) uint8, RGB."""

    t_s: float
    left: NDArray[np.uint8]
    right: NDArray[np.uint8]


class StereoCamera(Device):
    """The Flea2 stereo pair."""

    @abstractmethod
    def read(self) -> StereoFrame:
        """Grab both cameras, then retrieve both frames."""

    def read_async(self) -> Future[StereoFrame]:
        """The pair exposed now, delivered when ready: a device that can render or decode in the
        background (the sim) lets the caller go on meanwhile; by default the pair is read now."""
        future: Future[StereoFrame] = Future()
        try:
            future.set_result(self.read())
        except Exception as exc:
            future.set_exception(exc)
        return future
