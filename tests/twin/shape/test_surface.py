"""The 3-D variant on data whose answer is known: the grid and heights of a synthetic cloud, the heights
of a triangle mesh, and a 6-30-G^2 network that learns heights from partly observed samples."""

import numpy as np
import pytest

from twin.interface.errors import ConfigError
from twin.shape.dataset import SurfaceData
from twin.shape.model import ShapeModel
from twin.shape.surface import (
    SurfaceGrid,
    grid_from_cloud,
    height_map,
    mesh_heights,
    surface_points_mm,
)
from twin.shape.surface_train import train_surface


def _tilted_top(rng, n=20000, half_m=0.025, centre=(0.01, -0.005)):
    """A block's top seen from above: z = 135 mm + 0.05 x, over a square 50 mm wide (metres)."""
    xy = rng.uniform(-half_m, half_m, (n, 2)) + centre
    return np.column_stack([xy, 0.135 + 0.05 * (xy[:, 0] - centre[0])])


def test_the_grid_sits_on_the_cloud_and_heights_follow_its_top():
    rng = np.random.default_rng(0)
    top = _tilted_top(rng)
    grid = grid_from_cloud(top, cells=8, margin_mm=1.0)
    assert grid.centre_mm == pytest.approx((10.0, -5.0), abs=0.5)
    assert grid.half_width_mm == pytest.approx(25.0 * 0.96 + 1.0, abs=0.5)  # 2nd-98th percentile + margin
    side = np.column_stack([top[:2000, :2], top[:2000, 2] - 0.02])  # points of a side wall, 20 mm below
    heights = height_map(np.vstack([top, side]), grid)
    centres = grid.centres_mm()
    expected = 135.0 + 0.05 * (centres[:, 0] - 10.0)
    assert np.nanmax(np.abs(heights - expected)) < 0.3  # mm: the top, not the wall below it
    assert np.isnan(height_map(top[:100] + np.array([1.0, 0, 0]), grid)).all()  # off the grid: unobserved
    points = surface_points_mm(heights, grid)
    assert points.shape == (64, 3) and np.allclose(points[:, :2], centres)
    with pytest.raises(ConfigError, match="too few"):
        grid_from_cloud(top[:3])


def test_seen_from_the_side_an_oblique_top_has_its_height_at_each_cell_centre():
    """The paper's lateral view (30 deg above the palm): the block's top is oblique to the view axis
    (1.7 mm of height per mm across a cell); each cell's height is the surface's at the cell centre,
    as the true mesh's, not its front edge (the 90th percentile of the points was 4 mm off)."""
    rng = np.random.default_rng(1)
    top = _tilted_top(rng) * np.array([1.0, 1.0, 0.0]) + np.array([0.0, 0.0, 0.135])  # a flat top
    elevation = np.radians(30.0)
    toward = np.array([np.cos(elevation), 0.0, np.sin(elevation)])  # from the palm's +x side, up 30 deg
    up = np.array([-np.sin(elevation), 0.0, np.cos(elevation)])
    view = np.vstack([np.cross(up, toward), up, toward])
    grid = grid_from_cloud(top, cells=6, view_from_hand=view)
    heights = height_map(top, grid)
    square = 1e-3 * np.array([[-15, -30, 135], [35, -30, 135], [35, 20, 135], [-15, 20, 135]], dtype=float)
    truth = mesh_heights(np.stack([square[[0, 1, 2]], square[[0, 2, 3]]]), grid)  # the cloud's square
    both = np.isfinite(truth) & np.isfinite(heights)
    error = np.abs(heights - truth)[both]
    assert both.sum() >= 10 and np.median(error) < 0.05  # mm (12 cells: the top is foreshortened)
    # at the cloud's edge, where its points end short of the cell's centre, the height stays within
    # theirs: the plane is not extrapolated
    assert error.max() < 1.0
    old_rule = np.array(
        [
            np.percentile(grid.to_view_mm(top)[grid.cell_index(grid.to_view_mm(top)[:, :2]) == c, 2], 90)
            for c in np.flatnonzero(both)
        ]
    )
    assert np.median(np.abs(old_rule - truth[both])) > 2.0  # the front of each cell, not its centre
    # the same points from above: the identity view, heights the top's z
    assert np.nanmax(np.abs(height_map(top, grid_from_cloud(top, cells=6)) - 135.0)) < 0.1


def test_mesh_heights_are_the_highest_surface_above_each_cell():
    grid = SurfaceGrid((0.0, 0.0), 10.0, cells=4)
    square = np.array([[-0.02, -0.02], [0.02, -0.02], [0.02, 0.02], [-0.02, 0.02]])

    def plane(z0_m, slope):
        corners = np.column_stack([square, z0_m + slope * square[:, 0]])
        return np.stack([corners[[0, 1, 2]], corners[[0, 2, 3]]])

    mesh = np.concatenate([plane(0.10, 0.5), plane(0.05, 0.0)])  # a sloped top over a flat bottom
    heights = mesh_heights(mesh, grid)
    assert np.allclose(heights, 100.0 + 0.5 * grid.centres_mm()[:, 0])
    off = SurfaceGrid((100.0, 0.0), 10.0, cells=4)
    assert np.isnan(mesh_heights(mesh, off)).all()


def _synthetic(trajectories=12, per=100, cells=16, seed=0) -> SurfaceData:
    """Heights that sink nonlinearly under three fingers, each cell hidden in 40 % of the samples."""
    rng = np.random.default_rng(seed)
    xs, hs, traj = [], [], []
    where = rng.uniform(-1, 1, (cells, 3))
    for k in range(trajectories):
        t = np.linspace(0, 6, per)
        p = 12000 + 200 * (
            1 + np.sin(2 * np.pi * rng.uniform(0.2, 0.8, 3) * t[:, None] + rng.uniform(0, 6, 3))
        )
        torque = 0.2 + 1e-3 * (p - 12000)
        dent = np.tanh((p - 12200) / 150)
        xs.append(np.column_stack([p, torque]))
        hs.append(135.0 - 2.0 * np.tanh(dent @ where.T))
        traj.append(np.full(per, k))
    heights = np.concatenate(hs)
    truth = heights.copy()
    heights[rng.random(heights.shape) < 0.4] = np.nan
    grid = SurfaceGrid((0.0, 0.0), 20.0, cells=4)
    return SurfaceData(
        np.concatenate(xs), heights, truth, np.concatenate(traj), dict.fromkeys(range(12), grid)
    )


def test_the_surface_network_learns_partly_observed_heights_and_beats_the_baselines(tmp_path):
    data = _synthetic()
    result = train_surface(data, epochs=1500, seed=0)
    errors = {e.name.split()[0]: e for e in result.evaluations}
    assert errors["network"].error_mm < 0.5 * errors["linear"].error_mm
    assert errors["network"].error_mm < errors["nearest"].error_mm
    assert errors["network"].error_mm < 0.1  # mm, on held-out trajectories
    # every cell is scored against the truth, seen or not, and the network fills in the hidden ones
    assert errors["network"].truth_error_mm < 0.1 and result.measured_truth_error_mm == 0.0
    assert result.observed_fraction == pytest.approx(0.6, abs=0.03) and result.modelled_cells == 16
    again = ShapeModel.load(result.model.save(tmp_path / "m"))
    assert again.target == "surface" and again.predict(data.inputs[0]).shape == (16,)
    assert np.allclose(again.predict(data.inputs[:5]), result.model.predict_torch(data.inputs[:5]), atol=1e-3)
