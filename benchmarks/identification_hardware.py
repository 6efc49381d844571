"""Identification through the hardware bridge (issue 38): hidden foams in `twin emulate rig`, recorded by
`twin run compress --backend hardware --cameras`, estimated as for the sim's hidden runs.

One case per shape from benchmarks/identification.py's hidden distribution (its draw_cases: size or
mesh, modulus, Poisson ratio, placement), drawn on a seed of its own. Each is put in the emulated rig's
hand with the emulator's own object options (`--young --poisson --size-mm --placement-mm`, or
`--object-mesh`), served with two opposite stereo pairs (CAMERA_FLAGS), and recorded by the driver with
the cameras on, 14 s, as a lab would. The estimate is `twin identify --poisson-from-cameras`'s, told the
shape and size (or the mesh) only: nu read from the two pairs, the modulus simulations drawing nu within
its interval (benchmarks/identification_cameras.py's identify_with_cameras, scored as
benchmarks/identification.py scores). Beside each, the same case as a sim run watched by the same two
pairs, estimated alike: what the bridge adds.

Usage: python benchmarks/run_all.py --only identification_hardware (wall-time runs: a quiet machine).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks import emulated_rig
from benchmarks import identification as hidden
from benchmarks import identification_cameras as cams

DRAW_SEED = 2044
"""The seed benchmarks/identification.py's history left for the next method: nothing was looked at on it
before this draw."""
FIRST_NOISE_SEED = 30000
CANDIDATES = 3
"""Draws per shape: the first the hand holds is scored (a tall mesh may topple as the hand closes)."""
CAMERA_FLAGS = ("--camera-placement", cams.PLACEMENTS, "--camera-rate", "10")
"""Two opposite pairs at 10 fps: four rendered cameras, the driver's two vision pipelines and the real-time
twin share this project's 2 cores; at 30 fps the hand loop fell to 11-13 Hz, at 10 to ~26 Hz (one pair at
30 fps: 22.8-26.5). The nu read takes the frames nearest the squeeze's troughs: within 50 ms at 10 fps."""


def emulator_flags(case: dict) -> list[str]:
    """`twin emulate rig`'s options for the case's foam: the sim case's (benchmarks/identification.py's
    _foam: the library block's material in the drawn shape, size, modulus, ratio and placement)."""
    from twin.sim.foam import LIBRARY

    block = LIBRARY["block"]
    flags = ["--young", repr(case["young_pa"]), "--poisson", repr(case["poisson"])]
    flags += ["--placement-mm", *(repr(1e3 * v) for v in case["placement_m"])]
    if "mesh" in case:
        return ["--object", "block", *flags, "--object-mesh", case["mesh"]]
    flags += ["--size-mm", *(repr(1e3 * v) for v in case["size_m"])]
    # the library shape, with the block's material where the library's differs (the sphere's density)
    return ["--object", case["shape"], *flags, "--density", repr(block.density_kg_m3)]


def hardware_run(case: dict, scratch: Path) -> dict:
    """The case's 14 s hardware run with the two pairs against the emulated rig holding it: the run's
    directory, the driver's exit status and last stderr line, and the emulator's object line."""
    name = f"hw-{case['shape']}-s{case['seed']}"
    rig = scratch / f"rig-{name}" / "rig.toml"
    run_dir = scratch / name
    shutil.rmtree(run_dir, ignore_errors=True)  # a wall-time run: never reused from an earlier one
    shutil.rmtree(rig.parent, ignore_errors=True)
    rig.parent.mkdir(parents=True)
    log = rig.parent / "emulator.log"
    flags = [
        *emulator_flags(case),
        "--seed",
        str(case["seed"]),
        *CAMERA_FLAGS,
    ]
    emulator = emulated_rig.start(rig, log, *flags, cwd=rig.parent)
    try:
        named = [] if "mesh" in case else ["--object", case["shape"]]  # a hardware run names a library shape
        started = time.perf_counter()
        driver = subprocess.run(
            [*emulated_rig.TWIN, "run", "compress", "--backend", "hardware", "--rig", str(rig), "--cameras",
             *named, "--duration", str(hidden.DURATION_S), "--out", str(run_dir), "--no-progress"],
            capture_output=True, text=True, cwd=rig.parent, timeout=600,
        )  # fmt: skip
        wall_s = time.perf_counter() - started
    finally:
        emulated_rig.stop(emulator)
    said = next((line for line in log.read_text().splitlines() if line.startswith("hand: ")), "")
    return {
        "run": str(run_dir),
        "driver_rc": driver.returncode,
        "driver_said": (driver.stderr.strip().splitlines() or [""])[-1],
        "emulator_object": said.split("object: ", 1)[-1].rstrip(")"),
        "run_wall_s": wall_s,
    }


def rig_figures(run_dir: str) -> dict:
    """What the bridge delivered: the hand's rate, and per stereo pair the frames recorded and the points
    per frame (median)."""
    from twin.interface.backend import stereo_stream_name
    from twin.recording.reader import Run

    run = Run(run_dir)
    hand = run.stream("hand")
    figures = {"status": run.status, "hand_hz": (len(hand.t_s) - 1) / float(hand.t_s[-1] - hand.t_s[0])}
    for pair, placement in enumerate(run.metadata.get("stereo_placements") or []):
        name = stereo_stream_name(pair, placement)
        if name in run.streams:
            stereo = run.stream(name)
            points = [len(p) for p in stereo["points_m"]] if len(stereo) else [0]
            figures.setdefault("pairs", []).append([len(stereo), float(np.median(points))])
    return figures


def _with_cameras(run_dir: str, case: dict, description) -> dict:
    """`twin identify --poisson-from-cameras`'s estimate of a run, scored against the case's modulus and
    Poisson ratio."""
    row = hidden._score(
        {"young_pa": case["young_pa"]} | cams.identify_with_cameras(Path(run_dir), 2, description)
    )
    if "nu_read" in row:
        row["nu_error"] = row["nu_read"] - case["poisson"]
        row["nu_covered"] = bool(row["nu_ci95"][0] <= case["poisson"] <= row["nu_ci95"][1])
    return row


def run(quick: bool = False) -> dict:
    """One held case per shape (block and sphere alone when quick)."""
    shapes = ("block", "sphere") if quick else hidden.SHAPES
    rows = []
    with tempfile.TemporaryDirectory() as scratch_name:
        scratch = Path(os.environ.get("TWIN_BENCH_RUNS") or scratch_name) / "identification_hardware"
        scratch.mkdir(parents=True, exist_ok=True)
        cases = hidden.draw_cases(CANDIDATES, scratch, DRAW_SEED, FIRST_NOISE_SEED)
        for shape in shapes:
            for case in (c for c in cases if c["shape"] == shape):
                made = hardware_run(case, scratch)
                row = {k: case[k] for k in ("shape", "young_pa", "poisson", "placement_m", "size_m", "seed")}
                row |= made
                if made["driver_rc"] != 0:
                    row["refused"] = f"the hardware run failed: {made['driver_said']}"
                    rows.append(row)
                    print(f"  {shape}: {row['refused']}", file=sys.stderr, flush=True)
                    continue
                row |= rig_figures(made["run"])
                if not hidden.held(made["run"]):
                    row["variant"] = "not held"
                    row["sim"] = {"held": hidden.held(hidden.make_run((case, str(scratch))))}
                    rows.append(row)
                    print(f"  {shape} s{case['seed']}: not held, next draw", file=sys.stderr, flush=True)
                    continue
                description = _description(case)
                row["size_m"] = tuple(description.size_m)  # a mesh's: its extents
                row = row | _with_cameras(made["run"], case, description)
                row["variant"] = "hidden"
                # The same case as a sim run watched by the same two pairs, estimated alike: what the
                # bridge adds.
                sim_run = cams.make_camera_run(case, scratch / "sim")
                row["sim"] = {"held": hidden.held(str(sim_run))} | _with_cameras(
                    str(sim_run), case, description
                )
                rows.append(row)
                print(
                    f"  {shape}: E {row['young_pa'] / 1e3:.1f} kPa: {row.get('error', row.get('refused'))}",
                    file=sys.stderr,
                    flush=True,
                )
                break
    return {"rows": rows, "quick": quick}


def _description(case: dict):
    """What the estimate is told: the shape and size, or the mesh (the material is what it finds)."""
    from twin.sim.foam import FoamParams, get_object, mesh_object

    if "mesh" in case:
        return mesh_object(Path(case["mesh"]), get_object("block"))
    shape = case["shape"]
    return FoamParams(name=shape, shape=shape, size_m=tuple(case["size_m"]), young_pa=4e4, poisson=0.3)


def _cell(est: dict | None) -> str:
    """One estimate in one cell: the number and its interval, the interval alone and what it withheld,
    or why there is none."""
    if not est:
        return ""
    held = "" if est.get("held", True) else "not held; "
    if "estimate_pa" in est:
        low, high = (v / 1e3 for v in est["ci95_pa"])
        return f"{held}**{est['estimate_pa'] / 1e3:.1f}** ({low:.1f}-{high:.1f}), {100 * est['error']:+.1f} %"
    if "interval_only_pa" in est:
        low, high = (v / 1e3 for v in est["interval_only_pa"])
        return f"{held}{low:.1f}-{high:.1f} alone (withheld {100 * est['withheld_error']:+.1f} %)"
    if "refused" in est:
        return f"{held}refused: {est['refused'].split(': ')[0]}"  # its first clause: what failed
    return held.removesuffix("; ") or "held"


def _summary(estimates: list[dict]) -> str:
    """Numbers, their errors, the withheld estimates' errors and the coverage over a column, and nu's."""
    numbers = [abs(e["error"]) for e in estimates if "error" in e]
    withheld = [abs(e["withheld_error"]) for e in estimates if "withheld_error" in e]
    covered = [e["covered"] for e in estimates if "covered" in e]
    said = f"a number for {len(numbers)} of {len(estimates)}"
    if numbers:
        said += f" (|error| median {100 * np.median(numbers):.1f} %, max {100 * max(numbers):.1f} %)"
    if withheld:
        said += f", the withheld estimates {100 * min(withheld):.1f}-{100 * max(withheld):.1f} % off"
    said += f"; the 95 % interval holds the truth in {sum(covered)} of {len(covered)}"
    nu = [e for e in estimates if "nu_error" in e]
    said += f"; nu read on {len(nu)} of {len(estimates)}"
    if nu:
        median = float(np.median([abs(e["nu_error"]) for e in nu]))
        held = sum(e["nu_covered"] for e in nu)
        said += f" (|error| median {median:.3f}, its interval holding the truth on {held})"
    return said


def _nu_cell(est: dict | None) -> str:
    """nu as the two pairs read it, its 95 % interval and error, or why there is none."""
    if not est:
        return ""
    if "nu_read" in est:
        low, high = est["nu_ci95"]
        return f"{est['nu_read']:.3f} ({low:.3f}-{high:.3f}), {est['nu_error']:+.3f}"
    return f"none: {est['nu_failed'][:70]}" if est.get("nu_failed") else ""


TABLE_HEAD = (
    "| shape | size (mm) | placement (mm) | Poisson | true E (kPa) | through the bridge: E (kPa) | "
    "nu read (95 %), error | hand (Hz); frames (points, median) per pair | the sim: E (kPa) | "
    "the sim: nu read |",
    "|---|---|---|---|---|---|---|---|---|---|",
)
"""The per-case table's head (benchmarks/identification_hardware_numbered.py's too)."""


def to_markdown(results: dict) -> str:
    """The BENCHMARKS.md section."""
    rows = results["rows"]
    scored = [r for r in rows if r.get("variant") == "hidden"]
    lines = [
        "## Identification through the hardware bridge (`twin emulate rig` holding hidden foams)",
        "",
        "`benchmarks/identification_hardware.py`. One hidden case per shape, drawn as the sim's hidden "
        f"cases are (benchmarks/identification.py's distribution, seed {DRAW_SEED}, noise seeds from "
        f"{FIRST_NOISE_SEED}; the next draw of a shape where the hand did not hold one), put in the emulated "
        "rig's hand with `twin emulate rig --young --poisson --size-mm --placement-mm` (or "
        f"`--object-mesh`) and `{' '.join(CAMERA_FLAGS)}` (two opposite stereo pairs, rig.toml's "
        "[[stereo]]), recorded by the driver with the cameras on (`twin run compress --backend hardware "
        f"--cameras`, {hidden.DURATION_S:g} s), and identified as `twin identify --poisson-from-cameras` "
        "does, told the shape and size (or the mesh) alone: nu read from the two pairs, the modulus "
        "simulations drawing nu within its 95 % interval. Beside each, the same case as a sim run watched by "
        "the same two pairs, identified alike: what the bridge adds.",
        "",
        f"**{len(scored)} held hardware runs: {_summary(scored)}.** The same cases in the sim: "
        f"{_summary([r['sim'] for r in scored])}.",
        "",
        *TABLE_HEAD,
    ]
    for r in rows:
        size = " x ".join(f"{1e3 * s:.0f}" for s in r["size_m"]) if r["size_m"] else "(mesh)"
        placed = ", ".join(f"{1e3 * v:+.1f}" for v in r["placement_m"])
        watched = _cell(r if r.get("variant") == "hidden" else r | {"held": False})
        if r.get("refused", "").startswith("the hardware run failed"):
            watched = r["refused"]
        pairs = "; ".join(f"{n} ({p:.0f})" for n, p in r.get("pairs", []))
        rig = f"{r['hand_hz']:.1f}; {pairs}" if "hand_hz" in r else ""
        sim = r.get("sim") or {}
        lines.append(
            f"| {r['shape']} | {size} | {placed} | {r['poisson']:.3f} | {r['young_pa'] / 1e3:.1f} | "
            f"{watched} | {_nu_cell(r)} | {rig} | {_cell(sim)} | {_nu_cell(sim)} |"
        )
    lines += [
        "",
        "*E*: the estimate in bold with its 95 % interval and error where a number is given; the interval "
        "alone where it is wider than 15 % (twin.sim.modulus.PRECISION), with the error of the estimate "
        "withheld. *nu*: the two pairs' read, its 95 % interval as linearised from the strains (the "
        "results file cuts it to the Poisson ratios simulated, 0.2-0.35; the drawn ratios lie within those, "
        "so whether it holds the truth is the same either way) and its error. *hand*: the driver's "
        "recorded hand samples per second of run time (target 30 Hz); "
        "*frames*: per pair, the frames recorded and the median of the points reconstructed per frame.",
        "",
    ]
    return "\n".join(lines)
