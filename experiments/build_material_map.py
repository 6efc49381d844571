"""Build the material mapping (twin/identify/material_map.json) from compress runs of the twin.

For each shape and size, runs `twin run compress` on a log grid of Young's moduli, identifies each
run exactly as `twin identify` would, and fits ln E against each mapping feature (the grip
stiffness, the thumb's secant and tangent; twin.identify.material). To add a shape, or a size range
for a new object:

    python -m experiments.build_material_map --shape block --sizes-mm 50 60 70 --workers 2

(a new shape is added to the stored mapping beside the others; its sizes replace that shape's).
Check the printed leave-one-out error before trusting it: the mapping is only as good as each
feature is monotone in E for that shape (see BENCHMARKS.md, identification).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from twin.identify.material import (
    FALLING,
    FEATURES,
    MAP_FILE,
    MappingError,
    MaterialMap,
    coordinate,
    fit_curve,
    knot_value,
)

MAPPED_RANGE_PA = (1e4, 3e5)
"""The moduli the mapping is for (issue 6's range)."""
YOUNG_RANGE_PA = (8e3, 3.6e5)
"""A little wider than MAPPED_RANGE_PA, so its ends are not extrapolated."""
GRID_POINTS = (16, 24)
"""The stored mapping's grids (--points for 60, 62.5, 72.5, 75, 77.5 and 80 mm, and for 65-70 mm)."""
DURATION_S = 14.0
"""Close and balance take ~3.5 s; the rest is 5 whole compression cycles at 0.5 Hz."""
SOFT_BELOW_PA = 3e4
"""Below this a soft object's grasp can settle in one of two clutch states (F1 and F2 broken away
through the cycles, or breaking away and re-coupling in each), which shifts every stiffness by up to
~20 %. Since the close holds where contact is confirmed, which state is mostly set by size and modulus;
where the touch is close to breaking a clutch (the 67.5 mm sphere near 18-20 kPa) it is still noise.
--soft-seeds averages more seeds there (docs/identification.md has what 6 did to the stored mapping)."""


def sweep_run(
    args: tuple[str, float, float, int, float, str],
) -> tuple[str, float, float, int, dict[str, float]]:
    """One compress run (sim) and its mapping features: (shape, size, E, seed, {feature: k})."""
    shape, size_m, young_pa, seed, duration_s, out_dir = args
    from experiments.compress import run_compress
    from twin.identify.identify import identify_run, material_features
    from twin.sim.backend import SimBackend
    from twin.sim.foam import LIBRARY

    base = next(p for p in LIBRARY.values() if p.shape == shape)
    foam = base.with_overrides(young_pa=young_pa, size_m=(size_m,) * 3)
    run_dir = Path(out_dir) / run_name(shape, size_m, young_pa, seed)
    if not run_complete(run_dir):  # resumable: a finished run is identified again, not re-run
        if run_dir.exists():
            import shutil

            shutil.rmtree(run_dir)
        run_compress(SimBackend(foam, seed=seed), run_dir, duration_s=duration_s, object_name=foam.name)
    result = identify_run(run_dir, material_map=MaterialMap(curves={}, provenance={}))
    features = {
        name: value
        for name, (value, _) in material_features(result.fingers, result.grip, result.closure).items()
    }
    return shape, size_m, young_pa, seed, features


def run_name(shape: str, size_m: float, young_pa: float, seed: int) -> str:
    """The directory name of one sweep run (kept runs are found again by it)."""
    return f"{shape}-{size_m * 1e3:.0f}mm-{young_pa:.0f}Pa-s{seed}"


def draw_moduli(
    n: int, rng: np.random.Generator, range_pa: tuple[float, float] = MAPPED_RANGE_PA
) -> list[float]:
    """n moduli log-uniform in range_pa, each >= 3 % away from the stored mapping's grids: unseen foams."""
    grid = np.concatenate([np.geomspace(*YOUNG_RANGE_PA, n) for n in GRID_POINTS])
    out: list[float] = []
    while len(out) < n:
        e = float(np.exp(rng.uniform(*np.log(range_pa))))
        if np.min(np.abs(np.log(grid / e))) > np.log(1.03):
            out.append(e)
    return out


def run_complete(run_dir: Path) -> bool:
    """Whether a run directory holds a run that finished (kept runs are reused, not re-simulated)."""
    import json

    try:
        return json.loads((run_dir / "run.json").read_text())["status"] == "complete"
    except (OSError, ValueError, KeyError):
        return False


def main(argv: list[str] | None = None) -> int:
    """Sweep, fit, write."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--shape", default="sphere", choices=("block", "cylinder", "sphere"))
    p.add_argument("--sizes-mm", type=float, nargs="+", default=[60.0, 65.0, 70.0, 75.0, 80.0])
    p.add_argument("--points", type=int, default=16, help="moduli per size (log-spaced)")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument(
        "--seeds", type=int, default=2, help="noise seeds per grid point (stiffness averaged in log)"
    )
    p.add_argument(
        "--soft-seeds",
        type=int,
        help=f"noise seeds per grid point below {SOFT_BELOW_PA / 1e3:g} kPa (default: --seeds)",
    )
    p.add_argument("--out", type=Path, default=MAP_FILE)
    p.add_argument(
        "--keep-runs", type=Path, help="keep the sweep's runs here, and reuse those already there (resumable)"
    )
    args = p.parse_args(argv)

    from rich.progress import Progress

    grid = np.geomspace(*YOUNG_RANGE_PA, args.points)
    soft_seeds = args.seeds if args.soft_seeds is None else args.soft_seeds
    if min(args.seeds, soft_seeds) < 1 or args.points < 2:
        p.error("--seeds and --soft-seeds must be >= 1, --points >= 2")
    with tempfile.TemporaryDirectory() as tmp:
        out_dir = args.keep_runs or Path(tmp)
        jobs = [
            (args.shape, s / 1e3, float(e), seed, DURATION_S, str(out_dir))
            for s in args.sizes_mm
            for e in grid
            for seed in range(soft_seeds if e < SOFT_BELOW_PA else args.seeds)
        ]
        results = []
        with ProcessPoolExecutor(args.workers) as pool, Progress() as bar:
            task = bar.add_task(f"{args.shape} sweep", total=len(jobs))
            for r in pool.map(sweep_run, jobs):
                results.append(r)
                bar.advance(task)
    curves = []
    for s in args.sizes_mm:
        for feature in FEATURES:
            rows = [(e, f[feature]) for _, size, e, _, f in results if abs(size * 1e3 - s) < 1e-6]
            young = np.unique([e for e, _ in rows])
            per_e = [[k for e, k in rows if e == y] for y in young]
            k = np.array([knot_value(feature, ks) for ks in per_e])
            noise = np.array(
                [
                    np.nan_to_num(np.std(coordinate(feature, ks), ddof=1)) if len(ks) > 1 else 0.0
                    for ks in per_e
                ]
            )
            try:
                curve = fit_curve(s / 1e3, k, young, noise, feature)
            except MappingError as exc:
                print(f"build_material_map: {args.shape} {exc}; left out", file=sys.stderr)
                continue
            curves.append(curve)
            lo, hi = curve.young_range_pa
            print(
                f"{args.shape} {s:g} mm, {feature}: valid {lo / 1e3:.0f}-{hi / 1e3:.0f} kPa "
                "(monotone there), "
                f"leave-one-out {100 * (np.exp(curve.loo_rms_log) - 1):.1f} % RMS, run-to-run "
                + (
                    f"{1e3 * np.median(curve.knots_noise_x):.0f} counts (median)"
                    if feature in FALLING
                    else f"{100 * np.median(curve.knots_noise_x):.1f} % (median)"
                )
            )
    if not curves:
        print(f"build_material_map: no size of {args.shape} could be mapped", file=sys.stderr)
        return 1
    try:
        stored = MaterialMap.load(args.out) if args.out.exists() else MaterialMap(curves={}, provenance={})
    except MappingError:
        stored = MaterialMap(curves={}, provenance={})
    provenance = {
        "built_by": "python -m experiments.build_material_map "
        + " ".join(argv if argv is not None else sys.argv[1:]),
        "young_range_pa": list(YOUNG_RANGE_PA),
        "points": args.points,
        "seeds": args.seeds,
        "soft_seeds": soft_seeds,
        "soft_below_pa": SOFT_BELOW_PA,
        "duration_s": DURATION_S,
        "procedure": "twin run compress defaults, sim backend, sensor noise on",
    }
    built = {round(s / 1e3, 9) for s in args.sizes_mm}
    kept = [
        c for c in stored.curves.get(args.shape, []) if round(c.size_m, 9) not in built
    ]  # other sizes stay
    merged = sorted(kept + curves, key=lambda c: (c.feature, c.size_m))
    sizes_provenance = stored.provenance.get(args.shape, {}) | {
        f"{s:g} mm": provenance for s in args.sizes_mm
    }
    mapping = MaterialMap(
        curves=stored.curves | {args.shape: merged},
        provenance=stored.provenance | {args.shape: sizes_provenance},
    )
    print(f"wrote {mapping.save(args.out)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
