"""Tactile fill-in (paper §5): the pads' contact points complete the surface where fingers hide it.

The cameras cannot see the object where a finger touches it; the pads can. Each pressed taxel
(pressure above the eq. 6 activity threshold) is a point of the object's surface, at the taxel's
centre on the pad face, placed in the hand frame by the hand's kinematics (twin.kinematics). The
fused cloud is the visual cloud plus these points; the fused mesh is a Delaunay triangulation of all
of them as seen from the left camera (the cloud is a 2.5-D surface from that view), with the long
edges across holes and depth jumps removed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import Delaunay, QhullError

from twin.tactile.calibration import ACTIVE_THRESHOLD_KPA

VISION, TACTILE = 0, 1
"""Where a fused point came from (the `point_source` of a recorded surface)."""


@dataclass(frozen=True)
class FusedSurface:
    """The surface a run stores: points in the hand frame, their source and a triangle mesh."""

    points_hand: NDArray[np.float32]
    """(N, 3) metres, hand frame."""
    source: NDArray[np.uint8]
    """(N,) VISION or TACTILE."""
    triangles: NDArray[np.int32]
    """(M, 3) indices into points_hand."""


def pressed_taxels(
    pressure_kpa: NDArray[np.float64],
    taxels_hand: NDArray[np.float64],
    threshold_kpa: float = ACTIVE_THRESHOLD_KPA,
) -> NDArray[np.float64]:
    """(k, 3) hand-frame centres of the taxels pressed above `threshold_kpa`."""
    return taxels_hand[np.asarray(pressure_kpa) > threshold_kpa]


def fuse(
    vision_points_hand: NDArray[np.float64],
    tactile_points_hand: NDArray[np.float64],
    image_from_hand: NDArray[np.float64],
    *,
    max_edge_m: float = 0.016,
    max_tactile_edge_m: float = 0.02,
) -> FusedSurface:
    """One cloud and one mesh from the visual points and the pressed taxels.

    `image_from_hand`: the 3x4 projection of hand-frame points into the (rectified left) image in
    which the mesh is triangulated. Triangles are dropped when an edge between two visual points
    exceeds `max_edge_m`, or an edge that reaches a taxel exceeds `max_tactile_edge_m` (taxels sit
    6 mm apart, and the finger hides the few millimetres between them and the visible surface).
    """
    vision = np.asarray(vision_points_hand, dtype=np.float64).reshape(-1, 3)
    tactile = np.asarray(tactile_points_hand, dtype=np.float64).reshape(-1, 3)
    points = np.concatenate([vision, tactile])
    source = np.concatenate([np.full(len(vision), VISION), np.full(len(tactile), TACTILE)]).astype(np.uint8)
    triangles = np.zeros((0, 3), dtype=np.int32)
    if len(points) >= 3:
        uvw = np.column_stack([points, np.ones(len(points))]) @ np.asarray(image_from_hand).T
        in_front = uvw[:, 2] > 1e-9
        uv = uvw[:, :2] / np.where(in_front, uvw[:, 2], 1.0)[:, None]
        # A fixed sub-pixel jitter breaks qhull's ties on the pixel grid (as twin.vision.reconstruct).
        uv += np.random.default_rng(0).uniform(-1e-3, 1e-3, uv.shape)
        try:
            simplices = Delaunay(uv).simplices
        except (QhullError, ValueError):  # all points on a line, or too few distinct ones
            simplices = np.zeros((0, 3), dtype=np.intp)
        corners = points[simplices]
        edges = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2)
        touches_tactile = (source[simplices] == TACTILE).any(axis=1)
        limit = np.where(touches_tactile, max_tactile_edge_m, max_edge_m)
        doubled_area = np.linalg.norm(
            np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1
        )
        flat = doubled_area <= 1e-3 * edges.max(axis=1) ** 2  # slivers of (nearly) collinear points
        keep = (edges.max(axis=1) <= limit) & in_front[simplices].all(axis=1) & ~flat
        triangles = simplices[keep].astype(np.int32)
    return FusedSurface(points.astype(np.float32), source, triangles)
