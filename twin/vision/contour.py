"""The object's outer contour in a camera image, as the shape network's target (paper §7).

The same code for sim and hardware frames. The object is segmented in the rectified left view by the
tracker's normalized-RGB histogram back-projection (twin.vision.reconstruct.ObjectTracker). Its
boundary is then taken at sub-pixel precision from the back-projection itself, not from the
thresholded mask's pixel staircase: the likelihood, kept near the tracker's blobs, is Gaussian-blurred
(LIKELIHOOD_SIGMA_PX) and cut at half the object's interior level by marching squares
(skimage.measure.find_contours). Why: under the fingers the thresholded mask holds one- or two-pixel
slivers along the object's edge that single pixels' noise connects to the blob or not; each one that
joins lengthens the traced staircase by twice its length, and arc-length resampling slides every
point after it. The blurred likelihood's iso-line moves continuously with the image and leaves such
slivers out (on the twin's block under the fingers, the contour's frame-to-frame jitter fell from
~1.2 px to ~0.2 px; BENCHMARKS.md and docs/shape_network.md).

Two targets come out of one frame:
- `largest`: the outline of the largest visible piece of the object (the paper's contour);
- `hull`: the convex hull of every visible piece. The fingers hide parts of the object from the
  top-down camera and cut what remains into pieces whose relative size changes from frame to frame:
  the largest piece can switch, and its outline jumps by tens of pixels (the cylinder). The hull of
  all pieces is one closed curve that moves continuously with them.

Each is resampled to n points equally spaced in arc length, starting from a stable anchor (where the
ray from the contour's centroid straight up the image, -v, crosses it) and running counter-clockwise
on screen. Fixed n and anchor make contours comparable sample by sample, which is what a network
regressing 2n outputs needs.

In millimetres, each contour pixel's ray from the rectified left camera is cut with the plane through
the object's centre square to the camera's axis (the silhouette lies near the object's widest section
as the camera sees it), in the image's right and up directions: the palm's (x, y) from above.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.ndimage import gaussian_filter
from skimage.measure import find_contours

from twin.interface.errors import TwinError
from twin.vision.reconstruct import ObjectTracker, Rectifier

DEFAULT_POINTS = 32
TARGETS = ("largest", "hull")
"""The contours a frame yields: the largest visible piece's outline, the hull of all pieces."""
BOUNDARIES = ("likelihood", "pixels")
"""How the boundary is traced: sub-pixel from the back-projection (the default), or the first
version's pixel staircase of the thresholded mask (kept to measure against)."""
LIKELIHOOD_SIGMA_PX = 1.0
"""Gaussian sigma (px) of the back-projection before its iso-line is cut. On the twin's block under
the fingers, 0.7 / 1.0 / 1.5 px gave frame-to-frame jitter of 0.22 / 0.18 / 0.16 px and errors
against the true silhouette of 0.92 / 0.92 / 0.97 px: 1 px keeps the outline's corners."""
NEIGHBOURHOOD_PX = 3
"""The back-projection is kept this far around the tracker's blobs (background blobs of a similar
colour elsewhere stay out), so the blur sees the object's edge and the background just beyond it."""
MASK_SIGMA_PX = 0.7
"""Blur of a binary mask before its 0.5 iso-line: that line then runs along the pixel edges between
inside and outside pixels, with the corners of the staircase rounded (a mask's own sub-pixel outline)."""
MIN_PIECE_AREA_PX = 16.0
"""Pieces of the object smaller than this (px^2) are ignored: a few pixels of noise, not an outline."""
SMOOTHING_PX = 2.0
"""Gaussian sigma (boundary pixels) applied along a pixel staircase before resampling: a staircase is
~5 % longer than the curve it samples, and that slack would shift points along it."""


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


def _polygon_area(points: NDArray[np.float64]) -> float:
    """Unsigned area enclosed by a closed polyline (shoelace)."""
    u, v = points[:, 0], points[:, 1]
    return float(abs(0.5 * np.sum(u * np.roll(v, -1) - np.roll(u, -1) * v)))


def iso_lines(
    field: NDArray[np.floating], level: float, min_area_px: float = MIN_PIECE_AREA_PX
) -> list[NDArray[np.float64]]:
    """Outer outlines (m, 2) in (u, v) of the regions where a 2-D field exceeds `level`, by marching
    squares, each enclosing at least `min_area_px`, largest first. Holes (a pore cluster inside the
    object) are left out. Outside the image the field counts as 0, so every line closes."""
    padded = np.pad(np.asarray(field, dtype=np.float64), 1)
    lines = []
    for line in find_contours(padded, level):
        rows, cols = line[:-1, 0], line[:-1, 1]  # the last point repeats the first
        if np.sum(rows * np.roll(cols, -1) - np.roll(rows, -1) * cols) >= 0:
            continue  # skimage winds around high regions one way, around holes the other
        uv = np.column_stack([cols, rows]) - 1.0
        if len(uv) >= 3 and _polygon_area(uv) >= min_area_px:
            lines.append(uv)
    return sorted(lines, key=_polygon_area, reverse=True)


def likelihood_field(
    likelihood: NDArray[np.uint8], mask: NDArray[np.bool_], sigma_px: float = LIKELIHOOD_SIGMA_PX
) -> NDArray[np.float64]:
    """The tracker's back-projection near its blobs, blurred, and scaled so the object's interior is 1.

    The interior level is the median of the blurred likelihood over the blobs shrunk by 2 px (over the
    blobs themselves when that leaves too little): the object's pores and shading lower it, and the
    iso-line at half of it sits where the image turns from object to background.
    """
    blobs = np.asarray(mask, dtype=np.uint8)
    grow = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * NEIGHBOURHOOD_PX + 1,) * 2)
    near = cv2.dilate(blobs, grow).astype(bool)
    kept = np.where(near, np.asarray(likelihood, dtype=np.float64), 0.0)
    blurred = gaussian_filter(kept, sigma_px, mode="constant")
    inner = cv2.erode(blobs, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))).astype(bool)
    where = inner if inner.sum() >= 20 else blobs.astype(bool)
    level = float(np.median(blurred[where])) if where.any() else 0.0
    if level <= 0:
        raise ContourError("the object mask is empty: no contour")
    return blurred / level


def outlines(
    mask: NDArray[np.bool_], likelihood: NDArray[np.uint8] | None = None
) -> list[NDArray[np.float64]]:
    """Sub-pixel closed outlines (u, v) of every visible piece of the object, largest first.

    With the tracker's back-projection: its iso-line at half the interior level (`likelihood_field`).
    Without: the mask's own outline (the 0.5 iso-line of the mask blurred by MASK_SIGMA_PX), e.g. for a
    true silhouette.
    """
    if likelihood is None:
        field = gaussian_filter(np.asarray(mask, dtype=np.float64), MASK_SIGMA_PX, mode="constant")
    else:
        field = likelihood_field(likelihood, mask)
    pieces = iso_lines(field, 0.5)
    if not pieces:
        raise ContourError("the object mask is empty: no contour")
    return pieces


def hull(pieces: list[NDArray[np.float64]]) -> NDArray[np.float64]:
    """(m, 2) the convex hull of all the pieces' outlines, as a closed polyline."""
    points = np.vstack(pieces).astype(np.float32)
    return cv2.convexHull(points)[:, 0, :].astype(np.float64)


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


VIEW_TOLERANCE_DEG = 10.0
"""Views whose toward-the-cameras directions lie this close count as one (a rig re-mounted a little):
a contour model serves runs from its training data's view only. The paper's lateral view is 60 deg
from the top view."""


def view_from_hand(rectifier: Rectifier) -> NDArray[np.float64]:
    """3 x 3: rows the rectified left camera's image right, image up and its direction toward the
    camera (minus its optical axis), in the hand frame: the frame contours and height maps use."""
    rot = rectifier.hand_from_rectified[:3, :3]
    return np.vstack([rot[:, 0], -rot[:, 1], -rot[:, 2]])  # OpenCV camera: y down, z forward


def view_angle_deg(view_a: ArrayLike, view_b: ArrayLike) -> float:
    """Degrees between two views' directions toward the cameras (the third rows of view_from_hand)."""
    toward_a, toward_b = np.asarray(view_a, dtype=np.float64)[2], np.asarray(view_b, dtype=np.float64)[2]
    return float(np.degrees(np.arccos(np.clip(toward_a @ toward_b, -1.0, 1.0))))


def to_view_plane(
    contour_px: NDArray[np.float64], rectifier: Rectifier, centre_m: ArrayLike
) -> NDArray[np.float64]:
    """(n, 2) metres: where the rectified-left rays through the pixels meet the plane through `centre_m`
    (hand frame: the object's centre) square to the camera's optical axis, as (image right, image up)
    from the centre. One rule for every placement of the pair: from straight above it is the palm's
    (x, y); from the side, a section through the object's centre as the camera sees it."""
    px = np.asarray(contour_px, dtype=np.float64)
    p1 = rectifier.P1
    rays_rect = np.column_stack(
        [(px[:, 0] - p1[0, 2]) / p1[0, 0], (px[:, 1] - p1[1, 2]) / p1[1, 1], np.ones(len(px))]
    )
    hand_from_rect = rectifier.hand_from_rectified
    rot, origin = hand_from_rect[:3, :3], hand_from_rect[:3, 3]
    right, up, toward = view_from_hand(rectifier)
    axis = -toward
    centre = np.asarray(centre_m, dtype=np.float64).reshape(3)
    rays = rays_rect @ rot.T
    t = ((centre - origin) @ axis) / (rays @ axis)
    offset = origin + t[:, None] * rays - centre
    return np.column_stack([offset @ right, offset @ up])


@dataclass(frozen=True)
class Contour:
    """One frame's contours, resampled, in pixels (rectified left) and, where a plane is given, in
    mm on the view plane through the object's centre (to_view_plane): the largest visible piece's outline,
    and the hull of all pieces."""

    pixels: NDArray[np.float64]
    hand_mm: NDArray[np.float64] | None
    hull_pixels: NDArray[np.float64] | None = None
    hull_mm: NDArray[np.float64] | None = None


def _pixel_pieces(mask: NDArray[np.bool_]) -> list[NDArray[np.float64]]:
    """The first version's boundaries: every blob's integer outline (cv2.findContours), largest first."""
    contours, _ = cv2.findContours(
        np.ascontiguousarray(mask, dtype=np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE
    )
    pieces = [c[:, 0, :].astype(np.float64) for c in contours if cv2.contourArea(c) >= MIN_PIECE_AREA_PX]
    return sorted(pieces, key=_polygon_area, reverse=True)


class ContourExtractor:
    """Frame by frame: track the object from its first-frame box, trace and resample its contours.

    Takes rectified left frames (a live pair through `Rectifier.remap`, or a recording's frames), so
    sim and hardware runs go through the same calls. `boundary`: "likelihood" (sub-pixel, from the
    back-projection) or "pixels" (the first version's mask staircase, kept for comparison)."""

    def __init__(
        self,
        rectifier: Rectifier,
        first_left: NDArray[np.uint8],
        box: tuple[int, int, int, int],
        *,
        points: int = DEFAULT_POINTS,
        plane_z_m: float | None = None,
        boundary: str = "likelihood",
    ) -> None:
        if boundary not in BOUNDARIES:
            raise ContourError(f"unknown boundary '{boundary}' (choose from {', '.join(BOUNDARIES)})")
        self.rectifier = rectifier
        self.points = points
        self.plane_z_m = plane_z_m
        self.boundary = boundary
        self.tracker = ObjectTracker(first_left, box)

    def __call__(self, left_rect: NDArray[np.uint8]) -> Contour:
        """The contours in this frame (ContourError when the object is lost)."""
        mask, _ = self.tracker.track(left_rect)
        if self.boundary == "likelihood":
            pieces = outlines(mask, self.tracker.back_project(left_rect))
            largest = pieces[0]
        else:
            largest = outer_contour(mask)
            pieces = _pixel_pieces(mask) or [largest]
        pixels = resample(largest, self.points)
        hull_pixels = resample(hull(pieces), self.points)
        hand = hull_hand = None
        if self.plane_z_m is not None:
            centre = (0.0, 0.0, self.plane_z_m)  # on the palm's axis, at the object's mid-height
            hand = 1e3 * to_view_plane(pixels, self.rectifier, centre)
            hull_hand = 1e3 * to_view_plane(hull_pixels, self.rectifier, centre)
        return Contour(pixels=pixels, hand_mm=hand, hull_pixels=hull_pixels, hull_mm=hull_hand)
