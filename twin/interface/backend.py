"""What the rig needs from a backend: its devices and its clock.

The sim backend's clock is simulated time that advances as fast as the physics runs (deterministic
for a seed); the hardware backend's clock is wall time. The rig only calls this interface.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from twin.interface.devices import Hand, StereoCamera, TactileArray


class Clock(ABC):
    """The run clock, in seconds from the start of the run."""

    @abstractmethod
    def now(self) -> float:
        """Present time on the run clock (s)."""

    @abstractmethod
    def advance_to(self, t_s: float) -> None:
        """Bring the world to time t_s: step the physics (sim) or sleep (hardware)."""

    def start(self) -> None:  # noqa: B027  (optional hook: most clocks need nothing)
        """The run starts now: a wall clock restarts from zero; sim time is left as it is."""


STEREO_CALIBRATION_KEY = "stereo_calibration"
"""The first pair's calibration in Backend.write_calibration's files (and the run's calibration/)."""


def stereo_stream_name(pair: int, name: str) -> str:
    """The recorded stream of the rig's pair `pair`, named `name` (Backend.named_stereo_pairs): `stereo`
    for the first (every reader of a one-pair run reads it), `stereo_<name>` for a further one."""
    return "stereo" if pair == 0 else f"stereo_{name}"


def stereo_calibration_key(pair: int, name: str) -> str:
    """Pair `pair`'s calibration in Backend.write_calibration's files (its file: the key + .json)."""
    return STEREO_CALIBRATION_KEY if pair == 0 else f"{STEREO_CALIBRATION_KEY}_{name}"


class Backend(ABC):
    """A set of devices on one clock."""

    name: str
    hand: Hand
    tactile: TactileArray | None = None
    stereo: StereoCamera | None = None

    @property
    @abstractmethod
    def clock(self) -> Clock:
        """The clock the rig schedules sampling on."""

    @property
    def is_simulated(self) -> bool:
        """True when time is simulated (the rig never sleeps)."""
        return False

    def connect(self) -> None:
        """Connect every device; on failure disconnect those already connected."""
        done = []
        try:
            for device in self.devices():
                device.connect()
                done.append(device)
        except BaseException:
            for device in reversed(done):
                device.disconnect()
            raise

    def disconnect(self) -> None:
        """Disconnect every device (idles the hand first), each even if another fails; the first
        failure is raised once all were tried."""
        first: Exception | None = None
        for device in reversed(self.devices()):
            try:
                device.disconnect()
            except Exception as exc:
                first = first or exc
        if first is not None:
            raise first

    def devices(self) -> list[Any]:
        """The devices present, hand first."""
        return [d for d in (self.hand, self.tactile, self.stereo) if d is not None]

    def ground_truth(self) -> Mapping[str, np.ndarray] | None:
        """Quantities only a simulator knows (joint angles, contact forces); None on hardware."""
        return None

    def metadata(self) -> dict[str, Any]:
        """What the run's metadata should record about this backend."""
        return {"backend": self.name}

    def scene(self) -> tuple[Any, Any] | None:
        """(MjModel, MjData) to draw in 3-D, where the backend has a MuJoCo world; None otherwise."""
        return None

    def named_stereo_pairs(self) -> list[tuple[str, StereoCamera]]:
        """Every stereo pair of the rig with the name of where it stands, `stereo` first: a run records
        each (twin.rig.stereo_stream_name). Default: `stereo` alone, named `main`."""
        return [] if self.stereo is None else [("main", self.stereo)]

    def object_box(self, rectifier: Any, *, pair: int = 0) -> tuple[int, int, int, int] | None:
        """The object's bounding box (x, y, w, h) in the rectified left view of pair `pair`, where the
        backend knows it (the sim projects its foam); None: the user draws it (`--bbox`)."""
        return None

    def surface_truth(self, rectifier: Any) -> Any:
        """A snapshot of the object's true surface now (the sim), to score the reconstruction of the
        frame sampled now against; None where nobody knows it (hardware)."""
        return None

    def score_surface(self, truth: Any, points_hand: np.ndarray, pixels: np.ndarray) -> dict | None:
        """Score reconstructed points and their rectified left pixels against a `surface_truth`
        snapshot (thread-safe: it may run on the vision worker); None without truth."""
        return None

    def hand_pose_in_world(self) -> np.ndarray | None:
        """4x4 pose of the hand frame (palm) in the 3-D scene's world frame; None without a scene."""
        return None

    def safety_limits(self) -> Any:
        """The rig's SafetyLimits where it declares its own (hardware: rig.toml); None: the defaults."""
        return None

    def write_calibration(self, directory: Path) -> dict[str, Path]:
        """Put the calibration files in force into `directory` (a run's record of them); name -> path.

        The sim writes the files of its simulated sensors; hardware copies the rig's files. The rig
        loads the conversions from these copies, so a run carries the calibration it was converted with.
        """
        return {}

    def diagnostics(self) -> dict[str, Any]:
        """Problems the backend noticed during the run (e.g. MuJoCo warnings); empty when clean."""
        return {}
