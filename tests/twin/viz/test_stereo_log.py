"""Stereo logging against real Rerun and a real SimBackend: frames, reconstruction, read back."""

from __future__ import annotations

import numpy as np
import pytest

from twin.sim.backend import SimBackend
from twin.sim.foam import get_object
from twin.vision.reconstruct import ObjectTracker, Rectifier, default_matcher, reconstruct
from twin.viz.rerun_log import (
    CLOUD_ENTITY,
    FUSED_CLOUD_ENTITY,
    FUSED_MESH_ENTITY,
    FUSED_PERIOD_S,
    HAND_ENTITY,
    IMAGE_PERIOD_S,
    MESH_ENTITY,
    RECTIFIED_ENTITY,
    STEREO_ENTITY,
    TACTILE_POINTS_ENTITY,
    RunRecording,
    _short_triangles,
    read_rrd_entities,
    read_rrd_images,
    read_rrd_meshes,
    read_rrd_pinholes,
    read_rrd_points,
    read_rrd_transforms,
    read_rrd_views,
)

FRAMES = 3
MAX_BYTES_PER_FRAME = 400_000
"""Whole file / frames, blueprint and statics included: measured ~330 kB for 3 frames 0.1 s apart (the
~6000-point coloured cloud of every pixel and its mesh are most of it; a run logs every 2nd row and
column, and clouds and meshes at 5 Hz only) plus the ~1500-point fused cloud of this test. Raw images
alone would be 450 kB a frame."""


@pytest.fixture(scope="module")
def logged(tmp_path_factory):
    """FRAMES stereo frames of the block on the palm, reconstructed and logged; what went in."""
    backend = SimBackend(get_object("block"), stereo=True)
    backend.connect()
    try:
        calibration = backend.stereo.calibration()
        rectifier = Rectifier(calibration)
        matcher = default_matcher(rectifier)
        first = backend.stereo.read()
        tracker = ObjectTracker(rectifier.rectify(first.left, first.right)[0], backend.object_box(rectifier))
        path = tmp_path_factory.mktemp("rrd") / "stereo.rrd"
        inputs = []
        with RunRecording(path, recording_id="stereo") as rec:
            hand_pose = backend.hand_pose_in_world()
            rec.log_stereo_setup(calibration, hand_pose)
            for i in range(FRAMES):
                backend.world.advance_to((i + 1) * FUSED_PERIOD_S)  # every frame's surfaces logged
                frame = backend.stereo.read()
                r = reconstruct(frame.left, frame.right, rectifier, tracker, matcher=matcher, mesh_stride=2)
                fused = r.points_hand[::4]
                fused_triangles = np.array([[0, 1, 2], [1, 2, 3]])
                tactile = np.array([[0.0, 0.03, 0.1], [0.0, -0.03, 0.1]])
                rec.log_stereo(frame.t_s, frame.left, frame.right, r, fused, fused_triangles, tactile)
                inputs.append((frame, r, fused, tactile))
        yield path, calibration, rectifier, hand_pose, inputs
    finally:
        backend.disconnect()


def test_stereo_entities_one_row_per_frame(logged):
    path, *_ = logged
    entities = read_rrd_entities(path)
    for side in ("left", "right"):
        assert entities[f"/{STEREO_ENTITY}/{side}"] == 1  # static: transform + pinhole
        assert entities[f"/{STEREO_ENTITY}/{side}/image"] == FRAMES
    assert entities[f"/{HAND_ENTITY}"] == 1
    for entity in (CLOUD_ENTITY, MESH_ENTITY, f"{RECTIFIED_ENTITY}/depth", FUSED_CLOUD_ENTITY):
        assert entities[f"/{entity}"] == FRAMES
    assert entities[f"/{FUSED_MESH_ENTITY}"] == entities[f"/{TACTILE_POINTS_ENTITY}"] == FRAMES
    bytes_per_frame = path.stat().st_size / FRAMES
    assert bytes_per_frame < MAX_BYTES_PER_FRAME, bytes_per_frame
    views = read_rrd_views(path)
    assert views["left camera"]["kind"] == "2D" and views["left camera"]["origin"] == f"/{STEREO_ENTITY}/left"
    depth_view = views["rectified left: depth (m) and contours"]
    assert depth_view["kind"] == "2D" and depth_view["origin"] == f"/{RECTIFIED_ENTITY}"


def test_cameras_are_pinholes_in_the_hand_frame(logged):
    path, calibration, rectifier, hand_pose, _ = logged
    pinholes = read_rrd_pinholes(path)
    k, size = pinholes[f"/{STEREO_ENTITY}/left"]
    np.testing.assert_allclose(k, calibration.left.matrix, rtol=1e-6)
    assert size == (320, 240)
    np.testing.assert_allclose(pinholes[f"/{STEREO_ENTITY}/right"][0], calibration.right.matrix, rtol=1e-6)
    np.testing.assert_allclose(pinholes[f"/{RECTIFIED_ENTITY}"][0], rectifier.P1[:3, :3], rtol=1e-6)
    (hand,) = read_rrd_transforms(path, HAND_ENTITY)
    np.testing.assert_allclose(hand, hand_pose, atol=1e-9)
    (left,) = read_rrd_transforms(path, f"{STEREO_ENTITY}/left")
    np.testing.assert_allclose(left, calibration.hand_from_left, atol=1e-6)
    (right,) = read_rrd_transforms(path, f"{STEREO_ENTITY}/right")
    # The right camera sits one baseline to the left camera's +x (OpenCV: t = -R c_right).
    np.testing.assert_allclose(np.linalg.norm(right[:3, 3] - left[:3, 3]), calibration.baseline_m, rtol=1e-6)
    right_from_left = np.linalg.inv(right) @ left
    np.testing.assert_allclose(right_from_left[:3, :3], calibration.rotation, atol=1e-6)
    np.testing.assert_allclose(right_from_left[:3, 3], calibration.translation_m, atol=1e-6)


def test_images_points_mesh_and_depth_read_back(logged):
    path, _, rectifier, _, inputs = logged
    images = read_rrd_images(path, f"{STEREO_ENTITY}/left/image")
    assert len(images) == FRAMES
    for (t, image), (frame, *_) in zip(images, inputs, strict=True):
        assert t == pytest.approx(frame.t_s)
        assert image.shape == frame.left.shape == (240, 320, 3)
        assert np.abs(image.astype(int) - frame.left).mean() < 6  # JPEG
    clouds = read_rrd_points(path, CLOUD_ENTITY)
    meshes = read_rrd_meshes(path, MESH_ENTITY)
    depths = read_rrd_images(path, f"{RECTIFIED_ENTITY}/depth")
    fused_clouds = read_rrd_points(path, FUSED_CLOUD_ENTITY)
    tactile_clouds = read_rrd_points(path, TACTILE_POINTS_ENTITY)
    for (_, points, colors), (verts, faces, _), (_, depth), (_, r, fused, tactile), f, c in zip(
        clouds, meshes, depths, inputs, fused_clouds, tactile_clouds, strict=True
    ):
        assert len(points) == len(r.points_hand) > 3000
        np.testing.assert_allclose(points, r.points_hand, atol=1e-6)
        np.testing.assert_array_equal(colors[:, :3], r.colors)
        # The mesh (every 2nd row and column) carries the vertices it uses only, and no triangle much
        # longer than its neighbours (one that would join points across a gap).
        kept = _short_triangles(r.points_hand, r.triangles)
        assert len(faces) == len(kept) > 0.9 * len(r.triangles) > 500
        np.testing.assert_allclose(verts[faces], r.points_hand[kept], atol=1e-6)
        assert len(verts) < len(points) / 2
        # Depth of the rectified left camera: the cloud's z there, within the 0.1 mm quantum.
        rect_from_hand = np.linalg.inv(rectifier.hand_from_rectified)
        z = r.points_hand @ rect_from_hand[2, :3] + rect_from_hand[2, 3]
        np.testing.assert_allclose(depth[r.pixels[:, 0], r.pixels[:, 1]], z, atol=1e-4)
        assert (depth[~r.mask] == 0).all()
        np.testing.assert_allclose(f[1], fused, atol=1e-6)
        np.testing.assert_allclose(c[1], tactile, atol=1e-7)


def test_stereo_without_setup_or_reconstruction(tmp_path):
    """A real rig with no 3-D scene: images only, or a reconstruction without a depth image."""
    path = tmp_path / "bare.rrd"
    image = np.full((240, 320, 3), 128, np.uint8)
    with RunRecording(path, recording_id="bare") as rec:
        rec.log_stereo(0.0, image, image, jpeg_quality=None)
        rec.log_stereo(0.1, image, image)
    entities = read_rrd_entities(path)
    assert entities[f"/{STEREO_ENTITY}/left/image"] == 2 and f"/{CLOUD_ENTITY}" not in entities
    (t0, raw), (t1, jpeg) = read_rrd_images(path, f"{STEREO_ENTITY}/right/image")
    assert (t0, t1) == (0.0, pytest.approx(0.1))
    np.testing.assert_array_equal(raw, image)
    assert np.abs(jpeg.astype(int) - 128).max() <= 2
    assert "left camera" not in read_rrd_views(path)


def test_images_and_depth_at_10_fps_surfaces_at_5_hz_the_fused_at_2_hz_of_a_30_fps_pair(logged, tmp_path):
    """A 30 fps pair: every third image pair with its depth, every sixth cloud, every 15th fused mesh."""
    *_, inputs = logged
    frame, r, fused, tactile = inputs[0]
    path = tmp_path / "rates.rrd"
    with RunRecording(path) as rec:
        rec.log_stereo_setup(logged[1])
        for i in range(16):
            rec.log_stereo(i / 30, frame.left, frame.right, r, fused, np.array([[0, 1, 2]]), tactile)
    entities = read_rrd_entities(path)
    assert entities[f"/{RECTIFIED_ENTITY}/depth"] == 6
    assert entities[f"/{STEREO_ENTITY}/left/image"] == entities[f"/{STEREO_ENTITY}/right/image"] == 6
    assert entities[f"/{CLOUD_ENTITY}"] == 3
    assert entities[f"/{FUSED_MESH_ENTITY}"] == entities[f"/{FUSED_CLOUD_ENTITY}"] == 2  # at 0 and 0.5 s
    times = [t for t, _ in read_rrd_images(path, f"{STEREO_ENTITY}/left/image")]
    np.testing.assert_allclose(np.diff(times), IMAGE_PERIOD_S, atol=1e-6)
    depth_times = [t for t, _ in read_rrd_images(path, f"{RECTIFIED_ENTITY}/depth")]
    assert depth_times == times  # each depth image with the images it came from


def test_a_triangle_across_a_gap_is_not_drawn():
    grid = np.array([[x, y, 0.0] for y in range(3) for x in range(3)]) * 1e-3
    far = np.array([[0.0, 0.0, 0.05]])  # a point 5 cm behind the surface
    points = np.vstack([grid, far])
    triangles = np.array([[0, 1, 3], [1, 4, 3], [1, 2, 4], [2, 5, 4], [4, 5, 9]])
    np.testing.assert_array_equal(_short_triangles(points, triangles), triangles[:4])


def test_a_reconstruction_without_triangles_logs_its_cloud_but_no_empty_mesh(logged, tmp_path):
    """The rig's per-frame reconstruction meshes nothing (only the fused cloud is meshed): its cloud is
    drawn, and the per-frame mesh entity stays out of the recording instead of an empty mesh every frame."""
    import dataclasses

    _, _, _, _, inputs = logged
    frame, r, _, _ = inputs[0]
    bare = dataclasses.replace(r, triangles=np.zeros((0, 3), dtype=np.int32))
    path = tmp_path / "no_mesh.rrd"
    with RunRecording(path, recording_id="no-mesh") as rec:
        rec.log_stereo(frame.t_s, frame.left, frame.right, bare)
    entities = read_rrd_entities(path)
    assert entities[f"/{CLOUD_ENTITY}"] == 1 and f"/{MESH_ENTITY}" not in entities
