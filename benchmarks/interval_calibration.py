"""The identification interval's calibration: split conformal prediction on hidden benchmark runs.

Each row of interval_calibration.csv is a hidden run of benchmarks/identification.py that ended with a
95 % interval (a number or the interval alone): its estimate (the number, or the one withheld), its
interval and the twin's truth. Draws 2038, 2039 and 2040, read off BENCHMARKS.md as committed in
981c082, 94e6c6b and 89799df (values to the table's 3-4 significant figures); the first two with the
interval before calibration (interval_scale 1), 2040 with the scale 2038-2039 gave (0.585). A run's
score is its error in units of its own interval's sigma before calibration,
|log(E / E_true)| / sigma; the calibrated multiplier of sigma is the ceil(0.95 (n + 1))-th smallest
score, so that on a new run exchangeable with these the interval holds the truth with probability at
least 95 % (split conformal prediction with a locally weighted score: Lei, G'Sell, Rinaldo, Tibshirani &
Wasserman 2018, J. Am. Stat. Assoc. 113:1094, sec. 5.2). twin.sim.modulus.INTERVAL_SCALE is that
multiplier over Z95; tests/benchmarks/test_interval_calibration.py holds the two together.

`python benchmarks/interval_calibration.py` prints the quantile and what it does on these runs, and draws
the scores against a calibrated Gaussian's (interval_calibration.png).
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

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
    from twin.sim.modulus import Z95

    return math.log(row["ci95_high_pa"] / row["ci95_low_pa"]) / (2 * Z95 * row["interval_scale"])


def scores(rows: list[dict]) -> np.ndarray:
    """Each run's error in units of its sigma before calibration: |log(E / E_true)| / sigma."""
    return np.array([abs(math.log(r["estimate_pa"] / r["true_young_pa"])) / raw_sigma(r) for r in rows])


def conformal_quantile(score: np.ndarray, level: float = LEVEL) -> float:
    """The ceil(level (n + 1))-th smallest score: split conformal prediction's finite-sample quantile. With
    too few scores for the level (rank beyond n) no finite multiplier is guaranteed: infinite."""
    rank = math.ceil(level * (len(score) + 1))
    return float(np.sort(score)[rank - 1]) if rank <= len(score) else math.inf


def main() -> None:
    from twin.sim.modulus import INTERVAL_SCALE, PRECISION, Z95

    rows = load()
    score = scores(rows)
    q = conformal_quantile(score)
    print(
        f"{len(rows)} calibration runs; |z| median {np.median(score):.2f}, 95 % quantile (conformal) {q:.3f}"
    )
    print(f"implied INTERVAL_SCALE {q / Z95:.3f} (twin.sim.modulus: {INTERVAL_SCALE})")
    error = np.array([math.log(r["estimate_pa"] / r["true_young_pa"]) for r in rows])
    sigma = np.array([raw_sigma(r) for r in rows])
    for scale in (1.0, INTERVAL_SCALE):
        half = Z95 * scale * sigma
        given = half <= math.log1p(PRECISION)
        shown = np.abs(np.expm1(error[given]))
        print(
            f"scale {scale:.3f}: covered {np.mean(np.abs(error) <= half):.1%} of {len(rows)}; numbers given "
            f"{given.sum()} (median {np.median(shown):.1%}, max {shown.max():.1%}, covered "
            f"{np.mean(np.abs(error[given]) <= half[given]):.1%}) [in-sample]"
        )


def plot(score: np.ndarray, scale: float, path: Path, label: str) -> None:
    """The scores' empirical distribution against |N(0, 1)|'s (what a calibrated Gaussian interval's
    errors would follow), with the 95 % half-width before (1.96) and after calibration."""
    from matplotlib.figure import Figure
    from scipy.stats import halfnorm

    from twin.sim.modulus import Z95

    fig = Figure(figsize=(6.5, 4.5))
    ax = fig.subplots()
    x = np.sort(score)
    ax.step(x, np.arange(1, len(x) + 1) / len(x), where="post", label=f"{len(x)} hidden runs ({label})")
    grid = np.linspace(0, 2.5, 200)
    ax.plot(grid, halfnorm.cdf(grid), "k--", lw=1, label="calibrated Gaussian: |z| ~ |N(0, 1)|")
    ax.axvline(Z95, color="0.5", lw=1, label=f"95 % half-width before: {Z95:.2f} sigma")
    ax.axvline(scale * Z95, color="C3", lw=1.5, label=f"after (conformal): {scale * Z95:.2f} sigma")
    ax.axhline(LEVEL, color="0.8", lw=0.8)
    ax.set(
        xlabel="|log(E / E_true)| / sigma",
        ylabel="share of runs",
        xlim=(0, 2.5),
        ylim=(0, 1.02),
        title="twin identify's interval: errors in units of its sigma",
    )
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)


if __name__ == "__main__":
    main()
    from twin.sim.modulus import INTERVAL_SCALE

    rows = load()
    draws = sorted({r["draw"] for r in rows})
    plot(scores(rows), INTERVAL_SCALE, DATA.with_suffix(".png"), f"draws {draws[0]}-{draws[-1]}")
