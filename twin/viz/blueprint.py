"""The Rerun blueprints of the project: what a run (compress, free, with cameras, predicting, identified)
shows at first sight, and the fixed colours and names its views share.

One fixed colour per finger everywhere (plots, the hand model, the pads); a view's title carries its
quantity and unit (Rerun 0.41's time-series axes take no label of their own); what is compared sits in
one view: command against measured position, the simulator's truth against what the sensors say.
Entity paths are the ones twin.viz.rerun_log writes (and twin.identify.report for /plots/identify).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from twin.units import FINGER_MAX_COUNTS, FINGERTIP_FORCE_LIMIT_KG

TIMELINE = "sim_time"
FINGERS = ("F1", "F2", "F3")
FINGER_RGB = {"F1": (228, 26, 28), "F2": (30, 120, 220), "F3": (40, 170, 60), "S": (150, 150, 150)}
"""Red, blue, green (grey for the spread): the same in every plot and on the hand model's finger links."""
PALM_RGB = (150, 150, 150)
HAND_ENTITY = "world/hand"
STEREO_ENTITY = f"{HAND_ENTITY}/stereo"
RECTIFIED_ENTITY = f"{STEREO_ENTITY}/rectified_left"
DEPTH_ENTITY = f"{RECTIFIED_ENTITY}/depth"
CLOUD_ENTITY = f"{STEREO_ENTITY}/cloud"
MESH_ENTITY = f"{STEREO_ENTITY}/mesh"
FUSED_CLOUD_ENTITY = f"{HAND_ENTITY}/fused/cloud"
POINT_ERROR_SCALE_MM = 5.0
"""Sim camera runs colour the stereo points by their distance to the true surface, pale violet at 0 to
deep purple at this many mm and beyond (the stereo bar is a 1.5 mm median: issue 21)."""
POINT_ERROR_COLORMAP = "Purples"
POINT_ERROR_COLORMAP_FROM = 0.35
"""0 mm sits this far up the colour map (its bottom is white: a point of no error stays visible)."""
ERROR_RGB = (120, 50, 170)
"""Errors that belong to no finger (the reconstruction's against the truth) in purple, the points'
colour map's hue: red, green and blue are the fingers' (one colour meaning per view, issue 39)."""
CONTACT_RGB = (255, 255, 255)
"""Contacts in the 3-D view (the simulator's contact forces, the pads' contact points) in white."""
FUSED_RGB = (175, 175, 175)
"""The fused reconstruction of the foam in grey (it was light blue, beside F2's blue)."""
FUSED_MESH_ENTITY = f"{HAND_ENTITY}/fused/mesh"
TACTILE_POINTS_ENTITY = f"{HAND_ENTITY}/tactile_contacts"
TACTILE_ENTITY = "tactile"
LOG_ENTITY = "log"
EVENTS_ENTITY = "events"
"""The run's events as states on the shared time axis: events/phase (the procedure's phase),
events/F<k>_force_cap (a finger at the fingertip-force cap, where the safety layer stops its closing),
events/F<k>_command (its command clipped), events/hand_cycle (a hardware cycle the driver recovered),
events/hand_loop (a hardware loop over a period behind its schedule), events/tactile_frames (a scan
after pad frames were lost), events/run (a stop: a refused command, a lost hand).
RunRecording.log_event writes them, twin.rig decides them."""
COMPRESS_PHASE = "compress"
"""The phase whose window the compression view shows (twin.experiments.compress)."""
FORCE_CAP_ENTITY = "plots/hand/force_cap_kg"
"""The safety layer's fingertip-force cap, drawn on the force plot as a line."""
LINKED_X = rrb.TimeAxis(link=rrb.components.LinkAxis.LinkToGlobal)
"""Stacked plots share one time axis: the same instant at the same x in every one."""
COMPRESSION_WINDOW_S = 4.0
"""Before the compress phase is known (a recording still being written), the compression-window view
shows the last 4 s before the time cursor (two periods of the 0.5 Hz sine); after, it starts at the
compress phase and its y axis fits the squeeze instead of the 0 -> 12,000-count close."""
Y_MARGIN = 0.05
"""A data range drawn with this fraction of its span above and below, so no curve runs along an edge."""
DEFAULT_EYE_TARGET_M = (0.0, 0.0, 0.12)
"""Where the 3-D view looks when the run holds no object (a free run): between the palm (z 0.075 m,
twin/sim/scene.py) and the fingertips, where they meet over it, so the whole hand is in the picture."""
EYE_OFFSET_M = (0.14, -0.19, 0.11)
"""Where the 3-D camera sits from what it looks at (the foam): in front of the palm, above, to one side."""
FINGER_KEY = "F1 red, F2 blue, F3 green"
"""The colour key, in the titles of the plots that show the fingers (their legends are hidden: they
covered the curves; a series' name shows on hover)."""
IDENTIFY_QUANTITIES = {
    "tactile_n": "R tactile (eq. 6)",
    "gauge_eq4_n": "R strain gauge (eq. 4)",
    "model_n": "R model",
}
"""/plots/identify/f<k>/<quantity> (twin.identify.report) and the name each series gets here."""
IDENTIFY_RESULT_ENTITY = "identify/result"
"""Where `twin identify` writes its result as a Markdown document (twin.identify.report)."""


def lighter(rgb: Sequence[int], amount: float = 0.5) -> tuple[int, int, int]:
    """A colour blended towards white: the same finger's command or truth beside its measurement."""
    return tuple(round(c + (255 - c) * amount) for c in rgb)  # type: ignore[return-value]


def finger_of(name: str) -> str | None:
    """ "F1" for a body or pad named f1_*, "S" for the spread, None for anything else (the palm)."""
    low = name.lower()
    for finger in FINGERS:
        if low.startswith(finger.lower()):
            return finger
    return None


def finger_colors(labels: Sequence[str], *, light: bool = False) -> list[tuple[int, int, int]]:
    """The fixed colour of each series label ("F1", "f2_tip", "palm"...), lighter for a reference."""
    out = []
    for label in labels:
        finger = finger_of(label) if label != "S" else "S"
        rgb = FINGER_RGB[finger] if finger else PALM_RGB
        if finger and "inner" in label.lower():  # a finger's second pad: between its colour and white
            rgb = lighter(rgb, 0.35)
        out.append(lighter(rgb) if light else tuple(rgb))
    return out


def series(labels: Sequence[str], *, light: bool = False, width: float = 2.0) -> rr.SeriesLines:
    """Named, fixed-colour lines for a multi-series entity (thin and light for a command or truth)."""
    return rr.SeriesLines(
        names=list(labels), colors=finger_colors(labels, light=light), widths=[width] * len(labels)
    )


def series_of(path: str) -> rr.SeriesLines | None:
    """The names, colours and widths SERIES_STYLE (and SERIES_RGB) give a plotted entity; None: unknown."""
    if path not in SERIES_STYLE:
        return None
    labels, light, width = SERIES_STYLE[path]
    if path not in SERIES_RGB:
        return series(labels, light=light, width=width)
    colors = [lighter(c) if light else tuple(c) for c in SERIES_RGB[path]]
    return rr.SeriesLines(names=list(labels), colors=colors, widths=[width] * len(labels))


# What each plotted entity is called and how it is drawn: (labels, light, width).
_HAND = {
    f"/plots/hand/{f}": (FINGERS, False, 2.0) for f in ("position_counts", "velocity_rad_s", "torque_nm")
}
_HAND["/plots/hand/force_kg"] = (FINGERS, False, 2.0)
_HAND[f"/{FORCE_CAP_ENTITY}"] = (("force cap",), False, 1.0)
_COMMAND = {"/plots/command/position_counts": (tuple(f"{f} command" for f in FINGERS), True, 1.5)}
_PADS = ("f1_tip", "f2_tip", "f3_tip", "f1_inner", "f2_inner", "f3_inner", "palm")
_TIPS = ("F1 tip", "F2 tip", "F3 tip")
_SIM = {
    "/plots/truth/tip_contact_force_n": (tuple(f"{t} true" for t in _TIPS), True, 1.5),
    "/plots/tactile/tip_force_n": (tuple(f"{t} eq. 6" for t in _TIPS), False, 2.0),
    "/plots/truth/outer_rad": (tuple(f"{f} outer true" for f in FINGERS), True, 1.5),
    "/plots/observer/outer_rad": (tuple(f"{f} outer observer" for f in FINGERS), False, 2.0),
    "/plots/truth/inner_rad": (tuple(f"{f} inner true" for f in FINGERS), True, 1.5),
    "/plots/observer/inner_rad": (tuple(f"{f} inner observer" for f in FINGERS), False, 2.0),
}
DIFFERENCE_STREAM = "difference"
"""/plots/difference/<field>: an estimate minus the simulator's truth at the instants both were taken."""
_DIFFERENCES = {
    f"/plots/{DIFFERENCE_STREAM}/tip_force_n": (tuple(f"{t} eq. 6 - true" for t in _TIPS), False, 2.0),
    f"/plots/{DIFFERENCE_STREAM}/outer_rad": (
        tuple(f"{f} outer observer - true" for f in FINGERS),
        False,
        2.0,
    ),
    f"/plots/{DIFFERENCE_STREAM}/inner_rad": (
        tuple(f"{f} inner observer - true" for f in FINGERS),
        False,
        2.0,
    ),
}
_STEREO_ERROR = {
    "/plots/stereo_truth/median_mm": (("median",), False, 2.0),
    "/plots/stereo_truth/p90_mm": (("90th percentile",), True, 1.5),
}
SERIES_STYLE: dict[str, tuple[Sequence[str], bool, float]] = {
    **_HAND,
    **_COMMAND,
    "/plots/tactile/pad_force_n": (_PADS, False, 1.5),
    **_SIM,
    **_DIFFERENCES,
    **_STEREO_ERROR,
}
"""Every multi-series plot entity RunRecording writes: its series' names, whether drawn light, width.
The recording logs these statically (rr.SeriesLines) and the views override with them too, so the
colours hold whichever file the viewer opens first."""
SERIES_RGB = {path: [ERROR_RGB] for path in _STEREO_ERROR}
"""Series that belong to no finger, in their own colour (drawn lighter where SERIES_STYLE says light)."""
DEVICE_RANGES = {
    "/plots/hand/position_counts": (0.0, float(FINGER_MAX_COUNTS)),
    "/plots/command/position_counts": (0.0, float(FINGER_MAX_COUNTS)),
}
"""y ranges of the device's own: the drive's 0-17,800 counts (the fingertip force's, to past the run's own
cap, is device_range's). A view of other entities spans the run's recorded data (RunKind.y_ranges)."""
FORCE_PATHS = ("/plots/hand/force_kg", f"/{FORCE_CAP_ENTITY}")


@dataclass(frozen=True)
class RunKind:
    """What a run recorded, which decides its views."""

    experiment: str = "compress"
    sim: bool = True
    stereo: bool = False
    predict: bool = False
    identify: bool = False
    eye_target_m: tuple[float, float, float] | None = None
    tactile: bool = True
    """Whether the run has the pads (a hand-only hardware run has none: no empty pad views)."""
    y_ranges: tuple[tuple[str, float, float], ...] = ()
    """(entity, low, high) of each plotted entity's recorded values: the y range of a view the device
    gives none (empty until the run has data: RunRecording and kind_of_run fill it)."""
    compress_start_s: float | None = None
    """When the compress phase began (s): the compression window starts there."""
    window_y_range: tuple[float, float] | None = None
    """The finger positions' and commands' range over the compress phase (counts)."""
    force_cap_kg: float = FINGERTIP_FORCE_LIMIT_KG
    """The safety layer's fingertip-force cap on this run (a rig.toml may set its own; else the
    datasheet's)."""

    @property
    def name(self) -> str:
        """ "compress", "free", "cameras", "predict" or "identify" (the richest that applies)."""
        if self.identify:
            return "identify"
        if self.predict:
            return "predict"
        if self.stereo:
            return "cameras"
        return self.experiment


def _overrides(paths: Sequence[str]) -> dict[str, rr.SeriesLines]:
    return {path: lines for path in paths if (lines := series_of(path)) is not None}


def padded(low: float, high: float) -> tuple[float, float]:
    """A data range with Y_MARGIN of its span each side (a flat series: 5 % of its size, or 1e-3)."""
    span = high - low
    margin = Y_MARGIN * span if span > 0 else max(Y_MARGIN * abs(high), 1e-3)
    return (low - margin, high + margin)


def device_range(kind: RunKind, path: str) -> tuple[float, float] | None:
    """The device's own y range of a plotted entity (DEVICE_RANGES; the force to 1.25x the run's cap)."""
    if path in FORCE_PATHS:
        return (0.0, 1.25 * kind.force_cap_kg)
    return DEVICE_RANGES.get(path)


def y_range(kind: RunKind, paths: Sequence[str]) -> tuple[float, float] | None:
    """A view's y range: the device's where its entities have one (widened, with a margin, only where
    the run's values leave it: a gauge's offset below 0 kg), else the span of the run's recorded values
    (padded); None while nothing is recorded."""
    device = [r for r in (device_range(kind, p) for p in paths) if r is not None]
    recorded = {path: (lo, hi) for path, lo, hi in kind.y_ranges}
    spans = [recorded[p] for p in paths if p in recorded]
    data = (min(lo for lo, _ in spans), max(hi for _, hi in spans)) if spans else None
    if not device:
        return None if data is None else padded(*data)
    low, high = min(lo for lo, _ in device), max(hi for _, hi in device)
    if data is not None:
        margin = Y_MARGIN * (max(high, data[1]) - min(low, data[0]))
        low = data[0] - margin if data[0] < low else low
        high = data[1] + margin if data[1] > high else high
    return (low, high)


def _plot(
    name: str, paths: Sequence[str], kind: RunKind, *, y: tuple[float, float] | None = None, **kwargs: object
) -> rrb.TimeSeriesView:
    """A time-series view of explicit entities, series named and coloured by SERIES_STYLE; the time
    axis linked to every other plot's, the y axis over `y` or else y_range (the device's or the data's)."""
    if "time_ranges" not in kwargs:  # a view of its own window (the compression's) keeps its own axis
        kwargs["axis_x"] = LINKED_X
    span = y if y is not None else y_range(kind, paths)
    if span is not None:
        kwargs["axis_y"] = rrb.ScalarAxis(range=span)
    return rrb.TimeSeriesView(
        name=name,
        origin="/plots",
        contents=list(paths),
        overrides=_overrides(paths),
        plot_legend=rrb.PlotLegend(visible=False),  # it covered the curves; colours: see FINGER_KEY
        **kwargs,
    )


def scene_view(kind: RunKind) -> rrb.Spatial3DView:
    """The hand and the foam, z up, the eye in front of the palm looking at the foam. In camera runs one
    cloud (the stereo points: coloured by their error to the truth in sim runs) and one mesh (the fused
    surface) are on; the stereo mesh, the fused cloud and the depth image's back-projection are hidden."""
    target = np.array(kind.eye_target_m or DEFAULT_EYE_TARGET_M, dtype=float)
    eye = rrb.EyeControls3D(
        kind=rrb.Eye3DKind.Orbital,
        position=(target + EYE_OFFSET_M).tolist(),
        look_target=target.tolist(),
        eye_up=[0.0, 0.0, 1.0],
    )
    hidden = {}
    if kind.stereo:
        hidden = {
            f"/{p}": rrb.EntityBehavior(visible=False)
            for p in (MESH_ENTITY, FUSED_CLOUD_ENTITY, DEPTH_ENTITY)
        }
    name = "hand (m, z up)" if kind.experiment == "free" else "hand and foam (m, z up)"
    if kind.sim:
        name += "; contacts white"
    if kind.stereo:
        name += "; fused surface grey"
    if kind.stereo and kind.sim:
        name += (
            f"; stereo points by error to the truth: pale violet 0 to purple >= {POINT_ERROR_SCALE_MM:g} mm"
        )
    return rrb.Spatial3DView(name=name, origin="/world", eye_controls=eye, overrides=hidden)


def compression_window(kind: RunKind) -> rrb.TimeSeriesView:
    """Command against position over the compress phase (from its start to the cursor), the y axis over
    that phase's positions; before the phase is known, the last COMPRESSION_WINDOW_S before the cursor."""
    position = ["/plots/hand/position_counts", "/plots/command/position_counts"]
    if kind.compress_start_s is None:
        start = rrb.TimeRangeBoundary.cursor_relative(seconds=-COMPRESSION_WINDOW_S)
        name = f"compression window, last {COMPRESSION_WINDOW_S:g} s (counts)"
    else:
        start = rrb.TimeRangeBoundary.absolute(nanos=round(1e9 * kind.compress_start_s))  # as logged
        name = (
            f"compression window, from the {COMPRESS_PHASE} phase at {kind.compress_start_s:.1f} s (counts)"
        )
    window = rrb.VisibleTimeRange(
        TIMELINE, start=start, end=rrb.TimeRangeBoundary.cursor_relative(seconds=0.0)
    )
    span = padded(*kind.window_y_range) if kind.window_y_range is not None else y_range(kind, position)
    return _plot(name, position, kind, y=span, time_ranges=window)


def hand_views(kind: RunKind) -> list[rrb.View]:
    """Command against measured position (whole run and the compression window), velocity, torque, force."""
    position = ["/plots/hand/position_counts", "/plots/command/position_counts"]
    views: list[rrb.View] = [_plot(f"finger position (counts), command light: {FINGER_KEY}", position, kind)]
    if kind.experiment == "compress":
        views.append(compression_window(kind))
    views += [
        _plot("joint velocity (rad/s)", ["/plots/hand/velocity_rad_s"], kind),
        _plot("strain-gauge torque, eq. 2 (N·m)", ["/plots/hand/torque_nm"], kind),
        _plot(
            f"fingertip force, eq. 3 (kg); grey: the {kind.force_cap_kg:g} kg cap",
            ["/plots/hand/force_kg", f"/{FORCE_CAP_ENTITY}"],
            kind,
        ),
    ]
    return views


EVENTS_VIEW = "events: phase, force cap, clipped command, hand cycle and loop, stop"


def events_view() -> rrb.StateTimelineView:
    """Phases and safety events as lanes on the shared time axis."""
    return rrb.StateTimelineView(name=EVENTS_VIEW, origin=f"/{EVENTS_ENTITY}", time_view=LINKED_X)


def truth_views(kind: RunKind) -> list[rrb.View]:
    """Sim runs: the simulator's truth (light) over what the sensors and the science say."""
    return [
        _plot(
            "tip contact force: true (light) vs eq. 6 (N)",
            ["/plots/tactile/tip_force_n", "/plots/truth/tip_contact_force_n"],
            kind,
        ),
        _plot(
            "outer joint: true (light) vs clutch observer (rad)",
            ["/plots/observer/outer_rad", "/plots/truth/outer_rad"],
            kind,
        ),
        _plot(
            "inner joint: true (light) vs clutch observer (rad)",
            ["/plots/observer/inner_rad", "/plots/truth/inner_rad"],
            kind,
        ),
    ]


def difference_views(kind: RunKind) -> list[rrb.View]:
    """Sim runs: each estimate minus the truth it is drawn over (the curves overlap within a line's width),
    and in camera runs the reconstruction's error (purple: no finger's)."""
    views: list[rrb.View] = [
        _plot(
            f"tip contact force: eq. 6 - true (N): {FINGER_KEY}",
            [f"/plots/{DIFFERENCE_STREAM}/tip_force_n"],
            kind,
        ),
        _plot(
            f"outer joint: observer - true (rad): {FINGER_KEY}",
            [f"/plots/{DIFFERENCE_STREAM}/outer_rad"],
            kind,
        ),
        _plot(
            f"inner joint: observer - true (rad): {FINGER_KEY}",
            [f"/plots/{DIFFERENCE_STREAM}/inner_rad"],
            kind,
        ),
    ]
    if kind.stereo:
        error = ["/plots/stereo_truth/median_mm", "/plots/stereo_truth/p90_mm"]
        views.append(_plot("reconstruction error vs truth (mm): median dark, p90 light", error, kind))
    return views


def tactile_view(full_scale_kpa: float | None = None) -> rrb.Spatial2DView:
    """The pads as filled cells (one image a pad), colour scale stated in the view."""
    scale = "colour bar at the right" if full_scale_kpa is None else f"0-{full_scale_kpa:g} kPa"
    return rrb.Spatial2DView(name=f"tactile pressure (kPa, viridis, {scale})", origin=f"/{TACTILE_ENTITY}")


def camera_views(kind: RunKind) -> list[rrb.View]:
    """Left and right images, the rectified depth (with the contours in a predicting run)."""
    views: list[rrb.View] = [
        rrb.Spatial2DView(name=f"{side} camera", origin=f"/{STEREO_ENTITY}/{side}")
        for side in ("left", "right")
    ]
    views.append(
        rrb.Spatial2DView(name="rectified left: depth (m) and contours", origin=f"/{RECTIFIED_ENTITY}")
    )
    return views


def identify_views(kind: RunKind) -> list[rrb.View]:
    """The identification (`twin identify`): per finger, reaction force by three routes and the indentation,
    on separate axes (N and mm)."""
    views: list[rrb.View] = []
    for k in (1, 2, 3):
        paths = [f"/plots/identify/f{k}/{q}" for q in IDENTIFY_QUANTITIES]
        overrides = {
            p: rr.SeriesLines(
                names=[f"F{k} {IDENTIFY_QUANTITIES[q]}"],
                colors=[lighter(FINGER_RGB[f"F{k}"], {"tactile_n": 0.0, "gauge_eq4_n": 0.45}.get(q, 0.7))],
                widths=[2.0 if q == "tactile_n" else 1.5],
            )
            for p, q in zip(paths, IDENTIFY_QUANTITIES, strict=True)
        }
        views.append(
            rrb.TimeSeriesView(
                name=f"F{k} reaction force R (N): tactile eq. 6 (dark), gauge eq. 4 (mid), model (light)",
                origin="/plots/identify",
                contents=paths,
                overrides=overrides,
                plot_legend=rrb.PlotLegend(visible=False),
                **_y_axis(kind, paths),
            )
        )
    paths = [f"/plots/identify/f{k}/indentation_mm" for k in (1, 2, 3)]
    overrides = {
        p: rr.SeriesLines(names=[f"F{k} indentation"], colors=[FINGER_RGB[f"F{k}"]])
        for k, p in zip((1, 2, 3), paths, strict=True)
    }
    views.append(
        rrb.TimeSeriesView(
            name=f"indentation δ (mm): {FINGER_KEY}",
            origin="/plots/identify",
            contents=paths,
            overrides=overrides,
            plot_legend=rrb.PlotLegend(visible=False),
            **_y_axis(kind, paths),
        )
    )
    return views


def _y_axis(kind: RunKind, paths: Sequence[str]) -> dict[str, rrb.ScalarAxis]:
    span = y_range(kind, paths)
    return {} if span is None else {"axis_y": rrb.ScalarAxis(range=span)}


def run_blueprint(kind: RunKind, *, extra: Sequence[str] = ()) -> rrb.Blueprint:
    """The default blueprint of a run of this kind.

    Left: the 3-D scene above the sensors (cameras and depth side by side in camera runs, the tactile
    pads beside them). Right: the time series in tabs, the hand's first; the events' lanes and the log
    (phases and warnings) below them.
    """
    sensors: list[rrb.View] = [tactile_view()] if kind.tactile else []
    if kind.stereo:
        sensors += camera_views(kind)
    elif kind.predict:
        sensors.append(rrb.Spatial2DView(name="contour: predicted (px)", origin=f"/{RECTIFIED_ENTITY}"))
    left = (
        rrb.Vertical(scene_view(kind), rrb.Horizontal(*sensors), row_shares=[3, 2])
        if sensors
        else scene_view(kind)
    )
    pads = _plot("pad forces, eq. 6 (N)", ["/plots/tactile/pad_force_n"], kind)
    tabs: list[rrb.Container] = [rrb.Vertical(*hand_views(kind), name="hand")]
    if kind.sim:
        tabs.append(rrb.Vertical(*truth_views(kind), pads, name="truth vs sensors"))
        tabs.append(rrb.Vertical(*difference_views(kind), name="errors: estimate - truth"))
    elif kind.tactile:
        tabs.append(rrb.Vertical(pads, name="tactile"))
    if extra:  # plotted entities no view of this kind names
        tabs.append(rrb.Vertical(_plot("other series", list(extra), kind), name="other"))
    if kind.identify:
        result = rrb.TextDocumentView(name="identification: the result", origin=f"/{IDENTIFY_RESULT_ENTITY}")
        tabs.insert(
            0, rrb.Vertical(result, *identify_views(kind), name="identification", row_shares=[2, 2, 2, 2, 2])
        )
    log = rrb.TextLogView(name="log: phases and warnings", origin=f"/{LOG_ENTITY}")
    right = rrb.Vertical(rrb.Tabs(*tabs, active_tab=0), events_view(), log, row_shares=[5, 1, 1])
    return rrb.Blueprint(
        rrb.TimePanel(state="collapsed", timeline=TIMELINE),
        rrb.Horizontal(left, right, column_shares=[3, 2]),
        collapse_panels=True,
    )


def views_of(blueprint: rrb.Blueprint | rrb.Container) -> list[rrb.View]:
    """Every view in a blueprint (or container), depth first."""
    out: list[rrb.View] = []
    root = blueprint.root_container if isinstance(blueprint, rrb.Blueprint) else blueprint
    for part in root.contents if isinstance(root, rrb.Container) else [root]:
        if isinstance(part, rrb.View):
            out.append(part)
        elif isinstance(part, rrb.Container):
            out += views_of(part)
    return out


def plotted_paths(kind: RunKind) -> set[str]:
    """The entities the time-series views of a run's blueprint name explicitly."""
    return {
        str(path)
        for view in views_of(run_blueprint(kind))
        if isinstance(view, rrb.TimeSeriesView)
        for path in view.contents
    }


def kind_of_run(run_dir: Path, eye_target_m: Sequence[float] | None = None) -> RunKind:
    """What a run directory holds (run.json's experiment, backend and streams; an identify.rrd beside
    it), as the kind its blueprint is made for, with the y ranges and the compress phase's start its
    recordings hold (run.rrd and the analyses' .rrd files beside it). A run.json that cannot be read
    gives the default."""
    import json

    from twin.viz.rerun_log import recorded_plot_facts

    try:
        info = json.loads((run_dir / "run.json").read_text())
    except (OSError, ValueError):
        info = {}
    meta = info.get("metadata", {}) if isinstance(info, dict) else {}
    streams = info.get("streams", {}) if isinstance(info, dict) else {}
    experiment = meta.get("experiment", {})
    facts = recorded_plot_facts([run_dir / "run.rrd", *sorted(run_dir.glob("*/*.rrd"))])
    cap = meta.get("force_cap", {}).get("limit_kg") if isinstance(meta.get("force_cap"), dict) else None
    return RunKind(
        experiment=str(experiment.get("name", "compress")) if isinstance(experiment, dict) else "compress",
        sim=meta.get("backend", "sim") == "sim",
        stereo="stereo" in streams,
        predict="shape" in streams,
        identify=any(run_dir.glob("*/identify.rrd")),
        tactile="tactile" in streams or not streams,
        eye_target_m=None if eye_target_m is None else tuple(float(x) for x in eye_target_m),
        force_cap_kg=float(cap) if isinstance(cap, int | float) and cap > 0 else FINGERTIP_FORCE_LIMIT_KG,
        **facts,
    )
