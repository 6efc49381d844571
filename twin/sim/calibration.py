"""The foam's modulus made the material's: one scale k on the flex's Young's modulus per foam, fitted so
that the flex pushes back on the hand's own fingertips as an FEM of the same contact does.

The load case is the grasp's: in the compress procedure the three distal links close over the object and
lie flat on its top (measured in the twin's default run: contact normals -z within 4 degrees, the links'
palmar faces 8-9 mm into a 70 mm block), pressing it onto the palm. The bench poses the links' collision
geometry (models/barrett_mjcf/bh8.xml: the distal box and its tip capsule) by the hand's own kinematics,
level, where the grasp holds them; it presses them 2 / 4 / 6 mm into the object from first touch, the
object resting on the palm. twin.sim.fem solves the same case (rigid links, frictionless unilateral
contact, the palm under the object) and k is chosen so MuJoCo's force matches the FEM's over the depths.

k depends on the geometry, the Poisson ratio, the discretization and MuJoCo, not on E (MuJoCo's flex force
is linear in E and the fingers' contact is far stiffer than foam: benchmarks/foam_fidelity.py measures
both), so it is cached by a digest of those. The library's values ship in calibrations.json beside this
file; any other foam is calibrated at its first composition and stored in the user's cache.
"""

from __future__ import annotations

import datetime
import functools
import hashlib
import json
import math
import os
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from twin.interface.errors import ConfigError
from twin.sim.foam import PRESETS, FoamParams

CALIBRATION_VERSION = 1
"""Bumped whenever the load case, the FEM or the fit change: every cached k is then stale."""
DEPTHS_M = (0.002, 0.004, 0.006)
REFERENCE_YOUNG_PA = 40e3
"""The modulus the bench runs at (k does not depend on it; the library block's)."""
GRASP_INDENT_M = 0.009
"""How far the level links sit below the object's top at the balanced grasp (the twin's default compress
run on the library block: contacts at 136-138 mm against a 146 mm top): where the bench poses them."""
CLEARANCE_M = 0.01
FINGERS = ("f1", "f2", "f3")
TIP_GEOMS = ("outer_collision", "tip_collision")
FEM_LEVELS_M = ((0.008, 0.016), (0.006, 0.012), (0.0045, 0.012))
"""The FEM's refinement levels: element size within 12 mm of the contacts (the links; the palm under a
curved bottom), and elsewhere..."""
FEM_CONVERGED = 0.02
"""...taken until the force at 6 mm changes by less than this between two levels (the block: 0.1 %)."""
SETTLE_S, RAMP_S, HOLD_S = 0.3, 0.4, 0.4
PALM_FRICTION = 1.0
RIGID_SOLIMP = (0.9999, 0.9999, 0.001)
SHIPPED = Path(__file__).with_name("calibrations.json")
POISSON_NODES = (0.2, 0.35)
"""A mesh foam is calibrated at these Poisson ratios (the range of flexible foams) and its k interpolated
linearly between them (benchmarks/foam_calibration.py measures what that costs at the midpoint)."""
MAX_RESIDUAL = 0.15
"""The most a calibrated flex's force may differ from the FEM's at any depth for its k to be applied."""
MAX_FIT_ROUNDS = 5
TOPPLED_M = 0.005
"""A foam whose centre moved further than this across the palm in the bench toppled or rolled."""
FIT_TOLERANCE = 0.01
"""The fit stops once a round changes k by less than this (relative)."""

Progress = Callable[[str], None]


@dataclass(frozen=True)
class TipGeom:
    """One collision geom of a distal link, posed in the world (the palm frame) for the bench."""

    name: str
    type: int
    size: tuple[float, float, float]
    pos_m: tuple[float, float, float]
    quat: tuple[float, float, float, float]


def cache_dir() -> Path:
    """Where first-use calibrations are stored: $TWIN_CACHE_DIR, else ~/.cache/barrett-twin."""
    base = os.environ.get("TWIN_CACHE_DIR") or Path.home() / ".cache" / "barrett-twin"
    return Path(base) / "foam_calibration"


def digest(foam: FoamParams) -> str:
    """What k depends on: geometry (a mesh file by its bytes), Poisson ratio, discretization, MuJoCo."""
    key: dict[str, Any] = {
        "version": CALIBRATION_VERSION,
        "mujoco": mujoco.__version__,
        **_geometry_key(foam),
        "fidelity": foam.fidelity,
        "dof": foam.dof,
        "resolution": foam.resolution,
    }
    return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:20]


def _geometry_key(foam: FoamParams) -> dict[str, Any]:
    """The object's shape and size (a mesh: its file's bytes and scale) and its Poisson ratio, as digests
    key them."""
    key: dict[str, Any] = {"shape": foam.shape, "poisson": round(foam.poisson, 4)}
    if foam.shape == "mesh":
        key["mesh_sha256"] = hashlib.sha256(Path(foam.mesh_file).read_bytes()).hexdigest()
        key["mesh_scale_m"] = foam.mesh_scale_m
    else:
        key["size_mm"] = [round(s * 1e3, 2) for s in foam.size_m]
    return key


@functools.cache
def _shipped() -> dict[str, dict[str, Any]]:
    if not SHIPPED.exists():
        return {}
    return json.loads(SHIPPED.read_text())["calibrations"]


def lookup(foam: FoamParams) -> dict[str, Any] | None:
    """The stored calibration of `foam` (shipped, then the user's cache), or None."""
    key = digest(foam)
    if key in _shipped():
        return _shipped()[key]
    path = cache_dir() / f"{key}.json"
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


@dataclass(frozen=True)
class Scale:
    """k for one foam and where it came from: `source` is "calibrated" (an FEM calibration of this very
    geometry), "law" (the shape's law, fitted through the shipped grid of calibrations) or "uncalibrated"
    (k = 1: a discretization no preset has, whose k was never measured)."""

    k: float
    source: str
    detail: dict[str, Any]

    def to_json(self) -> dict[str, Any]:
        return {"modulus_scale": self.k, "source": self.source} | self.detail


def _is_preset(foam: FoamParams) -> bool:
    preset = PRESETS["faithful" if foam.shape == "mesh" else foam.fidelity]
    return foam.dof == PRESETS[foam.fidelity].dof and foam.resolution == preset.resolution


@functools.cache
def _laws() -> dict[str, dict[str, Any]]:
    if not SHIPPED.exists():
        return {}
    return json.loads(SHIPPED.read_text()).get("laws", {})


def law_features(foam: FoamParams, law: dict[str, Any]) -> np.ndarray:
    """The law's regressors: 1, log footprint, log height (both against the law's reference), Poisson."""
    ref = law["reference"]
    footprint_m = math.sqrt(foam.size_m[0] * foam.size_m[1])
    return np.array(
        [1.0, math.log(footprint_m / ref["footprint_m"]), math.log(foam.size_m[2] / ref["height_m"]),
         foam.poisson - ref["poisson"]]
    )  # fmt: skip


def scale_of(foam: FoamParams, progress: Progress | None = None) -> Scale:
    """k for `foam`: its own calibration if one is stored (the library's ship with the package), its
    shape's law for any other primitive, and for a mesh foam a calibration made now (then stored) at
    POISSON_NODES, interpolated in the Poisson ratio. A node that one k cannot fit (_trusted) ends it
    there: the interpolated k would not be applied either, so the next node's FEM would buy nothing."""
    if not _is_preset(foam):
        return Scale(1.0, "uncalibrated", {"why": "a discretization other than its preset's"})
    entry = lookup(foam)
    if entry is not None and entry.get("uncalibrated"):  # a mesh's node the bench could not hold, at its nu
        return Scale(1.0, "uncalibrated", _summary(entry) | {"why": entry["uncalibrated"]})
    if entry is not None:
        return _trusted(Scale(float(entry["k"]), "calibrated", _summary(entry)), entry["residual"])
    if foam.shape != "mesh":
        law = _laws().get(f"{foam.shape}/{foam.fidelity}")
        if law is None:
            return Scale(1.0, "uncalibrated", {"why": f"no law shipped for {foam.shape}/{foam.fidelity}"})
        if law["mujoco"] != mujoco.__version__:  # k is MuJoCo's: a law of another version does not apply
            why = f"the shipped calibrations are MuJoCo {law['mujoco']}'s; this is {mujoco.__version__}"
            return Scale(1.0, "uncalibrated", {"why": why})
        k = float(np.exp(law_features(foam, law) @ np.asarray(law["coef"])))
        detail = {key: law[key] for key in ("fitted_on", "held_out_max_error", "date")}
        return _trusted(Scale(k, "law", detail), [law["max_residual"]])
    nodes: list[dict[str, Any]] = []
    for nu in POISSON_NODES:
        at = foam.with_overrides(poisson=nu)
        node = lookup(at)
        if node is None:  # the second node starts from the first's k: one round fewer
            node = calibrate(at, progress=progress or _stderr_line, k0=nodes[-1]["k"] if nodes else 1.0)
            store(at, node)
        if node.get("uncalibrated"):  # the bench could not hold it: cached, so it is not tried again
            return Scale(1.0, "uncalibrated", _summary(node) | {"why": node["uncalibrated"]})
        if max(abs(r) for r in node["residual"]) > MAX_RESIDUAL:  # no k serves this node: nor can one
            return _trusted(Scale(float(node["k"]), "calibrated", _summary(node)), node["residual"])
        nodes.append(node)
    (nu0, k0), (nu1, k1) = ((n["foam"]["poisson"], n["k"]) for n in nodes)
    k = float(k0 + (k1 - k0) * (foam.poisson - nu0) / (nu1 - nu0))
    detail = _summary(nodes[0]) | {"poisson_nodes": list(POISSON_NODES), "k_at_nodes": [k0, k1]}
    return _trusted(Scale(k, "calibrated", detail), [r for n in nodes for r in n["residual"]])


def _trusted(scale: Scale, residual: list[float]) -> Scale:
    """`scale`, or k = 1 where one k leaves the force more than MAX_RESIDUAL off the FEM's at some depth:
    a round top's contact widens with depth in the FEM, not on the flex's facets, and a k fitted from 2 to
    6 mm off first touch would then misstate the grasp, which works deeper (docs/foam_calibration.md)."""
    worst = max(abs(r) for r in residual)
    if worst <= MAX_RESIDUAL:
        return scale
    why = (f"one k ({scale.k:.3g}) leaves the force {100 * worst:.0f} % off the FEM's at some depth "
           f"(at most {100 * MAX_RESIDUAL:.0f} %): not applied")  # fmt: skip
    return Scale(1.0, "uncalibrated", scale.detail | {"why": why, "k_fitted": scale.k})


def _summary(entry: dict[str, Any]) -> dict[str, Any]:
    return {
        "residual": entry.get("residual"),
        "fem_dofs": entry["fem"]["dofs"],
        "fem_last_change": entry["fem"]["last_change"],
        "date": entry["provenance"]["date"],
        "mujoco": entry["provenance"]["mujoco"],
    }


def modulus_scale(foam: FoamParams, progress: Progress | None = None) -> float:
    """k for `foam` (scale_of)."""
    return scale_of(foam, progress).k


def store(foam: FoamParams, entry: dict[str, Any]) -> Path | None:
    """Write `entry` to the user's cache (atomically); None, with no error, if the cache is not writable:
    the foam is still calibrated for this process."""
    return _write_json(cache_dir() / f"{digest(foam)}.json", entry)


def _write_json(path: Path, entry: dict[str, Any]) -> Path | None:
    """`entry` written to `path` atomically; None, with no error, where the directory is not writable."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile("w", dir=path.parent, suffix=".tmp", delete=False) as tmp:
            json.dump(entry, tmp, indent=1)
        os.replace(tmp.name, path)
    except OSError:
        return None
    return path


def _stderr_line(message: str) -> None:
    print(f"twin: {message}", file=sys.stderr, flush=True)


# --------------------------------------------------------------------------------------------- the load


def _hand_around(foam: FoamParams) -> tuple[mujoco.MjModel, mujoco.MjData]:
    """The hand model with a rigid stand-in of the object (its primitive, or a mesh's bounding box) resting
    on the palm, to keep the inner links out of it."""
    from dm_control import mjcf

    from twin.assets import HAND_XML
    from twin.sim.scene import PALM_SURFACE_Z_M

    root = mjcf.from_path(str(HAND_XML))
    x, y, z = foam.size_m
    kind = {"block": "box", "cylinder": "cylinder", "sphere": "ellipsoid"}.get(foam.shape, "box")
    size = [x / 2, z / 2] if kind == "cylinder" else [x / 2, y / 2, z / 2]
    pos = [*foam.placement_m, PALM_SURFACE_Z_M + z / 2]
    root.worldbody.add("geom", name="object", type=kind, size=size, pos=pos, contype=0, conaffinity=0)
    model = mujoco.MjModel.from_xml_string(root.to_xml_string(), root.get_assets())
    return model, mujoco.MjData(model)


def fingertip_geoms(foam: FoamParams) -> list[TipGeom]:
    """The distal links' collision geoms, each finger posed by the hand's kinematics (spread 0): its inner
    link no deeper in the object than the grasp indents it (GRASP_INDENT_M), its distal link level (or as
    near level as the joints allow), its lowest point as near GRASP_INDENT_M below the top as that allows
    (1 mm of height weighs as 1 degree of tilt); then all lifted CLEARANCE_M above the object's top."""
    from twin.sim.scene import PALM_SURFACE_Z_M

    model, data = _hand_around(foam)
    obstacle = model.geom("object").id
    top_m = PALM_SURFACE_Z_M + foam.size_m[2]
    geoms: list[TipGeom] = []
    for finger in FINGERS:
        inner = model.joint(f"{finger}_inner").qposadr[0]
        outer = model.joint(f"{finger}_outer").qposadr[0]
        body = model.body(f"{finger}_outer").id
        inner_link = model.geom(f"{finger}_inner_collision").id
        ids = [model.geom(f"{finger}_{g}").id for g in TIP_GEOMS]
        best: tuple[float, np.ndarray] | None = None
        for q_inner in np.linspace(0.0, model.jnt_range[model.joint(f"{finger}_inner").id][1], 600):
            q_outer = _level_outer_angle(model, data, inner, outer, body, q_inner)
            data.qpos[outer] = q_outer
            mujoco.mj_kinematics(model, data)
            if mujoco.mj_geomDistance(model, data, inner_link, obstacle, 0.01, None) < -GRASP_INDENT_M:
                continue
            low = min(_lowest_z(model, data, g) for g in ids)
            tilt_deg = math.degrees(math.asin(min(1.0, abs(float(data.xmat[body][6])))))
            miss = abs(low - (top_m - GRASP_INDENT_M)) + 1e-3 * tilt_deg  # level first, then the height
            if best is None or miss < best[0] - 1e-6:
                best = (miss, data.qpos.copy())
        if best is None:
            raise ConfigError(
                f"foam '{foam.name}': no level pose of {finger}'s distal link clears the object"
            )
        data.qpos[:] = best[1]
        mujoco.mj_kinematics(model, data)
        lift_m = top_m + CLEARANCE_M - min(_lowest_z(model, data, g) for g in ids)
        for g in ids:
            quat = np.zeros(4)
            mujoco.mju_mat2Quat(quat, data.geom_xmat[g])
            geoms.append(
                TipGeom(
                    name=model.geom(g).name,
                    type=int(model.geom_type[g]),
                    size=tuple(float(v) for v in model.geom_size[g]),
                    pos_m=(*(float(v) for v in data.geom_xpos[g][:2]), float(data.geom_xpos[g][2] + lift_m)),
                    quat=tuple(float(v) for v in quat),
                )
            )
    return geoms


def _level_outer_angle(
    model: mujoco.MjModel, data: mujoco.MjData, inner: int, outer: int, body: int, q_inner: float
) -> float:
    """The outer joint angle that levels the distal link at this inner angle (or comes nearest)."""
    lo, hi = (float(v) for v in model.jnt_range[_joint_of(model, outer)])

    def tilt(q_outer: float) -> float:
        data.qpos[:] = 0.0
        data.qpos[inner], data.qpos[outer] = q_inner, q_outer
        mujoco.mj_kinematics(model, data)
        return float(data.xmat[body].reshape(3, 3)[2, 0])

    a, b = tilt(lo), tilt(hi)
    if a * b > 0:  # no level pose at this inner angle: the end of the range nearest level
        return lo if abs(a) < abs(b) else hi
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        m = tilt(mid)
        if (m > 0) == (a > 0):
            lo, a = mid, m
        else:
            hi = mid
    return 0.5 * (lo + hi)


def _joint_of(model: mujoco.MjModel, qposadr: int) -> int:
    return int(np.flatnonzero(model.jnt_qposadr == qposadr)[0])


def _lowest_z(model: mujoco.MjModel, data: mujoco.MjData, geom: int) -> float:
    """Lowest world z of a box or capsule geom at the present kinematics."""
    R = data.geom_xmat[geom].reshape(3, 3)
    size = model.geom_size[geom]
    z = data.geom_xpos[geom][2]
    if model.geom_type[geom] == mujoco.mjtGeom.mjGEOM_BOX:
        return float(z - np.abs(R[2]) @ size)
    radius, half = size[0], size[1]
    return float(z - abs(R[2, 2]) * half - radius)


def _tips_mjcf(parent: Any, tips: list[TipGeom], offset_m: np.ndarray, **contact: Any) -> None:
    """Add the tip geoms under `parent` (an mjcf body), shifted by -offset (their frame's origin)."""
    kinds = {int(mujoco.mjtGeom.mjGEOM_BOX): "box", int(mujoco.mjtGeom.mjGEOM_CAPSULE): "capsule"}
    for tip in tips:
        size = list(tip.size) if tip.type == mujoco.mjtGeom.mjGEOM_BOX else list(tip.size[:2])
        parent.add(
            "geom", name=tip.name, type=kinds[tip.type], size=size,
            pos=list(np.asarray(tip.pos_m) - offset_m), quat=list(tip.quat), **contact,
        )  # fmt: skip


def _gap_fn(tips: list[TipGeom]) -> Callable[[np.ndarray], np.ndarray]:
    """Rest gap along +z from points to the tip geoms, by MuJoCo's own ray cast on their exact shapes."""
    from dm_control import mjcf

    root = mjcf.RootElement(model="tips")
    _tips_mjcf(root.worldbody, tips, np.zeros(3))
    model = mujoco.MjModel.from_xml_string(root.to_xml_string())
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    up = np.array([0.0, 0.0, 1.0])
    geomid = np.zeros(1, dtype=np.int32)

    def gap(points_m: np.ndarray) -> np.ndarray:
        out = np.empty(len(points_m))
        for i, p in enumerate(points_m):
            d = mujoco.mj_ray(model, data, np.asarray(p, float), up, None, 1, -1, geomid)
            out[i] = d if d >= 0 else np.inf
        return out

    return gap


# ------------------------------------------------------------------------------------------ the FEM side


def reference_mesh(foam: FoamParams, edge_top_m: float, edge_far_m: float) -> Any:
    """The FEM's tetrahedral mesh of `foam` in the palm frame (resting on the palm at its placement):
    `edge_top_m` within 12 mm of its top and of its bottom (the palm's contact), `edge_far_m` elsewhere."""
    from twin.sim.scene import PALM_SURFACE_Z_M
    from twin.sim.tetmesh import TetMesh, _extract_tets, _foam_gmsh, decimated_surface, load_surface

    x, y, z = foam.size_m
    if foam.shape == "mesh":  # decimated before gmsh's session: in a worker a Ctrl-C ends at once
        scan = load_surface(Path(foam.mesh_file), foam.mesh_scale_m)
        surface = decimated_surface(scan, edge_top_m, f"mesh file '{foam.mesh_file}'")
    with _foam_gmsh() as gmsh:
        occ = gmsh.model.occ
        if foam.shape == "block":
            occ.addBox(-x / 2, -y / 2, -z / 2, x, y, z)
        elif foam.shape == "cylinder":
            tag = occ.addCylinder(0, 0, -z / 2, 0, 0, z, x / 2)
            occ.dilate([(3, tag)], 0, 0, 0, 1.0, y / x, 1.0)
        elif foam.shape == "sphere":
            tag = occ.addSphere(0, 0, 0, x / 2)
            occ.dilate([(3, tag)], 0, 0, 0, 1.0, y / x, z / x)
        else:
            _add_surface_volume(gmsh, surface, remesh=surface is scan)
        if foam.shape != "mesh":
            occ.synchronize()
        field = gmsh.model.mesh.field
        bands = []
        flat_bottom = foam.shape in ("block", "cylinder")  # seated on the palm: no contact to resolve there
        for z0, z1 in ((z / 2 - 0.012, 1.0), (-1.0, -z / 2 + 0.012))[: 1 if flat_bottom else 2]:
            band = field.add("Box")
            for key, value in (
                ("VIn", edge_top_m),
                ("VOut", edge_far_m),
                ("XMin", -1),
                ("XMax", 1),
                ("YMin", -1),
                ("YMax", 1),
                ("ZMin", z0),
                ("ZMax", z1),
                ("Thickness", 0.006),
            ):
                field.setNumber(band, key, value)  # fmt: skip
            bands.append(band)
        box = field.add("Min")
        field.setNumbers(box, "FieldsList", bands)
        field.setAsBackgroundMesh(box)
        for opt in (
            "Mesh.MeshSizeExtendFromBoundary",
            "Mesh.MeshSizeFromPoints",
            "Mesh.MeshSizeFromCurvature",
        ):
            gmsh.option.setNumber(opt, 0)
        gmsh.option.setNumber("Mesh.MeshSizeMax", edge_far_m)
        gmsh.model.mesh.generate(3)
        mesh = _extract_tets(gmsh)
    shift = np.array([*foam.placement_m, PALM_SURFACE_Z_M + z / 2])
    return TetMesh(mesh.points_m + shift, mesh.tets)


def _add_surface_volume(gmsh: Any, surface: Any, remesh: bool) -> None:
    """A volume bounded by a closed triangulated surface (centred on its bounding box), for meshing."""
    from twin.sim.tetmesh import _FEATURE_ANGLE_RAD, _GMSH_TRIANGLE

    model = gmsh.model
    centre = (surface.points_m.min(axis=0) + surface.points_m.max(axis=0)) / 2.0
    entity = model.addDiscreteEntity(2)
    model.mesh.addNodes(
        2, entity, np.arange(1, len(surface.points_m) + 1), (surface.points_m - centre).ravel()
    )
    model.mesh.addElementsByType(entity, _GMSH_TRIANGLE, [], (surface.triangles + 1).ravel())
    if remesh:  # a decimated scan is already at the mesh's density: kept as it is
        model.mesh.classifySurfaces(_FEATURE_ANGLE_RAD, True, True, math.pi)
        model.mesh.createGeometry()
    loop = model.geo.addSurfaceLoop([tag for _, tag in model.getEntities(2)])
    model.geo.addVolume([loop])
    model.geo.synchronize()


def fem_digest(foam: FoamParams, tips: list[TipGeom]) -> str:
    """What the FEM's forces depend on: the geometry, the Poisson ratio, the fingertips' poses and the FEM's
    own settings and versions. Not the flex's discretization nor MuJoCo: both presets of a shape share it."""
    key: dict[str, Any] = {
        "version": CALIBRATION_VERSION,
        "levels_m": FEM_LEVELS_M,
        "converged": FEM_CONVERGED,
        "depths_m": DEPTHS_M,
        "scikit_fem": _version("scikit-fem"),
        "gmsh": _version("gmsh"),
        **_geometry_key(foam),
        "placement_mm": [round(p * 1e3, 2) for p in foam.placement_m],
        "tips": [[t.name, t.type, *(round(v, 7) for v in (*t.size, *t.pos_m, *t.quat))] for t in tips],
    }
    return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:20]


def cached_fem_force_per_pa(foam: FoamParams, tips: list[TipGeom]) -> tuple[np.ndarray, dict[str, Any]]:
    """fem_force_per_pa, read back from the cache (fem/) where this geometry, Poisson ratio and load were
    solved before (the other preset's calibration of the same foam), else solved and stored there."""
    path = cache_dir() / "fem" / f"{fem_digest(foam, tips)}.json"
    try:
        stored = json.loads(path.read_text())
        force = np.array(stored["force_per_pa_n"], dtype=float)
        if force.shape == (len(DEPTHS_M),) and np.all(force > 0) and isinstance(stored["info"], dict):
            return force, stored["info"] | {"reused": path.name}  # anything else: solved again
    except (OSError, ValueError, KeyError, TypeError):
        pass
    force, info = fem_force_per_pa(foam, tips)
    _write_json(path, {"force_per_pa_n": [float(f) for f in force], "info": info})
    return force, info


def fem_force_per_pa(foam: FoamParams, tips: list[TipGeom]) -> tuple[np.ndarray, dict[str, Any]]:
    """The FEM's force on the links at DEPTHS_M per pascal of E, refined (FEM_LEVELS_M) until the deepest
    force changes by less than FEM_CONVERGED; the record says how it converged."""
    from twin.sim.fem import indentation_force_per_pa

    t0 = time.process_time()
    gap = _gap_fn(tips)
    record, previous = [], None
    for edge_top_m, edge_far_m in FEM_LEVELS_M:
        result = indentation_force_per_pa(
            reference_mesh(foam, edge_top_m, edge_far_m), foam.poisson, gap, DEPTHS_M
        )
        force = np.array(result.force_per_pa_n)
        change = None if previous is None else float(abs(force[-1] / previous[-1] - 1.0))
        record.append({"edge_top_m": edge_top_m, "edge_far_m": edge_far_m, "dofs": result.dofs,
                       "force_per_pa_n": [float(f) for f in force], "change": change})  # fmt: skip
        previous = force
        if change is not None and change < FEM_CONVERGED:
            break
    info = {
        "element": "quadratic tetrahedra (scikit-fem ElementTetP2), small-strain linear elasticity",
        "contact": "rigid frictionless unilateral (primal-dual active set); palm: unilateral, held sideways",
        "dofs": result.dofs,
        "contact_candidates": result.candidates,
        "active_set_iterations": list(result.iterations),
        "equilibrium": [
            round(s / f, 4) for s, f in zip(result.support_per_pa_n, result.force_per_pa_n, strict=True)
        ],
        "convergence": record,
        "last_change": record[-1]["change"],
        "cpu_s": round(time.process_time() - t0, 2),
    }
    return previous, info


# ------------------------------------------------------------------------------------------- the twin side


def bench_model(
    foam: FoamParams, tips: list[TipGeom], modulus_scale: float, probe: bool = False
) -> mujoco.MjModel:
    """The foam resting on the palm (a plate with the palm's contact), the tips on one mocap body above.
    `probe`: the tips see the foam from afar (margin) without ever acting on it (gap), to measure where
    they would touch; a margin shifts the contact's own reference, so the bench itself has none."""
    from dm_control import mjcf

    from twin.sim.scene import PALM_SURFACE_Z_M, add_foam, compile_scene

    root = mjcf.RootElement(model="foam_calibration")
    root.option.timestep = 0.002
    root.option.integrator = "discrete"
    root.worldbody.add(
        "geom", name="palm", type="box", size=[0.1, 0.1, 0.005], pos=[0, 0, PALM_SURFACE_Z_M - 0.005],
        friction=[PALM_FRICTION, 0.005, 0.0001], solref=[0.004, 1.0], solimp=list(RIGID_SOLIMP), priority=5,
    )  # fmt: skip
    body = root.worldbody.add("body", name="tips", mocap=True, pos=[0, 0, 0])
    finger = dict(friction=[1.0, 0.005, 0.0001], solref=[0.004, 1.0], solimp=[0.95, 0.99, 0.001])
    reach = dict(margin=2 * CLEARANCE_M, gap=2 * CLEARANCE_M) if probe else {}
    _tips_mjcf(body, tips, np.zeros(3), **reach, **finger)
    add_foam(root, foam, modulus_scale=modulus_scale)
    return compile_scene(root)


def bench_force_n(foam: FoamParams, tips: list[TipGeom], modulus_scale: float) -> np.ndarray:
    """MuJoCo's force on the tips at DEPTHS_M from first touch: settle, then ramp and hold each depth
    (the mean over the last third of each hold)."""
    return _bench(foam, tips, modulus_scale)[0]


def _bench(
    foam: FoamParams, tips: list[TipGeom], modulus_scale: float, vertices: list[np.ndarray] | None = None
) -> tuple[np.ndarray, float]:
    """bench_force_n's forces, and how far (m) the foam's centre moved across the palm meanwhile: a
    round-bottomed object may topple off the tips' line, where the FEM holds its base. `vertices`, where
    given, gets the flex's vertex positions (n, 3) once settled and at the end of each depth's hold."""
    model = bench_model(foam, tips, modulus_scale)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    start_m = data.flexvert_xpos.mean(axis=0)
    dt = model.opt.timestep
    for _ in range(round(SETTLE_S / dt)):
        mujoco.mj_step(model, data)
    tip_ids = {model.geom(t.name).id for t in tips}
    if vertices is not None:
        vertices.append(data.flexvert_xpos.copy())
    probe = bench_model(foam, tips, modulus_scale, probe=True)
    seen = mujoco.MjData(probe)
    seen.qpos[:], seen.mocap_pos[:] = data.qpos, data.mocap_pos
    mujoco.mj_forward(probe, seen)
    gaps = [c.dist for c in seen.contact[: seen.ncon] if c.geom[0] in tip_ids or c.geom[1] in tip_ids]
    if not gaps:
        raise ConfigError(f"foam '{foam.name}': the fingertips do not reach it in the calibration bench")
    touch_m = float(min(gaps))  # MuJoCo's own distance (flex faces and radius included) before the touch
    n_ramp, n_hold = round(RAMP_S / dt), round(HOLD_S / dt)
    forces, previous = [], 0.0
    wrench = np.zeros(6)
    for depth in DEPTHS_M:
        samples = []
        for i in range(n_ramp + n_hold):
            d = previous + (depth - previous) * min(1.0, (i + 1) / n_ramp)
            data.mocap_pos[0, 2] = -(touch_m + d)
            mujoco.mj_step(model, data)
            if i >= n_ramp + 2 * n_hold // 3:
                total = 0.0
                for c in range(data.ncon):
                    con = data.contact[c]
                    if con.geom[0] in tip_ids or con.geom[1] in tip_ids:
                        mujoco.mj_contactForce(model, data, c, wrench)
                        fz = (con.frame.reshape(3, 3).T @ wrench[:3])[2]  # on geom2 from geom1
                        total += fz if con.geom[0] in tip_ids else -fz
                samples.append(-total)  # the foam pushes the tips up
        forces.append(float(np.mean(samples)))
        if vertices is not None:
            vertices.append(data.flexvert_xpos.copy())
        previous = depth
    moved_m = float(np.linalg.norm((data.flexvert_xpos.mean(axis=0) - start_m)[:2]))
    return np.array(forces), moved_m


def calibrate(foam: FoamParams, progress: Progress | None = None, k0: float = 1.0) -> dict[str, Any]:
    """Fit k for `foam` (at REFERENCE_YOUNG_PA), starting from `k0`, and say where it came from: the entry
    the caches store."""
    say = progress or (lambda _message: None)
    t0 = time.perf_counter()
    bench = foam.with_overrides(young_pa=REFERENCE_YOUNG_PA, placement_m=(0.0, 0.0))
    say(f"calibrating foam '{foam.name}' at nu = {foam.poisson:g} against an FEM of the fingertips' contact "
        "(first use of this shape and fidelity; stored for next time)...")  # fmt: skip
    tips = fingertip_geoms(bench)
    try:
        fem_per_pa, fem_info = cached_fem_force_per_pa(bench, tips)
    except Exception as exc:  # gmsh or the solver on a shape it cannot handle: one line
        detail = " ".join(str(exc).split()) or type(exc).__name__
        raise ConfigError(
            f"foam '{foam.name}': the FEM of its fingertip contact cannot be built: {detail}"
        ) from None
    target = fem_per_pa * REFERENCE_YOUNG_PA
    say(f"FEM: {' / '.join(f'{f:.2f}' for f in target)} N at 2 / 4 / 6 mm; fitting the flex...")
    k, rounds = k0, []
    for _ in range(MAX_FIT_ROUNDS):
        force, moved_m = _bench(bench, tips, k)
        if not (force > 0).all():  # no contact at some depth: nothing to fit (and no log of zero)
            cause = (f"the object moved {1e3 * moved_m:.0f} mm across the palm (it toppled or rolled)"
                     if moved_m > TOPPLED_M else "MuJoCo found no contact where the FEM did")  # fmt: skip
            why = (f"the bench read {' / '.join(f'{f:.2f}' for f in force)} N at 2 / 4 / 6 mm where the "
                   f"FEM, which holds the base, read {' / '.join(f'{f:.2f}' for f in target)} N: {cause}; "
                   "it cannot be calibrated resting on the palm: k = 1")  # fmt: skip
            say(f"foam '{foam.name}': {why}")
            return _entry(foam, bench, t0, 1.0, target, force, None, rounds, fem_info) | {"uncalibrated": why}
        ratio = float(np.exp(np.mean(np.log(target / force))))
        rounds.append({"k": k, "force_n": [round(float(f), 4) for f in force]})
        k *= ratio
        if abs(ratio - 1.0) < FIT_TOLERANCE:
            break
    residual = force / target - 1.0
    if not (math.isfinite(k) and k > 0):
        raise ConfigError(f"foam '{foam.name}': the flex's force could not be fitted to the FEM's (k = {k})")
    return _entry(foam, bench, t0, k, target, force, residual, rounds, fem_info)


def _entry(
    foam: FoamParams,
    bench: FoamParams,
    t0: float,
    k: float,
    target: np.ndarray,
    force: np.ndarray,
    residual: np.ndarray | None,
    rounds: list[dict[str, Any]],
    fem_info: dict[str, Any],
) -> dict[str, Any]:
    """What a calibration stores: k, the load, both forces, the fit's rounds and the provenance."""
    return {
        "k": round(k, 5),
        "foam": {
            key: bench.to_json()[key]
            for key in ("shape", "size_m", "poisson", "fidelity", "dof", "resolution")
        }
        | ({"mesh_file": Path(foam.mesh_file).name} if foam.shape == "mesh" else {}),
        "load": "the three distal links (bh8.xml collision geoms), level, pressed 2 / 4 / 6 mm into the top",
        "fem_force_n": [round(float(f), 4) for f in target],
        "twin_force_n": [round(float(f), 4) for f in force],
        "residual": None if residual is None else [round(float(r), 4) for r in residual],
        "reference_young_pa": REFERENCE_YOUNG_PA,
        "fit_rounds": rounds,
        "fem": fem_info,
        "provenance": {
            "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
            "mujoco": mujoco.__version__,
            "scikit_fem": _version("scikit-fem"),
            "gmsh": _version("gmsh"),
            "calibration_version": CALIBRATION_VERSION,
            "wall_s": round(time.perf_counter() - t0, 1),
        },
    }


def _version(dist: str) -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(dist)
    except PackageNotFoundError:
        return "absent"
