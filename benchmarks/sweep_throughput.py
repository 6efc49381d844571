"""Sweep throughput (issue 7): trajectory-seconds simulated per wall second with 1 and 2 worker
processes, on the default contour sweep of the block.

Its own section because it measures the machine: it must run with nothing else on the cores (the
shape-network section trains networks and sweeps for half an hour, and anything beside it skews both).
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

from twin.experiments.sweep import draw_trajectories, sweep

OBJECT = "block"
TRAJECTORIES = 4
DURATION_S = 20.0
"""Long enough that starting the worker processes (spawned: ~2 s of imports each) is amortized, as in
any real sweep."""
POINTS = 32


def _rate(tmp: Path, workers: int, n: int, duration_s: float) -> float:
    """Trajectory-seconds simulated per wall second with `workers` processes."""
    trajectories = draw_trajectories([OBJECT], n, seed=99, duration_s=duration_s, points=POINTS)
    t0 = time.perf_counter()
    sweep(trajectories, tmp / f"workers-{workers}", workers=workers)
    return n * duration_s / (time.perf_counter() - t0)


def run(quick: bool = False) -> dict:
    """The same trajectories swept with 1, then 2 workers."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    n, duration = (2, 7.0) if quick else (TRAJECTORIES, DURATION_S)
    with tempfile.TemporaryDirectory() as tmp:
        rate_1 = _rate(Path(tmp), 1, n, duration)
        rate_2 = _rate(Path(tmp), 2, n, duration)
    return {"trajectories": n, "duration_s": duration, "rate_1": rate_1, "rate_2": rate_2}


def to_markdown(results: dict) -> str:
    """The sweep_throughput section of BENCHMARKS.md."""
    r = results
    return (
        "## Sweep throughput (`twin sweep`, local executor)\n\n"
        f"{r['trajectories']} trajectories of {r['duration_s']:g} s of the {OBJECT} with contours "
        f"({POINTS} points): {r['rate_1']:.2f} trajectory-seconds per second with 1 worker, "
        f"{r['rate_2']:.2f} with 2: **{r['rate_2'] / r['rate_1']:.2f}x** (target 1.7x on 2 cores).\n"
    )
