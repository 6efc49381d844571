"""Menagerie-style model checks: every scene compiles, steps 1 s under random controls with no
MuJoCo warning, and the folder keeps the Menagerie layout."""

from pathlib import Path

import mujoco
import numpy as np
import pytest

from twin.assets import HAND_XML, MODEL_DIR, SCENE_XML
from twin.sim.foam import LIBRARY
from twin.sim.scene import build_model

REQUIRED_FILES = ("bh8.xml", "scene.xml", "README.md", "LICENSE", "CHANGELOG.md")


def _step_random(model: mujoco.MjModel, seconds: float = 1.0, seed: int = 0) -> mujoco.MjData:
    data = mujoco.MjData(model)
    rng = np.random.default_rng(seed)
    lo, hi = model.actuator_ctrlrange.T
    for i in range(int(seconds / model.opt.timestep)):
        if i % 50 == 0:
            data.ctrl[:] = rng.uniform(lo, hi)
        mujoco.mj_step(model, data)
    return data


def _warnings(data: mujoco.MjData) -> dict[str, int]:
    return {mujoco.mjtWarning(i).name: w.number for i, w in enumerate(data.warning) if w.number}


@pytest.mark.parametrize("path", [HAND_XML, SCENE_XML], ids=lambda p: p.name)
def test_xml_compiles_and_steps_without_warnings(path: Path):
    model = mujoco.MjModel.from_xml_path(str(path))
    data = _step_random(model)
    assert _warnings(data) == {}
    assert np.isfinite(data.qpos).all()


@pytest.mark.parametrize("name", sorted(LIBRARY))
def test_scene_with_each_foam_steps_without_warnings(name: str):
    model = build_model(LIBRARY[name])
    data = _step_random(model)
    assert _warnings(data) == {}
    assert model.nflex == 1
    assert np.isfinite(data.flexvert_xpos).all()
    # The foam stays in the hand: no vertex fell below the palm surface.
    assert data.flexvert_xpos[:, 2].min() > 0.06


def test_hand_structure_matches_datasheet():
    model = mujoco.MjModel.from_xml_path(str(HAND_XML))
    link_joints = [
        model.joint(i).name for i in range(model.njnt) if not model.joint(i).name.endswith("_drive")
    ]
    assert sorted(link_joints) == sorted(
        ["f1_spread", "f2_spread", "f1_inner", "f2_inner", "f3_inner", "f1_outer", "f2_outer", "f3_outer"]
    )
    assert model.nu == 4
    masses = {b: model.body(b).mass[0] for b in ("palm", "f1_knuckle", "f1_inner", "f1_outer")}
    assert masses == pytest.approx(
        {"palm": 0.506, "f1_knuckle": 0.141, "f1_inner": 0.0621, "f1_outer": 0.0414}
    )
    assert np.degrees(model.joint("f1_inner").range) == pytest.approx([0, 140])
    assert np.degrees(model.joint("f1_outer").range) == pytest.approx([0, 48])
    assert np.degrees(model.joint("f1_spread").range) == pytest.approx([0, 180])


def test_visual_and_collision_classes_are_separate():
    model = mujoco.MjModel.from_xml_path(str(HAND_XML))
    for i in range(model.ngeom):
        name = model.geom(i).name
        if name.endswith("_visual"):
            assert model.geom_contype[i] == 0 and model.geom_conaffinity[i] == 0, name
            assert model.geom_group[i] == 2, name
        elif name.endswith("_collision"):
            assert model.geom_group[i] == 3, name


def test_menagerie_folder_layout():
    present = {p.name for p in MODEL_DIR.iterdir()}
    missing = [f for f in REQUIRED_FILES if f not in present]
    assert not missing, f"models/barrett_mjcf lacks {missing}"
    readme = (MODEL_DIR / "README.md").read_text()
    for number in ("0.506", "17000", "1.1675", "0.5 N"):
        assert number in readme, f"README does not document {number}"
