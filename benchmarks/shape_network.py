"""The shape network (paper §7) on a twin sweep: contour error on whole held-out trajectories against
two baselines, inference time at batch size 1, and sweep throughput with 1 and 2 worker processes.
"""

from __future__ import annotations

import tempfile
import time
import timeit
from pathlib import Path

from experiments.sweep import draw_trajectories, sweep

OBJECTS = {"block": 24, "cylinder": 24, "sphere": 12}
"""Trajectories per object. The cylinder's contour moves most under the fingers (4.7 px per point),
the block's ~1 px, the sphere's barely (0.1 px): the sphere alone would make any predictor look good."""
OBJECT = "block"
"""The object of the throughput measurement."""
DURATION_S = 20.0
POINTS = 32
THROUGHPUT_TRAJECTORIES = 4
THROUGHPUT_DURATION_S = 20.0
"""Long enough that starting the worker processes (spawned: ~2 s of imports each) is amortized, as
in any real sweep."""


def _throughput(tmp: Path, workers: int, quick: bool) -> float:
    """Trajectory-seconds simulated per wall second with `workers` processes."""
    n = 2 if quick else THROUGHPUT_TRAJECTORIES
    duration = 7.0 if quick else THROUGHPUT_DURATION_S
    trajectories = draw_trajectories([OBJECT], n, seed=99, duration_s=duration, points=POINTS)
    t0 = time.perf_counter()
    sweep(trajectories, tmp / f"throughput-{workers}", workers=workers)
    return n * duration / (time.perf_counter() - t0)


def run(quick: bool = False) -> dict:
    """Sweep, train, evaluate, time."""
    from twin.shape.dataset import load_dataset
    from twin.shape.train import train

    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        rate_1 = _throughput(tmp, 1, quick)
        rate_2 = _throughput(tmp, 2, quick)
        objects = {"sphere": 4} if quick else OBJECTS
        duration = 8.0 if quick else DURATION_S
        per_object = []
        for obj, n in objects.items():
            trajectories = draw_trajectories([obj], n, seed=0, duration_s=duration, points=POINTS)
            t0 = time.perf_counter()
            sweep(trajectories, tmp / "dataset", workers=2)
            sweep_s = time.perf_counter() - t0
            data = load_dataset(tmp / "dataset", obj)
            result = train(data, epochs=300 if quick else 3000, seed=0)
            per_object.append(
                {
                    "object": obj,
                    "trajectories": n,
                    "samples": len(data),
                    "motion_px": float(data.contour_px.std(axis=0).mean()),
                    "validation_trajectories": result.validation_trajectories,
                    "sweep_s": sweep_s,
                    "rows": [
                        {
                            "name": e.name,
                            "px": e.error_px,
                            "mm": e.error_mm,
                            "smoothed_px": e.error_px_smoothed,
                        }
                        for e in result.evaluations
                    ],
                }
            )
    model = result.model
    x = data.inputs[:1]
    number = 2000 if quick else 20000
    numpy_us = min(timeit.repeat(lambda: model.predict(x[0]), number=number, repeat=3)) / number * 1e6
    torch_us = (
        min(timeit.repeat(lambda: model.predict_torch(x[0]), number=number // 10, repeat=3))
        / (number // 10)
        * 1e6
    )
    return {
        "objects": per_object,
        "duration_s": duration,
        "rate_1": rate_1,
        "rate_2": rate_2,
        "numpy_us": numpy_us,
        "torch_us": torch_us,
    }


def to_markdown(results: dict) -> str:
    """The shape-network section of BENCHMARKS.md."""
    r = results
    lines = [
        "## Shape network (paper §7): contours from finger positions and torques",
        "",
        f"Per object: `twin sweep --trajectories N --duration {r['duration_s']:g}` ({POINTS} contour points, "
        "2 workers), then `twin train`: 25 % of the trajectories held out whole, never seen in training. "
        "'Motion' is how much the measured contour moves: the per-point standard deviation over the dataset.",
        "",
        "| object | trajectories (samples) | motion (px) | held out | network (px / mm) | linear (px / mm) "
        "| nearest neighbours (px / mm) | network, linear, neighbours vs 5-frame-smoothed contours (px) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for o in r["objects"]:
        cells = " | ".join(f"{row['px']:.2f} / {row['mm']:.2f}" for row in o["rows"])
        cells += " | " + ", ".join(f"{row['smoothed_px']:.2f}" for row in o["rows"])
        lines.append(
            f"| {o['object']} | {o['trajectories']} ({o['samples']}) | {o['motion_px']:.2f} | "
            f"{o['validation_trajectories']} | {cells} |"
        )
    lines += [
        "",
        f"Inference at batch size 1 on the CPU: **{r['numpy_us']:.1f} µs** per prediction (numpy, the "
        f"normalization folded into the weights), {r['torch_us']:.0f} µs through torch.",
        "",
        f"Sweep throughput ({THROUGHPUT_TRAJECTORIES} trajectories of {THROUGHPUT_DURATION_S:g} s): "
        f"{r['rate_1']:.2f} trajectory-seconds per second with 1 worker, {r['rate_2']:.2f} with 2: "
        f"**{r['rate_2'] / r['rate_1']:.2f}x**.",
    ]
    return "\n".join(lines) + "\n"
