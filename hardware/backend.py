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
from twin.hardware.rig_config import RigConfig

from twin.interface.backend import Backend, Clock, stereo_calibration_key
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
        pairs = self.config.stereo_pairs
        for k, pair in enumerate(pairs):  # a missing or bad file fails here, before anything is opened
            stereo_file = self.config.calibration.get(stereo_calibration_key(k, pair.name))
            if stereo_file is not None:
                from twin.vision.calibration import StereoCalibration  # only a rig with cameras needs it

                StereoCalibration.load(stereo_file)
        self.stereo_pairs: list[StereoCapture] = []
        """Every pair of the rig, `stereo` first (rig.toml's [stereo], or its [[stereo]] in order)."""
        if pairs:  # OpenCV is imported only by a rig with cameras
            from twin.hardware.cameras.driver import StereoCapture

            self.stereo_pairs = [StereoCapture(pair.capture, self._clock) for pair in pairs]
        self.stereo: StereoCapture | None = self.stereo_pairs[0] if self.stereo_pairs else None
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

    def devices(self) -> list[Any]:
        """The devices configured, hand first, every stereo pair last."""
        return [d for d in (self.hand, self.tactile) if d is not None] + list(self.stereo_pairs)

    def named_stereo_pairs(self) -> list[tuple[str, StereoCapture]]:
        """Every pair with its rig.toml name, `stereo` first."""
        names = [pair.name for pair in self.config.stereo_pairs]
        return list(zip(names, self.stereo_pairs, strict=True))

    def object_box(self, rectifier: object, *, pair: int = 0) -> tuple[int, int, int, int] | None:
        """Pair `pair`'s bbox in rig.toml (None: `--bbox` must give the first pair's)."""
        pairs = self.config.stereo_pairs
        return pairs[pair].bbox if pair < len(pairs) else None

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
            # each pair's name, in order (as the sim records its placements): what names its stream and
            # its calibration file, so a reader finds both (twin.vision.strain_record)
            meta["stereo_placements"] = [name for name, _ in self.named_stereo_pairs()]
        for name, capture in self.named_stereo_pairs()[1:]:
            meta[f"stereo_driver_{name}"] = capture.metadata()
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
        for name, capture in self.named_stereo_pairs()[1:]:
            out[f"stereo_capture_{name}"] = capture.diagnostics()
        return out
