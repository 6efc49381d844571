"""Camera-to-hand and stereo calibration (paper §4.1) on real MuJoCo renders of the twin's targets:
blob finding and sorting, mid-point triangulation, the acceptance against the twin's ground truth,
one-line errors, and `twin calibrate cameras` end to end."""

import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from twin.experiments.calibrate_cameras import (
    CalibrationOutcome,
    calibrate_from_images,
    render_sim_views,
    save_views,
)

from twin.sim.cameras import LEFT_CAMERA, PLACEMENTS, RIGHT_CAMERA
from twin.sim.checkerboard import (
    CHESSBOARD_PATTERN,
    OPEN_HAND,
    calibration_scene,
    chessboard_object_points,
    open_hand,
    palm_board_centres,
)
from twin.vision.calibration import CameraIntrinsics, StereoCalibration
from twin.vision.hand_eye import (
    PALM_LAYOUT_COLS_ROWS,
    CalibrationImageError,
    dark_square_blobs,
    find_chessboard,
    hand_from_left,
    midpoint_of_rays,
    midpoint_triangulate,
    palm_board_centres_px,
    pose_error,
    rigid_transform,
    sort_by_layout,
)

TWIN = [sys.executable, "-m", "twin.cli"]


@pytest.fixture(scope="module")
def views():
    """20 chessboard pairs and the palm pair at 640x480, and the truth at 320x240 (seed 0)."""
    return render_sim_views(20, seed=0)


def project(calibration: StereoCalibration, points_hand: np.ndarray, side: str) -> np.ndarray:
    """Pixels of hand-frame points in one camera of `calibration` (its size)."""
    pose = np.linalg.inv(calibration.hand_from_left)
    if side == "right":
        right_from_left = np.eye(4)
        right_from_left[:3, :3], right_from_left[:3, 3] = calibration.rotation, calibration.translation_m
        pose = right_from_left @ pose
    cam = calibration.left if side == "left" else calibration.right
    rvec, _ = cv2.Rodrigues(pose[:3, :3])
    uv, _ = cv2.projectPoints(points_hand, rvec, pose[:3, 3], cam.matrix, cam.distortion)
    return uv.reshape(-1, 2)


def test_palm_board_squares_are_found_and_sorted_in_both_views(views):
    _, (left, right), truth = views
    truth = truth.scaled(640, 480)
    for side, image in (("left", left), ("right", right)):
        assert len(dark_square_blobs(image)) == 6
        found = palm_board_centres_px(image, side)
        expected = project(truth, palm_board_centres(), side)
        # Sub-pixel: the perspective offset of an oblique square's centroid (~0.1 px) and noise remain.
        assert np.abs(found - expected).max() < 0.25


@pytest.mark.parametrize("angle_deg", [0.0, 37.0, 90.0, 180.0, 251.0])
def test_sorting_follows_the_layout_at_any_in_plane_rotation(angle_deg):
    rng = np.random.default_rng(int(angle_deg))
    grid = np.asarray(PALM_LAYOUT_COLS_ROWS, dtype=float)
    rot = Rotation.from_rotvec([0.0, 0.0, np.radians(angle_deg)]).as_matrix()[:2, :2]
    shear = np.array([[1.0, 0.15], [0.0, 0.85]])  # a board seen obliquely
    expected = grid @ (25.0 * rot @ shear).T + [300.0, 200.0] + rng.normal(0, 0.3, (6, 2))
    shuffled = expected[rng.permutation(6)]
    np.testing.assert_array_equal(sort_by_layout(shuffled), expected)
    # Six dark squares on a plain 3x2 grid are not the board.
    grid_3x2 = np.array([[c, r] for r in range(2) for c in range(3)], dtype=float)
    with pytest.raises(CalibrationImageError, match="not in the board's layout"):
        sort_by_layout(grid_3x2 @ (25.0 * rot).T)


def test_sorting_holds_on_a_rotated_render(views):
    _, (left, _), truth = views
    expected = project(truth.scaled(640, 480), palm_board_centres(), "left")
    turn = cv2.getRotationMatrix2D(tuple(expected.mean(axis=0)), 135.0, 1.0)
    rotated = cv2.warpAffine(left, turn, (640, 480), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    found = palm_board_centres_px(rotated)
    assert np.abs(found - (expected @ turn[:, :2].T + turn[:, 2])).max() < 0.4


def test_midpoint_of_skew_and_crossing_rays():
    # Skew rays: the x axis, and a line along y through (0, 0, 1): midpoint (0, 0, 0.5), 1 apart.
    point, gap = midpoint_of_rays(
        np.zeros(3), np.array([[2.0, 0, 0]]), np.array([0, 5.0, 1.0]), np.array([[0, 1.0, 0]])
    )
    np.testing.assert_allclose(point, [[0.0, 0.0, 0.5]], atol=1e-12)
    np.testing.assert_allclose(gap, [1.0])
    rng = np.random.default_rng(3)
    targets = rng.uniform(-1, 1, (10, 3))
    o_a, o_b = np.array([0.0, 0, -3]), np.array([1.0, 2, -3])
    points, gaps = midpoint_of_rays(o_a, targets - o_a, o_b, (targets - o_b) * 0.3)
    np.testing.assert_allclose(points, targets, atol=1e-12)
    assert gaps.max() < 1e-12
    with pytest.raises(ValueError, match="parallel"):
        midpoint_of_rays(o_a, np.array([[0, 0, 1.0]]), o_b, np.array([[0, 0, 2.0]]))


def test_midpoint_triangulation_through_distorted_cameras():
    k = np.array([[800.0, 0, 320], [0, 805.0, 240], [0, 0, 1]])
    cam = CameraIntrinsics(k, np.array([-0.2, 0.05, 0.001, -0.0005, 0.0]), (640, 480))
    rotation = Rotation.from_euler("y", -30, degrees=True).as_matrix()
    translation = np.array([-0.2, 0.0, 0.05])
    calibration = StereoCalibration(cam, cam, rotation, translation, np.eye(4))
    points = np.random.default_rng(0).uniform([-0.05, -0.05, 0.35], [0.05, 0.05, 0.45], (12, 3))
    left, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), k, cam.distortion)
    right, _ = cv2.projectPoints(points, cv2.Rodrigues(rotation)[0], translation, k, cam.distortion)
    found, gaps = midpoint_triangulate(calibration, left.reshape(-1, 2), right.reshape(-1, 2))
    np.testing.assert_allclose(found, points, atol=1e-6)
    assert gaps.max() < 1e-6


def test_rigid_transform_recovers_a_pose():
    rng = np.random.default_rng(1)
    pose = np.eye(4)
    pose[:3, :3] = Rotation.random(random_state=2).as_matrix()
    pose[:3, 3] = [0.1, -0.2, 0.4]
    source = rng.uniform(-0.05, 0.05, (6, 3))
    target = source @ pose[:3, :3].T + pose[:3, 3]
    np.testing.assert_allclose(rigid_transform(source, target), pose, atol=1e-12)


def test_chessboard_corners_come_in_one_order_whatever_the_view(views):
    pairs, _, _ = views
    left = pairs[0][0]
    corners = find_chessboard(left, CHESSBOARD_PATTERN)
    assert corners is not None and len(corners) == len(chessboard_object_points())
    upside_down = find_chessboard(left[::-1, ::-1].copy(), CHESSBOARD_PATTERN)
    np.testing.assert_allclose(upside_down, [639, 479] - corners, atol=0.05)


def test_calibration_on_the_twin_meets_the_acceptance(views):
    """Acceptance (§4.1): hand_from_left within 1 mm and 0.5 deg of the twin's truth."""
    pairs, palm, truth = views
    calibration, fit, hand = calibrate_from_images(pairs, palm, palm_board_centres())
    outcome = CalibrationOutcome(calibration, fit, hand, truth)
    e = outcome.errors()
    assert e["hand_translation_mm"] < 1.0 and e["hand_rotation_deg"] < 0.5
    # The stereo pair itself, at the processed 320x240 the file describes.
    assert calibration.left.image_size == calibration.right.image_size == (320, 240)
    assert e["stereo_translation_mm"] < 0.5 and e["stereo_rotation_deg"] < 0.1
    assert e["focal_error_px"] < 0.5 and e["centre_error_px"] < 0.5
    assert max(fit.rms_left_px, fit.rms_right_px, fit.rms_stereo_px) < 0.15
    assert fit.views_used == 20 and hand.fit_rms_m < 1e-4


def test_a_finger_over_a_square_is_a_one_line_error():
    model = calibration_scene(chessboard=False, placement=PLACEMENTS["top"])  # seen from above,
    data = mujoco.MjData(model)
    open_hand(model, data, {**OPEN_HAND, "f3_inner": 1.6})  # the thumb bends over the palm board
    with mujoco.Renderer(model, 480, 640) as renderer:
        renderer.update_scene(data, camera=LEFT_CAMERA)
        left = renderer.render()
        renderer.update_scene(data, camera=RIGHT_CAMERA)
        right = renderer.render()
    with pytest.raises(CalibrationImageError, match=r"^found 5 black squares in the left image, expected 6$"):
        palm_board_centres_px(left, "left")
    cam = CameraIntrinsics(np.diag([811.0, 811.0, 1.0]), np.zeros(5), (640, 480))
    with pytest.raises(CalibrationImageError, match="in the left image"):
        hand_from_left(StereoCalibration(cam, cam, np.eye(3), np.array([-0.2, 0, 0]), np.eye(4)), left, right,
                       palm_board_centres())  # fmt: skip


def test_a_cropped_view_is_a_one_line_error(views):
    _, (_, right), truth = views
    centres = project(truth.scaled(640, 480), palm_board_centres(), "right")
    cut = int(np.sort(centres[:, 0])[-1] - 5)  # through the right-most square
    with pytest.raises(
        CalibrationImageError, match=r"^found 5 black squares in the right image, expected 6$"
    ):
        palm_board_centres_px(np.ascontiguousarray(right[:, :cut]), "right")


def twin(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "MUJOCO_GL": "egl"}
    env.pop("DISPLAY", None)
    return subprocess.run([*TWIN, *args], capture_output=True, text=True, env=env, timeout=300)


@pytest.mark.slow
def test_cli_calibrates_on_the_twin_and_reports_errors(tmp_path: Path):
    out = tmp_path / "cal" / "stereo.json"
    bad = twin("calibrate", "cameras", "--out", str(out))
    assert bad.returncode == 2 and bad.stderr.strip().count("\n") == 0
    assert "no such directory" in bad.stderr and not out.exists()
    out.parent.mkdir()
    result = twin("calibrate", "cameras", "--out", str(out), "--seed", "1")
    assert result.returncode == 0, result.stderr
    assert "vs truth: hand_from_left" in result.stdout and "reprojection RMS" in result.stdout
    calibration = StereoCalibration.load(out)
    assert calibration.left.image_size == (320, 240)
    assert json.loads(out.read_text())["format"] == "barrett-twin stereo calibration v1"
    assert not list(out.parent.glob("*.tmp"))


def test_cli_calibrates_from_image_pairs_on_disk(views, tmp_path: Path):
    pairs, palm, truth = views
    save_views(tmp_path / "views", pairs[:10], palm)
    out = tmp_path / "from_views.json"
    result = twin("calibrate", "cameras", "--views", str(tmp_path / "views"), "--out", str(out))
    assert result.returncode == 0, result.stderr
    assert "vs truth" not in result.stdout  # images alone carry no truth
    t_err, r_err = pose_error(StereoCalibration.load(out).hand_from_left, truth.hand_from_left)
    assert t_err < 2e-3 and r_err < 0.5
    (tmp_path / "views" / "palm_right.png").unlink()
    missing = twin(
        "calibrate", "cameras", "--views", str(tmp_path / "views"), "--out", str(tmp_path / "x.json")
    )
    assert missing.returncode == 2 and "missing the palm board image palm_right.png" in missing.stderr
    assert "Traceback" not in missing.stderr and not (tmp_path / "x.json").exists()


@pytest.mark.slow
def test_the_procedure_calibrates_the_papers_lateral_view_too():
    """The same procedure (chessboard held up to the pair + palm board) on the twin with the cameras
    at the paper's lateral placement: the board squares seen obliquely are still found, and the
    result meets the §4.1 acceptance (hand within 1 mm and 0.5 deg) against the twin's truth."""
    from twin.interface.stereo_spec import StereoConfig
    from twin.sim.cameras import SimStereo, ground_truth_calibration
    from twin.sim.checkerboard import place_chessboard, random_chessboard_poses
    from twin.sim.world import SimWorld

    lateral = PLACEMENTS["lateral"]
    config = StereoConfig()
    native = StereoConfig(
        width=config.native_width,
        height=config.native_height,
        native_width=config.native_width,
        native_height=config.native_height,
        noise_std=config.noise_std,
        fovy_deg=config.fovy_deg,
    )
    world = SimWorld(calibration_scene(placement=lateral))
    model, data = world.model, world.data
    open_hand(model, data)
    pairs = []
    with SimStereo(world, native, np.random.default_rng([0, 2])) as camera:
        for pos, rotation in random_chessboard_poses(20, np.random.default_rng(0), placement=lateral):
            place_chessboard(model, data, pos, rotation)
            frame = camera.read()
            pairs.append((frame.left, frame.right))
        place_chessboard(model, data)  # parked out of view
        frame = camera.read()
        palm = (frame.left, frame.right)
    mujoco.mj_kinematics(model, data)
    truth = ground_truth_calibration(model, data, config)
    calibration, fit, hand = calibrate_from_images(pairs, palm, palm_board_centres())
    e = CalibrationOutcome(calibration, fit, hand, truth).errors()
    assert e["hand_translation_mm"] < 1.0 and e["hand_rotation_deg"] < 0.5, e


def test_a_pair_whose_board_is_read_from_opposite_ends_is_left_out_of_the_stereo_fit():
    """The twin's seed 9 (30 views, the CLI's default): find_chessboard's end-square test reads one
    right view from the board's other end (that pair's own left-to-right pose is 164 deg off the rest).
    Fitted with it, the pair sat 390 mm off and the hand 409 mm; left out, the acceptance holds."""
    from twin.experiments.calibrate_cameras import DEFAULT_VIEWS, calibrate_sim

    outcome = calibrate_sim(views=DEFAULT_VIEWS, seed=9)
    assert (outcome.stereo.views_used, outcome.stereo.views_given) == (DEFAULT_VIEWS - 1, DEFAULT_VIEWS)
    e = outcome.errors()
    assert e["hand_translation_mm"] < 1.0 and e["hand_rotation_deg"] < 0.5
    assert e["stereo_translation_mm"] < 1.0 and outcome.stereo.rms_stereo_px < 0.5
