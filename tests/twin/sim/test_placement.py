"""An object placed off the palm's centre: where the twin puts it, and what it refuses."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from twin.interface.errors import ConfigError
from twin.sim.foam import LIBRARY
from twin.sim.scene import FOAM_NAME, build_model


@pytest.mark.parametrize("placement_m", [(0.0, 0.0), (0.003, -0.002), (-0.008, 0.006)])
def test_the_foam_starts_centred_on_its_placement(placement_m):
    model = build_model(LIBRARY["block"].with_overrides(placement_m=placement_m))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    flex = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_FLEX, FOAM_NAME)
    start = model.flex_vertadr[flex]
    vertices = data.flexvert_xpos[start : start + model.flex_vertnum[flex]]
    centre = (vertices.min(axis=0) + vertices.max(axis=0)) / 2
    assert np.allclose(centre[:2], placement_m, atol=1e-6)


@pytest.mark.parametrize(
    ("placement_m", "words"),
    [
        ((0.011, 0.0), "over 10 mm off the palm centre"),
        ((0.0, float("nan")), "2 finite offsets"),
    ],
)
def test_a_placement_off_the_palm_is_one_line(placement_m, words):
    with pytest.raises(ConfigError, match=words):
        LIBRARY["block"].with_overrides(placement_m=placement_m)


def test_a_wide_object_placed_off_centre_reaches_the_finger_roots():
    wide = LIBRARY["block"].with_overrides(size_m=(0.085, 0.06, 0.07))
    with pytest.raises(ConfigError, match="reaches the finger roots"):
        wide.with_overrides(placement_m=(0.004, 0.0))
