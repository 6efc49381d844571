"""The fused 3-D surface as a fixed-size point set: heights on a fixed grid of the hand frame.

The cameras look down on the palm-up hand, so the fused cloud (twin.vision.fusion: the stereo points
plus the pressed taxels) is a 2.5-D surface seen from above. A height map is its natural fixed-size
form: a grid of G x G cells in the hand frame's x-y plane, and in each cell the height (z) of the top
of the cloud's points that fall in it (their 90th percentile: robust to a stray point). The top, not
the median: a cell at the object's edge also holds points of its side walls, and the pads' contact
points lie on the sides, below the top (on a squeezed block, median: 1.4 mm mean error against the
true top, 90th percentile: 0.38 mm). The point set is then the cells' centres (x, y), fixed, with
their heights z: G^2 outputs for a network on the same 6 inputs as the contour's.

The grid is laid once per trajectory on its first cloud (the object at rest, before the fingers
close): centred on the cloud's median x-y, square, its half-width the larger of the cloud's x and y
half-extents (2nd to 98th percentile) plus a margin. The same rule works on a recorded hardware run.
Cells with no point (hidden by the fingers, or off the object) are NaN: unobserved, not zero.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from twin.interface.errors import ConfigError

GRID_CELLS = 10
"""Cells per side: 100 heights. On the 55 mm block a cell is ~6 mm, about 8 camera pixels and a
dozen fused points at the pipeline's mesh stride."""
MARGIN_MM = 2.0
MIN_POINTS = 3
"""A cell's height needs this many points (one or two stray points are not a surface)."""
TOP_PERCENTILE = 90.0
"""A cell's height: this percentile of its points' z."""


@dataclass(frozen=True)
class SurfaceGrid:
    """A square grid in the hand frame's x-y plane."""

    centre_mm: tuple[float, float]
    half_width_mm: float
    cells: int = GRID_CELLS

    @property
    def cell_mm(self) -> float:
        """Cell side (mm)."""
        return 2 * self.half_width_mm / self.cells

    def centres_mm(self) -> NDArray[np.float64]:
        """(cells^2, 2) x-y of the cell centres (mm), row by row (y outer, x inner)."""
        offsets = -self.half_width_mm + (np.arange(self.cells) + 0.5) * self.cell_mm
        x, y = np.meshgrid(self.centre_mm[0] + offsets, self.centre_mm[1] + offsets)
        return np.column_stack([x.ravel(), y.ravel()])

    def cell_index(self, xy_mm: NDArray[np.float64]) -> NDArray[np.intp]:
        """Flat cell index of each x-y point (mm); -1 outside the grid."""
        xy = np.asarray(xy_mm, dtype=np.float64).reshape(-1, 2)
        ij = np.floor((xy - np.asarray(self.centre_mm) + self.half_width_mm) / self.cell_mm).astype(np.intp)
        inside = ((ij >= 0) & (ij < self.cells)).all(axis=1)
        return np.where(inside, ij[:, 1] * self.cells + ij[:, 0], -1)


def grid_from_cloud(
    points_hand_m: NDArray[np.float64], cells: int = GRID_CELLS, margin_mm: float = MARGIN_MM
) -> SurfaceGrid:
    """The grid laid on a cloud of the object at rest (hand frame, metres)."""
    xy = 1e3 * np.asarray(points_hand_m, dtype=np.float64).reshape(-1, 3)[:, :2]
    if len(xy) < 10:
        raise ConfigError(f"the first cloud holds {len(xy)} points: too few to lay the surface grid on")
    centre = np.median(xy, axis=0)
    lo, hi = np.percentile(xy, [2, 98], axis=0)
    half = float(np.max(np.maximum(hi - centre, centre - lo))) + margin_mm
    return SurfaceGrid((float(centre[0]), float(centre[1])), half, cells)


def height_map(
    points_hand_m: NDArray[np.float64], grid: SurfaceGrid, min_points: int = MIN_POINTS
) -> NDArray[np.float64]:
    """(cells^2,) the top (TOP_PERCENTILE of z, mm, hand frame) of the points in each cell; NaN where
    fewer than `min_points` fall."""
    p = 1e3 * np.asarray(points_hand_m, dtype=np.float64).reshape(-1, 3)
    out = np.full(grid.cells**2, np.nan)
    idx = grid.cell_index(p[:, :2])
    keep = idx >= 0
    idx, z = idx[keep], p[keep, 2]
    order = np.argsort(idx, kind="stable")
    idx, z = idx[order], z[order]
    cells, starts, counts = np.unique(idx, return_index=True, return_counts=True)
    for c, s, n in zip(cells, starts, counts, strict=True):
        if n >= min_points:
            out[c] = np.percentile(z[s : s + n], TOP_PERCENTILE)
    return out


def surface_points_mm(heights_mm: NDArray[np.float64], grid: SurfaceGrid) -> NDArray[np.float64]:
    """(..., cells^2, 3) the point set: the cell centres with their heights (NaN heights stay NaN)."""
    h = np.asarray(heights_mm, dtype=np.float64)
    xy = np.broadcast_to(grid.centres_mm(), (*h.shape, 2))
    return np.concatenate([xy, h[..., None]], axis=-1)


def mesh_heights(triangles_hand_m: NDArray[np.float64], grid: SurfaceGrid) -> NDArray[np.float64]:
    """(cells^2,) the highest z (mm) of a triangle mesh (T, 3, 3; hand frame, metres) straight above or
    below each cell centre; NaN where no triangle covers it. On the twin, the true surface's height map
    (what a perfect top-down camera would see with no fingers in the way)."""
    tri = 1e3 * np.asarray(triangles_hand_m, dtype=np.float64).reshape(-1, 3, 3)
    q = grid.centres_mm()
    out = np.full(len(q), np.nan)
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    det = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
    ok = np.abs(det) > 1e-12  # triangles seen edge-on from above cover no area
    a, b, c, det = a[ok], b[ok], c[ok], det[ok]
    for i, (x, y) in enumerate(q):
        # barycentric coordinates of (x, y) in every triangle's x-y projection
        l1 = ((b[:, 1] - c[:, 1]) * (x - c[:, 0]) + (c[:, 0] - b[:, 0]) * (y - c[:, 1])) / det
        l2 = ((c[:, 1] - a[:, 1]) * (x - c[:, 0]) + (a[:, 0] - c[:, 0]) * (y - c[:, 1])) / det
        l3 = 1 - l1 - l2
        inside = (l1 >= 0) & (l2 >= 0) & (l3 >= 0)
        if inside.any():
            z = l1[inside] * a[inside, 2] + l2[inside] * b[inside, 2] + l3[inside] * c[inside, 2]
            out[i] = z.max()
    return out
