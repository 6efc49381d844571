"""The object's lateral strain from two stereo pairs on opposite sides, and its ratio to the axial strain.

One pair sees one side face: its outward shift mixes the foam's expansion with the object's rigid shift
in the grasp. Two pairs on opposite sides (twin.sim.cameras PLACEMENTS `lateral` and `opposite`, the two
gaps the fingers leave along the palm's x) see both x faces: their distance is the object's width,
and a rigid shift cancels in it. The axial strain comes from the hand: in the compress grasp the distal
links lie flat on the object's top, so the downward-facing taxels' height is the top's (kinematics).
Backend-free: hand-frame point clouds and taxel poses in, numbers out.
"""

from __future__ import annotations

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
