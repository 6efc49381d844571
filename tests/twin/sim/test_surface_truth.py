"""Scoring reconstructions against the twin's true foam surface: real MuJoCo, real EGL rendering."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from twin.sim.backend import SimBackend
from twin.sim.foam import get_object
from twin.sim.surface_truth import (
    SurfaceScorer,
    closest_points_on_triangles,
    coverage,
    point_mesh_distance,
    true_surface,
)
from twin.vision.reconstruct import ObjectTracker, Rectifier, default_matcher, reconstruct


@pytest.fixture(scope="module")
def sim():
    """The default block on the palm, settled for 0.1 s, the stereo pair connected, and a scorer."""
    backend = SimBackend(get_object("block"), stereo=True)
    backend.connect()
    mujoco.mj_forward(backend.world.model, backend.world.data)
    backend.world.advance_to(0.1)
    rectifier = Rectifier(backend.stereo.calibration())
    with SurfaceScorer(backend.world.model, backend.world.data, rectifier) as scorer:
        yield backend, rectifier, scorer
    backend.disconnect()


def _outward_normals(tri: np.ndarray) -> np.ndarray:
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    outward = np.einsum("ij,ij->i", n, tri.mean(axis=1) - tri.reshape(-1, 3).mean(axis=0)) > 0
    return np.where(outward[:, None], n, -n)


def _samples(tri: np.ndarray, per_triangle: int, rng: np.random.Generator, margin: float = 0.0):
    """Points on each triangle at random barycentric coordinates, each weight >= margin."""
    w = rng.dirichlet(np.ones(3), size=(len(tri), per_triangle))
    w = margin + (1 - 3 * margin) * w
    return np.einsum("tkj,tjd->tkd", w, tri).reshape(-1, 3), np.repeat(np.arange(len(tri)), per_triangle)


def test_true_surface_is_the_rendered_flex_in_the_hand_frame(sim):
    backend, _, scorer = sim
    model, data = backend.world.model, backend.world.data
    tri = scorer.surface()
    shell = int(model.flex_shellnum[0])
    assert tri.shape == (shell, 3, 3)  # 6 sides x 3x3 quads x 2 triangles for the 4x4x4 box
    np.testing.assert_allclose(true_surface(model, data), tri, atol=1e-6)
    # The palm is the world origin on the sim: the hand frame is the world frame.
    np.testing.assert_allclose(backend.hand_pose_in_world(), np.eye(4), atol=1e-12)
    # The rendered surface is the shell pushed out by the flex radius (1 mm) along the vertex normals.
    verts = np.asarray(data.flexvert_xpos)
    radius = float(model.flex_radius[0])
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    # Face-interior vertices move out by the whole radius (corners by radius / sqrt 3).
    np.testing.assert_allclose(tri.reshape(-1, 3).min(axis=0), lo - radius, atol=5e-5)
    np.testing.assert_allclose(tri.reshape(-1, 3).max(axis=0), hi + radius, atol=5e-5)
    d = point_mesh_distance(verts[np.any(np.isclose(verts, lo) | np.isclose(verts, hi), axis=1)], tri)
    assert (d > 0.3 * radius).all() and (d <= radius + 1e-9).all()


def test_exact_point_triangle_distance_against_dense_sampling():
    rng = np.random.default_rng(1)
    tri = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.2, 0.8, 0.1]])
    p = rng.uniform(-1.0, 2.0, (400, 3))  # in every Voronoi region: vertices, edges, face
    closest = closest_points_on_triangles(p, *(np.broadcast_to(v, p.shape) for v in tri))
    exact = np.linalg.norm(p - closest, axis=1)
    n = 100
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1))
    keep = i + j <= n
    w = np.stack([i[keep], j[keep]], axis=1) / n
    grid = tri[0] + w[:, :1] * (tri[1] - tri[0]) + w[:, 1:] * (tri[2] - tri[0])
    dense = np.linalg.norm(p[:, None] - grid[None], axis=2).min(axis=1)
    assert (exact <= dense + 1e-12).all()  # never above a point of the triangle...
    assert (dense - exact).max() < 1.0 / n  # ...and as close as the grid resolves
    # The closest points lie on the triangle's plane.
    normal = np.cross(tri[1] - tri[0], tri[2] - tri[0])
    np.testing.assert_allclose((closest - tri[0]) @ normal, 0.0, atol=1e-12)


def test_kdtree_pruning_is_exact(sim):
    tri = sim[2].surface()
    rng = np.random.default_rng(2)
    center = tri.reshape(-1, 3).mean(axis=0)
    p = center + rng.normal(0, 0.03, (500, 3))  # inside, on and around the foam
    brute = np.min(
        [
            np.linalg.norm(
                p - closest_points_on_triangles(p, *(np.broadcast_to(v, p.shape) for v in t)), axis=1
            )
            for t in tri
        ],
        axis=0,
    )
    for k in (1, 3, 8, len(tri)):  # k = 1 sends nearly every point to the exhaustive fallback
        np.testing.assert_allclose(point_mesh_distance(p, tri, k=k), brute, atol=1e-12)


def test_points_on_the_surface_score_zero_and_offset_points_their_offset(sim):
    _, _, scorer = sim
    tri = scorer.surface()
    rng = np.random.default_rng(3)
    points, which = _samples(tri, 20, rng, margin=0.1)
    on = scorer.score(points_hand=points)
    assert on.n_points == len(points)
    assert on.median_mm < 1e-9 and on.p90_mm < 1e-9
    outward = points + 0.002 * _outward_normals(tri)[which]
    off = scorer.score(points_hand=outward)
    # Outward along the normal of a convex surface the nearest point is where the point came from:
    # 2 mm (less only near a crease of the radius offset).
    assert off.median_mm == pytest.approx(2.0, abs=1e-6)
    dist_mm = 1e3 * point_mesh_distance(outward, tri)
    assert dist_mm.max() <= 2.0 + 1e-9 and np.mean(dist_mm > 1.99) > 0.9


def test_coverage_counts_visible_pixels_holding_a_point(sim):
    _, _, scorer = sim
    visible = scorer.visible_mask()
    rows, cols = np.nonzero(visible)
    assert len(rows) > 3000  # the whole top of the block, ~6300 px at 320x240
    pixels = np.stack([rows, cols], axis=1)
    perfect = scorer.score(points_hand=np.zeros((0, 3)), pixels=pixels)
    assert perfect.coverage == 1.0 and perfect.visible_px == len(rows)
    assert np.isnan(perfect.median_mm) and perfect.n_points == 0
    left_half = pixels[cols < np.median(cols)]
    assert coverage(left_half, visible)[0] == pytest.approx(0.5, abs=0.02)
    # Repeated pixels count once; pixels off the foam do not count, and show as outside_fraction.
    background = np.argwhere(~visible)[: len(left_half)]
    cov, outside = coverage(np.concatenate([left_half, left_half, background]), visible)
    assert cov == pytest.approx(len(left_half) / len(rows))
    assert outside == pytest.approx(1 / 3)
    # Rectifying turns each toed-in view by 15 degrees, which magnifies the foam by ~10 %.
    assert visible.sum() == pytest.approx(scorer.visible_mask(rectified=False).sum(), rel=0.15)


def test_a_real_reconstruction_of_the_block_at_rest(sim):
    backend, rectifier, scorer = sim
    frame = backend.stereo.read()
    left_rect, _ = rectifier.rectify(frame.left, frame.right)
    tracker = ObjectTracker(left_rect, backend.object_box(rectifier))
    rec = reconstruct(frame.left, frame.right, rectifier, tracker, matcher=default_matcher(rectifier))
    score = scorer.score(rec)
    # Measured (SGBM, the default matcher): median 0.25 mm, p90 3.2 mm (its smoothing rounds the block's
    # edges against the palm), coverage 0.97, 3 % of the points off the foam.
    assert score.n_points == len(rec.points_hand) > 3000
    assert score.median_mm < 0.5 and score.p90_mm < 4.0
    assert score.coverage > 0.8 and score.outside_fraction < 0.1
    assert score.visible_px == scorer.visible_mask().sum()
    assert score.cost_ms > 0
