"""The twin's bulge against the material's (twin.sim.bulge): the reader on fields whose answer is known,
the map through its two lines, and a map made at first use against the FEM, stored and read back."""

from __future__ import annotations

import numpy as np
import pytest

from twin.sim import bulge
from twin.sim.foam import LIBRARY

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
    assert bulge.lateral_ratio(rest, moved, depth_m, size, PALM_Z_M) == pytest.approx(nu)


def test_a_foam_with_no_point_in_the_cameras_band_is_refused():
    rest = np.array([[0.03, 0.0, PALM_Z_M + 0.069], [-0.03, 0.0, PALM_Z_M + 0.069]])  # all near the top
    with pytest.raises(ValueError, match="band"):
        bulge.face_shift_m(rest, rest, 1.0, PALM_Z_M, 0.07)


def test_every_library_foam_ships_a_map_for_both_presets():
    for name, foam in LIBRARY.items():
        for fidelity in ("fast", "faithful"):
            made = bulge.lookup(foam.with_overrides(fidelity=fidelity))
            assert made is not None and made.fidelity == fidelity, (name, fidelity)
            assert made.fem_slope > 0 and made.provenance["mujoco"]  # the FEM bulges more at a larger nu


def test_the_map_reads_a_twins_nu_as_the_material_whose_fem_bulge_is_the_twins():
    made = bulge.lookup(LIBRARY["block"])
    assert made is not None
    for twin_nu in (0.2, 0.27, 0.35):
        material = made.material_poisson(twin_nu)
        twin_ratio = np.interp(twin_nu, made.poisson, made.twin_ratio)
        fem_ratio = made.fem_ratio[0] + made.fem_slope * (material - made.poisson[0])
        assert fem_ratio == pytest.approx(twin_ratio)
    said = made.equivalent(0.27, (0.24, 0.3))
    low, high = said["poisson_ci95"]
    assert said["within_materials"] and low < said["poisson"] < high
    # a twin read no material of the shape bulges like: no interval, and said so
    beyond = bulge.BulgeMap("fast", (0.2, 0.35), (0.06, 0.08), (0.17, 0.32), 0.006, {})
    said = beyond.equivalent(0.3, (0.25, 0.35))
    assert not said["within_materials"] and said["poisson_ci95"] is None and said["poisson"] > 0.5
    flat = bulge.BulgeMap("fast", (0.2, 0.35), (0.06, 0.06), (0.17, 0.32), 0.006, {})
    assert "does not tell nu" in flat.equivalent(0.3, (0.25, 0.35))["unavailable"]


def test_a_map_is_made_at_first_use_stored_and_read_back(tmp_path, monkeypatch):
    """A sphere of no library size (the cheapest FEM): measured against the FEM on first use with a
    progress line, stored in the user's cache with its provenance, read back the second time; and the
    library sphere measured now is the map the package ships (the shipped file is this code's)."""
    monkeypatch.setenv("TWIN_CACHE_DIR", str(tmp_path))
    foam = LIBRARY["sphere"].with_overrides(size_m=(0.06, 0.06, 0.06))
    assert bulge.lookup(foam) is None
    said: list[str] = []
    made = bulge.bulge_map(foam, progress=said.append)
    assert len(said) == 1 and "against an FEM" in said[0]
    stored = list((tmp_path / "foam_calibration" / "bulge").glob("*.json"))
    assert len(stored) == 1 and made.provenance["fem_edges_m"] == list(bulge.FEM_EDGES_M)
    again = bulge.bulge_map(foam, progress=said.append)
    assert again == made and len(said) == 1
    assert made.fem_slope > 0
    library = LIBRARY["sphere"]
    fresh, shipped = bulge.measure(library), bulge.lookup(library)
    assert shipped is not None
    assert fresh.fem_ratio == pytest.approx(shipped.fem_ratio, abs=2e-3)
    assert fresh.twin_ratio == pytest.approx(shipped.twin_ratio, abs=2e-3)
