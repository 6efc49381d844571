"""The stereo reconstruction pipeline on a small MuJoCo scene rendered in the test (not the project's sim).

A textured box on a plain floor, two cameras 20 cm apart each toed in 15 degrees (the paper's rig), the
calibration built from the cameras' exact poses and fovy: the reconstructed points are checked against
the box's analytic surface, and coverage against MuJoCo's segmentation of the left view.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from twin.vision.calibration import CameraIntrinsics, StereoCalibration
from twin.vision.reconstruct import (
    ObjectTracker,
    Rectifier,
    default_matcher,
    reconstruct,
)

W, H = 320, 240
FOVY_DEG = 33.0
BASELINE_M = 0.20
TOE_IN_DEG = 15.0
TARGET = np.array([0.0, 0.0, 0.03])
BOX_HALF = np.array([0.035, 0.025, 0.02])
BOX_YAW_DEG = 25.0
CV_FROM_MUJOCO = np.diag([1.0, -1.0, -1.0])


def camera_poses() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """World position and MuJoCo (x, y) axes of each camera, converging on TARGET from above."""
    height = 0.5 * BASELINE_M / math.tan(math.radians(TOE_IN_DEG))
    poses = {}
    for name, side in (("left", -1.0), ("right", 1.0)):
        pos = TARGET + np.array([side * BASELINE_M / 2, 0.0, height])
        forward = (TARGET - pos) / np.linalg.norm(TARGET - pos)
        x_axis = np.cross(forward, [0.0, 1.0, 0.0])
        x_axis /= np.linalg.norm(x_axis)
        poses[name] = (pos, np.stack([x_axis, np.cross(-forward, x_axis)]))
    return poses


def scene_xml(box_pos: np.ndarray) -> str:
    cams = "".join(
        f'<camera name="{n}" pos="{" ".join(map(str, p))}" xyaxes="{" ".join(map(str, a.ravel()))}" '
        f'fovy="{FOVY_DEG}"/>'
        for n, (p, a) in camera_poses().items()
    )
    return f"""
<mujoco>
  <visual><quality shadowsize="0" offsamples="0"/><global offwidth="{2 * W}" offheight="{2 * H}"/>
    <headlight ambient="0.35 0.35 0.35" diffuse="0.5 0.5 0.5" specular="0 0 0"/></visual>
  <asset>
    <texture name="foam" type="cube" builtin="flat" mark="random" random="0.35" width="96" height="96"
             rgb1="0.85 0.55 0.25" rgb2="0.85 0.55 0.25" markrgb="0.4 0.26 0.12"/>
    <material name="foam" texture="foam" specular="0" shininess="0"/>
    <material name="floor" rgba="0.35 0.4 0.5 1" specular="0" shininess="0"/>
  </asset>
  <worldbody>
    <light directional="true" pos="0 0 1" dir="0 0.3 -1" diffuse="0.4 0.4 0.4" specular="0 0 0"/>
    <geom name="floor" type="plane" size="1 1 0.01" material="floor"/>
    <geom name="box" type="box" size="{" ".join(map(str, BOX_HALF))}" pos="{" ".join(map(str, box_pos))}"
          euler="0 0 {BOX_YAW_DEG}" material="foam"/>
    {cams}
  </worldbody>
</mujoco>"""


def calibration_from_poses() -> StereoCalibration:
    """The exact OpenCV calibration of the two MuJoCo cameras; the hand frame is the world frame."""
    f = 0.5 * H / math.tan(math.radians(FOVY_DEG) / 2)
    k = np.array([[f, 0.0, W / 2 - 0.5], [0.0, f, H / 2 - 0.5], [0.0, 0.0, 1.0]])
    intrinsics = CameraIntrinsics(k, np.zeros(5), (W, H))
    world_from = {}
    for name, (pos, axes) in camera_poses().items():
        x, y = axes
        pose = np.eye(4)
        pose[:3, :3] = np.column_stack([x, y, np.cross(x, y)]) @ CV_FROM_MUJOCO.T
        pose[:3, 3] = pos
        world_from[name] = pose
    right_from_left = np.linalg.inv(world_from["right"]) @ world_from["left"]
    return StereoCalibration(
        intrinsics, intrinsics, right_from_left[:3, :3], right_from_left[:3, 3], world_from["left"]
    )


def render(box_pos: np.ndarray, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Left and right RGB at 320x240 (rendered at 640x480, area-averaged, noised) and the box's left mask."""
    import cv2

    model = mujoco.MjModel.from_xml_string(scene_xml(box_pos))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    rng = np.random.default_rng(seed)
    images = []
    with mujoco.Renderer(model, height=2 * H, width=2 * W) as renderer:
        for cam in ("left", "right"):
            renderer.update_scene(data, camera=cam)
            image = cv2.resize(renderer.render(), (W, H), interpolation=cv2.INTER_AREA).astype(float)
            images.append(np.clip(np.rint(image + 2.0 * rng.standard_normal(image.shape)), 0, 255))
        renderer.enable_segmentation_rendering()
        renderer.update_scene(data, camera="left")
        seg = (renderer.render()[..., 0] == model.geom("box").id).astype(np.float32)
    box_mask = cv2.resize(seg, (W, H), interpolation=cv2.INTER_AREA) > 0.5
    return images[0].astype(np.uint8), images[1].astype(np.uint8), box_mask


def box_distance(points: np.ndarray, box_pos: np.ndarray) -> np.ndarray:
    """Unsigned distance of world points to the box's surface."""
    rot = Rotation.from_euler("z", BOX_YAW_DEG, degrees=True).as_matrix()
    q = np.abs((points - box_pos) @ rot) - BOX_HALF
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    inside = np.minimum(q.max(axis=1), 0.0)
    return np.abs(outside + inside)


BOX_A = np.array([0.005, 0.0, BOX_HALF[2]])
BOX_B = BOX_A + np.array([0.03, 0.02, 0.0])  # moved 3.6 cm between frames


@pytest.fixture(scope="module")
def rectifier() -> Rectifier:
    return Rectifier(calibration_from_poses())


def rectified_truth(rectifier: Rectifier, box_mask: np.ndarray) -> np.ndarray:
    import cv2

    return rectifier.remap(box_mask.astype(np.uint8), interpolation=cv2.INTER_NEAREST) > 0


@pytest.fixture(scope="module")
def first(rectifier):
    """Frame A: the tracker seeded from the true box's bounding box, and its reconstruction."""
    import cv2

    left, right, box_mask = render(BOX_A)
    truth = rectified_truth(rectifier, box_mask)
    left_rect, _ = rectifier.rectify(left, right)
    tracker = ObjectTracker(left_rect, cv2.boundingRect(truth.astype(np.uint8)))
    rec = reconstruct(left, right, rectifier, tracker, matcher=default_matcher(rectifier))
    return {"left": left, "right": right, "truth": truth, "tracker": tracker, "rec": rec}


def coverage(rec, truth: np.ndarray) -> float:
    got = np.zeros_like(truth)
    got[rec.pixels[:, 0], rec.pixels[:, 1]] = True
    return float((got & truth).sum() / truth.sum())


def test_points_lie_on_the_box_surface(first):
    rec = first["rec"]
    distance = box_distance(rec.points_hand, BOX_A)
    print(
        f"points {len(distance)}, distance to the box surface: median {1e3 * np.median(distance):.3f} mm, "
        f"90 % {1e3 * np.percentile(distance, 90):.3f} mm, max {1e3 * distance.max():.2f} mm"
    )
    assert len(distance) > 1000
    assert np.median(distance) <= 1.5e-3
    assert np.percentile(distance, 90) <= 3e-3


def test_most_of_the_visible_box_gets_a_point(first):
    rec, truth = first["rec"], first["truth"]
    iou = (rec.mask & truth).sum() / (rec.mask | truth).sum()
    print(f"coverage {coverage(rec, truth):.1%}, mask IoU {iou:.3f}, timings {rec.timings_ms}")
    assert coverage(rec, truth) >= 0.6
    assert iou >= 0.8
    assert rec.colors.shape == rec.points_hand.shape and rec.colors.dtype == np.uint8
    assert set(rec.timings_ms) == {"rectify", "track", "disparity", "cloud", "mesh"}


def test_mesh_triangles_are_valid(first):
    rec = first["rec"]
    tri = rec.triangles
    assert tri.ndim == 2 and tri.shape[1] == 3 and len(tri) > len(rec.points_hand)
    assert tri.min() >= 0 and tri.max() < len(rec.points_hand)
    assert np.all((tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 0] != tri[:, 2]))
    corners = rec.points_hand[tri]
    edges = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2)
    assert edges.max() <= 0.008 + 1e-12


def test_mesh_stride_meshes_a_grid_subset(first, rectifier):
    rec = reconstruct(first["left"], first["right"], rectifier, first["truth"], mesh_stride=2)
    used = np.unique(rec.triangles)
    assert len(rec.triangles) > 0 and rec.box is None
    assert np.all(rec.pixels[used] % 2 == 0)
    with pytest.raises(ValueError, match="mesh_stride"):
        reconstruct(first["left"], first["right"], rectifier, first["truth"], mesh_stride=0)


def test_camshift_follows_the_moving_box(first, rectifier):
    left, right, box_mask = render(BOX_B, seed=1)
    truth = rectified_truth(rectifier, box_mask)
    tracker = first["tracker"]
    rec = reconstruct(left, right, rectifier, tracker)
    x, y, w, h = rec.box
    rows, cols = np.nonzero(truth)
    assert abs(x + w / 2 - cols.mean()) < 8 and abs(y + h / 2 - rows.mean()) < 8
    iou = (rec.mask & truth).sum() / (rec.mask | truth).sum()
    assert iou >= 0.8
    assert np.median(box_distance(rec.points_hand, BOX_B)) <= 1.5e-3
    assert coverage(rec, truth) >= 0.6


def test_a_lost_object_gives_an_empty_cloud(first, rectifier):
    left, right, _ = render(np.array([1.0, 1.0, BOX_HALF[2]]))  # out of view
    left_rect, _ = rectifier.rectify(first["left"], first["right"])
    tracker = ObjectTracker(left_rect, first["tracker"].window)
    rec = reconstruct(left, right, rectifier, tracker)
    assert rec.mask.sum() < 0.01 * rec.mask.size
    assert rec.triangles.shape[1] == 3 and rec.points_hand.shape[1] == 3


@pytest.mark.parametrize(
    ("bbox", "match"),
    [
        ((10, 10, 0, 20), "empty"),
        ((10, 10, 20, -1), "empty"),
        ((-5, 10, 20, 20), "not inside"),
        ((310, 10, 20, 20), "not inside"),
        ((10, 230, 20, 20), "not inside"),
        ((0, 0, 3, 3), "bright enough"),  # the black border rectification leaves
    ],
)
def test_bad_bounding_boxes_are_refused(first, rectifier, bbox, match):
    left_rect, _ = rectifier.rectify(first["left"], first["right"])
    with pytest.raises(ValueError, match=match):
        ObjectTracker(left_rect, bbox)


def test_rectification_geometry(rectifier):
    import cv2

    cal = calibration_from_poses()
    plain = Rectifier(cal, center_convergence=False)
    *_, q, _, _ = cv2.stereoRectify(
        cal.left.matrix, cal.left.distortion, cal.right.matrix, cal.right.distortion, (W, H),
        cal.rotation, cal.translation_m.reshape(3, 1), flags=cv2.CALIB_ZERO_DISPARITY, alpha=-1,
    )  # fmt: skip
    np.testing.assert_allclose(plain.Q, q, rtol=1e-9, atol=1e-9)
    assert rectifier.convergence_disparity == pytest.approx(0.0, abs=1e-6)
    assert plain.convergence_disparity == pytest.approx(2 * 405.1 * math.tan(math.radians(15)), rel=1e-3)
    # A world point seen at (u1, v) and (u2, v) triangulates back through Q and hand_from_rectified.
    world = np.array([0.02, -0.01, 0.04, 1.0])
    for r in (rectifier, plain):
        x_rect = np.linalg.inv(r.hand_from_rectified) @ world
        (u1, v1, z1), (u2, v2, z2) = r.P1 @ x_rect, r.P2 @ x_rect
        assert v1 / z1 == pytest.approx(v2 / z2)
        back = r.Q @ [u1 / z1, v1 / z1, u1 / z1 - u2 / z2, 1.0]
        np.testing.assert_allclose(
            r.hand_from_rectified @ np.append(back[:3] / back[3], 1.0), world, atol=1e-9
        )


def test_wrong_sizes_are_refused(first, rectifier):
    with pytest.raises(ValueError, match="calibration is"):
        rectifier.rectify(first["left"][:, :200], first["right"])
    with pytest.raises(ValueError, match="mask shape"):
        reconstruct(first["left"], first["right"], rectifier, np.ones((10, 10), bool))


def test_the_hand_region_keeps_the_grasp_and_drops_the_room():
    from twin.vision.reconstruct import HandRegion

    region = HandRegion(radius_m=0.15, z_min_m=0.06, z_max_m=0.35)
    points = np.array(
        [
            [0.0, 0.0, 0.11],  # a held object's centre
            [0.14, 0.0, 0.2],  # at the rim
            [0.0, 0.16, 0.11],  # beside the hand
            [0.0, 0.0, 0.05],  # below the palm's face (the mount, the bench)
            [0.0, 0.0, 0.40],  # above the reach of the fingers
        ]
    )
    np.testing.assert_array_equal(region.contains(points), [True, True, False, False, False])


def test_a_mask_at_the_frames_edge_is_matched_in_a_crop_wider_than_the_search():
    """An object cut by the frame's edge: the crop around it is widened inwards to more columns than
    the matcher searches (OpenCV's SGBM raised a negative allocation, or crashed, on a narrower one),
    and reads what the full frame reads: a textured plane 6 px apart, searched as a toed-in rig does."""
    import cv2

    from twin.vision.reconstruct import compute_disparity, disparity_around, make_sgbm_matcher

    rng = np.random.default_rng(3)
    texture = cv2.GaussianBlur(rng.integers(0, 255, (H, W + 6)).astype(np.uint8), (3, 3), 0)
    left, right = texture[:, 6:], texture[:, :-6]  # left[:, x] is right[:, x + 6]: disparity -6 px
    matcher = make_sgbm_matcher(64, 3, -32)  # a converged rig's search: -32 to +31 px
    full = compute_disparity(left, right, matcher)
    for first_col, last_col in ((W - 16, W), (0, 12), (150, 166)):  # two old crops under 64 columns
        mask = np.zeros((H, W), dtype=bool)
        mask[100:140, first_col:last_col] = True

        cropped = disparity_around(left, right, matcher, mask)

        assert np.array_equal(np.isfinite(cropped[mask]), np.isfinite(full[mask]))
        assert np.allclose(cropped[mask], full[mask], atol=0.5, equal_nan=True)
        assert np.isnan(cropped[:90]).all() and np.isnan(cropped[150:]).all()  # rows far from it: none
    assert np.nanmedian(cropped[mask]) == pytest.approx(-6.0, abs=0.5)  # the last mask lies inside
