"""The shape network (paper §7) on a twin sweep: contour error on whole held-out trajectories against
two baselines, inference time at batch size 1, and sweep throughput with 1 and 2 worker processes.
"""

from __future__ import annotations

import tempfile
import time
import timeit
from pathlib import Path

from experiments.sweep import draw_trajectories, sweep

OBJECT = "cylinder"
"""The library foam whose contour moves most under the fingers (the sphere's barely does: 0.1 px)."""
TRAJECTORIES = 24
DURATION_S = 20.0
POINTS = 32
THROUGHPUT_TRAJECTORIES = 4
THROUGHPUT_DURATION_S = 10.0


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
        n, duration = (4, 8.0) if quick else (TRAJECTORIES, DURATION_S)
        trajectories = draw_trajectories([OBJECT], n, seed=0, duration_s=duration, points=POINTS)
        t0 = time.perf_counter()
        sweep(trajectories, tmp / "dataset", workers=2)
        sweep_s = time.perf_counter() - t0
        data = load_dataset(tmp / "dataset", OBJECT)
        result = train(data, epochs=300 if quick else 3000, seed=0)
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
        "rows": [{"name": e.name, "px": e.error_px, "mm": e.error_mm} for e in result.evaluations],
        "samples": len(data),
        "trajectories": n,
        "duration_s": duration,
        "validation_trajectories": result.validation_trajectories,
        "sweep_s": sweep_s,
        "train_s": result.wall_s,
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
        f"`twin sweep --objects {OBJECT} --trajectories {r['trajectories']} --duration {r['duration_s']:g}` "
        f"({r['samples']} samples, {POINTS} contour points, {r['sweep_s']:.0f} s with 2 workers), then "
        f"`twin train`: whole trajectories {r['validation_trajectories']} held out, never seen in training.",
        "",
        "| predictor | mean contour error (px, 320x240) | (mm, hand frame) |",
        "|---|---|---|",
    ]
    lines += [f"| {row['name']} | {row['px']:.2f} | {row['mm']:.2f} |" for row in r["rows"]]
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
