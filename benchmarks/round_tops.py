"""Why a round top keeps k = 1 (issue 36): the library sphere's grasp at the k the FEM asks for.

Under the level fingertips the FEM's force on a sphere grows as a widening Hertz contact (F ~ d^1.5), the
flex's nearly linearly, so no one k follows the FEM from 2 to 6 mm (twin.sim.calibration keeps k = 1 and
says so). The k nearest the grasp is the one matching the FEM at the deepest depth the linear FEM covers,
6 mm (`deepest_k`: the flex's force is proportional to k, as its fit rounds measure). This benchmark runs
the twin's compress procedure on the library sphere (fast preset, the default; seed 0; 14 s, as `twin
identify` simulates) over the moduli identification draws, at k = 1 (as composed) and at that k, and
reports whether the grasp holds a squeeze to read (twin.sim.modulus.run_stiffness), each fingertip's
contact through the compression, the foam's height at the end against its diameter (a crushed flex), and
the squeeze stiffness S. MuJoCo's run depends on k and E only through k E (the flex's modulus), so the
table is also the grasp's answer to any sphere of that flex modulus.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

MODULI_PA = (8e3, 16e3, 40e3, 80e3, 150e3, 300e3)
"""The range identification draws (benchmarks/identification.py: 8-300 kPa log-uniform)."""
DURATION_S = 14.0
SEED = 0


def deepest_k(entry: dict) -> tuple[float, list[float]]:
    """The k matching an entry's FEM force at its deepest depth, and the force residual it leaves at each
    depth (the flex's force scaled from the entry's fitted k: proportional to k near the fit)."""
    ratio = entry["fem_force_n"][-1] / entry["twin_force_n"][-1]
    pairs = zip(entry["twin_force_n"], entry["fem_force_n"], strict=True)
    return float(entry["k"]) * ratio, [t * ratio / f - 1.0 for t, f in pairs]


def _shipped_sphere() -> dict:
    from twin.sim import calibration
    from twin.sim.foam import LIBRARY

    entry = calibration.lookup(LIBRARY["sphere"])
    if entry is None:
        raise RuntimeError("the library sphere has no stored calibration: this benchmark's premise is gone")
    return entry


def grasp(young_pa: float, k: float) -> dict:
    """One compress run of the library sphere at `young_pa` with its flex at k times that modulus.

    Composed as the sphere of modulus k E, which the twin composes at k = 1 (a round top: checked), so its
    flex has modulus k E exactly as a calibration's k would give it (the run depends on k E alone)."""
    from twin.experiments.compress import run_compress

    from twin.recording import open_run
    from twin.sim.backend import SimBackend
    from twin.sim.calibration import modulus_scale
    from twin.sim.foam import LIBRARY
    from twin.sim.modulus import EstimateError, run_stiffness

    foam = LIBRARY["sphere"].with_overrides(young_pa=k * young_pa)
    if modulus_scale(foam) != 1.0:
        raise RuntimeError("the library sphere is composed at k != 1: this benchmark's premise is gone")
    backend = SimBackend(foam, seed=SEED)
    with tempfile.TemporaryDirectory() as tmp:
        run_dir = Path(tmp) / "run"
        run_compress(backend, run_dir, duration_s=DURATION_S, object_name="sphere", viewer=False)
        height_m = float(np.ptp(backend.world.data.flexvert_xpos[:, 2]))
        row = {"young_pa": young_pa, "k": k, "height_ratio": height_m / foam.size_m[2]}
        try:
            s, _, _, contact, _ = run_stiffness(run_dir)
            row |= {"held": True, "s_n_per_m": s, "contact": [float(c) for c in contact]}
        except EstimateError as exc:
            row |= {"held": False, "why": str(exc).rsplit(": ", 1)[-1]}
        force = np.asarray(open_run(run_dir).stream("truth")["tip_contact_force_n"])
        row["median_force_n"] = [float(f) for f in np.median(force[len(force) // 2 :], axis=0)]
    return row


def run(quick: bool = False) -> dict:
    """Every modulus at k = 1 and at the deepest depth's k (two moduli when quick)."""
    entry = _shipped_sphere()
    k6, residual = deepest_k(entry)
    at_k1 = entry["fit_rounds"][0]  # the fit starts at k = 1: the flex as composed, measured
    if at_k1["k"] != 1.0:
        raise RuntimeError(f"the sphere's fit started at k = {at_k1['k']}, not 1")
    moduli = MODULI_PA[1::3] if quick else MODULI_PA
    rows = [grasp(e, k) for e in moduli for k in (1.0, k6)]
    return {
        "k_fitted": entry["k"],
        "residual_fitted": entry["residual"],
        "k_deepest": k6,
        "residual_deepest": residual,
        "fem_force_n": entry["fem_force_n"],
        "k1_over_fem": [t / f for t, f in zip(at_k1["force_n"], entry["fem_force_n"], strict=True)],
        "rows": rows,
    }


def _pct(values: list[float]) -> str:
    return " / ".join(f"{100 * v:+.0f} %" for v in values)


def to_markdown(results: dict) -> str:
    """The BENCHMARKS.md section."""
    lines = [
        "## Round tops: the library sphere's grasp at the k the FEM asks for",
        "",
        "The library sphere (70 mm, nu 0.3, fast preset) under the level fingertips, against the FEM "
        f"(`twin/sim/fem.py`, {' / '.join(f'{f:.2f}' for f in results['fem_force_n'])} N at 2 / 4 / 6 mm "
        "at 40 kPa): as composed (k = 1) the flex reads "
        f"{' / '.join(f'{r:.1f}x' for r in results['k1_over_fem'])} the FEM's force; one k over the three "
        f"depths ({results['k_fitted']:.3f}) leaves {_pct(results['residual_fitted'])}; matched at 6 mm, "
        f"the depth nearest the grasp, k = {results['k_deepest']:.3f} leaves "
        f"{_pct(results['residual_deepest'])}. The twin's compress procedure (seed 0, 14 s) at both:",
        "",
        "| E | k | flex modulus | squeeze read | fingertips in contact (F1 / F2 / F3) | height at the end "
        "| S (N/m) | median fingertip force (N), second half |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in results["rows"]:
        contact = " / ".join(f"{c:.2f}" for c in r["contact"]) if r["held"] else "-"
        s = f"{r['s_n_per_m']:.0f}" if r["held"] else "-"
        read = "yes" if r["held"] else f"no: {r['why']}"
        force = " / ".join(f"{f:.1f}" for f in r["median_force_n"])
        lines.append(
            f"| {r['young_pa'] / 1e3:g} kPa | {r['k']:.3f} | {r['k'] * r['young_pa'] / 1e3:.1f} kPa | {read} "
            f"| {contact} | {100 * r['height_ratio']:.0f} % | {s} | {force} |"
        )
    return "\n".join(lines) + "\n"
