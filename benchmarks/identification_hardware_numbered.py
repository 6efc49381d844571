"""Through the hardware bridge, the hidden cases the sim gives a number for (issue 38, line 2).

benchmarks/identification_hardware.py draws its own cases, and on its draw neither the bridge nor the sim
gives a number: the twin's grasp scatter keeps every interval wider than 15 %. "Within the same bounds"
has numbers to compare only where the sim gives them. So this takes the first NUMBERED runs, in the draw's
order, that benchmarks/identification_cameras.py's sim runs gave a number for (its hidden draw, seed 2043,
written 2026-11-27 21:09), and runs each through the bridge as identification_hardware.py does
(`twin emulate rig` holding the case with two opposite pairs at 10 fps, 14 s through the driver with the
cameras, `twin identify --poisson-from-cameras` told the shape and size alone), with the same case's sim
run re-made and identified beside it on today's code.

Usage: python benchmarks/run_all.py --only identification_hardware_numbered (wall-time runs: a quiet machine).
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

from benchmarks import identification as hidden
from benchmarks import identification_cameras as cams
from benchmarks import identification_hardware as bridge

NUMBERED = (("block", 167.1), ("cylinder", 17.2), ("block", 84.9))
"""(shape, true E in kPa to 0.1) of the first three runs of identification_cameras' draw that its sim runs
gave a number for (BENCHMARKS.md, *Identification with two stereo pairs*, in the table's order)."""


def numbered_cases(scratch: Path) -> list[dict]:
    """The NUMBERED cases, drawn again exactly as identification_cameras drew them."""
    cases = hidden.draw_cases(hidden.CANDIDATES, scratch, cams.DRAW_SEED, cams.FIRST_NOISE_SEED)
    chosen = {(c["shape"], round(c["young_pa"] / 1e3, 1)): c for c in cases}
    missing = [key for key in NUMBERED if key not in chosen]
    if missing:
        raise RuntimeError(f"the draw no longer holds {missing}: identification_cameras' draw changed")
    return [chosen[key] for key in NUMBERED]


def run(quick: bool = False) -> dict:
    """Each NUMBERED case through the bridge and in the sim (the first alone when quick)."""
    rows = []
    with tempfile.TemporaryDirectory() as scratch_name:
        base = Path(os.environ.get("TWIN_BENCH_RUNS") or scratch_name)
        scratch = base / "identification_hardware_numbered"
        scratch.mkdir(parents=True, exist_ok=True)
        for case in numbered_cases(scratch)[: 1 if quick else None]:
            made = bridge.hardware_run(case, scratch)
            row = {k: case[k] for k in ("shape", "young_pa", "poisson", "placement_m", "size_m", "seed")}
            row |= made
            if made["driver_rc"] != 0:
                row["refused"] = f"the hardware run failed: {made['driver_said']}"
            else:
                row |= bridge.rig_figures(made["run"])
                description = bridge._description(case)
                row["held"] = hidden.held(made["run"])
                row |= bridge._with_cameras(made["run"], case, description)
            sim_run = cams.make_camera_run(case, scratch / "sim")
            row["sim"] = {"held": hidden.held(str(sim_run))} | bridge._with_cameras(
                str(sim_run), case, bridge._description(case)
            )
            rows.append(row)
            said = row.get("error", row.get("withheld_error", row.get("refused")))
            print(f"  {case['shape']} {case['young_pa'] / 1e3:.1f} kPa: {said}", file=sys.stderr, flush=True)
    return {"rows": rows, "quick": quick}


def to_markdown(results: dict) -> str:
    """The BENCHMARKS.md section."""
    rows = results["rows"]
    ran = [r for r in rows if "refused" not in r or not r["refused"].startswith("the hardware run failed")]
    lines = [
        "## Identification through the bridge on the cases the sim gives a number for",
        "",
        "`benchmarks/identification_hardware_numbered.py`. The first "
        f"{len(NUMBERED)} runs, in the draw's order, that *Identification with two stereo pairs* (seed "
        f"{cams.DRAW_SEED}, the sim, written 2026-11-27 21:09) gave a number for, each put in `twin emulate "
        f"rig`'s hand with `{' '.join(bridge.CAMERA_FLAGS)}`, recorded by the driver with the cameras on "
        f"({hidden.DURATION_S:g} s) and identified as `twin identify --poisson-from-cameras` does, told the "
        "shape and size alone; beside each, the same case's sim run made again on this code and identified "
        "alike.",
        "",
        f"**Through the bridge: {bridge._summary(ran)}.** The same cases in the sim: "
        f"{bridge._summary([r['sim'] for r in rows])}.",
        "",
        *bridge.TABLE_HEAD,
    ]
    for r in rows:
        size = " x ".join(f"{1e3 * s:.0f}" for s in r["size_m"])
        placed = ", ".join(f"{1e3 * v:+.1f}" for v in r["placement_m"])
        if r.get("refused", "").startswith("the hardware run failed"):
            watched, nu, rig = r["refused"], "", ""
        else:
            watched, nu = bridge._cell(r), bridge._nu_cell(r)
            rig = f"{r['hand_hz']:.1f}; " + "; ".join(f"{n} ({p:.0f})" for n, p in r.get("pairs", []))
        lines.append(
            f"| {r['shape']} | {size} | {placed} | {r['poisson']:.3f} | {r['young_pa'] / 1e3:.1f} | "
            f"{watched} | {nu} | {rig} | {bridge._cell(r['sim'])} | {bridge._nu_cell(r['sim'])} |"
        )
    lines += [
        "",
        "Columns as in *Identification through the hardware bridge*.",
    ]
    return "\n".join(lines) + "\n"
