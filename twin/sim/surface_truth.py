"""Scoring a stereo reconstruction against what the twin knows: the foam's true surface (sim only).

The science modules (twin.vision) never import this; tests, benchmarks and experiments do.

Truth
    The foam's surface as MuJoCo renders it: the triangles `mjv_updateScene` puts in the scene for the
    flex (`MjvScene.flexface`), taken to the hand frame (the palm body's frame). For a volumetric flex
    these are the shell faces of `data.flexvert_xpos` pushed out by the flex radius along the vertex
    normals (0.4-1 mm for the default radius of 1 mm): the cameras see that surface, not the bare shell.

Scores (`SurfaceScore`)
    * distance: for every reconstructed point, its exact Euclidean distance to the nearest point of the
      true triangle mesh (point-to-triangle, not point-to-vertex); median and 90th percentile in mm.
    * coverage: let V be the set of pixels of the *rectified* left view that show the foam, obtained by
      rendering MuJoCo's segmentation of the left camera at the calibration's image size (MuJoCo labels
      flex pixels with objtype mjOBJ_FLEX and the flex id; occlusion by the fingers is included) and
      warping it with `Rectifier.remap(..., 'left', cv2.INTER_NEAREST)`. Let P be the set of distinct
      pixels `Reconstruction.pixels` (one reconstructed point each). coverage = |P ∩ V| / |V|: the
      fraction of the foam's visible pixels that hold a reconstructed point. Points outside V (on the
      fingers, the palm, the background) do not count towards coverage; their share is
      `outside_fraction`. The segmentation is rendered at the processed size directly: a pixel is in V
      when its centre sees the foam (no anti-aliasing), and the rectifying remap re-samples it once
      more; the outline pixels, where that decides, are ~5 % of V for the block at rest (340 of 6348).

Cost (`SurfaceScorer.score`, 2-core CPU, EGL): ~3 ms for the segmentation render and remap, plus the
distances, ~11 ms for 6000 points (the block at rest) and ~4 ms for the ~1000 points of a squeezed
block seen between the fingers; ~15 ms a frame at rest, ~7 ms squeezed.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import mujoco
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from twin.rendering import renderer
from twin.sim.cameras import FOAM_NAME, HAND_BODY, LEFT_CAMERA
from twin.vision.reconstruct import Reconstruction, Rectifier

_FLEX = int(mujoco.mjtObj.mjOBJ_FLEX)


@dataclass(frozen=True)
class SurfaceScore:
    """A reconstruction scored against the true foam surface."""

    median_mm: float
    """Median exact point-to-mesh distance of the reconstructed points (NaN without points)."""
    p90_mm: float
    """90th percentile of the same distances."""
    coverage: float
    """Fraction of the foam's visible (rectified left) pixels holding a reconstructed point, in [0, 1]."""
    n_points: int
    """Reconstructed points scored."""
    visible_px: int
    """Pixels of the rectified left view that show the foam."""
    outside_fraction: float = 0.0
    """Share of the reconstructed points whose pixel does not show the foam (fingers, palm, background)."""
    cost_ms: float = 0.0
    """What scoring this frame cost (render + distances + coverage)."""
    point_error_mm: NDArray[np.float64] | None = None
    """Each reconstructed point's distance to the true surface, in the points' order (for colouring)."""


# ------------------------------------------------------------------------------ the true surface
def _flex_id(model: mujoco.MjModel, name: str) -> int:
    f = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_FLEX, name)
    if f < 0:
        raise KeyError(f"no flex named {name!r} in the model")
    return int(f)


def pose(model: mujoco.MjModel, data: mujoco.MjData, body: str = HAND_BODY) -> NDArray[np.float64]:
    """4x4 world pose of a body now (forward kinematics must have run)."""
    b = model.body(body).id
    t = np.eye(4)
    t[:3, :3] = np.asarray(data.xmat[b]).reshape(3, 3)
    t[:3, 3] = data.xpos[b]
    return t


def rendered_flex_triangles(scene: mujoco.MjvScene, flex: int = 0) -> NDArray[np.float64]:
    """(T, 3, 3) world-frame triangles of flex `flex` as the last mjv_updateScene left them."""
    adr, used = int(scene.flexfaceadr[flex]), int(scene.flexfaceused[flex])
    faces = np.asarray(scene.flexface[9 * adr : 9 * (adr + used)], dtype=np.float64)
    return faces.reshape(-1, 3, 3)


def true_surface(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    *,
    flex: str = FOAM_NAME,
    hand_from_world: ArrayLike | None = None,
    scene: mujoco.MjvScene | None = None,
) -> NDArray[np.float64]:
    """(T, 3, 3) triangles of the flex's outer surface as MuJoCo renders it, in the hand (palm) frame.

    The state is taken as it is (as the cameras render it): run mj_forward on a world never stepped.
    Needs no GL context (mjv_updateScene only). `hand_from_world` defaults to the palm body's pose now;
    pass `scene` to reuse an MjvScene between calls.
    """
    f = _flex_id(model, flex)
    if scene is None:
        scene = mujoco.MjvScene(model, maxgeom=max(1000, 2 * model.ngeom))
    option, camera = mujoco.MjvOption(), mujoco.MjvCamera()
    mujoco.mjv_updateScene(model, data, option, None, camera, int(mujoco.mjtCatBit.mjCAT_ALL), scene)
    tri = rendered_flex_triangles(scene, f)
    t = np.linalg.inv(pose(model, data)) if hand_from_world is None else np.asarray(hand_from_world, float)
    return tri @ t[:3, :3].T + t[:3, 3]


# --------------------------------------------------------------------------- exact distances
def closest_points_on_triangles(p: NDArray, a: NDArray, b: NDArray, c: NDArray) -> NDArray[np.float64]:
    """(N, 3) closest point of triangle (a[i], b[i], c[i]) to p[i], all (N, 3); exact, vectorised.

    Ericson, Real-Time Collision Detection §5.1.5: the Voronoi region of p (vertex, edge or face) picks
    the closest feature. Degenerate triangles fall back to their vertices/edges through the region tests.
    """
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = _dot(ab, ap), _dot(ac, ap)
    bp = p - b
    d3, d4 = _dot(ab, bp), _dot(ac, bp)
    cp = p - c
    d5, d6 = _dot(ab, cp), _dot(ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        # Face interior by default.
        denom = va + vb + vc
        v = vb / denom
        w = vc / denom
        out = a + ab * v[:, None] + ac * w[:, None]
        # Edge BC.
        w_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        on_bc = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
        out = np.where(on_bc[:, None], b + (c - b) * w_bc[:, None], out)
        # Edge AC.
        w_ac = d2 / (d2 - d6)
        on_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        out = np.where(on_ac[:, None], a + ac * w_ac[:, None], out)
        # Edge AB.
        v_ab = d1 / (d1 - d3)
        on_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        out = np.where(on_ab[:, None], a + ab * v_ab[:, None], out)
    # Vertices (checked last: they take precedence over the edges, as in Ericson's early returns).
    out = np.where(((d6 >= 0) & (d5 <= d6))[:, None], c, out)
    out = np.where(((d3 >= 0) & (d4 <= d3))[:, None], b, out)
    out = np.where(((d1 <= 0) & (d2 <= 0))[:, None], a, out)
    return out


def _dot(u: NDArray, v: NDArray) -> NDArray:
    return np.einsum("ij,ij->i", u, v)


def point_mesh_distance(points: ArrayLike, triangles: ArrayLike, k: int = 8) -> NDArray[np.float64]:
    """(N,) exact distance of each point to the nearest point of a triangle soup (T, 3, 3), same units.

    A cKDTree over the triangles' centroids picks the candidates: every point of triangle t lies within
    R (the largest centroid-to-vertex radius) of its centroid c_t. Exact distances to the `k` nearest
    centroids' triangles settle a point when their minimum is <= d_k - R (d_k: the k-th centroid
    distance), since no other triangle can come closer; the few points left over are measured against
    every triangle whose centroid lies within (nearest centroid distance) + R, which is exact too.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    tri = np.asarray(triangles, dtype=np.float64).reshape(-1, 3, 3)
    if len(p) == 0:
        return np.zeros(0)
    if len(tri) == 0:
        raise ValueError("no triangles to measure against")
    centroids = tri.mean(axis=1)
    radius = float(np.linalg.norm(tri - centroids[:, None], axis=2).max())
    tree = cKDTree(centroids)
    k = min(k, len(tri))
    dk, ik = tree.query(p, k=k)
    dk, ik = dk.reshape(len(p), k), ik.reshape(len(p), k)
    best = _pair_distances(p, tri, np.repeat(np.arange(len(p)), k), ik.reshape(-1)).reshape(-1, k).min(axis=1)
    open_ = np.flatnonzero(best > dk[:, -1] - radius) if k < len(tri) else np.zeros(0, dtype=np.intp)
    if len(open_):
        candidates = tree.query_ball_point(p[open_], dk[open_, 0] + radius + 1e-12)
        counts = np.fromiter((len(c) for c in candidates), dtype=np.intp, count=len(open_))
        pi = np.repeat(open_, counts)
        ti = np.fromiter((t for c in candidates for t in c), dtype=np.intp, count=int(counts.sum()))
        np.minimum.at(best, pi, _pair_distances(p, tri, pi, ti))
    return best


def _pair_distances(p: NDArray, tri: NDArray, pi: NDArray, ti: NDArray) -> NDArray[np.float64]:
    """Exact distances of points p[pi] to triangles tri[ti]."""
    closest = closest_points_on_triangles(p[pi], tri[ti, 0], tri[ti, 1], tri[ti, 2])
    return np.linalg.norm(p[pi] - closest, axis=1)


def coverage(pixels: ArrayLike, visible: NDArray[np.bool_]) -> tuple[float, float]:
    """(coverage, outside_fraction) of reconstructed pixels (N, 2) (row, col) against a visible mask.

    coverage = distinct reconstructed pixels inside `visible` / pixels of `visible` (0 when nothing is
    visible); outside_fraction = share of the N points whose pixel is not in `visible`.
    """
    px = np.asarray(pixels, dtype=np.intp).reshape(-1, 2)
    h, w = visible.shape
    ok = (px[:, 0] >= 0) & (px[:, 0] < h) & (px[:, 1] >= 0) & (px[:, 1] < w)
    hit = np.zeros_like(visible, dtype=bool)
    hit[px[ok, 0], px[ok, 1]] = True
    inside = hit & visible
    n_visible = int(visible.sum())
    cov = float(inside.sum()) / n_visible if n_visible else 0.0
    on_object = np.zeros(len(px), dtype=bool)
    on_object[ok] = visible[px[ok, 0], px[ok, 1]]
    outside = float(1.0 - on_object.mean()) if len(px) else 0.0
    return cov, outside


# ------------------------------------------------------------------------------------ the scorer
@dataclass(frozen=True)
class SurfaceTruth:
    """What the twin knows of one instant: the foam's visible pixels and its true surface."""

    visible: NDArray[np.bool_]
    """(H, W) rectified left pixels that show the foam."""
    triangles: NDArray[np.float64]
    """(T, 3, 3) the rendered foam surface, hand frame."""


def score_against(
    truth: SurfaceTruth, points_hand: ArrayLike, pixels: ArrayLike, cost_from: float | None = None
) -> SurfaceScore:
    """Score points (hand frame) and their rectified left pixels against a snapshot of the truth
    (pure numpy: may run on a worker thread after the world moved on)."""
    t0 = time.perf_counter() if cost_from is None else cost_from
    points = np.asarray(points_hand, float).reshape(-1, 3)
    px = np.asarray(pixels).reshape(-1, 2)
    dist_mm = 1e3 * point_mesh_distance(points, truth.triangles)
    cov, outside = coverage(px, truth.visible)
    median, p90 = (
        (float(np.median(dist_mm)), float(np.percentile(dist_mm, 90))) if len(dist_mm) else (np.nan,) * 2
    )
    return SurfaceScore(
        median_mm=median,
        p90_mm=p90,
        coverage=cov,
        n_points=len(points),
        visible_px=int(truth.visible.sum()),
        outside_fraction=outside if len(px) else 0.0,
        cost_ms=1e3 * (time.perf_counter() - t0),
        point_error_mm=dist_mm,
    )


class SurfaceScorer:
    """Scores reconstructions of one sim world's foam, frame after frame; keeps its renderer.

    Per call: one segmentation render of the left camera at the calibration's size, one
    mjv_updateScene of the same renderer's scene (the true surface), the distances and the coverage.
    `hand_from_world` defaults to the inverse of the palm body's pose at each call. The world's state is
    scored as it is, exactly as SimStereo renders it (positions of the last mj_step's forward pass; run
    mj_forward on a world never stepped): score a reconstruction before stepping the world past the
    frame it came from.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        data: mujoco.MjData,
        rectifier: Rectifier,
        *,
        flex: str = FOAM_NAME,
        camera: str = LEFT_CAMERA,
        hand_from_world: ArrayLike | None = None,
    ) -> None:
        self.model, self.data, self.rectifier, self.camera = model, data, rectifier, camera
        self.flex_id = _flex_id(model, flex)
        self.hand_from_world = None if hand_from_world is None else np.asarray(hand_from_world, float)
        w, h = rectifier.image_size
        self._renderer: mujoco.Renderer | None = renderer(model, height=h, width=w)
        self._renderer.enable_segmentation_rendering()

    def close(self) -> None:
        """Free the GL context; safe to call twice."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __enter__(self) -> SurfaceScorer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _render(self) -> None:
        if self._renderer is None:
            raise RuntimeError("SurfaceScorer is closed")
        self._renderer.update_scene(self.data, camera=self.camera)

    def _hand_from_world(self) -> NDArray[np.float64]:
        if self.hand_from_world is not None:
            return self.hand_from_world
        return np.linalg.inv(pose(self.model, self.data))

    def visible_mask(self, rectified: bool = True) -> NDArray[np.bool_]:
        """The pixels of the left view that show the foam now (in the rectified view by default)."""
        self._render()
        return self._visible(rectified)

    def _visible(self, rectified: bool) -> NDArray[np.bool_]:
        assert self._renderer is not None
        seg = self._renderer.render()
        mask = ((seg[..., 1] == _FLEX) & (seg[..., 0] == self.flex_id)).astype(np.uint8)
        if rectified:
            mask = self.rectifier.remap(mask, "left", cv2.INTER_NEAREST)
        return mask.astype(bool)

    def surface(self) -> NDArray[np.float64]:
        """(T, 3, 3) the true rendered foam surface now, hand frame."""
        self._render()
        return self._surface()

    def _surface(self) -> NDArray[np.float64]:
        assert self._renderer is not None
        tri = rendered_flex_triangles(self._renderer.scene, self.flex_id)
        t = self._hand_from_world()
        return tri @ t[:3, :3].T + t[:3, 3]

    def score(
        self,
        reconstruction: Reconstruction | None = None,
        *,
        points_hand: ArrayLike | None = None,
        pixels: ArrayLike | None = None,
    ) -> SurfaceScore:
        """Score a reconstruction of the world's present state (or explicit points and pixels)."""
        t0 = time.perf_counter()
        if reconstruction is not None:
            points_hand, pixels = reconstruction.points_hand, reconstruction.pixels
        points = np.zeros((0, 3)) if points_hand is None else points_hand
        px = np.zeros((0, 2), dtype=np.intp) if pixels is None else pixels
        return score_against(self.snapshot(), points, px, cost_from=t0)

    def snapshot(self) -> SurfaceTruth:
        """The truth of the world's present state, to score a reconstruction of it later."""
        self._render()
        return SurfaceTruth(self._visible(rectified=True), self._surface())
