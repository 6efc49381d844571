"""Identification on a fresh draw of unseen foams (experiments/validate_material_map.py).

The identification section scores a fixed set of runs, which every change to the mapping's rules has
since been looked at against. This section draws its foams with its own seeds, which nothing was
tuned on: 20 per size at 65, 67.5 and 70 mm, half of them at the soft end (10-30 kPa); and 8 per size
halfway between the mapping's sizes (61.25-78.75 mm), half at the soft end. Change the draw seeds, and the
first noise seeds by the number of runs, to take a new draw once this one has been used to tune
anything.
"""

from __future__ import annotations

import numpy as np

from experiments.validate_material_map import summary, validate

DRAW_SEED = 2027
FIRST_NOISE_SEED = 400
"""Noise seeds 401-460: the mapping uses 0-5, the fresh-seed checks 6-9, the identification
benchmark 101-160 and the validation draw in docs/identification.md 301-360."""
SIZES_MM = [65.0, 67.5, 70.0]
BETWEEN_DRAW_SEED = 2028
BETWEEN_FIRST_NOISE_SEED = 460
"""Noise seeds 461-524."""
BETWEEN_SIZES_MM = [61.25, 63.75, 66.25, 68.75, 71.25, 73.75, 76.25, 78.75]
"""Halfway between the mapping's sizes (every 2.5 mm over 60-80 mm), where its size interpolation is
furthest from a stored curve."""


def run(quick: bool = False) -> dict:
    """Simulate and identify the draws (about 5 minutes on 2 cores)."""
    per_size, soft = (1, 1) if quick else (10, 10)
    rows = validate(
        SIZES_MM[-1:] if quick else SIZES_MM,
        per_size,
        soft,
        seed=DRAW_SEED,
        first_seed=FIRST_NOISE_SEED,
        progress=False,
    )
    between = validate(
        BETWEEN_SIZES_MM[:1] if quick else BETWEEN_SIZES_MM,
        1 if quick else 4,
        1 if quick else 4,
        seed=BETWEEN_DRAW_SEED,
        first_seed=BETWEEN_FIRST_NOISE_SEED,
        progress=False,
    )
    return {"rows": rows, "between": between, "quick": quick}


def to_markdown(results: dict) -> str:
    """The identification_unseen section of BENCHMARKS.md."""
    rows, between = results["rows"], results.get("between", [])
    lines = [
        "## Identification on a fresh draw of unseen foams (sphere, sensor noise on)",
        "",
        f"`python -m experiments.validate_material_map --seed {DRAW_SEED} --first-seed {FIRST_NOISE_SEED}`: "
        "per size 10 moduli over 10-300 kPa and 10 over 10-30 kPa, off the mapping's grid, with noise seeds "
        f"nothing was tuned on. **{summary(rows)}.**",
    ]
    if between:
        sizes = " ".join(f"{s:g}" for s in sorted({r["size_mm"] for r in between}))
        lines += [
            "",
            f"Between the mapping's sizes (`--sizes-mm {sizes} --per-size 4 --soft-per-size 4 "
            f"--seed {BETWEEN_DRAW_SEED} --first-seed {BETWEEN_FIRST_NOISE_SEED}`), where its curves are "
            f"interpolated in size: **{summary(between)}.**",
        ]
    lines += [
        "",
        "| size | runs | median error (abs) | max error (abs) | over 10 % | extrapolated | branch unsettled "
        "| truth in interval |",
        "|---|---|---|---|---|---|---|---|",
    ]
    every = rows + between
    for size in sorted({r["size_mm"] for r in every}):
        mine = [r for r in every if r["size_mm"] == size]
        errors = np.abs([r["error"] for r in mine if r["error"] is not None])
        tag = " (between sizes)" if any(r in between for r in mine) else ""
        lines.append(
            f"| {size:g} mm{tag} | {len(mine)} | {100 * np.median(errors):.1f} % | "
            f"{100 * errors.max():.1f} % | "
            f"{int(np.sum(errors > 0.1))} | {sum(r['extrapolated'] for r in mine)} | "
            f"{sum(r['branch_unsettled'] for r in mine)} | {sum(r['held'] for r in mine)} |"
        )
    worst = [r for r in every if r["error"] is None or abs(r["error"]) > 0.05 or not r["held"]]
    if worst:
        lines += [
            "",
            "Runs more than 5 % off, or with the truth outside the interval:",
            "",
            "| size | true E (kPa) | identified (kPa) | 95 % interval (kPa) | error | noise seed | flagged |",
            "|---|---|---|---|---|---|---|",
        ]
        for r in worst:
            m = r["estimate"]
            if m is None:
                lines.append(
                    f"| {r['size_mm']:g} mm | {r['young_pa'] / 1e3:.1f} | none | | | {r['seed']} | |"
                )
                continue
            flags = ", ".join(
                name
                for name, on in (
                    ("extrapolated", r["extrapolated"]),
                    ("branch unsettled", r["branch_unsettled"]),
                )
                if on
            )
            lines.append(
                f"| {r['size_mm']:g} mm | {r['young_pa'] / 1e3:.1f} | {m['young_pa'] / 1e3:.1f} | "
                f"{m['ci95_pa'][0] / 1e3:.1f}-{m['ci95_pa'][1] / 1e3:.1f} | {100 * r['error']:+.1f} % | "
                f"{r['seed']} | {flags} |"
            )
    return "\n".join(lines) + "\n"
