"""What `twin identify` leaves behind: the results JSON, a measured-vs-model figure, and the same
series as a Rerun recording that the viewer merges with the run's own (same recording id)."""

from __future__ import annotations

import contextlib
import json
import math
import multiprocessing
import os
from multiprocessing.connection import Connection
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from twin.identify.identify import Identification

RESULTS_FILE = "identify.json"
FIGURE_FILE = "identify.png"
RRD_FILE = "identify.rrd"
PLOT_POINTS = 600
"""Samples drawn per series: more add nothing a reader can see, and cost the figure time."""


def write_results(
    ident: Identification, out_dir: Path, figure_process: FigureProcess | None = None
) -> dict[str, Path]:
    """identify.json, identify.png and identify.rrd in out_dir (created); returns their paths.

    With a started `figure_process` the figure is drawn there while this process writes the recording.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {"results": out_dir / RESULTS_FILE, "figure": out_dir / FIGURE_FILE, "rerun": out_dir / RRD_FILE}
    paths["results"].write_text(json.dumps(json_safe(ident.to_json()), indent=2, allow_nan=False) + "\n")
    series = figure_series(ident)
    if figure_process is None:
        draw_figure(series, paths["figure"])
    else:
        figure_process.draw(series, paths["figure"])
    log_rerun(ident, paths["rerun"])
    if figure_process is not None:
        figure_process.wait()
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


def figure_series(ident: Identification) -> dict:
    """What the figure shows (per finger: R against delta from the pads, the gauges through eq. 4 and
    the model, and R over time), as plain numbers and text: drawing it needs nothing but matplotlib."""
    fingers = []
    for f in ident.fingers:
        order = np.argsort(f.delta_m)
        s = slice(None, None, max(1, len(f.t_s) // PLOT_POINTS))  # long runs: every n-th sample on screen
        fingers.append(
            {
                "title": f"F{f.finger}: k_s = {f.secant_n_m:.0f} N/m",
                "delta_mm": f.delta_m[s] * 1e3,
                "tactile_n": f.reaction_tactile_n[s],
                "gauge_n": f.reaction_torque_n[s],
                "rest_delta_mm": f.delta_m[order] * 1e3,
                "rest_n": f.fit.predict(f.delta_m[order], np.zeros_like(order, dtype=float)),
                "rest_label": f"{f.fit.model}, rate 0",
                "t_s": f.t_s,
                "tactile_t_n": f.reaction_tactile_n,
                "gauge_t_n": f.reaction_torque_n,
                "model_t_n": f.reaction_model_n,
                "model_label": f"model (R^2 {f.fit.r2:.2f})",
            }
        )
    title = f"{ident.run_path.name}: {ident.model}"
    if ident.material:
        m = ident.material
        low, high = (v / 1e3 for v in m["ci95_pa"])
        title += f"; E = {m['young_pa'] / 1e3:.1f} kPa (95 % {low:.1f}-{high:.1f})"
    return {"title": title, "fingers": fingers}


def draw_figure(series: dict, path: Path) -> Path:
    """The PNG of `figure_series`; no pyplot, so nothing global and any process can draw it."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(15, 8))
    axes = fig.subplots(2, 3)
    fig.subplots_adjust(left=0.05, right=0.98, top=0.92, bottom=0.07, wspace=0.25, hspace=0.3)
    for f, (top, bottom) in zip(series["fingers"], axes.T, strict=True):
        top.plot(f["delta_mm"], f["tactile_n"], ".", ms=3, alpha=0.5, label="tactile R (eq. 6)")
        top.plot(f["delta_mm"], f["gauge_n"], ".", ms=2, alpha=0.3, label="R from the gauge (eq. 4)")
        top.plot(f["rest_delta_mm"], f["rest_n"], "k-", lw=1.5, label=f["rest_label"])
        top.set(xlabel="indentation delta (mm)", ylabel="R (N)", title=f["title"])
        bottom.plot(f["t_s"], f["tactile_t_n"], lw=1, label="tactile")
        bottom.plot(f["t_s"], f["gauge_t_n"], lw=0.8, alpha=0.7, label="gauge (eq. 4)")
        bottom.plot(f["t_s"], f["model_t_n"], "k--", lw=1, label=f["model_label"])
        bottom.set(xlabel="t (s)", ylabel="R (N)")
    axes[0, 0].legend(fontsize=8)
    axes[1, 0].legend(fontsize=8)
    fig.suptitle(series["title"])
    fig.savefig(path, dpi=80)
    return path


class FigureProcess:
    """A worker process that imports matplotlib while the caller identifies the run, then draws.

    Importing matplotlib and drawing are about 0.8 s of `twin identify`'s ~2 s on a 60 s run; on the
    second core they overlap the identification and the Rerun recording instead of following them.
    Use as a context manager; `draw` hands it the figure, `wait` returns once the PNG is on disk.
    """

    def __enter__(self) -> FigureProcess:
        ctx = multiprocessing.get_context("spawn")  # fork would copy whatever threads the caller runs
        self._conn, child = ctx.Pipe()
        self._process = ctx.Process(target=_figure_worker, args=(child,), daemon=True, name="twin-figure")
        self._process.start()
        child.close()
        return self

    def draw(self, series: dict, path: Path) -> None:
        self._figure = (series, Path(path))
        with contextlib.suppress(BrokenPipeError, ConnectionResetError):  # gone: wait() draws here
            self._conn.send((series, str(path)))

    def wait(self) -> None:
        try:
            error = self._conn.recv()
        except EOFError:
            # The worker died: a script without an `if __name__ == "__main__":` guard, whose
            # re-import in the spawned process cannot start processes, or a killed worker. Draw here.
            draw_figure(*self._figure)
            return
        if error is not None:
            raise RuntimeError(f"the figure could not be drawn: {error}")

    def __exit__(self, *exc: object) -> None:
        self._conn.close()  # the worker exits on its own once the pipe closes; nothing waits for it
        if exc[0] is not None:
            self._process.terminate()


def _figure_worker(conn: Connection) -> None:
    """Import matplotlib now; draw the one figure sent; report None or the error; leave at once."""
    from matplotlib.figure import Figure  # noqa: F401

    try:
        series, path = conn.recv()
    except EOFError:  # the caller failed before it had a figure to draw
        os._exit(0)
    try:
        draw_figure(series, Path(path))
        conn.send(None)
    except Exception as e:  # the caller reports it as one line
        conn.send(f"{type(e).__name__}: {e}")
    conn.close()
    os._exit(0)  # the PNG is closed; skip tearing matplotlib down, which the caller would wait for


def poisson_line(poisson: dict) -> str:
    """One line: nu and its 95 % interval with where it came from, or the range drawn and what two pairs
    would add."""
    low, high = poisson["poisson_ci95"]
    if "poisson" not in poisson:
        return f"nu: the tolerated {low:.2f}-{high:.2f}, not measured; {poisson['cameras_would_add']}"
    drawn = "-".join(f"{v:.3f}" for v in poisson["drawn_range"])
    how = "" if poisson.get("narrowed", True) else " (the tolerated range: --poisson-from-cameras narrows it)"
    return (
        f"nu = {poisson['poisson']:.3f}  (95 % {low:.3f}-{high:.3f}) from the two opposite stereo pairs' "
        f"strains through {poisson['simulations']} simulations; the modulus simulations draw nu in "
        f"{drawn}{how}"
    )


def result_markdown(ident: Identification) -> str:
    """The result as a reader wants it first: E and its interval (or the interval alone and why), the
    squeeze it came from, and eq. 4 per finger (secant stiffness k_s, the reaction model's R^2)."""
    lines = [f"# {ident.run_path.name}: identification", ""]
    m = ident.material or {}
    if m.get("ci95_pa"):
        low, high = (v / 1e3 for v in m["ci95_pa"])
        if m.get("number_given", True):
            lines.append(f"**E = {m['young_pa'] / 1e3:.1f} kPa** (95 % interval {low:.1f}-{high:.1f} kPa)")
        else:
            lines += [f"**E within {low:.1f}-{high:.1f} kPa** (95 %): no number given", "", m.get("why", "")]
        if m.get("twin_young_pa"):
            lines.append(f"\nthe twin's E (the truth of a sim run): {m['twin_young_pa'] / 1e3:.1f} kPa")
        lines += ["", f"from the squeeze stiffness {m.get('squeeze_stiffness_n_m', float('nan')):.0f} N/m"]
        if m.get("poisson"):
            lines += ["", poisson_line(m["poisson"])]
    lines += ["", "| finger | k_s (N/m) | reaction model | R^2 |", "|---|---|---|---|"]
    for f in ident.fingers:
        lines.append(f"| F{f.finger} | {f.secant_n_m:.0f} | {f.fit.model} | {f.fit.r2:.2f} |")
    lines += [f"\nnote: {note}" for note in ident.notes]
    return "\n".join(lines) + "\n"


def log_rerun(ident: Identification, path: Path) -> Path:
    """The result as a document and the figure's time series under plots/identify/f<k>/..., on the run's
    timeline and recording id, with the run's blueprint and an identification tab: opened beside run.rrd
    in `rerun` (after it), the result shows without `twin view`."""
    import dataclasses

    import rerun as rr

    from twin.session import RRD_NAME
    from twin.viz.blueprint import (
        FINGER_RGB,
        IDENTIFY_QUANTITIES,
        IDENTIFY_RESULT_ENTITY,
        kind_of_run,
        run_blueprint,
    )
    from twin.viz.rerun_log import TIMELINE, look_target_of

    eye = look_target_of(ident.run_path / RRD_NAME)
    kind = kind_of_run(ident.run_path, eye)  # before the file is opened: not read back half-written
    rec = rr.RecordingStream("barrett_twin", recording_id=ident.run_path.name)
    rec.save(path)
    series = {  # the identification's own series: its views' y ranges span them (the run's are in kind)
        f"/plots/identify/f{f.finger}/{name}": np.asarray(values, dtype=float)
        for f in ident.fingers
        for name, values in (
            ("tactile_n", f.reaction_tactile_n),
            ("gauge_eq4_n", f.reaction_torque_n),
            ("model_n", f.reaction_model_n),
            ("indentation_mm", f.delta_m * 1e3),
        )
    }
    spans = tuple(
        (entity, float(np.nanmin(v)), float(np.nanmax(v)))
        for entity, v in series.items()
        if np.isfinite(v).any()
    )
    kind = dataclasses.replace(kind, identify=True, y_ranges=kind.y_ranges + spans)
    rec.send_blueprint(run_blueprint(kind), make_active=True, make_default=True)
    markdown = rr.TextDocument(result_markdown(ident), media_type=rr.MediaType.MARKDOWN)
    rec.log(IDENTIFY_RESULT_ENTITY, markdown, static=True)
    names = {**IDENTIFY_QUANTITIES, "indentation_mm": "indentation (mm)"}
    for f in ident.fingers:
        times = rr.TimeColumn(TIMELINE, duration=f.t_s)
        for name in ("tactile_n", "gauge_eq4_n", "model_n", "indentation_mm"):
            entity = f"plots/identify/f{f.finger}/{name}"
            values = series[f"/{entity}"]
            # named and coloured in the file itself, so the series read right even opened on their own
            label = f"F{f.finger} {names[name]}"
            rec.log(entity, rr.SeriesLines(names=[label], colors=[FINGER_RGB[f"F{f.finger}"]]), static=True)
            rec.send_columns(entity, indexes=[times], columns=rr.Scalars.columns(scalars=values))
    rec.flush()
    rec.disconnect()
    return path
