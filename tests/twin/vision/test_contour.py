"""Contours: resampling is stable (anchor, direction, spacing), and on the twin the back-projected
contour matches the true visible silhouette and lands on the sphere's equator in the hand frame."""

import cv2
import numpy as np
import pytest

from twin.sim.backend import SimBackend
from twin.sim.foam import get_object
from twin.vision.contour import (
    ContourError,
    ContourExtractor,
    contour_error_px,
    outer_contour,
    resample,
    to_hand_plane,
)
from twin.vision.reconstruct import Rectifier

pytestmark = pytest.mark.xdist_group("realtime")  # renders: keep off the wall-clock tests


def _disc(h=120, w=160, center=(80, 60), r=30):
    mask = np.zeros((h, w), np.uint8)
    cv2.circle(mask, center, r, 1, -1)
    return mask.astype(bool)


def test_resampling_is_even_anchored_on_top_and_counter_clockwise():
    pts = resample(outer_contour(_disc()), 32)
    assert pts.shape == (32, 2)
    assert pts[0] == pytest.approx([80, 30], abs=1.0)  # straight above the centroid
    steps = np.linalg.norm(np.diff(np.vstack([pts, pts[:1]]), axis=0), axis=1)
    assert steps.std() / steps.mean() < 0.05  # equal arc length
    assert pts[8, 0] < 80  # a quarter turn later: left of centre (counter-clockwise on screen)
    # the same shape walked the other way gives the same contour
    assert contour_error_px(resample(outer_contour(_disc())[::-1], 32), pts) < 0.5


def test_translation_moves_every_point_by_the_same_shift():
    a = resample(outer_contour(_disc(center=(80, 60))), 24)
    b = resample(outer_contour(_disc(center=(90, 55))), 24)
    assert np.allclose(b - a, [10, -5], atol=0.6)


@pytest.mark.parametrize("mask", [np.zeros((50, 50), bool), np.eye(50, dtype=bool)[:3]])
def test_nothing_to_trace_is_one_clear_error(mask):
    with pytest.raises(ContourError):
        outer_contour(mask)


def test_on_the_twin_the_contour_matches_the_true_silhouette_within_a_pixel():
    foam = get_object("sphere")
    backend = SimBackend(foam, stereo=True)
    backend.connect()
    try:
        calibration = backend.stereo.calibration()
        rectifier = Rectifier(calibration)
        box = backend.object_box(rectifier)
        frame = backend.stereo.read()
        left = rectifier.remap(frame.left)
        truth = backend.surface_truth(rectifier)
    finally:
        backend.disconnect()
    centre_z = foam.size_m[2] / 2 + 0.075  # resting on the palm plate (top face at z = 75 mm)
    contour = ContourExtractor(rectifier, left, box, points=32, plane_z_m=centre_z)(left)
    measured = contour.pixels
    true = resample(outer_contour(truth.visible), 32)
    assert contour_error_px(measured, true) < 1.0
    # the silhouette of a sphere seen from above is its equator: 35 mm from its axis, at its centre height
    radius_mm = np.linalg.norm(contour.hand_mm - contour.hand_mm.mean(axis=0), axis=1)
    assert np.median(radius_mm) == pytest.approx(1e3 * foam.size_m[0] / 2, abs=1.5)
    assert np.allclose(to_hand_plane(measured, rectifier, centre_z)[:, :2] * 1e3, contour.hand_mm)
