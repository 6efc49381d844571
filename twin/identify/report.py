"""What `twin identify` leaves behind: the results JSON, a measured-vs-model figure, and the same
series as a Rerun recording that the viewer merges with the run's own (same recording id)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from twin.identify.identify import Identification

RESULTS_FILE = "identify.json"
FIGURE_FILE = "identify.png"
RRD_FILE = "identify.rrd"
PLOT_POINTS = 600
"""Samples drawn per series: more add nothing a reader can see, and cost the figure time."""


def write_results(ident: Identification, out_dir: Path) -> dict[str, Path]:
    """identify.json, identify.png and identify.rrd in out_dir (created); returns their paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {"results": out_dir / RESULTS_FILE, "figure": out_dir / FIGURE_FILE, "rerun": out_dir / RRD_FILE}
    paths["results"].write_text(json.dumps(json_safe(ident.to_json()), indent=2, allow_nan=False) + "\n")
    plot(ident, paths["figure"])
    log_rerun(ident, paths["rerun"])
    return paths


def json_safe(x: object) -> object:
    """JSON has no NaN: unknown values become null."""
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: json_safe(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [json_safe(v) for v in x]
    return x


def plot(ident: Identification, path: Path) -> Path:
    """Per finger: R against delta (pads, gauges through eq. 4, model) and R over time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(15, 8))
    fig.subplots_adjust(left=0.05, right=0.98, top=0.92, bottom=0.07, wspace=0.25, hspace=0.3)
    for f, (top, bottom) in zip(ident.fingers, axes.T, strict=True):
        order = np.argsort(f.delta_m)
        s = slice(None, None, max(1, len(f.t_s) // PLOT_POINTS))  # long runs: every n-th sample on screen
        top.plot(f.delta_m[s] * 1e3, f.reaction_tactile_n[s], ".", ms=3, alpha=0.5, label="tactile R (eq. 6)")
        top.plot(
            f.delta_m[s] * 1e3, f.reaction_torque_n[s], ".", ms=2, alpha=0.3, label="R from the gauge (eq. 4)"
        )
        rest = f.fit.predict(f.delta_m[order], np.zeros_like(order, dtype=float))
        top.plot(f.delta_m[order] * 1e3, rest, "k-", lw=1.5, label=f"{f.fit.model}, rate 0")
        top.set(
            xlabel="indentation delta (mm)",
            ylabel="R (N)",
            title=f"F{f.finger}: k_s = {f.secant_n_m:.0f} N/m",
        )
        bottom.plot(f.t_s, f.reaction_tactile_n, lw=1, label="tactile")
        bottom.plot(f.t_s, f.reaction_torque_n, lw=0.8, alpha=0.7, label="gauge (eq. 4)")
        bottom.plot(f.t_s, f.reaction_model_n, "k--", lw=1, label=f"model (R^2 {f.fit.r2:.2f})")
        bottom.set(xlabel="t (s)", ylabel="R (N)")
    axes[0, 0].legend(fontsize=8)
    axes[1, 0].legend(fontsize=8)
    title = f"{ident.run_path.name}: {ident.model}"
    if ident.material:
        m = ident.material
        low, high = (v / 1e3 for v in m["ci95_pa"])
        title += f"; E = {m['young_pa'] / 1e3:.1f} kPa (95 % {low:.1f}-{high:.1f})"
    fig.suptitle(title)
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def log_rerun(ident: Identification, path: Path) -> Path:
    """The figure's time series under plots/identify/f<k>/..., on the run's timeline and recording id."""
    import rerun as rr

    from twin.viz.rerun_log import TIMELINE

    rec = rr.RecordingStream("barrett_twin", recording_id=ident.run_path.name)
    rec.save(path)
    for f in ident.fingers:
        times = rr.TimeColumn(TIMELINE, duration=f.t_s)
        for name, values in (
            ("tactile_n", f.reaction_tactile_n),
            ("gauge_eq4_n", f.reaction_torque_n),
            ("model_n", f.reaction_model_n),
            ("indentation_mm", f.delta_m * 1e3),
        ):
            rec.send_columns(
                f"plots/identify/f{f.finger}/{name}",
                indexes=[times],
                columns=rr.Scalars.columns(scalars=values),
            )
    rec.flush()
    rec.disconnect()
    return path
