"""The object's width from two stereo pairs on opposite sides: real renders of the twin's foam block
through the project's StereoPipeline, scored against the block's own geometry."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from twin.sim.backend import SimBackend
from twin.sim.cameras import PLACEMENTS
from twin.sim.foam import LIBRARY
from twin.sim.scene import PALM_SURFACE_Z_M
from twin.vision import lateral_strain as ls
from twin.vision.pipeline import StereoPipeline
from twin.vision.reconstruct import Rectifier

BLOCK = LIBRARY["block"]
SHIFT_M = 0.003


def _clouds_at_rest(x_m: float) -> tuple[list[np.ndarray], float]:
    """Both pairs' reconstructions of the block resting `x_m` off the palm's centre, and the flex's
    rendered skin (its radius: MuJoCo draws a flex that far outside its vertices)."""
    foam = replace(BLOCK, placement_m=(x_m, 0.0))
    backend = SimBackend(
        foam, seed=5, stereo=True, stereo_placement=[PLACEMENTS["lateral"], PLACEMENTS["opposite"]]
    )
    backend.connect()
    try:
        clouds = []
        for k, stereo in enumerate(backend.stereo_pairs):
            calibration = stereo.calibration()
            pipeline = StereoPipeline(calibration, backend.object_box(Rectifier(calibration), pair=k))
            clouds.append(pipeline.process(stereo.read()).reconstruction.points_hand)
        return clouds, float(backend.world.model.flex_radius[0])
    finally:
        backend.disconnect()


@pytest.fixture(scope="module")
def seen() -> dict[float, tuple[list[np.ndarray], float]]:
    return {x: _clouds_at_rest(x) for x in (0.0, SHIFT_M)}


def test_two_opposite_pairs_read_the_blocks_width(seen):
    """The distance between the two x faces is the block's width (plus the rendered skin either side)."""
    for (plus, minus), skin_m in seen.values():
        width = ls.width_m(plus, minus, PALM_SURFACE_Z_M, BLOCK.size_m[2])
        assert width == pytest.approx(BLOCK.size_m[0] + 2 * skin_m, abs=0.5e-3)


def test_a_rigid_shift_moves_each_face_but_not_the_width(seen):
    """3 mm of placement moves the face one pair sees by 3 mm (what one pair cannot tell from expansion)
    and leaves the width; the two faces' midpoint reads the shift."""
    (plus0, minus0), _ = seen[0.0]
    (plus1, minus1), _ = seen[SHIFT_M]
    args = (PALM_SURFACE_Z_M, BLOCK.size_m[2])
    face_shift = ls.face_position_m(plus1, 1.0, *args) - ls.face_position_m(plus0, 1.0, *args)
    assert face_shift == pytest.approx(SHIFT_M, abs=0.3e-3)
    assert ls.width_m(plus1, minus1, *args) - ls.width_m(plus0, minus0, *args) == pytest.approx(
        0.0, abs=0.3e-3
    )
    assert ls.centre_x_m(plus1, minus1, *args) - ls.centre_x_m(plus0, minus0, *args) == pytest.approx(
        SHIFT_M, abs=0.2e-3
    )


def test_a_face_out_of_view_is_one_clear_error():
    with pytest.raises(ValueError, match="not in view"):
        ls.face_position_m(np.zeros((5, 3)), 1.0, PALM_SURFACE_Z_M, BLOCK.size_m[2])


def _hooke(young_pa: np.ndarray, poisson: np.ndarray, stress_pa: float) -> np.ndarray:
    """(eps_x, eps_z) of a free block under a uniaxial stress (Hooke): eps_z = -s/E, eps_x = -nu eps_z."""
    eps_z = -stress_pa / young_pa
    return np.column_stack([-poisson * eps_z, eps_z])


def test_the_joint_read_inverts_hookes_law_within_its_interval():
    """Strains of a free block under a set stress (the balanced grasp's force is set) at the twin's grid
    of E x nu: blocks between the grid's points are read back, E and nu each within its 95 % interval."""
    young = np.repeat([28e3, 40e3, 57e3], 3)
    poisson = np.tile([0.2, 0.275, 0.35], 3)
    stress_pa = 5e3
    grid = _hooke(young, poisson, stress_pa)
    for e_true, nu_true in ((33e3, 0.31), (48e3, 0.22)):
        strains = _hooke(np.array([e_true]), np.array([nu_true]), stress_pa)[0]
        reading = ls.read_modulus_and_poisson(tuple(strains), young, poisson, grid)
        assert reading.poisson_95[0] <= nu_true <= reading.poisson_95[1]
        assert reading.young_95_pa[0] <= e_true <= reading.young_95_pa[1]
        assert reading.poisson == pytest.approx(nu_true, abs=0.01)
        assert reading.young_pa == pytest.approx(e_true, rel=0.02)
