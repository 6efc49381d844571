"""Calibrate the stereo pair and place it in the hand frame (paper §4.1); writes the StereoCalibration
JSON file that runs load (`twin run compress --cameras --stereo-calibration FILE`).

Two steps, both from images only (twin.vision.hand_eye):
1. the stereo pair: views of an OpenCV chessboard (8 x 5 inner corners, 15 mm squares, 9 x 6 squares
   with a black square at the first corner) in several poses in front of both cameras ->
   cv2.calibrateCamera per camera, cv2.stereoCalibrate;
2. the hand: one view of the tiny 4x3 palm board (six black 14 mm squares centred on the palm face,
   columns along the palm's x, row 0 toward F3; twin.sim.checkerboard) -> black-square centres,
   mid-point triangulation, rigid transform -> hand_from_left.

Views are taken at the native 640x480 (the chessboard corners and blob centroids are twice as
finely sampled as at 320x240); the file describes the processed 320x240 images runs use
(CameraIntrinsics.scaled: the same camera read out at half the resolution).

Sim: the twin renders the views (hand without foam, fingers spread aside, the chessboard a mocap
body) with the cameras' noise, and the result is compared with the ground truth it knows.
Hardware: `views_dir` holds image pairs taken with the Flea2 pair: chessboard pairs
left_*.png / right_*.png (matched by the part after the prefix) and the palm board pair
palm_left.png / palm_right.png, at any one resolution of the Flea2 pair (the file is scaled to
320x240). There is no live capture path here: this procedure does not drive the hardware stereo
driver (hardware/cameras) — someone has to move the chessboard between captures anyway — so the pairs
are grabbed first (with that driver or any camera tool) and passed as files. The physical boards must
be made to the dimensions above, the palm board centred on the palm face as described.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from twin.interface.errors import ConfigError
from twin.interface.stereo_spec import StereoConfig
from twin.vision.calibration import StereoCalibration
from twin.vision.hand_eye import (
    HandEyeResult,
    StereoFit,
    hand_from_left,
    pose_error,
    stereo_calibrate,
    with_hand_from_left,
)

DEFAULT_VIEWS = 30
PALM_LEFT, PALM_RIGHT = "palm_left.png", "palm_right.png"

ImagePair = tuple[NDArray[np.uint8], NDArray[np.uint8]]


@dataclass(frozen=True)
class CalibrationOutcome:
    """The calibration at the processed size, the fits behind it, and (sim) its errors against truth."""

    calibration: StereoCalibration
    stereo: StereoFit
    hand: HandEyeResult
    truth: StereoCalibration | None = None

    def errors(self) -> dict[str, float]:
        """Recovered vs truth (sim only): hand_from_left, R/t left->right, focal lengths and centres."""
        if self.truth is None:
            return {}
        c, g = self.calibration, self.truth
        t_err, r_err = pose_error(c.hand_from_left, g.hand_from_left)
        lr = np.eye(4), np.eye(4)
        lr[0][:3, :3], lr[0][:3, 3] = c.rotation, c.translation_m
        lr[1][:3, :3], lr[1][:3, 3] = g.rotation, g.translation_m
        st_err, sr_err = pose_error(*lr)
        intr = [
            (
                np.abs(np.diag(a.matrix)[:2] - np.diag(b.matrix)[:2]).max(),
                np.abs(a.matrix[:2, 2] - b.matrix[:2, 2]).max(),
            )
            for a, b in ((c.left, g.left), (c.right, g.right))
        ]
        return {
            "hand_translation_mm": t_err * 1e3,
            "hand_rotation_deg": r_err,
            "stereo_translation_mm": st_err * 1e3,
            "stereo_rotation_deg": sr_err,
            "baseline_error_mm": (c.baseline_m - g.baseline_m) * 1e3,
            "focal_error_px": float(max(f for f, _ in intr)),
            "centre_error_px": float(max(p for _, p in intr)),
        }

    def summary(self) -> list[str]:
        """Human-readable lines (what `twin calibrate cameras` prints)."""
        s = self.stereo
        lines = [
            f"stereo: {s.views_used}/{s.views_given} chessboard pairs used; reprojection RMS "
            f"left {s.rms_left_px:.3f} px, right {s.rms_right_px:.3f} px, stereo {s.rms_stereo_px:.3f} px "
            f"(at {s.calibration.left.image_size[0]}x{s.calibration.left.image_size[1]})",
            f"hand: palm board fit RMS {self.hand.fit_rms_m * 1e3:.3f} mm, "
            f"ray gaps up to {self.hand.ray_gap_m.max() * 1e3:.3f} mm",
        ]
        e = self.errors()
        if e:
            lines += [
                f"vs truth: hand_from_left {e['hand_translation_mm']:.3f} mm, "
                f"{e['hand_rotation_deg']:.3f} deg",
                f"vs truth: left->right {e['stereo_translation_mm']:.3f} mm, "
                f"{e['stereo_rotation_deg']:.3f} deg (baseline {e['baseline_error_mm']:+.3f} mm)",
                f"vs truth at {self.calibration.left.image_size[0]}x{self.calibration.left.image_size[1]}: "
                f"focal lengths within {e['focal_error_px']:.3f} px, principal points within "
                f"{e['centre_error_px']:.3f} px",
            ]
        return lines


def calibrate_from_images(
    chessboard_pairs: list[ImagePair],
    palm_pair: ImagePair,
    board_points_hand_m: NDArray[np.float64],
    *,
    processed_size: tuple[int, int] | None = None,
    source: str = "",
) -> tuple[StereoCalibration, StereoFit, HandEyeResult]:
    """Stereo-calibrate on the chessboard pairs, place the pair in the hand from the palm pair, and
    give the calibration at `processed_size` (width, height; default StereoConfig's 320x240)."""
    from twin.sim.checkerboard import CHESSBOARD_PATTERN, chessboard_object_points

    fit = stereo_calibrate(chessboard_pairs, chessboard_object_points(), CHESSBOARD_PATTERN, source=source)
    hand = hand_from_left(fit.calibration, palm_pair[0], palm_pair[1], board_points_hand_m)
    width, height = processed_size or (StereoConfig().width, StereoConfig().height)
    calibration = with_hand_from_left(fit.calibration, hand.hand_from_left).scaled(width, height)
    return calibration, fit, hand


def render_sim_views(
    views: int = DEFAULT_VIEWS, seed: int = 0, config: StereoConfig | None = None
) -> tuple[list[ImagePair], ImagePair, StereoCalibration]:
    """The twin's chessboard pairs and palm-board pair at the native size (with the cameras' noise),
    and the ground-truth calibration at the processed size."""
    import mujoco

    from twin.sim.cameras import SimStereo, ground_truth_calibration
    from twin.sim.checkerboard import calibration_scene, open_hand, place_chessboard, random_chessboard_poses
    from twin.sim.world import SimWorld

    config = config or StereoConfig()
    native = StereoConfig(
        width=config.native_width,
        height=config.native_height,
        native_width=config.native_width,
        native_height=config.native_height,
        noise_std=config.noise_std,
        fovy_deg=config.fovy_deg,
    )
    world = SimWorld(calibration_scene())
    model, data = world.model, world.data
    open_hand(model, data)
    rng = np.random.default_rng(seed)
    camera = SimStereo(world, native, np.random.default_rng([seed, 2]))
    pairs = []
    with camera:
        for pos, rotation in random_chessboard_poses(views, rng):
            place_chessboard(model, data, pos, rotation)
            frame = camera.read()
            pairs.append((frame.left, frame.right))
        place_chessboard(model, data)  # parked out of view
        frame = camera.read()
        palm = (frame.left, frame.right)
    mujoco.mj_kinematics(model, data)
    return pairs, palm, ground_truth_calibration(model, data, config)


def calibrate_sim(views: int = DEFAULT_VIEWS, seed: int = 0) -> CalibrationOutcome:
    """The whole procedure on the twin, with the errors against its ground truth."""
    from twin.sim.checkerboard import palm_board_centres

    pairs, palm, truth = render_sim_views(views, seed)
    calibration, fit, hand = calibrate_from_images(
        pairs, palm, palm_board_centres(), source=f"twin calibrate cameras (sim, seed {seed})"
    )
    return CalibrationOutcome(calibration, fit, hand, truth)


def _read(path: Path) -> NDArray[np.uint8]:
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise ConfigError(f"{path}: not a readable image")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def load_views(directory: Path) -> tuple[list[ImagePair], ImagePair]:
    """Chessboard pairs left_X.png / right_X.png and the palm pair palm_left.png / palm_right.png."""
    directory = Path(directory)
    if not directory.is_dir():
        raise ConfigError(f"--views {directory}: no such directory")
    lefts = {p.name[len("left_") :]: p for p in directory.glob("left_*.png")}
    rights = {p.name[len("right_") :]: p for p in directory.glob("right_*.png")}
    if set(lefts) != set(rights):
        odd = sorted(set(lefts) ^ set(rights))
        raise ConfigError(f"--views {directory}: unpaired chessboard images ({', '.join(odd[:3])})")
    if not lefts:
        raise ConfigError(f"--views {directory}: no left_*.png / right_*.png chessboard pairs")
    for name in (PALM_LEFT, PALM_RIGHT):
        if not (directory / name).is_file():
            raise ConfigError(f"--views {directory}: missing the palm board image {name}")
    pairs = [(_read(lefts[k]), _read(rights[k])) for k in sorted(lefts)]
    return pairs, (_read(directory / PALM_LEFT), _read(directory / PALM_RIGHT))


def calibrate_views(directory: Path) -> CalibrationOutcome:
    """The procedure on image pairs from disk (hardware, or any saved sim views)."""
    from twin.sim.checkerboard import palm_board_centres

    pairs, palm = load_views(directory)
    calibration, fit, hand = calibrate_from_images(
        pairs, palm, palm_board_centres(), source=f"twin calibrate cameras --views {directory}"
    )
    return CalibrationOutcome(calibration, fit, hand)


def save_views(directory: Path, pairs: list[ImagePair], palm: ImagePair) -> None:
    """Write views in load_views' layout (so a sim set can be re-run like a hardware one)."""
    directory.mkdir(parents=True, exist_ok=True)
    for k, (left, right) in enumerate(pairs):
        cv2.imwrite(str(directory / f"left_{k:02d}.png"), cv2.cvtColor(left, cv2.COLOR_RGB2BGR))
        cv2.imwrite(str(directory / f"right_{k:02d}.png"), cv2.cvtColor(right, cv2.COLOR_RGB2BGR))
    cv2.imwrite(str(directory / PALM_LEFT), cv2.cvtColor(palm[0], cv2.COLOR_RGB2BGR))
    cv2.imwrite(str(directory / PALM_RIGHT), cv2.cvtColor(palm[1], cv2.COLOR_RGB2BGR))
