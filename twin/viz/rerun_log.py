"""Every Rerun call of the project: one recording per run, saved to an .rrd with the blueprint of its
kind of run (twin.viz.blueprint).

The 3-D view shows the MuJoCo model (visual geoms on their bodies, each finger's links in its fixed
colour) and the deforming foam; time series show each finger's measured position against its command,
velocity (rad/s), torque and force, and in sim runs the simulator's truth against what the sensors and
the science say, and their difference; the pads are images of filled cells (kPa) beside a colour bar;
the procedure's phases and the safety layer's events are lanes on the time axis and rows of the log.

Stereo (log_stereo_setup, log_stereo): everything the vision produces lives in the hand frame
(HAND_ENTITY, "/world/hand", posed at the palm body's world pose so it sits on the hand model): the
two cameras as pinholes with their images (JPEG, 10 fps), the rectified left camera with the depth from
the disparity (PNG, with the images), the reconstructed cloud and mesh (5 Hz), the fused cloud and mesh
(2 Hz), and the tactile contact points.

Size (benchmarks/recording_size.py: `twin run compress`, 12 s against 6 s, per minute): a camera run
31.2 MB a minute (39.5 before the fused surface went from 5 to 2 Hz), a run without cameras 8.5 (8.3
before the differences to the truth were plotted); the blueprint, sent once at close, ~0.2 MB.

Reading an .rrd back uses Rerun's own chunk reader (`rerun.chunk.RrdReader`): Rerun 0.41 has no
`rerun.dataframe` module any more, and its DataFusion query API (`ChunkStore.reader`) needs the
optional `datafusion` package, which this project does not install.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from datetime import timedelta
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import rerun as rr
from numpy.typing import ArrayLike

if TYPE_CHECKING:
    import mujoco
    from rerun.chunk import Chunk

    from twin.vision.calibration import StereoCalibration
    from twin.vision.reconstruct import Reconstruction

from twin import units
from twin.viz.blueprint import (
    CLOUD_ENTITY,
    COMPRESS_PHASE,
    CONTACT_RGB,
    DIFFERENCE_STREAM,
    EVENTS_ENTITY,
    FINGER_RGB,
    FINGERS,
    FUSED_CLOUD_ENTITY,
    FUSED_MESH_ENTITY,
    FUSED_RGB,
    HAND_ENTITY,
    LOG_ENTITY,
    MESH_ENTITY,
    POINT_ERROR_COLORMAP,
    POINT_ERROR_COLORMAP_FROM,
    POINT_ERROR_SCALE_MM,
    RECTIFIED_ENTITY,
    SERIES_STYLE,
    STEREO_ENTITY,
    TACTILE_ENTITY,
    TACTILE_POINTS_ENTITY,
    TIMELINE,
    RunKind,
    finger_colors,
    finger_of,
    plotted_paths,
    run_blueprint,
    series_of,
)

__all__ = [
    "CLOUD_ENTITY",
    "FUSED_CLOUD_ENTITY",
    "FUSED_MESH_ENTITY",
    "HAND_ENTITY",
    "LOG_ENTITY",
    "MESH_ENTITY",
    "RECTIFIED_ENTITY",
    "STEREO_ENTITY",
    "TACTILE_ENTITY",
    "TACTILE_POINTS_ENTITY",
    "TIMELINE",
    "RunKind",
    "RunRecording",
]
FOAM_RGB = (240, 190, 100)  # pale yellow-orange
CONTACTS_ENTITY = "world/contacts"
PRESSURE_SCALES_KPA = (10.0, 20.0, 50.0, 100.0, 150.0, 200.0, 300.0, 500.0)
"""The tactile colour scale's top: the smallest of these above the 80th percentile of the loaded taxels'
pressures (> 1 kPa) of any scan so far, so that the 7-13 N a pad carries in a squeeze spreads over the
colours (a 6 s compress run: 50 kPa; its peaks, up to ~250 kPa on a few taxels, show as the top colour
and read exactly on hover). A fixed 150 kPa left nearly every cell dark."""
PRESSURE_SCALE_PERCENTILE = 80.0
PRESSURE_COLORMAP = rr.components.Colormap.Viridis
CONTACT_ARROW_M_PER_N = 0.004
CAMERA_SIDES = ("left", "right")
HAND_POSE_RATE_HZ = 30.0
"""How often a hardware run's hand model is posed from its readings: the sim scene's rate (twin.rig)."""
CONTOUR_RGB = {"predicted": (230, 60, 200), "measured": (40, 220, 90)}
"""The shape network's contour in magenta, the camera's in green."""
JPEG_QUALITY = 80
"""Camera images are logged JPEG-compressed: ~11 kB a 320x240 view of the lateral pair instead of
230 kB raw, 1.9 grey levels from the frame on average (85: 13.7 kB and 1.2 levels; the cameras' own
noise is 2)."""
DEPTH_MM_PER_UNIT = 0.1
"""Depth images are uint16 in units of 0.1 mm (0 = no depth), good to 6.5 m, logged PNG-compressed."""
CAMERA_PLANE_M = 0.05
"""Where the viewer draws each camera's image plane, in front of its centre."""
IMAGE_PERIOD_S = 0.1
"""Camera images and the depth go to the .rrd at 10 fps (every third frame of the 30 fps pair): from
the paper's lateral view a JPEG is ~11 kB, and at 15 fps they were a third of a camera run's
recording. Every frame stays in the run's stereo stream (left_jpeg, right_jpeg)."""
PERIOD_SLACK_S = 0.01
"""Frame times sit on the simulator's step grid (2 ms): two frames of a 30 fps pair may be 66 ms apart."""
SURFACE_PERIOD_S = 0.2
"""The stereo reconstruction's cloud (and mesh, if it has one) goes to the .rrd at 5 Hz: 10 updates per
cycle of the 0.5 Hz squeeze. Every frame's clouds and meshes stay in the run's stereo stream."""
FUSED_PERIOD_S = 0.5
"""The fused cloud and mesh go to the .rrd at 2 Hz: in the compress phase of a sim camera run the fused
surface moves 0.30 mm (median nearest-point distance) in 0.5 s and 0.21 mm in 0.2 s, no more than the
reconstruction's own median error against the truth (0.30 mm), so faster updates mostly redraw its
noise; at 5 Hz the fused mesh was a third of a camera run's recording (benchmarks/recording_size.py)."""
MAX_EDGE_FACTOR = 4.0
"""A triangle whose longest edge exceeds this many times the mesh's median edge joins points that are
not neighbours on the surface (a finger's edge behind the foam): it is not drawn."""
TACTILE_POINTS_RGB = CONTACT_RGB
OTHER_PLOTS_VIEW = "other series"
_WINDOWED = ("/plots/hand/position_counts", "/plots/command/position_counts")
"""The entities of the compression window, whose range over the compress phase is kept."""
_UNPAIRED_KEPT = 64
"""Halves of a difference kept waiting for their other half (2 s at 30 Hz): the rig delivers a
reading's truth and its sensors' estimate within a latency of each other."""
# mjtGeom values (stable across MuJoCo 3.x): plane 0, hfield 1, sphere 2, capsule 3, ellipsoid 4,
# cylinder 5, box 6, mesh 7, sdf 8. Height fields and SDFs are not drawn.
_PLANE, _SPHERE, _CAPSULE, _ELLIPSOID, _CYLINDER, _BOX, _MESH = 0, 2, 3, 4, 5, 6, 7
_DEFAULT_RGBA = np.array([0.5, 0.5, 0.5, 1.0], dtype=np.float32)  # MuJoCo's geom rgba default
_SCALARS = rr.Scalars.descriptor_scalars().component
# Entity path parts that Rerun takes verbatim (anything else it escapes or drops, with a warning).
_UNSAFE = re.compile(r"[^\w.\-]")


ROWS_PER_SEND = 60
"""Rows of time-varying entities sent to Rerun together, with one send_columns call an entity (2 s of a
30 Hz stream): a log call a row made Rerun cost half the physics of a run (issue 19). A killed process
loses what is still pending (at most this many rows an entity) from the .rrd; close() sends it all."""

Columns = tuple[str, type, dict[str, np.ndarray], list[int]]
"""What one send_columns call takes: entity path, archetype, its components (instances of all the rows
concatenated) and the number of instances in each row."""


class _Pending:
    """Rows waiting to be sent as columns: their times (ns) and, per value, one array a row whose first
    axis is the row's instances. `split` turns the concatenated values and the rows' lengths into the
    columns of one or more entities (e.g. taxel pressures into the colours of every pad), once for all
    the rows."""

    def __init__(self, split: Callable[[dict[str, np.ndarray], list[int]], list[Columns]]) -> None:
        self.split = split
        self.rows: list[tuple[int, Mapping[str, np.ndarray]]] = []

    def add(self, t_ns: int, values: Mapping[str, np.ndarray]) -> int:
        """Keep one row (its arrays are kept as given: pass copies); the rows now pending. One append, so
        a Ctrl-C landing here never leaves a row with some of its values (a ragged column Rerun refuses)."""
        self.rows.append((t_ns, dict(values)))
        return len(self.rows)

    def send(self, rec: rr.RecordingStream) -> None:
        """Send every pending row, one send_columns call an entity, and forget them."""
        rows, self.rows = self.rows, []
        if not rows:
            return
        lengths = [len(next(iter(values.values()))) for _, values in rows]
        stacked = {name: np.concatenate([values[name] for _, values in rows]) for name in rows[0][1]}
        t_ns = np.array([t for t, _ in rows], dtype=np.int64).astype("timedelta64[ns]")
        times = rr.TimeColumn(TIMELINE, duration=t_ns)
        for path, archetype, components, row_lengths in self.split(stacked, lengths):
            columns = archetype.columns(**components).partition(row_lengths)
            rec.send_columns(path, indexes=[times], columns=columns)


def _as_is(path: str, archetype: type) -> Callable[[dict, list[int]], list[Columns]]:
    """Pending rows of one entity, sent as they were kept."""
    return lambda stacked, lengths: [(path, archetype, stacked, lengths)]


def _mesh(path: str, faces: np.ndarray) -> Callable[[dict, list[int]], list[Columns]]:
    """Pending mesh rows (vertex positions) with their vertex normals, all rows in one pass."""

    def split(stacked: dict, lengths: list[int]) -> list[Columns]:
        verts = stacked["vertex_positions"]
        normals = _vertex_normals(verts.reshape(len(lengths), -1, 3), faces).reshape(-1, 3)
        return [(path, rr.Mesh3D, {"vertex_positions": verts, "vertex_normals": normals}, lengths)]

    return split


def _bodies(paths: list[str]) -> Callable[[dict, list[int]], list[Columns]]:
    """Pending poses of every moving body (one row: all of them) as each body's Transform3D rows."""

    def split(stacked: dict, lengths: list[int]) -> list[Columns]:
        rows = len(lengths)
        xyz = stacked["translation"].reshape(rows, len(paths), 3)
        quat = stacked["quaternion"].reshape(rows, len(paths), 4)
        return [
            (path, rr.Transform3D, {"translation": xyz[:, j], "quaternion": quat[:, j]}, [1] * rows)
            for j, path in enumerate(paths)
        ]

    return split


@dataclass(frozen=True)
class _PadImage:
    """Where one pad's taxels go in its tactile image (one pixel a cell) and where the image sits on the
    2-D canvas (mm)."""

    path: str
    ids: np.ndarray
    pixel: tuple[np.ndarray, np.ndarray]
    shape: tuple[int, int]
    corner_mm: tuple[float, float]
    pitch_mm: float


def _pad_images() -> list[_PadImage]:
    """The pads' images, laid out as twin.tactile.layout.canvas_mm places their cells."""
    from twin.tactile.layout import LAYOUT, canvas_mm

    centers, _ = canvas_mm()
    out = []
    for k, pad in enumerate(LAYOUT.pads):
        ids = np.flatnonzero(LAYOUT.pad_index == k)
        c = centers[ids]
        pitch = pad.pitch_m * 1e3
        lo = c.min(axis=0)
        col, row = np.rint((c - lo) / pitch).astype(int).T
        shape = (int(row.max()) + 1, int(col.max()) + 1)
        corner = (float(lo[0] - pitch / 2), float(lo[1] - pitch / 2))
        out.append(_PadImage(f"{TACTILE_ENTITY}/{pad.name}", ids, (row, col), shape, corner, pitch))
    return out


TACTILE_KPA_PER_UNIT = 0.1
"""The pads' images are uint16 in units of 0.1 kPa (meter = 10: the viewer's hover reads kPa)."""
COLOUR_BAR_ROWS = 64
COLOUR_BAR_WIDTH_MM = 6.0
"""The tactile colour bar: an image of this many rows (top: the scale's top) this wide on the canvas."""


def _pad_pixels(pad: _PadImage, pressure_kpa: np.ndarray) -> np.ndarray:
    """(rows, h*w*2) bytes of a pad's uint16 image (TACTILE_KPA_PER_UNIT; 0 where it has no cell) for
    (rows, 162) pressures (kPa)."""
    rows = len(pressure_kpa)
    image = np.zeros((rows, *pad.shape), dtype=np.uint16)
    units = np.clip(np.rint(pressure_kpa[:, pad.ids] / TACTILE_KPA_PER_UNIT), 0, 65535)
    image[:, pad.pixel[0], pad.pixel[1]] = units
    return image.reshape(rows, -1).view(np.uint8)


def _image_format(pad: _PadImage) -> rr.components.ImageFormat:
    return rr.components.ImageFormat(width=pad.shape[1], height=pad.shape[0], channel_datatype="U16")


def _taxels(
    pads: list[_PadImage], points: list[tuple[str, np.ndarray]], scale: Callable[[], float]
) -> Callable[[dict, list[int]], list[Columns]]:
    """Pending scans (162 pressures a row, kPa) as each pad's image (filled cells, coloured by the
    viewer) and the colours of each pad's taxels on the hand (3-D)."""

    def split(stacked: dict, lengths: list[int]) -> list[Columns]:
        rows = len(lengths)
        pressure = stacked["pressure_kpa"].reshape(rows, -1)
        out: list[Columns] = []
        for pad in pads:
            buffers = list(_pad_pixels(pad, pressure))
            out.append((pad.path, rr.DepthImage, {"buffer": buffers}, [1] * rows))  # format: static
        colors = _heat((pressure / scale()).reshape(-1)).reshape(rows, -1, 3)
        for path, ids in points:
            out.append((path, rr.Points3D, {"colors": colors[:, ids].reshape(-1, 3)}, [len(ids)] * rows))
        return out

    return split


def _pressure_scale_kpa(pressure_kpa: np.ndarray) -> float:
    """The colour scale's top for one scan's pressures (see PRESSURE_SCALES_KPA)."""
    loaded = pressure_kpa[pressure_kpa > 1.0]
    high = float(np.percentile(loaded, PRESSURE_SCALE_PERCENTILE)) if loaded.size else 0.0
    return next((s for s in PRESSURE_SCALES_KPA if s >= high), PRESSURE_SCALES_KPA[-1])


class RunRecording:
    """One Rerun recording of a run, saved to an .rrd file, with the blueprint of its kind of run.

    Time-varying entities of the 3-D scene, the pads and the plots are sent in columns of
    ROWS_PER_SEND rows; parts that do not change (a mesh's triangles and colour, the taxels' places,
    the series' names and colours) are logged once, static."""

    def __init__(
        self,
        rrd_path: Path | str,
        *,
        application_id: str = "barrett_twin",
        recording_id: str | None = None,
        kind: RunKind | None = None,
    ) -> None:
        """Open the recording and its .rrd file with the blueprint of `kind` (default: a sim compress run;
        stereo and prediction are added when they are logged)."""
        self.rrd_path = Path(rrd_path)
        self.kind = kind or RunKind()
        # Chunks of up to 2 s or 4 MB of what is logged row by row (images, clouds): fewer, larger chunks.
        batcher = rr.ChunkBatcherConfig(flush_tick=timedelta(seconds=2), flush_num_bytes=4 << 20)
        self.rec = rr.RecordingStream(application_id, recording_id=recording_id, batcher_config=batcher)
        self.rec.save(self.rrd_path)  # the blueprint follows at close, from what was logged
        self._blueprint_sent = False
        self._plotted = plotted_paths(self.kind)
        self._other_plots: list[str] = []
        self._series_named: set[str] = set()
        self._flex: list[tuple[str, int, int, int, np.ndarray]] = []
        self._bodies: list[tuple[int, str]] = []
        self._welded: list[tuple[int, str]] = []
        self._closed = False
        self._body_paths: dict[str, str] = {}
        self._depth_from_disparity: tuple[float, float, float] | None = None
        self._pending: dict[str, _Pending] = {}
        self._started: set[str] = set()
        """Entities whose first, complete row has been logged (later rows carry what changes only)."""
        self._body_ids = np.zeros(0, dtype=int)
        self._time_s: float | None = None
        """The current time (s): the rows logged now go there."""
        self._time_set: float | None = None
        """The time last given to Rerun's set_time (only logs made now, not pending rows, need it)."""
        self._t_ns = 0
        self._tactile_pads: list[tuple[str, np.ndarray]] = []
        self._pressure_scale_kpa = 0.0
        self._phase: str | None = None
        self._at_cap = np.zeros(3, dtype=bool)
        self._hand_model = None
        self._hand_posed_t_s = -np.inf
        self._observer: object | None = None
        self._last_surface_s: float | None = None
        self._last_fused_s: float | None = None
        self._last_image_s: float | None = None
        self._extremes: dict[str, tuple[float, float]] = {}
        self._compress_start_s: float | None = None
        self._window_extremes: tuple[float, float] | None = None
        self._halves: dict[str, tuple[dict[int, np.ndarray], dict[int, np.ndarray]]] = {}
        """Per difference: estimates and truths by time (ns) still waiting for their other half."""

    def _set_kind(self, **changes: object) -> None:
        """The run turned out richer (cameras, a prediction, the foam's place): re-send its blueprint."""
        kind = replace(self.kind, **changes)
        if kind != self.kind:
            self.kind = kind
            self._plotted = plotted_paths(kind)
            if self._blueprint_sent:
                self._send_blueprint()

    def _send_blueprint(self) -> None:
        """The blueprint, once, at close: it takes the y ranges and the compress phase's start from what
        was logged, and each one sent costs ~0.2 MB of the .rrd (a chunk per view part). A recording
        whose process was killed has none: `twin view` makes it from the files (kind_of_run)."""
        self._blueprint_sent = True
        blueprint = run_blueprint(self.kind)
        if self._other_plots:  # series no view of the run's kind knows: shown, not lost
            blueprint = run_blueprint(self.kind, extra=self._other_plots)
        self.rec.send_blueprint(blueprint, make_active=True, make_default=True)

    def _open(self, t_s: float | None, *, pending_only: bool = False) -> None:
        """Check the recording is open and make t_s the current time. `pending_only`: the caller only
        keeps rows pending (or calls _sync_time before logging now), so Rerun's time is set lazily."""
        if self._closed:
            raise RuntimeError(f"recording {self.rrd_path} is closed")
        if t_s is not None and float(t_s) != self._time_s:
            self._time_s = float(t_s)
            self._t_ns = round(1e9 * self._time_s)  # as Rerun's set_time rounds it
        if not pending_only:
            self._sync_time()

    def _sync_time(self) -> None:
        """Give Rerun the current time before logging a row now (set_time costs ~10 us a call)."""
        if self._time_s is not None and self._time_s != self._time_set:
            self.rec.set_time(TIMELINE, duration=self._time_s)
            self._time_set = self._time_s

    def _buffer(
        self,
        key: str,
        values: Mapping[str, np.ndarray],
        split: Callable[[], Callable[[dict, list[int]], list[Columns]]],
    ) -> None:
        """Keep one row at the current time under `key` (`split()` makes its columns, asked once); send
        the rows once ROWS_PER_SEND wait."""
        pending = self._pending.get(key)
        if pending is None:
            pending = self._pending[key] = _Pending(split())
        if pending.add(self._t_ns, values) >= ROWS_PER_SEND:
            pending.send(self.rec)

    def _first(self, path: str) -> bool:
        """True (once) when `path` has no row yet: log its complete first row."""
        if path in self._started:
            return False
        self._started.add(path)
        return True

    def log_model(self, model: mujoco.MjModel) -> None:
        """Static geometry of the visual geoms (group < 3) under their bodies; remembers flex surfaces."""
        self._open(None)
        self._bodies, self._welded, self._flex = [], [], []
        bodies = _unique([_name(model, "body", b) for b in range(model.nbody)])
        geoms = [_name(model, "geom", g) for g in range(model.ngeom)]
        drawn: set[int] = set()
        used: set[str] = set()
        for g in range(model.ngeom):
            body = int(model.geom_bodyid[g])
            rgba = _geom_rgba(model, g)
            if model.geom_group[g] >= 3 or model.geom_type[g] == _PLANE or rgba[3] == 0:
                continue
            color = (rgba * 255).round().astype(np.uint8)
            finger = finger_of(bodies[body])
            if finger is not None:  # a finger's links in its fixed colour, as in every plot
                color[:3] = FINGER_RGB[finger]
            shape = _geom_archetype(model, g, color)
            if shape is None:
                continue
            path = f"world/bodies/{bodies[body]}/{geoms[g]}"
            if path in used:
                path = f"{path}_{g}"
            used.add(path)
            pos, quat = model.geom_pos[g], model.geom_quat[g]
            self.rec.log(path, rr.Transform3D(translation=pos, quaternion=_xyzw(quat)), shape, static=True)
            drawn.add(body)
        # Only bodies that draw something are posed (the world body is the identity); bodies welded
        # to the world are posed once (MuJoCo gives a mocap body a weld root of its own).
        for b in sorted(drawn - {0}):
            fixed = model.body_weldid[b] == 0
            (self._welded if fixed else self._bodies).append((b, f"world/bodies/{bodies[b]}"))
            self._body_paths[bodies[b]] = f"world/bodies/{bodies[b]}"
        self._body_ids = np.array([b for b, _ in self._bodies], dtype=int)
        if model.nflex:  # frame the 3-D view on the foam where the model puts it (its place at rest)
            import mujoco

            rest = mujoco.MjData(model)
            mujoco.mj_forward(model, rest)
            if rest.flexvert_xpos.size:
                f = next((i for i in range(model.nflex) if _name(model, "flex", i) == "foam"), 0)
                adr, num = int(model.flex_vertadr[f]), int(model.flex_vertnum[f])
                centre = rest.flexvert_xpos[adr : adr + num].mean(axis=0)
                self._set_kind(eye_target_m=tuple(float(x) for x in centre))
        for f, name in enumerate(_unique([_name(model, "flex", f) for f in range(model.nflex)])):
            self._flex.append(
                (
                    f"world/flex/{name}",
                    int(model.flex_vertadr[f]),
                    int(model.flex_vertnum[f]),
                    int(model.flex_dim[f]),
                    _flex_surface(model, f),
                )
            )

    def log_hand_model(self) -> None:
        """A run without a simulated scene (hardware): the hand's own model (bh8.xml), posed from each
        hand reading by the kinematics the vision uses (twin.kinematics: link angles through the
        clutch observer), so the 3-D view shows the hand as the encoders and gauges place it."""
        from twin.kinematics import HandKinematics

        self._hand_model = HandKinematics()
        self.log_model(self._hand_model.model)

    def log_scene(self, t_s: float, data: mujoco.MjData) -> None:
        """Body world poses and the flex meshes (positions, normals) at sim time t_s."""
        self._open(t_s, pending_only=True)
        for b, path in self._welded:
            self.rec.log(path, _pose(data, b), static=True)
        self._welded = []
        if self._bodies:
            values = {
                "translation": data.xpos[self._body_ids],  # fancy indexing: copies, as pending rows must be
                "quaternion": data.xquat[self._body_ids][:, [1, 2, 3, 0]],  # MuJoCo's wxyz, Rerun's xyzw
            }
            self._buffer("world/bodies", values, lambda: _bodies([path for _, path in self._bodies]))
        for path, adr, num, dim, faces in self._flex:
            verts = np.array(data.flexvert_xpos[adr : adr + num], dtype=np.float32)
            if dim == 1:  # a cable: its edges
                self._sync_time()
                self.rec.log(path, rr.LineStrips3D(verts[faces], colors=[FOAM_RGB]))
            elif self._first(path):
                # triangles and colour once, static; the vertices (and normals) every frame
                mesh = rr.Mesh3D.from_fields(triangle_indices=faces, albedo_factor=[*FOAM_RGB, 255])
                self.rec.log(path, mesh, static=True)
                self._buffer(path, {"vertex_positions": verts}, lambda p=path, f=faces: _mesh(p, f))
            else:
                self._buffer(path, {"vertex_positions": verts}, lambda p=path, f=faces: _mesh(p, f))

    def log_tactile(self, t_s: float, pressure_kpa: ArrayLike, pad_force_n: ArrayLike) -> None:
        """Pads as images of filled cells in their layout (2-D, kPa on hover, viridis over a scale that
        follows the run's pressures), taxels coloured on the hand (3-D), eq. 6 forces (and the
        fingertips' beside the simulator's true contact force)."""
        from twin.tactile.layout import LAYOUT

        self._open(t_s, pending_only=True)
        pressure = np.array(pressure_kpa, dtype=float)  # a copy: the row may wait to be sent
        if self._first(TACTILE_ENTITY):  # layout, names and the taxels' places once, static
            self._pad_images = _pad_images()
            where, labels, colors = _pad_labels(self._pad_images)
            self.rec.log(
                f"{TACTILE_ENTITY}/names",
                rr.Points2D(where, labels=labels, radii=0.1, colors=colors, show_labels=True),
                static=True,
            )
            for pad in self._pad_images:
                self.rec.log(
                    pad.path,
                    rr.Transform3D(
                        translation=[*pad.corner_mm, 0.0], scale=[pad.pitch_mm, pad.pitch_mm, 1.0]
                    ),
                    rr.DepthImage.from_fields(
                        format=_image_format(pad),
                        meter=1.0 / TACTILE_KPA_PER_UNIT,
                        colormap=PRESSURE_COLORMAP,
                        magnification_filter="Nearest",
                    ),
                    static=True,
                )
            for pad_index, pad in enumerate(LAYOUT.pads):
                body_path = self._body_paths.get(pad.body)
                if body_path is None:
                    continue
                ids = np.flatnonzero(LAYOUT.pad_index == pad_index)
                path = f"{body_path}/taxels_{pad.name}"
                self._tactile_pads.append((path, ids))
                self.rec.log(path, rr.Points3D(LAYOUT.position_m[ids], radii=pad.pitch_m * 0.4), static=True)
        scale = max(self._pressure_scale_kpa, _pressure_scale_kpa(pressure))
        if scale > self._pressure_scale_kpa:
            self._set_pressure_scale(t_s, scale)
        self._buffer(
            TACTILE_ENTITY,
            {"pressure_kpa": pressure[None]},
            lambda: _taxels(self._pad_images, self._tactile_pads, lambda: self._pressure_scale_kpa),
        )
        forces = np.asarray(pad_force_n, dtype=float)
        tips = [LAYOUT.pad_names.index(f"f{k}_tip") for k in (1, 2, 3)]
        self.log_scalars(
            "tactile",
            t_s,
            {"pad_force_n": forces, "tip_force_n": forces[tips]},
            labels={"pad_force_n": LAYOUT.pad_names},
        )
        if self.kind.sim:
            self._difference("tip_force_n", t_s, forces[tips], None)

    def _set_pressure_scale(self, t_s: float, scale_kpa: float) -> None:
        """The tactile colour scale's top (kPa): on every pad (static: one scale for the whole run, the
        largest it needed), written on the canvas and in the log."""
        self._pressure_scale_kpa = scale_kpa
        for pad in self._pad_images:
            self.rec.log(
                pad.path,
                rr.DepthImage.from_fields(depth_range=[0.0, scale_kpa / TACTILE_KPA_PER_UNIT]),
                static=True,
            )
        self._log_colour_bar(scale_kpa)
        self.log_text(t_s, f"tactile colour scale: 0-{scale_kpa:g} kPa")

    def _log_colour_bar(self, scale_kpa: float) -> None:
        """A colour bar right of the pads: the pads' colour map over 0..scale_kpa as an image of its own
        (same format, meter and range as theirs), ticks at 0, half and full scale."""
        x0, y0, y1 = _colour_bar_place(self._pad_images)
        rows = COLOUR_BAR_ROWS
        units = np.linspace(scale_kpa / TACTILE_KPA_PER_UNIT, 0.0, rows).round().astype(np.uint16)
        bar = f"{TACTILE_ENTITY}/colour_bar"
        self.rec.log(
            bar,
            rr.Transform3D(translation=[x0, y0, 0.0], scale=[COLOUR_BAR_WIDTH_MM, (y1 - y0) / rows, 1.0]),
            rr.DepthImage(
                units[:, None],
                meter=1.0 / TACTILE_KPA_PER_UNIT,
                colormap=PRESSURE_COLORMAP,
                depth_range=[0.0, scale_kpa / TACTILE_KPA_PER_UNIT],
                magnification_filter="Nearest",
            ),
            static=True,
        )
        ticks = [(y1, "0"), ((y0 + y1) / 2, f"{scale_kpa / 2:g}"), (y0, f"{scale_kpa:g} kPa")]
        self.rec.log(
            f"{TACTILE_ENTITY}/scale",
            rr.Points2D(
                [[x0 + COLOUR_BAR_WIDTH_MM + 4.0, y] for y, _ in ticks],
                labels=[text for _, text in ticks],
                radii=0.1,
                show_labels=True,
            ),
            static=True,
        )

    def log_hand(
        self,
        t_s: float,
        position_counts: ArrayLike,
        strain_counts: ArrayLike,
        physical: Mapping[str, ArrayLike],
    ) -> None:
        """One hand reading: measured position (counts), velocity (rad/s), torque (N m), force (kg) of
        F1-F3, and in sim runs the clutch observer's joint angles (to set beside the truth)."""
        from twin.interface.devices import FINGER_LABELS

        counts = np.asarray(position_counts, dtype=float)
        values = {
            "position_counts": counts[:3],
            "velocity_rad_s": np.asarray(physical["velocity_rad_s"], dtype=float)[:3],
            "torque_nm": physical["torque_nm"],
            "force_kg": physical["force_kg"],
        }
        self.log_scalars("hand", t_s, values, labels=dict.fromkeys(values, FINGER_LABELS))
        cap_kg = self.kind.force_cap_kg
        self.log_scalars("hand", t_s, {"force_cap_kg": cap_kg})
        at_cap = np.asarray(physical["force_kg"], dtype=float)[:3] >= cap_kg
        for k in np.flatnonzero(at_cap != self._at_cap):
            finger = FINGER_LABELS[k]
            text = (
                f"{finger} at the {cap_kg:g} kg fingertip-force cap: the safety layer "
                "lets it hold or open, not close further"
            )
            cap = f"at the {cap_kg:g} kg cap"
            self.log_event(
                t_s, f"{finger}_force_cap", cap if at_cap[k] else None, text if at_cap[k] else None
            )
        self._at_cap = at_cap
        if self.kind.sim or self._hand_model is not None:
            from twin.kinematics import ClutchObserver

            if self._observer is None:
                self._observer = ClutchObserver()
            links = self._observer.update(counts, strain_counts)
        if self.kind.sim:
            self.log_scalars("observer", t_s, {"inner_rad": links[:, 0], "outer_rad": links[:, 1]})
            self._difference("inner_rad", t_s, links[:, 0], None)
            self._difference("outer_rad", t_s, links[:, 1], None)
        if self._hand_model is not None and t_s - self._hand_posed_t_s >= 0.999 / HAND_POSE_RATE_HZ:
            self._hand_posed_t_s = t_s
            self._hand_model.set_angles(links, float(units.spread_counts_to_rad(counts[3])))
            self.log_scene(t_s, self._hand_model.data)

    def log_command(self, t_s: float, position_counts: ArrayLike, phase: str) -> None:
        """A command as applied (F1-F3 set points, counts); a change of the procedure's phase goes to
        the log."""
        self.log_scalars("command", t_s, {"position_counts": np.asarray(position_counts, dtype=float)[:3]})
        if phase != self._phase:
            self._phase = phase
            if phase == COMPRESS_PHASE and self._compress_start_s is None:
                self._compress_start_s = float(t_s)
            self.log_event(t_s, "phase", phase, f"phase: {phase}", level="INFO")

    def log_truth(self, t_s: float, truth: Mapping[str, ArrayLike]) -> None:
        """What only the simulator knows, beside what the sensors say: the fingertips' true contact
        force (N) and the true inner and outer joint angles (rad)."""
        keep = ("tip_contact_force_n", "inner_rad", "outer_rad")
        self.log_scalars("truth", t_s, {k: truth[k] for k in keep if k in truth})
        if "tip_contact_force_n" in truth:
            self._difference("tip_force_n", t_s, None, truth["tip_contact_force_n"])
        for joint in ("inner_rad", "outer_rad"):
            if joint in truth:
                self._difference(joint, t_s, None, truth[joint])

    def log_contacts(self, t_s: float, points_m: ArrayLike, forces_n: ArrayLike) -> None:
        """Contact points and their normal forces as arrows in the 3-D scene (pointing into the pad)."""
        self._open(t_s, pending_only=True)
        points = np.asarray(points_m, dtype=float).reshape(-1, 3)
        vectors = np.asarray(forces_n, dtype=float).reshape(-1, 3) * CONTACT_ARROW_M_PER_N
        if self._first(CONTACTS_ENTITY):
            self._sync_time()
            arrows = rr.Arrows3D(origins=points - vectors, vectors=vectors, colors=[CONTACT_RGB])
            self.rec.log(CONTACTS_ENTITY, arrows)
        else:
            values = {"origins": points - vectors, "vectors": vectors}
            self._buffer(CONTACTS_ENTITY, values, lambda: _as_is(CONTACTS_ENTITY, rr.Arrows3D))

    def log_scalars(
        self,
        stream: str,
        t_s: float,
        values: Mapping[str, ArrayLike],
        labels: Mapping[str, Sequence[str]] | None = None,
    ) -> None:
        """One time-series row: entity plots/<stream>/<field>, one series per element of an array field.

        labels[field] names the series of a field (set once, statically); its length must match. The
        series of the blueprint's plots get their fixed names and colours (twin.viz.blueprint), others
        their labels and each finger's colour; an entity no view names gets an "other series" view.
        """
        self._open(t_s, pending_only=True)
        for field, value in values.items():
            path = f"plots/{stream}/{field}"
            arr = np.array(value, dtype=np.float64, ndmin=1)  # a copy: the row may wait to be sent
            if arr.ndim != 1:
                raise ValueError(f"{path}: a time series takes a scalar or a 1-D array, got {arr.shape}")
            if path not in self._series_named:
                self._name_series(path, field, arr.size, labels)
            self._note_extremes(f"/{path}", t_s, arr)
            self._buffer(path, {"scalars": arr}, lambda p=path: _as_is(p, rr.Scalars))

    def _note_extremes(self, path: str, t_s: float, values: np.ndarray) -> None:
        """Keep each plotted entity's smallest and largest value (the y ranges of the closing blueprint),
        and the positions' and commands' over the compress phase (its window's)."""
        finite = values[np.isfinite(values)]
        if not finite.size:
            return
        low, high = float(finite.min()), float(finite.max())
        old = self._extremes.get(path)
        self._extremes[path] = (low, high) if old is None else (min(old[0], low), max(old[1], high))
        if path in _WINDOWED and self._compress_start_s is not None and t_s >= self._compress_start_s:
            w = self._window_extremes
            self._window_extremes = (low, high) if w is None else (min(w[0], low), max(w[1], high))

    def _difference(
        self, field: str, t_s: float, estimate: ArrayLike | None, truth: ArrayLike | None
    ) -> None:
        """plots/difference/<field>: an estimate minus the truth, at an instant both were logged at (each
        half waits, a few rows at most, for the other; instants that never meet give no difference)."""
        key = round(1e9 * t_s)
        halves = self._halves.setdefault(field, ({}, {}))
        side = 0 if estimate is not None else 1
        value = np.array(estimate if estimate is not None else truth, dtype=float)  # a copy: it may wait
        other = halves[1 - side].pop(key, None)
        if other is None:
            mine = halves[side]
            mine[key] = value
            while len(mine) > _UNPAIRED_KEPT:
                mine.pop(next(iter(mine)))
            return
        diff = value - other if side == 0 else other - value
        self.log_scalars(DIFFERENCE_STREAM, t_s, {field: diff})

    def _name_series(
        self, path: str, field: str, size: int, labels: Mapping[str, Sequence[str]] | None
    ) -> None:
        """Names and colours of an entity's series, logged once (static), and its place in a view."""
        if labels and field in labels:
            names = [str(n) for n in labels[field]]
            if len(names) != size:
                raise ValueError(f"{path}: {len(names)} labels for {size} values")
        self._series_named.add(path)
        style = SERIES_STYLE.get(f"/{path}")
        if style is not None and len(style[0]) == size:
            self.rec.log(path, series_of(f"/{path}"), static=True)
        elif labels and field in labels:
            self.rec.log(path, rr.SeriesLines(names=names, colors=finger_colors(names)), static=True)
        if f"/{path}" not in self._plotted and f"/{path}" not in self._other_plots:
            self._other_plots.append(f"/{path}")

    def log_event(
        self, t_s: float, lane: str, state: str | None, text: str | None = None, level: str = "WARN"
    ) -> None:
        """A state on the lane events/<lane> from t_s on (None clears it: the lane's bar ends), and a
        row in the text log when `text` is given: the phases, the force cap, a clipped or refused
        command, a recovered hand cycle, a hand loop behind its schedule, lost pad frames (twin.rig)."""
        self._open(t_s)
        change = rr.StateChange(state=state) if state is not None else rr.StateChange.cleared()
        self.rec.log(f"{EVENTS_ENTITY}/{lane}", change)
        if text:
            self.log_text(t_s, text, level=level)

    def log_text(self, t_s: float, text: str, level: str = "INFO") -> None:
        """A line in the run's text log (entity "log")."""
        self._open(t_s)
        self.rec.log(LOG_ENTITY, rr.TextLog(text, level=level))

    def log_stereo_setup(
        self, calibration: StereoCalibration, hand_from_world: ArrayLike | None = None
    ) -> None:
        """The stereo pair, statically: the hand frame, both cameras and the rectified left camera.

        `hand_from_world` is the palm body's world pose (4x4; on the sim it is fixed: the hand is
        mounted), so that whatever is logged in the hand frame sits on the hand model; None logs the hand
        frame at the world origin (a real rig without a 3-D scene). Entities: HAND_ENTITY (that pose),
        STEREO_ENTITY/left and /right (Transform3D hand_from_camera + Pinhole, OpenCV axes) and
        RECTIFIED_ENTITY (the rectified left camera, whose depth image log_stereo fills).
        """
        from twin.vision.reconstruct import Rectifier

        if self.kind.sim:  # matplotlib's colour maps loaded now, not mid-run where a Ctrl-C could land in
            error_colors([0.0])  # its C extension's import (a crash at exit, seen on a loaded host)
        self._open(None)
        pose = np.eye(4) if hand_from_world is None else np.asarray(hand_from_world, dtype=np.float64)
        if pose.shape != (4, 4):
            raise ValueError(f"hand_from_world must be a 4x4 pose, got shape {pose.shape}")
        self.rec.log(HAND_ENTITY, _transform(pose), static=True)
        right_from_left = np.eye(4)
        right_from_left[:3, :3] = calibration.rotation
        right_from_left[:3, 3] = np.ravel(calibration.translation_m)
        hand_from_right = calibration.hand_from_left @ np.linalg.inv(right_from_left)
        for side, cam, hand_from_cam in (
            ("left", calibration.left, calibration.hand_from_left),
            ("right", calibration.right, hand_from_right),
        ):
            self.rec.log(
                f"{STEREO_ENTITY}/{side}",
                _transform(hand_from_cam),
                _pinhole(cam.matrix, cam.image_size),
                static=True,
            )
        rectifier = Rectifier(calibration)
        self.rec.log(
            RECTIFIED_ENTITY,
            _transform(rectifier.hand_from_rectified),
            _pinhole(rectifier.P1[:3, :3], rectifier.image_size),
            static=True,
        )
        q = rectifier.Q  # Z = Q[2,3] / (Q[3,2] d + Q[3,3]) in the rectified left frame
        self._depth_from_disparity = (float(q[2, 3]), float(q[3, 2]), float(q[3, 3]))
        self._set_kind(stereo=True)

    def log_stereo(
        self,
        t_s: float,
        left: np.ndarray,
        right: np.ndarray,
        reconstruction: Reconstruction | None = None,
        fused_points_hand: ArrayLike | None = None,
        fused_triangles: ArrayLike | None = None,
        tactile_points_hand: ArrayLike | None = None,
        *,
        jpeg_quality: int | None = JPEG_QUALITY,
        cloud_stride: int = 1,
        point_error_mm: ArrayLike | None = None,
    ) -> None:
        """One stereo frame at sim time t_s: both images, and what the vision made of them.

        `point_error_mm` (sim runs: each reconstructed point's distance to the true surface) colours the
        stereo points by their error (POINT_ERROR_SCALE_MM) instead of the image's colours.

        `cloud_stride`: log the coloured points of every n-th pixel row and column only (n^2 fewer;
        the largest part of a stereo frame in the .rrd).

        Images (RGB uint8) go under their pinholes, JPEG-compressed (`jpeg_quality` None: raw). With a
        reconstruction: its disparity as a depth image of the rectified left camera (uint16,
        DEPTH_MM_PER_UNIT, only where the object's mask holds a match; needs log_stereo_setup), its
        coloured points (CLOUD_ENTITY) and its mesh (MESH_ENTITY, the vertices it uses only). The fused
        cloud and mesh and the tactile contact points, hand frame, when given. Nothing is logged for
        what is not given, so a viewer keeps showing the last one.
        """
        self._open(t_s)
        if self._last_image_s is None or t_s - self._last_image_s >= IMAGE_PERIOD_S - PERIOD_SLACK_S:
            self._last_image_s = float(t_s)
            for side, image in (("left", left), ("right", right)):
                self.rec.log(f"{STEREO_ENTITY}/{side}/image", _image(image, jpeg_quality))
            if reconstruction is not None and self._depth_from_disparity is not None:
                r = reconstruction  # the depth with the images it came from
                depth = _depth_units(r.disparity, r.mask, *self._depth_from_disparity)
                self.rec.log(f"{RECTIFIED_ENTITY}/depth", _png_depth(depth))
        if tactile_points_hand is not None:
            tactile = np.asarray(tactile_points_hand, dtype=np.float32).reshape(-1, 3)
            self.rec.log(
                TACTILE_POINTS_ENTITY, rr.Points3D(tactile, colors=[TACTILE_POINTS_RGB], radii=0.0015)
            )
        self._log_fused(t_s, fused_points_hand, fused_triangles)
        if (
            self._last_surface_s is not None
            and t_s - self._last_surface_s < SURFACE_PERIOD_S - PERIOD_SLACK_S
        ):
            return  # the 3-D surfaces at SURFACE_PERIOD_S only (the run's stereo stream keeps them all)
        self._last_surface_s = float(t_s)
        if reconstruction is not None:
            r = reconstruction
            points = np.asarray(r.points_hand, dtype=np.float32).reshape(-1, 3)
            colors = np.asarray(r.colors, dtype=np.uint8).reshape(-1, 3)
            pixels = np.asarray(r.pixels).reshape(-1, 2)
            on_grid = ((pixels % cloud_stride) == 0).all(axis=1)  # the depth image keeps every point
            if point_error_mm is not None:
                errors = np.asarray(point_error_mm, dtype=float).reshape(-1)
                if len(errors) == len(points):
                    colors = error_colors(errors)
            self.rec.log(CLOUD_ENTITY, rr.Points3D(points[on_grid], colors=colors[on_grid], radii=0.0006))
            used, faces = _compact_mesh(_short_triangles(points, np.asarray(r.triangles).reshape(-1, 3)))
            if len(faces):  # the per-frame pipeline meshes only the fused cloud: no empty mesh each frame
                self.rec.log(
                    MESH_ENTITY,
                    rr.Mesh3D(
                        vertex_positions=points[used], triangle_indices=faces, vertex_colors=colors[used]
                    ),
                )

    def _log_fused(
        self, t_s: float, fused_points_hand: ArrayLike | None, fused_triangles: ArrayLike | None
    ) -> None:
        """The fused cloud and mesh (hand frame) at FUSED_PERIOD_S."""
        if fused_points_hand is not None and (
            self._last_fused_s is None or t_s - self._last_fused_s >= FUSED_PERIOD_S - PERIOD_SLACK_S
        ):
            self._last_fused_s = float(t_s)
            fused = np.asarray(fused_points_hand, dtype=np.float32).reshape(-1, 3)
            self.rec.log(FUSED_CLOUD_ENTITY, rr.Points3D(fused, colors=[FUSED_RGB], radii=0.0006))
            if fused_triangles is not None:
                used, faces = _compact_mesh(
                    _short_triangles(fused, np.asarray(fused_triangles).reshape(-1, 3))
                )
                verts = fused[used]
                self.rec.log(
                    FUSED_MESH_ENTITY,
                    rr.Mesh3D(
                        vertex_positions=verts,
                        triangle_indices=faces,
                        vertex_normals=_vertex_normals(verts, faces) if len(faces) else None,
                        albedo_factor=[*FUSED_RGB, 255],
                    ),
                )

    def log_contour(self, t_s: float, kind: str, contour_px: ArrayLike) -> None:
        """A contour ("predicted" or "measured") as a closed line over the rectified left camera's image
        space (where the depth image lives), so both show together on the camera's 2-D view."""
        self._open(t_s)
        if kind == "predicted":
            self._set_kind(predict=True)
        pts = np.asarray(contour_px, dtype=np.float32).reshape(-1, 2)
        strip = np.vstack([pts, pts[:1]])
        self.rec.log(
            f"{RECTIFIED_ENTITY}/contour/{kind}", rr.LineStrips2D([strip], colors=[CONTOUR_RGB[kind]])
        )

    def close(self) -> None:
        """Flush and finish the .rrd; safe to call twice."""
        if not self._closed:
            self._set_kind(  # the closing blueprint: y ranges from what was logged
                y_ranges=tuple((path, lo, hi) for path, (lo, hi) in sorted(self._extremes.items())),
                compress_start_s=self._compress_start_s,
                window_y_range=self._window_extremes,
            )
            if not self._blueprint_sent:
                self._send_blueprint()
            self._closed = True
            try:
                for pending in self._pending.values():
                    pending.send(self.rec)
            finally:
                self.rec.flush()
                self.rec.disconnect()

    def __enter__(self) -> RunRecording:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


_HEAT_STOPS = np.array([[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]], float)
"""Viridis at 0, 1/4, 1/2, 3/4 and 1: the taxels on the hand (3-D) in the pads' (2-D) colour map."""


def _heat(x: ArrayLike) -> np.ndarray:
    """Colours of values in [0, 1] on viridis, linearly between its stops (out-of-range values clipped)."""
    x = np.clip(np.nan_to_num(np.asarray(x, dtype=float)), 0.0, 1.0) * (len(_HEAT_STOPS) - 1)
    lo = np.minimum(x.astype(int), len(_HEAT_STOPS) - 2)
    frac = (x - lo)[:, None]
    return ((1 - frac) * _HEAT_STOPS[lo] + frac * _HEAT_STOPS[lo + 1]).astype(np.uint8)


def _pad_labels(pads: list[_PadImage]) -> tuple[np.ndarray, list[str], list[tuple[int, int, int]]]:
    """Where the canvas's labels go (mm), their text and colours: each finger's name once over its
    column (its colour), the rows' names ("tip", "inner") left of them and "palm" left of the palm. Six
    full names over 30 mm columns ran into each other; two letters a column do not."""
    place = {p.path.rsplit("/", 1)[1]: p for p in pads}
    where, labels, colors = [], [], []
    for finger in FINGERS:
        top = place.get(f"{finger.lower()}_tip")
        if top is not None:
            where.append([top.corner_mm[0] + top.pitch_mm * top.shape[1] / 2, top.corner_mm[1] - 8.0])
            labels.append(finger)
            colors.append(FINGER_RGB[finger])
    for row in ("tip", "inner", "palm"):
        pad = place.get("f1_" + row if row != "palm" else row)
        if pad is not None:
            where.append([pad.corner_mm[0] - 14.0, pad.corner_mm[1] + pad.pitch_mm * pad.shape[0] / 2])
            labels.append(row)
            colors.append((200, 200, 200))
    return np.array(where, dtype=float), labels, colors


def _colour_bar_place(pads: list[_PadImage]) -> tuple[float, float, float]:
    """The colour bar's left edge and its top and bottom (mm): right of the pads, over the inner pads'
    and the palm's height."""
    right = max(p.corner_mm[0] + p.pitch_mm * p.shape[1] for p in pads)
    top = min(p.corner_mm[1] for p in pads if p.path.endswith("_inner"))
    bottom = max(p.corner_mm[1] + p.pitch_mm * p.shape[0] for p in pads)
    return right + 12.0, top, bottom


def _name(model: mujoco.MjModel, kind: str, i: int) -> str:
    """An object's MuJoCo name made a safe entity path part, or <kind>_<i> when it has none."""
    adr = int(getattr(model, f"name_{kind}adr")[i])
    raw = bytes(model.names[adr:]).split(b"\0", 1)[0].decode("utf-8", "replace")
    return _UNSAFE.sub("_", raw).strip("_") or f"{kind}_{i}"


def _unique(names: list[str]) -> list[str]:
    """Suffix the index to names met before, so that no two objects share an entity."""
    seen: set[str] = set()
    out = []
    for i, name in enumerate(names):
        out.append(name if name not in seen else f"{name}_{i}")
        seen.add(out[-1])
    return out


def _xyzw(quat_wxyz: ArrayLike) -> rr.Quaternion:
    w, x, y, z = np.asarray(quat_wxyz, dtype=np.float64)
    return rr.Quaternion(xyzw=[x, y, z, w])


def _pose(data: mujoco.MjData, b: int) -> rr.Transform3D:
    return rr.Transform3D(translation=data.xpos[b], quaternion=_xyzw(data.xquat[b]))


def _geom_rgba(model: mujoco.MjModel, g: int) -> np.ndarray:
    """MuJoCo's rule (mjv): the material's colour unless the geom sets an rgba of its own."""
    rgba = np.asarray(model.geom_rgba[g], dtype=np.float32)
    mat = int(model.geom_matid[g])
    if mat >= 0 and np.array_equal(rgba, _DEFAULT_RGBA):
        rgba = np.asarray(model.mat_rgba[mat], dtype=np.float32)
    return np.clip(rgba, 0, 1)


def _geom_archetype(model: mujoco.MjModel, g: int, color: np.ndarray) -> rr.AsComponents | None:
    kind = int(model.geom_type[g])
    size = model.geom_size[g]
    fill = rr.components.FillMode.Solid
    if kind == _BOX:
        return rr.Boxes3D(half_sizes=[size], colors=[color], fill_mode=fill)
    if kind == _SPHERE:
        return rr.Ellipsoids3D(half_sizes=[[size[0]] * 3], colors=[color], fill_mode=fill)
    if kind == _ELLIPSOID:
        return rr.Ellipsoids3D(half_sizes=[size], colors=[color], fill_mode=fill)
    if kind == _CAPSULE:
        # Rerun capsules run from the origin along +z; MuJoCo's are centred.
        return rr.Capsules3D(
            lengths=[2 * size[1]], radii=[size[0]], translations=[[0, 0, -size[1]]], colors=[color]
        )
    if kind == _CYLINDER:
        return rr.Cylinders3D(lengths=[2 * size[1]], radii=[size[0]], colors=[color], fill_mode=fill)
    if kind == _MESH:
        m = int(model.geom_dataid[g])
        v0, nv = int(model.mesh_vertadr[m]), int(model.mesh_vertnum[m])
        f0, nf = int(model.mesh_faceadr[m]), int(model.mesh_facenum[m])
        verts = np.asarray(model.mesh_vert[v0 : v0 + nv], dtype=np.float32)
        faces = np.asarray(model.mesh_face[f0 : f0 + nf], dtype=np.uint32)
        return rr.Mesh3D(
            vertex_positions=verts,
            triangle_indices=faces,
            vertex_normals=_vertex_normals(verts, faces),
            albedo_factor=color,
        )
    return None


def _transform(pose: ArrayLike) -> rr.Transform3D:
    """A 4x4 parent_from_child pose as the child entity's Transform3D."""
    t = np.asarray(pose, dtype=np.float64)
    return rr.Transform3D(translation=t[:3, 3], mat3x3=t[:3, :3])


def _pinhole(matrix: ArrayLike, image_size: Sequence[int]) -> rr.Pinhole:
    """An OpenCV camera (x right, y down, z forward) of intrinsics K and (width, height)."""
    return rr.Pinhole(
        image_from_camera=np.asarray(matrix, dtype=np.float64),
        resolution=[float(image_size[0]), float(image_size[1])],
        camera_xyz=rr.ViewCoordinates.RDF,
        image_plane_distance=CAMERA_PLANE_M,
    )


def _image(rgb: np.ndarray, jpeg_quality: int | None) -> rr.Image | rr.EncodedImage:
    """An RGB (or grey) uint8 image, JPEG-encoded by OpenCV unless jpeg_quality is None."""
    image = np.asarray(rgb)
    if jpeg_quality is None:
        return rr.Image(image, color_model="RGB" if image.ndim == 3 else "L")
    import cv2

    bgr = cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if image.ndim == 3 else image
    ok, jpeg = cv2.imencode(
        ".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality), cv2.IMWRITE_JPEG_OPTIMIZE, 1]
    )
    if not ok:
        raise ValueError(f"could not JPEG-encode an image of shape {image.shape}")
    return rr.EncodedImage(contents=jpeg.tobytes(), media_type="image/jpeg")


def _png_depth(depth_units: np.ndarray) -> rr.EncodedDepthImage:
    """A uint16 depth image (DEPTH_MM_PER_UNIT) PNG-compressed: mostly zeros outside the object's mask,
    it shrinks ~40-fold (a raw 320x240 depth image is 154 kB). Run-length deflate: on the twin's lateral
    view 3.8 kB in 1.2 ms, where zlib's level 9 took 10 ms (16 ms on the hand loop's thread under load)
    for 4.0 kB."""
    import cv2

    image = np.ascontiguousarray(depth_units, dtype=np.uint16)
    options = [cv2.IMWRITE_PNG_COMPRESSION, 9, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE]
    ok, png = cv2.imencode(".png", image, options)
    if not ok:
        raise ValueError(f"could not PNG-encode a depth image of shape {depth_units.shape}")
    return rr.EncodedDepthImage(png.tobytes(), media_type="image/png", meter=1e3 / DEPTH_MM_PER_UNIT)


def _depth_units(disparity: np.ndarray, mask: np.ndarray, q23: float, q32: float, q33: float) -> np.ndarray:
    """uint16 depth (DEPTH_MM_PER_UNIT) of the rectified left view where the mask holds a match, else 0."""
    d = np.asarray(disparity, dtype=np.float32)
    with np.errstate(divide="ignore", invalid="ignore"):
        z_mm = 1e3 * q23 / (q32 * d + q33)
    units = z_mm / DEPTH_MM_PER_UNIT
    ok = np.asarray(mask, dtype=bool) & np.isfinite(units) & (units > 0) & (units < 65535)
    return np.where(ok, np.rint(units), 0).astype(np.uint16)


def error_colors(error_mm: ArrayLike, scale_mm: float = POINT_ERROR_SCALE_MM) -> np.ndarray:
    """RGB (uint8) for distances to the truth: POINT_ERROR_COLORMAP over 0..scale_mm, clipped above."""
    from matplotlib import colormaps

    fraction = np.clip(np.asarray(error_mm, dtype=float) / scale_mm, 0.0, 1.0)
    position = POINT_ERROR_COLORMAP_FROM + (1.0 - POINT_ERROR_COLORMAP_FROM) * fraction
    return (255 * colormaps[POINT_ERROR_COLORMAP](position)[:, :3]).astype(np.uint8)


def _short_triangles(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """The triangles whose longest edge is at most MAX_EDGE_FACTOR times the median edge."""
    if len(triangles) == 0:
        return triangles
    corners = np.asarray(points, dtype=np.float64)[triangles]  # (t, 3, 3)
    edges = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2)  # (t, 3)
    longest = edges.max(axis=1)
    return triangles[longest <= MAX_EDGE_FACTOR * np.median(edges)]


def _compact_mesh(triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The indices of the vertices a triangle list uses (ascending) and the triangles re-indexed into
    them: a mesh over a subset of a cloud (mesh_stride > 1) logs that subset only."""
    if len(triangles) == 0:
        return np.zeros(0, dtype=np.intp), np.zeros((0, 3), dtype=np.uint32)
    used, inverse = np.unique(triangles.reshape(-1), return_inverse=True)
    return used, inverse.reshape(-1, 3).astype(np.uint32)


def _flex_surface(model: mujoco.MjModel, f: int) -> np.ndarray:
    """Vertex indices, local to the flex, of its outer surface triangles (of its edges for a 1-D flex)."""
    dim = int(model.flex_dim[f])
    if dim == 3:
        adr, num = int(model.flex_shelldataadr[f]), int(model.flex_shellnum[f])
        return np.asarray(model.flex_shell[adr : adr + 3 * num], dtype=np.uint32).reshape(-1, 3)
    adr, num = int(model.flex_elemdataadr[f]), int(model.flex_elemnum[f])
    return np.asarray(model.flex_elem[adr : adr + (dim + 1) * num], dtype=np.uint32).reshape(-1, dim + 1)


def _vertex_normals(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit vertex normals, (m, 3) of (m, 3) vertices or (r, m, 3) of r frames of them: the area-weighted
    sum of the adjacent faces' normals (a vertex on no face: 0)."""
    frames = np.asarray(verts).reshape(-1, *np.shape(verts)[-2:])
    r, m = frames.shape[:2]
    corners = [frames[:, faces[:, i]] for i in range(3)]
    face_n = np.cross(corners[1] - corners[0], corners[2] - corners[0])  # (r, faces, 3)
    # Each face's normal adds to its three vertices: one bincount per axis over every frame at once.
    vertex = (np.arange(r)[:, None] * m + faces.T.reshape(3, 1, -1)).reshape(-1)
    normals = np.empty((r * m, 3), dtype=frames.dtype)
    for axis in range(3):
        weights = np.broadcast_to(face_n[None, ..., axis], (3, *face_n.shape[:2])).reshape(-1)
        normals[:, axis] = np.bincount(vertex, weights=weights, minlength=r * m)
    norm = np.linalg.norm(normals, axis=1, keepdims=True)
    return (normals / np.where(norm > 0, norm, 1.0)).reshape(np.shape(verts))


def _chunks(rrd_path: Path | str, **filters: object) -> Iterator[Chunk]:
    """The chunks of the first recording in an .rrd (no blueprint), filtered on Rerun's side."""
    from rerun.chunk import RrdReader

    path = Path(rrd_path)
    if not path.is_file():
        raise FileNotFoundError(path)
    stream = RrdReader(path).stream()
    return iter(stream.filter(**filters) if filters else stream)


def read_rrd_entities(rrd_path: Path | str) -> dict[str, int]:
    """Entity path ("/world/flex/foam") -> rows logged to it, static rows included."""
    counts: dict[str, int] = {}
    for chunk in _chunks(rrd_path):
        counts[chunk.entity_path] = counts.get(chunk.entity_path, 0) + chunk.num_rows
    return counts


def recorded_plot_facts(rrd_paths: Sequence[Path | str]) -> dict[str, object]:
    """What a blueprint takes from recordings already written (RunKind's fields): each plotted entity's
    smallest and largest value (y_ranges), when the compress phase began (compress_start_s) and the
    positions' and commands' range from then on (window_y_range). A file that is missing or cannot be
    read (one still being written) is passed over."""
    extremes: dict[str, tuple[float, float]] = {}
    start: float | None = None
    state = rr.StateChange.descriptor_state().component
    readable = []
    for path in rrd_paths:
        try:
            for t, cells in _rows(path, f"/{EVENTS_ENTITY}/phase", [state]):
                if start is None and t is not None and cells[state] == [COMPRESS_PHASE]:
                    start = t
            readable.append(path)
        except Exception:  # a missing, partial or foreign file: its ranges are not known
            continue
    window: tuple[float, float] | None = None
    for path in readable:
        try:
            chunks = list(_chunks(path, components=[_SCALARS], is_static=False))
        except Exception:
            continue
        for chunk in chunks:
            batch = chunk.to_record_batch()
            if _SCALARS not in batch.schema.names:
                continue
            rows = [np.asarray(v, dtype=float) for v in batch.column(_SCALARS).to_pylist() if v is not None]
            values = np.concatenate(rows) if rows else np.zeros(0)
            values = values[np.isfinite(values)]
            if not values.size:
                continue
            entity = chunk.entity_path
            old = extremes.get(entity, (np.inf, -np.inf))
            extremes[entity] = (min(old[0], float(values.min())), max(old[1], float(values.max())))
            if entity in _WINDOWED and start is not None and TIMELINE in batch.schema.names:
                t = batch.column(TIMELINE).to_numpy(zero_copy_only=False)
                t_s = t.astype("timedelta64[ns]").astype(np.int64) / 1e9 if t.dtype.kind == "m" else t
                cells = batch.column(_SCALARS).to_pylist()
                late = [
                    np.asarray(v, dtype=float) for ti, v in zip(t_s, cells, strict=True) if v and ti >= start
                ]
                if late:
                    w = np.concatenate(late)
                    lo, hi = float(np.nanmin(w)), float(np.nanmax(w))
                    window = (lo, hi) if window is None else (min(window[0], lo), max(window[1], hi))
    return {
        "y_ranges": tuple((entity, lo, hi) for entity, (lo, hi) in sorted(extremes.items())),
        "compress_start_s": start,
        "window_y_range": window,
    }


def read_rrd_scalars(
    rrd_path: Path | str, entity_path: str, timeline: str = TIMELINE
) -> tuple[np.ndarray, np.ndarray]:
    """Times (s) and values, (n,) for one series or (n, k) for k, of an rr.Scalars entity, in time order.

    Raises KeyError when the entity has no scalars on that timeline.
    """
    entity_path = "/" + entity_path.lstrip("/")
    times, values = [], []
    for chunk in _chunks(rrd_path, content=entity_path, is_static=False, components=_SCALARS):
        batch = chunk.to_record_batch()
        if chunk.entity_path != entity_path or timeline not in batch.schema.names:
            continue
        t = batch.column(timeline).to_numpy(zero_copy_only=False)
        for ti, v in zip(t, batch.column(_SCALARS).to_pylist(), strict=True):
            if v is not None:
                times.append(ti)
                values.append(v)
    if not times:
        raise KeyError(f"no scalars at {entity_path} on timeline {timeline!r} in {rrd_path}")
    t = np.array(times)
    t_s = t.astype("timedelta64[ns]").astype(np.int64) / 1e9 if t.dtype.kind == "m" else t.astype(float)
    v = np.array(values, dtype=np.float64)
    order = np.argsort(t_s, kind="stable")
    v = v[order]
    return t_s[order], v[:, 0] if v.shape[1] == 1 else v


def read_rrd_meshes(
    rrd_path: Path | str, entity_path: str
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Vertex positions (m, 3), triangles (t, 3) and vertex normals (m, 3 or 0, 3) of each Mesh3D row
    logged at an entity, in time order; a row without triangles has the latest logged before it (as the
    viewer shows it: RunRecording sends a mesh's triangles with its first row only)."""
    columns = [
        rr.Mesh3D.descriptor_vertex_positions().component,
        rr.Mesh3D.descriptor_triangle_indices().component,
        rr.Mesh3D.descriptor_vertex_normals().component,
    ]
    return [
        (
            np.array(cells[columns[0]], dtype=np.float32).reshape(-1, 3),
            np.array(cells[columns[1]] or [], dtype=np.uint32).reshape(-1, 3),
            np.array(cells[columns[2]] or [], dtype=np.float32).reshape(-1, 3),
        )
        for _, cells in _rows(rrd_path, entity_path, columns, latest_at=True)
    ]


def read_rrd_views(rrd_path: Path | str) -> dict[str, dict[str, object]]:
    """View name -> {"kind", "origin", "contents"} of the last blueprint in an .rrd."""
    from rerun.chunk import RrdReader

    reader = RrdReader(Path(rrd_path))
    # Blueprint stores are listed in no particular order; the last one sent holds the newest chunk
    # (chunk ids are TUIDs: "chunk_" + 32 hex digits, nanoseconds since the epoch first).
    chunks = [list(reader.stream(store=store)) for store in reader.blueprints()]
    if not chunks:
        return {}
    props: dict[str, dict[str, object]] = {}
    newest = max(chunks, key=lambda cs: max((int(c.id.removeprefix("chunk_"), 16) for c in cs), default=0))
    for chunk in newest:
        batch = chunk.to_record_batch()
        for column in batch.schema.names:
            if column.startswith(("ViewBlueprint:", "ViewContents:")):
                last = [v for v in batch.column(column).to_pylist() if v is not None]
                if last:
                    view = chunk.entity_path.removesuffix("/ViewContents")
                    props.setdefault(view, {})[column.split(":", 1)[1]] = last[-1]
    return {
        str(p.get("display_name", [view])[0]): {
            "kind": p.get("class_identifier", [""])[0],
            "origin": p.get("space_origin", [""])[0],
            "contents": list(p.get("query", [])),
        }
        for view, p in props.items()
    }


def read_rrd_blueprint(rrd_path: Path | str) -> dict[str, dict[str, object]]:
    """Blueprint entity ("/view/<id>/EyeControls3D", ".../ViewContents/overrides/<entity>/visualizers/<id>")
    -> {column ("EyeControls3D:look_target"): its last value} of the last blueprint in an .rrd."""
    from rerun.chunk import RrdReader

    reader = RrdReader(Path(rrd_path))
    chunks = [list(reader.stream(store=store)) for store in reader.blueprints()]
    if not chunks:
        return {}
    newest = max(chunks, key=lambda cs: max((int(c.id.removeprefix("chunk_"), 16) for c in cs), default=0))
    out: dict[str, dict[str, object]] = {}
    for chunk in newest:
        batch = chunk.to_record_batch()
        for column in batch.schema.names:
            if ":" in column:
                values = [v for v in batch.column(column).to_pylist() if v is not None]
                if values:
                    out.setdefault(chunk.entity_path, {})[column] = values[-1]
    return out


def look_target_of(rrd_path: Path | str) -> list[float] | None:
    """The 3-D view's look target a run's own blueprint chose (its object's centre); None if the
    recording has none or cannot be read (the blueprint's default eye then)."""
    path = Path(rrd_path)
    if not path.is_file():
        return None
    return next(
        (
            c["EyeControls3D:look_target"][0]
            for p, c in read_rrd_blueprint(path).items()
            if p.endswith("/EyeControls3D") and "EyeControls3D:look_target" in c
        ),
        None,
    )


def _rows(
    rrd_path: Path | str,
    entity_path: str,
    columns: Sequence[str],
    timeline: str = TIMELINE,
    *,
    latest_at: bool = False,
) -> list[tuple[float | None, dict[str, object]]]:
    """(time in s, or None for a static row; {column: cell}) of each row of an entity that has
    columns[0], in time order (static rows first). With `latest_at`, a row that has any of the columns
    counts, and a column it lacks holds the latest value logged before it (the viewer's latest-at)."""
    entity_path = "/" + entity_path.lstrip("/")
    rows: list[tuple[float | None, dict[str, object]]] = []
    for chunk in _chunks(rrd_path, content=entity_path, components=list(columns)):
        batch = chunk.to_record_batch()
        wanted = columns if latest_at else columns[:1]
        if chunk.entity_path != entity_path or not any(c in batch.schema.names for c in wanted):
            continue
        n = batch.num_rows
        cells = {c: batch.column(c).to_pylist() if c in batch.schema.names else [None] * n for c in columns}
        if timeline in batch.schema.names:
            t = batch.column(timeline).to_numpy(zero_copy_only=False)
            times = t.astype("timedelta64[ns]").astype(np.int64) / 1e9 if t.dtype.kind == "m" else t
        else:
            times = [None] * n
        for i in range(n):
            if any(cells[c][i] is not None for c in wanted):
                rows.append(
                    (None if times[i] is None else float(times[i]), {c: cells[c][i] for c in columns})
                )
    rows.sort(key=lambda r: -np.inf if r[0] is None else r[0])
    if not latest_at:
        return rows
    latest: dict[str, object] = dict.fromkeys(columns)
    out = []
    timed = any(t is not None for t, _ in rows)
    for t, cells in rows:
        latest.update({c: v for c, v in cells.items() if v is not None})
        if latest[columns[0]] is not None and (t is not None or not timed):  # static parts join later rows
            out.append((t, dict(latest)))
    return out


def read_rrd_pinholes(rrd_path: Path | str) -> dict[str, tuple[np.ndarray, tuple[int, int]]]:
    """Entity -> (K (3, 3), (width, height)) of every rr.Pinhole in an .rrd (the last one logged)."""
    k_col = rr.Pinhole.descriptor_image_from_camera().component
    res_col = rr.Pinhole.descriptor_resolution().component
    out: dict[str, tuple[np.ndarray, tuple[int, int]]] = {}
    for chunk in _chunks(rrd_path, components=[k_col, res_col]):
        batch = chunk.to_record_batch()
        if k_col not in batch.schema.names:
            continue
        ks = batch.column(k_col).to_pylist()
        res = batch.column(res_col).to_pylist() if res_col in batch.schema.names else [None] * len(ks)
        for k, r in zip(ks, res, strict=True):
            if k is not None:
                size = (0, 0) if r is None else (int(r[0][0]), int(r[0][1]))
                out[chunk.entity_path] = (np.array(k[0], dtype=np.float64).reshape(3, 3).T, size)
    return out


def read_rrd_transforms(rrd_path: Path | str, entity_path: str) -> list[np.ndarray]:
    """4x4 parent_from_entity poses of the Transform3D rows (translation + mat3x3) of an entity."""
    columns = [
        rr.Transform3D.descriptor_translation().component,
        rr.Transform3D.descriptor_mat3x3().component,
    ]
    poses = []
    for _, cells in _rows(rrd_path, entity_path, columns):
        pose = np.eye(4)
        pose[:3, 3] = np.asarray(cells[columns[0]], dtype=np.float64).reshape(-1)
        if cells[columns[1]] is not None:
            pose[:3, :3] = np.asarray(cells[columns[1]], dtype=np.float64).reshape(3, 3).T
        poses.append(pose)
    return poses


def read_rrd_points(
    rrd_path: Path | str, entity_path: str
) -> list[tuple[float | None, np.ndarray, np.ndarray]]:
    """(time s, positions (n, 3), colours (n, 4) RGBA uint8 or (0, 4)) of each Points3D row, in time
    order; a row that changes the colours only has the positions logged before it (the viewer's
    latest-at: RunRecording sends the taxels' places with their first row only)."""
    columns = [rr.Points3D.descriptor_positions().component, rr.Points3D.descriptor_colors().component]
    out = []
    for t, cells in _rows(rrd_path, entity_path, columns, latest_at=True):
        colors = np.array(cells[columns[1]] or [], dtype=np.uint32)
        rgba = ((colors[:, None] >> np.array([24, 16, 8, 0], dtype=np.uint32)) & 0xFF).astype(np.uint8)
        out.append((t, np.array(cells[columns[0]], dtype=np.float32).reshape(-1, 3), rgba.reshape(-1, 4)))
    return out


_DATATYPES = {6: np.uint8, 7: np.int8, 8: np.uint16, 9: np.int16, 10: np.uint32, 11: np.int32, 33: np.float16}
_DATATYPES |= {12: np.uint64, 13: np.int64, 34: np.float32, 35: np.float64}


def _decode(buffer: object, fmt: dict) -> np.ndarray:
    """An rr.Image / rr.DepthImage buffer as an (H, W[, C]) array."""
    dtype = _DATATYPES[int(fmt["channel_datatype"])]
    flat = np.frombuffer(np.asarray(buffer, dtype=np.uint8).tobytes(), dtype=dtype)
    image = flat.reshape(int(fmt["height"]), int(fmt["width"]), -1)
    return image[..., 0] if image.shape[2] == 1 else image


def read_rrd_images(rrd_path: Path | str, entity_path: str) -> list[tuple[float | None, np.ndarray]]:
    """(time s, image) of each image row of an entity, in time order: rr.EncodedImage rows decoded
    (RGB uint8 for colour JPEG/PNG), rr.Image rows as logged, rr.DepthImage and rr.EncodedDepthImage
    rows in metres (0 = none)."""
    encoded = [rr.EncodedImage.descriptor_blob().component]
    encoded_depth = [
        rr.EncodedDepthImage.descriptor_blob().component,
        rr.EncodedDepthImage.descriptor_meter().component,
    ]
    raw = [rr.Image.descriptor_buffer().component, rr.Image.descriptor_format().component]
    depth = [
        rr.DepthImage.descriptor_buffer().component,
        rr.DepthImage.descriptor_format().component,
        rr.DepthImage.descriptor_meter().component,
    ]
    import cv2

    out: list[tuple[float | None, np.ndarray]] = []
    for t, cells in _rows(rrd_path, entity_path, encoded):
        blob = np.asarray(cells[encoded[0]][0], dtype=np.uint8)
        image = cv2.imdecode(blob, cv2.IMREAD_UNCHANGED)
        out.append((t, cv2.cvtColor(image, cv2.COLOR_BGR2RGB) if image.ndim == 3 else image))
    for t, cells in _rows(rrd_path, entity_path, encoded_depth):
        image = cv2.imdecode(np.asarray(cells[encoded_depth[0]][0], dtype=np.uint8), cv2.IMREAD_UNCHANGED)
        meter = cells[encoded_depth[1]][0] if cells[encoded_depth[1]] else 1.0
        out.append((t, image.astype(np.float64) / float(meter)))
    for t, cells in _rows(rrd_path, entity_path, raw):
        out.append((t, _decode(cells[raw[0]][0], cells[raw[1]][0])))
    for t, cells in _rows(rrd_path, entity_path, depth, latest_at=True):  # format, meter: maybe static
        meter = cells[depth[2]][0] if cells[depth[2]] else 1.0
        out.append((t, _decode(cells[depth[0]][0], cells[depth[1]][0]).astype(np.float64) / float(meter)))
    out.sort(key=lambda r: -np.inf if r[0] is None else r[0])
    return out
