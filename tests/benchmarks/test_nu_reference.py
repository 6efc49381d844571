"""The bulge reader of benchmarks/nu_reference.py on fields whose answer is known."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks import nu_reference


def _box_points(size_m, palm_z_m, n=6):
    axes = [np.linspace(-s / 2, s / 2, n) for s in size_m[:2]] + [np.linspace(0, size_m[2], n) + palm_z_m]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def test_a_uniform_lateral_strain_nu_times_the_axial_reads_as_nu():
    """An affine squeeze: eps_z = -d/h on every point, eps_x = nu d/h, a rigid shift along x on top (which
    the width cancels): the reader gives nu at every depth, whatever the shift."""
    size, palm_z, nu = (0.06, 0.06, 0.07), 0.075, 0.27
    rest = _box_points(size, palm_z)
    depths = (0.002, 0.004, 0.006)
    moved = []
    for d in depths:
        at = rest.copy()
        at[:, 0] *= 1 + nu * d / size[2]
        at[:, 2] = palm_z + (at[:, 2] - palm_z) * (1 - d / size[2])
        at[:, 0] += 0.003  # the object slid in the grasp
        moved.append(at)
    assert nu_reference.lateral_ratio(rest, moved, depths, size, palm_z) == pytest.approx([nu] * 3)


def test_a_face_with_no_points_in_the_band_is_refused():
    rest = np.array([[0.03, 0.0, 0.075 + 0.069], [-0.03, 0.0, 0.075 + 0.069]])  # all near the top
    with pytest.raises(ValueError, match="x face's band"):
        nu_reference.face_shift_m(rest, rest, 1.0, 0.075, 0.07)
