"""`twin emulate rig`: every emulated device of the rig on one twin, with the rig.toml to reach them.

The hand (BH8-262 on a serial line), the tactile pads (the PPS interface streaming frames) and,
with `cameras=True`, the stereo pair or pairs (two MJPEG-over-HTTP streams each,
hardware/cameras/emulator.py) are
served from the same real-time twin, so the pads feel what the emulated hand squeezes and the
cameras see it; the pads' calibration files are the twin's simulated ones, written as a manufacturer
would ship them, and the cameras' is the twin's ground-truth stereo calibration.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from twin.hardware.bh262.emulator import HandEmulator, make_hand_emulator
from twin.hardware.bh262.firmware import RealTimeTwin
from twin.hardware.pps.emulator import FaultPlan as TactileFaultPlan
from twin.hardware.pps.emulator import TactileEmulator
from twin.hardware.rig_config import StereoPairFile, rig_toml

from twin.interface.errors import ConfigError

if TYPE_CHECKING:
    from twin.hardware.cameras.emulator import CameraEmulator

    from twin.sim.foam import FoamParams


def twin_tactile_source(twin: RealTimeTwin) -> Callable[[], np.ndarray]:
    """A tactile emulator source that scans the twin's pads (under the twin's lock)."""
    tactile = twin.backend.tactile
    if tactile is None:
        raise ValueError("the twin has no tactile pads")

    def scan() -> np.ndarray:
        with twin.lock:
            return tactile.read().counts

    return scan


class RigEmulator:
    """The hand, tactile and (optionally) camera emulators on one twin."""

    def __init__(
        self,
        obj: str | FoamParams | None = "block",
        *,
        baud: int = 9600,
        faults: str | None = None,
        tactile_faults: str | None = None,
        seed: int = 0,
        on_event: Callable[[str], None] | None = None,
        cameras: bool = False,
        camera_placements: str | Sequence[str] | None = None,
        camera_rate_hz: float | None = None,
    ) -> None:
        """`obj`: a library name, any foam (`twin.api.foam(...)`) or None (make_hand_emulator).
        `cameras`: also render and stream the stereo pair (it costs ~20-30 ms of CPU per frame), one pair
        at each of `camera_placements` (twin.sim.cameras PLACEMENTS, e.g. `lateral,opposite`; None: the
        default pair alone). Each pair costs its own render process. `camera_rate_hz`: the cameras' frame
        rate (None: the Flea2's 30 fps), written to rig.toml so the run samples them at it.

        Both fault specs are checked first (ConfigError, one line), before the twin is built."""
        tactile_plan = TactileFaultPlan.parse(tactile_faults, option="--tactile-faults")
        if camera_placements is not None and not cameras:
            raise ConfigError("camera placements need cameras")
        self.hand: HandEmulator = make_hand_emulator(
            obj,
            baud=baud,
            faults=faults,
            seed=seed,
            on_event=on_event,
            stereo=cameras,
            camera_placements=camera_placements,
        )
        self.tactile = TactileEmulator(
            twin_tactile_source(self.hand.twin),
            rate_hz=self.hand.twin.backend.tactile.config.rate_hz,
            faults=tactile_plan,
            on_event=on_event,
        )
        self.camera_pairs: list[CameraEmulator] = []
        """One emulator per stereo pair of the twin, in its order."""
        if cameras:  # OpenCV (the frames' JPEG) is imported only by a rig with cameras
            from twin.hardware.cameras.emulator import CameraEmulator

            self.camera_pairs = [
                CameraEmulator(self.hand.twin, pair=k, rate_hz=camera_rate_hz, seed=seed, on_event=on_event)
                for k in range(len(self.hand.twin.backend.stereo_pairs))
            ]
        self.cameras: CameraEmulator | None = self.camera_pairs[0] if self.camera_pairs else None
        """The first pair's emulator."""
        self.camera_pair_addresses: list[tuple[str, str]] = []
        """Each pair's left and right stream URLs once served."""
        self.baud = baud
        self._tmp: tempfile.TemporaryDirectory | None = None

    def serve(self, where: str = "pty") -> tuple[str, str]:
        """Serve the hand and pads on ptys (`pty`) or TCP (`tcp:PORT`: the hand on PORT, the pads on
        PORT + 1; `tcp:0` picks free ports); returns their two addresses. The cameras, if any, are
        served over HTTP on PORT + 2, a second pair on PORT + 3 ... (free ports with `pty` or `tcp:0`):
        see `camera_addresses`."""
        port = 0
        if where == "pty":
            hand = self.hand.serve_pty()
        else:
            port = int(where.split(":", 1)[1])
            hand = self.hand.serve_tcp(port)
            port = 0 if port == 0 else port + 1
        self.hand.twin.start()  # the pads scan the twin from their first frame on
        tactile = self.tactile.serve_pty() if where == "pty" else self.tactile.serve_tcp(port)
        self.camera_pair_addresses = [
            camera.serve_http(0 if port == 0 else port + 1 + k) for k, camera in enumerate(self.camera_pairs)
        ]
        return hand, tactile

    @property
    def camera_addresses(self) -> tuple[str, str] | None:
        """The first pair's left and right stream URLs once served (None without cameras)."""
        return self.camera_pair_addresses[0] if self.camera_pair_addresses else None

    def write_rig_file(self, path: Path | str | None) -> Path:
        """The twin's tactile (and stereo) calibration beside a rig.toml that names every port; returns
        the rig.toml."""
        if path is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="twin-rig-")
            path = Path(self._tmp.name) / "rig.toml"
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        files = self.hand.twin.backend.tactile.sensor.write_files(path.parent / "calibration")
        table = files["tactile_table"].relative_to(path.parent)
        pairs = []
        served = zip(self.camera_pairs, self.camera_pair_addresses, strict=False)
        for k, (camera, sources) in enumerate(served):
            written = camera.write_calibration(path.parent / "calibration")
            name = camera.name if len(self.camera_pairs) > 1 else None  # one pair: [stereo], as ever
            relative = str(written.relative_to(path.parent))
            pairs.append(StereoPairFile(name, sources, relative, self._object_box(written, k)))
        text = rig_toml(
            self.hand.address,
            baud=self.baud,
            tactile_url=self.tactile.address,
            tactile_table=str(table),
            stereo=pairs[0].sources if len(pairs) == 1 else None,
            stereo_rate_hz=self.cameras.rate_hz if self.cameras is not None else 30.0,
            stereo_calibration=pairs[0].calibration if len(pairs) == 1 else None,
            stereo_bbox=pairs[0].bbox if len(pairs) == 1 else None,
            more_stereo=pairs if len(pairs) > 1 else (),
            emulated=True,
        )
        path.write_text(text)
        return path

    def _object_box(self, calibration_file: Path, pair: int = 0) -> tuple[int, int, int, int] | None:
        """The twin's foam box on pair `pair`'s first frame: what a user would draw for the run (rig.toml
        bbox)."""
        from twin.vision.calibration import StereoCalibration
        from twin.vision.reconstruct import Rectifier

        twin = self.hand.twin
        with twin.lock:
            return twin.backend.object_box(Rectifier(StereoCalibration.load(calibration_file)), pair=pair)

    def failed(self) -> str | None:
        """Why the hand or the pads no longer serve (one line), or None while both do."""
        hand, tactile = self.hand.failed(), self.tactile.failed()
        return f"hand: {hand}" if hand else (f"tactile: {tactile}" if tactile else None)

    def close(self) -> None:
        """Stop every emulator and the twin."""
        for camera in self.camera_pairs:
            camera.close()
        self.tactile.close()
        self.hand.close()
        if self._tmp is not None:
            self._tmp.cleanup()

    def __enter__(self) -> RigEmulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
