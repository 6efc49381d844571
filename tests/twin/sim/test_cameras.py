"""The simulated stereo pair: real EGL rendering, its frames, and its ground-truth calibration."""

from __future__ import annotations

import math

import cv2
import mujoco
import numpy as np
import pytest

from twin.interface.errors import ConfigError
from twin.interface.stereo_spec import StereoConfig, stereo_device_spec
from twin.sim.cameras import (
    DEFAULT_PLACEMENT,
    LEFT_CAMERA,
    PLACEMENTS,
    RIGHT_CAMERA,
    TARGET_M,
    CameraPlacement,
    SimStereo,
    add_stereo_cameras,
    ground_truth_calibration,
    pair_camera_names,
    placement_axes,
    stereo_camera_poses,
)
from twin.sim.foam import get_object
from twin.sim.scene import compile_scene, scene_mjcf
from twin.sim.world import SimWorld
from twin.vision.calibration import StereoCalibration

CONFIG = StereoConfig()


def _world(palm_pos: list[float] | None = None, palm_euler: list[float] | None = None) -> SimWorld:
    root = scene_mjcf(get_object("block"))
    add_stereo_cameras(root, CONFIG)
    if palm_pos is not None:  # a hand that is not at the world origin: the hand frame must follow it
        palm = root.find("body", "palm")
        palm.pos, palm.euler = palm_pos, palm_euler
    return SimWorld(compile_scene(root))


@pytest.fixture(scope="module")
def world() -> SimWorld:
    return _world()


@pytest.fixture(scope="module")
def stereo(world: SimWorld):
    cam = SimStereo(world, CONFIG, np.random.default_rng(0))
    with cam:
        yield cam


def _foam_mask(world: SimWorld, camera: str, width: int, height: int) -> np.ndarray:
    """Pixels MuJoCo's segmentation rendering assigns to the foam's flex."""
    renderer = mujoco.Renderer(world.model, height=height, width=width)
    try:
        renderer.enable_segmentation_rendering()
        renderer.update_scene(world.data, camera=camera)
        seg = renderer.render()
    finally:
        renderer.close()
    return (seg[..., 1] == int(mujoco.mjtObj.mjOBJ_FLEX)) & (seg[..., 0] == 0)


def _project(cal: StereoCalibration, world: SimWorld, side: str) -> np.ndarray:
    """The foam's flex vertices (hand frame) projected with the calibration, (N, 2) pixels."""
    palm = world.model.body("palm").id
    hand_from_world = np.eye(4)
    rot = world.data.xmat[palm].reshape(3, 3)
    hand_from_world[:3, :3] = rot.T
    hand_from_world[:3, 3] = -rot.T @ world.data.xpos[palm]
    points = world.data.flexvert_xpos @ hand_from_world[:3, :3].T + hand_from_world[:3, 3]
    cam_from_hand = np.linalg.inv(cal.hand_from_left)
    intrinsics = cal.left
    if side == "right":
        left_to_right = np.eye(4)
        left_to_right[:3, :3], left_to_right[:3, 3] = cal.rotation, cal.translation_m
        cam_from_hand = left_to_right @ cam_from_hand
        intrinsics = cal.right
    rvec, _ = cv2.Rodrigues(cam_from_hand[:3, :3])
    pixels, _ = cv2.projectPoints(
        points, rvec, cam_from_hand[:3, 3], intrinsics.matrix, intrinsics.distortion
    )
    return pixels.reshape(-1, 2)


def _check_projection(cal: StereoCalibration, world: SimWorld, width: int, height: int) -> None:
    """Projected vertices fall on foam pixels; their silhouette matches the rendered one to a fraction
    of a pixel (a half-pixel principal-point slip would fail the centroid check)."""
    for side, camera in (("left", LEFT_CAMERA), ("right", RIGHT_CAMERA)):
        mask = _foam_mask(world, camera, width, height)
        pixels = _project(cal, world, side)
        cols, rows = np.rint(pixels).astype(int).T
        assert np.all((cols >= 0) & (cols < width) & (rows >= 0) & (rows < height)), side
        near_foam = cv2.dilate(mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        assert near_foam[rows, cols].all(), f"{side}: projected vertices off the foam"
        hull = cv2.convexHull(pixels.astype(np.float32))
        moments = cv2.moments(hull)
        hull_centroid = np.array([moments["m10"], moments["m01"]]) / moments["m00"]
        ys, xs = np.nonzero(mask)
        mask_centroid = np.array([xs.mean(), ys.mean()])
        np.testing.assert_allclose(mask_centroid, hull_centroid, atol=0.2, err_msg=side)
        # The rendered skin stands the flex radius (1 mm, ~1 px) proud of the vertices: ~4 % more area.
        assert mask.sum() == pytest.approx(1.04 * moments["m00"], rel=0.03), side


def test_spec_declares_both_frames():
    spec = stereo_device_spec(CONFIG)
    assert spec.rate_hz == 30.0 and set(spec.channels) == {"left", "right"}
    for channel in spec.channels.values():
        assert channel.shape == (240, 320, 3) and channel.dtype == "uint8"
        assert channel.saturation == (0, 255) and channel.noise_std == CONFIG.noise_std
    # Flea2 (7.4 um pixels) behind a 6 mm lens: f = 811 px at 640x480, 405 px at 320x240.
    assert CONFIG.fovy_deg == pytest.approx(32.98, abs=0.01)
    assert CONFIG.focal_px == pytest.approx(6.0 / 0.0074 / 2, rel=1e-9)


@pytest.mark.parametrize(
    "overrides", [{"rate_hz": 0}, {"noise_std": -1}, {"width": 1280}, {"height": 200}, {"fovy_deg": 180}]
)
def test_config_rejects_bad_values(overrides):
    with pytest.raises(ConfigError):
        StereoConfig(**overrides)


def test_frames_are_processed_size_and_show_the_scene(stereo, world):
    frame = stereo.read()
    assert frame.t_s == world.time_s
    for image in (frame.left, frame.right):
        assert image.shape == (240, 320, 3) and image.dtype == np.uint8
        assert image.std() > 20  # not blank
    assert not np.array_equal(frame.left, frame.right)
    # The foam is the pale yellow-orange, porous block where the segmentation puts it.
    mask = _foam_mask(world, LEFT_CAMERA, 320, 240)
    foam = frame.left[mask].astype(float)
    assert mask.sum() > 2000
    assert foam[:, 0].mean() > foam[:, 2].mean() + 40  # yellow: red well above blue
    assert foam[:, 0].std() > 8  # pores, not a flat colour


def test_noise_is_declared_and_seeded(world):
    quiet = SimStereo(world, StereoConfig(noise_std=0.0), np.random.default_rng(1), render_native=True)
    noisy = [SimStereo(world, CONFIG, np.random.default_rng(5)) for _ in range(2)]
    with quiet, noisy[0], noisy[1]:
        clean = quiet.read()
        a, b = noisy[0].read(), noisy[1].read()
        assert np.array_equal(clean.left, quiet.read().left)  # noiseless: deterministic
    assert np.array_equal(a.left, b.left) and np.array_equal(a.right, b.right)  # same seed, same frame
    diff = a.left.astype(float) - clean.left
    unclipped = (clean.left > 10) & (clean.left < 245)
    assert diff[unclipped].std() == pytest.approx(CONFIG.noise_std, rel=0.1)


def test_foam_centre_projects_near_both_image_centres(world):
    cal = ground_truth_calibration(world.model, world.data, CONFIG)
    for side in ("left", "right"):
        centre = _project(cal, world, side).mean(axis=0)
        assert np.linalg.norm(centre - [159.5, 119.5]) < 15, (side, centre)


def test_calibration_geometry_matches_the_rig(world):
    cal = ground_truth_calibration(world.model, world.data, CONFIG)
    assert cal.baseline_m == pytest.approx(0.20, abs=0.01)
    axis_angle = math.degrees(math.acos(np.clip(cal.rotation[2, 2], -1, 1)))
    assert axis_angle == pytest.approx(30.0, abs=3.0)
    np.testing.assert_allclose(cal.rotation @ cal.rotation.T, np.eye(3), atol=1e-9)
    # The default placement: the left camera 386 mm from the target (on the palm axis at the foam's
    # mid-height), its optical axis through the target, toed in by half the vergence from the pair's
    # direction (placement_axes); in the hand frame, as the calibration reports it.
    origin, axis = cal.hand_from_left[:3, 3], cal.hand_from_left[:3, 2]
    to_target = np.asarray(TARGET_M) - origin
    assert np.linalg.norm(to_target) == pytest.approx(0.386, abs=0.005)
    assert math.degrees(math.acos(axis @ to_target / np.linalg.norm(to_target))) < 0.5
    toward = placement_axes(PLACEMENTS[DEFAULT_PLACEMENT])[2]
    toe_in = math.degrees(math.acos(-axis @ toward))
    assert toe_in == pytest.approx(15.0, abs=0.5)
    k = cal.left.matrix
    assert cal.left.image_size == (320, 240)
    assert k[0, 0] == k[1, 1] == pytest.approx(CONFIG.focal_px)
    assert (k[0, 2], k[1, 2]) == (159.5, 119.5)


def test_calibration_projects_onto_rendered_foam(world):
    _check_projection(ground_truth_calibration(world.model, world.data, CONFIG), world, 320, 240)


def test_scaled_calibration_holds_at_native_size(world):
    cal = ground_truth_calibration(world.model, world.data, CONFIG).scaled(640, 480)
    _check_projection(cal, world, 640, 480)


def test_calibration_follows_a_moved_hand(world):
    moved = _world(palm_pos=[0.01, 0.015, -0.01], palm_euler=[0.0, 0.0, 0.3])  # below the foam
    cal = ground_truth_calibration(moved.model, moved.data, CONFIG)
    at_rest = ground_truth_calibration(world.model, world.data, CONFIG)
    assert not np.allclose(cal.hand_from_left, at_rest.hand_from_left)
    _check_projection(cal, moved, 320, 240)


def test_calibration_round_trips_through_json(world, tmp_path):
    cal = ground_truth_calibration(world.model, world.data, CONFIG)
    loaded = StereoCalibration.load(cal.save(tmp_path / "stereo.json"))
    for a, b in ((cal.left, loaded.left), (cal.right, loaded.right)):
        np.testing.assert_array_equal(a.matrix, b.matrix)
        np.testing.assert_array_equal(a.distortion, b.distortion)
        assert a.image_size == b.image_size
    np.testing.assert_array_equal(cal.rotation, loaded.rotation)
    np.testing.assert_array_equal(cal.translation_m, loaded.translation_m)
    np.testing.assert_array_equal(cal.hand_from_left, loaded.hand_from_left)


@pytest.mark.parametrize("name", sorted(PLACEMENTS))
def test_every_placement_is_the_papers_pair_converging_on_the_target(name):
    """Whatever the view: 20 cm baseline along the image rows, 30 deg between the optical axes, both
    crossing at the target (MuJoCo's own camera frames of the compiled scene)."""
    root = scene_mjcf(None)
    add_stereo_cameras(root, CONFIG, placement=PLACEMENTS[name])
    model = compile_scene(root)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)  # camera frames: mj_camlight
    pos = {c: data.cam_xpos[model.camera(c).id] for c in (LEFT_CAMERA, RIGHT_CAMERA)}
    axes = {c: -data.cam_xmat[model.camera(c).id].reshape(3, 3)[:, 2] for c in pos}  # MuJoCo looks along -z
    assert np.linalg.norm(pos[RIGHT_CAMERA] - pos[LEFT_CAMERA]) == pytest.approx(0.20, abs=1e-9)
    assert math.degrees(math.acos(axes[LEFT_CAMERA] @ axes[RIGHT_CAMERA])) == pytest.approx(30.0, abs=1e-6)
    for c in pos:
        to_target = np.asarray(TARGET_M) - pos[c]
        assert axes[c] @ to_target / np.linalg.norm(to_target) == pytest.approx(1.0, abs=1e-9)
        right = data.cam_xmat[model.camera(c).id].reshape(3, 3)[:, 0]
        baseline = (pos[RIGHT_CAMERA] - pos[LEFT_CAMERA]) / 0.20
        assert right @ baseline > 0.94  # within 20 deg: the baseline runs along the image rows


def test_the_top_placement_is_the_rig_looking_straight_down():
    poses = stereo_camera_poses(PLACEMENTS["top"])
    height = 0.1 / math.tan(math.radians(15.0))
    for name, side in ((LEFT_CAMERA, -1.0), (RIGHT_CAMERA, 1.0)):
        expected = np.asarray(TARGET_M) + np.array([side * 0.1, 0.0, height])
        np.testing.assert_allclose(poses[name][0], expected, atol=1e-12)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"baseline_m": 0.0}, "baseline_m"),
        ({"vergence_deg": 180.0}, "vergence_deg"),
        ({"elevation_deg": -45.0}, "elevation_deg"),
        ({"target_m": (0.0, 0.0)}, "target_m"),
    ],
)
def test_an_impossible_placement_is_a_one_line_error(kwargs, message):
    with pytest.raises(ValueError, match=rf"^camera placement 'bad': {message}"):
        CameraPlacement("bad", **kwargs)


def test_a_rig_of_two_pairs_keeps_the_first_pairs_cameras_and_mirrors_the_second():
    """Two placements: the first pair is the one-pair rig's (same names, same poses), the second stands
    where its placement says (`opposite`: the lateral pair turned 180 deg about the palm axis)."""
    root = scene_mjcf(None)
    add_stereo_cameras(root, CONFIG, placement=[PLACEMENTS["lateral"], PLACEMENTS["opposite"]])
    model = compile_scene(root)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    assert model.ncam == 4
    one_pair = stereo_camera_poses(PLACEMENTS["lateral"])
    second = pair_camera_names(1)
    assert second != (LEFT_CAMERA, RIGHT_CAMERA)
    half_turn = np.diag([-1.0, -1.0, 1.0])  # about the palm axis through the target (x = y = 0)
    for first, other in zip((LEFT_CAMERA, RIGHT_CAMERA), second, strict=True):
        pos = data.cam_xpos[model.camera(first).id]
        np.testing.assert_allclose(pos, one_pair[first][0], atol=1e-9)
        np.testing.assert_allclose(data.cam_xpos[model.camera(other).id], half_turn @ pos, atol=1e-9)
