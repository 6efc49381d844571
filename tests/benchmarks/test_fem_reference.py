"""The finite-element reference (benchmarks/fem_reference.py) against analytic mechanics and its own cache."""

import math

import numpy as np
import pytest

from benchmarks import fem_reference as fem
from twin.sim.foam import LIBRARY


def test_uniaxial_compression_between_frictionless_plates_is_e_a_strain():
    """Laterally free compression: F = E·A·ε exactly (the quadratic field holds the linear solution)."""
    s = fem.setup_for("block", "punch_slipping")
    depth_m = 0.003
    force = fem.uniaxial_force_per_pa(s, h_fine_m=0.01, depth_m=depth_m)
    x, y, z = s.size_m
    assert force == pytest.approx(1.0 * x * z * depth_m / y, rel=0.01)


def test_rigid_sphere_on_a_large_block_follows_hertz():
    """Frictionless rigid sphere on an elastic half-space, a = sqrt(R d) << block size.

    Hertz: F = (4/3) E* sqrt(R) d^1.5 with E* = E / (1 - nu^2) for a rigid indenter
    (K. L. Johnson, Contact Mechanics, Cambridge University Press, 1985, eqs. 4.22-4.23).
    """
    radius_m, depth_m, nu = 0.012, 0.0003, 0.3
    s = fem.Setup(
        shape="block",
        size_m=(0.06, 0.06, 0.06),
        poisson=nu,
        indenter="sphere",
        far_face_fixed=True,
        sphere_radius_m=radius_m,
        reach_m=0.003,
    )
    assert math.sqrt(radius_m * depth_m) < s.size_m[0] / 20  # contact radius << block
    res = fem.solve_setup(s, h_fine_m=0.0006, depths_m=(depth_m,))
    assert res["rigid_modes_left"] == 0
    hertz = 4.0 / 3.0 / (1 - nu**2) * math.sqrt(radius_m) * depth_m**1.5
    assert res["solutions"][0]["force_per_pa_n"] == pytest.approx(hertz, rel=0.10)


def test_cache_is_what_the_code_computes():
    """Re-solve the block's bonded punch on the coarsest mesh: the cached convergence entry must match."""
    cached = fem.load_cache()["cases"]["block/punch_bonded"]["convergence"]
    s = fem.setup_for("block", "punch_bonded")
    res = fem.solve_setup(s, fem.PUNCH_LEVELS_M[0], (0.006,))
    assert cached["h_fine_m"][0] == fem.PUNCH_LEVELS_M[0]
    assert res["solutions"][0]["force_per_pa_n"] == pytest.approx(cached["force_6mm_per_pa_n"][0], rel=1e-4)


def test_flat_punch_on_the_block_is_linear_in_depth_and_balanced_by_the_wall():
    s = fem.setup_for("block", "punch_slipping")
    res = fem.solve_setup(s, fem.PUNCH_LEVELS_M[0], (0.002, 0.006))
    f2, f6 = (sol["force_per_pa_n"] for sol in res["solutions"])
    assert f6 == pytest.approx(3 * f2, rel=1e-9)
    assert res["solutions"][1]["wall_per_pa_n"] == pytest.approx(f6, rel=1e-6)


def test_cache_matches_the_issue_audit_with_its_wall():
    """The issue's scikit-fem audit: library block, bonded punch, 3.9 / 7.8 / 11.7 N at 2 / 4 / 6 mm."""
    check = fem.load_cache()["extras"]["issue_crosscheck"]
    audit = np.array(check["issue_audit_n"])
    assert np.allclose(check["punch_bonded_wall_bonded_n"], audit, rtol=0.03)
    # the bench's frictionless wall: a few percent softer, and a slipping punch softer still
    ours = np.array(fem.load_cache()["cases"]["block/punch_bonded"]["force_n"])
    assert np.all(ours < np.array(check["punch_bonded_wall_bonded_n"]))
    slipping = np.array(fem.load_cache()["cases"]["block/punch_slipping"]["force_n"])
    assert np.all(slipping < ours)


def test_cache_is_converged_and_complete():
    cache = fem.load_cache()
    assert set(cache["cases"]) == set(fem.CASES)
    for name, entry in cache["cases"].items():
        assert entry["convergence"]["rel_change"][-1] < 0.01, name
        assert entry["young_pa"] == LIBRARY[entry["object"]].young_pa
        forces = np.array(entry["force_n"])
        assert np.all(np.diff(forces) > 0), name
        assert np.allclose(entry["wall_force_n"], forces, rtol=1e-4, atol=2e-5), name  # equilibrium
        depths, f = fem.force_depth(name, cache)
        assert np.array_equal(f, forces) and len(depths) == len(f)
        prof = fem.profile(name, cache)
        assert prof["uy_m"].max() <= 0.006 + 1e-9 and prof["uy_m"].max() > 0.004, name


def test_sphere_contact_stiffens_like_hertz():
    """Contact force grows clearly faster than linearly under the sphere (Hertz: d^1.5), unlike the punch."""
    for name in ("sphere/sphere", "block/sphere"):
        depths, f = fem.force_depth(name)
        slope = np.polyfit(np.log(depths[:4]), np.log(f[:4]), 1)[0]
        assert slope > 1.3, (name, slope)


def test_neo_hookean_forms_reduce_to_linear_elasticity_at_small_strain():
    """The hyperelastic residual and tangent at u -> 0 are the linear stiffness (same Lamé parameters)."""
    from skfem import Basis, ElementTetP2, ElementVector, MeshTet, asm
    from skfem.helpers import det, inv, transpose
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    mesh = MeshTet.init_tensor(*[np.linspace(0, 0.01, 3)] * 3)
    basis = Basis(mesh, ElementVector(ElementTetP2()))
    lam, mu = lame_parameters(1.0, 0.3)
    residual, tangent = fem._neo_hookean_forms(mu, lam)
    u = 1e-9 * np.random.default_rng(0).standard_normal(basis.N)
    F = basis.interpolate(u).grad + np.eye(3)[:, :, None, None]
    kin = {"FinvT": transpose(inv(F)), "lnJ": np.log(det(F))}
    K = asm(linear_elasticity(lam, mu), basis)
    r = asm(residual, basis, F=F, **kin)
    assert np.linalg.norm(r - K @ u) < 1e-5 * np.linalg.norm(K @ u)
    assert abs(asm(tangent, basis, **kin) - K).max() < 1e-5 * abs(K).max()


def test_neo_hookean_entry_is_close_to_linear_at_small_depth():
    nh = fem.load_cache()["extras"]["neo_hookean"]
    ratio = np.array(nh["ratio"])
    assert 0.98 < ratio[0] < 1.03 and np.all(np.diff(ratio) > 0)  # stiffens with depth, like the audit's foam
