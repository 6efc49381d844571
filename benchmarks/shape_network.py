"""The shape network (paper §7) on a twin sweep: the contour measurement against the twin's true
silhouette (jitter and error, first version's pixel staircase and the sub-pixel likelihood boundary),
contour error on whole held-out trajectories against two baselines (both contour targets), the 3-D
variant's height error against the measured and the true surface, and inference time at batch size 1.
Sweep throughput is its own section (benchmarks/sweep_throughput.py): it measures the machine, and must
not share the cores with this half-hour of sweeps and training.
"""

from __future__ import annotations

import itertools
import os
import tempfile
import time
import timeit
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from twin.experiments.sweep import TrajectoryController, draw_trajectories, sweep

if TYPE_CHECKING:
    from twin.shape.dataset import ShapeData

OBJECTS = {"block": 24, "cylinder": 24, "sphere": 12}
"""Trajectories per object. The cylinder's contour moves most under the fingers (4.7 px per point),
the block's ~1 px, the sphere's barely (0.1 px): the sphere alone would make any predictor look good."""
DURATION_S = 20.0
POINTS = 32
SURFACE_OBJECT, SURFACE_TRAJECTORIES = "block", 12
"""The 3-D variant on the block: the fingers leave most of its top in view (the rounder foams, which
they wrap, leave slivers)."""
MEASUREMENT_S = 12.0
"""One trajectory per object for the measurement check: the grasp, then ~8 s under the fingers."""
REST_FRAMES = 30
WALK_NOTE_PX = 5.0
"""Trajectories whose contour's centre wandered further than this are named under the table."""


def _measurement(obj: str, duration_s: float) -> list[dict]:
    """Each boundary and target against the twin's true silhouette: at rest (the same scene, fresh
    camera noise each frame) and under the fingers (every 2nd frame of one trajectory's compression).

    jitter: the mean point distance between consecutive frames' errors (contour minus true contour),
    i.e. the frame-to-frame change the true silhouette's own motion does not explain; error: the mean
    point distance to the true contour. The true contour is the true visible mask's sub-pixel outline
    (twin.vision.contour.outlines), taken the same way for both targets."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    from twin.sim.backend import SimBackend
    from twin.sim.cameras import LEFT_CAMERA
    from twin.sim.foam import get_object
    from twin.vision.contour import BOUNDARIES, ContourExtractor, hull, outlines, resample
    from twin.vision.reconstruct import Rectifier

    (trajectory,) = draw_trajectories([obj], 1, seed=0, duration_s=duration_s, points=POINTS)
    backend = SimBackend(get_object(obj), seed=trajectory.seed, stereo=True, tactile=False)
    backend.connect()
    keys = [(b, t) for b in BOUNDARIES for t in ("largest", "hull")]
    errors = {(phase, *k): [] for phase in ("rest", "fingers") for k in keys}
    try:
        rectifier = Rectifier(backend.stereo.calibration())
        box = backend.object_box(rectifier)
        first = rectifier.remap(backend.stereo.read_view(LEFT_CAMERA))
        extract = {b: ContourExtractor(rectifier, first, box, points=POINTS, boundary=b) for b in BOUNDARIES}

        def frame(phase: str) -> None:
            left = rectifier.remap(backend.stereo.read_view(LEFT_CAMERA))
            true = outlines(backend.surface_truth(rectifier).visible)
            truth = {"largest": resample(true[0], POINTS), "hull": resample(hull(true), POINTS)}
            for b, ex in extract.items():
                c = ex(left)
                for t, pixels in (("largest", c.pixels), ("hull", c.hull_pixels)):
                    errors[phase, b, t].append(pixels - truth[t])

        for _ in range(REST_FRAMES):
            frame("rest")
        controller = TrajectoryController(trajectory)
        period = backend.hand.spec.period_s
        for k in range(int(duration_s / period) + 1):
            backend.world.advance_to(k * period)
            reading = backend.hand.read()
            backend.hand.command(controller(reading))
            if controller.phase == "compress" and k % 2 == 0:
                frame("fingers")
    finally:
        backend.disconnect()
    rows = []
    for (phase, b, t), e in errors.items():
        rows.append(
            {
                "object": obj,
                "phase": phase,
                "boundary": b,
                "target": t,
                "frames": len(e),
                "jitter_px": float(
                    np.mean([np.linalg.norm(x - y, axis=1).mean() for x, y in itertools.pairwise(e)])
                ),
                "error_px": float(np.mean([np.linalg.norm(x, axis=1).mean() for x in e])),
            }
        )
    return rows


def _motion_mm(heights_mm: np.ndarray) -> float:
    """Mean over the cells of each observed cell's height standard deviation."""
    with warnings.catch_warnings():  # cells never observed: NaN, left out
        warnings.simplefilter("ignore", RuntimeWarning)
        return float(np.nanmean(np.nanstd(heights_mm, axis=0)))


def _walk_px(data: ShapeData) -> dict[int, float]:
    """Per trajectory, how far the contour's centre wandered (px) from where it sat in the first second
    of the compression: an object walking in the grasp, which no function of the current readings
    can follow."""
    out = {}
    for k in np.unique(data.trajectory):
        centre = data.contour_px[data.trajectory == k].mean(axis=1)
        out[int(k)] = float(np.linalg.norm(centre - centre[:30].mean(axis=0), axis=1).max())
    return out


def _rows(evaluations: list) -> list[dict]:
    return [
        {"name": e.name, "px": e.error_px, "mm": e.error_mm, "smoothed_px": e.error_px_smoothed}
        for e in evaluations
    ]


def run(quick: bool = False) -> dict:
    """Measure the contours, sweep, train, evaluate, time."""
    from twin.shape.dataset import load_dataset, load_surface_dataset
    from twin.shape.surface_train import train_surface
    from twin.shape.train import FOLDS, NETWORK, cross_validate

    measurement = []
    measurement_s = 7.0 if quick else MEASUREMENT_S
    for obj in ("sphere",) if quick else OBJECTS:
        measurement += _measurement(obj, measurement_s)
    epochs = 300 if quick else 3000
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        objects = {"sphere": 4} if quick else OBJECTS
        duration = 8.0 if quick else DURATION_S
        per_object = []
        for obj, n in objects.items():
            trajectories = draw_trajectories([obj], n, seed=0, duration_s=duration, points=POINTS)
            t0 = time.perf_counter()
            sweep(trajectories, tmp / "dataset", workers=2)
            sweep_s = time.perf_counter() - t0
            for target in ("hull", "largest"):
                data = load_dataset(tmp / "dataset", obj, target)
                cv = cross_validate(data, folds=FOLDS, epochs=epochs, seed=0)
                model = cv.model
                walk = _walk_px(data)
                worst = max(cv.trajectory_errors_px, key=cv.trajectory_errors_px.get)
                per_object.append(
                    {
                        "object": obj,
                        "target": target,
                        "trajectories": n,
                        "samples": len(data),
                        "motion_px": float(data.contour_px.std(axis=0).mean()),
                        "folds": cv.folds,
                        "fold_errors_px": cv.fold_errors_px[NETWORK],
                        "worst_trajectory": worst,
                        "worst_px": cv.trajectory_errors_px[worst],
                        "worst_walk_px": walk[worst],
                        "walk_px": walk,
                        "trajectory_errors_px": cv.trajectory_errors_px,
                        "sweep_s": sweep_s,
                        "rows": _rows(cv.evaluations),
                    }
                )
        n_surface = 3 if quick else SURFACE_TRAJECTORIES
        trajectories = draw_trajectories(
            [SURFACE_OBJECT], n_surface, seed=0, duration_s=duration, points=POINTS, surface=True
        )
        t0 = time.perf_counter()
        sweep(trajectories, tmp / "surface", workers=2)
        surface_sweep_s = time.perf_counter() - t0
        surface_data = load_surface_dataset(tmp / "surface", SURFACE_OBJECT)
        s = train_surface(surface_data, epochs=epochs, seed=0)
        surface = {
            "object": SURFACE_OBJECT,
            "trajectories": n_surface,
            "samples": len(surface_data),
            "sweep_s": surface_sweep_s,
            "cells": surface_data.heights_mm.shape[1],
            "modelled_cells": s.modelled_cells,
            "observed_fraction": s.observed_fraction,
            "motion_mm": _motion_mm(surface_data.heights_mm),
            "measured_vs_truth_mm": s.measured_truth_error_mm,
            "validation_trajectories": s.validation_trajectories,
            "rows": [{"name": e.name, "mm": e.error_mm, "truth_mm": e.truth_error_mm} for e in s.evaluations],
        }
    x = data.inputs[:1]
    number = 2000 if quick else 20000
    numpy_us = min(timeit.repeat(lambda: model.predict(x[0]), number=number, repeat=3)) / number * 1e6
    torch_us = (
        min(timeit.repeat(lambda: model.predict_torch(x[0]), number=number // 10, repeat=3))
        / (number // 10)
        * 1e6
    )
    return {
        "measurement": measurement,
        "measurement_s": measurement_s,
        "objects": per_object,
        "surface": surface,
        "duration_s": duration,
        "numpy_us": numpy_us,
        "torch_us": torch_us,
    }


def to_markdown(results: dict) -> str:
    """The shape-network section of BENCHMARKS.md."""
    r = results
    lines = [
        "## Shape network (paper §7): contours from finger positions and torques",
        "",
        "**The contour measurement** against the twin's true silhouette (the true visible mask's "
        f"sub-pixel outline), one trajectory per object (seed 0, {r['measurement_s']:g} s): at rest "
        f"({REST_FRAMES} frames of the same scene, fresh camera noise each) and under the fingers (every "
        "2nd frame of the compression). 'Jitter': the mean point distance between consecutive frames' "
        "errors, the change the true silhouette's own motion does not explain. 'pixels': the first "
        "version's staircase of the thresholded mask; 'likelihood': the sub-pixel iso-line of the "
        "blurred back-projection (the default).",
        "",
        "| object | target | at rest: jitter, pixels → likelihood (px) | error (px) "
        "| under the fingers: jitter (px) | error (px) |",
        "|---|---|---|---|---|---|",
    ]
    m = {(x["object"], x["phase"], x["boundary"], x["target"]): x for x in r["measurement"]}
    for obj, target in sorted(
        {(x["object"], x["target"]) for x in r["measurement"]}, key=lambda k: (k[0], k[1] == "hull")
    ):
        cells = []
        for phase in ("rest", "fingers"):
            a, b = m[obj, phase, "pixels", target], m[obj, phase, "likelihood", target]
            cells.append(f"{a['jitter_px']:.2f} → **{b['jitter_px']:.2f}**")
            cells.append(f"{a['error_px']:.2f} → **{b['error_px']:.2f}**")
        lines.append(f"| {obj} | {target} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "**Held-out contour error.** Per object: "
        f"`twin sweep --trajectories N --duration {r['duration_s']:g}` "
        f"({POINTS} contour points, 2 workers), then `twin train --target hull|largest`: 4-fold "
        "cross-validation over whole trajectories, so every trajectory is scored once by a network (and "
        "baselines) trained on the other three quarters, never on it; the errors are pooled over all "
        "held-out samples. 'hull': the convex hull of all visible pieces (the default target); "
        "'largest': the largest visible piece's outline (the paper's contour). 'Motion' is how much the "
        "measured contour moves: the per-point standard deviation over the dataset. 'Walk': how far the "
        "contour's centre wandered from where it sat in the first second of the compression.",
        "",
        "| object | target | trajectories (samples) | motion (px) | network (px / mm) "
        "| linear (px / mm) | nearest neighbours (px / mm) | network per fold (px) "
        "| worst trajectory: network (px), walk (px) "
        "| network, linear, neighbours vs 5-frame-smoothed contours (px) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for o in r["objects"]:
        cells = " | ".join(f"{row['px']:.2f} / {row['mm']:.2f}" for row in o["rows"])
        folds = ", ".join(f"{e:.2f}" for e in o["fold_errors_px"])
        worst = f"#{o['worst_trajectory']}: {o['worst_px']:.2f}, {o['worst_walk_px']:.1f}"
        smoothed = ", ".join(f"{row['smoothed_px']:.2f}" for row in o["rows"])
        lines.append(
            f"| {o['object']} | {o['target']} | {o['trajectories']} ({o['samples']}) | "
            f"{o['motion_px']:.2f} | {cells} | {folds} | {worst} | {smoothed} |"
        )
    walks = [
        (o["object"], k, w, o["trajectory_errors_px"][k])
        for o in r["objects"]
        if o["target"] == "hull"
        for k, w in o["walk_px"].items()
        if w > WALK_NOTE_PX
    ]
    if walks:
        lines += [
            "",
            f"Trajectories whose contour walked more than {WALK_NOTE_PX:g} px (hull target; network error "
            "when held out): "
            + "; ".join(f"{obj} #{k}: walk {w:.1f} px, {e:.2f} px" for obj, k, w, e in walks)
            + ".",
        ]
    s = r["surface"]
    side = round(s["cells"] ** 0.5)
    lines += [
        "",
        f"**3-D variant** (`twin sweep --surface`, `twin train --target surface`), {s['object']}: "
        f"{s['trajectories']} trajectories ({s['samples']} samples), the fused cloud's heights on a "
        f"{side}×{side} hand-frame grid; {s['modelled_cells']} cells observed often enough to model, "
        f"{100 * s['observed_fraction']:.0f} % of the held-out (sample, cell) pairs observed; "
        f"heights move {s['motion_mm']:.2f} mm (per-cell "
        f"standard deviation). The measured heights' own error against the true surface: "
        f"{s['measured_vs_truth_mm']:.2f} mm. Held out: {s['validation_trajectories']}.",
        "",
        "| predictor | vs measured heights (mm) | vs the true surface (mm) |",
        "|---|---|---|",
    ]
    lines += [f"| {row['name']} | {row['mm']:.2f} | {row['truth_mm']:.2f} |" for row in s["rows"]]
    lines += [
        "",
        f"Inference at batch size 1 on the CPU: **{r['numpy_us']:.1f} µs** per prediction (numpy, the "
        f"normalization folded into the weights), {r['torch_us']:.0f} µs through torch.",
        "",
        "Sweep throughput: section *Sweep throughput* below, measured on its own.",
    ]
    return "\n".join(lines) + "\n"
