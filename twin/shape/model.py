"""The paper's network (§7): 6 inputs -> 30 hidden (tanh) -> 2n outputs, with the inputs and outputs
standardized by the training set's statistics, saved with them and with its metadata."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from numpy.typing import NDArray

HIDDEN = 30
WEIGHTS_FILE = "model.pt"
META_FILE = "model.json"


class ShapeMLP(torch.nn.Module):
    """6 -> 30 (tanh) -> 2n."""

    def __init__(self, points: int, hidden: int = HIDDEN) -> None:
        super().__init__()
        self.points = points
        self.net = torch.nn.Sequential(
            torch.nn.Linear(6, hidden), torch.nn.Tanh(), torch.nn.Linear(hidden, 2 * points)
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Standardized inputs (b, 6) -> standardized outputs (b, 2n)."""
        return self.net(x)


@dataclass
class ShapeModel:
    """A trained network with its normalization; predicts contours (n, 2) in px from raw readings."""

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

    def predict(self, inputs: NDArray[np.float64]) -> NDArray[np.float64]:
        """(6,) or (b, 6) raw inputs (counts, N*m) -> (n, 2) or (b, n, 2) contour pixels."""
        x = np.asarray(inputs, dtype=np.float64)
        y = np.tanh(x @ self._w1.T + self._b1) @ self._w2.T + self._b2
        return y.reshape(*x.shape[:-1], self.points, 2)

    def predict_torch(self, inputs: NDArray[np.float64]) -> NDArray[np.float64]:
        """The same through torch (what training optimized; `predict` must agree with it)."""
        x = (np.atleast_2d(inputs) - self.x_mean) / self.x_std
        with torch.no_grad():
            y = self.net(torch.as_tensor(x, dtype=torch.float32)).numpy().astype(np.float64)
        y = y * self.y_std + self.y_mean
        return y.reshape(len(y), self.points, 2)

    def save(self, directory: Path | str) -> Path:
        """model.pt (weights) and model.json (normalization, metadata) in directory."""
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        torch.save(self.net.state_dict(), directory / WEIGHTS_FILE)
        meta = {
            "points": self.points,
            "hidden": HIDDEN,
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
        """Read a saved model; ValueError names the file when it is not one."""
        directory = Path(directory)
        try:
            meta = json.loads((directory / META_FILE).read_text())
            net = ShapeMLP(int(meta["points"]), int(meta.get("hidden", HIDDEN)))
            net.load_state_dict(torch.load(directory / WEIGHTS_FILE, weights_only=True))
        except (OSError, ValueError, KeyError, RuntimeError) as exc:
            raise ValueError(
                f"{directory}: not a trained shape model ({type(exc).__name__}: {exc})"
            ) from None
        stats = {k: np.asarray(meta.pop(k), dtype=np.float64) for k in ("x_mean", "x_std", "y_mean", "y_std")}
        return cls(net=net, metadata=meta, **stats)
