"""Does the flex bulge as the material does? The twin's lateral strain against the FEM's, per library
shape and preset (issue 38), and the maps `twin identify` reads a camera nu through (twin.sim.bulge).

`twin identify` reads the Poisson ratio from two opposite stereo pairs: the object's width along the
palm's x against the squeeze of its top, read through twin simulations at known nu (twin.sim.poisson).
That reading is the material's only where the flex's lateral strain follows the material's. Reference:
the FEM of the foam calibration's own load case (twin.sim.fem: scikit-fem quadratic tetrahedra, the
three level distal links pressed 6 mm into the top, the base held on the palm), the x faces read as the
cameras read them. Writes twin/sim/bulge_maps.json (the library's maps, which the package reads).
"""

from __future__ import annotations

import json

OBJECTS = ("block", "cylinder", "sphere")
"""The library's geometries (soft_block and firm_block are the block's: the same map)."""
FIDELITIES = ("fast", "faithful")


def run(quick: bool = False) -> dict:
    from twin.sim import bulge
    from twin.sim.foam import LIBRARY

    objects = OBJECTS[:1] if quick else OBJECTS
    rows, shipped = [], {}
    for name in objects:
        for fidelity in FIDELITIES:
            foam = LIBRARY[name].with_overrides(fidelity=fidelity)
            made = bulge.measure(foam)
            rows.append({"object": name, "size_m": list(foam.size_m), **made.to_json()})
            shipped[bulge.digest(foam)] = made.to_json() | {"object": name}
    if not quick:
        bulge.SHIPPED.write_text(
            json.dumps({"by": "benchmarks/nu_reference.py", "maps": shipped}, indent=1) + "\n"
        )
    return {"rows": rows}


def material_read_as(row: dict, material_poisson: float) -> float:
    """The nu the twin reads a material of `material_poisson` as: where the twin's line reaches the
    FEM's ratio at that nu."""
    (p0, p1), (f0, f1), (t0, t1) = row["poisson"], row["fem_ratio"], row["twin_ratio"]
    fem = f0 + (f1 - f0) / (p1 - p0) * (material_poisson - p0)
    return p0 + (fem - t0) / ((t1 - t0) / (p1 - p0))


def to_markdown(results: dict) -> str:
    from twin.sim.bulge import BulgeMap

    lines = [
        "## The Poisson ratio's reference: the flex's bulge against the FEM's",
        "",
        "Each library geometry (the blocks share one) under the calibration's load: the three level distal "
        "links pressed 6 mm into its top, the base held on the palm. -eps_x / eps_z: the width's strain "
        "along the palm's x (each x face's median outward shift, its points in 15-65 % of the height within "
        "3 mm of the outermost, as `twin/vision/lateral_strain.py` reads the cameras' points) over the top's "
        "(depth / height). Reference: the FEM (`twin/sim/fem.py`, scikit-fem quadratic tetrahedra, the "
        "calibration's finest mesh); twin: the calibrated flex (its k at each nu) in the same bench. A "
        "Poisson ratio read through the twin is the material's where the twin's ratio moves with nu as the "
        "FEM's does (*slope*); `twin identify` maps it through both lines (`twin/sim/bulge.py`, the maps "
        "shipped in `twin/sim/bulge_maps.json` from this run).",
        "",
        "| object | preset | FEM -eps_x/eps_z at nu 0.2 / 0.35 | twin | slope in nu: FEM | twin "
        "| a material's 0.2 / 0.35 read by the twin as | the twin's 0.2 / 0.35 is a material's |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in results["rows"]:
        m = BulgeMap.from_json(r)
        read = " / ".join(f"{material_read_as(r, p):.3f}" for p in m.poisson)
        back = " / ".join(f"{m.material_poisson(p):.3f}" for p in m.poisson)
        lines.append(
            f"| {r['object']} | {m.fidelity} | {m.fem_ratio[0]:.3f} / {m.fem_ratio[1]:.3f} "
            f"| {m.twin_ratio[0]:.3f} / {m.twin_ratio[1]:.3f} | {m.fem_slope:.3f} | {m.twin_slope:.3f} "
            f"| {read} | {back} |"
        )
    lines += [
        "",
        "A Poisson ratio outside 0-0.5 in the last column means no material of that shape bulges as the "
        "twin does there: `twin identify` then says the camera read has no material meaning "
        "(`within_materials: false` in its results file). The maps assume the flex is off the material's "
        "bulge by as much in the grasp as under this load; the grasp itself was not compared with an FEM.",
    ]
    return "\n".join(lines) + "\n"
