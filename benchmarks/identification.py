"""Identification against the twin's truth: `twin identify` (eq. 4 + the material mapping) and
`twin fit` (rollout least squares) on sphere runs whose moduli the mapping has not seen.

Moduli are drawn log-uniformly in 1e4-3e5 Pa (seeded), at least 3 % from every grid modulus of the
mapping (its 24-point grid at 65-70 mm and its 16-point grid elsewhere), with sensor noise on and
noise seeds the mapping was not built with. Sizes 65, 67.5 and 70 mm are mapping sizes (the acceptance
table); 68.75 mm, between two of them, is reported apart. Also timed: the `twin identify` command on a
60 s run, and every fit (2 worker processes).

TWIN_BENCH_RUNS=DIR keeps the runs there and reuses the finished ones (to re-score a rebuilt mapping
without simulating again).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from experiments.build_material_map import DURATION_S, MAPPED_RANGE_PA, draw_moduli, run_complete

RANGE_PA = MAPPED_RANGE_PA
SIZES_MM = {70.0: 12, 65.0: 9, 67.5: 9}
BETWEEN_SIZES_MM = {68.75: 4}
SOFT_END_PA = (1.5e4, 2.2e4)
SOFT_END_MM = {67.5: 4, 70.0: 4}
"""Extra runs where the soft sphere's grasp used to change regime (clutches that break away or not, a
thumb pushing with its inner link): runs there reached +13.8 % before the close touched at 12000
counts/s and held where contact is confirmed. They count in the acceptance figures."""
SOFT_END_65_PA = (1.1e4, 2.2e4)
SOFT_END_65_MM = {65.0: 6}
"""The 65 mm sphere's soft end, where with the earlier close fresh noise seeds at the mapping's own
moduli read up to 49 % off (docs/identification.md). Drawn after the other tables, so their moduli
and seeds stay as they were."""
FIT_CASES = 8
TIMING_RUN_S = 60.0


def make_run(args: tuple[float, float, int, float, str]) -> dict:
    """One sphere compress run and its identification: a table row."""
    size_mm, young_pa, seed, duration_s, out_dir = args
    from experiments.compress import run_compress
    from twin.identify.identify import identify_run
    from twin.sim.backend import SimBackend
    from twin.sim.foam import get_object

    foam = get_object("sphere").with_overrides(young_pa=young_pa, size_m=(size_mm / 1e3,) * 3)
    run_dir = Path(out_dir) / f"sphere-{size_mm:g}mm-{young_pa:.0f}Pa-s{seed}-{duration_s:g}s"
    if not run_complete(run_dir):
        if run_dir.exists():
            import shutil

            shutil.rmtree(run_dir)
        run_compress(SimBackend(foam, seed=seed), run_dir, duration_s=duration_s, object_name=foam.name)
    ident = identify_run(run_dir)
    m = ident.material or {}
    return {
        "run": str(run_dir),
        "size_mm": size_mm,
        "young_pa": young_pa,
        "seed": seed,
        "identified_pa": m.get("young_pa", float("nan")),
        "ci95_pa": m.get("ci95_pa", [float("nan")] * 2),
        "extrapolated": m.get("extrapolated", True),
    }


def run(quick: bool = False) -> dict:
    """Runs, identifications, fits and timings."""
    rng = np.random.default_rng(2026)
    sizes = {70.0: 2} if quick else SIZES_MM
    between = {} if quick else BETWEEN_SIZES_MM
    soft = {} if quick else SOFT_END_MM
    soft_65 = {} if quick else SOFT_END_65_MM
    duration = 10.0 if quick else DURATION_S
    with tempfile.TemporaryDirectory() as scratch:
        tmp = os.environ.get("TWIN_BENCH_RUNS") or scratch
        Path(tmp).mkdir(parents=True, exist_ok=True)
        jobs, groups = [], []
        seed = 100
        tables = (
            ("mapped", sizes, RANGE_PA),
            ("between", between, RANGE_PA),
            ("soft", soft, SOFT_END_PA),
            ("soft", soft_65, SOFT_END_65_PA),
        )
        for group, table, range_pa in tables:
            for size, n in table.items():
                for e in draw_moduli(n, rng, range_pa):
                    seed += 1
                    jobs.append((size, e, seed, duration, tmp))
                    groups.append(group)
        with ProcessPoolExecutor(2) as pool:
            rows = list(pool.map(make_run, jobs))
        for row, group in zip(rows, groups, strict=True):
            row["group"] = group
            row["error"] = row["identified_pa"] / row["young_pa"] - 1.0
            row["in_ci"] = bool(row["ci95_pa"][0] <= row["young_pa"] <= row["ci95_pa"][1])
        from twin.sim.fit import fit_run

        fits = []
        acceptance = [r for r in rows if r["size_mm"] in sizes]
        for row in acceptance[: 1 if quick else FIT_CASES]:
            result = fit_run(row["run"], workers=2)
            fits.append(
                {
                    "held": result.held,
                    "start_from": result.start_from,
                    "size_mm": row["size_mm"],
                    "young_pa": row["young_pa"],
                    "fitted": result.fitted,
                    "error": result.to_json()["error"],
                    "identifiable": result.identifiable,
                    "evaluations": result.evaluations,
                    "wall_s": result.wall_s,
                    "window_s": result.window_s,
                }
            )
        timing = _time_identify(Path(scratch), 12.0 if quick else TIMING_RUN_S)
    return {"rows": rows, "fits": fits, "timing": timing, "sizes": list(sizes), "quick": quick}


def _time_identify(tmp: Path, duration_s: float) -> dict:
    """Wall time of the `twin identify` command (process start to exit, best of 3) and of `twin fit`
    on a run of duration_s."""
    run_dir = tmp / "timing-run"
    twin = [sys.executable, "-m", "twin.cli"]
    subprocess.run(
        [
            *twin,
            "run",
            "compress",
            "--object",
            "sphere",
            "--duration",
            str(duration_s),
            "--out",
            str(run_dir),
            "--no-progress",
        ],
        check=True,
        capture_output=True,
    )
    walls = []
    for _ in range(3):
        t0 = time.perf_counter()
        subprocess.run(
            [*twin, "identify", str(run_dir), "--out", str(tmp / "timing-out")],
            check=True,
            capture_output=True,
        )
        walls.append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    subprocess.run(
        [*twin, "fit", str(run_dir), "--no-progress", "--out", str(tmp / "fit-out")],
        check=True,
        capture_output=True,
    )
    fit_wall = time.perf_counter() - t0
    return {"run_s": duration_s, "wall_s": min(walls), "walls_s": walls, "fit_wall_s": fit_wall}


def _flag(identifiable: bool) -> str:
    return "" if identifiable else " (not identifiable: held at the description)"


def _pct(x: float) -> str:
    return f"{100 * x:+.1f} %"


def to_markdown(results: dict) -> str:
    """The identification section of BENCHMARKS.md."""
    rows = results["rows"]
    acc = [r for r in rows if r["group"] != "between"]
    between = [r for r in rows if r["group"] == "between"]
    errs = np.abs([r["error"] for r in acc])
    drawn = np.abs([r["error"] for r in acc if r["group"] == "mapped"])
    soft_errs = np.abs([r["error"] for r in acc if r["group"] == "soft"])
    lines = [
        "## Identification against the twin's truth (sphere, unseen moduli, sensor noise on)",
        "",
        "`twin identify` (Kelvin-Voigt per finger; the grasp closure from the encoders, the grip stiffness "
        "from the hand's gauges and encoders and the thumb's secant and tangent pad stiffness, combined "
        "through the stored mapping) on "
        f"{len(acc)} runs of {DURATION_S:g} s at moduli the mapping has not seen, "
        f"{sum(r['group'] == 'soft' for r in acc)} of them at the soft end "
        f"({SOFT_END_PA[0] / 1e3:.0f}-{SOFT_END_PA[1] / 1e3:.0f} kPa at 67.5 and 70 mm, "
        f"{SOFT_END_65_PA[0] / 1e3:.0f}-{SOFT_END_65_PA[1] / 1e3:.0f} kPa at 65 mm, where the grasp "
        "changes regime): "
        "**median |E error| "
        f"{100 * np.median(errs):.1f} %, max {100 * errs.max():.1f} %**; the true E is inside the 95 % "
        f"interval in {sum(r['in_ci'] for r in acc)} of {len(acc)}.",
        "",
        *(
            [
                f"The {len(drawn)} random draws alone: median {100 * np.median(drawn):.1f} %, "
                f"max {100 * drawn.max():.1f} %; the soft-end runs alone: median "
                f"{100 * np.median(soft_errs):.1f} %, max {100 * soft_errs.max():.1f} %.",
                "",
            ]
            if len(drawn) and len(soft_errs)
            else []
        ),
        *(
            [
                f"Not in those figures: {len(between)} runs between two mapping sizes "
                f"({between[0]['size_mm']:g} mm), where the mapping interpolates linearly in size "
                "at fixed E: "
                f"max |E error| {100 * np.max(np.abs([r['error'] for r in between])):.1f} %.",
                "",
            ]
            if between
            else []
        ),
        "| size | true E (kPa) | identified (kPa) | 95 % interval (kPa) | error | noise seed | flagged |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in sorted(rows, key=lambda r: (r["size_mm"], r["young_pa"])):
        ci = r["ci95_pa"]
        tag = {"mapped": "", "soft": " (soft end)", "between": " (between mapping sizes)"}[r["group"]]
        lines.append(
            f"| {r['size_mm']:g} mm{tag} | {r['young_pa'] / 1e3:.1f} | {r['identified_pa'] / 1e3:.1f} | "
            f"{ci[0] / 1e3:.1f}-{ci[1] / 1e3:.1f} | {_pct(r['error'])} | {r['seed']} | "
            f"{'extrapolated' if r['extrapolated'] else ''} |"
        )
    fits = results["fits"]
    if fits:
        fe = np.abs([f["error"]["young_pa"] for f in fits])
        lines += [
            "",
            f"`twin fit` (replays of the run's commands in 2 processes; the modulus from `twin identify`'s "
            "estimate, the Poisson ratio and damping from the run's description of the object, each kept "
            "only if a profile shows the run can tell it apart) "
            f"on {len(fits)} of "
            f"those runs: **median |E error| {100 * np.median(fe):.2f} %, max {100 * fe.max():.2f} %**; "
            f"wall time {min(f['wall_s'] for f in fits):.0f}-{max(f['wall_s'] for f in fits):.0f} s "
            f"(limit 180 s).",
            "",
            "| size | true E (kPa) | fitted E (kPa) | E error | Poisson (true 0.3) | damping (true 0.002 s) "
            "| replays | wall |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for f in fits:
            p, ident = f["fitted"], f["identifiable"]
            lines.append(
                f"| {f['size_mm']:g} mm | {f['young_pa'] / 1e3:.1f} | {p['young_pa'] / 1e3:.1f} | "
                f"{_pct(f['error']['young_pa'])} | {p['poisson']:.3f}{_flag(ident['poisson'])} | "
                f"{p['damping']:.4f}{_flag(ident['damping'])} | {f['evaluations']} | {f['wall_s']:.0f} s |"
            )
    t = results["timing"]
    lines += [
        "",
        f"`twin identify` on a {t['run_s']:g} s run, whole command (process start to exit, including the "
        f"figure and the Rerun file): **{t['wall_s']:.2f} s** (best of 3; limit 2 s). "
        f"`twin fit` on the same run, all three parameters, 2 processes: **{t['fit_wall_s']:.0f} s** "
        "(limit 180 s; it replays the grasp and 3 cycles, whatever the run's length).",
    ]
    return "\n".join(lines) + "\n"
