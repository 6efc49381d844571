"""An independent mechanics reference for the foams: small-strain linear elasticity (scikit-fem, quadratic
tetrahedra) under rigid indenters with frictionless unilateral contact.

It is the reference the flex foam is calibrated against (twin.sim.calibration), so it shares nothing with
MuJoCo but the geometry: gmsh meshes the object's volume, scikit-fem assembles the stiffness (E = 1 Pa:
force is proportional to E), one partial SuperLU factorization condenses it onto the candidate contact
dofs, and a primal-dual active set (Hüeber & Wohlmuth's semismooth Newton form: add the penetrating
nodes, drop the tensile ones, repeat) solves the contact at each depth. The indenters move along -z by
the depth from first touch; the object's supported nodes are held (the palm under a grasp: friction holds it).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from twin.sim.tetmesh import TetMesh

MAX_ACTIVE_SET_ITERATIONS = 60
MAX_CANDIDATE_DOFS = 4000
"""The dense contact problem grows as the square of its candidates; more means the gap reach is too wide."""

GapFn = Callable[[np.ndarray], np.ndarray]
"""Rest gap along +z (m) from each point (n, 3) to the indenters' surface; inf where none is above."""


@dataclass(frozen=True)
class IndentationResult:
    """Indenter force per pascal of Young's modulus at each depth, and what the solve cost."""

    depths_m: tuple[float, ...]
    force_per_pa_n: tuple[float, ...]
    support_per_pa_n: tuple[float, ...]
    """The plate's reaction (equilibrium check: equal to the indenter force)."""
    dofs: int
    candidates: int
    iterations: tuple[int, ...]
    vertex_displacement_m: tuple[np.ndarray, ...] = ()
    """With `keep_displacement`: each depth's displacement (3, vertices) at the mesh's vertices (the
    indenters impose depths, so it does not scale with E)."""


def indentation_force_per_pa(
    mesh: TetMesh,
    poisson: float,
    gap_fn: GapFn,
    depths_m: tuple[float, ...],
    reach_m: float = 0.002,
    held_m: float = 0.001,
    keep_displacement: bool = False,
) -> IndentationResult:
    """Press rigid frictionless indenters into `mesh` along -z by each depth from first touch, the object
    resting on a rigid plate at its lowest point (unilateral in z; the nodes within `held_m` of the plate
    held sideways, as the palm's friction holds them).

    `gap_fn`: the indenters' rest gap above each point. Surface nodes within `reach_m` beyond the deepest
    depth of an indenter, or within `reach_m` of the plate, are the contact candidates."""
    from skfem import Basis, ElementTetP2, ElementVector, MeshTet, asm
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    skmesh = MeshTet(np.ascontiguousarray(mesh.points_m.T), np.ascontiguousarray(mesh.tets.T))
    # Quadrature of order 2 integrates this stiffness exactly: the strains of quadratic elements on straight
    # tetrahedra are linear, their products quadratic. scikit-fem's default (4, for P2) gives the same K to
    # 6e-16 in 2.3x the time (benchmarks/fem_condensation.py).
    basis = Basis(skmesh, ElementVector(ElementTetP2()), intorder=2)
    K = asm(linear_elasticity(*lame_parameters(1.0, poisson)), basis).tocsr()
    xyz = basis.doflocs
    surface = basis.get_dofs()
    surface_z = surface.all("u^3")
    gap_above = np.asarray(gap_fn(xyz[:, surface_z].T), dtype=float)
    gap_above -= float(np.min(gap_above))  # depths count from first touch
    gap_below = xyz[2, surface_z] - float(xyz[2].min())
    top = gap_above < max(depths_m) + reach_m
    seated = (gap_below <= 1e-9) & ~top  # resting on the plate already: a flat bottom stays down (held)
    bottom = (gap_below < reach_m) & ~top & ~seated
    cand = np.concatenate([surface_z[top], surface_z[bottom]])
    if len(cand) > MAX_CANDIDATE_DOFS:
        raise ValueError(f"{len(cand)} contact candidates (at most {MAX_CANDIDATE_DOFS}): mesh too fine")
    side = np.concatenate([np.ones(top.sum()), -np.ones(bottom.sum())])
    gap = np.concatenate([gap_above[top], gap_below[bottom]])
    moving = side > 0
    held_nodes = surface_z[(bottom | seated) & (gap_below < held_m)]  # z-dofs: x and y are 2 and 1 before
    fixed = np.concatenate([held_nodes - 2, held_nodes - 1, surface_z[seated]])
    rest = np.setdiff1d(np.arange(basis.N), np.concatenate([fixed, cand]))
    condensed = condense(K, rest, cand)
    forces, supports, iterations, displacements = [], [], [], []
    active = gap <= 0.0
    for depth in depths_m:
        u_c, active, iters = _solve_contact(condensed.S, side, gap - depth * moving, active)
        u = np.zeros(basis.N)
        u[condensed.order] = condensed.displacement(u_c)
        f = K @ u
        forces.append(float(-f[cand[moving]].sum()))
        supports.append(float(f[cand[~moving]].sum() + f[surface_z[seated]].sum()))
        iterations.append(iters)
        if keep_displacement:
            displacements.append(u[basis.nodal_dofs])
    return IndentationResult(
        depths_m=tuple(depths_m),
        force_per_pa_n=tuple(forces),
        support_per_pa_n=tuple(supports),
        dofs=int(basis.N),
        candidates=len(cand),
        iterations=tuple(iterations),
        vertex_displacement_m=tuple(displacements),
    )


@dataclass(frozen=True)
class Condensed:
    """A stiffness matrix condensed onto its contact candidates: the Schur complement S (the candidates'
    reactions per metre of their displacement, every other free dof in equilibrium) and the factors that
    give the rest of the field."""

    S: np.ndarray
    order: np.ndarray
    """The free dofs as factored: the rest (fill-reducing order), then the candidates."""
    lu: spla.SuperLU

    def displacement(self, u_cand: np.ndarray) -> np.ndarray:
        """Every free dof's displacement (in `order`) with the candidates at `u_cand` and no load elsewhere:
        the full system solved for the candidates' own reactions S u."""
        rhs = np.zeros(len(self.order))
        rhs[len(self.order) - len(u_cand) :] = self.S @ u_cand
        return self.lu.solve(rhs)


def condense(K: Any, rest: np.ndarray, cand: np.ndarray) -> Condensed:
    """Condense the stiffness over `rest` + `cand` onto `cand` by one partial factorization: the candidates
    ordered last, the trailing block of the factors is the Schur complement (L_cc U_cc = K_cc - K_cr
    K_rr^-1 K_rc).

    The rest is ordered by nested dissection (METIS), SuperLU factors in that order with diagonal pivots
    (SuperLU's own minimum degree, tried once on a scan's FEM: 1.3x the entries, 2.4x the time). Against
    factoring the rest and solving for each candidate as a right-hand side, the scan's FEM took 3.9x less
    time, for the same forces to 4e-14 (benchmarks/fem_condensation.py)."""
    order = np.concatenate([rest[_nested_dissection(K, rest)], cand])
    lu = spla.splu(
        K[order][:, order].tocsc(),
        permc_spec="NATURAL",
        diag_pivot_thresh=0.0,
        options={"SymmetricMode": True},
    )
    if not np.array_equal(lu.perm_r, np.arange(len(order))):  # a pivot off the diagonal: K is not SPD
        raise ValueError("the stiffness is not positive definite on its free dofs (an unconstrained body?)")
    n_rest = len(rest)
    L = lu.L.tocsc()[n_rest:, n_rest:].toarray()
    U = lu.U.tocsc()[n_rest:, n_rest:].toarray()
    S = L @ U
    return Condensed(S=0.5 * (S + S.T), order=order, lu=lu)


def _nested_dissection(K: Any, dofs: np.ndarray) -> np.ndarray:
    """A fill-reducing order of `dofs` (indices into it): METIS's nested dissection (pymetis) of the graph of
    their nodes (dof // 3), each node's dofs kept together."""
    import pymetis

    block = K[dofs][:, dofs].tocoo()
    nodes, node_of = np.unique(dofs // 3, return_inverse=True)
    graph = sp.csr_matrix(
        (np.ones(block.nnz), (node_of[block.row], node_of[block.col])), shape=(len(nodes), len(nodes))
    )
    graph.setdiag(0)  # METIS takes no self-loops
    graph.eliminate_zeros()
    _, position = pymetis.nested_dissection(pymetis.CSRAdjacency(graph.indptr, graph.indices))
    return np.argsort(np.asarray(position)[node_of] * 3 + dofs % 3, kind="stable")


def factor_spd(matrix: Any) -> spla.SuperLU:
    """SuperLU of a symmetric positive-definite sparse matrix (a stiffness block) in its symmetric mode: a
    minimum-degree ordering of A + A^T, pivots kept on the diagonal. COLAMD, SuperLU's default, orders for
    unsymmetric matrices: on a scan's 24,369-dof FEM its factors held 2.7x the entries, and factoring and
    condensing 1,720 contact dofs took 2.6x as long, for the same answer (to 1e-12)."""
    return spla.splu(
        matrix.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True}
    )


def _solve_contact(
    S: np.ndarray, side: np.ndarray, limit_m: np.ndarray, active: np.ndarray
) -> tuple[np.ndarray, np.ndarray, int]:
    """Candidate z-displacements under side * u <= limit (the indenters' surface above, +1; the plate
    below, -1), each reaction S u pressing, never pulling.

    An active node whose reaction pulls leaves the set, an inactive one that penetrates joins it."""
    seen: set[bytes] = set()
    for iters in range(1, MAX_ACTIVE_SET_ITERATIONS + 1):
        u = np.where(active, side * limit_m, 0.0)
        free = ~active
        if free.any():
            rhs = -(S[np.ix_(free, active)] @ u[active])
            u[free] = sla.solve(S[np.ix_(free, free)], rhs, assume_a="pos")
        pressing = side * (S @ u) < 0.0
        new_active = np.where(active, pressing, side * u > limit_m + 1e-12)
        if np.array_equal(new_active, active):
            return u, active, iters
        key = np.packbits(new_active).tobytes()
        if key in seen:  # cycling at the contact's edge: the last set is as good as any of the cycle
            return u, active, iters
        seen.add(key)
        active = new_active
    raise RuntimeError(f"the contact set did not settle in {MAX_ACTIVE_SET_ITERATIONS} iterations")
