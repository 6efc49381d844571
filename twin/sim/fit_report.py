"""What `twin fit` leaves behind: fit.json and an overlay of the measured run, the first guess's
replay and the fitted replay (counts, torques, fingertip forces)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from twin.identify.report import json_safe
from twin.sim.fit import FitResult

RESULTS_FILE = "fit.json"
FIGURE_FILE = "fit.png"


def write_fit(result: FitResult, out_dir: Path) -> dict[str, Path]:
    """fit.json and fit.png in out_dir (created); returns their paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {"results": out_dir / RESULTS_FILE, "figure": out_dir / FIGURE_FILE}
    # strict JSON: a held parameter's formal sigma (NaN) becomes null
    paths["results"].write_text(json.dumps(json_safe(result.to_json()), indent=2, allow_nan=False) + "\n")
    plot_fit(result, paths["figure"])
    return paths


def plot_fit(result: FitResult, path: Path) -> Path:
    """Per finger: counts, distal torque and fingertip force, measured vs first guess vs fitted."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    m, a, b = result.measured, result.sim_initial, result.sim_fitted
    assert m is not None and a is not None and b is not None
    t = b.t_s
    fig, axes = plt.subplots(3, 3, figsize=(15, 9), sharex=True, constrained_layout=True)
    forces = {"meas": m.force_n, "init": _pair(a.tip_force_n), "fit": _pair(b.tip_force_n)}
    for k in range(3):
        axes[0, k].plot(t, m.position_counts[:, k], "k", lw=1.2, label="measured")
        axes[0, k].plot(t, a.position_counts[:, k], ":", lw=1, label="first guess")
        axes[0, k].plot(t, b.position_counts[:, k], "--", lw=1, label="fitted")
        axes[0, k].set(title=f"F{k + 1}", ylabel="counts")
        axes[1, k].plot(t, m.torque_nm[:, k], "k", lw=1.2)
        axes[1, k].plot(t, a.torque_nm[:, k], ":", lw=1)
        axes[1, k].plot(t, b.torque_nm[:, k], "--", lw=1)
        axes[1, k].set(ylabel="distal torque (N*m)")
    for j, label in enumerate(("F1 + F2 fingertips", "F3 fingertip")):
        ax = axes[2, j]
        ax.plot(t, forces["meas"][:, j], "k", lw=1.2)
        ax.plot(t, forces["init"][:, j], ":", lw=1)
        ax.plot(t, forces["fit"][:, j], "--", lw=1)
        ax.set(ylabel="force (N)", xlabel="t (s)", title=label)
    ax = axes[2, 2]
    ax.axis("off")
    text = [
        f"{n}: {result.fitted[n]:.4g}" + ("" if result.identifiable[n] else " (not identifiable)")
        for n in result.names
    ]
    text += [f"rms {k}: {result.rms_initial[k]:.3g} -> {result.rms_fitted[k]:.3g}" for k in result.rms_fitted]
    ax.text(0.0, 1.0, "\n".join(text), va="top", family="monospace", fontsize=9)
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(f"{result.run_path.name}: twin fit ({result.evaluations} replays, {result.wall_s:.0f} s)")
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def _pair(tips: np.ndarray) -> np.ndarray:
    return np.column_stack([tips[:, 0] + tips[:, 1], tips[:, 2]])
