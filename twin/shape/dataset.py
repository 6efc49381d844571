"""A sweep dataset (experiments/sweep.py) as arrays: inputs (p1, p2, p3 counts; T1, T2, T3 N*m) and
one target, grouped by trajectory so that validation holds out whole trajectories.

Targets (`TARGETS`): "largest", the outline of the largest visible piece of the object (the paper's
contour); "hull", the convex hull of all visible pieces (twin.vision.contour says why); "surface", the
fused 3-D surface as heights on the trajectory's hand-frame grid (twin.shape.surface)."""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

from twin.interface.errors import ConfigError
from twin.shape.surface import TOP_VIEW, SurfaceGrid
from twin.vision.contour import VIEW_TOLERANCE_DEG, view_angle_deg

INPUTS = ("p1_counts", "p2_counts", "p3_counts", "T1_nm", "T2_nm", "T3_nm")
CONTOUR_TARGETS = {"largest": ("contour_px", "contour_mm"), "hull": ("hull_px", "hull_mm")}
TARGETS = (*CONTOUR_TARGETS, "surface")
DEFAULT_TARGET = "hull"
"""The fingers cut the object into pieces in the top-down view and the largest piece can switch from
frame to frame (docs/shape_network.md); the hull of all pieces is one closed curve around everything
visible, and moves continuously."""


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


@dataclass(frozen=True)
class SurfaceData:
    """Samples of one object: inputs (n, 6), measured and true heights (n, cells^2) in mm (NaN where
    unobserved), trajectory id per sample; and each trajectory's grid (cell centres, mm)."""

    inputs: NDArray[np.float64]
    heights_mm: NDArray[np.float64]
    truth_mm: NDArray[np.float64]
    trajectory: NDArray[np.int64]
    grids: dict[int, SurfaceGrid]

    def __len__(self) -> int:
        return len(self.inputs)

    def subset(self, mask: NDArray[np.bool_]) -> SurfaceData:
        """The samples where mask is True."""
        return SurfaceData(
            self.inputs[mask], self.heights_mm[mask], self.truth_mm[mask], self.trajectory[mask], self.grids
        )


def load_dataset(directory: Path | str, object_name: str, target: str = DEFAULT_TARGET) -> ShapeData:
    """Every trajectory of `object_name` in a sweep directory, with the contour `target` ("largest" or
    "hull"); ConfigError names what is wrong."""
    if target not in CONTOUR_TARGETS:
        raise ConfigError(f"unknown contour target '{target}' (choose from {', '.join(CONTOUR_TARGETS)})")
    px_key, mm_key = CONTOUR_TARGETS[target]
    parts = [
        (x, d[px_key], d[mm_key], k)
        for x, d, k in _trajectories(Path(directory), object_name, (px_key, mm_key))
    ]
    x, px, mm, traj = (np.concatenate(p) for p in zip(*parts, strict=True))
    return ShapeData(x, px, mm, traj.astype(np.int64))


def load_surface_dataset(directory: Path | str, object_name: str) -> SurfaceData:
    """Every trajectory of `object_name` swept with `--surface` (heights on its grid); true heights are
    NaN for recorded runs. ConfigError names what is wrong."""
    parts, grids = [], {}
    for x, d, k in _trajectories(Path(directory), object_name, ("surface_mm",)):
        truth = d["surface_truth_mm"] if "surface_truth_mm" in d else np.full_like(d["surface_mm"], np.nan)
        parts.append((x, d["surface_mm"], truth, k))
        spec = d["surface_grid"]
        view = spec.get("view_from_hand")  # absent in datasets swept from the top before it was recorded
        grids[int(k[0])] = SurfaceGrid(
            **{
                **spec,
                "centre_mm": tuple(spec["centre_mm"]),
                "view_from_hand": TOP_VIEW if view is None else tuple(tuple(row) for row in view),
            }
        )
    cells = {p[1].shape[1] for p in parts}
    if len(cells) > 1:
        raise ConfigError(f"{directory}: trajectories of '{object_name}' use different surface grids {cells}")
    x, h, t, traj = (np.concatenate(p) for p in zip(*parts, strict=True))
    return SurfaceData(x, h, t, traj.astype(np.int64), grids)


def dataset_view(directory: Path | str, object_name: str) -> list[list[float]] | None:
    """The view frame the object's trajectories were seen in (twin.vision.contour.view_from_hand; None
    for datasets that did not record it); ConfigError when they were seen from different sides."""
    views = []
    for _, arrays, _ in _trajectories(Path(directory), object_name, ()):
        if "view_from_hand" in arrays:
            views.append(np.asarray(json.loads(str(arrays["view_from_hand"])), dtype=np.float64))
    if not views:
        return None
    spread = max(view_angle_deg(v, views[0]) for v in views)
    if spread > VIEW_TOLERANCE_DEG:
        raise ConfigError(
            f"{directory}: the trajectories of '{object_name}' were seen from cameras {spread:.0f} deg "
            "apart; a contour model learns one view: sweep them with the cameras in one place"
        )
    return views[0].tolist()


def _trajectories(
    directory: Path, object_name: str, needed: tuple[str, ...]
) -> list[tuple[NDArray[np.float64], dict, NDArray[np.int64]]]:
    """(inputs, arrays, trajectory ids) of every non-empty trajectory of the object holding `needed`."""
    index_path = directory / "index.json"
    if not index_path.is_file():
        raise ConfigError(f"{directory}: not a sweep dataset (no index.json); make one with `twin sweep`")
    entries = [e for e in _index_entries(index_path) if e["object_name"] == object_name]
    if not entries:
        raise ConfigError(f"{directory}: no trajectories of '{object_name}'")
    parts = []
    for e in entries:
        path = directory / e["file"]
        try:
            with np.load(path) as d:
                missing = [k for k in needed if k not in d.files]
                if missing:
                    raise ConfigError(
                        f"{path}: no '{missing[0]}' column (swept by an older version, or without "
                        "--surface); sweep it again"
                    )
                if len(d["t_s"]) == 0:
                    continue
                arrays = {k: d[k] for k in d.files if k != "trajectory"}
                if "surface_grid" in arrays:
                    arrays["surface_grid"] = json.loads(str(arrays["surface_grid"]))
                x = np.column_stack([d["position_counts"], d["torque_nm"]])
                parts.append((x, arrays, np.full(len(x), e["index"])))
        except (OSError, ValueError, KeyError, zipfile.BadZipFile) as exc:
            if isinstance(exc, ConfigError):
                raise
            reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
            raise ConfigError(f"{path}: not a readable trajectory ({reason}); rerun the sweep") from None
    if not parts:
        raise ConfigError(f"{directory}: the trajectories of '{object_name}' hold no samples")
    return parts


_ENTRY_KEYS = {"object_name": str, "file": str, "index": int}


def _index_entries(index_path: Path) -> list[dict]:
    """index.json's trajectory entries, each with a name, a file and an index; ConfigError (one line,
    naming the file and the entry) for anything else."""
    try:
        index = json.loads(index_path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise ConfigError(f"{index_path}: not readable JSON ({exc}); rerun the sweep") from None
    except RecursionError:
        raise ConfigError(f"{index_path}: not readable JSON (nested too deeply); rerun the sweep") from None
    entries = index.get("trajectories") if isinstance(index, dict) else None
    if not isinstance(entries, list):
        raise ConfigError(f"{index_path}: no 'trajectories' list; not a sweep index (rerun the sweep)")
    for k, entry in enumerate(entries):
        for key, kind in _ENTRY_KEYS.items():
            value = entry.get(key) if isinstance(entry, dict) else None
            if not isinstance(value, kind) or isinstance(value, bool):
                raise ConfigError(
                    f"{index_path}: trajectories[{k}].{key}: expected {kind.__name__}, got {value!r:.60}"
                )
    return entries


Samples = TypeVar("Samples", ShapeData, SurfaceData)


def split_by_trajectory(data: Samples, validation_fraction: float, seed: int) -> tuple[Samples, Samples]:
    """Whole trajectories held out for validation (at least one), chosen by seed."""
    ids = np.unique(data.trajectory)
    if len(ids) < 2:
        raise ConfigError("a held-out validation needs >= 2 trajectories; sweep more")
    rng = np.random.default_rng(seed)
    n_val = max(1, round(validation_fraction * len(ids)))
    if n_val >= len(ids):  # nothing left to train on
        raise ConfigError(
            f"--validation {validation_fraction:g} holds out all {len(ids)} trajectories, leaving none to "
            f"train on; hold out at most {(len(ids) - 1) / len(ids):.3g}, or sweep more"
        )
    held = rng.choice(ids, size=n_val, replace=False)
    val = np.isin(data.trajectory, held)
    return data.subset(~val), data.subset(val)
