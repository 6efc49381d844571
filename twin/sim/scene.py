"""Compose the simulated rig in code: the MJCF hand scene plus a foam object from parameters."""

from __future__ import annotations

from pathlib import Path

import mujoco
from dm_control import mjcf

from twin.interface.errors import ConfigError
from twin.sim.foam import FLEXCOMP_TYPE, FoamParams

MODEL_DIR = Path(__file__).resolve().parents[2] / "models" / "barrett_mjcf"
SCENE_XML = MODEL_DIR / "scene.xml"
HAND_XML = MODEL_DIR / "bh8.xml"
PALM_SURFACE_Z_M = 0.075
"""Top of the palm collision cylinder in the palm frame (bh8.xml)."""
FOAM_NAME = "foam"


def scene_mjcf(foam: FoamParams | None = None, *, cameras: bool = False) -> mjcf.RootElement:
    """The hand scene as an mjcf tree, with the foam resting on the palm if given, and the simulated
    Flea2 stereo pair (twin.sim.cameras) above it if `cameras`."""
    root = mjcf.from_path(str(SCENE_XML))
    if foam is not None:
        add_foam(root, foam)
    if cameras:
        from twin.sim.cameras import add_stereo_cameras  # cameras.py reads FOAM_NAME from here

        add_stereo_cameras(root)
    return root


def add_foam(root: mjcf.RootElement, foam: FoamParams) -> None:
    """Add `foam` as a volumetric flexcomp centred on the palm, 1 mm above its surface."""
    count = foam.resolution
    spacing = [s / (count - 1) for s in foam.size_m]
    z = PALM_SURFACE_Z_M + foam.size_m[2] / 2 + 0.001
    fc = root.worldbody.add(
        "flexcomp",
        name=FOAM_NAME,
        type=FLEXCOMP_TYPE[foam.shape],
        dim=3,
        count=[count] * 3,
        spacing=spacing,
        pos=[0.0, 0.0, z],
        radius=0.001,
        dof=foam.dof,
        mass=foam.mass_kg,
        rgba=list(foam.rgba),
    )
    fc.elasticity.young = foam.young_pa
    fc.elasticity.poisson = foam.poisson
    fc.elasticity.damping = foam.damping
    fc.contact.selfcollide = "none"
    fc.contact.condim = 3
    fc.contact.friction = [foam.friction, 0.005, 0.0001]
    fc.contact.solref = [0.004, 1]
    fc.contact.solimp = [0.95, 0.99, 0.001]
    fc.edge.equality = "false"


def compile_scene(root: mjcf.RootElement) -> mujoco.MjModel:
    """Compile an mjcf tree to an MjModel (assets passed in memory); ConfigError, one line, when MuJoCo
    refuses the scene (e.g. an object too light for its mass and inertia to be represented)."""
    try:
        return mujoco.MjModel.from_xml_string(root.to_xml_string(), root.get_assets())
    except ValueError as exc:
        reason = " ".join(str(exc).removeprefix("Error: ").split())
        raise ConfigError(f"MuJoCo cannot build the scene: {reason}") from None


def build_model(foam: FoamParams | None = None, *, cameras: bool = False) -> mujoco.MjModel:
    """The compiled scene with an optional foam object and, optionally, the stereo cameras."""
    return compile_scene(scene_mjcf(foam, cameras=cameras))
