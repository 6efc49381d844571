"""The twin's bulge against the material's: what Poisson ratio a material has whose lateral strain the
twin's shows (issue 38).

`twin identify` reads nu from the cameras through twin simulations (twin.sim.poisson): the nu at which
the twin's object widens as the run's did. That is the material's nu only where the flex widens as the
material does, and it does not everywhere (the coarse fast foam widens ~35 % less than the FEM on the
library block; benchmarks/nu_reference.py). The reference is the calibration's own load case and FEM
(twin.sim.calibration, twin.sim.fem: the three level distal links pressed into the top, the base held
on the palm): per object and preset, the width's strain over the top's (-eps_x / eps_z, read from the
x faces as the cameras read them: twin.vision.lateral_strain's band and face depth) at the deepest depth
and at two Poisson ratios, for the FEM and for the calibrated flex. Both move linearly with nu over
the foams' range (the FEM: 0.181 / 0.256 / 0.330 on the block at 0.2 / 0.275 / 0.35), so a twin's nu maps
to the material's through two lines: the material whose FEM ratio equals the twin's ratio at that nu.

The map assumes the flex's bulge is off the material's by the same in the grasp as under this load (the
grasp was not compared with an FEM: it also holds the object's y sides). Cached like k: shipped for
the library foams (bulge_maps.json), made at first use for anything else (two FEM solves and two bench
runs: 12-30 s on 2 cores for the library's shapes; a scan first needs its k, 40-60 s in all).
"""

from __future__ import annotations

import datetime
import functools
import hashlib
import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from twin.sim import calibration
from twin.sim.foam import FoamParams

BULGE_VERSION = 1
"""Bumped whenever the load, the reading or the FEM's mesh change: every cached map is then stale."""
POISSONS = (0.2, 0.35)
"""The Poisson ratios both lines go through: the ends of the range the twin reads nu over
(twin.sim.poisson.SIM_POISSON)."""
FEM_EDGES_M = calibration.FEM_LEVELS_M[-1]
"""The calibration's finest FEM level (element size near the contacts, elsewhere): the block's force
changed 0.0 % from the level before."""
MATERIAL_POISSON = (0.0, 0.5)
"""The Poisson ratios an isotropic material can have (a foam's: 0-0.5)."""
SHIPPED = Path(__file__).with_name("bulge_maps.json")


@dataclass(frozen=True)
class BulgeMap:
    """-eps_x / eps_z at the deepest calibration depth, FEM and calibrated flex, at POISSONS: the two
    lines a twin's nu is read through to the material's."""

    fidelity: str
    poisson: tuple[float, float]
    fem_ratio: tuple[float, float]
    twin_ratio: tuple[float, float]
    depth_m: float
    provenance: dict[str, Any]

    @property
    def fem_slope(self) -> float:
        """How fast the material's ratio moves with nu (1 for a free uniaxial compression)."""
        return (self.fem_ratio[1] - self.fem_ratio[0]) / (self.poisson[1] - self.poisson[0])

    @property
    def twin_slope(self) -> float:
        """How fast the twin's ratio moves with its nu."""
        return (self.twin_ratio[1] - self.twin_ratio[0]) / (self.poisson[1] - self.poisson[0])

    def material_poisson(self, twin_poisson: float) -> float:
        """The nu of a material whose FEM ratio is the twin's at `twin_poisson` (the lines extended
        linearly; not cut to what a material can have)."""
        twin = self.twin_ratio[0] + self.twin_slope * (twin_poisson - self.poisson[0])
        return self.poisson[0] + (twin - self.fem_ratio[0]) / self.fem_slope

    def equivalent(self, twin_poisson: float, twin_ci95: tuple[float, float]) -> dict[str, Any]:
        """A twin's read of nu as the material's (results-file form): the value and its 95 % interval
        mapped, the interval cut to MATERIAL_POISSON. Where the value lies outside that, no material of
        this shape bulges as the twin did: the read has no material meaning, and no interval is given."""
        if not self.fem_slope > 0:
            return {"unavailable": "the FEM's bulge does not grow with nu on this shape: it does not tell nu"}
        value = self.material_poisson(twin_poisson)
        low, high = MATERIAL_POISSON
        within = bool(low <= value < high)
        ends = sorted(float(np.clip(self.material_poisson(v), low, high)) for v in twin_ci95)
        return {
            "poisson": round(value, 4),
            "poisson_ci95": [round(v, 4) for v in ends] if within else None,
            "within_materials": within,
            "fem_ratio": list(self.fem_ratio),
            "twin_ratio": list(self.twin_ratio),
            "at_poisson": list(self.poisson),
            "twin_modulus_scale": self.provenance.get("flex_modulus_scale"),
            "reference": "scikit-fem (twin.sim.fem) under the calibration's load, the x faces read as the "
            "cameras read them (twin.sim.bulge)",
        }

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> BulgeMap:
        return cls(
            fidelity=str(data["fidelity"]),
            poisson=tuple(float(v) for v in data["poisson"]),
            fem_ratio=tuple(float(v) for v in data["fem_ratio"]),
            twin_ratio=tuple(float(v) for v in data["twin_ratio"]),
            depth_m=float(data["depth_m"]),
            provenance=dict(data["provenance"]),
        )


def face_shift_m(
    rest_m: np.ndarray, moved_m: np.ndarray, sign: float, palm_z_m: float, height_m: float
) -> float:
    """The median outward shift along x of one x face's points (rest (n, 3) to moved (n, 3)), the face as
    the cameras read it: the points in FACE_BAND within FACE_DEPTH_M of the band's outermost."""
    from twin.vision.lateral_strain import FACE_BAND, FACE_DEPTH_M

    lo, hi = (palm_z_m + f * height_m for f in FACE_BAND)
    band = (rest_m[:, 2] > lo) & (rest_m[:, 2] < hi)
    if not band.any():
        raise ValueError("no point in the cameras' band of heights")
    x = sign * rest_m[:, 0]
    face = band & (x > x[band].max() - FACE_DEPTH_M)
    return float(np.median(sign * (moved_m[face, 0] - rest_m[face, 0])))


def lateral_ratio(
    rest_m: np.ndarray, moved_m: np.ndarray, depth_m: float, size_m: tuple[float, ...], palm_z_m: float
) -> float:
    """-eps_x / eps_z: the width's strain along x (the two faces' outward shifts over the width) over
    the top's (depth over height). A rigid shift along x cancels."""
    width_m, height_m = size_m[0], size_m[2]
    grown_m = sum(face_shift_m(rest_m, moved_m, s, palm_z_m, height_m) for s in (1.0, -1.0))
    return (grown_m / width_m) / (depth_m / height_m)


def measure(foam: FoamParams) -> BulgeMap:
    """The FEM's and the calibrated flex's ratio for `foam`'s geometry and preset at POISSONS: two FEM
    solves and two bench runs (twin.sim.calibration's load, at its reference modulus)."""
    from twin.sim.fem import indentation_force_per_pa
    from twin.sim.scene import PALM_SURFACE_Z_M

    t0 = time.perf_counter()
    fem, twin, scales = [], [], []
    depth_m = calibration.DEPTHS_M[-1]
    for nu in POISSONS:
        at = foam.with_overrides(poisson=nu, young_pa=calibration.REFERENCE_YOUNG_PA, placement_m=(0.0, 0.0))
        tips = calibration.fingertip_geoms(at)
        mesh = calibration.reference_mesh(at, *FEM_EDGES_M)
        solved = indentation_force_per_pa(
            mesh, nu, calibration._gap_fn(tips), calibration.DEPTHS_M, keep_displacement=True
        )
        moved = mesh.points_m + solved.vertex_displacement_m[-1].T
        fem.append(lateral_ratio(mesh.points_m, moved, depth_m, at.size_m, PALM_SURFACE_Z_M))
        scale = calibration.scale_of(at)
        vertices: list[np.ndarray] = []
        calibration._bench(at, tips, scale.k, vertices)
        twin.append(lateral_ratio(vertices[0], vertices[-1], depth_m, at.size_m, PALM_SURFACE_Z_M))
        scales.append({"k": scale.k, "source": scale.source})
    return BulgeMap(
        fidelity=foam.fidelity,
        poisson=POISSONS,
        fem_ratio=(round(fem[0], 5), round(fem[1], 5)),
        twin_ratio=(round(twin[0], 5), round(twin[1], 5)),
        depth_m=depth_m,
        provenance={
            "flex_modulus_scale": scales,
            "fem_edges_m": list(FEM_EDGES_M),
            "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
            "mujoco": mujoco.__version__,
            "bulge_version": BULGE_VERSION,
            "wall_s": round(time.perf_counter() - t0, 1),
        },
    )


def digest(foam: FoamParams) -> str:
    """What a map depends on: the geometry, the preset's discretization, MuJoCo, the FEM's mesh and the
    calibration (k): not E, nu or the placement."""
    geometry = {key: v for key, v in calibration._geometry_key(foam).items() if key != "poisson"}
    key = {
        "bulge_version": BULGE_VERSION,
        "calibration_version": calibration.CALIBRATION_VERSION,
        "mujoco": mujoco.__version__,
        "fem_edges_m": FEM_EDGES_M,
        **geometry,
        "fidelity": foam.fidelity,
        "dof": foam.dof,
        "resolution": foam.resolution,
    }
    return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:20]


@functools.cache
def _shipped() -> dict[str, dict[str, Any]]:
    if not SHIPPED.exists():
        return {}
    return json.loads(SHIPPED.read_text())["maps"]


def _cache_path(foam: FoamParams) -> Path:
    return calibration.cache_dir() / "bulge" / f"{digest(foam)}.json"


def lookup(foam: FoamParams) -> BulgeMap | None:
    """The stored map of `foam` (shipped, then the user's cache), or None."""
    key = digest(foam)
    if key in _shipped():
        return BulgeMap.from_json(_shipped()[key])
    try:
        return BulgeMap.from_json(json.loads(_cache_path(foam).read_text()))
    except (OSError, ValueError, KeyError, TypeError):
        return None


def bulge_map(foam: FoamParams, progress: calibration.Progress | None = None) -> BulgeMap:
    """`foam`'s map: stored, else measured now (with a progress line) and stored in the user's cache."""
    stored = lookup(foam)
    if stored is not None:
        return stored
    say = progress or calibration._stderr_line
    say(f"measuring how foam '{foam.name}' ({foam.fidelity}) bulges against an FEM (first use: 4 solves)...")
    made = measure(foam)
    calibration._write_json(_cache_path(foam), made.to_json())
    return made
