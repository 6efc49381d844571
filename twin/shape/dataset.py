"""A sweep dataset (experiments/sweep.py) as arrays: inputs (p1, p2, p3 counts; T1, T2, T3 N*m) and
contour targets, grouped by trajectory so that validation holds out whole trajectories."""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from twin.interface.errors import ConfigError

INPUTS = ("p1_counts", "p2_counts", "p3_counts", "T1_nm", "T2_nm", "T3_nm")


@dataclass(frozen=True)
class ShapeData:
    """Samples of one object: inputs (n, 6), contours (n, k, 2) in px and mm, trajectory id per sample."""

    inputs: NDArray[np.float64]
    contour_px: NDArray[np.float64]
    contour_mm: NDArray[np.float64]
    trajectory: NDArray[np.int64]

    def __len__(self) -> int:
        return len(self.inputs)

    def subset(self, mask: NDArray[np.bool_]) -> ShapeData:
        """The samples where mask is True."""
        return ShapeData(
            self.inputs[mask], self.contour_px[mask], self.contour_mm[mask], self.trajectory[mask]
        )


def load_dataset(directory: Path | str, object_name: str) -> ShapeData:
    """Every trajectory of `object_name` in a sweep directory; ConfigError names what is wrong."""
    directory = Path(directory)
    index_path = directory / "index.json"
    if not index_path.is_file():
        raise ConfigError(f"{directory}: not a sweep dataset (no index.json); make one with `twin sweep`")
    entries = [
        e for e in json.loads(index_path.read_text())["trajectories"] if e["object_name"] == object_name
    ]
    if not entries:
        raise ConfigError(f"{directory}: no trajectories of '{object_name}'")
    parts = []
    for e in entries:
        try:
            with np.load(directory / e["file"]) as d:
                if len(d["t_s"]) == 0:
                    continue
                x = np.column_stack([d["position_counts"], d["torque_nm"]])
                parts.append((x, d["contour_px"], d["contour_mm"], np.full(len(x), e["index"])))
        except (OSError, ValueError, KeyError, zipfile.BadZipFile) as exc:
            raise ConfigError(
                f"{directory / e['file']}: not a readable trajectory ({exc}); rerun the sweep"
            ) from None
    if not parts:
        raise ConfigError(f"{directory}: the trajectories of '{object_name}' hold no samples")
    x, px, mm, traj = (np.concatenate(p) for p in zip(*parts, strict=True))
    return ShapeData(x, px, mm, traj.astype(np.int64))


def split_by_trajectory(
    data: ShapeData, validation_fraction: float, seed: int
) -> tuple[ShapeData, ShapeData]:
    """Whole trajectories held out for validation (at least one), chosen by seed."""
    ids = np.unique(data.trajectory)
    if len(ids) < 2:
        raise ConfigError("a held-out validation needs >= 2 trajectories; sweep more")
    rng = np.random.default_rng(seed)
    n_val = max(1, round(validation_fraction * len(ids)))
    held = rng.choice(ids, size=n_val, replace=False)
    val = np.isin(data.trajectory, held)
    return data.subset(~val), data.subset(val)
