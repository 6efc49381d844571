"""The paper's network (§7): 6 inputs -> 30 hidden (tanh) -> 2n outputs, with the inputs and outputs
standardized by the training set's statistics, saved with them and with its metadata.

The 3-D variant is the same network with one output per point (a height on its grid): `dims` = 1."""

from __future__ import annotations

import json
import pickle
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from numpy.typing import NDArray

from twin.interface.errors import ConfigError
from twin.validation import check_number
from twin.vision.contour import VIEW_TOLERANCE_DEG, view_angle_deg

HIDDEN = 30
WEIGHTS_FILE = "model.pt"
META_FILE = "model.json"


class ShapeMLP(torch.nn.Module):
    """6 -> 30 (tanh) -> dims * n: 2n for a contour (u, v per point), n for heights."""

    def __init__(self, points: int, hidden: int = HIDDEN, dims: int = 2) -> None:
        super().__init__()
        self.points = points
        self.dims = dims
        self.net = torch.nn.Sequential(
            torch.nn.Linear(6, hidden), torch.nn.Tanh(), torch.nn.Linear(hidden, dims * points)
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Standardized inputs (b, 6) -> standardized outputs (b, 2n)."""
        return self.net(x)


@dataclass
class ShapeModel:
    """A trained network with its normalization; predicts contours (n, 2) in px (or, with dims = 1,
    heights (n,) in mm) from raw readings. `metadata["target"]` says which: largest, hull, surface."""

    net: ShapeMLP
    x_mean: NDArray[np.float64]
    x_std: NDArray[np.float64]
    y_mean: NDArray[np.float64]
    y_std: NDArray[np.float64]
    metadata: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.net.eval()
        w1, b1 = (p.detach().numpy().astype(np.float64) for p in self.net.net[0].parameters())
        w2, b2 = (p.detach().numpy().astype(np.float64) for p in self.net.net[2].parameters())
        # numpy copies with the normalization folded in: one prediction is two small matrix products
        self._w1 = w1 / self.x_std
        self._b1 = b1 - self._w1 @ self.x_mean
        self._w2 = w2 * self.y_std[:, None]
        self._b2 = b2 * self.y_std + self.y_mean

    @property
    def points(self) -> int:
        """Contour points per prediction."""
        return self.net.points

    @property
    def target(self) -> str:
        """What it predicts: "largest" or "hull" (contours), or "surface" (heights)."""
        return str(self.metadata.get("target", "largest"))

    def check_view(self, view_from_hand: NDArray[np.float64]) -> None:
        """ConfigError (one line) when the cameras look at the hand from another side than those whose
        contours the model learned (metadata "view_from_hand": twin.vision.contour.view_from_hand):
        its pixels would be another view's. Models from datasets that did not record it pass."""
        trained = self.metadata.get("view_from_hand")
        if trained is None:
            return
        angle = view_angle_deg(trained, view_from_hand)
        if angle > VIEW_TOLERANCE_DEG:
            raise ConfigError(
                f"--predict: the model learned contours seen from {angle:.0f} deg away from where these "
                "cameras stand; sweep and train it again with the cameras where they are"
            )

    def _shape(self, batch: tuple[int, ...]) -> tuple[int, ...]:
        return (*batch, self.points) if self.net.dims == 1 else (*batch, self.points, self.net.dims)

    def predict(self, inputs: NDArray[np.float64]) -> NDArray[np.float64]:
        """(6,) or (b, 6) raw inputs (counts, N*m) -> (n, 2) or (b, n, 2) contour pixels ((n,) or (b, n)
        heights in mm for a surface model)."""
        x = np.asarray(inputs, dtype=np.float64)
        y = np.tanh(x @ self._w1.T + self._b1) @ self._w2.T + self._b2
        return y.reshape(self._shape(x.shape[:-1]))

    def predict_torch(self, inputs: NDArray[np.float64]) -> NDArray[np.float64]:
        """The same through torch (what training optimized; `predict` must agree with it)."""
        x = (np.atleast_2d(inputs) - self.x_mean) / self.x_std
        with torch.no_grad():
            y = self.net(torch.as_tensor(x, dtype=torch.float32)).numpy().astype(np.float64)
        y = y * self.y_std + self.y_mean
        return y.reshape(self._shape((len(y),)))

    def save(self, directory: Path | str) -> Path:
        """model.pt (weights) and model.json (normalization, metadata) in directory."""
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        torch.save(self.net.state_dict(), directory / WEIGHTS_FILE)
        meta = {
            "points": self.points,
            "hidden": HIDDEN,
            "dims": self.net.dims,
            "x_mean": self.x_mean.tolist(),
            "x_std": self.x_std.tolist(),
            "y_mean": self.y_mean.tolist(),
            "y_std": self.y_std.tolist(),
            **self.metadata,
        }
        (directory / META_FILE).write_text(json.dumps(meta, indent=1))
        return directory

    @classmethod
    def load(cls, directory: Path | str) -> ShapeModel:
        """Read a saved model; ConfigError (a ValueError) in one line names the directory and what is
        wrong with it, whatever garbage the files hold (truncated, not JSON, missing keys, wrong types)."""
        directory = Path(directory)
        try:
            return cls._load(directory)
        except _UNREADABLE as exc:
            reason = exc if isinstance(exc, ConfigError) else f"{type(exc).__name__}: {exc}"
            text = " ".join(str(reason).split())
            raise ConfigError(f"{directory}: not a trained shape model ({text[:200]})") from None

    @classmethod
    def _load(cls, directory: Path) -> ShapeModel:
        meta = json.loads((directory / META_FILE).read_text(encoding="utf-8"))
        if not isinstance(meta, dict):
            raise ConfigError(f"{META_FILE} holds {type(meta).__name__}, not an object")
        points = int(check_number(meta.get("points"), "points", kind=int, min=1, max=100_000))
        hidden = int(check_number(meta.get("hidden", HIDDEN), "hidden", kind=int, min=1, max=10_000))
        dims = int(check_number(meta.pop("dims", 2), "dims", kind=int, min=1, max=2))
        sizes = {"x_mean": 6, "x_std": 6, "y_mean": dims * points, "y_std": dims * points}
        stats = {}
        for key, size in sizes.items():
            values = np.asarray(meta.pop(key), dtype=np.float64)
            if values.shape != (size,) or not np.isfinite(values).all():
                raise ConfigError(f"{key}: expected {size} finite numbers, got shape {values.shape}")
            if key.endswith("_std") and not (values > 0).all():
                raise ConfigError(f"{key}: standard deviations must be > 0")
            stats[key] = values
        net = ShapeMLP(points, hidden, dims)
        state = torch.load(directory / WEIGHTS_FILE, weights_only=True)
        if not isinstance(state, dict):
            raise ConfigError(f"{WEIGHTS_FILE} holds {type(state).__name__}, not a state dict")
        net.load_state_dict(state)
        return cls(net=net, metadata=meta, **stats)


_UNREADABLE = (
    OSError,
    ValueError,  # ConfigError, JSONDecodeError, UnicodeDecodeError
    KeyError,
    TypeError,
    AttributeError,
    IndexError,
    RuntimeError,  # torch: a truncated archive, a state dict of other shapes
    EOFError,
    pickle.UnpicklingError,
    zipfile.BadZipFile,
)
"""What reading a damaged model directory raises."""
