"""The foam library: flexcomp foam objects described by parameters and validated up front.

An object is a FoamParams; the scene composes it into MJCF with dm_control.mjcf (no copied XML).
Stiffness classes follow flexible polyurethane foams (soft ~10-20 kPa, medium ~30-60 kPa,
firm ~100-300 kPa Young's modulus; Poisson ratio ~0.2-0.35; density ~20-60 kg/m^3).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any, Literal

from twin.interface.errors import ConfigError

Shape = Literal["block", "cylinder", "sphere", "mesh"]
Dof = Literal["trilinear", "quadratic", "full"]
Fidelity = Literal["fast", "faithful"]
SHAPES: tuple[str, ...] = ("block", "cylinder", "sphere", "mesh")
DOFS: tuple[str, ...] = ("trilinear", "quadratic", "full")
FIDELITIES: tuple[str, ...] = ("fast", "faithful")
FLEXCOMP_TYPE = {"block": "box", "cylinder": "cylinder", "sphere": "ellipsoid"}


@dataclass(frozen=True)
class Discretization:
    """How a fidelity preset meshes a foam for MuJoCo, and how its surface meets rigid bodies.

    `volumetric`: a tetrahedral mesh of the whole volume (twin.sim.tetmesh, gmsh) with `resolution`
    vertices along the longest extent; otherwise a flexcomp primitive with `resolution` vertices per axis.
    Contacts: MuJoCo's soft constraints are scaled by the effective mass, and a foam vertex weighs
    ~0.1 g, so the fingers' solref/solimp let a light flex sink in by as much as the dent itself; the
    faithful foam takes the contact (priority over the fingers) with an impedance of 0.9999 throughout."""

    volumetric: bool
    dof: Dof
    resolution: int
    solref: tuple[float, float]
    solimp: tuple[float, float, float]
    priority: int
    armature_kg: float = 0.0
    """Inertia added to every vertex dof (no weight): it conditions MuJoCo's M + h^2 K solve so CG meets
    its tolerance in fewer iterations (benchmarks/foam_solver_study.py); 1e-3 kg puts a vertex's own
    frequency near 115 Hz, far above the 0.5 Hz squeeze and the 30 Hz readings."""


PRESETS: dict[str, Discretization] = {
    "fast": Discretization(
        volumetric=False,
        dof="trilinear",
        resolution=4,
        solref=(0.004, 1.0),
        solimp=(0.95, 0.99, 0.001),
        priority=0,
    ),
    "faithful": Discretization(
        volumetric=True,
        dof="full",
        resolution=6,
        solref=(0.004, 1.0),
        solimp=(0.9999, 0.9999, 0.001),
        priority=1,
        armature_kg=1e-3,
    ),
}
"""The fidelity presets (BENCHMARKS.md, foam fidelity: figures of each against the FEM reference)."""

MAX_HALF_WIDTH_M = 0.045
"""Largest footprint half-width that clears the finger roots (inner joints at |y| = 50 mm, link
palmar face 12.5 mm inboard: models/barrett_mjcf/README.md)."""
MAX_HEIGHT_M = 0.110
"""Tallest object the closed fingers still wrap (fingertips reach ~150 mm above the wrist)."""
MIN_SIZE_M = 0.015
MAX_PLACEMENT_M = 0.010
"""Farthest an object's centre may sit from the palm's centre: a lab places it by hand, within millimetres."""


@dataclass(frozen=True, kw_only=True)
class FoamParams:
    """A foam object: geometry, material and discretization. Sizes are full extents (m)."""

    name: str
    shape: Shape
    size_m: tuple[float, float, float]
    young_pa: float
    poisson: float
    damping: float = 0.002
    """Flex elasticity damping (MuJoCo <elasticity damping>, s): a Kelvin-Voigt time constant."""
    density_kg_m3: float = 30.0
    fidelity: Fidelity = "fast"
    """Discretization preset (PRESETS): `fast` (8 trilinear nodes) or `faithful` (a volumetric mesh)."""
    resolution: int | None = None
    """Vertices per axis (fast) or along the longest extent (faithful); None: the preset's."""
    dof: Dof | None = None
    """MuJoCo flex dof (full, quadratic or trilinear); None: the preset's."""
    mesh_file: str = ""
    """A closed .stl/.obj surface for shape "mesh" (mesh_object(): size_m is then its extents)."""
    mesh_scale_m: float = 0.001
    """Metres per mesh-file unit (scanners and CAD export millimetres)."""
    friction: float = 0.8
    placement_m: tuple[float, float] = (0.0, 0.0)
    """Where the object's centre sits on the palm, from the palm's centre along the hand frame's x and
    y (m): a lab places an object by hand, a few millimetres off."""
    stiffness_class: str = ""
    rgba: tuple[float, float, float, float] = (0.95, 0.75, 0.35, 1.0)

    def __post_init__(self) -> None:
        preset = PRESETS.get(self.fidelity)
        if preset is not None:  # fill the preset's discretization; validate() refuses an unknown fidelity
            if self.resolution is None:  # a mesh foam's surface is always its tetrahedral mesh's
                mesh = self.shape == "mesh"
                object.__setattr__(
                    self, "resolution", PRESETS["faithful" if mesh else self.fidelity].resolution
                )
            if self.dof is None:
                object.__setattr__(self, "dof", preset.dof)
        validate(self)

    @property
    def discretization(self) -> Discretization:
        """The preset with this object's dof and resolution."""
        return replace(PRESETS[self.fidelity], dof=self.dof, resolution=self.resolution)

    @property
    def edge_m(self) -> float:
        """Target edge length of a tetrahedral mesh (m): the longest extent over resolution - 1."""
        return max(self.size_m) / (self.resolution - 1)

    @property
    def volume_m3(self) -> float:
        """Volume of the ideal shape (m^3)."""
        x, y, z = self.size_m
        if self.shape == "block":
            return x * y * z
        if self.shape == "cylinder":
            return math.pi * (x / 2) * (y / 2) * z
        if self.shape == "mesh":
            from twin.sim.scene import foam_mesh  # gmsh: only for mesh foams; the scene's (cached) mesh

            return foam_mesh(self).volume_m3
        return 4.0 / 3.0 * math.pi * (x / 2) * (y / 2) * (z / 2)

    @property
    def mass_kg(self) -> float:
        """Total mass (kg)."""
        return self.density_kg_m3 * self.volume_m3

    def to_json(self) -> dict[str, Any]:
        """Plain-JSON parameters (for `twin objects --json` and run metadata)."""
        d = asdict(self)
        d["size_m"] = list(self.size_m)
        d["placement_m"] = list(self.placement_m)
        d["rgba"] = list(self.rgba)
        d["mass_kg"] = self.mass_kg
        return d

    def with_overrides(self, **overrides: Any) -> FoamParams:
        """A copy with some parameters replaced (validated); None values are ignored. A new fidelity
        brings its preset's dof and resolution unless those are given too."""
        given = {k: v for k, v in overrides.items() if v is not None}
        unknown = set(given) - {f.name for f in fields(self)}
        if unknown:
            raise ConfigError(f"unknown foam parameter(s): {', '.join(sorted(unknown))}")
        if "fidelity" in given and given["fidelity"] != self.fidelity:
            given = {"dof": None, "resolution": None} | given
        return replace(self, **given)


def _fail(params: FoamParams, message: str) -> None:
    raise ConfigError(f"foam '{params.name}': {message}")


def validate(p: FoamParams) -> None:
    """Raise ConfigError (one line) for a physically invalid or ill-fitting object."""
    finite = all(math.isfinite(v) for v in (*p.size_m, p.young_pa, p.poisson, p.damping, p.density_kg_m3))
    if not finite:
        _fail(p, "parameters must be finite numbers")
    if p.shape not in SHAPES:
        _fail(p, f"unknown shape '{p.shape}' (choose from {', '.join(SHAPES)})")
    if p.fidelity not in FIDELITIES:
        _fail(p, f"unknown fidelity '{p.fidelity}' (choose from {', '.join(FIDELITIES)})")
    if (p.shape == "mesh") != bool(p.mesh_file):
        _fail(p, "a mesh foam needs a mesh file, and only a mesh foam takes one")
    if p.dof not in DOFS:
        _fail(p, f"unknown discretization '{p.dof}' (choose from {', '.join(DOFS)})")
    if not p.young_pa > 0:
        _fail(p, f"Young's modulus must be > 0 Pa, got {p.young_pa:g}")
    if not 0.0 <= p.poisson < 0.5:
        _fail(p, f"Poisson ratio must be in [0, 0.5), got {p.poisson:g}")
    if p.damping < 0:
        _fail(p, f"damping must be >= 0, got {p.damping:g}")
    if not p.density_kg_m3 > 0:
        _fail(p, f"density must be > 0 kg/m^3, got {p.density_kg_m3:g}")
    if len(p.size_m) != 3:
        _fail(p, "size_m needs 3 extents (x, y, z)")
    if min(p.size_m) < MIN_SIZE_M:
        _fail(p, f"every extent must be >= {MIN_SIZE_M * 1e3:.0f} mm, got {_mm(p.size_m)}")
    if max(p.size_m[0], p.size_m[1]) / 2 > MAX_HALF_WIDTH_M or p.size_m[2] > MAX_HEIGHT_M:
        _fail(
            p,
            f"{_mm(p.size_m)} does not fit in the hand (footprint <= "
            f"{2 * MAX_HALF_WIDTH_M * 1e3:.0f} mm, height <= {MAX_HEIGHT_M * 1e3:.0f} mm)",
        )
    if not isinstance(p.resolution, int) or not 3 <= p.resolution <= 12:
        _fail(p, f"resolution must be 3-12 vertices per axis, got {p.resolution}")
    if len(p.placement_m) != 2 or not all(math.isfinite(v) for v in p.placement_m):
        _fail(p, "placement_m needs 2 finite offsets (x, y)")
    if max(abs(v) for v in p.placement_m) > MAX_PLACEMENT_M:
        _fail(
            p,
            f"placement {_mm(p.placement_m)} is over {MAX_PLACEMENT_M * 1e3:.0f} mm off the palm centre",
        )
    if max(abs(o) + s / 2 for o, s in zip(p.placement_m, p.size_m[:2], strict=False)) > MAX_HALF_WIDTH_M:
        _fail(p, f"{_mm(p.size_m)} placed {_mm(p.placement_m)} off centre reaches the finger roots")
    if not 0 < p.friction <= 3:
        _fail(p, f"friction must be in (0, 3], got {p.friction:g}")


def _mm(size_m: tuple[float, ...]) -> str:
    return " x ".join(f"{s * 1e3:.0f}" for s in size_m) + " mm"


LIBRARY: dict[str, FoamParams] = {
    p.name: p
    for p in (
        FoamParams(
            name="block",
            shape="block",
            size_m=(0.060, 0.060, 0.070),
            young_pa=40e3,
            poisson=0.3,
            stiffness_class="medium",
        ),
        FoamParams(
            name="soft_block",
            shape="block",
            size_m=(0.060, 0.060, 0.070),
            young_pa=15e3,
            poisson=0.25,
            density_kg_m3=22.0,
            stiffness_class="soft",
        ),
        FoamParams(
            name="firm_block",
            shape="block",
            size_m=(0.060, 0.060, 0.070),
            young_pa=150e3,
            poisson=0.3,
            density_kg_m3=50.0,
            stiffness_class="firm",
            rgba=(0.35, 0.55, 0.85, 1.0),
        ),
        FoamParams(
            name="cylinder",
            shape="cylinder",
            size_m=(0.065, 0.065, 0.070),
            young_pa=25e3,
            poisson=0.3,
            stiffness_class="soft",
            rgba=(0.9, 0.45, 0.35, 1.0),
        ),
        FoamParams(
            name="sphere",
            shape="sphere",
            size_m=(0.070, 0.070, 0.070),
            young_pa=80e3,
            poisson=0.3,
            density_kg_m3=40.0,
            stiffness_class="firm",
            rgba=(0.5, 0.75, 0.45, 1.0),
        ),
    )
}
DEFAULT_OBJECT = "block"


def mesh_object(path: Path, material: FoamParams, scale_m: float = 0.001) -> FoamParams:
    """A foam of the closed surface in `path` (.stl/.obj, `scale_m` metres per unit) with the material
    and fidelity of `material`; ConfigError (one line) for a file that is no closed, fitting surface."""
    from twin.sim.tetmesh import load_surface  # imports meshio: only for mesh foams

    surface = load_surface(Path(path), scale_m)
    extent = surface.points_m.max(axis=0) - surface.points_m.min(axis=0)
    return replace(  # resolution and dof None: the mesh foam's own defaults, not the material's
        material,
        name=Path(path).stem,
        shape="mesh",
        mesh_file=str(Path(path).resolve()),
        mesh_scale_m=scale_m,
        size_m=tuple(float(e) for e in extent),
        resolution=None,
        dof=None,
    )


def get_object(name: str) -> FoamParams:
    """Look up a library object; ConfigError names the choices."""
    try:
        return LIBRARY[name]
    except KeyError:
        raise ConfigError(f"unknown object '{name}' (choose from {', '.join(sorted(LIBRARY))})") from None
