"""Does the flex bulge as the material does? The twin's lateral strain against the FEM's (issue 38).

`twin identify` reads the Poisson ratio from two opposite stereo pairs: the object's width along the
palm's x at mid-height against the squeeze of its top, read through twin simulations at known nu
(twin.sim.poisson). That reading is the material's only if the flex's lateral strain follows the
material's as nu changes. Reference: the FEM of the foam calibration's own load case (twin.sim.fem:
scikit-fem quadratic tetrahedra, the three level distal links pressed 2 / 4 / 6 mm into the top, the
base held on the palm), with the x faces read as the cameras read them (twin.vision.lateral_strain: the
median outward shift of each x face's points between 15 and 65 % of the height; width = the two
faces' difference, so a rigid shift cancels). The twin side: the calibration bench's flex (its k), its
x-face vertices read the same way. Per preset, at nu 0.2 and 0.35: -eps_x / eps_z (eps_z = -depth /
height), and the slope of that ratio in nu, against which a reading of nu scales.
"""

from __future__ import annotations

import numpy as np

OBJECT = "block"
POISSONS = (0.2, 0.35)
FIDELITIES = ("fast", "faithful")
FEM_EDGES_M = (0.0045, 0.012)
"""The calibration's finest FEM level (twin.sim.calibration.FEM_LEVELS_M's last): the block's force
changed 0.0 % from the level before."""
FACE_TOLERANCE_M = 0.001
"""A point of an x face: within this of the rest shape's extreme x."""


def face_shift_m(
    rest_m: np.ndarray, moved_m: np.ndarray, sign: float, palm_z_m: float, height_m: float
) -> float:
    """The median outward shift of one x face's points (rest (n, 3), moved (n, 3)) in the cameras' band."""
    from twin.vision.lateral_strain import FACE_BAND

    lo, hi = (palm_z_m + f * height_m for f in FACE_BAND)
    x = sign * rest_m[:, 0]
    on_face = (x > x.max() - FACE_TOLERANCE_M) & (rest_m[:, 2] > lo) & (rest_m[:, 2] < hi)
    if on_face.sum() < 3:
        raise ValueError(f"only {on_face.sum()} points on the {'+' if sign > 0 else '-'}x face's band")
    return float(np.median(sign * (moved_m[on_face, 0] - rest_m[on_face, 0])))


def lateral_ratio(rest_m: np.ndarray, moved: list[np.ndarray], depths_m: tuple[float, ...], size_m, palm_z_m):
    """-eps_x / eps_z at each depth: the width's strain along x over the top's (depth / height)."""
    width, height = size_m[0], size_m[2]
    out = []
    for depth, at in zip(depths_m, moved, strict=True):
        grown = sum(face_shift_m(rest_m, at, s, palm_z_m, height) for s in (1.0, -1.0))
        out.append((grown / width) / (depth / height))
    return out


def measure(fidelity: str, poisson: float) -> dict:
    """The FEM's and the calibrated flex's lateral ratio for the library block at `poisson`."""
    from twin.sim import calibration
    from twin.sim.fem import indentation_force_per_pa
    from twin.sim.foam import LIBRARY
    from twin.sim.scene import PALM_SURFACE_Z_M

    foam = LIBRARY[OBJECT].with_overrides(
        fidelity=fidelity, poisson=poisson, young_pa=calibration.REFERENCE_YOUNG_PA, placement_m=(0.0, 0.0)
    )
    tips = calibration.fingertip_geoms(foam)
    mesh = calibration.reference_mesh(foam, *FEM_EDGES_M)
    fem = indentation_force_per_pa(
        mesh, poisson, calibration._gap_fn(tips), calibration.DEPTHS_M, keep_displacement=True
    )
    fem_moved = [mesh.points_m + u.T for u in fem.vertex_displacement_m]
    k = calibration.scale_of(foam).k
    vertices: list[np.ndarray] = []
    force, _ = calibration._bench(foam, tips, k, vertices)
    args = (calibration.DEPTHS_M, foam.size_m, PALM_SURFACE_Z_M)
    return {
        "fidelity": fidelity,
        "poisson": poisson,
        "k": k,
        "fem_ratio": lateral_ratio(mesh.points_m, fem_moved, *args),
        "flex_ratio": lateral_ratio(vertices[0], vertices[1:], *args),
        "fem_force_n": [f * foam.young_pa for f in fem.force_per_pa_n],
        "flex_force_n": [float(f) for f in force],
    }


def run(quick: bool = False) -> dict:
    fidelities = FIDELITIES[:1] if quick else FIDELITIES
    return {"rows": [measure(f, nu) for f in fidelities for nu in POISSONS]}


def _slope(rows: list[dict], key: str, depth: int) -> float:
    (a, b) = rows
    return (b[key][depth] - a[key][depth]) / (b["poisson"] - a["poisson"])


def to_markdown(results: dict) -> str:
    rows = results["rows"]
    lines = [
        "## The Poisson ratio's reference: the flex's bulge against the FEM's",
        "",
        "The library block (60 x 60 x 70 mm) under the calibration's load (the three level distal links "
        "pressed into its top, the base held on the palm). -eps_x / eps_z: the width's strain along the "
        "palm's x at 15-65 % of the height (each x face's median outward shift, as "
        "`twin/vision/lateral_strain.py` reads the cameras' points) over the top's (depth / height). "
        "Reference: the FEM (`twin/sim/fem.py`, scikit-fem quadratic tetrahedra, the calibration's finest "
        "mesh); twin: the calibrated flex in the same bench. A Poisson ratio read through the twin is the "
        "material's where the twin's ratio moves with nu as the FEM's does (*slope*).",
        "",
        "| preset | nu | k | FEM -eps_x/eps_z at 2 / 4 / 6 mm | flex | FEM force (N) | flex force (N) |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        ratios = [" / ".join(f"{v:.3f}" for v in r[key]) for key in ("fem_ratio", "flex_ratio")]
        forces = [" / ".join(f"{v:.2f}" for v in r[key]) for key in ("fem_force_n", "flex_force_n")]
        lines.append(f"| {r['fidelity']} | {r['poisson']:g} | {r['k']:.3f} | {ratios[0]} | {ratios[1]} "
                     f"| {forces[0]} | {forces[1]} |")  # fmt: skip
    lines += [
        "",
        "*read as*: the nu a twin of this preset matches a material's bulge with (the lines through both "
        "points at 6 mm): what reading a real foam of that nu through it would give.",
        "",
        "| preset | slope in nu at 6 mm: FEM | flex | flex / FEM | material's nu read as |",
        "|---|---|---|---|---|",
    ]
    for fidelity in dict.fromkeys(r["fidelity"] for r in rows):
        pair = [r for r in rows if r["fidelity"] == fidelity]
        fem, flex = _slope(pair, "fem_ratio", -1), _slope(pair, "flex_ratio", -1)
        read = ", ".join(f"{r['poisson']:g} as {read_as(pair, r['fem_ratio'][-1]):.3f}" for r in pair)
        lines.append(f"| {fidelity} | {fem:.3f} | {flex:.3f} | {flex / fem:.2f} | {read} |")
    return "\n".join(lines) + "\n"


def read_as(pair: list[dict], ratio: float) -> float:
    """The nu at which the twin's ratio (the line through its two points at 6 mm) is `ratio`."""
    low = pair[0]
    return low["poisson"] + (ratio - low["flex_ratio"][-1]) / _slope(pair, "flex_ratio", -1)
