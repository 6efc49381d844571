"""Compose the simulated rig in code: the MJCF hand scene plus a foam object from parameters."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import mujoco
from dm_control import mjcf

from twin.assets import SCENE_XML
from twin.interface.errors import ConfigError
from twin.sim.foam import FLEXCOMP_TYPE, FoamParams

if TYPE_CHECKING:
    from twin.sim.tetmesh import TetMesh

PALM_SURFACE_Z_M = 0.075
"""Top of the palm collision cylinder in the palm frame (bh8.xml)."""
FOAM_NAME = "foam"


def scene_mjcf(
    foam: FoamParams | None = None, *, cameras: bool = False, camera_placement: object = None
) -> mjcf.RootElement:
    """The hand scene as an mjcf tree, with the foam resting on the palm if given, and the simulated
    Flea2 stereo pair (twin.sim.cameras) if `cameras`, at `camera_placement` (a
    twin.sim.cameras.CameraPlacement, or a sequence of them for one pair each; None: its default)."""
    root = mjcf.from_path(str(SCENE_XML))
    if foam is not None:
        add_foam(root, foam)
    if cameras:
        from twin.sim.cameras import add_stereo_cameras  # cameras.py reads FOAM_NAME from here

        add_stereo_cameras(root, placement=camera_placement)
    return root


VOLUMETRIC_SOLVER = {"solver": "CG", "tolerance": 1e-5, "iterations": 120}
"""Solver options a volumetric foam needs: MuJoCo's discrete integrator solves M + h^2 K by PCG, whose
residual target is `tolerance` and whose cap is `iterations`; with light vertices and h^2 K >> M it stops
short at 1e-8 (mjWARN_INERTIA). With the preset's vertex armature 120 iterations suffice; CG is ~1.8x
faster than Newton here (benchmarks/foam_solver_study.py)."""


def foam_mesh(foam: FoamParams) -> TetMesh:
    """The volumetric mesh of a faithful foam (gmsh; cached)."""
    from twin.sim.tetmesh import file_mesh, primitive_mesh  # gmsh: only for volumetric foams

    if foam.shape == "mesh":
        return file_mesh(Path(foam.mesh_file), foam.edge_m, foam.mesh_scale_m)
    return primitive_mesh(foam.shape, foam.size_m, foam.edge_m)


def add_foam(root: mjcf.RootElement, foam: FoamParams, modulus_scale: float | None = None) -> None:
    """Add `foam` as a flexcomp resting on the palm, 1 mm above its surface at its placement: a
    tetrahedral mesh of its volume (faithful, and every mesh foam, whose fast preset drives that mesh
    by 8 trilinear nodes) or a flexcomp primitive (fast), per its fidelity preset.

    The flex's modulus is `young_pa` times the foam's calibration scale (twin.sim.calibration: what makes
    the flex push back on the fingertips as the material does); `modulus_scale` overrides it."""
    disc = foam.discretization
    z = PALM_SURFACE_Z_M + foam.size_m[2] / 2 + 0.001
    pos = [*foam.placement_m, z]
    common = dict(name=FOAM_NAME, dim=3, pos=pos, radius=0.001, dof=disc.dof, rgba=list(foam.rgba))
    if disc.volumetric or foam.shape == "mesh":
        mesh = foam_mesh(foam)
        parent = root.worldbody
        if disc.armature_kg:  # the vertex joints flexcomp makes take their default from the frame's class
            cls = root.default.add("default", dclass=f"{FOAM_NAME}_vertex")
            cls.joint.armature = disc.armature_kg
            parent = root.worldbody.add("body", name=f"{FOAM_NAME}_frame", childclass=f"{FOAM_NAME}_vertex")
        fc = parent.add(
            "flexcomp",
            type="direct",
            point=mesh.points_m.ravel().tolist(),
            element=mesh.tets.ravel().tolist(),
            mass=foam.mass_kg,
            **common,
        )
        if disc.volumetric:
            for key, value in VOLUMETRIC_SOLVER.items():
                setattr(root.option, key, value)
    else:
        count = disc.resolution
        spacing = [s / (count - 1) for s in foam.size_m]
        fc = root.worldbody.add(
            "flexcomp",
            type=FLEXCOMP_TYPE[foam.shape],
            count=[count] * 3,
            spacing=spacing,
            mass=foam.mass_kg,
            **common,
        )
    if modulus_scale is None:
        from twin.sim.calibration import modulus_scale as calibrated_scale

        modulus_scale = calibrated_scale(foam)
    fc.elasticity.young = foam.young_pa * modulus_scale
    fc.elasticity.poisson = foam.poisson
    fc.elasticity.damping = foam.damping
    fc.contact.selfcollide = "none"
    fc.contact.condim = 3
    fc.contact.friction = [foam.friction, 0.005, 0.0001]
    fc.contact.solref = list(disc.solref)
    fc.contact.solimp = list(disc.solimp)
    if disc.priority:
        fc.contact.priority = disc.priority
    fc.edge.equality = "false"


def compile_scene(root: mjcf.RootElement) -> mujoco.MjModel:
    """Compile an mjcf tree to an MjModel (assets passed in memory); ConfigError, one line, when MuJoCo
    refuses the scene (e.g. an object too light for its mass and inertia to be represented)."""
    try:
        return mujoco.MjModel.from_xml_string(root.to_xml_string(), root.get_assets())
    except ValueError as exc:
        reason = " ".join(str(exc).removeprefix("Error: ").split())
        raise ConfigError(f"MuJoCo cannot build the scene: {reason}") from None


def build_model(
    foam: FoamParams | None = None, *, cameras: bool = False, camera_placement: object = None
) -> mujoco.MjModel:
    """The compiled scene with an optional foam object and, optionally, the stereo cameras."""
    return compile_scene(scene_mjcf(foam, cameras=cameras, camera_placement=camera_placement))
