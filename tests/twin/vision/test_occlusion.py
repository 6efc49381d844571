"""The fingers' occlusion test (twin.vision.occlusion) against MuJoCo's own ray caster, and the finger
boxes the pipeline takes from the hand's kinematics against the hand model's geoms."""

import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from twin.vision.occlusion import box_corners, hidden_by_box, hidden_by_boxes

BOX_XML = """
<mujoco><worldbody>
  <geom name="box" type="box" size="{hx} {hy} {hz}" pos="{px} {py} {pz}" quat="{qw} {qx} {qy} {qz}"/>
</worldbody></mujoco>"""


def _random_box(seed: int):
    rng = np.random.default_rng(seed)
    half = rng.uniform(0.005, 0.03, 3)
    centre = rng.uniform(-0.02, 0.02, 3) + np.array([0.0, 0.0, 0.3])
    rotation = Rotation.random(random_state=seed)
    x, y, z, w = rotation.as_quat()
    xml = BOX_XML.format(hx=half[0], hy=half[1], hz=half[2], px=centre[0], py=centre[1], pz=centre[2],
                         qw=w, qx=x, qy=y, qz=z)  # fmt: skip
    return mujoco.MjModel.from_xml_string(xml), centre, rotation.as_matrix(), half


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_box_hides_exactly_the_points_mujocos_ray_caster_says(seed):
    model, centre, rotation, half = _random_box(seed)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    eye = np.zeros(3)
    rng = np.random.default_rng(100 + seed)
    points = centre + rng.uniform(-0.06, 0.06, (400, 3))  # around, behind, in front of and in the box
    hidden = hidden_by_box(points, eye, box_corners(centre, rotation, half), margin_m=0.0)
    geomid = np.zeros(1, dtype=np.int32)
    for p, h in zip(points, hidden, strict=True):
        distance = np.linalg.norm(p)
        hit = mujoco.mj_ray(model, data, eye, p / distance, None, 1, -1, geomid)
        local = np.abs((p - centre) @ rotation)
        inside = (local <= half).all()
        truth = inside or (hit >= 0 and hit <= distance)
        assert h == truth, (p, hit, distance, inside)
    assert 0 < hidden.sum() < len(points)  # both kinds occur


def test_the_image_prefilter_changes_nothing():
    _, centre, rotation, half = _random_box(3)
    corners = box_corners(centre, rotation, half)[None]
    k = np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]])
    projection = k @ np.eye(3, 4)
    points = centre + np.random.default_rng(4).uniform(-0.06, 0.06, (500, 3))
    uvw = points @ k.T
    pixels = uvw[:, :2] / uvw[:, 2:]
    full = hidden_by_boxes(points, np.zeros(3), corners)
    culled = hidden_by_boxes(points, np.zeros(3), corners, pixels_xy=pixels, image_from_frame=projection)
    np.testing.assert_array_equal(full, culled)
    assert full.any()


def test_the_finger_boxes_are_the_hand_models_visual_geoms():
    """The pipeline's finger corners (from link angles) enclose the hand model's own finger geoms at
    the same pose: every vertex MuJoCo puts on a finger's visual geom lies in (or on) one of them."""
    from twin.vision.calibration import CameraIntrinsics, StereoCalibration
    from twin.vision.pipeline import StereoPipeline

    k = np.array([[300.0, 0, 159.5], [0, 300.0, 119.5], [0, 0, 1]])
    cam = CameraIntrinsics(k, np.zeros(5), (320, 240))
    hand_from_left = np.eye(4)
    hand_from_left[:3, :3] = np.diag([1.0, -1.0, -1.0])
    hand_from_left[:3, 3] = [0.0, 0.0, 0.5]
    calibration = StereoCalibration(cam, cam, np.eye(3), np.array([-0.2, 0.0, 0.0]), hand_from_left)
    pipeline = StereoPipeline(calibration, (100, 80, 100, 80))
    assert pipeline.finger_corners() is None  # no hand reading yet
    links = np.array([[0.8, 0.5], [1.0, 0.6], [1.2, 0.7]])
    pipeline.kinematics.set_angles(links, 0.3)
    corners = pipeline.finger_corners()
    m, d = pipeline.kinematics.model, pipeline.kinematics.data
    palm = m.body("palm").id
    hand_from_world = np.eye(4)
    hand_from_world[:3, :3] = d.xmat[palm].reshape(3, 3).T
    hand_from_world[:3, 3] = -hand_from_world[:3, :3] @ d.xpos[palm]
    geoms = [
        g
        for g in range(m.ngeom)
        if m.geom_group[g] == 2 and m.body(m.geom_bodyid[g]).name[:3] in ("f1_", "f2_", "f3_")
    ]
    assert len(corners) == len(geoms) >= 9
    for g in geoms:  # the geom's centre and its extreme points along its own axes
        rot, size = d.geom_xmat[g].reshape(3, 3), m.geom_size[g]
        extent = size if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX else [size[0], size[0], size[1]]
        world = d.geom_xpos[g] + 0.999 * (np.diag(extent) @ rot.T)
        hand = world @ hand_from_world[:3, :3].T + hand_from_world[:3, 3]
        below = np.array([0.0, 0.0, -1.0])  # any eye: a point inside a box is hidden
        inside = [
            hidden_by_box(
                np.vstack([hand, d.geom_xpos[g] @ hand_from_world[:3, :3].T + hand_from_world[:3, 3]]),
                below,
                box,
            )
            for box in corners
        ]
        assert np.any(inside, axis=0).all(), m.geom(g).name
