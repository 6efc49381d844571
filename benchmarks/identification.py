"""Identification against the twin's truth: `twin identify`'s modulus on hidden foams of every shape.

Hidden cases, drawn once from a seed nothing was developed or tuned on (DRAW_SEED): five shapes (the
block, the cylinder, the sphere and two closed meshes: an egg and a bumpy sphere, written as STL here),
sizes across what the hand holds, moduli log-uniform over 8-300 kPa, the Poisson ratio uniform over
the foams' 0.2-0.35, the object placed uniformly within 3 mm of the palm's centre (either axis), sensor
noise on with unused noise seeds; each a 14 s `twin run compress` and an estimate from the run and the
object's description (shape and size, or the mesh: never its modulus, Poisson ratio or placement).
Robustness, apart: a description 1 mm larger than the object, a different compression profile, and
hardware runs through the emulated rig (`twin emulate rig`). Timing: benchmarks/identify_speed.py.
"""

from __future__ import annotations

import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from benchmarks import emulated_rig

DRAW_SEED = 2042
"""2031 was looked at while the squeeze statistic was chosen, 2032 while a failed twin simulation was made
a missing point, 2033 before a placement square was tried. 2034 scored that square (median 8.0 %, max
588 %) and the centred bracket (5.7 %, 34.5 %); its worst runs were then studied to build the grasp-matched
sweep (docs/identification.md). 2035, with noise seeds from 12000, scored the sweep (median 6.1 %, max
122 %, 6 of 30 over 15 %) and the centred bracket (7.9 %, 127 %, 9 of 31) on the same runs; one of its
runs crashed the sweep's fit (fixed, with a test) and the whole draw was run again. Its runs were then
used to build the nuisance-drawn rounds (each simulation's placement, size and Poisson ratio drawn over
their tolerances), scored on 2036 with noise seeds from 14000 (median 2.2 %, max 69.2 %, 11 refused),
beside the method before on the same runs (2.4 %, 82.4 %, 6 refused). Variants of it were tried on 2035
only; open-loop replays of the run's commands instead of its procedure on 20 of 2036's runs (two
intervals missed; not kept). 2037, with noise seeds from 16000, scored the precision rule (a number only
where its 95 % interval is within 15 %, PRECISION in twin.sim.modulus), fixed before the draw was made:
20 numbers, median 2.5 %, max 18.9 %, coverage 90 %; 15 intervals alone (14 hold the truth), 5 refused.
Two of its numbers lay outside their intervals (a sphere on a second branch of grasps the robust fit
set aside, a block read beyond its like simulations); studied on 2037's runs, the interval became a
prediction from every like simulation near the run's S (predictive_sigma), scored on 2038 with noise
seeds from 18000: 12 numbers, median 1.3 %, max 8.2 %, coverage 100 %; 18 intervals alone (18 hold the
truth), 10 refused (two with no first estimate: the twin dropped the object at 40 kPa). 2037's captured
simulations were then studied for where the width comes from, and its refused runs and 2038's two
were run again to try the first estimate's firm and soft fallbacks and the extra round (FALLBACK_PA and
EXTRA_ROUNDS in twin.sim.modulus), scored on 2039 with noise seeds from 20000. The intervals of 2038 and
2039 then set the interval's calibrated scale (INTERVAL_SCALE, benchmarks/interval_calibration.py), and
2039's 8 runs refused for too few like grasps were run again with three extra rounds: 4 became intervals,
one of which missed the truth (an egg at 129 kPa read 67.2-120.6), at 39-66 s a run; not kept.
Scored on 2040 with noise seeds from 22000: 19 numbers, median 1.7 %, max 15.0 %, coverage 89 % (17 of 19);
14 intervals alone (11 hold the truth); 7 refused. 2040's intervals were then added to the calibration
(the scale became 0.725), scored on 2041 with noise seeds from 24000: 14 numbers, median 2.5 %, max
12.4 %, coverage 79 % (11 of 14); 16 intervals alone (13 hold the truth). Both calibrations covered too
little on the draw after them, so the scale went back to 1 (benchmarks/interval_calibration.py scores
each draw at both). The next method, and the scale of 1 itself on a draw it was not chosen on, must be
scored on a seed of its own (2042 on). 2042, with noise seeds from 26000, scores the twin on MuJoCo 4.0
with the foam calibrated against the FEM (issue 36); its first attempt stopped at a tall egg the
calibration bench could not hold (now k = 1, with the reason), before any estimate was looked at. The
next method must be scored on 2043 on. 2043, with noise seeds from 28000, scored `twin identify
--poisson-from-cameras` on runs recorded with two stereo pairs (lateral and opposite;
benchmarks/identification_cameras.py): 39 held runs (the egg's 24 draws gave 7), a number for 7 (18 %),
median 1.6 %, max 4.8 %; each of the 24 intervals given held the truth (62 % of all runs); nu read on 21,
the range drawn narrowed on 9. Its first attempt stopped after 8 rows on an egg run whose stereo crop
crashed OpenCV's matcher (fixed in twin.vision.reconstruct, with a test; the failed run made again); one
egg's nu read crashed on a mesh the calibration bench could not hold (fixed in twin.sim.calibration, with
a test) and was estimated again. The default `twin identify` (nu 0.2-0.35 drawn) on the first 11 of its
runs: 3 numbers as with the cameras, 8 of 11 covered (cameras 7). The next method must be scored on 2044
on. 2044, with noise seeds from 30000, scored the hardware bridge (benchmarks/identification_hardware.py:
one case per shape in `twin emulate rig`, with and without the cameras, beside the sim run of each): a
first attempt (--quick, beside a loaded suite: the hand loop far behind) was discarded; the second, quiet,
gave 4 held runs, each an interval alone holding the truth (withheld -13.9, -10.2, +11.7, +16.1 %), and was
run again with the camera-less and sim columns added: the third is the record. The next method
must be scored on 2045 on. Seeds 3001-3002 are benchmarks/identifiability.py's draws."""
FIRST_NOISE_SEED = 26000
PER_SHAPE = 8
CANDIDATES = 24
"""Draws per shape: the first PER_SHAPE the hand holds are the hidden cases (some tall meshes topple or
squirt out while the hand closes; those runs are scored apart, as refusals the estimator must make)."""
HELD_BELOW_COUNTS = 16000
"""A finger whose drive passes this in the compression closed on nothing (fully closed: ~16,780)."""
SHAPES = ("block", "cylinder", "sphere", "egg", "bumpy")
RANGE_PA = (8e3, 3e5)
POISSON = (0.2, 0.35)
PLACEMENT_MM = 3.0
DURATION_S = 14.0
EMULATED = ("soft_block", "block", "sphere")
"""Library objects the emulated rig holds (`twin emulate rig --object`), one hardware run each."""


def _surface_stl(path: Path, radius_mm: tuple[float, float, float], kind: str) -> Path:
    """A closed surface in millimetres: an egg (one end blunter) or a bumpy ellipsoid."""
    from twin.sim.example_shapes import write_closed_surface

    if kind == "egg":
        return write_closed_surface(path, radius_mm, egg=0.12, rings=24, segments=48)
    return write_closed_surface(path, radius_mm, bump=0.06, rings=24, segments=48)


def draw_cases(
    n_per_shape: int, scratch: Path, draw_seed: int = DRAW_SEED, first_noise_seed: int = FIRST_NOISE_SEED
) -> list[dict]:
    """Candidate cases: shape, size (or mesh), modulus, Poisson ratio, placement and noise seed."""
    rng = np.random.default_rng(draw_seed)
    cases = []
    seed = first_noise_seed
    for shape in SHAPES:
        for i in range(n_per_shape):
            seed += 1
            young = float(math.exp(rng.uniform(*np.log(RANGE_PA))))
            poisson = float(rng.uniform(*POISSON))
            placement = tuple(float(v) for v in rng.uniform(-PLACEMENT_MM, PLACEMENT_MM, 2) / 1e3)
            case = {
                "shape": shape,
                "young_pa": young,
                "poisson": poisson,
                "placement_m": placement,
                "seed": seed,
            }
            if shape == "block":
                case["size_m"] = (
                    rng.uniform(0.050, 0.075),
                    rng.uniform(0.050, 0.075),
                    rng.uniform(0.050, 0.090),
                )
            elif shape == "cylinder":
                d = rng.uniform(0.050, 0.078)
                case["size_m"] = (d, d, rng.uniform(0.050, 0.090))
            elif shape == "sphere":
                case["size_m"] = (rng.uniform(0.050, 0.080),) * 3
            else:
                radii = (rng.uniform(24, 36), rng.uniform(24, 36), rng.uniform(24, 40))
                case["mesh"] = str(_surface_stl(scratch / f"{shape}-{i}.stl", radii, shape))
            case["size_m"] = tuple(float(v) for v in case.get("size_m", ()))
            cases.append(case)
    return cases


def _foam(case: dict):
    from twin.sim.foam import get_object, mesh_object

    material = get_object("block").with_overrides(
        young_pa=case["young_pa"], poisson=case["poisson"], placement_m=case["placement_m"]
    )
    if "mesh" in case:
        return mesh_object(Path(case["mesh"]), material)
    return material.with_overrides(name=case["shape"], shape=case["shape"], size_m=case["size_m"])


def make_run(args: tuple[dict, str]) -> str:
    """One hidden case's compress run (its directory)."""
    case, out_dir = args
    from twin.experiments.compress import CompressProfile, run_compress

    from twin.sim.backend import SimBackend

    foam = _foam(case)
    run_dir = Path(out_dir) / f"{case['shape']}-s{case['seed']}"
    if not (run_dir / "run.json").exists():
        shutil.rmtree(run_dir, ignore_errors=True)
        profile = CompressProfile(**case["profile"]) if "profile" in case else None
        run_compress(
            SimBackend(foam, seed=case["seed"]),
            run_dir,
            duration_s=DURATION_S,
            object_name=foam.name,
            profile=profile,
        )
    return str(run_dir)


def held(run_dir: str) -> bool:
    """Whether the hand held the object through the compression, by the twin's own account (no finger
    closed on nothing): the ground truth against which a refusal is right or wrong."""
    from twin.recording.reader import Run

    run = Run(run_dir)
    phases = list(run.metadata["phases"])
    cmd, hand = run.stream("command"), run.stream("hand")
    compress = cmd["phase"] == phases.index("compress") if "compress" in phases else np.zeros(len(cmd), bool)
    if not compress.any():  # the grasp never settled: never held
        return False
    drive = hand["position_counts"][hand.t_s >= float(cmd.t_s[compress][0]), :3]
    return bool(len(drive)) and bool((drive < HELD_BELOW_COUNTS).all())


def estimate(run_dir: str, description=None, tolerances=None, workers: int = 2) -> dict:
    """estimate_modulus's figures for a row (or why there is none); `tolerances` as `twin identify`'s
    (default: twin.sim.modulus.Tolerances())."""
    from twin.sim.modulus import EstimateError, ImpreciseEstimateError, estimate_modulus

    started = time.perf_counter()
    try:
        e = estimate_modulus(run_dir, description=description, workers=workers, tolerances=tolerances)
    except ImpreciseEstimateError as exc:  # the interval alone: scored for coverage, and what it hid
        return {
            "refused": str(exc).removeprefix(f"{run_dir}: "),
            "interval_only_pa": list(exc.estimate.ci95_pa),
            "withheld_pa": exc.estimate.young_pa,
            "wall_s": exc.estimate.wall_s,
        }
    except EstimateError as exc:
        return {"refused": str(exc).removeprefix(f"{run_dir}: "), "wall_s": time.perf_counter() - started}
    return {
        "estimate_pa": e.young_pa,
        "ci95_pa": list(e.ci95_pa),
        "sigma_log": e.sigma_log,
        "simulations": len(e.simulations),
        "wall_s": e.wall_s,
    }


def _score(row: dict) -> dict:
    if "estimate_pa" in row:
        row["error"] = row["estimate_pa"] / row["young_pa"] - 1.0
        row["covered"] = bool(row["ci95_pa"][0] <= row["young_pa"] <= row["ci95_pa"][1])
    if "interval_only_pa" in row:
        row["withheld_error"] = row["withheld_pa"] / row["young_pa"] - 1.0
        row["covered"] = bool(row["interval_only_pa"][0] <= row["young_pa"] <= row["interval_only_pa"][1])
    return row


def _emulated_run(name: str, scratch: Path) -> dict:
    """A hardware run against the emulated rig holding library object `name`, and its estimate."""
    from twin.sim.foam import get_object

    foam = get_object(name)
    rig = scratch / f"rig-{name}" / "rig.toml"
    rig.parent.mkdir(parents=True, exist_ok=True)
    emulator = emulated_rig.start(
        rig, rig.parent / "emulator.log", "--no-cameras", "--object", name, cwd=rig.parent
    )
    try:
        run_dir = scratch / f"hw-{name}"
        shutil.rmtree(run_dir, ignore_errors=True)  # a wall-time run: never reused from an earlier one
        subprocess.run(
            [*emulated_rig.TWIN, "run", "compress", "--backend", "hardware", "--rig", str(rig),
             "--duration", str(DURATION_S), "--out", str(run_dir), "--no-progress"],
            check=True, capture_output=True, cwd=rig.parent,
        )  # fmt: skip
    finally:
        emulated_rig.stop(emulator)  # Ctrl-C, then kill after a grace: a busy machine never loses the table
    from twin.sim.foam import FoamParams

    description = FoamParams(name=name, shape=foam.shape, size_m=foam.size_m, young_pa=4e4, poisson=0.3)
    row = {
        "shape": f"{name} (emulated rig)",
        "young_pa": foam.young_pa,
        "poisson": foam.poisson,
        "size_m": foam.size_m,
    }
    return _score(row | estimate(str(run_dir), description))


def run(quick: bool = False) -> dict:
    """Hidden cases, robustness cases, the draws not held and the emulated rig's runs."""
    per_shape = 1 if quick else PER_SHAPE
    with tempfile.TemporaryDirectory() as scratch_name:
        scratch = Path(os.environ.get("TWIN_BENCH_RUNS") or scratch_name)
        scratch.mkdir(parents=True, exist_ok=True)
        candidates = draw_cases(2 if quick else CANDIDATES, scratch)
        cases, dropped, made = [], [], 0
        with ProcessPoolExecutor(2) as pool:  # each shape's draws in order, two at a time, until enough held
            for shape in SHAPES:
                queue = [c for c in candidates if c["shape"] == shape]
                while queue and sum(c["shape"] == shape for c in cases) < per_shape:
                    batch, queue = queue[:2], queue[2:]
                    for case, run_dir in zip(
                        batch, pool.map(make_run, [(c, str(scratch)) for c in batch]), strict=True
                    ):
                        made += 1
                        case["run"] = run_dir
                        if sum(c["shape"] == shape for c in cases) < per_shape:
                            (cases if held(run_dir) else dropped).append(case)
                print(f"  {shape}: {made} runs made so far", file=sys.stderr, flush=True)
        # Robustness: the first block and sphere described 1 mm larger; two cases under another profile.
        robust = []
        for shape in ("block", "sphere"):
            first = next(c for c in cases if c["shape"] == shape)
            robust.append(first | {"variant": "described 1 mm larger", "describe_grown_m": 0.001})
        for shape in ("block", "cylinder"):
            first = next(c for c in cases if c["shape"] == shape)
            variant = {
                "variant": "profile 300 + 300 sin(2 pi t / 3) counts",
                "profile": {"offset_counts": 300.0, "amplitude_counts": 300.0, "frequency_hz": 1 / 3},
                "seed": first["seed"] + 1000,
            }
            robust.append({k: v for k, v in first.items() if k != "run"} | variant)
        if quick:
            robust = robust[:1]
        with ProcessPoolExecutor(2) as pool:
            for case, run_dir in zip(
                robust, pool.map(make_run, [(c, str(scratch)) for c in robust]), strict=True
            ):
                case["run"] = run_dir
        rows = []
        for case in cases + robust + dropped:
            description = None
            if "describe_grown_m" in case:
                from twin.recording.reader import Run
                from twin.sim.fit import foam_of_run

                true = foam_of_run(Run(case["run"]))
                description = true.with_overrides(
                    size_m=tuple(s + case["describe_grown_m"] for s in true.size_m)
                )
            row = {k: case[k] for k in ("shape", "young_pa", "poisson", "placement_m", "size_m", "seed")}
            row["variant"] = case.get("variant", "hidden" if case in cases else "not held")
            if "mesh" in case:
                from twin.recording.reader import Run

                row["size_m"] = tuple(Run(case["run"]).metadata["object"]["size_m"])
            row = _score(row | estimate(case["run"], description))
            rows.append(row)
            print(
                f"  {row['shape']:8s} {row['variant'][:20]:20s} E {row['young_pa'] / 1e3:6.1f} kPa: "
                f"{row.get('error', row.get('refused'))}",
                file=sys.stderr,
                flush=True,
            )
        emulated = [] if quick else [_emulated_run(name, scratch) for name in EMULATED]
    return {"rows": rows, "emulated": emulated, "drawn": made, "quick": quick}


def _summary(rows: list[dict]) -> dict:
    scored = [r for r in rows if "error" in r]
    errors = np.abs([r["error"] for r in scored]) if scored else np.array([np.nan])
    intervals = [r for r in rows if "interval_only_pa" in r]
    return {
        "n": len(rows),
        "refused": len(rows) - len(scored),
        "median": float(np.median(errors)),
        "max": float(np.max(errors)),
        "coverage": float(np.mean([r["covered"] for r in scored])) if scored else float("nan"),
        "interval_only": len(intervals),
        "interval_only_covered": sum(r["covered"] for r in intervals),
        "withheld_max": max((abs(r["withheld_error"]) for r in intervals), default=float("nan")),
    }


INTRO = (
    "Simulation-based inference (`twin/sim/modulus.py`, docs/identification.md): the run's squeeze "
    "stiffness (the fingertips' summed force on their summed travel) against the twin running the run's own "
    "procedure with the described object at candidate moduli, what the run cannot tell apart (placement "
    "within 3 mm, size within 1 mm, Poisson ratio 0.2-0.35) drawn anew for every simulation, the power "
    "law fitted to those that grasp the object as the hand did; a 95 % interval from the statistic's "
    "noise and their scatter. No table per shape or size. Hidden cases drawn from seed {seed} (which "
    "earlier seeds were looked at, and for what: DRAW_SEED in benchmarks/identification.py): the "
    "first {per_shape} per shape the hand held (block, cylinder, sphere, "
    "an egg and a bumpy sphere from STL), sizes 50-90 mm, E log-uniform 8-300 kPa, Poisson ratio "
    "0.2-0.35, placed uniformly within 3 mm of the palm's centre, sensor noise on, 14 s runs; the "
    "estimate gets the shape and size (or the mesh) only."
)


def to_markdown(results: dict) -> str:
    """The BENCHMARKS.md section."""
    from twin.sim.modulus import INTERVAL_SCALE

    hidden = [r for r in results["rows"] if r["variant"] == "hidden"]
    s = _summary(hidden)
    lines = [
        "## Identification: the modulus of any object in the hand (`twin identify`, hidden foams)",
        "",
        INTRO.format(seed=DRAW_SEED, per_shape=PER_SHAPE),
        "",
        f"Interval scale (twin.sim.modulus.INTERVAL_SCALE): {INTERVAL_SCALE:g}.",
        "",
        f"**{s['n']} hidden runs: median |E error| {100 * s['median']:.1f} %, max {100 * s['max']:.1f} %, "
        f"the 95 % interval holds the truth in {100 * s['coverage']:.0f} %; {s['refused']} refused, of which "
        f"{s['interval_only']} with their interval alone (it holds the truth in {s['interval_only_covered']} "
        f"of {s['interval_only']}; the numbers withheld were off by up to {100 * s['withheld_max']:.1f} %)** "
        "(target: median <= 5 %, max <= 15 %, coverage >= 90 %; errors and coverage over the numbers given; "
        "a number is given where its 95 % interval is within 15 %, PRECISION in twin.sim.modulus).",
        "",
        "| shape | runs | refused | median abs error | max abs error | coverage | median interval (+-) |",
        "|---|---|---|---|---|---|---|",
    ]
    for shape in SHAPES:
        part = [r for r in hidden if r["shape"] == shape]
        if not part:
            continue
        p = _summary(part)
        widths = [math.expm1(1.959964 * r["sigma_log"]["total"]) for r in part if "sigma_log" in r]
        width = 100 * float(np.median(widths)) if widths else float("nan")
        lines.append(
            f"| {shape} | {p['n']} | {p['refused']} | {100 * p['median']:.1f} % | {100 * p['max']:.1f} % | "
            f"{100 * p['coverage']:.0f} % | {width:.0f} % |"
        )
    lines += [
        "",
        "Every hidden run:",
        "",
        "| " + " | ".join(ROW_HEADER) + " |",
        "|---" * len(ROW_HEADER) + "|",
    ]
    lines += [_row(r) for r in hidden]
    lines += [
        "",
        "Robustness (the same draw's first cases, varied; the emulated rig's hardware runs):",
        "",
        "| case | true E (kPa) | estimate (kPa) | 95 % interval | error | covered |",
        "|---|---|---|---|---|---|",
    ]
    for r in [r for r in results["rows"] if r["variant"] not in ("hidden", "not held")] + results["emulated"]:
        name = f"{r['shape']}, {r['variant']}" if "variant" in r else r["shape"]
        lines.append(_short_row(name, r))
    dropped = [r for r in results["rows"] if r["variant"] == "not held"]
    refused = sum("refused" in r for r in dropped)
    lines += [
        "",
        f"Of {results['drawn']} draws, the hand did not hold {len(dropped)} (a finger closed on nothing: the "
        f"object toppled or squirted out while the hand closed); the estimator refused {refused} of them in "
        "one line (a number for an object not held would be a failure):",
        "",
    ]
    for r in dropped:
        size = " x ".join(f"{v * 1e3:.0f}" for v in r["size_m"])
        said = (
            f"refused: {r['refused']}"
            if "refused" in r
            else f"**an estimate, {r['estimate_pa'] / 1e3:.1f} kPa**"
        )
        lines.append(f"- {r['shape']} {size} mm, E {r['young_pa'] / 1e3:.1f} kPa: {said}")
    return "\n".join(lines) + "\n"


ROW_HEADER = (
    "shape",
    "size (mm)",
    "placement (mm)",
    "Poisson",
    "true E (kPa)",
    "estimate (kPa)",
    "95 % interval",
    "error",
    "wall",
)


def _row(r: dict) -> str:
    size = " x ".join(f"{v * 1e3:.0f}" for v in r["size_m"])
    place = ", ".join(f"{v * 1e3:+.1f}" for v in r["placement_m"])
    head = f"| {r['shape']} | {size} | {place} | {r['poisson']:.2f} | {r['young_pa'] / 1e3:.1f} |"
    if "interval_only_pa" in r:
        return head + f" {_interval_only(r)} | {r['wall_s']:.0f} s |"
    if "error" not in r:
        return head + f" refused: {r['refused']} | | | {r['wall_s']:.0f} s |"
    lo, hi = (v / 1e3 for v in r["ci95_pa"])
    error = f"{100 * r['error']:+.1f} %"
    return head + f" {r['estimate_pa'] / 1e3:.1f} | {lo:.1f}-{hi:.1f} | {error} | {r['wall_s']:.0f} s |"


def _interval_only(r: dict) -> str:
    """The estimate, interval and error cells of a run given its interval alone."""
    lo, hi = (v / 1e3 for v in r["interval_only_pa"])
    return (
        f"interval only | {lo:.1f}-{hi:.1f} | withheld {r['withheld_pa'] / 1e3:.1f} "
        f"({100 * r['withheld_error']:+.1f} %)"
    )


def _short_row(name: str, r: dict) -> str:
    if "interval_only_pa" in r:
        covered = "yes" if r["covered"] else "no"
        return f"| {name} | {r['young_pa'] / 1e3:.1f} | {_interval_only(r)} | {covered} |"
    if "error" not in r:
        return f"| {name} | {r['young_pa'] / 1e3:.1f} | refused: {r['refused']} | | | |"
    lo, hi = (v / 1e3 for v in r["ci95_pa"])
    covered = "yes" if r["covered"] else "no"
    estimate = f"{r['estimate_pa'] / 1e3:.1f} | {lo:.1f}-{hi:.1f} | {100 * r['error']:+.1f} %"
    return f"| {name} | {r['young_pa'] / 1e3:.1f} | {estimate} | {covered} |"


def plot(results: dict, path: str) -> None:
    """Estimated against true modulus, with 95 % intervals, per shape (log-log)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.5, 5.5))
    ax = fig.subplots()
    for shape in SHAPES:
        part = [
            r for r in results["rows"] if r["shape"] == shape and r["variant"] == "hidden" and "error" in r
        ]
        if not part:
            continue
        true = np.array([r["young_pa"] for r in part]) / 1e3
        est = np.array([r["estimate_pa"] for r in part]) / 1e3
        ci = np.array([r["ci95_pa"] for r in part]).T / 1e3
        ax.errorbar(true, est, yerr=[est - ci[0], ci[1] - est], fmt="o", ms=4, capsize=2, label=shape)
    only = [r for r in results["rows"] if r["variant"] == "hidden" and "interval_only_pa" in r]
    if only:
        true = np.array([r["young_pa"] for r in only]) / 1e3
        ci = np.array([r["interval_only_pa"] for r in only]).T / 1e3
        ax.vlines(true, ci[0], ci[1], colors="0.55", lw=3, alpha=0.6, label="interval only (> 15 %)")
    ax.plot([5, 400], [5, 400], "k-", lw=0.8)
    ax.set(
        xscale="log",
        yscale="log",
        xlabel="true E (kPa)",
        ylabel="estimated E (kPa), 95 % interval",
        title="twin identify on hidden foams",
    )
    ax.legend()
    fig.savefig(path, dpi=90)


if __name__ == "__main__":
    import json

    results = run(quick="--quick" in sys.argv)
    print(to_markdown(results))
    print(json.dumps({k: v for k, v in results.items() if k != "rows"}, default=str)[:2000])
