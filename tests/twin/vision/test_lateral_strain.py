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
