"""`twin identify` against the clock: a 14 s compress run, process start to exit, best of 3, with 1
and 2 worker processes (the limit is 60 s on the 2-core machine)."""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

DURATION_S = 14.0
REPEATS = 3


def run(quick: bool = False) -> dict:
    """Best and all wall times per worker count."""
    twin = [sys.executable, "-m", "twin.cli"]
    out: dict = {}
    with tempfile.TemporaryDirectory() as scratch_name:
        scratch = Path(scratch_name)
        run_dir = scratch / "run"
        subprocess.run(
            [*twin, "run", "compress", "--young", "23000", "--duration", str(DURATION_S),
             "--out", str(run_dir), "--no-progress"],
            check=True, capture_output=True,
        )  # fmt: skip
        for workers in (1, 2):
            times = []
            for k in range(1 if quick else REPEATS):
                started = time.perf_counter()
                done = subprocess.run(
                    [*twin, "identify", str(run_dir), "--workers", str(workers), "--no-progress", "--out",
                     str(scratch / f"id-{workers}-{k}")],
                    capture_output=True, text=True,
                )  # fmt: skip
                times.append(time.perf_counter() - started)
                results = scratch / f"id-{workers}-{k}" / "identify.json"
                if not results.exists():  # exit 2 with identify.json: the interval alone, a whole estimate
                    raise RuntimeError(f"twin identify failed ({done.returncode}): {done.stderr.strip()}")
                material = json.loads(results.read_text())["material"]
            out[workers] = {"best_s": min(times), "all_s": times}
        out["number_given"] = bool(material["number_given"])
        out["ci95_pa"] = material["ci95_pa"]
    return out


def to_markdown(results: dict) -> str:
    """The BENCHMARKS.md section."""
    one, two = results[1]["best_s"], results[2]["best_s"]
    return (
        "## `twin identify` against the clock (target: <= 60 s for a 14 s run)\n\n"
        "A 14 s block compress run (E 23 kPa), `twin identify RUN --no-progress`, process start to "
        "exit, best of "
        f"{len(results[2]['all_s'])}: **{two:.1f} s with 2 workers**, {one:.1f} s with 1 (speed-up "
        f"{one / two:.2f}x). All: 2 workers {', '.join(f'{t:.1f}' for t in results[2]['all_s'])} s; 1 worker "
        f"{', '.join(f'{t:.1f}' for t in results[1]['all_s'])} s. "
        + ("A number" if results["number_given"] else "The interval alone")
        + f" ({results['ci95_pa'][0] / 1e3:.1f}-{results['ci95_pa'][1] / 1e3:.1f} kPa, 95 %): every "
        "simulation ran either way. The simulations come in dependent "
        "rounds (1, then 12 around the first estimate, then 12 around the first round's), so one estimate "
        "cannot use more than 12 workers; a Ray "
        "cluster (`twin sweep --address`) pays across many runs, not within one.\n"
    )
