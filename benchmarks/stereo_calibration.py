"""Accuracy of `twin calibrate cameras` on the twin: the recovered calibration against the ground truth.

Each seed draws new chessboard poses and new camera noise (`twin.experiments.calibrate_cameras.calibrate_sim`,
the procedure the CLI runs); errors are the recovered stereo-to-hand transform (hand_from_left), the
left-to-right transform and the intrinsics at 320x240 against what the twin knows. Target: the
stereo-to-hand transform within 1 mm and 0.5 deg.
"""

from __future__ import annotations

import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np
from twin.experiments.calibrate_cameras import DEFAULT_VIEWS, calibrate_sim

SEEDS = 10
KEYS = (
    ("hand_translation_mm", "hand translation (mm)"),
    ("hand_rotation_deg", "hand rotation (deg)"),
    ("stereo_translation_mm", "left->right translation (mm)"),
    ("stereo_rotation_deg", "left->right rotation (deg)"),
    ("focal_error_px", "focal length (px)"),
    ("centre_error_px", "principal point (px)"),
)


def run(quick: bool = False) -> dict:
    """Errors per seed, their max and mean, and the time per calibration."""
    seeds = 1 if quick else SEEDS
    views = 12 if quick else DEFAULT_VIEWS
    errors, seconds = [], []
    for seed in range(seeds):
        t0 = time.perf_counter()
        outcome = calibrate_sim(views=views, seed=seed)
        seconds.append(time.perf_counter() - t0)
        errors.append({k: abs(v) for k, v in outcome.errors().items()})
    return {
        "seeds": seeds,
        "views": views,
        "seconds": float(np.median(seconds)),
        "max": {k: float(max(e[k] for e in errors)) for k, _ in KEYS},
        "mean": {k: float(np.mean([e[k] for e in errors])) for k, _ in KEYS},
    }


def to_markdown(results: dict) -> str:
    """The BENCHMARKS.md section."""
    lines = [
        "## Camera calibration on the twin (target: stereo-to-hand within 1 mm and 0.5 deg)",
        "",
        f"`twin calibrate cameras` (sim) over {results['seeds']} seeds, {results['views']} chessboard views "
        f"each at 640x480 plus the 4x3 palm board, file at 320x240; {results['seconds']:.1f} s per "
        "calibration (`benchmarks/stereo_calibration.py`).",
        "",
        "| error vs the twin's truth | max | mean |",
        "|---|---|---|",
    ]
    for key, label in KEYS:
        lines.append(f"| {label} | {results['max'][key]:.3f} | {results['mean'][key]:.3f} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(to_markdown(run()))
