"""The stereo rig's calibration: both cameras' intrinsics, the left-to-right transform, and where the
pair sits in the hand frame; one JSON file that every run (sim or hardware) loads.

Conventions are OpenCV's: pixel coordinates with the origin at the top-left pixel centre, camera
frame x right, y down, z forward; R, t map a point from the left camera frame to the right one
(x_r = R x_l + t, as cv2.stereoCalibrate returns them); lengths in metres. `hand_from_left` is the
4x4 pose of the left camera in the hand (palm) frame: p_hand = hand_from_left @ [p_left, 1].
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from twin.interface.errors import ConfigError

FORMAT = "barrett-twin stereo calibration v1"


class StereoCalibrationError(ConfigError):
    """A calibration file that is missing or malformed; the message names the file and the key."""


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole + distortion of one camera at `image_size` (width, height) pixels."""

    matrix: NDArray[np.float64]
    """(3, 3) K."""
    distortion: NDArray[np.float64]
    """OpenCV distortion coefficients (k1, k2, p1, p2[, k3...])."""
    image_size: tuple[int, int]

    def scaled(self, width: int, height: int) -> CameraIntrinsics:
        """The same camera read out at another resolution (e.g. 640x480 processed at 320x240)."""
        sx, sy = width / self.image_size[0], height / self.image_size[1]
        k = self.matrix.copy()
        k[0, 0] *= sx
        k[0, 2] = (k[0, 2] + 0.5) * sx - 0.5
        k[1, 1] *= sy
        k[1, 2] = (k[1, 2] + 0.5) * sy - 0.5
        return CameraIntrinsics(k, self.distortion.copy(), (width, height))


@dataclass(frozen=True)
class StereoCalibration:
    """Both cameras, the pair's geometry, and the pair in the hand frame."""

    left: CameraIntrinsics
    right: CameraIntrinsics
    rotation: NDArray[np.float64]
    """(3, 3) R: left camera frame -> right camera frame."""
    translation_m: NDArray[np.float64]
    """(3,) t: left camera frame -> right camera frame (m)."""
    hand_from_left: NDArray[np.float64]
    """(4, 4) pose of the left camera in the hand frame."""
    source: str = ""

    @property
    def baseline_m(self) -> float:
        """Distance between the optical centres."""
        return float(np.linalg.norm(self.translation_m))

    def scaled(self, width: int, height: int) -> StereoCalibration:
        """Both cameras at another resolution; the geometry is unchanged."""
        return StereoCalibration(
            self.left.scaled(width, height),
            self.right.scaled(width, height),
            self.rotation,
            self.translation_m,
            self.hand_from_left,
            self.source,
        )

    def to_json(self) -> dict:
        """Plain JSON (lists), the file's content."""

        def cam(c: CameraIntrinsics) -> dict:
            return {
                "matrix": c.matrix.tolist(),
                "distortion": c.distortion.tolist(),
                "image_size": list(c.image_size),
            }

        return {
            "format": FORMAT,
            "left": cam(self.left),
            "right": cam(self.right),
            "rotation": self.rotation.tolist(),
            "translation_m": self.translation_m.tolist(),
            "hand_from_left": self.hand_from_left.tolist(),
        }

    def save(self, path: Path | str) -> Path:
        """Write the JSON file (atomically: a crash never leaves half a calibration)."""
        path = Path(path)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)  # O_EXCL
        try:
            with open(fd, "w", encoding="utf-8") as f:
                f.write(json.dumps(self.to_json(), indent=2) + "\n")
            os.replace(tmp, path)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise
        return path

    @classmethod
    def load(cls, path: Path | str) -> StereoCalibration:
        """Read and check a calibration file; StereoCalibrationError names the file and what is wrong."""
        path = Path(path)
        try:
            data = json.loads(path.read_text())
        except FileNotFoundError:
            raise StereoCalibrationError(f"{path}: no such stereo calibration file") from None
        except (OSError, UnicodeDecodeError) as exc:
            raise StereoCalibrationError(f"{path}: cannot read ({exc})") from None
        except json.JSONDecodeError as exc:
            raise StereoCalibrationError(f"{path}:{exc.lineno}: not valid JSON ({exc.msg})") from None
        except RecursionError:
            raise StereoCalibrationError(f"{path}: not valid JSON (nested too deeply)") from None
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise StereoCalibrationError(f"{path}: not a stereo calibration (format must be {FORMAT!r})")

        def array(key: str, shape: tuple[int, ...], where: dict | None = None, name: str = "") -> NDArray:
            table = data if where is None else where
            label = f"{name}.{key}" if name else key
            if key not in table:
                raise StereoCalibrationError(f"{path}: missing {label}")
            try:
                value = np.asarray(table[key], dtype=float)
            except (TypeError, ValueError):
                raise StereoCalibrationError(f"{path}: {label} is not numeric") from None
            if (shape and value.shape != shape) or not np.all(np.isfinite(value)):
                raise StereoCalibrationError(
                    f"{path}: {label} must be finite with shape {shape}, got {value.shape}"
                )
            return value

        def cam(name: str) -> CameraIntrinsics:
            if not isinstance(data.get(name), dict):
                raise StereoCalibrationError(f"{path}: missing {name}")
            table = data[name]
            size = array("image_size", (2,), table, name)
            distortion = array("distortion", (), table, name).ravel()
            if distortion.size not in (4, 5, 8, 12, 14):
                raise StereoCalibrationError(f"{path}: {name}.distortion has {distortion.size} coefficients")
            return CameraIntrinsics(
                array("matrix", (3, 3), table, name), distortion, (int(size[0]), int(size[1]))
            )

        rotation = array("rotation", (3, 3))
        if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-6):
            raise StereoCalibrationError(f"{path}: rotation is not a rotation matrix")
        return cls(
            cam("left"),
            cam("right"),
            rotation,
            array("translation_m", (3,)),
            array("hand_from_left", (4, 4)),
            str(path),
        )
