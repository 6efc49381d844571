"""The hardware backend: the real BH8, the tactile pads and the stereo cameras on wall time.

Drivers live beside this module and never import the simulator. A device the rig does not
configure fails to connect with DeviceNotConfiguredError, before any run directory is written.
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from twin.hardware.bh262.hand import BH8SerialHand
from twin.hardware.pps.driver import PPSTactile
from twin.hardware.rig_config import STEREO_CALIBRATION, RigConfig

from twin.interface.backend import Backend, Clock
from twin.interface.devices import Hand, HandCommand, HandReading
from twin.interface.errors import DeviceError, DeviceNotConfiguredError
from twin.interface.hand_spec import HandConfig, hand_device_spec
from twin.interface.specs import DeviceSpec
from twin.safety import SafetyLimits

if TYPE_CHECKING:
    from twin.hardware.cameras.driver import StereoCapture


class WallClock(Clock):
    """Wall time since the clock was created; advancing it sleeps."""

    def __init__(self) -> None:
        self._t0 = time.monotonic()

    def start(self) -> None:
        """Time zero is now."""
        self._t0 = time.monotonic()

    def now(self) -> float:
        """Seconds since the run started."""
        return time.monotonic() - self._t0

    def advance_to(self, t_s: float) -> None:
        """Sleep until t_s (returns at once if it has passed)."""
        delay = t_s - self.now()
        if delay > 0:
            time.sleep(delay)


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
            "hardware backend: no BH8 hand is configured on this rig: "
            "pass --hand PORT or a --rig file with a [hand] port (try `twin emulate rig`)"
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
    """Real devices (or their emulators) on wall time."""

    name = "hardware"

    def __init__(self, config: RigConfig | None = None) -> None:
        self.config = config or RigConfig()
        self._clock = WallClock()
        tactile = self.config.tactile_port
        self.tactile = (
            None
            if tactile is None
            else PPSTactile(
                self.config.tactile, tactile.url, self._clock, baud=tactile.baud, timeout_s=tactile.timeout_s
            )
        )
        stereo_file = self.config.calibration.get(STEREO_CALIBRATION)
        if stereo_file is not None:  # a missing or bad file fails here, before anything is opened
            from twin.vision.calibration import StereoCalibration  # only a rig with cameras needs it

            StereoCalibration.load(stereo_file)
        self.stereo: StereoCapture | None = None
        if self.config.stereo is not None:  # OpenCV is imported only by a rig with cameras
            from twin.hardware.cameras.driver import StereoCapture

            self.stereo = StereoCapture(self.config.stereo, self._clock)
        port = self.config.hand_port
        if port is None:
            self.hand: Hand = UnconfiguredHand(self.config.hand)
        else:
            self.hand = BH8SerialHand(
                self.config.hand,
                port.port,
                self._clock,
                initialize=port.initialize,
                watchdog_cycles=port.watchdog_cycles,
                lcvc=port.lcvc,
            )

    @property
    def clock(self) -> Clock:
        """Wall clock."""
        return self._clock

    def object_box(self, rectifier: object, *, pair: int = 0) -> tuple[int, int, int, int] | None:
        """rig.toml's [stereo].bbox (None: `--bbox` must give it); the rig has one pair."""
        return self.config.stereo_bbox

    def safety_limits(self) -> SafetyLimits:
        """The limits of the rig file (the datasheet's when it names none)."""
        return self.config.limits

    def write_calibration(self, directory: Path) -> dict[str, Path]:
        """Copies of the rig's calibration files, so the run carries what it was converted with."""
        directory.mkdir(parents=True, exist_ok=True)
        out = {}
        for name, source in self.config.calibration.items():
            out[name] = directory / f"{name}{source.suffix}"
            shutil.copyfile(source, out[name])
        return out

    def metadata(self) -> dict[str, Any]:
        """Ports and settings of this rig."""
        meta: dict[str, Any] = {"backend": self.name, "rig": self.config.to_json()}
        if isinstance(self.hand, BH8SerialHand):
            meta["hand_driver"] = self.hand.metadata()
        if self.tactile is not None:
            meta["tactile_driver"] = self.tactile.metadata()
        if self.stereo is not None:
            meta["stereo_driver"] = self.stereo.metadata()
        return meta

    def diagnostics(self) -> dict[str, Any]:
        """Cycles the hand driver had to recover, the tactile link's and the cameras' counters."""
        out: dict[str, Any] = {}
        if isinstance(self.hand, BH8SerialHand):
            out["hand_recoveries"] = list(self.hand.recoveries)
        if self.tactile is not None:
            out["tactile_link"] = self.tactile.diagnostics()
        if self.stereo is not None:
            out["stereo_capture"] = self.stereo.diagnostics()
        return out
