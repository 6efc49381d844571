"""`twin emulate rig`: every emulated device of the rig on one twin, with the rig.toml to reach them.

The hand (BH8-262 on a serial line), the tactile pads (the PPS interface streaming frames) and,
with `cameras=True`, the stereo pair (two MJPEG-over-HTTP streams, hardware/cameras/emulator.py) are
served from the same real-time twin, so the pads feel what the emulated hand squeezes and the
cameras see it; the pads' calibration files are the twin's simulated ones, written as a manufacturer
would ship them, and the cameras' is the twin's ground-truth stereo calibration.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from twin.hardware.bh262.emulator import HandEmulator, make_hand_emulator
from twin.hardware.bh262.firmware import RealTimeTwin
from twin.hardware.pps.emulator import FaultPlan as TactileFaultPlan
from twin.hardware.pps.emulator import TactileEmulator
from twin.hardware.rig_config import rig_toml

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
    ) -> None:
        """`obj`: a library name, any foam (`twin.api.foam(...)`) or None (make_hand_emulator).
        `cameras`: also render and stream the stereo pair (it costs ~20-30 ms of CPU per frame).

        Both fault specs are checked first (ConfigError, one line), before the twin is built."""
        tactile_plan = TactileFaultPlan.parse(tactile_faults, option="--tactile-faults")
        self.hand: HandEmulator = make_hand_emulator(
            obj, baud=baud, faults=faults, seed=seed, on_event=on_event, stereo=cameras
        )
        self.tactile = TactileEmulator(
            twin_tactile_source(self.hand.twin),
            rate_hz=self.hand.twin.backend.tactile.config.rate_hz,
            faults=tactile_plan,
            on_event=on_event,
        )
        self.cameras: CameraEmulator | None = None
        if cameras:  # OpenCV (the frames' JPEG) is imported only by a rig with cameras
            from twin.hardware.cameras.emulator import CameraEmulator

            self.cameras = CameraEmulator(self.hand.twin, seed=seed, on_event=on_event)
        self.camera_addresses: tuple[str, str] | None = None
        """The left and right stream URLs once served (None without cameras)."""
        self.baud = baud
        self._tmp: tempfile.TemporaryDirectory | None = None

    def serve(self, where: str = "pty") -> tuple[str, str]:
        """Serve the hand and pads on ptys (`pty`) or TCP (`tcp:PORT`: the hand on PORT, the pads on
        PORT + 1; `tcp:0` picks free ports); returns their two addresses. The cameras, if any, are
        served over HTTP on PORT + 2 (a free port with `pty` or `tcp:0`): see `camera_addresses`."""
        port = 0
        if where == "pty":
            hand = self.hand.serve_pty()
        else:
            port = int(where.split(":", 1)[1])
            hand = self.hand.serve_tcp(port)
            port = 0 if port == 0 else port + 1
        self.hand.twin.start()  # the pads scan the twin from their first frame on
        tactile = self.tactile.serve_pty() if where == "pty" else self.tactile.serve_tcp(port)
        if self.cameras is not None:
            self.camera_addresses = self.cameras.serve_http(0 if port == 0 else port + 1)
        return hand, tactile

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
        stereo_calibration, stereo_bbox = None, None
        if self.cameras is not None and self.camera_addresses is not None:
            written = self.cameras.write_calibration(path.parent / "calibration")
            stereo_calibration = str(written.relative_to(path.parent))
            stereo_bbox = self._object_box(written)
        text = rig_toml(
            self.hand.address,
            baud=self.baud,
            tactile_url=self.tactile.address,
            tactile_table=str(table),
            stereo=self.camera_addresses,
            stereo_rate_hz=self.cameras.rate_hz if self.cameras is not None else 30.0,
            stereo_calibration=stereo_calibration,
            stereo_bbox=stereo_bbox,
            emulated=True,
        )
        path.write_text(text)
        return path

    def _object_box(self, calibration_file: Path) -> tuple[int, int, int, int] | None:
        """The twin's foam box on the first frame: what a user would draw for the run (rig.toml bbox)."""
        from twin.vision.calibration import StereoCalibration
        from twin.vision.reconstruct import Rectifier

        twin = self.hand.twin
        with twin.lock:
            return twin.backend.object_box(Rectifier(StereoCalibration.load(calibration_file)))

    def failed(self) -> str | None:
        """Why the hand or the pads no longer serve (one line), or None while both do."""
        hand, tactile = self.hand.failed(), self.tactile.failed()
        return f"hand: {hand}" if hand else (f"tactile: {tactile}" if tactile else None)

    def close(self) -> None:
        """Stop every emulator and the twin."""
        if self.cameras is not None:
            self.cameras.close()
        self.tactile.close()
        self.hand.close()
        if self._tmp is not None:
            self._tmp.cleanup()

    def __enter__(self) -> RigEmulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
