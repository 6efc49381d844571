"""Every Rerun call of the project: one recording per run, saved to an .rrd with a default blueprint.

The 3-D view shows the MuJoCo model (visual geoms on moving bodies) and the deforming foam; time
series show each finger's position, velocity, torque and force; a tab waits for tactile heatmaps and
camera images. Reading an .rrd back uses Rerun's own chunk reader.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from numpy.typing import ArrayLike

if TYPE_CHECKING:
    import mujoco

TIMELINE = "sim_time"
PLOT_GROUPS = ("position_counts", "velocity_counts", "torque_nm", "force_kg")
FOAM_RGB = (240, 190, 100)
# mjtGeom values (stable across MuJoCo 3.x): plane 0, hfield 1, sphere 2, capsule 3, ellipsoid 4,
# cylinder 5, box 6, mesh 7.
_PLANE, _SPHERE, _CAPSULE, _ELLIPSOID, _CYLINDER, _BOX, _MESH = 0, 2, 3, 4, 5, 6, 7


def default_blueprint(
    streams: Sequence[str] = ("hand",), plot_groups: Sequence[str] = PLOT_GROUPS
) -> rrb.Blueprint:
    """3-D scene left; per-quantity time series right; a tab reserved for tactile pads and cameras."""
    plots = [
        rrb.TimeSeriesView(name=group, origin="/plots", contents=[f"/plots/{s}/{group}" for s in streams])
        for group in plot_groups
    ]
    sensors = rrb.Tabs(
        rrb.TextDocumentView(name="Tactile & cameras", origin="/notes/sensors"),
        name="Tactile & cameras",
    )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial3DView(name="hand and foam", origin="/world"), sensors, row_shares=[3, 1]
            ),
            rrb.Vertical(*plots),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


class RunRecording:
    """One Rerun recording of a run, saved to an .rrd file, with the default blueprint."""

    def __init__(
        self, rrd_path: Path | str, *, application_id: str = "barrett_twin", recording_id: str | None = None
    ) -> None:
        self.rrd_path = Path(rrd_path)
        self.rec = rr.RecordingStream(application_id, recording_id=recording_id)
        self.rec.save(self.rrd_path, default_blueprint=default_blueprint())
        self.rec.log(
            "notes/sensors",
            rr.TextDocument(
                "Tactile heatmaps and camera images appear here once those devices are on the rig."
            ),
            static=True,
        )
        self._series_named: set[str] = set()
        self._flex: list[tuple[str, int, int, np.ndarray]] = []
        self._bodies: list[tuple[int, str]] = []
        self._welded: list[tuple[int, str]] = []
        self._closed = False

    def _set_time(self, t_s: float) -> None:
        self.rec.set_time(TIMELINE, duration=float(t_s))

    def log_model(self, model: mujoco.MjModel) -> None:
        """Static geometry of the visual geoms, under their bodies; remembers flex surfaces."""
        names = {b: _body_path(model, b) for b in range(1, model.nbody)}
        drawn: set[int] = set()
        for g in range(model.ngeom):
            body = int(model.geom_bodyid[g])
            if (
                model.geom_group[g] >= 3
                or model.geom_type[g] == _PLANE
                or model.geom_rgba[g, 3] == 0
                or body == 0
            ):
                continue
            path = f"{names[body]}/{_name(model, 'geom', g)}"
            shape = _geom_archetype(model, g)
            if shape is None:
                continue
            pos, quat = model.geom_pos[g], model.geom_quat[g]
            self.rec.log(path, rr.Transform3D(translation=pos, quaternion=_xyzw(quat)), static=True)
            self.rec.log(path, shape, static=True)
            drawn.add(body)
        # Only bodies that draw something are posed; those welded to the world are posed once.
        for b in sorted(drawn):
            (self._welded if model.body_weldid[b] == 0 else self._bodies).append((b, names[b]))
        for f in range(model.nflex):
            faces = _flex_surface(model, f)
            name = _name(model, "flex", f)
            self._flex.append(
                (f"world/flex/{name}", int(model.flex_vertadr[f]), int(model.flex_vertnum[f]), faces)
            )

    def log_scene(self, t_s: float, data: mujoco.MjData) -> None:
        """Body poses and the flex meshes at sim time t_s."""
        for b, path in self._welded:
            self.rec.log(
                path, rr.Transform3D(translation=data.xpos[b], quaternion=_xyzw(data.xquat[b])), static=True
            )
        self._welded = []
        self._set_time(t_s)
        for b, path in self._bodies:
            self.rec.log(path, rr.Transform3D(translation=data.xpos[b], quaternion=_xyzw(data.xquat[b])))
        for path, adr, num, faces in self._flex:
            verts = np.asarray(data.flexvert_xpos[adr : adr + num], dtype=np.float32)
            self.rec.log(
                path,
                rr.Mesh3D(
                    vertex_positions=verts,
                    triangle_indices=faces,
                    vertex_normals=_vertex_normals(verts, faces),
                    albedo_factor=[*FOAM_RGB, 255],
                ),
            )

    def log_scalars(
        self,
        stream: str,
        t_s: float,
        values: Mapping[str, ArrayLike],
        labels: Mapping[str, Sequence[str]] | None = None,
    ) -> None:
        """One row of time series: entity plots/<stream>/<field>, several series per array field."""
        self._set_time(t_s)
        for field, value in values.items():
            path = f"plots/{stream}/{field}"
            arr = np.atleast_1d(np.asarray(value, dtype=np.float64))
            if path not in self._series_named and labels and field in labels:
                self.rec.log(path, rr.SeriesLines(names=list(labels[field])), static=True)
                self._series_named.add(path)
            self.rec.log(path, rr.Scalars(arr))

    def log_text(self, t_s: float, text: str, level: str = "INFO") -> None:
        """A line in the run's log panel."""
        self._set_time(t_s)
        self.rec.log("log", rr.TextLog(text, level=level))

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


def _name(model: mujoco.MjModel, kind: str, i: int) -> str:
    import mujoco

    obj = {
        "body": mujoco.mjtObj.mjOBJ_BODY,
        "geom": mujoco.mjtObj.mjOBJ_GEOM,
        "flex": mujoco.mjtObj.mjOBJ_FLEX,
    }
    raw = mujoco.mj_id2name(model, obj[kind], i)
    return (raw or f"{kind}_{i}").replace("/", "_").strip("_") or f"{kind}_{i}"


def _body_path(model: mujoco.MjModel, b: int) -> str:
    return f"world/bodies/{_name(model, 'body', b)}"


def _xyzw(quat_wxyz: ArrayLike) -> rr.Quaternion:
    w, x, y, z = np.asarray(quat_wxyz, dtype=np.float64)
    return rr.Quaternion(xyzw=[x, y, z, w])


def _geom_archetype(model: mujoco.MjModel, g: int) -> rr.AsComponents | None:
    kind = int(model.geom_type[g])
    size = model.geom_size[g]
    color = (np.clip(model.geom_rgba[g], 0, 1) * 255).astype(np.uint8)
    if model.geom_matid[g] >= 0:
        color = (np.clip(model.mat_rgba[model.geom_matid[g]], 0, 1) * 255).astype(np.uint8)
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
        m = model.geom_dataid[g]
        v0, nv = model.mesh_vertadr[m], model.mesh_vertnum[m]
        f0, nf = model.mesh_faceadr[m], model.mesh_facenum[m]
        return rr.Mesh3D(
            vertex_positions=model.mesh_vert[v0 : v0 + nv],
            triangle_indices=model.mesh_face[f0 : f0 + nf],
            albedo_factor=color,
        )
    return None


def _flex_surface(model: mujoco.MjModel, f: int) -> np.ndarray:
    """Triangles (vertex indices local to the flex) of a flex's outer surface."""
    dim = int(model.flex_dim[f])
    if dim == 3:
        adr, num = int(model.flex_shelldataadr[f]), int(model.flex_shellnum[f])
        return np.asarray(model.flex_shell[adr : adr + 3 * num], dtype=np.uint32).reshape(-1, 3)
    adr, num = int(model.flex_elemdataadr[f]), int(model.flex_elemnum[f])
    return np.asarray(model.flex_elem[adr : adr + (dim + 1) * num], dtype=np.uint32).reshape(-1, dim + 1)[
        :, :3
    ]


def _vertex_normals(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    a, b, c = (verts[faces[:, i]] for i in range(3))
    face_n = np.cross(b - a, c - a)
    normals = np.zeros_like(verts)
    for i in range(3):
        np.add.at(normals, faces[:, i], face_n)
    norm = np.linalg.norm(normals, axis=1, keepdims=True)
    return normals / np.where(norm > 0, norm, 1.0)


def _chunks(rrd_path: Path | str):
    from rerun.chunk import RrdReader

    return RrdReader(str(rrd_path)).stream()


def read_rrd_entities(rrd_path: Path | str) -> dict[str, int]:
    """Entity path -> rows logged, read back with Rerun's own reader."""
    counts: dict[str, int] = {}
    for chunk in _chunks(rrd_path):
        counts[chunk.entity_path] = counts.get(chunk.entity_path, 0) + chunk.num_rows
    return counts


def read_rrd_scalars(
    rrd_path: Path | str, entity_path: str, timeline: str = TIMELINE
) -> tuple[np.ndarray, np.ndarray]:
    """Times (s) and values (n,) or (n, k) of an rr.Scalars entity, sorted by time."""
    times, values = [], []
    for chunk in _chunks(rrd_path):
        if chunk.entity_path != entity_path or chunk.is_static:
            continue
        batch = chunk.to_record_batch()
        names = batch.schema.names
        t_col = next((n for n in names if n == timeline), None)
        v_col = next((n for n in names if n.endswith("scalars")), None)
        if t_col is None or v_col is None:
            continue
        t = batch.column(t_col).to_numpy(zero_copy_only=False)
        times.append(t.astype("timedelta64[ns]").astype(np.int64) / 1e9 if t.dtype.kind == "m" else t / 1e9)
        values.extend(np.asarray(v, dtype=np.float64) for v in batch.column(v_col).to_pylist())
    if not times:
        raise KeyError(f"no scalars at {entity_path} in {rrd_path}")
    t = np.concatenate(times)
    v = np.array(values)
    order = np.argsort(t, kind="stable")
    v = v[order]
    return t[order], v[:, 0] if v.ndim == 2 and v.shape[1] == 1 else v
