"""Stereo reconstruction of the squeezed object's visible surface (paper §4.2), backend-free.

Pipeline per stereo pair, each stage a small function:

1. `Rectifier.rectify`: undistort + rectify both views (cv2.stereoRectify, initUndistortRectifyMap,
   remap). For a converging (toed-in) rig the rectified principal points are shifted so the point where
   the optical axes cross lands at the centre of both rectified images (disparity ~0 there), which keeps
   the object in view and inside StereoBM's disparity search window.
2. `ObjectTracker.track`: the object segmented in the rectified left view by a normalized-RGB
   (r = R/(R+G+B), g = G/(R+G+B)) histogram learnt from a bounding box on the first frame:
   back-projection, cv2.CamShift, then blob analysis (small blobs and blobs far from the window dropped).
3. `disparity_around`: semi-global matching with the left-right check (cv2.StereoSGBM, 64 disparities,
   `make_sgbm_matcher`; or Konolige block matching, `make_block_matcher`) on the part of the pair
   around the tracked object.
4. `disparity_to_cloud`: cv2.reprojectImageTo3D with Q; valid pixels inside the mask; far points and
   points outside the hand's region dropped; points taken to the hand frame (rectified left -> left
   camera -> hand).
5. `surface_mesh`: scipy.spatial.Delaunay over the kept pixels' rectified image coordinates (a 2.5-D
   surface), triangles with an over-long 3-D edge removed.

Images are RGB uint8 (H, W, 3) at the calibration's image size; lengths in metres.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial import Delaunay

from twin.vision.calibration import StereoCalibration

Box = tuple[int, int, int, int]
"""(x, y, width, height) in pixels, OpenCV's rectangle."""


# --------------------------------------------------------------------------------------- rectification
def _disparity_to_depth(p1: NDArray[np.float64], p2: NDArray[np.float64]) -> NDArray[np.float64]:
    """OpenCV's 4x4 Q for a horizontal rectified pair with projections P1, P2 (as cv2.stereoRectify)."""
    f, cx1, cy = p1[0, 0], p1[0, 2], p1[1, 2]
    cx2, tx = p2[0, 2], p2[0, 3] / p2[0, 0]
    return np.array(
        [
            [1.0, 0.0, 0.0, -cx1],
            [0.0, 1.0, 0.0, -cy],
            [0.0, 0.0, 0.0, f],
            [0.0, 0.0, -1.0 / tx, (cx1 - cx2) / tx],
        ]
    )


def _convergence_point(rotation: NDArray[np.float64], translation: NDArray[np.float64]) -> NDArray | None:
    """Where the two optical axes pass closest (left camera frame), or None for a (near) parallel pair."""
    a1 = np.array([0.0, 0.0, 1.0])
    c2 = -rotation.T @ translation  # right optical centre in the left frame
    a2 = rotation.T @ a1
    cross = np.cross(a1, a2)
    if np.linalg.norm(cross) < 1e-6:
        return None
    # Closest points o1 + s a1 and c2 + u a2: solve the 2x2 normal equations.
    s, u = np.linalg.solve(np.array([[a1 @ a1, -(a1 @ a2)], [a1 @ a2, -(a2 @ a2)]]), [a1 @ c2, a2 @ c2])
    if s <= 0 or u <= 0:
        return None  # the axes diverge: no convergence in front of the cameras
    return 0.5 * (s * a1 + c2 + u * a2)


class Rectifier:
    """Rectification maps of a calibrated pair, computed once; `rectify` is two cv2.remap calls.

    `rectified_from_left` (R1) rotates the unrectified left camera frame onto the rectified one, so a
    point X_rect reconstructed with `Q` is X_left = R1.T X_rect and X_hand = `hand_from_rectified` X_rect.
    """

    def __init__(self, calibration: StereoCalibration, *, center_convergence: bool = True) -> None:
        left, right = calibration.left, calibration.right
        if left.image_size != right.image_size:
            raise ValueError(f"left and right image sizes differ: {left.image_size} vs {right.image_size}")
        self.calibration = calibration
        self.image_size: tuple[int, int] = tuple(left.image_size)  # (width, height)
        r1, r2, p1, p2, _, _, _ = cv2.stereoRectify(
            left.matrix,
            left.distortion,
            right.matrix,
            right.distortion,
            self.image_size,
            calibration.rotation,
            calibration.translation_m.reshape(3, 1),
            flags=cv2.CALIB_ZERO_DISPARITY,
            alpha=-1,
        )
        if abs(p2[1, 3]) > abs(p2[0, 3]):
            raise ValueError("a vertical stereo pair (cameras one above the other) is not supported")
        self.convergence_left_m = _convergence_point(calibration.rotation, calibration.translation_m)
        """The optical axes' crossing in the left camera frame (None for a parallel pair)."""
        if center_convergence and self.convergence_left_m is not None:
            x = r1 @ self.convergence_left_m
            w, h = self.image_size
            for p in (p1, p2):
                u, v, z = p @ np.append(x, 1.0)
                p[0, 2] -= u / z - (w - 1) / 2.0
                p[1, 2] -= v / z - (h - 1) / 2.0
        self.rectified_from_left: NDArray[np.float64] = r1
        self.rectified_from_right: NDArray[np.float64] = r2
        self.P1: NDArray[np.float64] = p1
        self.P2: NDArray[np.float64] = p2
        self.Q: NDArray[np.float64] = _disparity_to_depth(p1, p2)
        left_from_rectified = np.eye(4)
        left_from_rectified[:3, :3] = r1.T
        self.hand_from_rectified: NDArray[np.float64] = calibration.hand_from_left @ left_from_rectified
        """4x4: a point in the rectified left camera frame -> the hand frame."""
        self._maps = [
            cv2.initUndistortRectifyMap(cam.matrix, cam.distortion, r, p, self.image_size, cv2.CV_16SC2)
            for cam, r, p in ((left, r1, p1), (right, r2, p2))
        ]

    @property
    def convergence_disparity(self) -> float | None:
        """Disparity (px) of the optical axes' crossing in the rectified pair; None for a parallel pair."""
        if self.convergence_left_m is None:
            return None
        x = np.append(self.rectified_from_left @ self.convergence_left_m, 1.0)
        (u1, _, z1), (u2, _, z2) = self.P1 @ x, self.P2 @ x
        return float(u1 / z1 - u2 / z2)

    def remap(self, image: NDArray, side: str = "left", interpolation: int = cv2.INTER_LINEAR) -> NDArray:
        """One view rectified (`side` "left" or "right"); INTER_NEAREST for label or mask images."""
        if image.shape[1::-1] != self.image_size:
            raise ValueError(f"{side} image is {image.shape[1::-1]}, calibration is {self.image_size}")
        map1, map2 = self._maps[0 if side == "left" else 1]
        return cv2.remap(image, map1, map2, interpolation)

    def rectify(self, left: NDArray[np.uint8], right: NDArray[np.uint8]) -> tuple[NDArray, NDArray]:
        """Both views rectified: corresponding points on the same row, the right one `disparity` left."""
        return self.remap(left, "left"), self.remap(right, "right")


# ------------------------------------------------------------------------------------------- tracking
def normalized_rg(rgb: NDArray[np.uint8], min_intensity: int = 60) -> tuple[NDArray[np.uint8], NDArray]:
    """Chromaticity (r, g) * 255 as a (H, W, 2) uint8 image, and the mask of pixels bright enough to trust.

    r and g do not change with the shading of a surface (only with its colour); pixels with
    R + G + B < `min_intensity` (shadows, pores, the black rectification border) are too noisy.
    """
    total = rgb.sum(axis=2, dtype=np.float32)
    bright = total >= min_intensity
    scale = np.float32(255.0) / np.maximum(total, np.float32(1.0))
    rg = (rgb[..., :2] * scale[..., None]).astype(np.uint8)
    return rg, bright.astype(np.uint8) * 255


def _check_box(box: Box, image_shape: tuple[int, ...]) -> Box:
    x, y, w, h = (int(v) for v in box)
    height, width = image_shape[:2]
    if w <= 0 or h <= 0:
        raise ValueError(f"bounding box {box} is empty (width and height must be > 0)")
    if x < 0 or y < 0 or x + w > width or y + h > height:
        raise ValueError(f"bounding box {box} (x, y, w, h) is not inside the {width}x{height} image")
    return x, y, w, h


class ObjectTracker:
    """Segments and follows the object in the rectified left view with a normalized-RGB histogram.

    The model is a ratio histogram (Swain & Ballard): the 2-D (r, g) histogram of the box divided by that
    of the whole first frame, so colours that the background shares score low. Each `track` call
    back-projects it, moves the window with cv2.CamShift and thresholds the back-projection into a mask
    cleaned by blob analysis.
    """

    def __init__(
        self,
        first_left_rgb: NDArray[np.uint8],
        bbox: Box,
        *,
        bins: int = 32,
        min_intensity: int = 60,
        threshold: int = 64,
        min_blob_fraction: float = 0.1,
        window_margin: float = 0.25,
    ) -> None:
        self.window: Box = _check_box(bbox, first_left_rgb.shape)
        self.bins = bins
        self.min_intensity = min_intensity
        self.threshold = threshold
        self.min_blob_fraction = min_blob_fraction
        self.window_margin = window_margin
        self.hist = self._ratio_histogram(first_left_rgb, self.window)
        self._criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 10, 1.0)

    def _ratio_histogram(self, rgb: NDArray[np.uint8], box: Box) -> NDArray[np.float32]:
        """(bins, bins) float32 in [0, 255]: in-box count / whole-image count per (r, g) bin."""
        rg, bright = normalized_rg(rgb, self.min_intensity)
        x, y, w, h = box
        in_box = np.zeros_like(bright)
        in_box[y : y + h, x : x + w] = bright[y : y + h, x : x + w]
        if not in_box.any():
            raise ValueError(f"bounding box {box} holds no pixel bright enough to learn the object's colour")
        sizes, ranges = [self.bins, self.bins], [0, 256, 0, 256]
        box_hist = cv2.calcHist([rg], [0, 1], in_box, sizes, ranges)
        all_hist = cv2.calcHist([rg], [0, 1], bright, sizes, ranges)
        ratio = np.divide(box_hist, all_hist, out=np.zeros_like(box_hist), where=all_hist > 0)
        return np.minimum(ratio, 1.0).astype(np.float32) * np.float32(255.0)

    def back_project(self, rgb: NDArray[np.uint8]) -> NDArray[np.uint8]:
        """Per-pixel likelihood (0-255) that the pixel has the object's chromaticity."""
        rg, bright = normalized_rg(rgb, self.min_intensity)
        prob = cv2.calcBackProject([rg], [0, 1], self.hist, [0, 256, 0, 256], 1)
        return cv2.bitwise_and(prob, bright)

    def _clean(self, prob: NDArray[np.uint8], window: Box) -> NDArray[np.bool_]:
        """Blob analysis on the thresholded back-projection: keep the blobs near `window`, not too small."""
        _, binary = cv2.threshold(prob, self.threshold, 255, cv2.THRESH_BINARY)
        binary = cv2.morphologyEx(
            binary, cv2.MORPH_CLOSE, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
        )
        n, labels, stats, _ = cv2.connectedComponentsWithStats(binary, connectivity=8)
        x, y, w, h = window
        mx, my = self.window_margin * w, self.window_margin * h
        x0, y0, x1, y1 = x - mx, y - my, x + w + mx, y + h + my
        bx, by = stats[1:, cv2.CC_STAT_LEFT], stats[1:, cv2.CC_STAT_TOP]
        bw, bh = stats[1:, cv2.CC_STAT_WIDTH], stats[1:, cv2.CC_STAT_HEIGHT]
        area = stats[1:, cv2.CC_STAT_AREA]
        near = (bx < x1) & (bx + bw > x0) & (by < y1) & (by + bh > y0)
        if n <= 1 or not near.any():
            return np.zeros(prob.shape, dtype=bool)
        keep = near & (area >= self.min_blob_fraction * area[near].max())
        lut = np.concatenate([[False], keep])
        return lut[labels]

    def track(self, left_rgb: NDArray[np.uint8]) -> tuple[NDArray[np.bool_], Box]:
        """The object's mask and CamShift window in this rectified left frame (the window is kept if lost)."""
        prob = self.back_project(left_rgb)
        _, window = cv2.CamShift(prob, self.window, self._criteria)
        if window[2] > 0 and window[3] > 0:
            self.window = tuple(int(v) for v in window)
        return self._clean(prob, self.window), self.window


# ------------------------------------------------------------------------------ disparity and the cloud
def make_block_matcher(
    num_disparities: int = 64, block_size: int = 15, min_disparity: int = 0
) -> cv2.StereoBM:
    """Konolige block matching tuned for a finely textured (foam) surface at 320x240.

    X-Sobel prefilter (robust to the two cameras' gain differences), a texture threshold that rejects
    flat background, a uniqueness test against ambiguous matches, and speckle filtering of small
    disparity islands (mismatches at depth edges).
    """
    bm = cv2.StereoBM.create(numDisparities=num_disparities, blockSize=block_size)
    bm.setMinDisparity(min_disparity)
    bm.setPreFilterType(cv2.STEREO_BM_PREFILTER_XSOBEL)
    bm.setPreFilterCap(31)
    bm.setTextureThreshold(10)
    bm.setUniquenessRatio(10)
    bm.setSpeckleWindowSize(50)
    bm.setSpeckleRange(32)
    return bm


DISP12_MAX_DIFF_PX = 2
"""Left-right check: a pixel whose right-to-left match lands farther than this from it is dropped."""
SGBM_UNIQUENESS = 5
"""Percent by which the best match must beat the second best."""
SGBM_SPECKLE_RANGE = 4
"""Disparity step (x16 fixed point, i.e. 0.25 px) that splits a speckle island."""


def make_sgbm_matcher(
    num_disparities: int = 64, block_size: int = 3, min_disparity: int = 0
) -> cv2.StereoSGBM:
    """Semi-global matching (Hirschmuller) with its occlusion filters, the run's default matcher.

    The smoothness penalties (P1, P2 = 8, 32 x block^2, OpenCV's advice for one channel) fill the foam's
    weakly textured faces that block matching leaves empty; the left-right consistency check
    (DISP12_MAX_DIFF_PX) drops pixels the right camera cannot see, where an occluding finger's
    disparity would otherwise win; uniqueness and speckle filters drop ambiguous matches and small
    islands. 3-way mode: 8 paths at about the cost of StereoBM on one core.
    """
    return cv2.StereoSGBM.create(
        minDisparity=min_disparity,
        numDisparities=num_disparities,
        blockSize=block_size,
        P1=8 * block_size * block_size,
        P2=32 * block_size * block_size,
        disp12MaxDiff=DISP12_MAX_DIFF_PX,
        uniquenessRatio=SGBM_UNIQUENESS,
        speckleWindowSize=50,
        speckleRange=SGBM_SPECKLE_RANGE,
        preFilterCap=31,
        mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    )


def compute_disparity(
    left_rect: NDArray[np.uint8], right_rect: NDArray[np.uint8], matcher: cv2.StereoMatcher
) -> NDArray[np.float32]:
    """Disparity in pixels (float32, NaN where block matching found no reliable match)."""
    gray = [cv2.cvtColor(im, cv2.COLOR_RGB2GRAY) if im.ndim == 3 else im for im in (left_rect, right_rect)]
    raw = matcher.compute(gray[0], gray[1])
    disparity = raw.astype(np.float32) / np.float32(16.0)
    disparity[raw < matcher.getMinDisparity() * 16] = np.nan
    return disparity


@dataclass(frozen=True)
class HandRegion:
    """Where a held object can be, in the hand frame: a cylinder about the palm's axis (z), from just
    below the palm's face up. Points outside (the floor, the bench, the room) are dropped before the
    cloud's outlier test, which a large background blob of the object's colour would otherwise steer."""

    radius_m: float = 0.15
    z_min_m: float = 0.06
    """A little below the BH8 palm's face (75 mm above the hand frame's origin)."""
    z_max_m: float = 0.35

    def contains(self, points_hand: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Which (N, 3) hand-frame points lie inside."""
        r2 = points_hand[:, 0] ** 2 + points_hand[:, 1] ** 2
        z = points_hand[:, 2]
        return (r2 <= self.radius_m**2) & (z >= self.z_min_m) & (z <= self.z_max_m)


def disparity_around(
    left_rect: NDArray[np.uint8],
    right_rect: NDArray[np.uint8],
    matcher: cv2.StereoMatcher,
    mask: NDArray[np.bool_],
) -> NDArray[np.float32]:
    """compute_disparity on the part of the pair that can hold the masked pixels' matches: the mask's
    rows (plus the matching window) and its columns plus the disparity search on both sides; NaN
    elsewhere. Cropping both views alike leaves disparities unchanged, and matching only where the
    object is costs a fraction of the whole frame (the object fills ~1/6 of it)."""
    height, width = mask.shape
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    disparity = np.full((height, width), np.nan, dtype=np.float32)
    if not len(rows):
        return disparity
    pad = matcher.getBlockSize() // 2 + 1
    reach = max(abs(matcher.getMinDisparity()), abs(matcher.getMinDisparity() + matcher.getNumDisparities()))
    y0, y1 = max(rows[0] - pad, 0), min(rows[-1] + pad + 1, height)
    x0, x1 = max(cols[0] - reach - pad, 0), min(cols[-1] + reach + pad + 1, width)
    if x1 - x0 < (least := matcher.getNumDisparities() + matcher.getBlockSize()):
        # OpenCV's matchers need the view wider than their search (SGBM: a negative allocation, or a
        # segfault, at <= numDisparities columns): a mask at the frame's edge widens inwards
        x1 = min(x0 + least, width)
        x0 = max(x1 - least, 0)
    disparity[y0:y1, x0:x1] = compute_disparity(left_rect[y0:y1, x0:x1], right_rect[y0:y1, x0:x1], matcher)
    return disparity


def disparity_to_cloud(
    disparity: NDArray[np.float32],
    mask: NDArray[np.bool_],
    rectifier: Rectifier,
    *,
    max_depth_m: float = 2.0,
    outlier_factor: float = 3.0,
    region: HandRegion | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    """3-D points (rectified left frame) of the valid masked pixels, far points dropped; and their (row, col).

    Outliers: points behind the camera or beyond `max_depth_m`, points outside `region` (hand frame) if
    given, then points farther from the cloud's median than `outlier_factor` times the median such distance.
    """
    valid = mask & np.isfinite(disparity)
    xyz = cv2.reprojectImageTo3D(np.nan_to_num(disparity, nan=0.0), rectifier.Q)
    rows, cols = np.nonzero(valid)
    points = xyz[rows, cols].astype(np.float64)
    keep = np.isfinite(points).all(axis=1) & (points[:, 2] > 0) & (points[:, 2] <= max_depth_m)
    points, rows, cols = points[keep], rows[keep], cols[keep]
    if region is not None and len(points):
        keep = region.contains(to_hand(points, rectifier))
        points, rows, cols = points[keep], rows[keep], cols[keep]
    if len(points):
        dist = np.linalg.norm(points - np.median(points, axis=0), axis=1)
        keep = dist <= outlier_factor * max(float(np.median(dist)), 1e-6)
        points, rows, cols = points[keep], rows[keep], cols[keep]
    return points, np.stack([rows, cols], axis=1)


def to_hand(points_rect: NDArray[np.float64], rectifier: Rectifier) -> NDArray[np.float64]:
    """Points from the rectified left camera frame to the hand frame."""
    t = rectifier.hand_from_rectified
    return points_rect @ t[:3, :3].T + t[:3, 3]


def surface_mesh(
    pixels_uv: NDArray[np.float64], points: NDArray[np.float64], max_edge_m: float = 0.008
) -> NDArray[np.intp]:
    """(M, 3) triangles: Delaunay of the points' image coordinates, minus those with a 3-D edge > max_edge_m.

    Triangulating in the image (2.5-D) gives the visible surface without folds; long edges bridge depth
    jumps or holes in the cloud and are removed.
    """
    if len(points) < 3:
        return np.zeros((0, 3), dtype=np.intp)
    # Pixel centres sit on a grid, whose cocircular quads qhull resolves slowly: a fixed, far sub-pixel
    # jitter breaks the ties (about 2x faster) without changing which neighbours get connected.
    jitter = np.random.default_rng(0).uniform(-1e-3, 1e-3, pixels_uv.shape)
    try:
        triangles = Delaunay(pixels_uv + jitter).simplices
    except Exception:  # qhull: all points on a line
        return np.zeros((0, 3), dtype=np.intp)
    corners = points[triangles]
    edges = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2)
    return triangles[edges.max(axis=1) <= max_edge_m].astype(np.intp)


# ---------------------------------------------------------------------------------------- the pipeline
@dataclass
class Reconstruction:
    """One stereo pair's surface: points and mesh in the hand frame, with what produced them."""

    points_hand: NDArray[np.float64]
    """(N, 3) metres, hand frame."""
    colors: NDArray[np.uint8]
    """(N, 3) RGB of each point in the rectified left view."""
    pixels: NDArray[np.intp]
    """(N, 2) (row, col) of each point in the rectified left view."""
    triangles: NDArray[np.intp]
    """(M, 3) indices into points_hand."""
    disparity: NDArray[np.float32]
    """(H, W) pixels in the rectified pair, NaN where unmatched."""
    mask: NDArray[np.bool_]
    """(H, W) the object's segmentation in the rectified left view."""
    box: Box | None
    """The tracker's window (None when a mask was given)."""
    timings_ms: dict[str, float] = field(default_factory=dict)
    """Milliseconds per stage: rectify, track, disparity, cloud, mesh."""


def reconstruct(
    left: NDArray[np.uint8],
    right: NDArray[np.uint8],
    rectifier: Rectifier,
    tracker_or_mask: ObjectTracker | NDArray[np.bool_],
    *,
    matcher: cv2.StereoMatcher | None = None,
    max_depth_m: float = 2.0,
    outlier_factor: float = 3.0,
    max_edge_m: float = 0.008,
    mesh_stride: int = 1,
    mesh: bool = True,
    erode_px: int = 0,
    region: HandRegion | None = None,
) -> Reconstruction:
    """The whole pipeline on one unrectified RGB pair.

    `tracker_or_mask`: an ObjectTracker (updated in place) or a boolean mask in the rectified left view.
    `matcher`: a cv2.StereoSGBM or StereoBM (build it once with `default_matcher(rectifier)` when
    calling per frame).
    `mesh_stride`: mesh only the points on every n-th row and column (n^2 fewer vertices, the mesh being
    the slowest stage); the triangles still index `points_hand`, which keeps every point.
    `mesh`: False leaves `triangles` empty (for a caller that meshes a fused cloud itself).
    `erode_px`: shrink the object's mask by this many pixels before taking points: at its border a
    block straddles the object and whatever hides it, and takes the nearer surface's disparity.
    `region`: drop points outside this part of the hand frame (`HandRegion`).
    """
    if mesh_stride < 1:
        raise ValueError(f"mesh_stride must be >= 1, got {mesh_stride}")
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    left_rect, right_rect = rectifier.rectify(left, right)
    t1 = time.perf_counter()
    timings["rectify"] = 1e3 * (t1 - t0)
    if isinstance(tracker_or_mask, ObjectTracker):
        mask, box = tracker_or_mask.track(left_rect)
    else:
        mask, box = np.asarray(tracker_or_mask, dtype=bool), None
        if mask.shape != left_rect.shape[:2]:
            raise ValueError(f"mask shape {mask.shape} is not the image's {left_rect.shape[:2]}")
    if erode_px > 0:  # block matching smears a nearer occluder's disparity this far into the object
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * erode_px + 1, 2 * erode_px + 1))
        mask = cv2.erode(mask.astype(np.uint8), kernel).astype(bool)
    t2 = time.perf_counter()
    timings["track"] = 1e3 * (t2 - t1)
    disparity = disparity_around(left_rect, right_rect, matcher or default_matcher(rectifier), mask)
    t3 = time.perf_counter()
    timings["disparity"] = 1e3 * (t3 - t2)
    points, pixels = disparity_to_cloud(
        disparity, mask, rectifier, max_depth_m=max_depth_m, outlier_factor=outlier_factor, region=region
    )
    points_hand = to_hand(points, rectifier)
    colors = left_rect[pixels[:, 0], pixels[:, 1]] if left_rect.ndim == 3 else None
    t4 = time.perf_counter()
    timings["cloud"] = 1e3 * (t4 - t3)
    triangles = np.zeros((0, 3), dtype=np.intp)
    if mesh:
        on_grid = np.flatnonzero((pixels[:, 0] % mesh_stride == 0) & (pixels[:, 1] % mesh_stride == 0))
        uv = pixels[on_grid, ::-1].astype(np.float64)
        triangles = on_grid[surface_mesh(uv, points[on_grid], max_edge_m * mesh_stride)]
    timings["mesh"] = 1e3 * (time.perf_counter() - t4)
    if colors is None:
        colors = np.repeat(left_rect[pixels[:, 0], pixels[:, 1]][:, None], 3, axis=1)
    return Reconstruction(points_hand, colors, pixels, triangles, disparity, mask, box, timings)


def default_matcher(
    rectifier: Rectifier, num_disparities: int = 64, block_size: int = 3, kind: str = "sgbm"
) -> cv2.StereoMatcher:
    """The matcher (`kind` "sgbm": make_sgbm_matcher, "bm": make_block_matcher) searching around the
    optical axes' crossing (from 0 for a parallel rig)."""
    d = rectifier.convergence_disparity
    min_disparity = 0 if d is None else round(d) - num_disparities // 2
    if kind == "sgbm":
        return make_sgbm_matcher(num_disparities, block_size, min_disparity)
    if kind == "bm":
        return make_block_matcher(num_disparities, block_size, min_disparity)
    raise ValueError(f"matcher kind {kind!r}: expected 'sgbm' or 'bm'")
