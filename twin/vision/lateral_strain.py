"""The object's lateral strain from two stereo pairs on opposite sides, and its ratio to the axial strain.

One pair sees one side face: its outward shift mixes the foam's expansion with the object's rigid shift
in the grasp. Two pairs on opposite sides (twin.sim.cameras PLACEMENTS `lateral` and `opposite`, the two
gaps the fingers leave along the palm's x) see both x faces: their distance is the object's width,
and a rigid shift cancels in it. The axial strain comes from the hand: in the compress grasp the distal
links lie flat on the object's top, so the downward-facing taxels' height is the top's (kinematics).
The two strains are read as E and nu through the twin (read_modulus_and_poisson): in the grasp the
fingers also hold the object's y sides, more on a soft foam, so -eps_x/eps_z is nu only for a free
compression; the twin, run with the same cameras and code, knows by how much.
Backend-free: hand-frame point clouds and taxel poses in, numbers out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FACE_DEPTH_M = 0.003
"""A face's points: those within this of the cloud's outermost tenth along the outward axis (the
reconstruction's scatter about a flat face is ~0.3 mm; the face's edges round off by ~1-2 mm)."""
FACE_BAND = (0.15, 0.65)
"""Heights of the face read, as fractions of the object's rest height above the palm: clear of the
palm's edge below and of the fingers' links and the top edge above."""
DOWNWARD_COS = 0.9
"""A taxel lies on the object's top when its outward normal points this close to straight down."""


def face_position_m(
    points_hand: NDArray[np.float64], outward_sign: float, palm_z_m: float, height_m: float
) -> float:
    """Where the face a pair sees lies along the palm's x (m, hand frame): the median x of its points in
    the FACE_BAND, signed so that `outward_sign` (+1: the +x face, -1: the -x face) points away from
    the object. ValueError where the pair saw too little of it."""
    p = np.asarray(points_hand, dtype=float).reshape(-1, 3)
    lo, hi = (palm_z_m + f * height_m for f in FACE_BAND)
    s = outward_sign * p[(p[:, 2] > lo) & (p[:, 2] < hi), 0]
    if len(s) < 20:
        raise ValueError(f"the {'+' if outward_sign > 0 else '-'}x face is not in view ({len(s)} points)")
    outer = s[s > np.percentile(s, 90) - FACE_DEPTH_M]
    return float(np.median(outer))


def width_m(
    plus_x: NDArray[np.float64], minus_x: NDArray[np.float64], palm_z_m: float, height_m: float
) -> float:
    """The object's width along the palm's x: the +x face's position less the -x face's (m)."""
    return face_position_m(plus_x, 1.0, palm_z_m, height_m) + face_position_m(
        minus_x, -1.0, palm_z_m, height_m
    )


def centre_x_m(
    plus_x: NDArray[np.float64], minus_x: NDArray[np.float64], palm_z_m: float, height_m: float
) -> float:
    """The object's centre along the palm's x (m): halfway between its two x faces."""
    return 0.5 * (
        face_position_m(plus_x, 1.0, palm_z_m, height_m) - face_position_m(minus_x, -1.0, palm_z_m, height_m)
    )


def centre_y_reading_m(plus_x: NDArray[np.float64], minus_x: NDArray[np.float64]) -> float:
    """A reading of the object's centre along the palm's y (m): the mean of the two clouds' y extents'
    midpoints. Each pair sees a side face at a slant, so the reading carries an offset of the rig's;
    only its difference between two objects seen alike means a shift."""
    mids = []
    for cloud in (plus_x, minus_x):
        lo, hi = np.percentile(np.asarray(cloud, dtype=float).reshape(-1, 3)[:, 1], [1, 99])
        mids.append(0.5 * (lo + hi))
    return float(np.mean(mids))


def top_height_m(taxels_hand: NDArray[np.float64], normals_hand: NDArray[np.float64]) -> float:
    """The object's top (m, hand frame z) under a grasp whose distal links lie on it: the median height
    of the taxels facing down. ValueError where none faces down (the fingers are not on the top)."""
    n = np.asarray(normals_hand, dtype=float).reshape(-1, 3)
    down = n[:, 2] < -DOWNWARD_COS
    if not down.any():
        raise ValueError("no taxel faces down: the fingers are not lying on the object's top")
    return float(np.median(np.asarray(taxels_hand, dtype=float).reshape(-1, 3)[down, 2]))


def strain_ratio(width0_m: float, width1_m: float, height0_m: float, height1_m: float) -> float:
    """-eps_x / eps_z: the lateral strain over the axial one, between rest (0) and grasp (1). For a
    free uniaxial compression it is the Poisson ratio; in a grasp whose fingers also hold the other
    sides it is larger, by how much the twin knows (twin.vision.lateral_strain.nu_from_ratio)."""
    eps_z = height1_m / height0_m - 1.0
    if not eps_z < 0.0:
        raise ValueError(f"the object is not compressed (axial strain {eps_z:+.4f})")
    return -(width1_m / width0_m - 1.0) / eps_z


def nu_from_ratio(ratio: float, poisson: NDArray[np.float64], simulated_ratio: NDArray[np.float64]) -> float:
    """The Poisson ratio at which the twin's strain ratio (`simulated_ratio` at `poisson`, the run's
    modulus and placement) meets the run's: a least-squares line through the simulations, inverted
    (the ratio grows with the Poisson ratio; the line is extended past the simulated range)."""
    slope, intercept = np.polyfit(
        np.asarray(poisson, dtype=float), np.asarray(simulated_ratio, dtype=float), 1
    )
    if not slope > 0:
        raise ValueError("the twin's strain ratio does not grow with the Poisson ratio here")
    return float((ratio - intercept) / slope)


STRAIN_NOISE = (0.002, 0.003)
"""The scatter taken for a run's eps_x (two pairs' width) and eps_z (the downward taxels' height): on the
tuning runs (seeds 101-112) the width's strain was within 0.001-0.004 of the truth's affine strain, the
taxels' top within 0.1-0.6 mm of the true top. The weights of the two strains, and the noise term of
the interval (its coverage is measured on held-out runs: benchmarks/nu_from_cameras.py)."""
Z_95 = 1.96


@dataclass(frozen=True)
class StrainReading:
    """E and nu read together from the grasp's strains, each with its 95 % interval."""

    young_pa: float
    poisson: float
    young_95_pa: tuple[float, float]
    poisson_95: tuple[float, float]


def _design(log_e: NDArray[np.float64], poisson: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.column_stack([np.ones_like(log_e), log_e, log_e**2, poisson, log_e * poisson])


def read_modulus_and_poisson(
    strains: tuple[float, float],
    young_pa: NDArray[np.float64],
    poisson: NDArray[np.float64],
    simulated_strains: NDArray[np.float64],
) -> StrainReading:
    """(E, nu) whose strains under the grasp the twin puts nearest the run's `strains` (eps_x, eps_z):
    each strain fitted over the simulations (`simulated_strains`, one row per (young_pa, poisson)) as a
    quadratic in log E with a linear nu and their product, the fit searched over the simulated box
    (log E by 0.01, nu by 0.001), the residuals weighted by STRAIN_NOISE. The grasp's axial strain
    carries mostly E (the balanced grasp's force is set), the lateral one E and nu.
    The 95 % intervals: the two strains' scatter (STRAIN_NOISE and the fit's own residuals, in
    quadrature) carried through the fit's slopes at the estimate (their 2x2 Jacobian inverted)."""
    log_e = np.log(np.asarray(young_pa, dtype=float))
    nu = np.asarray(poisson, dtype=float)
    sim = np.asarray(simulated_strains, dtype=float).reshape(-1, 2)
    design = _design(log_e, nu)
    coef = np.linalg.lstsq(design, sim, rcond=None)[0]
    dof = max(len(sim) - design.shape[1], 1)
    residual_var = ((sim - design @ coef) ** 2).sum(axis=0) / dof
    sigma = np.sqrt(np.asarray(STRAIN_NOISE) ** 2 + residual_var)
    grid_e = np.arange(log_e.min(), log_e.max() + 1e-9, 0.01)
    grid_nu = np.arange(nu.min(), nu.max() + 1e-9, 0.001)
    ge, gn = (g.ravel() for g in np.meshgrid(grid_e, grid_nu))
    predicted = _design(ge, gn) @ coef
    cost = (((predicted - np.asarray(strains, dtype=float)) / sigma) ** 2).sum(axis=1)
    best = int(np.argmin(cost))
    le, n = float(ge[best]), float(gn[best])
    d_dloge = np.array([0.0, 1.0, 2.0 * le, 0.0, n]) @ coef  # (2,): each strain's slope in log E
    d_dnu = np.array([0.0, 0.0, 0.0, 1.0, le]) @ coef
    jacobian = np.column_stack([d_dloge, d_dnu])  # strains from (log E, nu)
    if abs(np.linalg.det(jacobian)) < 1e-12:
        raise ValueError("the twin's strains do not tell E and nu apart here")
    inverse = np.linalg.inv(jacobian)
    cov = inverse @ np.diag(sigma**2) @ inverse.T
    half_e, half_nu = Z_95 * np.sqrt(np.diag(cov))
    return StrainReading(
        float(np.exp(le)),
        n,
        (float(np.exp(le - half_e)), float(np.exp(le + half_e))),
        (n - float(half_nu), n + float(half_nu)),
    )
