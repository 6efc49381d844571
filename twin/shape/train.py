"""Train the shape network offline, with two baselines beside it, on whole held-out trajectories:
one held-out fraction (`train`) or K-fold cross-validation over trajectories (`cross_validate`, what
`twin train` does by default: every trajectory is scored once by predictors that never saw it).

- network: the paper's 6-30-2n MLP (twin.shape.model), Adam on the mean squared error of the
  standardized contour, full batch (a sweep holds thousands of samples, not millions), cosine
  schedule, keeping the final weights (the held-out trajectories are only scored, never used to
  choose);
- linear regression: contour = A [p, T, 1] by least squares;
- nearest neighbours: the mean contour of the k closest training samples in standardized input space.

Errors are the mean distance between predicted and measured contour points, in pixels at the
cameras' 320x240 and in millimetres in the hand frame (through the same per-sample px -> mm map the
measured contours used, i.e. the measured contour's plane). Beside them, the pixel error against the
measured contours smoothed over 5 frames: the camera's frame-to-frame jitter (~0.8 px on the block)
is a floor for the first score that no predictor can go below.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from twin.interface.errors import ConfigError
from twin.shape.dataset import ShapeData, split_by_trajectory
from twin.shape.model import ShapeMLP, ShapeModel

EPOCHS = 3000
LEARNING_RATE = 1e-2
NEIGHBOURS = 5
SMOOTHING_FRAMES = 5
NETWORK = "network (6-30-2n)"
FOLDS = 4
"""`cross_validate`'s default: each trajectory held out once, by a network trained on three quarters."""


@dataclass
class Evaluation:
    """Mean contour error of one predictor on the held-out trajectories."""

    name: str
    error_px: float
    error_mm: float
    error_px_smoothed: float = float("nan")
    """Against the measured contours averaged over SMOOTHING_FRAMES consecutive frames of their
    trajectory: the same score with most of the camera's frame-to-frame jitter taken out."""


@dataclass
class TrainResult:
    """The trained model and how it and the baselines did."""

    model: ShapeModel
    evaluations: list[Evaluation]
    train_samples: int
    validation_samples: int
    validation_trajectories: list[int]
    wall_s: float


def contour_errors(pred_px: NDArray, data: ShapeData) -> tuple[float, float]:
    """Mean point distance (px) and the same in mm, through each sample's px -> mm scale."""
    err_px = np.linalg.norm(pred_px - data.contour_px, axis=2)
    # local scale of the measured contour: mm per px from its own extent (a plane, ~uniform scale)
    span_px = np.linalg.norm(data.contour_px - data.contour_px.mean(axis=1, keepdims=True), axis=2).mean(
        axis=1
    )
    span_mm = np.linalg.norm(data.contour_mm - data.contour_mm.mean(axis=1, keepdims=True), axis=2).mean(
        axis=1
    )
    mm_per_px = span_mm / np.maximum(span_px, 1e-9)
    return float(err_px.mean()), float((err_px * mm_per_px[:, None]).mean())


def smoothed_targets(data: ShapeData, frames: int = SMOOTHING_FRAMES) -> NDArray[np.float64]:
    """Each measured contour averaged with its neighbours in time (a centred window within its
    trajectory, shorter at the ends)."""
    out = np.empty_like(data.contour_px)
    half = frames // 2
    for k in np.unique(data.trajectory):
        idx = np.flatnonzero(data.trajectory == k)
        c = data.contour_px[idx]
        for j in range(len(idx)):
            out[idx[j]] = c[max(0, j - half) : j + half + 1].mean(axis=0)
    return out


def _evaluation(name: str, pred_px: NDArray, data: ShapeData) -> Evaluation:
    smoothed = float(np.linalg.norm(pred_px - smoothed_targets(data), axis=2).mean())
    return Evaluation(name, *contour_errors(pred_px, data), error_px_smoothed=smoothed)


def _standardize(a: NDArray) -> tuple[NDArray, NDArray]:
    mean, std = a.mean(axis=0), a.std(axis=0)
    return mean, np.where(std > 1e-9, std, 1.0)


def train(
    data: ShapeData,
    *,
    validation_fraction: float = 0.25,
    seed: int = 0,
    epochs: int = EPOCHS,
    progress: Callable[[int, float], None] | None = None,
    metadata: dict | None = None,
) -> TrainResult:
    """Split by trajectory, train the network and the baselines, evaluate all on the held-out set."""
    started = time.perf_counter()
    train_set, val_set = split_by_trajectory(data, validation_fraction, seed)
    model, preds = _fit_and_predict(train_set, val_set, seed, epochs, progress, metadata)
    return TrainResult(
        model=model,
        evaluations=[_evaluation(name, p, val_set) for name, p in preds.items()],
        train_samples=len(train_set),
        validation_samples=len(val_set),
        validation_trajectories=sorted(int(t) for t in np.unique(val_set.trajectory)),
        wall_s=time.perf_counter() - started,
    )


@dataclass
class CrossValidation:
    """K-fold cross-validation by trajectory: every trajectory held out once, scored by predictors
    trained without it; and the model trained on every trajectory."""

    model: ShapeModel
    """Trained on all the trajectories (the folds' scores are its estimate on unseen ones)."""
    evaluations: list[Evaluation]
    """Each predictor over every held-out sample of every fold, pooled."""
    folds: list[list[int]]
    """The trajectories each fold held out."""
    fold_errors_px: dict[str, list[float]]
    """Per predictor, its mean error (px) on each fold's held-out trajectories."""
    trajectory_errors_px: dict[int, float]
    """The network's mean error (px) on each trajectory, when it was held out."""
    samples: int
    wall_s: float


def cross_validate(
    data: ShapeData,
    *,
    folds: int = FOLDS,
    seed: int = 0,
    epochs: int = EPOCHS,
    progress: Callable[[int, int], None] | None = None,
    metadata: dict | None = None,
) -> CrossValidation:
    """Split the trajectories into `folds` groups (shuffled by seed); for each, train the network and
    the baselines on the others and predict it; score the pooled predictions; then train the model to
    keep on every trajectory. Why: one random held-out quarter of a two-dozen-trajectory sweep is a
    noisy score (on the twin's block, 0.66-1.06 px across three split seeds, set by whether a
    trajectory where the block walks in the grasp is in it); K folds score every trajectory."""
    started = time.perf_counter()
    groups = fold_groups(data, folds, seed)
    pooled: dict[str, NDArray] = {}  # each predictor's contours, every sample predicted held out
    fold_errors: dict[str, list[float]] = {}
    for k, group in enumerate(groups):
        held = np.isin(data.trajectory, group)
        train_set, val_set = data.subset(~held), data.subset(held)
        _, preds = _fit_and_predict(train_set, val_set, seed + k, epochs, None, None)
        if progress is not None:
            progress(k + 1, folds + 1)
        for name, p in preds.items():
            pooled.setdefault(name, np.empty_like(data.contour_px))[held] = p
            fold_errors.setdefault(name, []).append(contour_errors(p, val_set)[0])
    evaluations = [_evaluation(name, p, data) for name, p in pooled.items()]
    sample_errors = np.linalg.norm(pooled[NETWORK] - data.contour_px, axis=2).mean(axis=1)
    trajectory_errors = {
        int(t): float(sample_errors[data.trajectory == t].mean()) for t in np.unique(data.trajectory)
    }
    model, _ = _fit_and_predict(data, None, seed, epochs, None, metadata)
    if progress is not None:
        progress(folds + 1, folds + 1)
    model.metadata["cross_validation"] = {
        "folds": groups,
        "held_out_error_px": {e.name: e.error_px for e in evaluations},
    }
    return CrossValidation(
        model=model,
        evaluations=evaluations,
        folds=groups,
        fold_errors_px=fold_errors,
        trajectory_errors_px=trajectory_errors,
        samples=len(data),
        wall_s=time.perf_counter() - started,
    )


def fold_groups(data: ShapeData, folds: int, seed: int) -> list[list[int]]:
    """The trajectories shuffled by seed into `folds` groups of (nearly) equal size; ConfigError
    unless 2 <= folds <= trajectories."""
    ids = np.unique(data.trajectory)
    if not 2 <= folds <= len(ids):
        raise ConfigError(f"folds must be 2 to {len(ids)} (one per trajectory at most), got {folds}")
    shuffled = np.random.default_rng(seed).permutation(ids)
    return [sorted(int(t) for t in g) for g in np.array_split(shuffled, folds)]


def _fit_and_predict(
    train_set: ShapeData,
    val_set: ShapeData | None,
    seed: int,
    epochs: int,
    progress: Callable[[int, float], None] | None,
    metadata: dict | None,
) -> tuple[ShapeModel, dict[str, NDArray]]:
    """The network trained on `train_set`, and each predictor's contours for `val_set` (none without)."""
    points = train_set.contour_px.shape[1]
    x_mean, x_std = _standardize(train_set.inputs)
    y_flat = train_set.contour_px.reshape(len(train_set), -1)
    y_mean, y_std = _standardize(y_flat)
    xt = torch.as_tensor((train_set.inputs - x_mean) / x_std, dtype=torch.float32)
    yt = torch.as_tensor((y_flat - y_mean) / y_std, dtype=torch.float32)
    watch = val_set if val_set is not None else train_set
    xv = torch.as_tensor((watch.inputs - x_mean) / x_std, dtype=torch.float32)
    yv = torch.as_tensor((watch.contour_px.reshape(len(watch), -1) - y_mean) / y_std, dtype=torch.float32)
    torch.manual_seed(seed)
    net = ShapeMLP(points)
    opt = torch.optim.Adam(net.parameters(), lr=LEARNING_RATE)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, epochs)
    for epoch in range(epochs):
        opt.zero_grad()
        loss = torch.mean((net(xt) - yt) ** 2)
        loss.backward()
        opt.step()
        sched.step()
        if progress is not None and (epoch % 10 == 0 or epoch == epochs - 1):
            with torch.no_grad():
                val = float(torch.mean((net(xv) - yv) ** 2))
            progress(epoch + 1, val)
    # The final weights, not the best held-out epoch's: choosing on the held-out trajectories would
    # let them into the model, and its score there would flatter it against the baselines.
    with torch.no_grad():
        val = float(torch.mean((net(xv) - yv) ** 2))
    key = "validation_mse_std" if val_set is not None else "training_mse_std"
    model = ShapeModel(
        net=net,
        x_mean=x_mean,
        x_std=x_std,
        y_mean=y_mean,
        y_std=y_std,
        metadata=(metadata or {}) | {"epochs": epochs, "seed": seed, key: val},
    )
    if val_set is None:
        return model, {}
    return model, {
        NETWORK: model.predict(val_set.inputs),
        "linear regression": _linear(train_set, val_set),
        f"nearest neighbours (k={NEIGHBOURS})": _knn(train_set, val_set, x_mean, x_std),
    }


def _linear(train_set: ShapeData, val_set: ShapeData) -> NDArray:
    a = np.column_stack([train_set.inputs, np.ones(len(train_set))])
    coef, *_ = np.linalg.lstsq(a, train_set.contour_px.reshape(len(train_set), -1), rcond=None)
    pred = np.column_stack([val_set.inputs, np.ones(len(val_set))]) @ coef
    return pred.reshape(val_set.contour_px.shape)


def _knn(train_set: ShapeData, val_set: ShapeData, x_mean: NDArray, x_std: NDArray) -> NDArray:
    tree = cKDTree((train_set.inputs - x_mean) / x_std)
    _, idx = tree.query((val_set.inputs - x_mean) / x_std, k=NEIGHBOURS)
    return train_set.contour_px[idx].mean(axis=1)
