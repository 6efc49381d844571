"""Camera-to-hand calibration (paper §4.1) and the stereo pair's own calibration, from images only.

Hand: a tiny 4x3 checkerboard sits in the palm at a known place. In each view the centres of its six
black squares are found by thresholding at the image mean and blob analysis, then sorted by their
known layout; the sorted lists correspond, each pair is mid-point triangulated in the left camera
frame, and the rigid transform between those points and the same points in the hand frame (Kabsch /
Umeyama, scipy's Rotation.align_vectors) gives where the pair sits in the hand: hand_from_left.

Stereo: views of an OpenCV chessboard (cv2.findChessboardCorners + cornerSubPix), cv2.calibrateCamera
per camera, then cv2.stereoCalibrate with the intrinsics fixed.

Images are (H, W, 3) RGB or (H, W) grey uint8; calibrations follow twin.vision.calibration (OpenCV
conventions). Nothing here knows whether the images came from the twin or from the Flea2 pair.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, replace

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from twin.interface.errors import ConfigError
from twin.vision.calibration import CameraIntrinsics, StereoCalibration

PALM_LAYOUT_COLS_ROWS: tuple[tuple[int, int], ...] = ((0, 0), (2, 0), (1, 1), (3, 1), (0, 2), (2, 2))
"""(col, row) of the black squares of the 4x3 palm board, in the order their centres are reported:
row-major, row 0 first (twin.sim.checkerboard.PALM_BOARD_LAYOUT gives the same squares as (row, col))."""


CAMERA_FLAGS = cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST
PAIR_POSE_TOLERANCE = (3.0, 0.010)
"""A chessboard pair is used for the stereo fit only if the left-to-right pose its two views give (each
camera's own board pose) lies within 3 deg and 10 mm of the pairs' median: a board read from opposite ends
in the two views (find_chessboard's end-square test can misjudge one view: 1 pair in 300 on the twin,
164 deg off) would otherwise pull the pair's pose 390 mm off. Consistent pairs agree within 0.5 deg, 3 mm."""
"""Camera model fitted: pinhole + radial k1, k2 (no k3, no tangential terms: a 6 mm C-mount lens on a
1/3" sensor needs no more, and the extra terms trade principal-point accuracy for nothing here)."""


class CalibrationImageError(ConfigError):
    """A calibration image does not show the target as expected (one line: what was found)."""


# --------------------------------------------------------------------------------------------------
# Palm board: blobs, sorting, triangulation, rigid transform


def _grey(image: NDArray[np.uint8]) -> NDArray[np.uint8]:
    if image.ndim == 3:
        return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    return image


def _square_blobs(
    dark: NDArray[np.bool_],
    erode: int,
    area_px: tuple[float, float],
    max_elongation: float,
    moment_range: tuple[float, float],
) -> tuple[NDArray[np.float64], NDArray[np.uint8]]:
    """Centroids of the square-looking components of a dark mask, and a mask of their pixels."""
    # A checkerboard's black squares meet at their corners: an erosion parts them (it shrinks a square
    # evenly on all sides, so its centroid stays put).
    mask = cv2.erode(dark.astype(np.uint8), np.ones((3, 3), np.uint8), iterations=erode)
    count, labels, stats, centroids = cv2.connectedComponentsWithStats(mask, connectivity=4)
    keep = []
    for k in range(1, count):
        if not area_px[0] <= stats[k, cv2.CC_STAT_AREA] <= area_px[1]:
            continue
        x, y, w, h = stats[k, :4]
        m = cv2.moments((labels[y : y + h, x : x + w] == k).astype(np.uint8), binaryImage=True)
        cov = np.array([[m["mu20"], m["mu11"]], [m["mu11"], m["mu02"]]]) / m["m00"]
        low, high = np.linalg.eigvalsh(cov)
        if low <= 0 or np.sqrt(high / low) > max_elongation:
            continue
        if not moment_range[0] <= np.sqrt(low * high) / m["m00"] <= moment_range[1]:
            continue
        keep.append(k)
    keep = _largest_group(keep, centroids, stats[:, cv2.CC_STAT_AREA])
    kept = np.isin(labels, keep).astype(np.uint8) if keep else np.zeros_like(mask)
    return np.array(centroids[keep], dtype=float).reshape(-1, 2), kept


GROUP_REACH = 2.5
"""Blobs whose centroids lie within this many sqrt(area) of each other belong to one board: a board's
squares meet at their corners (1.4 for a square seen from above, 1.6 seen 30 deg above its plane)."""


def _largest_group(keep: list[int], centroids: NDArray[np.float64], areas: NDArray) -> list[int]:
    """The largest set of `keep` components linked by nearness (a board), dropping stray dark blobs
    elsewhere in the view (a floor tile seen obliquely looks like a square too)."""
    if len(keep) < 2:
        return keep
    c = centroids[keep]
    reach = GROUP_REACH * np.sqrt(np.asarray(areas, dtype=float)[keep])
    dist = np.linalg.norm(c[:, None] - c[None], axis=2)
    linked = dist <= np.minimum(reach[:, None], reach[None])
    group = np.full(len(keep), -1)
    for start in range(len(keep)):
        if group[start] >= 0:
            continue
        group[start], stack = start, [start]
        while stack:
            i = stack.pop()
            for j in np.flatnonzero(linked[i] & (group < 0)):
                group[j] = start
                stack.append(j)
    largest = np.bincount(group).argmax()
    return [k for k, g in zip(keep, group, strict=True) if g == largest]


def dark_square_blobs(
    image: NDArray[np.uint8],
    *,
    min_area_frac: float = 2e-4,
    max_area_frac: float = 0.02,
    max_elongation: float = 3.5,
    moment_range: tuple[float, float] = (0.075, 0.095),
    erode: int = 1,
) -> NDArray[np.float64]:
    """(N, 2) centroids (x, y pixels) of the square-looking dark blobs of `image`.

    Blob analysis: threshold at a mean (darker pixels are foreground), erode the mask by `erode`
    pixels, label 4-connected components (cv2.connectedComponentsWithStats), keep those whose area
    lies within the given fractions of the image, whose principal axes differ by at most
    `max_elongation` (a square seen 20 deg above its plane: 2.9), and whose normalised second moment
    sqrt(det(covariance)) / area lies in `moment_range` (1/12 for any parallelogram, i.e. a square
    seen from any side, top or lateral; rings and L shapes fall above).

    Two passes: the first thresholds at the whole image's mean and finds the squares; the second
    thresholds at the mean of the smallest rotated rectangle around them, i.e. over the board
    itself. A checkerboard is half black, so that mean lies midway between its black and white: edge
    pixels then go to whichever colour covers more of them, and a square's centroid is unbiased. (At
    the darker whole-image mean, the grey pixels where two black squares meet at a corner count as
    black, pulling each square's centroid toward its diagonal neighbours by up to ~0.5 px.) The
    centroids of the second pass are grey-level weighted (_weighted_centres); if it does not find the
    same number of squares as the first, the first pass's binary centroids are returned.
    """
    grey = _grey(image)
    size = grey.shape[0] * grey.shape[1]
    args = (erode, (min_area_frac * size, max_area_frac * size), max_elongation, moment_range)
    centres, kept = _square_blobs(grey < grey.mean(), *args)
    if len(centres) < 2:
        return centres
    pixels = cv2.findNonZero(cv2.dilate(kept, np.ones((3, 3), np.uint8), iterations=erode))
    board = np.zeros_like(kept)
    cv2.fillConvexPoly(board, np.round(cv2.boxPoints(cv2.minAreaRect(pixels))).astype(np.int32), 1)
    threshold = grey[board > 0].mean()
    near = cv2.dilate(board, np.ones((3, 3), np.uint8), iterations=2 + erode) > 0
    refined, kept = _square_blobs((grey < threshold) & near, *args)
    if len(refined) != len(centres):
        return centres
    return _weighted_centres(grey, kept, board > 0, threshold, reach=erode + 3)


def _weighted_centres(
    grey: NDArray[np.uint8], kept: NDArray[np.uint8], board: NDArray[np.bool_], threshold: float, reach: int
) -> NDArray[np.float64]:
    """Sub-pixel centroids: each pixel within `reach` of a blob (and nearer it than any other blob)
    weighs by how black it is, linearly between the board's black and white levels; an edge pixel
    half covered by the square counts half, which the binary centroid cannot do (it is ~0.2 px off
    for a square whose edges run along the pixel grid)."""
    black = float(np.median(grey[kept > 0]))
    white = float(np.median(grey[board & (grey > threshold)]))
    weight = np.clip((white - grey.astype(float)) / max(white - black, 1.0), 0.0, 1.0)
    count, markers = cv2.connectedComponents(kept, connectivity=4)
    distance, nearest = cv2.distanceTransformWithLabels(
        (kept == 0).astype(np.uint8), cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_CCOMP
    )
    ys, xs = np.mgrid[0 : grey.shape[0], 0 : grey.shape[1]]
    centres = []
    for k in range(1, count):
        own = np.unique(nearest[markers == k])  # the distance labels of this blob's pixels
        region = np.isin(nearest, own) & (distance <= reach)
        w = weight[region]
        centres.append([(w * xs[region]).sum() / w.sum(), (w * ys[region]).sum() / w.sum()])
    return np.array(centres, dtype=float).reshape(-1, 2)


def sort_by_layout(
    centres: NDArray[np.float64],
    layout: Sequence[tuple[int, int]] = PALM_LAYOUT_COLS_ROWS,
    *,
    max_residual: float = 0.15,
) -> NDArray[np.float64]:
    """`centres` reordered to match `layout` ((col, row) grid cells, rows growing down the board).

    Every assignment of the blobs to the layout cells is tried (6! = 720 for the palm board, one
    matrix product): each is fitted with an affine map grid -> image by least squares, and the best
    fit wins among those that keep the board's handedness (a camera sees the board's front face, so
    the map cannot be a mirror image: its determinant is positive with image y down and rows down).
    An affine fit is exact for any in-plane rotation, scale and shear, so the sort holds however
    the board is turned in the image, and the 4x3 layout has no rotational symmetry (only a mirror
    one, which the handedness test excludes), so the winner is unique. The residual, relative to the
    fitted square size, must stay under `max_residual` (perspective on a small board is far below).
    """
    grid = np.asarray(layout, dtype=float)
    n = len(grid)
    if len(centres) != n:
        raise ValueError(f"{len(centres)} centres for a layout of {n}")
    design = np.column_stack([grid, np.ones(n)])
    solve = np.linalg.pinv(design)  # (3, n)
    perms = np.array(list(itertools.permutations(range(n))))
    targets = centres[perms]  # (P, n, 2)
    coef = np.einsum("kn,pnd->pkd", solve, targets)  # (P, 3, 2): rows a_col, a_row, offset
    residual = np.einsum("nk,pkd->pnd", design, coef) - targets
    rms = np.sqrt((residual**2).sum(axis=(1, 2)) / n)
    det = coef[:, 0, 0] * coef[:, 1, 1] - coef[:, 0, 1] * coef[:, 1, 0]
    rms[det <= 0] = np.inf
    best = int(np.argmin(rms))
    scale = np.sqrt(abs(det[best]))
    if not np.isfinite(rms[best]) or rms[best] > max_residual * scale:
        raise CalibrationImageError(
            f"the {n} dark squares are not in the board's layout (fit residual {rms[best]:.1f} px)"
        )
    return centres[perms[best]]


def palm_board_centres_px(
    image: NDArray[np.uint8], side: str = "left", layout: Sequence[tuple[int, int]] = PALM_LAYOUT_COLS_ROWS
) -> NDArray[np.float64]:
    """(6, 2) black-square centres of the palm board in one view, sorted by the layout; raises
    CalibrationImageError naming the view when not exactly that many squares are found."""
    centres = dark_square_blobs(image)
    if len(centres) != len(layout):
        raise CalibrationImageError(
            f"found {len(centres)} black squares in the {side} image, expected {len(layout)}"
        )
    return sort_by_layout(centres, layout)


def _fit(calibration: StereoCalibration, shape: tuple[int, ...]) -> StereoCalibration:
    """The calibration at the images' size (a camera read out at another resolution scales exactly)."""
    h, w = shape[:2]
    if calibration.left.image_size != (w, h):
        return calibration.scaled(w, h)
    return calibration


def _normalised(camera: CameraIntrinsics, pixels: NDArray[np.float64]) -> NDArray[np.float64]:
    """Undistorted rays (x, y, 1) of pixels in that camera's frame."""
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)  # the default 5 steps
    xy = cv2.undistortPoints(  # leave ~0.1 mm at 40 cm under strong distortion
        pixels.reshape(-1, 1, 2).astype(np.float64), camera.matrix, camera.distortion, criteria=criteria
    )
    return np.column_stack([xy.reshape(-1, 2), np.ones(len(pixels))])


def midpoint_triangulate(
    calibration: StereoCalibration, left_px: NDArray[np.float64], right_px: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Mid-point triangulation of corresponding pixels: (N, 3) points in the left camera frame and
    (N,) gaps between the two rays (m; a measure of the correspondence and calibration quality).

    Each pixel is undistorted into a ray; the left ray runs from the origin, the right one from the
    right camera's centre c = -R^T t along R^T d_r; the point is the middle of their common
    perpendicular (closest points o_l + s d_l and c + u d_r from the 2x2 normal equations).
    """
    r, t = calibration.rotation, calibration.translation_m
    d_l = _normalised(calibration.left, np.asarray(left_px, dtype=float))
    d_r = _normalised(calibration.right, np.asarray(right_px, dtype=float)) @ r  # rows: R^T d
    return midpoint_of_rays(np.zeros(3), d_l, -r.T @ t, d_r)


def midpoint_of_rays(
    origin_a: NDArray[np.float64],
    dirs_a: NDArray[np.float64],
    origin_b: NDArray[np.float64],
    dirs_b: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Midpoints of the common perpendiculars of rays origin_a + s dirs_a[i] and origin_b + u dirs_b[i],
    and the rays' distances there; parallel rays raise ValueError."""
    a, b = np.atleast_2d(dirs_a), np.atleast_2d(dirs_b)
    w = np.asarray(origin_b, dtype=float) - np.asarray(origin_a, dtype=float)
    aa, bb, ab = (a * a).sum(1), (b * b).sum(1), (a * b).sum(1)
    aw, bw = a @ w, b @ w
    den = aa * bb - ab**2
    if np.any(den <= 1e-12 * aa * bb):
        raise ValueError("parallel rays: no triangulation")
    s = (aw * bb - ab * bw) / den
    u = (ab * aw - aa * bw) / den
    pa = origin_a + s[:, None] * a
    pb = origin_b + u[:, None] * b
    return 0.5 * (pa + pb), np.linalg.norm(pa - pb, axis=1)


def rigid_transform(source: NDArray[np.float64], target: NDArray[np.float64]) -> NDArray[np.float64]:
    """4x4 T minimising sum |T source_i - target_i|^2 over rotations and translations (Kabsch):
    the rotation from scipy's Rotation.align_vectors on the centred sets, then the centroid shift."""
    source, target = np.asarray(source, dtype=float), np.asarray(target, dtype=float)
    mu_s, mu_t = source.mean(axis=0), target.mean(axis=0)
    rotation, _ = Rotation.align_vectors(target - mu_t, source - mu_s)
    pose = np.eye(4)
    pose[:3, :3] = rotation.as_matrix()
    pose[:3, 3] = mu_t - pose[:3, :3] @ mu_s
    return pose


@dataclass(frozen=True)
class HandEyeResult:
    """hand_from_left and how well the palm board's points fit."""

    hand_from_left: NDArray[np.float64]
    points_left_m: NDArray[np.float64]
    """(6, 3) triangulated black-square centres, left camera frame."""
    ray_gap_m: NDArray[np.float64]
    """(6,) distance between the two rays of each centre."""
    fit_rms_m: float
    """RMS distance between the board's known points and the triangulated ones mapped to the hand."""


def square_corners(
    board_points_m: NDArray[np.float64], layout: Sequence[tuple[int, int]] = PALM_LAYOUT_COLS_ROWS
) -> NDArray[np.float64]:
    """(N, 4, 3) corners of the black squares, from their centres and the layout: the board's column
    and row steps are fitted (least squares) to centre = origin + col * step_c + row * step_r."""
    grid = np.column_stack([np.asarray(layout, dtype=float), np.ones(len(layout))])
    (step_c, step_r, _), *_ = np.linalg.lstsq(grid, board_points_m, rcond=None)
    offsets = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * 0.5
    return board_points_m[:, None, :] + offsets[:, 0, None] * step_c + offsets[:, 1, None] * step_r


def _centroid_offsets(camera: CameraIntrinsics, corners_cam: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N, 2) area centroid of each projected square minus the projection of its centre (px)."""
    flat = corners_cam.reshape(-1, 3)
    uv, _ = cv2.projectPoints(flat, np.zeros(3), np.zeros(3), camera.matrix, camera.distortion)
    quad = uv.reshape(-1, 4, 2)
    centre, _ = cv2.projectPoints(
        corners_cam.mean(axis=1), np.zeros(3), np.zeros(3), camera.matrix, camera.distortion
    )
    x, y = quad[..., 0], quad[..., 1]
    xn, yn = np.roll(x, -1, axis=1), np.roll(y, -1, axis=1)
    cross = x * yn - xn * y
    area = cross.sum(axis=1) / 2
    cx = ((x + xn) * cross).sum(axis=1) / (6 * area)
    cy = ((y + yn) * cross).sum(axis=1) / (6 * area)
    return np.column_stack([cx, cy]) - centre.reshape(-1, 2)


def hand_from_left(
    calibration: StereoCalibration,
    left: NDArray[np.uint8],
    right: NDArray[np.uint8],
    board_points_hand_m: NDArray[np.float64],
    layout: Sequence[tuple[int, int]] = PALM_LAYOUT_COLS_ROWS,
    *,
    perspective_passes: int = 2,
) -> HandEyeResult:
    """The pose of the left camera in the hand frame from one stereo view of the palm board.

    `board_points_hand_m` (6, 3): the black-square centres in the hand frame, in layout order (where
    the board sits in the palm, known by construction). The calibration may be at another size than
    the images (it is scaled to them).

    Seen obliquely, a square's area centroid is not the image of its centre: its near half looks
    larger (here ~0.1 px toward each camera at 640x480, i.e. a ~0.2 mm depth bias). After the first
    estimate, `perspective_passes` times, the offset each square's projection would have under the
    present estimate is subtracted from the measured centroids, which are then triangulated again.
    """
    if left.shape != right.shape:
        raise CalibrationImageError(f"left and right images differ in size: {left.shape} vs {right.shape}")
    calibration = _fit(calibration, left.shape)
    board_points_hand_m = np.asarray(board_points_hand_m, dtype=float)
    pts_l = palm_board_centres_px(left, "left", layout)
    pts_r = palm_board_centres_px(right, "right", layout)
    corners_hand = square_corners(board_points_hand_m, layout)
    right_from_left = np.eye(4)
    right_from_left[:3, :3], right_from_left[:3, 3] = calibration.rotation, calibration.translation_m
    fix_l, fix_r = np.zeros_like(pts_l), np.zeros_like(pts_r)
    for k in range(perspective_passes + 1):
        points, gap = midpoint_triangulate(calibration, pts_l - fix_l, pts_r - fix_r)
        pose = rigid_transform(points, board_points_hand_m)
        if k < perspective_passes:
            left_from_hand = np.linalg.inv(pose)
            in_left = corners_hand @ left_from_hand[:3, :3].T + left_from_hand[:3, 3]
            in_right = in_left @ right_from_left[:3, :3].T + right_from_left[:3, 3]
            fix_l = _centroid_offsets(calibration.left, in_left)
            fix_r = _centroid_offsets(calibration.right, in_right)
    mapped = points @ pose[:3, :3].T + pose[:3, 3]
    rms = float(np.sqrt(((mapped - board_points_hand_m) ** 2).sum(axis=1).mean()))
    return HandEyeResult(pose, points, gap, rms)


# --------------------------------------------------------------------------------------------------
# Stereo pair: chessboard views


def find_chessboard(image: NDArray[np.uint8], pattern: tuple[int, int]) -> NDArray[np.float32] | None:
    """(N, 2) inner corners of a chessboard of `pattern` (corners per row, per column) in a canonical
    order, sub-pixel refined; None if the board is not found.

    OpenCV may start from either end of the board. The order is made canonical: the corner grid must
    keep the board's handedness (seen from its printed face, the map grid -> image has a negative
    determinant with x along a row, y along a column and image y down), and the outer square beyond
    the first corner must be the darker of the two end squares (a board with one even and one odd
    number of squares per side has a black square at one end and a white one at the other).
    """
    grey = _grey(image)
    found, corners = cv2.findChessboardCorners(
        grey, pattern, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    )
    if not found:
        return None
    cols, rows = pattern
    grid = corners.reshape(rows, cols, 2)
    spacing = float(np.linalg.norm(grid[0, 1] - grid[0, 0]))
    win = int(np.clip(spacing / 4, 2, 11))
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
    corners = cv2.cornerSubPix(grey, corners, (win, win), (-1, -1), criteria)
    grid = corners.reshape(rows, cols, 2)

    def handedness(g: NDArray) -> float:
        a, b = g[0, -1] - g[0, 0], g[-1, 0] - g[0, 0]
        return float(a[0] * b[1] - a[1] * b[0])

    def outer(g: NDArray) -> float:
        p = g[0, 0] - 0.5 * (g[0, 1] - g[0, 0]) - 0.5 * (g[1, 0] - g[0, 0])
        x = int(np.clip(np.rint(p[0]), 1, grey.shape[1] - 2))  # beyond the image edge: its border
        y = int(np.clip(np.rint(p[1]), 1, grey.shape[0] - 2))
        return float(grey[y - 1 : y + 2, x - 1 : x + 2].mean())

    candidates = [g for g in (grid, grid[::-1, ::-1], grid[::-1, :], grid[:, ::-1]) if handedness(g) < 0]
    best = min(candidates, key=outer)
    return np.ascontiguousarray(best.reshape(-1, 2), dtype=np.float32)


@dataclass(frozen=True)
class StereoFit:
    """The fitted pair and its residuals (reprojection RMS, px at the views' size)."""

    calibration: StereoCalibration
    rms_left_px: float
    rms_right_px: float
    rms_stereo_px: float
    views_used: int
    views_given: int


def stereo_calibrate(
    pairs: Sequence[tuple[NDArray[np.uint8], NDArray[np.uint8]]],
    object_points: NDArray[np.float32],
    pattern: tuple[int, int],
    *,
    min_views: int = 5,
    flags: int = CAMERA_FLAGS,
    refine_intrinsics: bool = True,
    source: str = "",
) -> StereoFit:
    """Both cameras' intrinsics (cv2.calibrateCamera) and the left-to-right transform
    (cv2.stereoCalibrate, which with `refine_intrinsics` refines both cameras jointly from there, else
    keeps them fixed) from chessboard views; pairs where either view misses the board are skipped.
    `flags`: the cameras' model (CAMERA_FLAGS: k1, k2 radial distortion). hand_from_left is the
    identity until hand_from_left() fills it in.

    `object_points` (N, 3): the inner corners in the board frame, in find_chessboard's order.
    """
    if not pairs:
        raise CalibrationImageError("no chessboard views")
    size = pairs[0][0].shape[:2]
    obj, img_l, img_r = [], [], []
    for left, right in pairs:
        if left.shape[:2] != size or right.shape[:2] != size:
            raise CalibrationImageError(f"chessboard views differ in size (expected {size[1]}x{size[0]})")
        c_l, c_r = find_chessboard(left, pattern), find_chessboard(right, pattern)
        if c_l is not None and c_r is not None:
            obj.append(object_points.astype(np.float32))
            img_l.append(c_l.reshape(-1, 1, 2))
            img_r.append(c_r.reshape(-1, 1, 2))
    if len(obj) < min_views:
        raise CalibrationImageError(
            f"the chessboard was found in both views of {len(obj)} of {len(pairs)} pairs, need {min_views}"
        )
    wh = (size[1], size[0])
    rms_l, k_l, d_l, rvec_l, tvec_l = cv2.calibrateCamera(obj, img_l, wh, None, None, flags=flags)
    rms_r, k_r, d_r, rvec_r, tvec_r = cv2.calibrateCamera(obj, img_r, wh, None, None, flags=flags)
    keep = _consistent_pairs(rvec_l, tvec_l, rvec_r, tvec_r)
    if keep.sum() < min_views:
        raise CalibrationImageError(
            f"only {keep.sum()} of {len(obj)} chessboard pairs agree on where the right camera is from the "
            f"left (within {PAIR_POSE_TOLERANCE[0]:g} deg and {1e3 * PAIR_POSE_TOLERANCE[1]:g} mm), "
            f"need {min_views}"
        )
    obj, img_l, img_r = ([v for v, k in zip(views, keep, strict=True) if k] for views in (obj, img_l, img_r))
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-9)
    rms, k_l, d_l, k_r, d_r, r, t, _, _ = cv2.stereoCalibrate(
        obj,
        img_l,
        img_r,
        k_l,
        d_l,
        k_r,
        d_r,
        wh,
        flags=(flags | cv2.CALIB_USE_INTRINSIC_GUESS) if refine_intrinsics else cv2.CALIB_FIX_INTRINSIC,
        criteria=criteria,
    )
    calibration = StereoCalibration(
        CameraIntrinsics(k_l, d_l.ravel(), wh),
        CameraIntrinsics(k_r, d_r.ravel(), wh),
        r,
        t.ravel(),
        np.eye(4),
        source,
    )
    return StereoFit(calibration, float(rms_l), float(rms_r), float(rms), len(obj), len(pairs))


def _consistent_pairs(
    rvec_l: Sequence[NDArray], tvec_l: Sequence[NDArray], rvec_r: Sequence[NDArray], tvec_r: Sequence[NDArray]
) -> NDArray[np.bool_]:
    """Pairs whose own left-to-right pose (from each camera's board pose) lies within
    PAIR_POSE_TOLERANCE of the median pair's."""
    rotations, translations = [], []
    for rl, tl, rr, tr in zip(rvec_l, tvec_l, rvec_r, tvec_r, strict=True):
        r_l, r_r = cv2.Rodrigues(rl)[0], cv2.Rodrigues(rr)[0]
        rotation = r_r @ r_l.T
        rotations.append(rotation)
        translations.append(np.ravel(tr) - rotation @ np.ravel(tl))
    translations_m = np.array(translations)
    median_m = np.median(translations_m, axis=0)
    reference = rotations[int(np.argmin(np.linalg.norm(translations_m - median_m, axis=1)))]
    angle_deg = np.array(
        [np.degrees(np.arccos(np.clip((np.trace(r @ reference.T) - 1) / 2, -1, 1))) for r in rotations]
    )
    offset_m = np.linalg.norm(translations_m - median_m, axis=1)
    return (angle_deg <= PAIR_POSE_TOLERANCE[0]) & (offset_m <= PAIR_POSE_TOLERANCE[1])


def with_hand_from_left(calibration: StereoCalibration, pose: NDArray[np.float64]) -> StereoCalibration:
    """The calibration with its hand_from_left replaced."""
    return replace(calibration, hand_from_left=np.asarray(pose, dtype=float))


def pose_error(estimate: NDArray[np.float64], truth: NDArray[np.float64]) -> tuple[float, float]:
    """(translation error in m, rotation error in degrees) between two 4x4 poses."""
    delta = np.linalg.inv(truth) @ estimate
    angle = Rotation.from_matrix(delta[:3, :3]).magnitude()
    return float(np.linalg.norm(estimate[:3, 3] - truth[:3, 3])), float(np.degrees(angle))
