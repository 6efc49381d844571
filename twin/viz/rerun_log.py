"""Every Rerun call of the project: one recording per run, saved to an .rrd with a default blueprint.

The 3-D view shows the MuJoCo model (visual geoms on their bodies) and the deforming foam; time series
show each finger's position, velocity, torque and force; a tab waits for tactile heatmaps and camera
images. Reading an .rrd back uses Rerun's own chunk reader (`rerun.chunk.RrdReader`): Rerun 0.41 has no
`rerun.dataframe` module any more, and its DataFusion query API (`ChunkStore.reader`) needs the
optional `datafusion` package, which this project does not install.
"""

from __future__ import annotations

import re
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from numpy.typing import ArrayLike

if TYPE_CHECKING:
    import mujoco
    from rerun.chunk import Chunk

TIMELINE = "sim_time"
PLOT_GROUPS = ("position_counts", "velocity_counts", "torque_nm", "force_kg")
PLOT_STREAMS = ("hand",)
FOAM_RGB = (240, 190, 100)  # pale yellow-orange
SENSORS_ENTITY = "notes/sensors"
TACTILE_ENTITY = "tactile"
CONTACTS_ENTITY = "world/contacts"
PRESSURE_FULL_SCALE_KPA = 150.0
"""Top of the heatmap colour scale: about 2 kg on four 6 mm taxels."""
CONTACT_ARROW_M_PER_N = 0.004
LOG_ENTITY = "log"
# mjtGeom values (stable across MuJoCo 3.x): plane 0, hfield 1, sphere 2, capsule 3, ellipsoid 4,
# cylinder 5, box 6, mesh 7, sdf 8. Height fields and SDFs are not drawn.
_PLANE, _SPHERE, _CAPSULE, _ELLIPSOID, _CYLINDER, _BOX, _MESH = 0, 2, 3, 4, 5, 6, 7
_DEFAULT_RGBA = np.array([0.5, 0.5, 0.5, 1.0], dtype=np.float32)  # MuJoCo's geom rgba default
_SCALARS = rr.Scalars.descriptor_scalars().component
# Entity path parts that Rerun takes verbatim (anything else it escapes or drops, with a warning).
_UNSAFE = re.compile(r"[^\w.\-]")


def default_blueprint(
    plot_groups: Sequence[str] = PLOT_GROUPS, *, streams: Sequence[str] = PLOT_STREAMS
) -> rrb.Blueprint:
    """3-D scene left, one time-series view per plot group right, a tab reserved for sensors.

    The view of group g shows field g of every stream in `streams` ("/plots/<stream>/<g>"). Rerun's
    entity filters only take `**` at the end of a path ("/plots/**/g" matches nothing), hence the
    explicit streams; RunRecording re-sends the blueprint when a new stream is logged.
    """
    plots = [
        rrb.TimeSeriesView(name=group, origin="/plots", contents=[f"/plots/{s}/{group}" for s in streams])
        for group in plot_groups
    ]
    sensors = rrb.Tabs(
        rrb.Spatial2DView(name="tactile pads (kPa)", origin=f"/{TACTILE_ENTITY}"),
        rrb.TimeSeriesView(name="pad forces, eq. 6 (N)", origin="/plots/tactile"),
        rrb.TextDocumentView(name="cameras", origin=f"/{SENSORS_ENTITY}"),
        rrb.TextLogView(name="log", origin=f"/{LOG_ENTITY}"),
        name="Tactile & cameras",
    )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial3DView(name="hand and foam", origin="/world"), sensors, row_shares=[3, 1]
            ),
            rrb.Vertical(*plots, name="time series"),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


class RunRecording:
    """One Rerun recording of a run, saved to an .rrd file, with the default blueprint."""

    def __init__(
        self,
        rrd_path: Path | str,
        *,
        application_id: str = "barrett_twin",
        recording_id: str | None = None,
        plot_streams: Sequence[str] = PLOT_STREAMS,
    ) -> None:
        """Open the recording and its .rrd file; `plot_streams` are plotted from the start."""
        self.rrd_path = Path(rrd_path)
        self.rec = rr.RecordingStream(application_id, recording_id=recording_id)
        self._plot_streams = list(dict.fromkeys(plot_streams))
        self.rec.save(self.rrd_path, default_blueprint=default_blueprint(streams=self._plot_streams))
        self.rec.log(
            SENSORS_ENTITY,
            rr.TextDocument("Camera images appear here once the stereo pair is on the rig."),
            static=True,
        )
        self._series_named: set[str] = set()
        self._flex: list[tuple[str, int, int, int, np.ndarray]] = []
        self._bodies: list[tuple[int, str]] = []
        self._welded: list[tuple[int, str]] = []
        self._closed = False
        self._tactile_static: tuple[np.ndarray, np.ndarray] | None = None
        self._body_paths: dict[str, str] = {}

    def _open(self, t_s: float | None) -> None:
        if self._closed:
            raise RuntimeError(f"recording {self.rrd_path} is closed")
        if t_s is not None:
            self.rec.set_time(TIMELINE, duration=float(t_s))

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
            shape = _geom_archetype(model, g, (rgba * 255).round().astype(np.uint8))
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

    def log_scene(self, t_s: float, data: mujoco.MjData) -> None:
        """Body world poses and the flex meshes (positions, normals) at sim time t_s."""
        self._open(t_s)
        for b, path in self._welded:
            self.rec.log(path, _pose(data, b), static=True)
        self._welded = []
        for b, path in self._bodies:
            self.rec.log(path, _pose(data, b))
        for path, adr, num, dim, faces in self._flex:
            verts = np.asarray(data.flexvert_xpos[adr : adr + num], dtype=np.float32)
            if dim == 1:  # a cable: its edges
                self.rec.log(path, rr.LineStrips3D(verts[faces], colors=[FOAM_RGB]))
                continue
            self.rec.log(
                path,
                rr.Mesh3D(
                    vertex_positions=verts,
                    triangle_indices=faces,
                    vertex_normals=_vertex_normals(verts, faces),
                    albedo_factor=[*FOAM_RGB, 255],
                ),
            )

    def log_tactile(self, t_s: float, pressure_kpa: ArrayLike, pad_force_n: ArrayLike) -> None:
        """Pads as heatmaps in their layout (2-D), taxels coloured on the hand (3-D), eq. 6 forces."""
        from twin.tactile.layout import LAYOUT

        self._open(t_s)
        pressure = np.asarray(pressure_kpa, dtype=float)
        colors = _heat(pressure / PRESSURE_FULL_SCALE_KPA)
        if not self._tactile_static:
            from twin.tactile.layout import canvas_mm

            centers, half = canvas_mm()
            self.rec.log(
                f"{TACTILE_ENTITY}/names",
                rr.Points2D(_pad_label_positions(), labels=list(LAYOUT.pad_names), radii=0.1),
                static=True,
            )
            self._tactile_static = (centers, half)
        centers, half = self._tactile_static
        self.rec.log(f"{TACTILE_ENTITY}/taxels", rr.Boxes2D(centers=centers, half_sizes=half, colors=colors))
        for pad_index, pad in enumerate(LAYOUT.pads):
            body_path = self._body_paths.get(pad.body)
            if body_path is None:
                continue
            ids = np.flatnonzero(LAYOUT.pad_index == pad_index)
            self.rec.log(
                f"{body_path}/taxels_{pad.name}",
                rr.Points3D(LAYOUT.position_m[ids], colors=colors[ids], radii=pad.pitch_m * 0.4),
            )
        self.log_scalars(
            "tactile", t_s, {"pad_force_n": pad_force_n}, labels={"pad_force_n": LAYOUT.pad_names}
        )

    def log_contacts(self, t_s: float, points_m: ArrayLike, forces_n: ArrayLike) -> None:
        """Contact points and their normal forces as arrows in the 3-D scene (pointing into the pad)."""
        self._open(t_s)
        points = np.asarray(points_m, dtype=float).reshape(-1, 3)
        vectors = np.asarray(forces_n, dtype=float).reshape(-1, 3) * CONTACT_ARROW_M_PER_N
        self.rec.log(
            CONTACTS_ENTITY, rr.Arrows3D(origins=points - vectors, vectors=vectors, colors=[(220, 40, 40)])
        )

    def log_scalars(
        self,
        stream: str,
        t_s: float,
        values: Mapping[str, ArrayLike],
        labels: Mapping[str, Sequence[str]] | None = None,
    ) -> None:
        """One time-series row: entity plots/<stream>/<field>, one series per element of an array field.

        labels[field] names the series of a field (set once, statically); its length must match.
        """
        self._open(t_s)
        if stream not in self._plot_streams:
            self._plot_streams.append(stream)
            self.rec.send_blueprint(default_blueprint(streams=self._plot_streams))
        for field, value in values.items():
            path = f"plots/{stream}/{field}"
            arr = np.atleast_1d(np.asarray(value, dtype=np.float64))
            if arr.ndim != 1:
                raise ValueError(f"{path}: a time series takes a scalar or a 1-D array, got {arr.shape}")
            if path not in self._series_named and labels and field in labels:
                names = [str(n) for n in labels[field]]
                if len(names) != arr.size:
                    raise ValueError(f"{path}: {len(names)} labels for {arr.size} values")
                self.rec.log(path, rr.SeriesLines(names=names), static=True)
                self._series_named.add(path)
            self.rec.log(path, rr.Scalars(arr))

    def log_text(self, t_s: float, text: str, level: str = "INFO") -> None:
        """A line in the run's text log (entity "log")."""
        self._open(t_s)
        self.rec.log(LOG_ENTITY, rr.TextLog(text, level=level))

    def close(self) -> None:
        """Flush and finish the .rrd; safe to call twice."""
        if not self._closed:
            self._closed = True
            self.rec.flush()
            self.rec.disconnect()

    def __enter__(self) -> RunRecording:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


_HEAT_STOPS = np.array([[40, 30, 90], [40, 110, 180], [60, 180, 120], [240, 210, 60], [250, 250, 230]], float)


def _heat(x: ArrayLike) -> np.ndarray:
    """Colours of values in [0, 1] on a dark-blue -> yellow scale (out-of-range values clipped)."""
    x = np.clip(np.nan_to_num(np.asarray(x, dtype=float)), 0.0, 1.0) * (len(_HEAT_STOPS) - 1)
    lo = np.minimum(x.astype(int), len(_HEAT_STOPS) - 2)
    frac = (x - lo)[:, None]
    return ((1 - frac) * _HEAT_STOPS[lo] + frac * _HEAT_STOPS[lo + 1]).astype(np.uint8)


def _pad_label_positions() -> np.ndarray:
    """Where each pad's name sits on the 2-D canvas (above its first cell)."""
    from twin.tactile.layout import LAYOUT, canvas_mm

    centers, _ = canvas_mm()
    return np.array([centers[LAYOUT.pad_index == k].min(axis=0) - (0, 6) for k in range(len(LAYOUT.pads))])


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


def _flex_surface(model: mujoco.MjModel, f: int) -> np.ndarray:
    """Vertex indices, local to the flex, of its outer surface triangles (of its edges for a 1-D flex)."""
    dim = int(model.flex_dim[f])
    if dim == 3:
        adr, num = int(model.flex_shelldataadr[f]), int(model.flex_shellnum[f])
        return np.asarray(model.flex_shell[adr : adr + 3 * num], dtype=np.uint32).reshape(-1, 3)
    adr, num = int(model.flex_elemdataadr[f]), int(model.flex_elemnum[f])
    return np.asarray(model.flex_elem[adr : adr + (dim + 1) * num], dtype=np.uint32).reshape(-1, dim + 1)


def _vertex_normals(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit vertex normals: the area-weighted sum of the adjacent faces' normals."""
    a, b, c = (verts[faces[:, i]] for i in range(3))
    face_n = np.cross(b - a, c - a)
    normals = np.zeros_like(verts)
    for i in range(3):
        np.add.at(normals, faces[:, i], face_n)
    norm = np.linalg.norm(normals, axis=1, keepdims=True)
    return normals / np.where(norm > 0, norm, 1.0)


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
    logged at an entity, in the order logged."""
    entity_path = "/" + entity_path.lstrip("/")
    columns = [
        rr.Mesh3D.descriptor_vertex_positions().component,
        rr.Mesh3D.descriptor_triangle_indices().component,
        rr.Mesh3D.descriptor_vertex_normals().component,
    ]
    rows = []
    for chunk in _chunks(rrd_path, content=entity_path, components=columns):
        batch = chunk.to_record_batch()
        if chunk.entity_path != entity_path or columns[0] not in batch.schema.names:
            continue
        cells = [
            batch.column(c).to_pylist() if c in batch.schema.names else [None] * batch.num_rows
            for c in columns
        ]
        for positions, triangles, normals in zip(*cells, strict=True):
            if positions is not None:
                rows.append(
                    (
                        np.array(positions, dtype=np.float32).reshape(-1, 3),
                        np.array(triangles or [], dtype=np.uint32).reshape(-1, 3),
                        np.array(normals or [], dtype=np.float32).reshape(-1, 3),
                    )
                )
    return rows


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
