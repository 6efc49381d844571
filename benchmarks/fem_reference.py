"""Independent finite-element reference for the foam objects (issue 19, deliverable 1).

Library: scikit-fem (pure Python over numpy/scipy; installs everywhere from the registry with no MPI or
compiled stack, which is why it was chosen over FEniCSx and SfePy). Meshes: gmsh (OCC geometry, size
fields refined at the indenter and the wall). Elements: quadratic tetrahedra (ElementTetP2, straight
sided), small-strain isotropic linear elasticity (skfem.models.elasticity). Solver: scipy's sparse
direct LU (SuperLU) on the dofs away from the contacts, a dense Schur complement on the candidate contact
dofs, and a primal-dual active set for the unilateral contacts (Hüeber & Wohlmuth's semismooth Newton
form of "add the penetrating nodes, drop the tensile ones, repeat until the set stops changing").

The bench (the MuJoCo bench of benchmarks/foam_fidelity.py; metres, object centred at x = y = 0):
- a rigid indenter on the object's -y side moves +y by the depth d from first touch, pressing the object
  against a rigid frictionless wall touching its +y extreme (unilateral u_y <= gap, active set);
- plate: frictionless; block and cylinder: bottom face z = 0 held at u_z = 0 (bilateral, it stays
  loaded); the sphere touches the plate at one point, so for it the horizontal mid-plane is a symmetry
  plane instead (u_z = 0 at z = 0, quarter model, indenter at z = 0);
- symmetry plane x = 0 (u_x = 0): half model (quarter for the sphere). Every case is checked to leave no
  rigid-body mode (the six rigid modes restricted to the constrained dofs have rank 6);
- gravity ignored: the foam weighs 0.05-0.1 N against indenter forces of several newtons;
- indenters: a flat punch 23 mm (x) x 50 mm (z) centred on the object's mid-height, "bonded" (contacted
  nodes move with the punch in x, y and z) or "slipping" (frictionless, only u_y imposed); a rigid sphere
  of radius 12 mm, frictionless, exact sphere gap measured along y (small strain). On the block's flat face
  the whole punch footprint touches at once (gap 0), so that case is linear in depth (verified: forces at
  2 and 6 mm differ by exactly 3x); on the cylinder and with the sphere the contact set is solved.

Linear elasticity: force is proportional to E, so everything is solved with E = 1 Pa and scaled by the
library modulus (twin.sim.foam.LIBRARY); results are computed per (geometry, poisson).

JSON schema (benchmarks/fem_reference.json; read it with `force_depth(case)` and `profile(case)`):
  {"provenance": {...versions, element, date, bcs...},
   "cases": {"<object>/<indenter>": {
       "object", "indenter" ("punch_bonded" | "punch_slipping" | "sphere"), "young_pa", "poisson",
       "depths_m": [...], "force_n": [...] (at young_pa), "force_per_pa_n": [...] (at E = 1 Pa),
       "wall_force_n": [...] (equilibrium check), "nodes", "dofs", "h_fine_m",
       "convergence": {"h_fine_m": [...], "dofs": [...], "force_6mm_per_pa_n": [...], "rel_change": [...]},
       "profile_6mm": {"x_m": [...], "z_m": [...], "y_rest_m": [...], "uy_m": [...]}  (points on the
           -y surface over the object's silhouette, 2 mm grid, full width by mirroring),
       "pressure_6mm": {"x_edges_m", "z_edges_m", "pressure_pa": [[nz x nx]]}  (flat punch only:
           indenter y-reaction binned on 12 x 26 cells of the 23 x 50 mm face / cell area)}},
   "extras": {...} (the Neo-Hookean comparison and the issue's cross-check)}

Run `python -m benchmarks.fem_reference` to recompute everything and rewrite the cache (~30 min on two
busy cores; `--only NAME ...` recomputes some cases into the existing cache); it prints the force table
and the convergence record. Convergence: the force at 6 mm on three meshes (element size at the indenter
4 / 2.8 / 2 mm for the punch, 2 / 1.4 / 1 mm for the sphere on the sphere, 2.8 / 2 / 1.4 mm for the
sphere on the block); the last change is < 1 % for every case (block bonded punch: 0.59 % then 0.14 %;
cylinder bonded: 2.2 % then 0.47 %, once its wall contact line was refined like the indenter; with a
4-8 mm mesh there it drifted 3.5 % per level). Cross-check with the issue's audit (3.9 / 7.8 / 11.7 N,
block, bonded punch): a bonded wall reproduces it (3.90 / 7.80 / 11.70 N); our frictionless wall gives
3.75 / 7.50 / 11.26 N (extras.issue_crosscheck). Neo-Hookean (extras.neo_hookean, block, bonded punch,
4 mm mesh, bilateral frictionless wall): +1.2 / +2.2 / +3.2 % over linear elasticity at 2 / 4 / 6 mm.
"""

from __future__ import annotations

import datetime
import itertools
import json
import math
import pathlib
import sys
from dataclasses import dataclass
from typing import Any

import gmsh
import numpy as np
import scipy.linalg as sla
import skfem
from scipy.interpolate import griddata
from skfem import Basis, ElementTetP2, ElementVector, MeshTet, asm
from skfem.helpers import ddot, det, grad, inv, mul, transpose
from skfem.models.elasticity import lame_parameters, linear_elasticity

from twin.sim.fem import factor_spd
from twin.sim.foam import LIBRARY
from twin.sim.tetmesh import gmsh_session

CACHE_PATH = pathlib.Path(__file__).with_name("fem_reference.json")
PUNCH_HALF_X_M = 0.0115  # 23 mm wide fingertip face (the BH8 fingertip, like foam_discretization.py)
PUNCH_HALF_Z_M = 0.025  # 50 mm tall
SPHERE_RADIUS_M = 0.012
DEPTHS_M = (0.002, 0.004, 0.006)
SPHERE_DEPTHS_M = (0.0005, 0.001, 0.0015, 0.002, 0.003, 0.004, 0.005, 0.006)
PROFILE_STEP_M = 0.002
PRESSURE_CELLS = (12, 26)  # (x, z) cells over the 23 x 50 mm punch face
PUNCH_LEVELS_M = (0.004, 0.0028, 0.002)  # element size at the indenter (refinement levels)
SPHERE_LEVELS_M = (0.002, 0.0014, 0.001)  # the sphere's contact on the sphere foam is smaller: finer
BLOCK_SPHERE_LEVELS_M = (0.0028, 0.002, 0.0014)  # on the block (its whole wall face is a contact)
H_WALL_MIN_M = 0.004  # the wall contact: max(2 h_fine, 4 mm)
H_FAR_MIN_M = 0.006  # far field: max(4 h_fine, 6 mm)
TOL_M = 1e-7


@dataclass(frozen=True)
class Setup:
    """One geometry, indenter and set of boundary conditions (dimensions in metres)."""

    shape: str  # "block" | "cylinder" | "sphere"
    size_m: tuple[float, float, float]
    poisson: float
    indenter: str  # "punch_bonded" | "punch_slipping" | "sphere"
    wall: str = "frictionless"  # "frictionless" | "bonded" (the bonded wall only for the cross-check)
    sphere_radius_m: float = SPHERE_RADIUS_M
    far_face_fixed: bool = False  # Hertz check: the +y face clamped instead of the wall
    reach_m: float | None = None  # half-size of the refined zone at the indenter (None: the bench's)

    @property
    def quarter(self) -> bool:
        """The sphere foam (and the Hertz block) also use the z = 0 mid-plane as a symmetry plane."""
        return self.shape == "sphere" or self.far_face_fixed

    @property
    def z_mid_m(self) -> float:
        return 0.0 if self.quarter else self.size_m[2] / 2

    @property
    def y_min_m(self) -> float:
        return -self.size_m[1] / 2


# --- mesh -------------------------------------------------------------------------------------------


def build_mesh(s: Setup, h_fine_m: float) -> MeshTet:
    """gmsh tetrahedral mesh of the half (or quarter) object, fine at the indenter, finer at the wall."""
    x, y, z = s.size_m
    with gmsh_session():
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.NumThreads", 1)
        gmsh.model.add("foam")
        occ = gmsh.model.occ
        zlen = z / 2 if s.quarter else z
        big = 2 * max(x, y, z)
        if s.shape == "block":
            occ.addBox(0, -y / 2, 0, x / 2, y, zlen)
        else:
            if s.shape == "cylinder":
                body = occ.addCylinder(0, 0, 0, 0, 0, z, x / 2)
            else:
                body = occ.addSphere(0, 0, 0, x / 2)
            keep = occ.addBox(0, -big, 0 if s.quarter else -big, big, 2 * big, big if s.quarter else 2 * big)
            occ.intersect([(3, body)], [(3, keep)])
        occ.synchronize()
        _size_fields(s, h_fine_m)
        gmsh.model.mesh.generate(3)
        tags, coords, _ = gmsh.model.mesh.getNodes()
        _, elem_nodes = gmsh.model.mesh.getElementsByType(4)
    points = coords.reshape(-1, 3)
    index = np.zeros(int(tags.max()) + 1, dtype=np.int64)
    index[tags.astype(np.int64)] = np.arange(len(tags))
    t = index[elem_nodes.astype(np.int64)].reshape(-1, 4)
    used = np.unique(t)
    remap = np.full(len(points), -1)
    remap[used] = np.arange(len(used))
    return MeshTet(points[used].T.copy(), remap[t].T.copy())


def _size_fields(s: Setup, h_fine_m: float) -> float:
    """Box fields: h_fine at the indenter, max(2 h_fine, 4 mm) at the wall, max(4 h_fine, 6 mm) elsewhere."""
    x, y, _ = s.size_m
    field = gmsh.model.mesh.field
    zc = s.z_mid_m
    if s.reach_m is not None:
        reach_x = reach_z = s.reach_m
    elif s.indenter == "sphere":
        reach_x, reach_z = 0.010, 0.010
    else:
        reach_x, reach_z = PUNCH_HALF_X_M + 0.002, PUNCH_HALF_Z_M + 0.002
    depth_in = s.reach_m or {"block": 0.006, "sphere": 0.009, "cylinder": 0.01}[s.shape]
    h_far = max(4 * h_fine_m, H_FAR_MIN_M)
    boxes = [
        (h_fine_m, (0, reach_x), (-y / 2 - 0.001, -y / 2 + depth_in), (zc - reach_z, zc + reach_z)),
        (  # the cylinder's wall contact is a line (Hertz in 2-D): refined like the indenter
            h_fine_m if s.shape == "cylinder" else max(2 * h_fine_m, H_WALL_MIN_M),
            (0, x / 2 if s.shape == "block" else 0.016),
            (y / 2 - 0.01, y / 2 + 0.001),
            (-1, 1),
        ),
    ]
    ids = []
    for h, (x0, x1), (y0, y1), (z0, z1) in boxes:
        f = field.add("Box")
        field.setNumber(f, "VIn", h)
        field.setNumber(f, "VOut", h_far)
        keys = ("XMin", "XMax", "YMin", "YMax", "ZMin", "ZMax")
        for key, val in zip(keys, (x0, x1, y0, y1, z0, z1), strict=True):
            field.setNumber(f, key, val)
        field.setNumber(f, "Thickness", 0.01)
        ids.append(f)
    fmin = field.add("Min")
    field.setNumbers(fmin, "FieldsList", ids)
    field.setAsBackgroundMesh(fmin)
    return h_far
    for opt in ("Mesh.MeshSizeExtendFromBoundary", "Mesh.MeshSizeFromPoints", "Mesh.MeshSizeFromCurvature"):
        gmsh.option.setNumber(opt, 0)
    gmsh.option.setNumber("Mesh.MeshSizeMax", h_far)


# --- constraints ------------------------------------------------------------------------------------


@dataclass
class Problem:
    """The assembled model and its constraint sets (global dof indices)."""

    setup: Setup
    basis: Basis
    K: Any
    xyz: np.ndarray  # (3, n_nodes) dof locations (P2 nodes)
    fixed0: np.ndarray  # homogeneous Dirichlet dofs (symmetry, plate, clamped faces)
    presc: np.ndarray  # dofs prescribed proportionally to depth (flat punch on a flat face)
    presc_unit: np.ndarray  # their value per metre of depth
    cand_node: np.ndarray  # candidate contact nodes (unilateral)
    cand_side: np.ndarray  # +1: indenter side (u_y >= d - gap), -1: wall side (u_y <= gap)
    cand_gap: np.ndarray  # rest gap (m), for the indenter side measured at d = 0
    bonded: bool  # indenter candidates carry x and z too (moved with the punch when in contact)
    punch_nodes: np.ndarray  # nodes whose y-reaction makes the indenter force
    surface_neg_y: np.ndarray  # outer-surface nodes on the -y side (profile)


def _outer_surface(s: Setup, p: np.ndarray) -> np.ndarray:
    """Nodes on the object's outer surface (not the symmetry planes or the plate)."""
    x, y, _ = s.size_m
    tol = 1e-6
    if s.shape == "block":
        return (np.abs(np.abs(p[1]) - y / 2) < tol) | (np.abs(p[0] - x / 2) < tol)
    if s.shape == "cylinder":
        return np.hypot(p[0], p[1]) > x / 2 - 5e-5
    return np.linalg.norm(p, axis=0) > x / 2 - 5e-5


def _sphere_gap(s: Setup, p: np.ndarray) -> np.ndarray:
    """Gap along y between the rest surface and the indenter sphere at first touch (inf beyond reach)."""
    r2 = p[0] ** 2 + (p[2] - s.z_mid_m) ** 2
    R = s.sphere_radius_m
    cap = np.sqrt(np.maximum(R**2 - r2, 0.0))
    y_centre = s.y_min_m - R  # first touch at (0, y_min, z_mid)
    return np.where(r2 < R**2, p[1] - (y_centre + cap), np.inf)


def build_problem(s: Setup, h_fine_m: float) -> Problem:
    """Assemble K (E = 1 Pa) and the constraint sets of one setup."""
    mesh = build_mesh(s, h_fine_m)
    basis = Basis(mesh, ElementVector(ElementTetP2()))
    K = asm(linear_elasticity(*lame_parameters(1.0, s.poisson)), basis)
    xyz = basis.doflocs[:, ::3]  # nodal dofs are interleaved (u^1, u^2, u^3) per node
    assert np.allclose(basis.doflocs[:, 1::3], xyz)
    n = xyz.shape[1]
    dof = np.arange(3 * n).reshape(n, 3)
    y = s.size_m[1]
    tol = 1e-6
    outer = _outer_surface(s, xyz)
    fixed = [dof[np.abs(xyz[0]) < tol, 0]]
    if s.quarter:
        fixed.append(dof[np.abs(xyz[2]) < tol, 2])
    else:
        fixed.append(dof[np.abs(xyz[2]) < tol, 2])  # frictionless plate, bilateral
    if s.far_face_fixed:
        fixed.append(dof[np.abs(xyz[1] - y / 2) < tol].ravel())
    fixed0 = np.unique(np.concatenate(fixed))

    if s.shape == "block":  # the flat -y and +y faces
        neg, pos = np.abs(xyz[1] + y / 2) < tol, np.abs(xyz[1] - y / 2) < tol
    else:
        neg, pos = outer & (xyz[1] < 0), outer & (xyz[1] > 0)
    in_punch = (np.abs(xyz[0]) <= PUNCH_HALF_X_M + tol) & (np.abs(xyz[2] - s.z_mid_m) <= PUNCH_HALF_Z_M + tol)
    presc, presc_unit = np.zeros(0, int), np.zeros(0)
    cand_nodes, sides, gaps = [], [], []
    bonded = s.indenter == "punch_bonded"
    if s.indenter.startswith("punch"):
        punch = np.flatnonzero(neg & in_punch)
        if s.shape == "block":  # flat face: the whole footprint touches at first contact
            comps = (0, 1, 2) if bonded else (1,)
            presc = dof[punch][:, comps].ravel()
            presc_unit = np.tile([1.0 if c == 1 else 0.0 for c in comps], len(punch))
        else:
            cand_nodes.append(punch)
            sides.append(np.ones(len(punch)))
            gaps.append(xyz[1, punch] - xyz[1, punch].min())
    else:
        gap = _sphere_gap(s, xyz)
        punch = np.flatnonzero(neg & (gap < 0.008))
        cand_nodes.append(punch)
        sides.append(np.ones(len(punch)))
        gaps.append(gap[punch])
    if not s.far_face_fixed:
        if s.wall == "bonded":
            fixed0 = np.unique(np.concatenate([fixed0, dof[pos & (np.abs(xyz[1] - y / 2) < tol)].ravel()]))
        else:
            wall = np.flatnonzero(pos & (y / 2 - xyz[1] < 0.006))
            cand_nodes.append(wall)
            sides.append(-np.ones(len(wall)))
            gaps.append(y / 2 - xyz[1, wall])
    cand = np.concatenate(cand_nodes) if cand_nodes else np.zeros(0, int)
    presc_keep = ~np.isin(presc, fixed0)
    return Problem(
        setup=s,
        basis=basis,
        K=K.tocsr(),
        xyz=xyz,
        fixed0=fixed0,
        presc=presc[presc_keep],
        presc_unit=presc_unit[presc_keep],
        cand_node=cand,
        cand_side=np.concatenate(sides) if sides else np.zeros(0),
        cand_gap=np.maximum(np.concatenate(gaps), 0.0) if gaps else np.zeros(0),
        bonded=bonded and s.shape != "block",
        punch_nodes=punch,
        surface_neg_y=np.flatnonzero(neg),
    )


def uniaxial_force_per_pa(s: Setup, h_fine_m: float, depth_m: float) -> float:
    """Compression between frictionless rigid plates (y faces), laterally free: force at E = 1 Pa (N)."""
    mesh = build_mesh(s, h_fine_m)
    basis = Basis(mesh, ElementVector(ElementTetP2()))
    K = asm(linear_elasticity(*lame_parameters(1.0, s.poisson)), basis).tocsr()
    xyz = basis.doflocs[:, ::3]
    n = xyz.shape[1]
    dof = np.arange(3 * n).reshape(n, 3)
    half_y, tol = s.size_m[1] / 2, 1e-6
    near, far = np.abs(xyz[1] + half_y) < tol, np.abs(xyz[1] - half_y) < tol
    u = np.zeros(3 * n)
    u[dof[near, 1]] = depth_m  # the -y plate moves +y, the +y plate stays: u_y only (frictionless)
    sym = [dof[np.abs(xyz[0]) < tol, 0], dof[np.abs(xyz[2]) < tol, 2]]  # symmetry x = 0, plate z = 0
    D = np.unique(np.concatenate([dof[near, 1], dof[far, 1], *sym]))
    u = skfem.solve(*skfem.condense(K, x=u, D=D))
    return float(2.0 * (K @ u)[dof[near, 1]].sum())


def rigid_modes_left(pr: Problem, constrained: np.ndarray) -> int:
    """How many of the six rigid-body modes the constrained dofs leave free (0 for a well-posed case)."""
    p = pr.xyz
    n = p.shape[1]
    modes = np.zeros((3 * n, 6))
    for k in range(3):
        modes[k::3, k] = 1.0
    for k, (a, b) in enumerate(((1, 2), (2, 0), (0, 1))):  # rotations about x, y, z
        modes[a::3, 3 + k] = -p[b]
        modes[b::3, 3 + k] = p[a]
    return 6 - np.linalg.matrix_rank(modes[constrained], tol=1e-9)


# --- solver -----------------------------------------------------------------------------------------


@dataclass
class Reduced:
    """The model condensed onto the candidate contact dofs (dense), for any depth."""

    pr: Problem
    rest: np.ndarray
    cdofs: np.ndarray  # candidate dofs: y (and x, z if bonded) of the candidate nodes
    lu: Any
    S: np.ndarray
    g: np.ndarray  # condensed force at cdofs per metre of prescribed depth


def condense(pr: Problem) -> Reduced:
    """Factorize the non-contact block once and build the dense Schur complement on the contact dofs."""
    n = pr.xyz.shape[1]
    dof = np.arange(3 * n).reshape(n, 3)
    comps = (0, 1, 2) if pr.bonded else (1,)
    cdofs = dof[pr.cand_node][:, comps].ravel()
    cdofs = cdofs[~np.isin(cdofs, pr.fixed0)]
    rest = np.setdiff1d(np.arange(3 * n), np.concatenate([pr.fixed0, pr.presc, cdofs]))
    K = pr.K
    lu = factor_spd(K[rest][:, rest])
    Krc = K[rest][:, cdofs].tocsc()
    Kcr = Krc.T.tocsr()
    S = K[cdofs][:, cdofs].toarray()
    for k0 in range(0, len(cdofs), 400):
        block = Krc[:, k0 : k0 + 400].toarray()
        S[:, k0 : k0 + 400] -= Kcr @ lu.solve(block)
    S = 0.5 * (S + S.T)
    g = np.zeros(len(cdofs))
    if len(pr.presc):
        w = lu.solve(K[rest][:, pr.presc] @ pr.presc_unit)
        g = K[cdofs][:, pr.presc] @ pr.presc_unit - Kcr @ w
    return Reduced(pr=pr, rest=rest, cdofs=cdofs, lu=lu, S=S, g=g)


def _node_of_cdof(red: Reduced) -> tuple[np.ndarray, np.ndarray]:
    """For each candidate dof: its candidate index and its component."""
    pos = {int(nd): i for i, nd in enumerate(red.pr.cand_node)}
    node = red.cdofs // 3
    return np.array([pos[int(v)] for v in node], dtype=int), red.cdofs % 3


def solve_depth(red: Reduced, depth_m: float, max_iter: int = 60) -> dict[str, Any]:
    """Solve one depth: primal-dual active set on the dense contact problem, then recover u and reactions."""
    pr = red.pr
    cand_i, comp = _node_of_cdof(red)
    side = pr.cand_side[cand_i]
    # target y-displacement of an active node: indenter side d - gap, wall side +gap
    target = np.where(side > 0, depth_m - pr.cand_gap[cand_i], pr.cand_gap[cand_i])
    ydof = comp == 1
    active = ydof & (((side > 0) & (target > 0)) | ((side < 0) & (pr.cand_gap[cand_i] <= 1e-9)))
    scale = float(np.mean(np.diag(red.S))) if len(red.S) else 1.0
    seen: dict[bytes, int] = {}
    tried: list[tuple[float, np.ndarray]] = []
    for iters in range(1, max_iter + 1):  # noqa: B007 (iters is reported)
        u, comp_lam, violation = _solve_active(red, active, cand_i, side, ydof, target, depth_m)
        # kkt error: worst penetration (per metre of depth) and worst tension (share of the total reaction)
        total = np.abs(comp_lam).sum() + 1e-300
        kkt = max(violation.max(initial=0.0) / depth_m, -comp_lam[active].min(initial=0.0) / total)
        tried.append((kkt, active.copy()))
        new_active = ydof & (np.where(active, comp_lam, 0.0) + scale * violation > 1e-12 * scale)
        if np.array_equal(new_active, active):
            break
        key = np.packbits(new_active).tobytes()
        if key in seen:  # the set cycles (nodes at the contact edge): keep the best member of the cycle
            kkt, active = min(tried[seen[key] :], key=lambda t: t[0])
            u, *_ = _solve_active(red, active, cand_i, side, ydof, target, depth_m)
            break
        seen[key] = len(tried)
        active = new_active
    else:
        raise RuntimeError(f"active set did not settle in {max_iter} iterations")
    out = _recover(red, depth_m, u, iters)
    out["kkt_error"] = float(kkt)
    return out


def _solve_active(
    red: Reduced,
    active: np.ndarray,
    cand_i: np.ndarray,
    side: np.ndarray,
    ydof: np.ndarray,
    target: np.ndarray,
    depth_m: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Contact dofs for one active set (bonded nodes glued in x and z), compressive reactions, penetration."""
    fixed = active.copy()
    if red.pr.bonded:
        fixed |= (side > 0) & np.isin(cand_i, np.unique(cand_i[active])) & ~ydof
    u = np.where(fixed, np.where(ydof, target, 0.0), 0.0)
    free = ~fixed
    if free.any():
        rhs = -(red.g[free] * depth_m + red.S[np.ix_(free, fixed)] @ u[fixed])
        u[free] = sla.solve(red.S[np.ix_(free, free)], rhs, assume_a="pos")
    lam = red.S @ u + red.g * depth_m  # contact reactions on the object (zero on free dofs)
    # "compressive" sign: the indenter pushes +y (lam >= 0), the wall pushes -y (lam <= 0)
    comp_lam = np.where(ydof, side * lam, 0.0)
    violation = np.where(ydof, side * (target - u), 0.0)  # > 0 where the node penetrates
    return u, comp_lam, violation


def _recover(red: Reduced, depth_m: float, u_c: np.ndarray, iters: int) -> dict[str, Any]:
    """Full displacement, reactions, indenter and wall forces (half/quarter model scaled to the full)."""
    pr = red.pr
    K = pr.K
    n3 = K.shape[0]
    u = np.zeros(n3)
    u[red.cdofs] = u_c
    u[pr.presc] = pr.presc_unit * depth_m
    known = np.concatenate([red.cdofs, pr.presc])
    u[red.rest] = red.lu.solve(-(K[red.rest][:, known] @ u[known]))
    f = K @ u
    mult = 4.0 if pr.setup.quarter else 2.0
    force = mult * f[3 * pr.punch_nodes + 1].sum()
    wall_nodes = pr.cand_node[pr.cand_side < 0]
    wall = -mult * f[3 * wall_nodes + 1].sum() if len(wall_nodes) else float("nan")
    return {"u": u, "f": f, "force_per_pa_n": float(force), "wall_per_pa_n": float(wall), "iterations": iters}


# --- outputs ----------------------------------------------------------------------------------------


def surface_profile(pr: Problem, u: np.ndarray) -> dict[str, list[float]]:
    """u_y of the -y surface on a regular (x, z) grid over the silhouette (mirrored to the full object)."""
    s = pr.setup
    idx = pr.surface_neg_y
    p = pr.xyz[:, idx]
    uy = u[3 * idx + 1]
    pts, vals, ys = [p[[0, 2]].T], [uy], [p[1]]
    pts.append(np.c_[-p[0], p[2]])
    vals.append(uy)
    ys.append(p[1])
    if s.quarter:
        for sx in (1, -1):
            pts.append(np.c_[sx * p[0], -p[2]])
            vals.append(uy)
            ys.append(p[1])
    P, V, Y = np.vstack(pts), np.concatenate(vals), np.concatenate(ys)
    x, _, z = s.size_m
    step = PROFILE_STEP_M
    gx = np.arange(-math.floor(x / 2 / step), math.floor(x / 2 / step) + 1) * step
    z0 = -z / 2 if s.quarter else 0.0
    gz = z0 + np.arange(0, math.floor(z / step + 1e-9) + 1) * step
    X, Z = np.meshgrid(gx, gz)
    X, Z = X.ravel(), Z.ravel()
    if s.shape == "block":
        inside = np.ones_like(X, bool)
    elif s.shape == "cylinder":
        inside = np.abs(X) <= x / 2 - 1e-9
    else:
        inside = X**2 + Z**2 <= (x / 2) ** 2 - 1e-12
    X, Z = X[inside], Z[inside]
    q = np.c_[X, Z]
    uy_q = griddata(P, V, q, method="linear")
    y_q = griddata(P, Y, q, method="linear")
    miss = np.isnan(uy_q) | np.isnan(y_q)
    if miss.any():
        uy_q[miss] = griddata(P, V, q[miss], method="nearest")
        y_q[miss] = griddata(P, Y, q[miss], method="nearest")
    return {
        "x_m": _r(X),
        "z_m": _r(Z),
        "y_rest_m": _r(y_q),
        "uy_m": _r(uy_q, 9),
    }


def punch_pressure(pr: Problem, f: np.ndarray, young_pa: float) -> dict[str, Any]:
    """Indenter y-reaction binned on cells over the 23 x 50 mm face, divided by the cell area (Pa)."""
    nx, nz = PRESSURE_CELLS
    xe = np.linspace(-PUNCH_HALF_X_M, PUNCH_HALF_X_M, nx + 1)
    ze = np.linspace(-PUNCH_HALF_Z_M, PUNCH_HALF_Z_M, nz + 1) + pr.setup.z_mid_m
    nodes = pr.punch_nodes
    fy = f[3 * nodes + 1] * young_pa
    px, pz = pr.xyz[0, nodes], pr.xyz[2, nodes]
    ix = np.clip(np.searchsorted(xe, px, side="right") - 1, nx // 2, nx - 1)  # x >= 0 half
    iz = np.clip(np.searchsorted(ze, pz, side="right") - 1, 0, nz - 1)
    half = np.zeros((nz, nx))
    np.add.at(half, (iz, ix), fy)
    full = half.copy()
    full[:, : nx // 2] = half[:, nx // 2 :][:, ::-1]  # mirror x >= 0 onto x < 0
    area = (xe[1] - xe[0]) * (ze[1] - ze[0])
    return {"x_edges_m": _r(xe), "z_edges_m": _r(ze), "pressure_pa": [_r(row, 1) for row in full / area]}


def _r(a: Any, digits: int = 6) -> list[float]:
    return [round(float(v), digits) for v in np.asarray(a).ravel()]


# --- cases ------------------------------------------------------------------------------------------

CASES: dict[str, tuple[str, str]] = {
    **{
        f"{o}/punch_{c}": (o, f"punch_{c}")
        for o in ("block", "soft_block", "firm_block", "cylinder")
        for c in ("bonded", "slipping")
    },
    "sphere/sphere": ("sphere", "sphere"),
    "block/sphere": ("block", "sphere"),
}


def setup_for(object_name: str, indenter: str, **kw: Any) -> Setup:
    """The bench setup for a library object (geometry and Poisson ratio from twin.sim.foam.LIBRARY)."""
    foam = LIBRARY[object_name]
    return Setup(shape=foam.shape, size_m=tuple(foam.size_m), poisson=foam.poisson, indenter=indenter, **kw)


def depths_for(indenter: str) -> tuple[float, ...]:
    """Depths solved: 2/4/6 mm for the punch, a finer ladder for the (nonlinear) sphere contact."""
    return SPHERE_DEPTHS_M if indenter == "sphere" else DEPTHS_M


def levels_for(indenter: str, shape: str) -> tuple[float, ...]:
    """Refinement levels (element size at the indenter)."""
    if indenter != "sphere":
        return PUNCH_LEVELS_M
    return SPHERE_LEVELS_M if shape == "sphere" else BLOCK_SPHERE_LEVELS_M


def solve_setup(s: Setup, h_fine_m: float, depths_m: tuple[float, ...]) -> dict[str, Any]:
    """Mesh, condense and solve every depth of one setup (E = 1 Pa)."""
    pr = build_problem(s, h_fine_m)
    red = condense(pr)
    sols = [solve_depth(red, d) for d in depths_m]
    constrained = np.concatenate([pr.fixed0, pr.presc, red.cdofs])
    left = rigid_modes_left(pr, constrained)
    return {"problem": pr, "reduced": red, "solutions": sols, "rigid_modes_left": left}


_PER_PA: dict[Setup, dict[str, Any]] = {}


def per_pascal_entry(s: Setup, log: bool = True) -> dict[str, Any]:
    """Everything at E = 1 Pa for one setup, every refinement level (memoized: block and firm_block share)."""
    if s in _PER_PA:
        return _PER_PA[s]
    depths = depths_for(s.indenter)
    levels = levels_for(s.indenter, s.shape)
    conv_f, conv_dofs = [], []
    res: dict[str, Any] = {}
    for h in levels:
        res = solve_setup(s, h, depths if h == levels[-1] else (depths[-1],))
        conv_f.append(res["solutions"][-1]["force_per_pa_n"])
        conv_dofs.append(int(res["problem"].K.shape[0]))
        if log:
            print(f"  h={h * 1e3:.1f} mm dofs={conv_dofs[-1]} F(6 mm)/E={conv_f[-1]:.6e} N/Pa", flush=True)
    if res["rigid_modes_left"] != 0:
        raise RuntimeError(f"{s}: {res['rigid_modes_left']} rigid-body mode(s) left")
    pr, sols = res["problem"], res["solutions"]
    out = {
        "problem": pr,
        "solutions": sols,
        "depths": depths,
        "convergence": {
            "h_fine_m": list(levels),
            "dofs": conv_dofs,
            "force_6mm_per_pa_n": [float(f"{v:.7g}") for v in conv_f],
            "rel_change": [round(abs(b - a) / abs(b), 5) for a, b in itertools.pairwise(conv_f)],
        },
    }
    _PER_PA[s] = out
    return out


def compute_case(name: str, log: bool = True) -> dict[str, Any]:
    """One case's JSON entry: forces at the library modulus, convergence, profile, pressure (finest mesh)."""
    object_name, indenter = CASES[name]
    foam = LIBRARY[object_name]
    res = per_pascal_entry(setup_for(object_name, indenter), log)
    pr, sols = res["problem"], res["solutions"]
    per_pa = [sol["force_per_pa_n"] for sol in sols]
    entry: dict[str, Any] = {
        "object": object_name,
        "indenter": indenter,
        "young_pa": foam.young_pa,
        "poisson": foam.poisson,
        "depths_m": list(res["depths"]),
        "force_per_pa_n": [float(f"{v:.7g}") for v in per_pa],
        "force_n": [round(v * foam.young_pa, 5) for v in per_pa],
        "wall_force_n": [round(sol["wall_per_pa_n"] * foam.young_pa, 5) for sol in sols],
        "active_set_iterations": [sol["iterations"] for sol in sols],
        "kkt_error": [float(f"{sol['kkt_error']:.3g}") for sol in sols],
        "nodes": int(pr.xyz.shape[1]),
        "dofs": int(pr.K.shape[0]),
        "h_fine_m": res["convergence"]["h_fine_m"][-1],
        "convergence": res["convergence"],
        "profile_6mm": surface_profile(pr, sols[-1]["u"]),
    }
    if indenter.startswith("punch"):
        entry["pressure_6mm"] = punch_pressure(pr, sols[-1]["f"], foam.young_pa)
    return entry


def bonded_wall_crosscheck(cases: dict[str, Any], h_fine_m: float = PUNCH_LEVELS_M[-1]) -> dict[str, Any]:
    """The issue's audit (3.9 / 7.8 / 11.7 N, block, bonded punch): our frictionless wall vs a bonded wall."""
    foam = LIBRARY["block"]
    sols = solve_setup(setup_for("block", "punch_bonded", wall="bonded"), h_fine_m, DEPTHS_M)["solutions"]
    return {
        "depths_m": list(DEPTHS_M),
        "h_fine_m": h_fine_m,
        "issue_audit_n": [3.9, 7.8, 11.7],
        "punch_bonded_wall_bonded_n": [round(foam.young_pa * v["force_per_pa_n"], 4) for v in sols],
        "punch_bonded_wall_frictionless_n": cases["block/punch_bonded"]["force_n"],
        "punch_slipping_wall_frictionless_n": cases["block/punch_slipping"]["force_n"],
    }


def _neo_hookean_forms(mu: float, lam: float) -> tuple[Any, Any]:
    """Compressible Neo-Hookean, W = mu/2 (I1 - 3 - 2 ln J) + lam/2 (ln J)^2 (Bonet & Wood, Nonlinear
    Continuum Mechanics for FEA, 2008, eq. 6.27): first Piola stress and its consistent tangent, with the
    kinematics (F^-T, ln J) precomputed once per Newton step and passed in as fields."""

    @skfem.LinearForm
    def residual(v: Any, w: Any) -> Any:
        stress = mu * (w["F"] - w["FinvT"]) + lam * w["lnJ"] * w["FinvT"]
        return ddot(stress, grad(v))

    @skfem.BilinearForm
    def tangent(u: Any, v: Any, w: Any) -> Any:
        gu, gv, FinvT = grad(u), grad(v), w["FinvT"]
        return (
            mu * ddot(gu, gv)
            + lam * ddot(FinvT, gu) * ddot(FinvT, gv)
            + (mu - lam * w["lnJ"]) * ddot(mul(FinvT, mul(transpose(gu), FinvT)), gv)
        )

    return residual, tangent


NH_DEPTHS_M = (0.001, 0.002, 0.003, 0.004, 0.005, 0.006)


def neo_hookean_block_punch(h_fine_m: float = PUNCH_LEVELS_M[0], depths_m: tuple = NH_DEPTHS_M) -> dict:
    """Bonded punch on the library block, Neo-Hookean vs linear elastic on the same mesh (E = 1 Pa).

    Same bench except the wall: bilateral frictionless (u_y = 0 on the +y face), so no active set is
    needed; the linear solve uses the same wall. Newton with load steps at each depth; force = punch
    y-reaction. Shows how far small strain is at 6 mm / 60 mm = 10 % nominal strain."""
    s = setup_for("block", "punch_bonded")
    pr = build_problem(s, h_fine_m)
    lam, mu = lame_parameters(1.0, s.poisson)
    residual, tangent = _neo_hookean_forms(mu, lam)
    wall_y = 3 * pr.cand_node[pr.cand_side < 0] + 1
    D = np.unique(np.concatenate([pr.fixed0, pr.presc, wall_y]))
    punch_y = 3 * pr.punch_nodes + 1
    basis = pr.basis
    u = np.zeros(pr.K.shape[0])
    u_lin = np.zeros_like(u)
    u_lin[pr.presc] = pr.presc_unit
    u_lin = skfem.solve(*skfem.condense(pr.K, x=u_lin, D=D))
    lin_per_m = 2.0 * float((pr.K @ u_lin)[punch_y].sum())
    forces, iters, d_prev = [], [], 0.0
    for d in depths_m:
        u += (d - d_prev) * u_lin  # linear predictor, then Newton
        d_prev = d
        for k in range(1, 31):  # noqa: B007 (k is reported)
            gradu = basis.interpolate(u).grad
            F = gradu + np.eye(3)[:, :, None, None]
            FinvT = transpose(inv(F))
            lnJ = np.log(det(F))
            r = asm(residual, basis, F=F, FinvT=FinvT, lnJ=lnJ)
            Kt = asm(tangent, basis, FinvT=FinvT, lnJ=lnJ)
            du = skfem.solve(*skfem.condense(Kt, -r, D=D))
            u += du
            if np.linalg.norm(du) < 1e-9 * np.linalg.norm(u):
                break
        else:
            raise RuntimeError(f"Newton did not converge at {d * 1e3:g} mm")
        iters.append(k)
        gradu = basis.interpolate(u).grad
        F = gradu + np.eye(3)[:, :, None, None]
        r = asm(residual, basis, F=F, FinvT=transpose(inv(F)), lnJ=np.log(det(F)))
        forces.append(2.0 * float(r[punch_y].sum()))
    foam = LIBRARY["block"]
    return {
        "case": "block/punch_bonded, bilateral frictionless wall",
        "h_fine_m": h_fine_m,
        "dofs": int(pr.K.shape[0]),
        "depths_m": list(depths_m),
        "neo_hookean_n": [round(f * foam.young_pa, 4) for f in forces],
        "linear_n": [round(lin_per_m * d * foam.young_pa, 4) for d in depths_m],
        "ratio": [round(f / (lin_per_m * d), 4) for f, d in zip(forces, depths_m, strict=True)],
        "newton_iterations": iters,
    }


def provenance() -> dict[str, Any]:
    return {
        "library": f"scikit-fem {skfem.__version__}",
        "mesher": f"gmsh {gmsh.__version__}",
        "python": sys.version.split()[0],
        "element": "ElementTetP2 (10-node quadratic tet, straight sided), small-strain linear elastic",
        "solver": "scipy SuperLU on the non-contact dofs + dense Schur complement + primal-dual active set",
        "bcs": (
            "half model (u_x = 0 on x = 0); block/cylinder: frictionless plate u_z = 0 on z = 0; sphere: "
            "quarter model, u_z = 0 on the mid-plane z = 0; rigid frictionless unilateral wall at y = y_max; "
            "rigid indenter on the -y side at mid-height moving +y by the depth; gravity ignored"
        ),
        "refinement": "h_fine at the indenter and the cylinder's wall line, max(2 h_fine, 4 mm) at the "
        "other walls, max(4 h_fine, 6 mm) far",
        "date": datetime.date.today().isoformat(),
    }


def load_cache(path: pathlib.Path = CACHE_PATH) -> dict[str, Any]:
    """The cached reference (written by `python -m benchmarks.fem_reference`)."""
    return json.loads(path.read_text())


def force_depth(case: str, cache: dict[str, Any] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(depths_m, force_n at the library modulus) for a case such as 'block/punch_bonded'."""
    entry = (cache or load_cache())["cases"][case]
    return np.array(entry["depths_m"]), np.array(entry["force_n"])


def profile(case: str, cache: dict[str, Any] | None = None) -> dict[str, np.ndarray]:
    """The indented side at 6 mm: arrays x_m, z_m, y_rest_m, uy_m (points over the silhouette)."""
    entry = (cache or load_cache())["cases"][case]
    return {k: np.array(v) for k, v in entry["profile_6mm"].items()}


def main(argv: list[str] | None = None) -> None:
    """Recompute every case (or `--only NAME ...`, merged into the existing cache) and the extras."""
    args = list(sys.argv[1:] if argv is None else argv)
    only = args[args.index("--only") + 1 :] if "--only" in args else None
    if only:
        cache = load_cache()
        cache["provenance"] = provenance()
    else:
        cache = {"provenance": provenance(), "cases": {}, "extras": {}}
    for name in only or CASES:
        print(name, flush=True)
        cache["cases"][name] = compute_case(name)
        CACHE_PATH.write_text(json.dumps(cache, separators=(",", ":")))
    print("bonded-wall cross-check", flush=True)
    cache["extras"]["issue_crosscheck"] = bonded_wall_crosscheck(cache["cases"])
    print(cache["extras"]["issue_crosscheck"], flush=True)
    print("Neo-Hookean", flush=True)
    cache["extras"]["neo_hookean"] = neo_hookean_block_punch()
    print(cache["extras"]["neo_hookean"], flush=True)
    CACHE_PATH.write_text(json.dumps(cache, separators=(",", ":")))
    print_table(cache)


def print_table(cache: dict[str, Any]) -> None:
    """Forces (N) per case and depth, and the convergence record."""
    for name, e in cache["cases"].items():
        forces = " ".join(f"{d * 1e3:g}mm:{f:.3f}" for d, f in zip(e["depths_m"], e["force_n"], strict=True))
        c = e["convergence"]
        conv = f"F6/E={c['force_6mm_per_pa_n']} rel={c['rel_change']} dofs={c['dofs']}"
        print(f"{name:26s} {forces}  {conv}")


if __name__ == "__main__":
    main()
