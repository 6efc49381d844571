"""The FEM's condensation onto the contact candidates: one partial factorization against right-hand sides.

The calibration's FEM (twin/sim/fem.py) condenses the stiffness onto the contact candidates. It does so
by one partial factorization (`fem.condense`: the candidates ordered last, the rest by METIS's nested
dissection; the trailing block of SuperLU's factors is the Schur complement). The baseline here is how it
was done before: factor the rest by minimum degree, then solve for the candidates' columns as right-hand
sides, 400 at a time. Both solve the same cases in one process, the whole of `indentation_force_per_pa`
timed with a wall clock, and their forces are compared: the densest level of the scans' FEM (the
20,480-triangle egg of `benchmarks/scan_foams.py`) and the library block's. Beside them, the stiffness
assembled at the quadrature order the FEM uses (2) and at scikit-fem's default (4).
"""

from __future__ import annotations

import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

RHS_BLOCK = 400
"""Right-hand sides per solve in the baseline, as the FEM had them (bounded memory)."""


@dataclass(frozen=True)
class _BySolves:
    """The baseline's condensation, shaped as fem.Condensed: S, the dofs' order and the rest's field."""

    S: np.ndarray
    order: np.ndarray
    lu: Any
    K_rc: Any

    def displacement(self, u_cand: np.ndarray) -> np.ndarray:
        return np.concatenate([self.lu.solve(-(self.K_rc @ u_cand)), u_cand])


def condense_by_solves(K: Any, rest: np.ndarray, cand: np.ndarray) -> _BySolves:
    """The baseline: K_rr factored by SuperLU's minimum degree, then S = K_cc - K_cr K_rr^-1 K_rc one block
    of candidate columns at a time."""
    from twin.sim.fem import factor_spd

    lu = factor_spd(K[rest][:, rest])
    K_rc = K[rest][:, cand].tocsc()
    S = K[cand][:, cand].toarray()
    for k0 in range(0, len(cand), RHS_BLOCK):
        S[:, k0 : k0 + RHS_BLOCK] -= K_rc.T @ lu.solve(K_rc[:, k0 : k0 + RHS_BLOCK].toarray())
    return _BySolves(S=0.5 * (S + S.T), order=np.concatenate([rest, cand]), lu=lu, K_rc=K_rc)


def _assembly(mesh: Any, poisson: float) -> dict:
    """The FEM's stiffness assembled at quadrature order 2 (fem.indentation_force_per_pa's: exact for
    quadratic tetrahedra on straight sides) and at scikit-fem's default (4 for P2): walls, and the largest
    entry of their difference against the largest of K."""
    from skfem import Basis, ElementTetP2, ElementVector, MeshTet, asm
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    skmesh = MeshTet(np.ascontiguousarray(mesh.points_m.T), np.ascontiguousarray(mesh.tets.T))
    form = linear_elasticity(*lame_parameters(1.0, poisson))
    timed = {}
    for order in (2, None):
        t0 = time.perf_counter()
        basis = Basis(skmesh, ElementVector(ElementTetP2()), **({"intorder": order} if order else {}))
        K = asm(form, basis).tocsr()
        timed[order] = (time.perf_counter() - t0, K)
    (order2_s, k2), (default_s, k4) = timed[2], timed[None]
    return {"order2_s": order2_s, "default_s": default_s, "k_rel_diff": abs(k2 - k4).max() / abs(k4).max()}


def _cases(tmp: Path, quick: bool) -> list[tuple[str, Any, Any]]:
    """(label, foam, refinement level) per case: the library block's finest level, and (not quick) the
    20,480-triangle scan's."""
    from twin.sim import calibration
    from twin.sim.example_shapes import write_scan_like_surface
    from twin.sim.foam import LIBRARY, mesh_object

    cases = [("library block", LIBRARY["block"], calibration.FEM_LEVELS_M[0 if quick else -1])]
    if not quick:
        path = write_scan_like_surface(tmp / "egg_5.stl", (32.0, 26.0, 22.0), egg=0.15, subdivisions=5)
        egg = mesh_object(path, LIBRARY["block"].with_overrides(fidelity="fast"))
        cases.append(("20,480-triangle scan", egg, calibration.FEM_LEVELS_M[-1]))
    return cases


def run(quick: bool = False) -> dict:
    """Each case solved by both condensations, in a calibration cache of its own (every FEM solved)."""
    cache = os.environ.get("TWIN_CACHE_DIR")
    with tempfile.TemporaryDirectory() as tmp:
        os.environ["TWIN_CACHE_DIR"] = str(Path(tmp) / "cache")
        try:
            rows = [_compare(label, foam, level) for label, foam, level in _cases(Path(tmp), quick)]
        finally:  # the caller's cache back
            if cache is None:
                os.environ.pop("TWIN_CACHE_DIR", None)
            else:
                os.environ["TWIN_CACHE_DIR"] = cache
    return {"rows": rows}


def _compare(label: str, foam: Any, level: tuple[float, float]) -> dict:
    """One case solved by both condensations, the partial factorization first: their walls and forces."""
    from twin.sim import calibration, fem

    tips = calibration.fingertip_geoms(foam)
    mesh = calibration.reference_mesh(foam, *level)
    partial, timed = fem.condense, {}
    for method, condense in (("partial factorization", partial), ("right-hand sides", condense_by_solves)):
        fem.condense = condense  # indentation_force_per_pa looks it up at each call
        try:
            t0 = time.perf_counter()
            result = fem.indentation_force_per_pa(
                mesh, foam.poisson, calibration._gap_fn(tips), calibration.DEPTHS_M
            )
            timed[method] = (time.perf_counter() - t0, result)
        finally:
            fem.condense = partial
    (new_s, new), (old_s, old) = timed["partial factorization"], timed["right-hand sides"]
    pairs = zip(new.force_per_pa_n, old.force_per_pa_n, strict=True)
    return _assembly(mesh, foam.poisson) | {
        "case": label,
        "edge_top_mm": level[0] * 1e3,
        "dofs": new.dofs,
        "candidates": new.candidates,
        "force_per_pa_n": list(new.force_per_pa_n),
        "new_s": new_s,
        "old_s": old_s,
        "max_rel_diff": max(abs(a / b - 1) for a, b in pairs),
    }


def to_markdown(results: dict) -> str:
    """The BENCHMARKS.md section."""
    lines = [
        "## The FEM's condensation onto the contact candidates (`benchmarks/fem_condensation.py`)",
        "",
        "`indentation_force_per_pa` (`twin/sim/fem.py`, the calibration's FEM: the three level links 2 / 4 / "
        "6 mm into the top) timed with a wall clock, the same case twice in one process: *partial "
        "factorization*, `fem.condense` (the candidates ordered last, the rest by METIS's nested dissection; "
        "the trailing block of SuperLU's factors is the Schur complement); *right-hand sides*, the baseline "
        "(the rest factored by SuperLU's minimum degree, then one solve a candidate, 400 at a time). Both "
        "include the assembly and the contact solve. *difference*: the largest relative difference of their "
        "three forces. *assembly*: the stiffness alone at quadrature order 2 (what the FEM uses: exact for "
        "quadratic tetrahedra on straight sides) against scikit-fem's default order 4, and the largest entry "
        "of their difference against K's largest.",
        "",
        "| case | element near the contact (mm) | dofs | candidates | force at 2 / 4 / 6 mm (N per Pa) "
        "| right-hand sides (s) | partial factorization (s) | **speed-up** | difference "
        "| assembly, order 4 / 2 (s) | K difference |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results["rows"]:
        force = " / ".join(f"{f:.4g}" for f in r["force_per_pa_n"])
        lines.append(
            f"| {r['case']} | {r['edge_top_mm']:g} | {r['dofs']:,} | {r['candidates']:,} | {force} "
            f"| {r['old_s']:.1f} | {r['new_s']:.1f} | **{r['old_s'] / r['new_s']:.1f}x** "
            f"| {r['max_rel_diff']:.1e} | {r['default_s']:.1f} / {r['order2_s']:.1f} "
            f"| {r['k_rel_diff']:.0e} |"
        )
    return "\n".join(lines) + "\n"
