"""Training the shape network (paper §7) on a `twin sweep` dataset, with its baselines, and the report
kept beside the model (evaluation.json): what `twin train` runs. Imports torch (the `[shape]` extra)."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from twin.interface.errors import ConfigError

TARGETS = ("hull", "largest", "surface")


@dataclass
class TrainingOutcome:
    """Where the model went, the evaluation.json written beside it, and the training's own result."""

    model_dir: Path
    report: dict[str, Any]
    result: Any
    """twin.shape.train.TrainResult / CrossValidation, or twin.shape.surface_train's result."""
    folds: int | None
    """Cross-validation folds (None: one held-out split)."""


def _nan_to_null(value: object) -> object:
    """A report with NaN floats as None (strict JSON)."""
    if isinstance(value, dict):
        return {k: _nan_to_null(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_nan_to_null(v) for v in value]
    if isinstance(value, float) and math.isnan(value):
        return None
    return value


def _held_out_rows(evaluations: list) -> list[dict]:
    """Each predictor's held-out errors, as evaluation.json keeps them."""
    return [
        {
            "predictor": e.name,
            "error_px": e.error_px,
            "error_mm": e.error_mm,
            "error_px_vs_smoothed": e.error_px_smoothed,
        }
        for e in evaluations
    ]


def train_shape_network(
    dataset: str | Path,
    object_name: str,
    *,
    target: str = "hull",
    out: str | Path | None = None,
    epochs: int = 3000,
    folds: int | None = None,
    validation: float | None = None,
    seed: int = 0,
    progress: Callable[[int, int], None] | None = None,
) -> TrainingOutcome:
    """Train `object_name`'s network on a sweep dataset and score it against linear and
    nearest-neighbour baselines on whole held-out trajectories.

    Contours (`target` hull or largest): K-fold cross-validation over trajectories by default (K = 4,
    or one fold per trajectory where there are fewer), the model kept trained on all of them; or one
    held-out fraction `validation`. `target="surface"`: the 3-D variant on one held-out split (0.25).
    `progress(done, total)` counts the networks trained. The model goes to `out` (default
    DATASET/models/OBJECT, or OBJECT-TARGET for the other targets) with evaluation.json beside it."""
    from twin.shape.dataset import DEFAULT_TARGET

    if target not in TARGETS:
        raise ConfigError(f"--target {target!r}: choose from {', '.join(TARGETS)}")
    if folds is not None and validation is not None:
        raise ConfigError("--folds and --validation: choose one way to hold trajectories out")
    dataset = Path(dataset)
    metadata = {
        "object": object_name,
        "target": target,
        "dataset": str(dataset),
        "inputs": ["p1", "p2", "p3", "T1", "T2", "T3"],
    }
    name = object_name if target == DEFAULT_TARGET else f"{object_name}-{target}"
    out_dir = Path(out) if out is not None else dataset / "models" / name
    if target == "surface":
        if folds is not None:
            raise ConfigError("--folds: the 3-D variant is scored on one held-out split (--validation F)")
        return _train_surface(dataset, object_name, out_dir, metadata, epochs, validation, seed)
    from twin.shape.dataset import dataset_view, load_dataset
    from twin.shape.train import FOLDS, cross_validate, fold_groups, train

    data = load_dataset(dataset, object_name, target)
    view = dataset_view(dataset, object_name)
    if view is not None:  # the cameras' side: `--predict` refuses a run seen from another
        metadata["view_from_hand"] = view
    if validation is None:
        folds = min(FOLDS, len(set(data.trajectory.tolist()))) if folds is None else folds
        fold_groups(data, folds, seed)  # a bad fold count fails here, in one line, before any training
        result = cross_validate(
            data, folds=folds, seed=seed, epochs=epochs, metadata=metadata, progress=progress
        )
        model_dir = result.model.save(out_dir)
        report = {
            "model": str(model_dir),
            "samples": result.samples,
            "folds": result.folds,
            "wall_s": result.wall_s,
            "held_out": _held_out_rows(result.evaluations),
            "fold_errors_px": result.fold_errors_px,
            "trajectory_errors_px": {str(k): v for k, v in result.trajectory_errors_px.items()},
        }
    else:
        result = train(data, validation_fraction=validation, seed=seed, epochs=epochs, metadata=metadata)
        model_dir = result.model.save(out_dir)
        report = {
            "model": str(model_dir),
            "train_samples": result.train_samples,
            "validation_samples": result.validation_samples,
            "validation_trajectories": result.validation_trajectories,
            "wall_s": result.wall_s,
            "held_out": _held_out_rows(result.evaluations),
        }
    (model_dir / "evaluation.json").write_text(json.dumps(report, indent=1))
    return TrainingOutcome(model_dir, report, result, folds if validation is None else None)


def _train_surface(
    dataset: Path,
    object_name: str,
    out_dir: Path,
    metadata: dict,
    epochs: int,
    validation: float | None,
    seed: int,
) -> TrainingOutcome:
    """The 3-D variant and its baselines, heights in mm."""
    from twin.shape.dataset import load_surface_dataset
    from twin.shape.surface_train import train_surface

    data = load_surface_dataset(dataset, object_name)
    result = train_surface(
        data,
        validation_fraction=0.25 if validation is None else validation,
        seed=seed,
        epochs=epochs,
        metadata=metadata,
    )
    model_dir = result.model.save(out_dir)
    report = _nan_to_null(
        {
            "model": str(model_dir),
            "train_samples": result.train_samples,
            "validation_samples": result.validation_samples,
            "validation_trajectories": result.validation_trajectories,
            "modelled_cells": result.modelled_cells,
            "observed_fraction": result.observed_fraction,
            "measured_vs_truth_mm": result.measured_truth_error_mm,
            "wall_s": result.wall_s,
            "held_out": [
                {"predictor": e.name, "error_mm": e.error_mm, "error_mm_vs_truth": e.truth_error_mm}
                for e in result.evaluations
            ],
        }
    )
    (model_dir / "evaluation.json").write_text(json.dumps(report, indent=1))
    return TrainingOutcome(model_dir, report, result, None)
