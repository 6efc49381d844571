"""The bulge reader and the map of benchmarks/nu_reference.py on fields whose answer is known."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks import nu_reference

PALM_Z_M = 0.075


def _box_points(size_m, palm_z_m, n=6):
    axes = [np.linspace(-s / 2, s / 2, n) for s in size_m[:2]] + [np.linspace(0, size_m[2], n) + palm_z_m]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


@pytest.mark.parametrize("depth_m", [0.002, 0.006])
def test_a_uniform_lateral_strain_nu_times_the_axial_reads_as_nu(depth_m: float):
    """An affine squeeze: eps_z = -d/h on every point, eps_x = nu d/h, and a rigid shift along x (which
    the width cancels): the reader gives nu, whatever the shift."""
    size, nu = (0.06, 0.06, 0.07), 0.27
    rest = _box_points(size, PALM_Z_M)
    moved = rest.copy()
    moved[:, 0] *= 1 + nu * depth_m / size[2]
    moved[:, 2] = PALM_Z_M + (moved[:, 2] - PALM_Z_M) * (1 - depth_m / size[2])
    moved[:, 0] += 0.003  # the object slid in the grasp
    assert nu_reference.lateral_ratio(rest, moved, depth_m, size, PALM_Z_M) == pytest.approx(nu)


def test_a_foam_with_no_point_in_the_cameras_band_is_refused():
    rest = np.array([[0.03, 0.0, PALM_Z_M + 0.069], [-0.03, 0.0, PALM_Z_M + 0.069]])  # all near the top
    with pytest.raises(ValueError, match="band"):
        nu_reference.face_shift_m(rest, rest, 1.0, PALM_Z_M, 0.07)


def test_the_calibration_load_map_and_its_inverse_meet_on_the_fem_line():
    """A twin's nu maps to the material whose FEM ratio is the twin's ratio there, and back."""
    row = {"poisson": [0.2, 0.35], "fem": [0.181, 0.330], "twin": [0.112, 0.239]}
    for twin_nu in (0.2, 0.3, 0.35):
        material = nu_reference.material_from_twin(row, twin_nu)
        fem = np.interp(material, row["poisson"], row["fem"], left=np.nan, right=np.nan)
        twin = np.interp(twin_nu, row["poisson"], row["twin"])
        assert np.isnan(fem) or fem == pytest.approx(twin)
        assert nu_reference.twin_from_material(row, material) == pytest.approx(twin_nu)
    assert nu_reference.material_from_twin(row, 0.2) < 0.2  # a twin that bulges less reads nu high
