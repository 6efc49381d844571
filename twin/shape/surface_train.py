"""The 3-D variant: the same 6-30 network, trained to predict the fused surface's heights on the
hand-frame grid (twin.shape.surface), with the contour network's two baselines beside it.

The network is fitted on three quarters of the training trajectories and stopped at the epoch that
does best on the remaining quarter (STOPPING_FRACTION); the baselines use all training trajectories.

A cell the cameras and pads did not see in a sample is NaN there: it is left out of the loss, of the
baselines' fits and of the measured error, never filled with a guess. Errors are mean absolute
height differences in mm:
- against the measured heights (the fused cloud), over the cells observed in each held-out sample;
- against the twin's true surface (sim sweeps only), over the modelled cells the true surface
  covers, seen or not: what the prediction is worth as a surface. Beside them, the measured heights' own error
  against the truth, on the cells both have: how good the training targets are.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import numpy as np
import torch
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from twin.interface.errors import ConfigError
from twin.shape.dataset import SurfaceData, split_by_trajectory
from twin.shape.model import ShapeMLP, ShapeModel
from twin.shape.train import EPOCHS, LEARNING_RATE, NEIGHBOURS

MIN_OBSERVED = 0.05
"""Cells observed in fewer than this share of the training samples are not modelled (NaN out)."""
STOPPING_FRACTION = 0.25
"""Share of the training trajectories (whole, at least one) set aside to choose the epoch to stop at.
Most cells are seen in a few trajectories only, and the network overfits them: on 8 block
trajectories, 300 / 1000 / 3000 epochs gave 0.38 / 0.52 / 0.74 mm against 0.37 mm for the linear
baseline. The held-out trajectories never take part in the choice."""


@dataclass
class SurfaceEvaluation:
    """Mean absolute height error (mm) of one predictor on the held-out trajectories."""

    name: str
    error_mm: float
    """Against the measured heights, over the observed cells."""
    truth_error_mm: float = float("nan")
    """Against the twin's true surface, over the cells it covers (NaN without truth)."""


@dataclass
class SurfaceTrainResult:
    """The trained model, the predictors' scores and the measurement's own error."""

    model: ShapeModel
    evaluations: list[SurfaceEvaluation]
    measured_truth_error_mm: float
    """The fused cloud's heights against the true surface on the held-out cells both have."""
    observed_fraction: float
    """Share of (held-out sample, cell) pairs with a measured height."""
    modelled_cells: int
    train_samples: int
    validation_samples: int
    validation_trajectories: list[int]
    wall_s: float


def _masked_mean_abs(a: NDArray, b: NDArray) -> float:
    d = np.abs(a - b)
    ok = np.isfinite(d)
    return float(d[ok].mean()) if ok.any() else float("nan")


def train_surface(
    data: SurfaceData,
    *,
    validation_fraction: float = 0.25,
    seed: int = 0,
    epochs: int = EPOCHS,
    metadata: dict | None = None,
) -> SurfaceTrainResult:
    """Split by trajectory, train the 6-30-G^2 network and the baselines, evaluate on the held-out set."""
    started = time.perf_counter()
    train_set, val_set = split_by_trajectory(data, validation_fraction, seed)
    y = train_set.heights_mm
    seen = np.isfinite(y)
    modelled = seen.mean(axis=0) >= MIN_OBSERVED
    if not modelled.any():
        raise ConfigError("no grid cell is observed often enough in the training trajectories")
    x_mean, x_std = train_set.inputs.mean(axis=0), train_set.inputs.std(axis=0)
    x_std = np.where(x_std > 1e-9, x_std, 1.0)
    with warnings.catch_warnings():  # cells never observed: their statistics are NaN, replaced below
        warnings.simplefilter("ignore", RuntimeWarning)
        y_mean, y_std = np.nanmean(y, axis=0), np.nanstd(y, axis=0)
    y_mean = np.where(modelled, np.nan_to_num(y_mean), 0.0)
    y_std = np.where(modelled & (np.nan_to_num(y_std) > 1e-6), np.nan_to_num(y_std), 1.0)
    if len(np.unique(train_set.trajectory)) >= 2:
        fit_set, stop_set = split_by_trajectory(train_set, STOPPING_FRACTION, seed + 1)
    else:  # one training trajectory: nothing to set aside, it runs all its epochs
        fit_set = stop_set = train_set

    def tensors(part: SurfaceData) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        h = part.heights_mm
        w = torch.as_tensor(np.isfinite(h) & modelled, dtype=torch.float32)
        x = torch.as_tensor((part.inputs - x_mean) / x_std, dtype=torch.float32)
        return x, torch.as_tensor(np.nan_to_num((h - y_mean) / y_std), dtype=torch.float32), w

    (xt, yt, wt), (xs, ys, ws) = tensors(fit_set), tensors(stop_set)
    torch.manual_seed(seed)
    net = ShapeMLP(y.shape[1], dims=1)
    opt = torch.optim.Adam(net.parameters(), lr=LEARNING_RATE)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, epochs)
    best, best_state, best_epoch = np.inf, None, 0
    for epoch in range(epochs):
        opt.zero_grad()
        loss = torch.sum(wt * (net(xt) - yt) ** 2) / wt.sum()
        loss.backward()
        opt.step()
        sched.step()
        if epoch % 10 == 0 or epoch == epochs - 1:
            with torch.no_grad():
                stop = float(torch.sum(ws * (net(xs) - ys) ** 2) / ws.sum().clamp(min=1.0))
            if stop < best:
                best, best_epoch = stop, epoch + 1
                best_state = {k: v.clone() for k, v in net.state_dict().items()}
    net.load_state_dict(best_state)
    model = ShapeModel(
        net=net,
        x_mean=x_mean,
        x_std=x_std,
        y_mean=y_mean,
        y_std=y_std,
        metadata=(metadata or {}) | {"target": "surface", "epochs": best_epoch, "seed": seed},
    )
    out = np.where(modelled, 0.0, np.nan)  # cells not modelled stay NaN in every prediction
    preds = {
        "network (6-30-G²)": model.predict(val_set.inputs) + out,
        "linear regression": _linear(train_set, val_set, modelled) + out,
        f"nearest neighbours (k={NEIGHBOURS})": _knn(train_set, val_set, x_mean, x_std) + out,
    }
    evaluations = [
        SurfaceEvaluation(
            name, _masked_mean_abs(p, val_set.heights_mm), _masked_mean_abs(p, val_set.truth_mm)
        )
        for name, p in preds.items()
    ]
    return SurfaceTrainResult(
        model=model,
        evaluations=evaluations,
        measured_truth_error_mm=_masked_mean_abs(val_set.heights_mm, val_set.truth_mm),
        observed_fraction=float(np.isfinite(val_set.heights_mm).mean()),
        modelled_cells=int(modelled.sum()),
        train_samples=len(train_set),
        validation_samples=len(val_set),
        validation_trajectories=sorted(int(t) for t in np.unique(val_set.trajectory)),
        wall_s=time.perf_counter() - started,
    )


def _linear(train_set: SurfaceData, val_set: SurfaceData, modelled: NDArray[np.bool_]) -> NDArray:
    """Per cell, height = a [p, T, 1] by least squares on the samples that observed it."""
    a = np.column_stack([train_set.inputs, np.ones(len(train_set))])
    av = np.column_stack([val_set.inputs, np.ones(len(val_set))])
    pred = np.full(val_set.heights_mm.shape, np.nan)
    for c in np.flatnonzero(modelled):
        seen = np.isfinite(train_set.heights_mm[:, c])
        coef, *_ = np.linalg.lstsq(a[seen], train_set.heights_mm[seen, c], rcond=None)
        pred[:, c] = av @ coef
    return pred


def _knn(train_set: SurfaceData, val_set: SurfaceData, x_mean: NDArray, x_std: NDArray) -> NDArray:
    """The mean of the k nearest training samples' heights, each cell over the neighbours that saw it
    (the cell's training mean when none did)."""
    tree = cKDTree((train_set.inputs - x_mean) / x_std)
    _, idx = tree.query((val_set.inputs - x_mean) / x_std, k=NEIGHBOURS)
    with warnings.catch_warnings():  # 'Mean of empty slice': a cell no neighbour saw, handled below
        warnings.simplefilter("ignore", RuntimeWarning)
        pred = np.nanmean(train_set.heights_mm[idx], axis=1)
        fallback = np.nanmean(train_set.heights_mm, axis=0)
    return np.where(np.isfinite(pred), pred, fallback)
