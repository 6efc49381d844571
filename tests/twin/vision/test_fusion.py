"""Tactile fill-in: the pads' points join the visual cloud and the mesh, without bridging holes."""

import numpy as np

from twin.vision.fusion import TACTILE, VISION, fuse, pressed_taxels


def _camera() -> np.ndarray:
    """A pinhole 0.4 m above the hand frame's origin looking down -z (hand frame = world here)."""
    k = np.array([[400.0, 0, 160], [0, 400.0, 120], [0, 0, 1]])
    cam_from_hand = np.array([[1.0, 0, 0, 0], [0, -1.0, 0, 0], [0, 0, -1.0, 0.4]])
    return k @ cam_from_hand


def test_tactile_points_fill_the_hole_a_finger_leaves():
    xs = np.arange(-0.03, 0.0301, 0.002)
    grid = np.array([(x, y, 0.1) for x in xs for y in xs])
    hidden = (np.abs(grid[:, 0]) < 0.009) & (np.abs(grid[:, 1]) < 0.009)  # a fingertip on top
    taxels = np.array([(x, y, 0.1) for x in (-0.006, 0.0, 0.006) for y in (-0.006, 0.0, 0.006)])
    fused = fuse(grid[~hidden], taxels, _camera(), max_edge_m=0.004, max_tactile_edge_m=0.009)
    assert fused.points_hand.dtype == np.float32 and fused.points_hand.shape == (len(grid[~hidden]) + 9, 3)
    assert (fused.source == VISION).sum() == (~hidden).sum() and (fused.source == TACTILE).sum() == 9
    corners = fused.points_hand[fused.triangles]
    edges = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2)
    assert edges.max() <= 0.009 + 1e-6
    touched = np.unique(fused.triangles[(fused.source[fused.triangles] == TACTILE).any(axis=1)])
    assert (fused.source[touched] == VISION).any()  # the taxels are stitched to the visible surface
    # The mesh covers the square without the hole: its area is the square's (60 mm side).
    a, b, c = (corners[:, i] for i in range(3))
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum()
    assert abs(area - 0.06**2) / 0.06**2 < 0.02
    without = fuse(grid[~hidden], np.zeros((0, 3)), _camera(), max_edge_m=0.004)
    c2 = without.points_hand[without.triangles]
    area2 = 0.5 * np.linalg.norm(np.cross(c2[:, 1] - c2[:, 0], c2[:, 2] - c2[:, 0]), axis=1).sum()
    assert area2 < area - 0.015**2  # the hole stays open without the pads


def test_degenerate_inputs_give_empty_meshes():
    line = np.array([[0.0, 0.0, 0.1], [0.001, 0.0, 0.1], [0.002, 0.0, 0.1]])
    assert len(fuse(line, np.zeros((0, 3)), _camera()).triangles) == 0
    assert len(fuse(np.zeros((0, 3)), np.zeros((0, 3)), _camera()).points_hand) == 0


def test_pressed_taxels_threshold():
    pressure = np.array([0.0, 0.4, 0.6, 30.0])
    taxels = np.arange(12.0).reshape(4, 3)
    np.testing.assert_array_equal(pressed_taxels(pressure, taxels), taxels[2:])
