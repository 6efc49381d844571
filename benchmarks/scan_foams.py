"""Scans of one shape at 10^3, 10^4 and 10^5 triangles become foams whose calibrated force agrees.

Each scan (a scanner-like uniform egg, twin.sim.example_shapes.write_scan_like_surface, 64 x 52 x 44 mm)
is made a foam at both presets and calibrated at first use in a fresh cache (twin.sim.calibration: the FEM
of the fingertips' contact at two Poisson ratios, the flex fitted to each): wall time from the file to a
composed scene, the decimated surface's Hausdorff distance to the scan, the vertices, and the calibrated
twin's force at 2 / 4 / 6 mm under the fingertips against the densest scan's.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

SUBDIVISIONS = (3, 5, 6)
"""1,280, 20,480 and 81,920 triangles."""
RADII_MM = (32.0, 26.0, 22.0)


def run(quick: bool = False) -> dict:
    """One row per scan and preset."""
    from twin.sim import calibration
    from twin.sim.example_shapes import write_scan_like_surface
    from twin.sim.foam import LIBRARY, mesh_object
    from twin.sim.scene import build_model, foam_mesh

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        os.environ["TWIN_CACHE_DIR"] = str(Path(tmp) / "cache")
        for n in SUBDIVISIONS[:1] if quick else SUBDIVISIONS:
            path = write_scan_like_surface(Path(tmp) / f"egg_{n}.stl", RADII_MM, egg=0.15, subdivisions=n)
            for fidelity in ("fast", "faithful"):
                t0 = time.perf_counter()
                foam = mesh_object(path, LIBRARY["block"].with_overrides(fidelity=fidelity))
                build_model(foam)  # meshes, calibrates at first use, composes
                wall_s = time.perf_counter() - t0
                mesh = foam_mesh(foam)
                scale = calibration.scale_of(foam)
                force = calibration.bench_force_n(
                    foam.with_overrides(young_pa=calibration.REFERENCE_YOUNG_PA),
                    calibration.fingertip_geoms(foam),
                    scale.k,
                )
                rows.append({
                    "triangles": 20 * 4**n, "fidelity": fidelity, "wall_s": wall_s,
                    "vertices": len(mesh.points_m), "hausdorff_mm": mesh.surface_error_m * 1e3,
                    "k": scale.k, "force_n": force.tolist(),
                })  # fmt: skip
    return {"rows": rows}


def to_markdown(results: dict) -> str:
    """The BENCHMARKS.md section."""
    rows = results["rows"]
    densest = {r["fidelity"]: r for r in rows if r["triangles"] == max(x["triangles"] for x in rows)}
    lines = [
        "## Scans of any density become calibrated foams (target: forces within 5 % of each other, <= 30 s)",
        "",
        "A scanner-like egg (64 x 52 x 44 mm, `benchmarks/scan_foams.py`) at three densities, each made a "
        "foam and calibrated at first use in a fresh cache (the FEM and the fit at nu = 0.2, then at 0.35 "
        "where one k fits the first): "
        "*wall*: from the file to the composed scene; *Hausdorff*: the decimated surface against the scan; "
        "forces: the "
        "calibrated twin under the fingertips at 40 kPa, nu 0.3, against the densest scan's.",
        "",
        "| triangles | preset | wall (s) | vertices | Hausdorff (mm) | k | force 2 / 4 / 6 mm (N) "
        "| against the densest |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        ref = densest[r["fidelity"]]["force_n"]
        diff = " / ".join(f"{100 * (f / g - 1):+.1f}%" for f, g in zip(r["force_n"], ref, strict=True))
        force = " / ".join(f"{f:.2f}" for f in r["force_n"])
        lines.append(
            f"| {r['triangles']} | {r['fidelity']} | {r['wall_s']:.1f} | {r['vertices']} "
            f"| {r['hausdorff_mm']:.2f} | {r['k']:.3f} | {force} | {diff} |"
        )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(to_markdown(run()))
