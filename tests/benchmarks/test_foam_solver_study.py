"""The foam solver study measures what it claims: variants set on the model, same state, real differences."""

import mujoco
import numpy as np

from benchmarks import foam_solver_study as study


def test_configure_sets_every_option_and_the_armature_takes_effect():
    backend, state = study.grasped_state(resolution=5, settle_s=0.3)
    model = backend.world.model
    dofs = study.foam_dofs(model)
    assert len(dofs) == 3 * model.nflexvert  # dof="full": three slides per vertex, nothing else
    heavy = study.Variant("heavy", solver="Newton", iterations=60, armature_kg=1e-3, disable=("WARMSTART",))
    study.configure(model, heavy)
    assert model.opt.solver == mujoco.mjtSolver.mjSOL_NEWTON and model.opt.iterations == 60
    assert model.opt.disableflags == mujoco.mjtDisableBit.mjDSBL_WARMSTART
    assert np.all(model.dof_armature[dofs] == 1e-3)
    data = mujoco.MjData(model)
    mujoco.mj_setState(model, data, state, study.STATE)
    heavy_m = _mass_diagonal(model, data, dofs[:6])  # the armature is in the mass matrix the solver uses
    study.configure(model, study.BASELINE)  # and the baseline takes it all back
    assert model.opt.solver == mujoco.mjtSolver.mjSOL_CG and model.opt.disableflags == 0
    assert np.all(model.dof_armature[dofs] == 0.0)
    assert np.allclose(heavy_m - _mass_diagonal(model, data, dofs[:6]), 1e-3)


def _mass_diagonal(model: mujoco.MjModel, data: mujoco.MjData, dofs: np.ndarray) -> np.ndarray:
    """Diagonal entries of the mass matrix at `dofs`, as mj_step builds it (M e_i)."""
    mujoco.mj_forward(model, data)
    out, unit, column = [], np.zeros(model.nv), np.zeros(model.nv)
    for i in dofs:
        unit[:] = 0.0
        unit[i] = 1.0
        mujoco.mj_mulM(model, data, column, unit)
        out.append(column[i])
    return np.array(out)


def test_quick_study_compares_variants_on_one_state():
    results = study.run(quick=True)
    rows = {r["label"]: r for r in results["steps"]["rows"]}
    base = rows[study.BASELINE.label]
    assert base["ratio"] == 1.0 and base["iterations"] == study.BASELINE.iterations  # CG runs to its cap
    assert rows[study.QUICK_VARIANT.label]["iterations"] <= study.QUICK_VARIANT.iterations
    assert results["steps"]["reference"]["force_n"] > 0  # the foam is held: there is a force to compare
    assert base["physics"]["mean_force_n"] > 0  # CG stopped at its cap is not the converged solve
    rig = {r["label"]: r for r in results["rig"]}
    assert rig[study.BASELINE.label]["diff"]["force_n"] == 0.0  # a run is deterministic
    assert rig[study.QUICK_VARIANT.label]["rtf"] > 0
    text = study.to_markdown(results)
    assert "| baseline: CG, tol 1e-5, 200 it |" in text and "| 5 | CG, 100 it, armature 1e-4 kg |" in text
