"""The identification interval's calibration: split conformal prediction on hidden benchmark runs.

Each row of interval_calibration.csv is a hidden run of benchmarks/identification.py that ended with a
95 % interval (a number or the interval alone): its estimate (the number, or the one withheld), its
interval and the twin's truth. Draws 2038 to 2042, read off BENCHMARKS.md as committed in 981c082,
94e6c6b, 89799df, with this file (2041) and in b82e7d1 (2042, MuJoCo 4.0 and the calibrated foam)
(values to the table's 3-4 significant figures); 2038-2039 with the interval before calibration
(interval_scale 1), 2040 with the scale 2038-2039 gave (0.585), 2041 with the scale 2038-2040 gave
(0.725), 2042 at 1. A run's score is its error in units of its own interval's sigma before calibration,
|log(E / E_true)| / sigma; the calibrated multiplier of sigma is the ceil(0.95 (n + 1))-th smallest
score, so that on a new run exchangeable with these the interval holds the truth with probability at
least 95 % (split conformal prediction with a locally weighted score: Lei, G'Sell, Rinaldo, Tibshirani &
Wasserman 2018, J. Am. Stat. Assoc. 113:1094, sec. 5.2). Scored on the draw after the ones it was set
on, that multiplier covered too little twice (twin.sim.modulus.INTERVAL_SCALE says how much), so the
method ships at scale 1; tests/benchmarks/test_interval_calibration.py checks that the scale shipped
covers the recorded runs.

`python benchmarks/run_all.py --only interval_calibration` scores each draw prequentially (BENCHMARKS.md)
and draws the scores against a calibrated Gaussian's (interval_calibration.png).
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from twin.sim.modulus import INTERVAL_SCALE, PRECISION, Z95

DATA = Path(__file__).with_name("interval_calibration.csv")
LEVEL = 0.95
"""The interval's nominal coverage."""


def load(path: Path = DATA) -> list[dict]:
    """The calibration runs, values as floats (draw and shape as read)."""
    with path.open(newline="") as f:
        rows = list(csv.DictReader(f))
    numeric = ("true_young_pa", "estimate_pa", "ci95_low_pa", "ci95_high_pa", "interval_scale")
    return [r | {k: float(r[k]) for k in numeric} for r in rows]


def raw_sigma(row: dict) -> float:
    """The run's 1-sigma in log E before calibration: its interval's half-width in log E over Z95, undone
    of the scale it was drawn with."""
    return math.log(row["ci95_high_pa"] / row["ci95_low_pa"]) / (2 * Z95 * row["interval_scale"])


def scores(rows: list[dict]) -> np.ndarray:
    """Each run's error in units of its sigma before calibration: |log(E / E_true)| / sigma."""
    return np.array([abs(math.log(r["estimate_pa"] / r["true_young_pa"])) / raw_sigma(r) for r in rows])


def conformal_quantile(score: np.ndarray, level: float = LEVEL) -> float:
    """The ceil(level (n + 1))-th smallest score: split conformal prediction's finite-sample quantile. With
    too few scores for the level (rank beyond n) no finite multiplier is guaranteed: infinite."""
    rank = math.ceil(level * (len(score) + 1))
    return float(np.sort(score)[rank - 1]) if rank <= len(score) else math.inf


def score_draw(rows: list[dict], scale: float) -> dict:
    """What an interval of `scale` sigma (before calibration) does on `rows`: coverage over all of them,
    and the numbers the precision rule would give (their count, median and max error, coverage)."""
    error = np.array([math.log(r["estimate_pa"] / r["true_young_pa"]) for r in rows])
    half = Z95 * scale * np.array([raw_sigma(r) for r in rows])
    given = half <= math.log1p(PRECISION)
    shown = np.abs(np.expm1(error[given]))
    return {
        "scale": scale,
        "runs": len(rows),
        "covered": int((np.abs(error) <= half).sum()),
        "numbers": int(given.sum()),
        "numbers_covered": int((np.abs(error[given]) <= half[given]).sum()),
        "median": float(np.median(shown)) if given.any() else math.nan,
        "max": float(shown.max()) if given.any() else math.nan,
    }


def run(quick: bool = False) -> dict:
    """Each recorded draw scored prequentially: at scale 1 (no calibration) and at the conformal scale of
    the draws before it (what calibrating on them would have promised the next one). `quick` is ignored:
    the data are recorded."""
    rows = load()
    draws = sorted({r["draw"] for r in rows})
    table = []
    for k, draw in enumerate(draws):
        these = [r for r in rows if r["draw"] == draw]
        before = [r for r in rows if r["draw"] in draws[:k]]
        entry = {
            "draw": draw,
            "run_scale": these[0]["interval_scale"],
            "uncalibrated": score_draw(these, 1.0),
        }
        if before:
            scale = conformal_quantile(scores(before)) / Z95
            entry["prequential"] = score_draw(these, scale) | {"calibrated_on": len(before)}
        table.append(entry)
    every = scores(rows)
    return {
        "draws": table,
        "pooled_scale": conformal_quantile(every) / Z95,
        "shipped_scale": INTERVAL_SCALE,
        "scores": every,
    }


def _cells(s: dict) -> str:
    errors = f"median {100 * s['median']:.1f} %, max {100 * s['max']:.1f} %"
    numbers = f"{s['numbers']} ({errors}; {s['numbers_covered']} covered)"
    return f"{s['scale']:.3f} | {s['covered']} of {s['runs']} | {numbers}"


def to_markdown(results: dict) -> str:
    """The BENCHMARKS.md section."""
    lines = [
        "## The identification interval's calibration (`benchmarks/interval_calibration.py`)",
        "",
        "Every hidden run of the identification benchmark that ended with a 95 % interval (draws as "
        "recorded in benchmarks/interval_calibration.csv, with the interval scale each was run with), its "
        "error scored in units of its sigma before calibration. Each draw is scored at scale 1 (the interval "
        "as the method draws it) and at the split-conformal scale of the draws before it: the 95 % quantile "
        "those promised the next draw (Lei et al. 2018, J. Am. Stat. Assoc. 113:1094). A number is given "
        "where the interval is within 15 %.",
        "",
        "| draw | run with scale | scale | interval holds the truth | numbers given |",
        "|---|---|---|---|---|",
    ]
    for d in results["draws"]:
        lines.append(f"| {d['draw']} | {d['run_scale']:g} | {_cells(d['uncalibrated'])} |")
        if "prequential" in d:
            p = d["prequential"]
            lines.append(
                f"| {d['draw']} (calibrated on the {p['calibrated_on']} runs before) | | {_cells(p)} |"
            )
    lines += [
        "",
        f"Conformal scale over all {len(results['scores'])} runs: {results['pooled_scale']:.3f} (in-sample); "
        f"twin.sim.modulus.INTERVAL_SCALE: {results['shipped_scale']:g}.",
        "",
    ]
    return "\n".join(lines)


def plot(results: dict, path: str) -> None:
    """The scores' empirical distribution against |N(0, 1)|'s (what a calibrated Gaussian interval's
    errors would follow), with the 95 % half-width at scale 1 and at the conformal scale of all runs."""
    from matplotlib.figure import Figure
    from scipy.stats import halfnorm

    score = results["scores"]
    fig = Figure(figsize=(6.5, 4.5))
    ax = fig.subplots()
    x = np.sort(score)
    draws = [d["draw"] for d in results["draws"]]
    label = f"{len(x)} hidden runs (draws {draws[0]}-{draws[-1]})"
    ax.step(x, np.arange(1, len(x) + 1) / len(x), where="post", label=label)
    grid = np.linspace(0, 4.5, 300)
    ax.plot(grid, halfnorm.cdf(grid), "k--", lw=1, label="calibrated Gaussian: |z| ~ |N(0, 1)|")
    ax.axvline(Z95, color="0.5", lw=1, label=f"95 % half-width at scale 1: {Z95:.2f} sigma")
    conformal = results["pooled_scale"] * Z95
    ax.axvline(conformal, color="C3", lw=1.5, label=f"conformal over all (in-sample): {conformal:.2f} sigma")
    ax.axhline(LEVEL, color="0.8", lw=0.8)
    ax.set(
        xlabel="|log(E / E_true)| / sigma",
        ylabel="share of runs",
        xlim=(0, 4.5),
        ylim=(0, 1.02),
        title="twin identify's interval: errors in units of its sigma",
    )
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
