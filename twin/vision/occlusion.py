"""Points a known occluder hides: the fingers, as boxes from the hand's kinematics (backend-free).

A stereo point inside a finger's silhouette took the finger's disparity (or lies behind it): the ray
from the left camera to the point enters one of the fingers' boxes before reaching the point. The
test is the slab method (Kay & Kajiya) on every point x every box, vectorized; the boxes are inflated
by a margin, since a matching window centred that close to a finger's edge straddles it.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

BOX_CORNER_SIGNS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
"""A box's 8 corners as signs of its half sizes: index 4 sx + 2 sy + sz with the bits for + signs."""


def box_corners(
    centre: NDArray[np.float64], rotation: NDArray[np.float64], half_m: NDArray[np.float64]
) -> NDArray[np.float64]:
    """(8, 3) corners of a box (centre, 3x3 rotation whose columns are its axes, half sizes)."""
    return (BOX_CORNER_SIGNS * half_m) @ np.asarray(rotation).T + centre


def hidden_by_box(
    points: NDArray[np.float64],
    eye: NDArray[np.float64],
    corners: NDArray[np.float64],
    margin_m: float = 0.001,
) -> NDArray[np.bool_]:
    """(N,) which points one box hides from `eye` (all in one frame): the segment eye -> point meets
    the box (grown by `margin_m`) before the point, or the point lies inside it.

    `corners`: (8, 3) in BOX_CORNER_SIGNS order (box_corners).
    """
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    corners = np.asarray(corners, dtype=float).reshape(8, 3)
    edges = np.stack([corners[4] - corners[0], corners[2] - corners[0], corners[1] - corners[0]], axis=1)
    length = np.linalg.norm(edges, axis=0)  # full edge lengths
    axes = edges / np.maximum(length, 1e-12)  # columns: the box's unit axes
    half = length / 2 + margin_m
    origin = (eye - corners.mean(axis=0)) @ axes  # the eye in box coordinates
    d = (points - eye) @ axes  # the segment (t in [0, 1]) in box coordinates
    inside_slab = np.abs(origin) <= half  # where a segment parallel to a slab stays
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-half - origin) / d
        t2 = (half - origin) / d
    parallel = d == 0
    lo = np.where(parallel, np.where(inside_slab, -np.inf, np.inf), np.minimum(t1, t2))
    hi = np.where(parallel, np.where(inside_slab, np.inf, -np.inf), np.maximum(t1, t2))
    t_in, t_out = lo.max(axis=1), hi.min(axis=1)
    return (t_in <= t_out) & (t_out >= 0.0) & (t_in <= 1.0)


def hidden_by_boxes(
    points: NDArray[np.float64],
    eye: NDArray[np.float64],
    corners: NDArray[np.float64],
    margin_m: float = 0.001,
    *,
    pixels_xy: NDArray | None = None,
    image_from_frame: NDArray[np.float64] | None = None,
) -> NDArray[np.bool_]:
    """(N,) which points any of the (G, 8, 3) boxes hides from `eye` (hidden_by_box for each).

    With the points' image pixels (`pixels_xy`, (N, 2) x, y) and the 3x4 projection of the frame into
    that image (`image_from_frame`, the camera at `eye`), only the points inside each box's projected
    bounding rectangle are tested: a box can hide nothing outside its own image.
    """
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    hidden = np.zeros(len(points), dtype=bool)
    corners = np.asarray(corners, dtype=float).reshape(-1, 8, 3)
    for box in corners:
        candidates = slice(None)
        if pixels_xy is not None and image_from_frame is not None:
            uvw = np.column_stack([box, np.ones(8)]) @ np.asarray(image_from_frame).T
            if (uvw[:, 2] > 1e-6).all():  # wholly in front of the camera: its image is bounded
                uv = uvw[:, :2] / uvw[:, 2:]
                (x0, y0), (x1, y1) = uv.min(axis=0) - 2.0, uv.max(axis=0) + 2.0  # the margin, in px
                candidates = np.flatnonzero(
                    (pixels_xy[:, 0] >= x0)
                    & (pixels_xy[:, 0] <= x1)
                    & (pixels_xy[:, 1] >= y0)
                    & (pixels_xy[:, 1] <= y1)
                )
                if not len(candidates):
                    continue
        hidden[candidates] |= hidden_by_box(points[candidates], eye, box, margin_m)
    return hidden
