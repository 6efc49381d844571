"""The twin's own grasp scatter: how much the squeeze stiffness S of one description moves, and why.

For each library shape (block, cylinder, sphere, at their library sizes) at a soft and a firm modulus, and
two soft objects of the hidden runs' kind whose `twin identify` intervals were wider than +-15 %
(HIDDEN_STYLE: a tall block and a small cylinder of benchmarks/identification.py's draw_cases on seed
5101, a seed no scoring uses, at moduli near theirs), the
simulation `twin identify` runs for one description (twin.sim.modulus._simulate: the default compress
procedure, the fast twin, S over the first CYCLES cycles) is repeated
- at the same description with only the twin's sensor-noise seed changed (what the twin itself varies:
  the contact found a reading earlier or later, the balance's path; MuJoCo is deterministic for a seed),
- with the placement alone drawn within PLACEMENT_MM of the palm's centre (a Latin hypercube, noise seed
  as `twin identify`'s),
- with the size alone drawn within SIZE_MM (every extent),
and once at 1.25 E for the local power p = d ln S / d ln E. Each source's 1-sigma of ln S, and divided by
p its 1-sigma in ln E (the interval's unit), is scored against PRECISION_SIGMA: the 1-sigma at which a
95 % interval reaches +-15 %, the precision `twin identify` gives a number at; p is read only where the
step moves S by more than twice the noise seed's scatter. How far apart the grasps lie: the largest
distance between two draws' fingertip shares (the like-grasp kernel, twin.sim.modulus.SHARE_TOLERANCE,
counts 0.05 apart 61 %, 0.1 apart 14 %).

The placement's effect is also regressed on x and y (what width_sources fits) and with x^2 added: F1 and
F2 mirror each other across x = 0, so an object off centre along x moves S alike either way, which a
term linear in x cannot carry and width_sources then counts as `grasp`.
"""

from __future__ import annotations

import math
import sys
from dataclasses import replace

import numpy as np

SHAPES = ("block", "cylinder", "sphere")
MODULI_PA = (15e3, 150e3)
"""A soft and a firm foam of the library's range (twin.sim.foam: soft ~10-20 kPa, firm ~100-300 kPa)."""
HIDDEN_STYLE = (("block", (0.061, 0.064, 0.089), 24e3), ("cylinder", (0.055, 0.055, 0.076), 14e3))
"""(shape, size, modulus) of two soft objects whose `twin identify` intervals were wider than +-15 %."""
DRAWS = 8
NOISE_SEEDS = 100
"""The first noise seed of the seed set (twin identify's own is twin.sim.modulus.SIM_SEED)."""
PLACEMENT_MM = 3.0
SIZE_MM = 1.0
POWER_STEP = 1.25
DURATION_S = 14.0
"""The hidden runs' length: the simulation covers their first CYCLES cycles (only those are compared)."""
PRECISION_SIGMA = math.log1p(0.15) / 1.959964
"""1-sigma in ln E at which a 95 % interval is +-15 % (twin.sim.modulus.PRECISION)."""
LHS_SEED = 5
SOURCES = ("noise seed", "placement", "size")


def _draws(base, n: int) -> dict[str, list]:
    """The description repeated under each source alone: (foam, noise seed) pairs."""
    from scipy.stats import qmc

    from twin.sim.modulus import SIM_SEED

    unit = qmc.LatinHypercube(d=3, seed=LHS_SEED).random(n)
    mm = 1e-3
    return {
        "noise seed": [(base, NOISE_SEEDS + i) for i in range(n)],
        "placement": [
            (
                replace(base, placement_m=((2 * a - 1) * PLACEMENT_MM * mm, (2 * b - 1) * PLACEMENT_MM * mm)),
                SIM_SEED,
            )
            for a, b, _ in unit
        ],
        "size": [
            (replace(base, size_m=tuple(v + (2 * c - 1) * SIZE_MM * mm for v in base.size_m)), SIM_SEED)
            for _, _, c in unit
        ],
    }


def _simulate(foam, seed: int) -> tuple[float, np.ndarray]:
    """twin identify's simulation of `foam` at noise seed `seed`: S and the fingertip shares."""
    from twin.sim import modulus

    kept = modulus.SIM_SEED
    modulus.SIM_SEED = seed  # _simulate reads it: the one thing varied
    try:
        s, _, shares, _ = modulus._simulate(foam)
    finally:
        modulus.SIM_SEED = kept
    return s, shares


def shares_apart(shares: np.ndarray) -> float:
    """The largest distance between two of these grasps' fingertip shares (those the twin held)."""
    finite = shares[np.isfinite(shares).all(axis=1)]
    if len(finite) < 2:
        return math.nan
    return float(np.linalg.norm(finite[:, None, :] - finite[None, :, :], axis=2).max())


def placement_r2(x_mm: np.ndarray, y_mm: np.ndarray, log_s: np.ndarray) -> tuple[float, float]:
    """R^2 of ln S on x and y, and on x, y and x^2."""

    def r2(columns: list[np.ndarray]) -> float:
        design = np.column_stack([*columns, np.ones_like(x_mm)])
        centred = log_s - log_s.mean()
        residual = log_s - design @ np.linalg.lstsq(design, log_s, rcond=None)[0]
        return float(1.0 - residual @ residual / (centred @ centred))

    return r2([x_mm, y_mm]), r2([x_mm, y_mm, x_mm**2])


def measure(shape: str, young_pa: float, n: int, size_m: tuple[float, float, float] | None = None) -> dict:
    """One description's scatter by source (the library object's size unless `size_m`)."""
    from twin.experiments.compress import CompressProfile

    from twin.sim import modulus
    from twin.sim.foam import get_object

    modulus._init_worker(CompressProfile(), DURATION_S, modulus.CYCLES)
    base = replace(modulus.describe(get_object(shape)), young_pa=young_pa)
    if size_m is not None:
        base = replace(base, size_m=size_m)
    s0, _ = _simulate(base, modulus.SIM_SEED)
    s1, _ = _simulate(replace(base, young_pa=POWER_STEP * young_pa), modulus.SIM_SEED)
    power = math.log(s1 / s0) / math.log(POWER_STEP)
    row: dict = {"shape": shape, "size_m": base.size_m, "young_pa": young_pa, "s_n_m": s0, "power": power}
    row["s_step_n_m"] = s1
    for source, draws in _draws(base, n).items():
        got = [_simulate(foam, seed) for foam, seed in draws]
        s = np.array([g[0] for g in got])
        held = np.isfinite(s)
        sigma = float(np.std(np.log(s[held]), ddof=1)) if held.sum() > 1 else math.nan
        row[source] = {
            "sigma_log_s": sigma,
            "held": int(held.sum()),
            "of": len(s),
            "shares_apart": shares_apart(np.array([g[1] for g in got])),
            "s_n_m": [float(v) for v in s],
            "shares": [[float(v) for v in g[1]] for g in got],
        }
        if source == "placement" and held.sum() > 4:
            x = np.array([f.placement_m[0] for f, _ in draws])[held] * 1e3
            y = np.array([f.placement_m[1] for f, _ in draws])[held] * 1e3
            row[source]["r2_linear"], row[source]["r2_with_x2"] = placement_r2(x, y, np.log(s[held]))
        print(f"  {shape} {young_pa / 1e3:g} kPa {source}: {sigma:.4f}", file=sys.stderr, flush=True)
    # p is read where the 25 % step moves S by more than twice the noise seed's scatter
    row["power_told"] = bool(abs(math.log(s1 / s0)) > 2 * row["noise seed"]["sigma_log_s"] and power > 0)
    for source in SOURCES:
        sigma = row[source]["sigma_log_s"]
        row[source]["sigma_log_e"] = sigma / power if row["power_told"] else math.nan
    return row


def run(quick: bool = False) -> dict:
    """Every shape and modulus (quick: the soft block, 2 draws)."""
    n = 2 if quick else DRAWS
    cases = [("block", MODULI_PA[0], None)] if quick else [(s, e, None) for s in SHAPES for e in MODULI_PA]
    cases += [] if quick else [(s, e, size) for s, size, e in HIDDEN_STYLE]
    return {"rows": [measure(s, e, n, size) for s, e, size in cases], "draws": n}


def to_markdown(results: dict) -> str:
    """The BENCHMARKS.md section."""
    n = results["draws"]
    sources = SOURCES
    lines = [
        "## The twin's own grasp scatter (`benchmarks/grasp_scatter.py`)",
        "",
        "The simulation `twin identify` runs for one description (twin.sim.modulus._simulate: the default "
        f"compress procedure on the fast twin, S over the first 3 cycles), {n} times per source with only "
        "that source varied: the twin's sensor-noise seed (the description fixed), the placement drawn "
        f"within {PLACEMENT_MM:g} mm (either axis), the size within {SIZE_MM:g} mm (every extent); and at "
        f"{POWER_STEP:g} E for the local power p. 1-sigma of ln S, and of ln E (divided by p), against "
        f"{PRECISION_SIGMA:.3f}: the 1-sigma at which a 95 % interval reaches +-15 % (a number from "
        "`twin identify`); p and ln E only where the 25 % step moves S by more than twice the noise seed's "
        "scatter. Apart: the largest distance between two draws' fingertip shares (the like-grasp kernel "
        "counts 0.05 apart 61 %, 0.1 apart 14 %). Placement R^2: ln S on x and y (what width_sources "
        "fits), and with x^2 (F1 and F2 mirror each other across x = 0).",
        "",
        "| shape | size (mm) | E (kPa) | S (N/m) | p | noise seed: ln S, ln E, apart "
        "| placement: ln S, ln E, apart | size: ln S, ln E | largest | placement R^2 x,y / +x^2 |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results["rows"]:
        cells = []
        for source in sources:
            c = r[source]
            held = "" if c["held"] == c["of"] else f" ({c['held']} of {c['of']} held)"
            in_e = f"{100 * c['sigma_log_e']:.1f} %" if math.isfinite(c["sigma_log_e"]) else "-"
            text = f"{100 * c['sigma_log_s']:.1f} %, {in_e}"
            cells.append(text + (f", {c['shares_apart']:.2f}" if source != "size" else "") + held)
        largest = max(
            sources, key=lambda k: r[k]["sigma_log_s"] if math.isfinite(r[k]["sigma_log_s"]) else -1
        )
        r2 = r["placement"].get("r2_linear"), r["placement"].get("r2_with_x2")
        r2_text = f"{r2[0]:.2f} / {r2[1]:.2f}" if None not in r2 else "-"
        size = " x ".join(f"{1e3 * v:.0f}" for v in r["size_m"])
        power = f"{r['power']:.2f}" if r["power_told"] else "-"
        lines.append(
            f"| {r['shape']} | {size} | {r['young_pa'] / 1e3:g} | {r['s_n_m']:.0f} | {power} | "
            + " | ".join(cells)
            + f" | {largest} | {r2_text} |"
        )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(to_markdown(run(quick="--quick" in sys.argv)))
