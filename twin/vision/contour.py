"""The object's outer contour in a camera image, as the shape network's target (paper §7).

The same code for sim and hardware frames: the object is segmented in the rectified left view by the
tracker's normalized-RGB histogram back-projection (twin.vision.reconstruct.ObjectTracker), its outer
boundary taken with cv2.findContours, and resampled to n points equally spaced in arc length, starting
from a stable anchor (where the ray from the contour's centroid straight up the image, -v, crosses it)
and running counter-clockwise on screen. Fixed n and anchor make contours comparable sample by sample,
which is what a network regressing 2n outputs needs.

In the hand frame, each contour pixel's ray from the rectified left camera is cut with a plane
parallel to the palm (the silhouette of a top-down view lies near the object's widest section).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from twin.interface.errors import TwinError
from twin.vision.reconstruct import ObjectTracker, Rectifier

DEFAULT_POINTS = 32
SMOOTHING_PX = 2.0
"""Gaussian sigma (boundary pixels) applied along the closed boundary before resampling: a pixel
staircase is ~5 % longer than the curve it samples, and that slack would shift points along it."""


class ContourError(TwinError, ValueError):
    """No usable contour (empty mask, or a blob too small to resample)."""


def outer_contour(mask: NDArray[np.bool_]) -> NDArray[np.float64]:
    """(m, 2) pixel coordinates (u, v) of the largest blob's outer boundary, as cv2.findContours walks it."""
    binary = np.ascontiguousarray(mask, dtype=np.uint8)
    contours, _ = cv2.findContours(binary, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        raise ContourError("the object mask is empty: no contour")
    largest = max(contours, key=cv2.contourArea)
    if len(largest) < 8 or cv2.contourArea(largest) < 16:
        raise ContourError(f"the object's blob is too small for a contour ({len(largest)} boundary pixels)")
    return _smooth_closed(largest[:, 0, :].astype(np.float64), SMOOTHING_PX)


def _smooth_closed(points: NDArray[np.float64], sigma: float) -> NDArray[np.float64]:
    """A closed polyline's coordinates convolved with a Gaussian along it (wrapping around)."""
    half = min(int(4 * sigma + 0.5), (len(points) - 1) // 2)
    k = np.exp(-0.5 * (np.arange(-half, half + 1) / sigma) ** 2)
    k /= k.sum()
    padded = np.vstack([points[-half:], points, points[:half]]) if half else points
    return np.column_stack([np.convolve(padded[:, j], k, mode="valid") for j in range(2)])


def resample(contour_px: NDArray[np.float64], n: int = DEFAULT_POINTS) -> NDArray[np.float64]:
    """(n, 2) points equally spaced in arc length along the closed contour, from the anchor, counter-
    clockwise on screen (v down)."""
    pts = np.asarray(contour_px, dtype=np.float64)
    if n < 3:
        raise ContourError(f"a contour needs >= 3 points, got n = {n}")
    u, v = pts[:, 0], pts[:, 1]
    signed_area = 0.5 * np.sum(u * np.roll(v, -1) - np.roll(u, -1) * v)  # > 0: clockwise on screen
    if signed_area > 0:
        pts = pts[::-1]
    closed = np.vstack([pts, pts[:1]])
    seg = np.linalg.norm(np.diff(closed, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    anchor_s = _anchor_arc(closed, arc)
    s = (anchor_s + np.arange(n) * arc[-1] / n) % arc[-1]
    return np.column_stack([np.interp(s, arc, closed[:, 0]), np.interp(s, arc, closed[:, 1])])


def _anchor_arc(closed: NDArray[np.float64], arc: NDArray[np.float64]) -> float:
    """Arc length where the upward ray from the area centroid leaves the contour (the topmost crossing)."""
    m = cv2.moments(closed[:-1].astype(np.float32))
    cu = m["m10"] / m["m00"] if m["m00"] else closed[:-1, 0].mean()
    best_v, best_s = np.inf, 0.0
    for i in range(len(closed) - 1):
        (u0, v0), (u1, v1) = closed[i], closed[i + 1]
        if (u0 - cu) * (u1 - cu) > 0 or (u0 == u1 and u0 != cu):
            continue
        f = 0.0 if u1 == u0 else (cu - u0) / (u1 - u0)
        v = v0 + f * (v1 - v0)
        if v < best_v:
            best_v, best_s = v, arc[i] + f * (arc[i + 1] - arc[i])
    return best_s


def contour_error_px(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    """Mean distance (px) between two resampled contours, point by point (same n, same anchor)."""
    return float(np.mean(np.linalg.norm(np.asarray(a) - np.asarray(b), axis=1)))


def to_hand_plane(
    contour_px: NDArray[np.float64], rectifier: Rectifier, plane_z_m: float
) -> NDArray[np.float64]:
    """(n, 3) hand-frame points (m) where the rectified-left rays through the pixels meet the plane
    z = plane_z_m of the hand frame (parallel to the palm)."""
    px = np.asarray(contour_px, dtype=np.float64)
    p1 = rectifier.P1
    rays_rect = np.column_stack(
        [(px[:, 0] - p1[0, 2]) / p1[0, 0], (px[:, 1] - p1[1, 2]) / p1[1, 1], np.ones(len(px))]
    )
    hand_from_rect = rectifier.hand_from_rectified
    rot, origin = hand_from_rect[:3, :3], hand_from_rect[:3, 3]
    rays = rays_rect @ rot.T
    t = (plane_z_m - origin[2]) / rays[:, 2]
    return origin + t[:, None] * rays


@dataclass(frozen=True)
class Contour:
    """One frame's contour: resampled pixels (rectified left) and, where a plane is given, hand-frame mm."""

    pixels: NDArray[np.float64]
    hand_mm: NDArray[np.float64] | None


class ContourExtractor:
    """Frame by frame: track the object from its first-frame box, trace and resample its contour.

    Takes rectified left frames (a live pair through `Rectifier.remap`, or a recording's frames), so
    sim and hardware runs go through the same calls."""

    def __init__(
        self,
        rectifier: Rectifier,
        first_left: NDArray[np.uint8],
        box: tuple[int, int, int, int],
        *,
        points: int = DEFAULT_POINTS,
        plane_z_m: float | None = None,
    ) -> None:
        self.rectifier = rectifier
        self.points = points
        self.plane_z_m = plane_z_m
        self.tracker = ObjectTracker(first_left, box)

    def __call__(self, left_rect: NDArray[np.uint8]) -> Contour:
        """The contour in this frame (ContourError when the object is lost)."""
        mask, _ = self.tracker.track(left_rect)
        pixels = resample(outer_contour(mask), self.points)
        hand = None
        if self.plane_z_m is not None:
            hand = 1e3 * to_hand_plane(pixels, self.rectifier, self.plane_z_m)[:, :2]
        return Contour(pixels=pixels, hand_mm=hand)
